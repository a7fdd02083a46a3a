//! Packet traversal against single rays: every lane of `closest_hit_packet` must report
//! exactly the hit that `closest_hit` finds for that ray alone, for coherent packets (one
//! origin, neighbouring directions, as a camera makes), incoherent ones (mixed direction
//! signs, split into groups), partial masks, short stacks that restart, and crowded
//! top-level leaves.

use glam::Vec3;
use sylva_geom::Instance;
use sylva_grow::Species;
use sylva_testkit::scenes::*;
use sylva_trace::{
    Hit, KdTracer, Ray, RayQuery, SceneAccel, ShadowRay, TraceStats, TraversalConfig, PACKET,
};

fn same(a: Option<Hit>, b: Option<Hit>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.t == b.t
                && a.instance == b.instance
                && a.triangle == b.triangle
                && a.u == b.u
                && a.v == b.v
        }
        _ => false,
    }
}

/// Checks every lane of the packet against single rays under `cfg`; returns the packet's
/// work counters.
fn check(accel: &SceneAccel, rays: &[Ray; PACKET], mask: u32, cfg: TraversalConfig) -> TraceStats {
    let mut st = TraceStats::default();
    let got = accel.closest_hit_packet(rays, mask, cfg, &mut st);
    for l in 0..PACKET {
        if mask >> l & 1 == 0 {
            assert!(got[l].is_none(), "lane {l} is not in the mask");
            continue;
        }
        let mut one = TraceStats::default();
        let want = accel.closest_hit(&rays[l], TraversalConfig::UNBOUNDED, &mut one);
        assert!(
            same(got[l], want),
            "lane {l} of {rays:?} (stack {}): packet {:?}, single {want:?}",
            cfg.stack_size,
            got[l]
        );
    }
    assert_eq!(st.rays, mask.count_ones() as u64);
    st
}

/// A small forest of red maples (alpha-tested leaves), rotated and scaled, on a ground.
fn maple_forest() -> SceneAccel {
    let model = Species::builtin("red_maple")
        .expect("built-in species")
        .build_model()
        .expect("red maple generates");
    let h = model.bounds.max.y;
    let mut instances = Vec::new();
    let mut r = rng(31);
    for k in 0..9 {
        instances.push(Instance {
            model: 0,
            position: Vec3::new(
                (k % 3) as f32 * 0.45 * h - 0.45 * h + uniform(&mut r, -0.1, 0.1) * h,
                0.0,
                (k / 3) as f32 * 0.45 * h - 0.45 * h,
            ),
            rotation_deg: uniform(&mut r, 0.0, 360.0),
            scale: uniform(&mut r, 0.8, 1.2),
        });
    }
    let half = 1.5 * h;
    SceneAccel::from_parts(&[model], &instances, Some([half, half])).unwrap()
}

/// A camera position outside a forest of height `h` and a point inside it to look at.
fn view_into_forest(r: &mut sylva_core::SplitMix64, h: f32) -> (Vec3, Vec3) {
    let eye = Vec3::new(
        uniform(r, -2.0, 2.0) * h,
        uniform(r, 0.1, 1.5) * h,
        uniform(r, 1.5, 2.5) * h,
    );
    let target = Vec3::new(
        uniform(r, -0.6, 0.6) * h,
        uniform(r, 0.2, 0.9) * h,
        uniform(r, -0.6, 0.6) * h,
    );
    (eye, target)
}

#[test]
fn coherent_packets_equal_single_rays_on_a_forest() {
    let accel = maple_forest();
    let b = accel.top_stats();
    assert!(b.nodes > 1);
    let h = accel.instances()[0].world_bounds.max.y;
    let mut r = rng(41);
    let mut hits = 0usize;
    let mut tree_hits = 0usize;
    let mut restarts = [0u64; 3];
    let cfgs = [
        TraversalConfig::with_stack(1),
        TraversalConfig::default(),
        TraversalConfig::UNBOUNDED,
    ];
    for k in 0..400 {
        // A camera outside the forest looking at a point inside it; four rays a small
        // angle apart (neighbouring pixels), sometimes less than a leaf apart.
        let (eye, target) = view_into_forest(&mut r, h);
        let spread = if k % 2 == 0 { 1e-3 } else { 2e-2 };
        let base = (target - eye).normalize();
        let rays: [Ray; PACKET] = std::array::from_fn(|l| {
            let jitter = Vec3::new(
                (l % 2) as f32 * spread,
                (l / 2) as f32 * spread,
                0.3 * spread * (l as f32 - 1.5),
            );
            let mut ray = Ray::new(eye, (base + jitter).normalize());
            if k % 5 == 0 {
                ray.t_max = uniform(&mut r, 0.5, 3.0) * h; // segments
            }
            ray
        });
        for (j, cfg) in cfgs.into_iter().enumerate() {
            let st = check(&accel, &rays, 0b1111, cfg);
            restarts[j] += st.restarts;
        }
        for ray in &rays {
            let mut st = TraceStats::default();
            if let Some(hit) = accel.closest_hit(ray, TraversalConfig::default(), &mut st) {
                hits += 1;
                tree_hits += !hit.is_ground() as usize;
            }
        }
    }
    assert!(tree_hits > 400, "{tree_hits} of {hits} hits on trees");
    assert_eq!(restarts[2], 0, "an unbounded stack never restarts");
    assert!(restarts[0] > restarts[1], "{restarts:?}");
}

#[test]
fn incoherent_packets_and_partial_masks_equal_single_rays() {
    let accel = maple_forest();
    let h = accel.instances()[0].world_bounds.max.y;
    let mut r = rng(43);
    for k in 0..600 {
        // Independent rays: mixed direction signs, so packets split into groups (and into
        // single rays where a group cannot be formed).
        let rays: [Ray; PACKET] = std::array::from_fn(|_| {
            let mut ray = random_ray(&mut r, h);
            ray.origin.y += 0.5 * h;
            ray
        });
        let mut mask = (k % 16) as u32;
        if mask == 0 {
            mask = 0b1111;
        }
        check(&accel, &rays, mask, TraversalConfig::default());
    }
    // Axis-aligned and invalid rays in one packet: infinite inverse directions go to the
    // single-ray path, invalid ones hit nothing.
    let eye = Vec3::new(0.0, 0.5 * h, 2.0 * h);
    let rays = [
        Ray::new(eye, Vec3::new(0.0, 0.0, -1.0)),
        Ray::new(eye, Vec3::new(0.0, -0.2, -1.0)),
        Ray::new(eye, Vec3::ZERO),
        Ray::new(eye, Vec3::new(0.01, -0.2, -1.0)),
    ];
    check(&accel, &rays, 0b1111, TraversalConfig::default());
}

#[test]
fn crowded_top_level_leaves_equal_single_rays() {
    // More instances per top-level leaf than are sorted (16), duplicates that tie exactly.
    let accel = crowded_scene();
    let mut r = rng(24);
    let mut hits = 0;
    for _ in 0..300 {
        let eye = unit(&mut r) * 3.5 + Vec3::new(0.0, 1.0, 0.0);
        let target = Vec3::new(
            uniform(&mut r, -0.5, 0.5),
            1.0 + uniform(&mut r, -0.5, 0.5),
            uniform(&mut r, -0.5, 0.5),
        );
        let base = (target - eye).normalize();
        let rays: [Ray; PACKET] = std::array::from_fn(|l| {
            Ray::new(eye, (base + Vec3::splat(0.004 * l as f32)).normalize())
        });
        for cfg in [TraversalConfig::with_stack(2), TraversalConfig::UNBOUNDED] {
            check(&accel, &rays, 0b1111, cfg);
        }
        let mut st = TraceStats::default();
        hits += rays
            .iter()
            .filter(|ray| {
                accel
                    .closest_hit(ray, TraversalConfig::default(), &mut st)
                    .is_some_and(|h| !h.is_ground())
            })
            .count();
    }
    assert!(hits > 300, "{hits}");
}

#[test]
fn occluder_cache_answers_exactly_and_is_used() {
    // Parallel shadow rays from neighbouring points of a forest: the cache holds the last
    // occluders; every answer must equal the uncached query and brute force, and the cache
    // must answer some of them (else it is dead weight).
    let accel = maple_forest();
    let h = accel.instances()[0].world_bounds.max.y;
    let sun = Vec3::new(0.3, 0.8, 0.2).normalize();
    let mut cache = sylva_trace::OccluderCache::new();
    let mut r = rng(47);
    let (mut blocked, mut cache_hits) = (0usize, 0u64);
    let mut base = Vec3::ZERO;
    for k in 0..3000 {
        // Runs of 20 points a few millimetres apart (as neighbouring pixels on one
        // surface), each run starting somewhere new in the forest or on the ground.
        if k % 20 == 0 {
            base = Vec3::new(
                uniform(&mut r, -0.6, 0.6) * h,
                if k % 60 == 0 {
                    1e-3 * h
                } else {
                    uniform(&mut r, 0.1, 0.8) * h
                },
                uniform(&mut r, -0.6, 0.6) * h,
            );
        }
        let p = base
            + Vec3::new(
                (k % 20) as f32 * 2e-4 * h,
                0.0,
                uniform(&mut r, 0.0, 2e-4) * h,
            );
        let ray = Ray::new(p, sun);
        let mut st = TraceStats::default();
        let cached = accel.any_hit_cached(&ray, TraversalConfig::default(), &mut st, &mut cache);
        let mut plain = TraceStats::default();
        let want = accel.any_hit(&ray, TraversalConfig::default(), &mut plain);
        assert_eq!(cached, want, "ray {k} {ray:?}");
        if k % 10 == 0 {
            assert_eq!(
                want,
                accel.brute_any_hit(&ray),
                "ray {k} against brute force"
            );
        }
        assert_eq!(plain.occluder_cache_hits, 0, "a fresh cache starts empty");
        blocked += want as usize;
        cache_hits += st.occluder_cache_hits;
    }
    assert!(blocked > 300 && blocked < 2900, "{blocked} of 3000 blocked");
    assert!(
        cache_hits > 0 && cache_hits <= blocked as u64,
        "{cache_hits} cache hits"
    );
}

#[test]
fn shadow_rays_from_their_own_instance_first_answer_exactly_with_less_work() {
    // Shadow rays from surface points of a forest whose crowns' boxes overlap: entering the
    // instance the ray starts on first must give exactly the answer of the plain query and
    // of brute force, whatever the hint (its own instance, another one, none, an id out of
    // range), and on such a forest it must save work overall.
    let accel = maple_forest();
    let h = accel.instances()[0].world_bounds.max.y;
    let n = accel.instances().len() as u32;
    let sun = Vec3::new(-0.4, 0.7, 0.3).normalize();
    let cfg = TraversalConfig::default();
    let mut r = rng(53);
    let (mut plain_work, mut hinted_work) = (TraceStats::default(), TraceStats::default());
    let (mut rays, mut blocked) = (0usize, 0usize);
    for k in 0..1500 {
        let (eye, target) = view_into_forest(&mut r, h);
        let primary = Ray::new(eye, (target - eye).normalize());
        let mut st = TraceStats::default();
        let Some(hit) = accel.closest_hit(&primary, cfg, &mut st) else {
            continue;
        };
        if hit.is_ground() {
            continue;
        }
        let ng = accel.geometric_normal(&hit);
        let side = if ng.dot(sun) >= 0.0 { 1.0 } else { -1.0 };
        let p = primary.at(hit.t);
        let ray = Ray::new(p + ng * (side * 1e-4 * p.abs().max_element().max(1.0)), sun);
        let want = accel.any_hit(&ray, cfg, &mut plain_work);
        let mut cache = sylva_trace::OccluderCache::new();
        let got = accel.any_hit_from(&ray, Some(hit.instance), cfg, &mut hinted_work, &mut cache);
        assert_eq!(got, want, "ray {k} from instance {}", hit.instance);
        for other in [(hit.instance + 1) % n, n, u32::MAX] {
            let mut st = TraceStats::default();
            let mut cache = sylva_trace::OccluderCache::new();
            let got = accel.any_hit_from(&ray, Some(other), cfg, &mut st, &mut cache);
            assert_eq!(got, want, "ray {k} with hint {other}");
        }
        if k % 10 == 0 {
            assert_eq!(
                want,
                accel.brute_any_hit(&ray),
                "ray {k} against brute force"
            );
        }
        rays += 1;
        blocked += want as usize;
    }
    assert!(rays > 500, "only {rays} rays hit a tree");
    assert!(
        blocked > rays / 10 && blocked < rays,
        "{blocked} of {rays} blocked"
    );
    assert_eq!(plain_work.rays, hinted_work.rays);
    assert!(
        hinted_work.nodes < plain_work.nodes,
        "own instance first: {} node steps, plain: {}",
        hinted_work.nodes,
        plain_work.nodes
    );
}

#[test]
fn batched_queries_equal_single_rays_for_any_batch_length() {
    let accel = maple_forest();
    let h = accel.instances()[0].world_bounds.max.y;
    let tracer = KdTracer::new(accel.clone(), TraversalConfig::default());
    let query: &dyn RayQuery = &tracer;
    assert!(query.preferred_batch() >= PACKET);
    let mut r = rng(53);
    // Batches of neighbouring camera rays, of lengths that leave ragged packets.
    for len in [1usize, 3, 4, 7, 64, 65] {
        let (eye, target) = view_into_forest(&mut r, h);
        let base = (target - eye).normalize();
        let rays: Vec<Ray> = (0..len)
            .map(|i| {
                let d = base + Vec3::new((i % 8) as f32 * 4e-3, (i / 8) as f32 * 4e-3, 0.0);
                Ray::new(eye, d.normalize())
            })
            .collect();
        let mut hits = vec![None; len];
        let mut st = TraceStats::default();
        query.closest_hits(&rays, &mut hits, &mut st);
        assert_eq!(st.rays, len as u64);
        let mut shadows = Vec::new();
        for (ray, hit) in rays.iter().zip(&hits) {
            let mut one = TraceStats::default();
            let want = accel.closest_hit(ray, TraversalConfig::UNBOUNDED, &mut one);
            assert!(same(*hit, want), "{ray:?}: {hit:?} vs {want:?}");
            if let Some(hit) = hit {
                let n = query.geometric_normal(hit);
                assert_eq!(n, accel.geometric_normal(hit));
                let p = ray.at(hit.t) + n * 1e-3;
                let from = (!hit.is_ground()).then_some(hit.instance);
                let dir = Vec3::new(0.3, 1.0, 0.2).normalize();
                shadows.push(ShadowRay {
                    ray: Ray::new(p, dir),
                    from,
                });
            }
        }
        let mut blocked = vec![false; shadows.len()];
        query.any_hits(&shadows, &mut blocked, &mut st);
        for (s, &b) in shadows.iter().zip(&blocked) {
            assert_eq!(b, accel.brute_any_hit(&s.ray), "{s:?}");
        }
    }
    assert_eq!(query.instances().len(), accel.instances().len());
}
