//! The kd-trees against brute force: random triangle soups, a generated tree, instanced
//! scenes; short stacks against the unbounded stack; restarts; determinism.

use glam::Vec3;
use std::sync::OnceLock;
use sylva_geom::{Instance, Model};
use sylva_grow::Species;
use sylva_testkit::scenes::*;
use sylva_trace::{Hit, ModelAccel, Ray, SceneAccel, TraceStats, TraversalConfig};

fn red_maple() -> &'static Model {
    static M: OnceLock<Model> = OnceLock::new();
    M.get_or_init(|| {
        Species::builtin("red_maple")
            .expect("built-in species")
            .build_model()
            .expect("red maple generates")
    })
}

fn red_maple_accel() -> &'static ModelAccel {
    static A: OnceLock<ModelAccel> = OnceLock::new();
    A.get_or_init(|| ModelAccel::build(red_maple()))
}

fn same(a: Option<Hit>, b: Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.t == b.t && a.instance == b.instance && a.triangle == b.triangle && a.u == b.u
        }
        _ => false,
    }
}

#[test]
fn soup_closest_and_any_hit_equal_brute_force() {
    for (n, seed) in [(1, 1), (7, 2), (60, 3), (2000, 4)] {
        let model = soup(n, seed);
        let accel = ModelAccel::build(&model);
        let mut r = rng(100 + seed);
        let mut hits = 0;
        for k in 0..3000 {
            let mut ray = random_ray(&mut r, 1.0);
            if k % 3 == 0 {
                ray.t_max = uniform(&mut r, 0.5, 3.0); // segments, as shadow rays use
            }
            let mut st = TraceStats::default();
            let kd = accel.closest_hit(&ray, TraversalConfig::default(), &mut st);
            let bf = accel.brute_closest_hit(&ray);
            assert!(
                same(kd, bf),
                "n={n} ray {k} {ray:?}: kd {kd:?} brute {bf:?}"
            );
            assert_eq!(
                accel.any_hit(&ray, TraversalConfig::default(), &mut st),
                bf.is_some(),
                "any-hit n={n} ray {k}"
            );
            hits += bf.is_some() as usize;
        }
        if n >= 60 {
            assert!(hits > 300, "too few hits ({hits}) to mean anything");
        }
    }
}

#[test]
fn tree_closest_hit_equals_brute_force_and_short_stacks_equal_unbounded() {
    let model = red_maple();
    let accel = red_maple_accel();
    let b = model.bounds;
    let (c, ext) = ((b.min + b.max) * 0.5, (b.max - b.min).max_element() * 0.5);
    let mut r = rng(7);
    let mut hits = 0;
    let mut restarts = [0u64; 3];
    for k in 0..300 {
        let mut ray = random_ray(&mut r, ext);
        ray.origin += c;
        let bf = accel.brute_closest_hit(&ray);
        let mut st = TraceStats::default();
        let unb = accel.closest_hit(&ray, TraversalConfig::UNBOUNDED, &mut st);
        assert_eq!(st.restarts, 0, "unbounded stack never restarts");
        assert!(same(unb, bf), "ray {k}: kd {unb:?} brute {bf:?}");
        for (j, size) in [1usize, 2, 5].into_iter().enumerate() {
            let mut st = TraceStats::default();
            let cfg = TraversalConfig::with_stack(size);
            let h = accel.closest_hit(&ray, cfg, &mut st);
            assert!(same(h, unb), "stack {size}, ray {k}");
            assert_eq!(accel.any_hit(&ray, cfg, &mut st), bf.is_some());
            restarts[j] += st.restarts;
        }
        hits += bf.is_some() as usize;
    }
    assert!(hits > 100, "{hits} hits");
    // A stack of 1 on a tree of depth ~30 must drop entries and restart.
    assert!(
        restarts[0] > 0 && restarts[0] >= restarts[2],
        "{restarts:?}"
    );
}

#[test]
fn crowded_top_level_leaves_equal_brute_force() {
    // 40 instances piled on nearly the same spot: the top-level leaves hold more instances
    // than the closest-hit query sorts by entry (16), so the overflow path runs too; a
    // duplicate pair (same model and transform) makes exact ties between instances.
    let accel = crowded_scene();
    let top = accel.top_stats();
    // On average more than 16 per non-empty leaf: some leaf overflows the sorted array.
    assert!(
        top.references > 16 * (top.leaves - top.empty_leaves),
        "{top:?}"
    );
    let mut r = rng(24);
    let (mut hits, mut dup_wins) = (0, 0);
    for k in 0..800 {
        let mut ray = random_ray(&mut r, 2.0);
        ray.origin += Vec3::new(0.0, 1.0, 0.0);
        if k % 4 == 0 {
            ray.t_max = uniform(&mut r, 0.5, 3.0);
        }
        for cfg in [TraversalConfig::default(), TraversalConfig::UNBOUNDED] {
            let mut st = TraceStats::default();
            let kd = accel.closest_hit(&ray, cfg, &mut st);
            assert!(same(kd, accel.brute_closest_hit(&ray)), "ray {k}");
            assert_eq!(accel.any_hit(&ray, cfg, &mut st), accel.brute_any_hit(&ray));
            if let Some(h) = kd {
                hits += !h.is_ground() as usize;
                // The copy of instance 7 never wins: ties go to the lower instance.
                dup_wins += (h.instance == 40) as usize;
            }
        }
    }
    assert!(hits > 300, "{hits}");
    assert_eq!(dup_wins, 0);
}

#[test]
fn instanced_scene_equals_flattened_brute_force() {
    // Two models, six instances with rotations, scales and overlaps, and a ground.
    let models = vec![soup(300, 11), soup(150, 12)];
    let mut instances = Vec::new();
    for k in 0..6 {
        instances.push(Instance {
            model: (k % 2) as u32,
            position: Vec3::new(
                k as f32 * 0.9 - 2.0,
                1.0 + 0.1 * k as f32,
                (k % 3) as f32 * 0.5,
            ),
            rotation_deg: 37.0 * k as f32,
            scale: 0.6 + 0.25 * k as f32,
        });
    }
    let accel = SceneAccel::from_parts(&models, &instances, Some([4.0, 4.0])).unwrap();
    // Flattened world-space triangle soup.
    let mut world: Vec<(u32, u32, [Vec3; 3])> = Vec::new();
    for (k, inst) in instances.iter().enumerate() {
        let x = inst.transform();
        let m = &models[inst.model as usize].mesh;
        for (t, tri) in m.indices.iter().enumerate() {
            let p = tri.map(|i| x.transform_point3(Vec3::from_array(m.positions[i as usize])));
            world.push((k as u32, t as u32, p));
        }
    }
    let mut r = rng(5);
    let mut tree_hits = 0;
    for k in 0..1500 {
        let mut ray = random_ray(&mut r, 3.0);
        ray.origin += Vec3::new(0.0, 1.5, 0.0);
        let mut st = TraceStats::default();
        let kd = accel.closest_hit(&ray, TraversalConfig::default(), &mut st);
        // Same arithmetic per instance: identical.
        assert!(same(kd, accel.brute_closest_hit(&ray)), "ray {k}");
        assert_eq!(
            accel.any_hit(&ray, TraversalConfig::default(), &mut st),
            accel.brute_any_hit(&ray)
        );
        // World space: equal up to rounding.
        let mut flat: Option<(f32, u32, u32)> = None;
        for &(i, t, [a, b, c]) in &world {
            if let Some((th, _, _)) = sylva_trace::ray::intersect_triangle_vertices(&ray, a, b, c) {
                if flat.is_none_or(|f| th < f.0) {
                    flat = Some((th, i, t));
                }
            }
        }
        let ground = accel.ground_hit(&ray);
        let flat = match (flat, ground) {
            (Some(f), Some(g)) if g < f.0 => Some((g, Hit::GROUND, 0)),
            (None, Some(g)) => Some((g, Hit::GROUND, 0)),
            (f, _) => f,
        };
        match (kd, flat) {
            (None, None) => {}
            (Some(h), Some(f)) => {
                assert!(
                    (h.t - f.0).abs() <= 1e-4 * (1.0 + f.0),
                    "ray {k}: {h:?} {f:?}"
                );
                // Different triangles only where two candidates are equally near.
                if (h.instance, h.triangle) != (f.1, f.2) {
                    assert!(
                        (h.t - f.0).abs() <= 1e-5 * (1.0 + f.0),
                        "ray {k}: {h:?} {f:?}"
                    );
                }
                tree_hits += !h.is_ground() as usize;
            }
            (a, b) => panic!("ray {k}: kd {a:?} flattened {b:?}"),
        }
    }
    assert!(tree_hits > 200, "{tree_hits}");
}

#[test]
fn build_and_results_are_deterministic_across_thread_counts() {
    let model = soup(5000, 21);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| ModelAccel::build(&model));
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap()
        .install(|| ModelAccel::build(&model));
    assert_eq!(one.tree().stats(), two.tree().stats());
    let mut r = rng(9);
    for _ in 0..500 {
        let ray = random_ray(&mut r, 1.0);
        let mut s1 = TraceStats::default();
        let mut s2 = TraceStats::default();
        let a = one.closest_hit(&ray, TraversalConfig::default(), &mut s1);
        let b = two.closest_hit(&ray, TraversalConfig::default(), &mut s2);
        assert!(same(a, b));
        assert_eq!(s1, s2, "same work, same tree");
    }
}

#[test]
fn tree_statistics_are_sane() {
    let accel = red_maple_accel();
    let s = accel.tree().stats();
    assert_eq!(s.primitives, red_maple().triangle_count());
    assert!(s.references >= s.primitives);
    assert!(s.max_depth <= sylva_trace::MAX_DEPTH);
    assert_eq!(s.nodes, 2 * s.leaves - 1, "a binary tree");
    // Every triangle is referenced by at least one leaf: rays at each triangle's centroid
    // along its normal find it (or something at the same distance).
    let model = red_maple();
    let mut st = TraceStats::default();
    for (i, tri) in model.mesh.indices.iter().enumerate().step_by(97) {
        let p = tri.map(|k| Vec3::from_array(model.mesh.positions[k as usize]));
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        if n.length() < 1e-12 {
            continue;
        }
        let c = (p[0] + p[1] + p[2]) / 3.0;
        let n = n.normalize();
        let ray = Ray::segment(c + n * 1e-3, -n, 0.0, 2e-3);
        let kd = accel.closest_hit(&ray, TraversalConfig::default(), &mut st);
        let bf = accel.brute_closest_hit(&ray);
        assert!(same(kd, bf), "triangle {i}");
    }
}

/// Every opaque hit of `ray` on `accel`'s instances by testing every triangle of every
/// instance in model space (the trees' arithmetic), sorted like `all_hits`.
fn brute_all_hits(accel: &SceneAccel, models: &[&Model], ray: &Ray) -> Vec<(u32, u32, f32)> {
    let mut out = Vec::new();
    for (k, inst) in accel.instances().iter().enumerate() {
        let m = &models[inst.model as usize].mesh;
        let o = inst.to_model.transform_point3(ray.origin);
        let d = inst.to_model.transform_vector3(ray.dir);
        for (t, tri) in m.indices.iter().enumerate() {
            let p = tri.map(|i| Vec3::from_array(m.positions[i as usize]));
            let data = sylva_trace::TriangleData::new(p[0], p[1], p[2]);
            if data.is_degenerate() {
                continue;
            }
            let Some((th, u, v)) =
                sylva_trace::intersect_triangle(o, d, &data, ray.t_min, ray.t_max)
            else {
                continue;
            };
            if accel.models()[inst.model as usize].is_opaque_at(t as u32, u, v) {
                out.push((k as u32, t as u32, th));
            }
        }
    }
    out.sort_by(|a, b| (a.2, a.0, a.1).partial_cmp(&(b.2, b.0, b.1)).unwrap());
    out
}

#[test]
fn all_hits_equal_brute_force_with_alpha_and_instances() {
    // Alpha-tested leaves (the maple) and opaque soups, translated, rotated and scaled, some
    // overlapping: every opaque surface a line crosses, each once, in order.
    let maple = red_maple().clone();
    let soup_model = soup(400, 31);
    let models = vec![maple, soup_model];
    let instances = vec![
        Instance {
            model: 0,
            position: Vec3::ZERO,
            rotation_deg: 0.0,
            scale: 1.0,
        },
        Instance {
            model: 0,
            position: Vec3::new(3.0, 0.0, 1.0),
            rotation_deg: 50.0,
            scale: 0.8,
        },
        Instance {
            model: 1,
            position: Vec3::new(0.5, 6.0, 0.0),
            rotation_deg: 10.0,
            scale: 2.0,
        },
    ];
    let accel = SceneAccel::from_parts(&models, &instances, Some([9.0, 9.0])).unwrap();
    let refs: Vec<&Model> = models.iter().collect();
    let b = models[0].bounds;
    let ext = (b.max - b.min).max_element() * 0.5;
    let mut r = rng(41);
    let (mut multi, mut alpha_rejects) = (0, 0);
    let mut out = Vec::new();
    for k in 0..120 {
        let mut ray = random_ray(&mut r, ext);
        ray.origin += (b.min + b.max) * 0.5;
        if k % 5 == 0 {
            ray.t_max = uniform(&mut r, 1.0, 10.0);
        }
        let mut st = TraceStats::default();
        accel.all_hits(&ray, TraversalConfig::default(), &mut st, &mut out);
        alpha_rejects += st.alpha_rejects;
        let got: Vec<(u32, u32, f32)> = out.iter().map(|h| (h.instance, h.triangle, h.t)).collect();
        assert_eq!(got, brute_all_hits(&accel, &refs, &ray), "ray {k}");
        // The first of them is the closest hit (the ground aside).
        let closest = accel.closest_hit(&ray, TraversalConfig::UNBOUNDED, &mut st);
        if let (Some(first), Some(c)) = (out.first(), closest.filter(|h| !h.is_ground())) {
            assert_eq!(
                (first.instance, first.triangle, first.t),
                (c.instance, c.triangle, c.t)
            );
        }
        multi += (out.len() > 3) as usize;
    }
    assert!(
        multi > 20,
        "too few rays crossing several surfaces: {multi}"
    );
    assert!(alpha_rejects > 0, "the alpha rule never ran");
}

#[test]
fn parts_hold_every_reference_once() {
    // The top level enters a model's tree part by part, so the parts must hold every
    // triangle reference of the tree, each in exactly one part.
    let accel = red_maple_accel();
    let tree = accel.tree();
    let parts = accel.parts();
    assert!(parts.len() > 8, "{} parts", parts.len());
    let mut seen = 0usize;
    for part in parts {
        let n = tree.subtree_primitives(part.node).len();
        assert!(n > 0, "empty parts are left out");
        seen += n;
    }
    assert_eq!(seen, tree.stats().references);
}

#[test]
fn forest_closest_hits_equal_brute_force_and_any_hit_agrees() {
    // Nine red maples (about 90 k alpha-tested triangles each), rotated, scaled and
    // overlapping: rays cross several crowns' parts. Rays come from outside the forest
    // (cameras) and from inside the crowns (shadow and gather rays).
    let model = red_maple().clone();
    let h = model.bounds.max.y;
    let mut r = rng(61);
    let instances: Vec<Instance> = (0..9)
        .map(|k| Instance {
            model: 0,
            position: Vec3::new(
                ((k % 3) as f32 - 1.0) * 0.4 * h,
                0.0,
                ((k / 3) as f32 - 1.0) * 0.4 * h,
            ),
            rotation_deg: uniform(&mut r, 0.0, 360.0),
            scale: uniform(&mut r, 0.8, 1.2),
        })
        .collect();
    let accel = SceneAccel::from_parts(&[model], &instances, Some([2.0 * h, 2.0 * h])).unwrap();
    assert!(accel.models()[0].parts().len() > 8);
    let (mut tree_hits, mut misses) = (0, 0);
    for k in 0..240 {
        let target = Vec3::new(
            uniform(&mut r, -0.7, 0.7) * h,
            uniform(&mut r, 0.1, 1.0) * h,
            uniform(&mut r, -0.7, 0.7) * h,
        );
        let origin = if k % 2 == 0 {
            Vec3::new(uniform(&mut r, -2.0, 2.0), uniform(&mut r, 0.1, 1.5), 2.5) * h
        } else {
            // Inside the crowns, in any direction.
            target + unit(&mut r) * uniform(&mut r, 0.0, 0.3) * h
        };
        let mut ray = Ray::new(origin, (target - origin).normalize_or(Vec3::Y));
        if k % 2 == 1 {
            ray.dir = unit(&mut r);
        }
        if k % 5 == 0 {
            ray.t_max = uniform(&mut r, 0.05, 1.0) * h;
        }
        let bf = accel.brute_closest_hit(&ray);
        for cfg in [TraversalConfig::default(), TraversalConfig::UNBOUNDED] {
            let mut st = TraceStats::default();
            let kd = accel.closest_hit(&ray, cfg, &mut st);
            assert!(same(kd, bf), "ray {k} {ray:?}: kd {kd:?} brute {bf:?}");
            assert_eq!(
                accel.any_hit(&ray, cfg, &mut st),
                kd.is_some(),
                "any-hit against closest hit, ray {k}"
            );
        }
        match bf {
            Some(h) => tree_hits += !h.is_ground() as usize,
            None => misses += 1,
        }
    }
    assert!(
        tree_hits > 80 && misses > 10,
        "{tree_hits} tree hits, {misses} misses"
    );
}

/// A model's kd-tree is cached: read back it answers every ray as the built one, another
/// mesh is another entry, a damaged entry is built again (its file named and replaced), and
/// a tree whose bytes break its structure is refused, never walked.
#[test]
fn cached_trees_answer_as_built_and_damaged_ones_are_built_again() {
    use sylva_core::cache::Cache;
    use sylva_trace::kdtree::KdTree;

    let mut models = vec![soup(300, 41), soup(200, 42)];
    models[0].name = "first".into();
    models[1].name = "second".into();
    let instances: Vec<Instance> = (0..3)
        .map(|k| Instance {
            model: (k % 2) as u32,
            position: Vec3::new(k as f32, 1.0, 0.0),
            rotation_deg: 30.0 * k as f32,
            scale: 1.0,
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::new(dir.path());
    let build = |models: &[Model]| {
        SceneAccel::from_parts_cached(models, &instances, Some([4.0, 4.0]), Some(&cache)).unwrap()
    };
    let plain = SceneAccel::from_parts(&models, &instances, Some([4.0, 4.0])).unwrap();
    let (first, r) = build(&models);
    assert_eq!((r.cached, r.built, r.warnings.len()), (0, 2, 0), "{r:?}");
    let (second, r) = build(&models);
    assert_eq!((r.cached, r.built), (2, 0), "{r:?}");
    for (a, b) in second.models().iter().zip(plain.models()) {
        assert_eq!(a.tree().nodes(), b.tree().nodes());
        assert_eq!(a.tree().leaf_indices(), b.tree().leaf_indices());
        assert_eq!(a.tree().stats(), b.tree().stats());
    }
    let mut r = rng(43);
    for k in 0..400 {
        let mut ray = random_ray(&mut r, 2.0);
        ray.origin += Vec3::new(1.0, 1.0, 0.0);
        let mut st = TraceStats::default();
        let cfg = TraversalConfig::default();
        let want = plain.closest_hit(&ray, cfg, &mut st);
        assert!(same(first.closest_hit(&ray, cfg, &mut st), want), "ray {k}");
        assert!(
            same(second.closest_hit(&ray, cfg, &mut st), want),
            "ray {k}"
        );
        assert_eq!(
            second.any_hit(&ray, cfg, &mut st),
            plain.any_hit(&ray, cfg, &mut st)
        );
    }
    let entries = || {
        let mut v: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        v.sort();
        v
    };
    assert_eq!(entries().len(), 2);

    // Another mesh (one vertex moved): its own entry.
    let mut moved = models.clone();
    moved[1].mesh.positions[0][0] += 0.01;
    let (_, r) = build(&moved);
    assert_eq!((r.cached, r.built), (1, 1), "{r:?}");
    assert_eq!(entries().len(), 3);

    // A truncated entry and a foreign file: built again, the file named, and replaced.
    let path = entries()
        .into_iter()
        .find(|p| p.to_string_lossy().contains("first-kdtree"))
        .unwrap();
    let good = std::fs::read(&path).unwrap();
    for bad in [&good[..good.len() / 2], &b"not a tree"[..]] {
        std::fs::write(&path, bad).unwrap();
        let (again, r) = build(&models);
        assert_eq!(r.built, 1, "{r:?}");
        assert_eq!(r.warnings.len(), 1, "{r:?}");
        assert!(
            r.warnings[0].contains(&path.display().to_string()),
            "{:?}",
            r.warnings
        );
        assert_eq!(again.models().len(), 2);
        assert_eq!(std::fs::read(&path).unwrap(), good, "replaced");
    }

    // The bytes of a tree round-trip; broken structure is refused with the reason.
    let tree = plain.models()[0].tree();
    let n = models[0].mesh.indices.len();
    let bytes = tree.to_bytes();
    let back = KdTree::from_bytes(&bytes, n).unwrap();
    assert_eq!(back.nodes(), tree.nodes());
    assert!(KdTree::from_bytes(&bytes, 3)
        .unwrap_err()
        .contains("triangles"));
    assert!(KdTree::from_bytes(&bytes[..bytes.len() - 1], n).is_err());
    // The root's far child pointed back at itself: refused (a walk would never end).
    let root = tree.nodes()[0].raw();
    assert_ne!(root[0] & 3, 3, "the root is an inner node");
    let at = 24 + 56 + 8; // box, statistics, node count
    let mut looped = bytes.clone();
    looped[at..at + 4].copy_from_slice(&(root[0] & 3).to_le_bytes());
    let e = KdTree::from_bytes(&looped, n).unwrap_err();
    assert!(e.contains("node 0"), "{e}");
}
