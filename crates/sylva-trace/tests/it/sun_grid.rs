//! The sun-aligned grid (004 §4.1) answers shadow rays exactly as the top-level kd-tree does.

use glam::Vec3;
use sylva_geom::Instance;
use sylva_testkit::scenes::*;
use sylva_trace::{
    KdTracer, OccluderCache, RayQuery, SceneAccel, ShadowRay, SunGrid, SunGridQuery, TraceStats,
    TraversalConfig,
};

/// A spread-out forest of 60 instances of two soups (rotated, scaled, overlapping).
fn forest() -> SceneAccel {
    let models = vec![soup(200, 31), soup(120, 32)];
    let mut r = rng(33);
    let instances: Vec<Instance> = (0..60)
        .map(|k| Instance {
            model: (k % 2) as u32,
            position: Vec3::new(
                uniform(&mut r, -8.0, 8.0),
                1.0 + uniform(&mut r, 0.0, 0.5),
                uniform(&mut r, -8.0, 8.0),
            ),
            rotation_deg: uniform(&mut r, 0.0, 360.0),
            scale: uniform(&mut r, 0.5, 1.5),
        })
        .collect();
    SceneAccel::from_parts(&models, &instances, Some([10.0, 10.0])).unwrap()
}

#[test]
fn shadow_rays_through_the_grid_equal_the_kd_tree_and_brute_force() {
    for (name, accel, spread) in [("forest", forest(), 9.0), ("crowded", crowded_scene(), 1.5)] {
        let mut r = rng(41);
        let mut blocked = 0;
        for s in 0..6 {
            // Suns from low to high, any azimuth (one straight up).
            let to_sun = if s == 0 {
                Vec3::Y
            } else {
                let e = uniform(&mut r, 0.1, 1.4);
                let a = uniform(&mut r, 0.0, std::f32::consts::TAU);
                Vec3::new(e.cos() * a.cos(), e.sin(), e.cos() * a.sin())
            };
            let grid = SunGrid::build(&accel, to_sun);
            let (nu, nv) = grid.tiles();
            assert!(nu >= 1 && nv >= 1 && nu <= 1024 && nv <= 1024);
            for k in 0..600 {
                let o = Vec3::new(
                    uniform(&mut r, -spread, spread),
                    uniform(&mut r, 0.0, 2.5),
                    uniform(&mut r, -spread, spread),
                );
                let mut ray = sylva_trace::Ray::new(o, to_sun);
                if k % 5 == 0 {
                    ray.t_max = uniform(&mut r, 0.1, 3.0);
                }
                let from = (k % 3 == 0).then_some((k % 60) as u32 % accel.instances().len() as u32);
                for cfg in [TraversalConfig::default(), TraversalConfig::UNBOUNDED] {
                    let mut st = TraceStats::default();
                    let want = accel.brute_any_hit(&ray);
                    let kd =
                        accel.any_hit_from(&ray, from, cfg, &mut st, &mut OccluderCache::new());
                    let g =
                        grid.any_hit(&accel, &ray, from, cfg, &mut st, &mut OccluderCache::new());
                    assert_eq!(kd, want, "{name} sun {s} ray {k}");
                    assert_eq!(g, want, "{name} sun {s} ray {k}");
                    blocked += g as usize;
                }
            }
        }
        assert!(
            blocked > 300,
            "{name}: {blocked} blocked rays: the test must see shadows"
        );
    }
}

#[test]
fn the_grid_query_answers_batches_like_the_kd_tracer() {
    let accel = forest();
    let to_sun = Vec3::new(0.4, 0.8, -0.3).normalize();
    let grid = SunGrid::build(&accel, to_sun);
    let kd = KdTracer::new(accel, TraversalConfig::default());
    let query = SunGridQuery::new(&kd, &grid);
    assert_eq!(query.preferred_batch(), kd.preferred_batch());
    let mut r = rng(51);
    // Mostly rays towards the sun, some in other directions (the kd path answers those).
    let rays: Vec<ShadowRay> = (0..2000)
        .map(|k| {
            let o = Vec3::new(
                uniform(&mut r, -9.0, 9.0),
                uniform(&mut r, 0.0, 2.5),
                uniform(&mut r, -9.0, 9.0),
            );
            let dir = if k % 7 == 0 { unit(&mut r) } else { to_sun };
            ShadowRay {
                ray: sylva_trace::Ray::new(o, dir),
                from: None,
            }
        })
        .collect();
    let (mut a, mut b) = (vec![false; rays.len()], vec![false; rays.len()]);
    let (mut sa, mut sb) = (TraceStats::default(), TraceStats::default());
    kd.any_hits(&rays, &mut a, &mut sa);
    query.any_hits(&rays, &mut b, &mut sb);
    assert_eq!(a, b);
    assert!(a.iter().filter(|&&x| x).count() > 100);
    assert_eq!(sa.rays, sb.rays);
    // A grid for no usable direction serves no ray, and answers through the kd path.
    let none = SunGrid::build(&kd.accel, Vec3::ZERO);
    assert!(!none.serves(to_sun));
    assert!(grid.serves(to_sun * 3.0) && !grid.serves(-to_sun));
    let q = SunGridQuery::new(&kd, &none);
    let mut c = vec![false; rays.len()];
    q.any_hits(&rays, &mut c, &mut TraceStats::default());
    assert_eq!(a, c);
}
