//! The physical light relit (issue 27, docs/relight.md): at a sun part's direction (a lattice
//! one or one on the rings between) the relit light is the light solved for that sun (the
//! forest grid's weights and whole frames, final gather included), moving the sun solves
//! nothing, and the sun's parts interpolate between their directions.

use std::sync::atomic::Ordering;

use glam::Vec3;
use sylva_core::Sun;
use sylva_lb::lattice::unit;
use sylva_lb::light::Environment;
use sylva_lb::{CpuSolver, LbSolver};
use sylva_light::forest::{ForestBases, ForestLight};
use sylva_light::lighting::{physical_environment, PartWeights};
use sylva_light::relight::physical::{
    sun_directions, sun_part_weights, LATTICE_SUN_DIRECTIONS, SUN_PARTS,
};
use sylva_light::relight::{
    GlobalGridOptions, PhysicalBasis, PhysicalTarget, StoredPhysicalBasis, SunWeights,
};
use sylva_light::{Light, Silent};
use sylva_pipeline::bench::{relight_physical, DirectSolve, RelightBenchPlan};
use sylva_pipeline::{
    load_scene, scene_illumination, scene_to_sun, BasisUse, LbPlan, PrepareOptions, PreparedScene,
    RelightPlan, ShadowMethod,
};

use crate::forest::{instances, shade_parts};
use crate::relight::Counting;

const GRID: usize = 24;
const FOREST: GlobalGridOptions = GlobalGridOptions { sites: 32 };

/// The lattice direction `c` as a sun (towards it).
fn lattice_sun(c: [i32; 3]) -> Vec3 {
    let k = LATTICE_SUN_DIRECTIONS
        .iter()
        .copied()
        .find(|&k| sylva_lb::lattice::C[k] == c)
        .expect("a sun direction");
    let d = unit(k);
    -Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32)
}

fn close(a: Vec3, b: Vec3, scale: f32) -> bool {
    (a - b).abs().max_element() <= 2e-4 * scale.max(1e-3)
}

fn weights_close(a: &PartWeights, b: &PartWeights) -> bool {
    let scale = [a.sun, a.sky_top, a.sky, a.ground]
        .iter()
        .map(|v| v.max_element())
        .fold(0.0f32, f32::max);
    close(a.sun, b.sun, scale)
        && close(a.sky_top, b.sky_top, scale)
        && close(a.sky, b.sky, scale)
        && close(a.ground, b.ground, scale)
}

#[test]
fn sun_parts_are_the_face_of_a_sun_above_the_horizon() {
    assert_eq!(sun_directions().len(), SUN_PARTS);
    for elevation in [0.5f64, 10.0, 35.0, 60.0, 89.0] {
        for azimuth in [0.0f64, 20.0, 45.0, 133.0, 271.0] {
            let sun = Sun::from_angles(elevation, azimuth).unwrap().to_sun();
            let w = sun_part_weights([-sun.x, -sun.y, -sun.z]).unwrap();
            let total: f64 = w.iter().map(|x| x.1).sum();
            assert!((total - 1.0).abs() < 1e-9, "{elevation} {azimuth}: {w:?}");
            assert!(w.len() <= 3 && w.iter().all(|&(p, x)| p < SUN_PARTS && x > 0.0));
        }
    }
    // A part's direction (a lattice one, one on a ring) is its own part; below the horizon
    // there is none.
    let w = sun_part_weights([1.0, -1.0, 0.0]).unwrap();
    assert_eq!(w.len(), 1, "{w:?}");
    let w = sun_part_weights(sun_directions()[20]).unwrap();
    assert_eq!(w, vec![(20, 1.0)]);
    assert!(sun_part_weights([0.3, 0.5, 0.1]).unwrap().is_empty());
}

#[test]
fn the_forest_relit_at_a_part_direction_is_the_forest_solved_for_it() {
    let (scene, fine) = shade_parts();
    let insts = instances(&scene, &fine, &[0, 1, 2]);
    let base = physical_environment(&scene_illumination(&scene)).unwrap();
    let bases =
        ForestBases::solve(&insts, base.ground_albedo, 0.0, &FOREST, &mut |_, _| {}).unwrap();
    let ring = |k: usize| -Vec3::from_array(sun_directions()[k].map(|c| c as f32));
    let suns = [
        lattice_sun([0, -1, 0]),
        lattice_sun([-1, -1, 0]),
        lattice_sun([0, -1, 1]),
        lattice_sun([1, 0, 0]),
        ring(14),
        ring(23),
    ];
    for (c, to_sun) in suns.into_iter().enumerate() {
        let env = Environment {
            sun_travel: (-to_sun).as_dvec3().to_array(),
            ..base
        };
        let solved = ForestLight::solve(&insts, &env, 0.0, &FOREST, &mut |_, _| {}).unwrap();
        let relit = bases.light(&env).unwrap();
        assert_eq!(solved.dims, relit.dims);
        for (i, (a, b)) in solved.weights.iter().zip(&relit.weights).enumerate() {
            assert!(
                weights_close(a, b),
                "{c:?} instance {i}: solved {a:?} relit {b:?}"
            );
        }
    }
    // Between lattice directions the weights lie within what the face's corners give.
    let env = Environment {
        sun_travel: [-0.5, -0.8, -0.3],
        ..base
    };
    let relit = bases.light(&env).unwrap();
    for w in &relit.weights {
        assert!(
            w.sun.min_element() >= 0.0 && w.sun.max_element() <= 1.0 + 1e-4,
            "{w:?}"
        );
    }
    // A ground other than the one solved with is refused.
    let other = Environment {
        ground_albedo: Some([0.5; 3]),
        ..env
    };
    assert!(bases.light(&other).is_err());
}

/// `scene` lit by the physical light: relit from its uncompressed bases, or solved for its
/// sun.
fn prepare(scene: &sylva_geom::Scene, solver: &dyn LbSolver, relight: bool) -> PreparedScene {
    let plan = RelightPlan {
        basis: BasisUse::Always,
        physical: None,
        ..RelightPlan::default()
    };
    prepare_with(scene, solver, relight.then_some(plan), None).unwrap()
}

fn prepare_with(
    scene: &sylva_geom::Scene,
    solver: &dyn LbSolver,
    relight: Option<RelightPlan>,
    cache_dir: Option<&std::path::Path>,
) -> Result<PreparedScene, sylva_pipeline::PipelineError> {
    PreparedScene::new(
        scene.clone(),
        &PrepareOptions {
            lb: Some(LbPlan {
                solver,
                grid: Some(GRID),
                cache_dir,
                light: Light::Physical,
            }),
            light: Light::Physical,
            forest: Some(FOREST),
            gather_rays: 2,
            relight,
            largest_frame: Some((40, 30, 1)),
            ..PrepareOptions::default()
        },
        &Silent,
    )
}

/// Sum of every pixel's light, and the largest difference between two frames' pixels.
fn compare(a: &sylva_render::Frame, b: &sylva_render::Frame) -> (f32, f32) {
    let total = |r: &sylva_render::Radiance| r.local + r.indirect + r.sky;
    let peak = a
        .pixels
        .iter()
        .map(|p| total(p).max_element())
        .fold(0.0f32, f32::max);
    let worst = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(p, q)| (total(p) - total(q)).abs().max_element())
        .fold(0.0f32, f32::max);
    (peak, worst)
}

#[test]
fn relit_at_a_part_direction_the_frame_is_the_solved_one_and_moving_the_sun_solves_nothing() {
    let mut scene = load_scene("shade", None).unwrap();
    // The per-sun light solves each model for the world's sun; the relit light turns it into
    // each instance's frame. Unrotated instances see the same sun in both.
    for i in &mut scene.instances {
        i.rotation_deg = 0.0;
    }
    let to_sun = lattice_sun([-1, -1, 0]);
    scene.sun = Sun::from_direction(to_sun.x as f64, to_sun.y as f64, to_sun.z as f64).unwrap();
    let solved = prepare(&scene, &CpuSolver, false);
    let counting = Counting::default();
    let mut relit = prepare(&scene, &counting, true);
    assert!(relit.physical.is_some() && solved.physical.is_none());
    let solves = counting.0.load(Ordering::SeqCst);
    // 25 sun parts and 3 diffuse ones per model (their colours in one solve each).
    assert_eq!(solves, 2 * 28);

    let frame = |p: &PreparedScene| {
        let camera = p.camera(40, 30);
        p.render(&p.settings(camera, 1, 7), &Silent).unwrap()
    };
    let (a, b) = (frame(&solved), frame(&relit));
    let (peak, worst) = compare(&a, &b);
    assert!(peak > 0.0);
    assert!(
        worst <= 1e-3 * peak,
        "relit differs by {worst} (peak {peak})"
    );
    // The plants' LB light took part: it is not all direct sunlight.
    let indirect: f32 = b.pixels.iter().map(|p| p.indirect.max_element()).sum();
    assert!(indirect > 0.0);

    // The sun moves: no solve, and the light follows it (lower sun, less light).
    for (elevation, azimuth) in [(35.0, 20.0), (15.0, 200.0), (60.0, 90.0)] {
        let s = Sun::from_angles(elevation, azimuth).unwrap().to_sun();
        relit
            .set_sun(Vec3::new(s.x as f32, s.y as f32, s.z as f32))
            .unwrap();
        let f = frame(&relit);
        assert!(f.pixels.iter().all(|p| (p.local + p.indirect).is_finite()));
    }
    assert_eq!(
        counting.0.load(Ordering::SeqCst),
        solves,
        "moving the sun solved"
    );
    // Back at the lattice sun: the first frame again.
    relit.set_sun(to_sun).unwrap();
    let (_, again) = compare(&b, &frame(&relit));
    assert!(again <= 1e-6 * peak, "{again}");
    // At a part's direction on the low ring (22.5° up, no lattice direction) the relit frame
    // is the light solved for that sun too.
    let ring = -Vec3::from_array(sun_directions()[15].map(|c| c as f32));
    scene.sun = Sun::from_direction(ring.x as f64, ring.y as f64, ring.z as f64).unwrap();
    let solved = prepare(&scene, &CpuSolver, false);
    relit.set_sun(ring).unwrap();
    let (a, b) = (frame(&solved), frame(&relit));
    let (peak, worst) = compare(&a, &b);
    assert!(peak > 0.0);
    assert!(
        worst <= 1e-3 * peak,
        "relit on the ring differs by {worst} (peak {peak})"
    );
    assert_eq!(counting.0.load(Ordering::SeqCst), solves);
    // Below the horizon: refused, not lit from below.
    assert!(relit.set_sun(Vec3::new(0.3, -0.5, 0.1)).is_err());
}

/// A frame that reads the relit light at least once per 8 sites of its grids decodes the sun's light once ([`PreparedScene::bake_summary`]): from the parts it is the same frame
/// bit for bit, from compressed ones the same within the codec's error; a small frame, or a
/// budget of 0, decodes nothing.
#[test]
fn the_relit_light_decoded_for_a_sun_renders_the_same_frame() {
    let scene = load_scene("shade", None).unwrap();
    let mut relit = prepare(&scene, &CpuSolver, true);
    let frame = |p: &PreparedScene, (w, h): (u32, u32), rpp: u32| {
        let camera = p.camera(w, h);
        p.render(&p.settings(camera, rpp, 7), &Silent).unwrap()
    };
    let (first, second) = (
        Sun::from_angles(35.0, 20.0).unwrap().to_sun(),
        Sun::from_angles(50.0, 120.0).unwrap().to_sun(),
    );
    let (first, second) = (
        Vec3::new(first.x as f32, first.y as f32, first.z as f32),
        Vec3::new(second.x as f32, second.y as f32, second.z as f32),
    );
    relit.set_sun(first).unwrap();
    // 10 × 8 pixels at 1 sample and 2 gather rays: 240 lookups, not an eighth of a grid.
    frame(&relit, (10, 8), 1);
    assert_eq!(relit.bake_summary(), None);
    relit.set_bake_budget(0);
    relit.set_sun(second).unwrap();
    relit.set_sun(first).unwrap();
    let parts = frame(&relit, (40, 30), 16);
    assert_eq!(relit.bake_summary(), None, "a budget of 0 decodes nothing");
    relit.set_bake_budget(sylva_pipeline::DEFAULT_BAKE_BUDGET);
    relit.set_sun(second).unwrap();
    relit.set_sun(first).unwrap();
    let baked = frame(&relit, (40, 30), 16);
    let summary = relit.bake_summary().expect("decoded for a large frame");
    let with_basis = relit.scene.instances.len();
    assert_eq!((summary.instances, summary.of), (with_basis, with_basis));
    // A grid per instance's plants and per instance's ground at most (the forest grid weighs
    // each instance's plants; its ground reads its model's light alone).
    assert!(summary.grids >= 1 && summary.grids <= 2 * with_basis && summary.bytes > 0);
    let same = parts.pixels.iter().zip(&baked.pixels).all(|(a, b)| a == b);
    assert!(same, "decoded light changed the frame");
    let (peak, _) = compare(&parts, &baked);
    assert!(peak > 0.0);
}

#[test]
fn the_physical_light_takes_no_exact_weights_and_no_ambient() {
    let scene = load_scene("shade", None).unwrap();
    for plan in [
        RelightPlan {
            sun: SunWeights::Exact,
            ..RelightPlan::default()
        },
        RelightPlan {
            ambient: 0.3,
            ..RelightPlan::default()
        },
    ] {
        let err = PreparedScene::new(
            scene.clone(),
            &PrepareOptions {
                lb: Some(LbPlan {
                    solver: &CpuSolver,
                    grid: Some(GRID),
                    cache_dir: None,
                    light: Light::Physical,
                }),
                relight: Some(plan),
                ..PrepareOptions::default()
            },
            &Silent,
        )
        .err()
        .expect("refused");
        assert!(err.to_string().contains("paper light"), "{err}");
    }
}

#[test]
fn the_bench_against_direct_solves_is_exact_at_part_suns_and_not_between() {
    let mut scene = load_scene("shade", None).unwrap();
    for i in &mut scene.instances {
        i.rotation_deg = 0.0;
    }
    // Azimuth 0: the path's ends (45° either side of the zenith) and its middle (the zenith)
    // are lattice directions, the two suns between them (67.5° at azimuths 0 and 180) are no
    // part's (the high ring's lie at the diagonal azimuths).
    scene.sun = Sun::from_angles(50.0, 0.0).unwrap();
    let mut relit = prepare(&scene, &CpuSolver, true);
    let plan = RelightBenchPlan {
        suns: 5,
        runs: 1,
        shadows: ShadowMethod::KdTree,
        size: (40, 30),
        seed: 7,
        against_direct: true,
    };
    // The direct solves need the LB plan; asked without it, the bench says so.
    assert!(relight_physical(&mut relit, plan, None, &|| {}).is_err());
    let direct = DirectSolve {
        lb: LbPlan {
            solver: &CpuSolver,
            grid: Some(GRID),
            cache_dir: None,
            light: Light::Physical,
        },
        forest: Some(FOREST),
    };
    let report = relight_physical(&mut relit, plan, Some(&direct), &|| {}).unwrap();
    let a = report.against_direct.as_ref().expect("measured");
    assert_eq!(report.rmse_vs_direct, Some(a.image_rmse));
    assert_eq!(a.per_sun.len(), 5);
    assert!(a.plant_pixels > 0);
    let lattice: Vec<bool> = a.per_sun.iter().map(|s| s.on_part).collect();
    assert_eq!(lattice, [true, false, true, false, true], "{a:#?}");
    let exact = a.per_sun.iter().filter(|s| s.on_part);
    let noise = exact.fold(0.0f64, |m, s| m.max(s.image_rmse).max(s.plant_rel_rmse));
    // Measured: about 5e-9 (f32 rounding of the same light summed in another order).
    assert!(noise < 1e-6, "at lattice suns: {a:#?}");
    for s in a.per_sun.iter().filter(|s| !s.on_part) {
        assert!(
            s.plant_rel_rmse > 1e-3 && s.image_rmse > 1e3 * noise,
            "between lattice suns the parts are interpolated: {s:?}"
        );
        assert!((s.plant_ratio - 1.0).abs() < 0.2, "{s:?}");
    }
    // The largest errors are the interpolated suns', and the overall figures pool them.
    assert!(a.largest.len() == 3 && !a.per_sun[a.largest[0]].on_part);
    assert!(a.image_rmse > 0.0 && a.plant_rel_rmse > 0.0);
    // The bench left the scene's own sun in place.
    assert!((relit.to_sun - scene_to_sun(&scene)).length() < 1e-6);
}

#[test]
fn the_compressed_physical_light_is_cached_and_relit_close_to_the_parts() {
    let scene = load_scene("shade", None).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let plan = RelightPlan {
        basis: BasisUse::Always,
        keep_raw: true,
        ..RelightPlan::default()
    };
    assert_eq!(plan.physical, Some(PhysicalTarget::recommended()));
    let counting = Counting::default();
    let mut first = prepare_with(&scene, &counting, Some(plan), Some(dir.path())).unwrap();
    assert_eq!(counting.0.load(Ordering::SeqCst), 2 * 28);
    let frame = |p: &PreparedScene| {
        let camera = p.camera(40, 30);
        p.render(&p.settings(camera, 1, 7), &Silent).unwrap()
    };
    let p = first.physical.as_ref().unwrap();
    let (mut compressed, mut raw) = (0, 0);
    for m in 0..2 {
        match p.model(m) {
            Some(StoredPhysicalBasis::Compressed(c)) => compressed += c.bytes(),
            other => panic!("model {m}: {other:?}"),
        }
        raw += PhysicalBasis::memory_needed(p.model(m).unwrap().dims());
    }
    assert!(compressed < raw / 2, "{compressed} of {raw} bytes");
    assert_eq!(first.physical_raw_bytes, raw);
    // Relit from the compressed parts, the frame is the parts' within the codec's error. A
    // frame this small reads blocks decoded on first use, not every site decoded.
    let small = frame(&first);
    assert_eq!(first.bake_summary(), None);
    let blocks = first.physical.as_ref().unwrap().blocks_decoded();
    assert!(blocks > 0, "no block read");
    first.use_uncompressed(true).unwrap();
    let full = frame(&first);
    first.use_uncompressed(false).unwrap();
    let (peak, worst) = compare(&full, &small);
    assert!(worst > 0.0 && worst <= 0.03 * peak, "{worst} of {peak}");
    // One entry per model holds the compressed basis: a second preparation reads it and
    // solves nothing, not even its parts, and relights the same.
    let entries = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension() == Some("spbasis".as_ref()))
        .count();
    assert_eq!(entries, 2);
    let lookup = RelightPlan {
        basis: BasisUse::IfCached,
        ..RelightPlan::default()
    };
    let counting = Counting::default();
    let second = prepare_with(&scene, &counting, Some(lookup), Some(dir.path())).unwrap();
    assert_eq!(counting.0.load(Ordering::SeqCst), 0);
    assert!(!second.has_uncompressed());
    let (_, again) = compare(&small, &frame(&second));
    assert_eq!(again, 0.0);
    // Another codec is another entry: cached bases only, so none.
    let other = RelightPlan {
        physical: PhysicalTarget::parse("haar:0.01", sylva_lb::relight::Precision::F16).unwrap(),
        ..lookup
    };
    let third = prepare_with(&scene, &counting, Some(other), Some(dir.path())).unwrap();
    // Its parts are cached (the first preparation stored them), so it is made from them.
    assert!(third.physical.is_some());
    assert_eq!(counting.0.load(Ordering::SeqCst), 0);
}

/// The forest grid's parts are cached: read back, they relight the forest bit for bit as
/// solved; what the root sends makes the same; a damaged entry is solved again.
#[test]
fn the_forest_grid_parts_are_cached_and_relight_as_solved() {
    use sylva_light::forest::ForestCache;
    use sylva_light::lighting::LightingSource;

    let (scene, fine) = shade_parts();
    let insts = instances(&scene, &fine, &[0, 1, 2]);
    let base = physical_environment(&scene_illumination(&scene)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cache = ForestCache::new(dir.path(), "shade");
    let at = Some(&cache);
    let cached = || {
        ForestBases::solve_cached(&insts, base.ground_albedo, 0.0, &FOREST, at, &mut |_, _| {})
            .unwrap()
    };
    let (solved, r) = cached();
    assert_eq!(r.source, LightingSource::Computed);
    let path = r.path.expect("an entry");
    let (read, r) = cached();
    assert_eq!(r.source, LightingSource::Cached);
    let sent = ForestBases::with_parts(
        &insts,
        base.ground_albedo,
        0.0,
        &FOREST,
        &solved.parts_bytes(),
    )
    .unwrap();
    let env = Environment {
        sun_travel: [-0.5, -0.8, -0.3],
        ..base
    };
    let want = solved.light(&env).unwrap();
    assert_eq!(read.light(&env).unwrap(), want);
    assert_eq!(sent.light(&env).unwrap(), want);
    // Another ground is another entry (its floors differ).
    let (_, r) = ForestBases::solve_cached(&insts, None, 0.0, &FOREST, at, &mut |_, _| {}).unwrap();
    assert_eq!(r.source, LightingSource::Computed);
    assert_ne!(r.path.as_ref(), Some(&path));
    // Parts for another forest are refused.
    assert!(ForestBases::with_parts(
        &insts[..2],
        base.ground_albedo,
        0.0,
        &FOREST,
        &solved.parts_bytes()
    )
    .is_err());
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..100]).unwrap();
    let (again, r) = cached();
    assert!(
        matches!(&r.source, LightingSource::Recomputed { reason } if reason.contains(&path.display().to_string())),
        "{:?}",
        r.source
    );
    assert_eq!(again.light(&env).unwrap(), want);
}
