//! Relighting in the renderer (paper 004): relit light against direct solves, rotation
//! invariance, no LB solve when only the sun moves, the basis and global caches, and the
//! coarse global grid (≈ 1 around a lone tree, less in a neighbour's shade).

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use glam::{Affine3A, Quat, Vec3};
use sylva_geom::{Model, Scene};
use sylva_lb::relight::{BasisWeights, CompressTarget};
use sylva_lb::solver::{solve_lighting, Boundary, SolveOptions, SolveReport};
use sylva_lb::{
    CpuSolver, DensityGrid, LbBenchmark, LbSolver, LbSolverError, LightingGrid, MediumParams,
    OnSchedule, Schedule,
};
use sylva_light::lighting::LightingSource;
use sylva_light::relight::{
    model_basis, BasisCacheOptions, BasisReport, GlobalGridOptions, GlobalInstance, GlobalLight,
    GlobalReport, RelitIllumination, RelitLight, StoredBasis, SunWeights,
};
use sylva_light::{Light, Progress, Silent};
use sylva_pipeline::{
    load_scene, BasisUse, LbPlan, PipelineError, PrepareOptions, PreparedScene, RelightPlan,
};
use sylva_render::Frame;

const GRID: usize = 16;
/// A small coarse grid keeps the tests quick (the rose is 2 m across).
const GLOBAL: GlobalGridOptions = GlobalGridOptions { sites: 24 };

fn roses(rotation: f32, sun: Vec3, camera: (Vec3, Vec3)) -> String {
    format!(
        r#"
name = "roses"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]
rotation = {rotation}

[ground]
size = [400.0, 400.0]

[sun]
direction = [{}, {}, {}]

[camera]
position = [{}, {}, {}]
look_at = [{}, {}, {}]
fov = 40.0
resolution = [48, 36]

[lb]
grid = {GRID}
"#,
        sun.x, sun.y, sun.z, camera.0.x, camera.0.y, camera.0.z, camera.1.x, camera.1.y, camera.1.z
    )
}

fn scene_from(dir: &Path, name: &str, toml: &str) -> Scene {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, toml).unwrap();
    load_scene(path.to_str().unwrap(), None).unwrap()
}

/// The LB solver, counting its solves.
#[derive(Default)]
pub(crate) struct Counting(pub(crate) AtomicUsize);

impl LbSolver for Counting {
    fn solve_lighting_rgb(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundaries: &[Boundary; 3],
        floor: Option<&sylva_lb::Floor>,
        source: Option<&sylva_lb::VolumeSource>,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), LbSolverError> {
        self.0.fetch_add(1, Ordering::SeqCst);
        CpuSolver.solve_lighting_rgb(grid, medium, boundaries, floor, source, opts, progress)
    }
    fn benchmark(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundary: Boundary,
        steps: usize,
        repeats: usize,
        progress: &mut dyn FnMut(usize),
    ) -> Result<LbBenchmark, LbSolverError> {
        CpuSolver.benchmark(grid, medium, boundary, steps, repeats, progress)
    }
    fn device(&self) -> &'static str {
        "cpu"
    }
    fn describe(&self) -> String {
        "counting CPU".into()
    }
    fn cache_tag(&self) -> String {
        "cpu".into()
    }
    fn schedule(&self) -> sylva_lb::Schedule {
        CpuSolver.schedule()
    }
}

/// What the pipeline reported about bases and the global grid.
#[derive(Default)]
struct Log(Mutex<Vec<String>>);

fn source_name(s: &LightingSource) -> String {
    match s {
        LightingSource::Cached => "cached".into(),
        LightingSource::Computed => "computed".into(),
        LightingSource::Recomputed { reason } => format!("recomputed: {reason}"),
    }
}

impl Progress for Log {
    fn model_basis(&self, model: &Model, r: &BasisReport) {
        self.0
            .lock()
            .unwrap()
            .push(format!("basis {} {}", model.name, source_name(&r.source)));
    }
    fn global_grid(&self, r: &GlobalReport) {
        self.0
            .lock()
            .unwrap()
            .push(format!("global {}", source_name(&r.source)));
    }
}

fn plan(basis: BasisUse, sun: SunWeights, global: bool, keep_raw: bool) -> RelightPlan {
    RelightPlan {
        basis,
        sun,
        ambient: 0.0,
        global: global.then_some(GLOBAL),
        target: CompressTarget::recommended(),
        physical: None,
        keep_raw,
    }
}

fn prepare(
    scene: Scene,
    solver: &dyn LbSolver,
    cache: Option<&Path>,
    relight: Option<RelightPlan>,
    progress: &dyn Progress,
) -> Result<PreparedScene, PipelineError> {
    // Relighting is the paper light's (its bases are 004's sun-only boundary solves).
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver,
            grid: None,
            cache_dir: cache,
            light: Light::Paper,
        }),
        light: Light::Paper,
        relight,
        largest_frame: Some((48, 36, 1)),
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, progress)
}

fn frame(p: &PreparedScene) -> Frame {
    let camera = p.camera(48, 36);
    p.render(&p.settings(camera, 1, 1), &Silent).unwrap()
}

#[test]
fn exact_relit_light_equals_a_direct_solve_for_every_instance() {
    let dir = tempfile::tempdir().unwrap();
    let sun = Vec3::new(0.35, 0.8, -0.25);
    let mut toml = roses(0.0, sun, (Vec3::new(0.0, 2.0, -5.0), Vec3::Y * 0.5));
    toml = toml.replace(
        "[ground]",
        "[[instances]]\nmodel = \"rose\"\nposition = [2.0, 0.0, 1.0]\nrotation = 130.0\nscale = 1.3\n\n[ground]",
    );
    let scene = scene_from(dir.path(), "two", &toml);
    let model = scene.models[0].clone();
    // Plain steps are linear in the boundary, so the relit light is the direct solve's
    // exactly; an extrapolated solve is not linear (its step factor is measured).
    let mut p = prepare(
        scene,
        &OnSchedule::new(Box::new(CpuSolver), Schedule::Papers),
        None,
        Some(plan(BasisUse::Always, SunWeights::Exact, false, true)),
        &Silent,
    )
    .unwrap();
    p.use_uncompressed(true).unwrap();
    let relit = p.relit.as_ref().unwrap();
    let density = sylva_light::relight::basis_density(&model, GRID).unwrap();
    let medium = sylva_lb::Preset::Leaf.params();
    let opts = SolveOptions::papers(density.dims);
    let placement = sylva_lb::relight::Placement::new(density.dims, density.bounds);
    for (i, inst) in p.tracer.cpu().accel.instances().iter().enumerate() {
        // A direct solve for the sun as this instance's model space sees it.
        let travel = inst.to_model.transform_vector3(-p.to_sun).normalize();
        let t = [travel.x as f64, travel.y as f64, travel.z as f64];
        let (direct, _) = solve_lighting(
            &density,
            &medium,
            Boundary::sun(t, 1.0),
            &opts,
            &mut |_, _, _| {},
        )
        .unwrap();
        let norm: f64 = Boundary::sun(t, 1.0).values.iter().map(|&v| v as f64).sum();
        let d = density.dims;
        let mut worst = 0.0f32;
        for s in 0..d.sites() {
            let (x, y, z) = d.coords(s);
            let pm = Vec3::from_array(placement.model_point([x as f32, y as f32, z as f32]));
            let got = relit.sample_instance(i, pm).unwrap();
            for c in 0..3 {
                let want = (direct.colours[c][s] as f64 / norm) as f32;
                let err = (got[c] - want).abs() / want.abs().max(1e-3);
                worst = worst.max(err);
            }
        }
        assert!(worst < 1e-5, "instance {i}: relative error {worst}");
    }
}

/// Everything rotated by `deg` about +y: the instance, the sun and the camera.
fn rotated_roses(dir: &Path, deg: f32) -> Scene {
    let q = Quat::from_rotation_y(deg.to_radians());
    let sun = Vec3::new(0.5, 0.7, -0.3);
    let cam = (Vec3::new(1.0, 1.6, -4.0), Vec3::new(0.0, 0.6, 0.0));
    scene_from(
        dir,
        &format!("rot{deg}"),
        &roses(deg, q * sun, (q * cam.0, q * cam.1)),
    )
}

/// Fraction of pixels whose full radiance differs by more than 1e-3 (relative, floor 0.05),
/// and the mean absolute difference of the indirect part over its mean.
fn difference(a: &Frame, b: &Frame) -> (f64, f64) {
    let mut off = 0usize;
    let (mut d, mut m) = (0.0f64, 0.0f64);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        let (x, y) = (p.local + p.indirect + p.sky, q.local + q.indirect + q.sky);
        if (x - y).abs().max_element() > 1e-3 * x.max_element().max(y.max_element()).max(0.05) {
            off += 1;
        }
        d += (p.indirect - q.indirect).abs().element_sum() as f64;
        m += p.indirect.element_sum() as f64;
    }
    (off as f64 / a.pixels.len() as f64, d / m.max(1e-12))
}

#[test]
fn a_rotated_model_under_a_rotated_sun_renders_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    for mode in [SunWeights::Exact, SunWeights::ThreeBasis] {
        let render = |deg: f32, relight: bool| {
            let r = relight.then(|| plan(BasisUse::Always, mode, false, false));
            frame(
                &prepare(
                    rotated_roses(dir.path(), deg),
                    &CpuSolver,
                    Some(&cache),
                    r,
                    &Silent,
                )
                .unwrap(),
            )
        };
        let base = render(0.0, true);
        for deg in [90.0, 37.0] {
            // The model-space sun is the same, so are the weights and the face: equal up to
            // the rounding of the rotated geometry (a few silhouette pixels).
            let (off, indirect) = difference(&base, &render(deg, true));
            assert!(off < 0.02, "{mode:?} {deg}°: {off} of pixels differ");
            assert!(
                indirect < 2e-3,
                "{mode:?} {deg}°: indirect differs by {indirect}"
            );
            // The per-sun light of paper 000 (solved once per model, the world's sun taken as
            // the model's) turns with the model: the test tells the two apart.
            if mode == SunWeights::Exact {
                let (_, stat) = difference(&render(0.0, false), &render(deg, false));
                assert!(
                    stat > 10.0 * indirect.max(1e-4),
                    "{deg}°: per-sun light differs by {stat}, relit by {indirect}"
                );
            }
        }
    }
}

#[test]
fn only_moving_the_sun_solves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let scene = || rotated_roses(dir.path(), 20.0);
    // First: every basis solved (one call per base solution: three colours each), cached;
    // the global grid solved and cached.
    let first = Counting::default();
    let log = Log::default();
    let relit_plan = plan(BasisUse::Always, SunWeights::ThreeBasis, true, false);
    prepare(scene(), &first, Some(&cache), Some(relit_plan), &log).unwrap();
    assert_eq!(first.0.load(Ordering::SeqCst), 18);
    assert_eq!(
        *log.0.lock().unwrap(),
        ["basis rose computed", "global computed"]
    );

    // Then from the cache: no solve, not even as the sun moves through a day.
    let again = Counting::default();
    let log = Log::default();
    let cached_plan = RelightPlan {
        basis: BasisUse::IfCached,
        ..relit_plan
    };
    let mut p = prepare(scene(), &again, Some(&cache), Some(cached_plan), &log).unwrap();
    assert_eq!(
        *log.0.lock().unwrap(),
        ["basis rose cached", "global cached"]
    );
    assert_eq!(p.lb_models_cached, 1);
    let mut means = Vec::new();
    for sun in sylva_light::relight::sun_path(5, 30.0) {
        p.set_sun(sun).unwrap();
        means.push(sylva_render::mean_luminance(
            &frame(&p).compose(sylva_render::Mode::Lb),
        ));
    }
    assert_eq!(again.0.load(Ordering::SeqCst), 0, "no LB solve");
    // The light did change with the sun.
    assert!(
        means.windows(2).any(|w| (w[0] - w[1]).abs() > 1e-4),
        "{means:?}"
    );
    for sun in [Vec3::ZERO, Vec3::NAN] {
        assert!(p.set_sun(sun).is_err());
    }

    // Without cached bases the cached-only plan lights the scene per sun, as before.
    let fresh = Counting::default();
    let other = dir.path().join("other-cache");
    let mut q = prepare(scene(), &fresh, Some(&other), Some(cached_plan), &Silent).unwrap();
    assert!(q.relit.is_none());
    assert_eq!(fresh.0.load(Ordering::SeqCst), 1, "one per-sun solve");
    let e = q.set_sun(Vec3::Y).unwrap_err();
    assert!(matches!(e, PipelineError::NeedsBasis), "{e}");
    assert!(e.to_string().contains("sylva basis"), "{e}");
}

#[test]
fn the_physical_light_refuses_the_exact_weights_before_any_solve() {
    // The exact weights are exact for the paper light's boundary sun; the physical light's
    // sun parts are weighed by the face the sun crosses (docs/relight.md): asking for them is
    // an error before any solve, never a silently different light.
    let dir = tempfile::tempdir().unwrap();
    let solver = Counting::default();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &solver,
            grid: None,
            cache_dir: Some(&dir.path().join("cache")),
            light: Light::Physical,
        }),
        light: Light::Physical,
        relight: Some(plan(BasisUse::Always, SunWeights::Exact, false, false)),
        largest_frame: Some((48, 36, 1)),
        ..PrepareOptions::default()
    };
    let e = PreparedScene::new(rotated_roses(dir.path(), 0.0), &opts, &Silent)
        .err()
        .expect("exact weights under the physical light are refused");
    assert!(matches!(e, PipelineError::Shading(_)), "{e}");
    assert!(e.to_string().contains("--light paper"), "{e}");
    assert_eq!(solver.0.load(Ordering::SeqCst), 0, "nothing solved");
}

#[test]
fn damaged_basis_and_global_entries_are_solved_again() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let scene = || rotated_roses(dir.path(), 0.0);
    let relit_plan = plan(BasisUse::Always, SunWeights::ThreeBasis, true, false);
    prepare(scene(), &CpuSolver, Some(&cache), Some(relit_plan), &Silent).unwrap();
    let find = |ext: &str| {
        std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.extension().is_some_and(|e| e == ext))
            .unwrap()
    };
    for (ext, what) in [("scbasis", "basis rose"), ("sglobal", "global")] {
        let path = find(ext);
        let mut bytes = std::fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x10;
        std::fs::write(&path, &bytes).unwrap();
        let log = Log::default();
        prepare(scene(), &CpuSolver, Some(&cache), Some(relit_plan), &log).unwrap();
        let events = log.0.lock().unwrap().clone();
        let line = events.iter().find(|l| l.starts_with(what)).unwrap();
        assert!(
            line.contains("recomputed") && line.contains(&path.display().to_string()),
            "{line}"
        );
        // Replaced by a good entry.
        let log = Log::default();
        prepare(scene(), &CpuSolver, Some(&cache), Some(relit_plan), &log).unwrap();
        assert!(log.0.lock().unwrap().iter().all(|l| l.ends_with("cached")));
    }
}

fn density(model: &Model) -> DensityGrid {
    sylva_light::relight::basis_density(model, GRID).unwrap()
}

fn scales(g: &GlobalLight, to_sun: Vec3) -> Vec<(f32, f32)> {
    let w: BasisWeights = RelitIllumination::new(to_sun, SunWeights::ThreeBasis, 0.0)
        .weights(&Affine3A::IDENTITY)
        .unwrap();
    g.scales(&w).iter().map(|s| (s.sun, s.ambient)).collect()
}

#[test]
fn the_global_grid_leaves_a_lone_tree_alone() {
    let dir = tempfile::tempdir().unwrap();
    let scene = rotated_roses(dir.path(), 25.0);
    let d = density(&scene.models[0]);
    let medium = sylva_lb::Preset::Leaf.params();
    // One tree, and two trees far apart across every sun below.
    let one = [GlobalInstance {
        density: Some(&d),
        to_world: scene.instances[0].transform(),
    }];
    let far = Affine3A::from_scale_rotation_translation(
        Vec3::splat(1.2),
        Quat::from_rotation_y(1.0),
        Vec3::new(0.0, 0.0, 30.0),
    );
    let two = [
        one[0],
        GlobalInstance {
            density: Some(&d),
            to_world: far,
        },
    ];
    for (instances, what) in [(&one[..], "one tree"), (&two[..], "two trees")] {
        let g = GlobalLight::solve(instances, &medium, &GLOBAL, &mut |_, _| {}).unwrap();
        assert_eq!(g.instances(), instances.len());
        for sun in sylva_light::relight::sun_path(6, 0.0) {
            for (i, (s, a)) in scales(&g, sun).into_iter().enumerate() {
                assert!((s - 1.0).abs() < 0.05, "{what} {i}: sun scale {s} at {sun}");
                assert!((a - 1.0).abs() < 0.05, "{what} {i}: ambient scale {a}");
            }
        }
    }
    // An instance without a fine grid keeps scale 1 exactly.
    let g = GlobalLight::solve(
        &[GlobalInstance {
            density: None,
            to_world: Affine3A::IDENTITY,
        }],
        &medium,
        &GLOBAL,
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(scales(&g, Vec3::Y), vec![(1.0, 1.0)]);
    let bad = GlobalGridOptions { sites: 4 };
    assert!(GlobalLight::solve(&one, &medium, &bad, &mut |_, _| {}).is_err());
}

#[test]
fn a_tree_in_its_neighbours_shade_gets_less_indirect_light() {
    // 004 Fig. 2 as the built-in scene `shade`: instance 1 stands in the beech's shade,
    // instance 2, the same model, in the open.
    let scene = load_scene("shade", None).unwrap();
    assert_eq!(scene.instances.len(), 3);
    assert_eq!(scene.instances[1].model, scene.instances[2].model);
    let opts = BasisCacheOptions {
        grid: GRID,
        preset: "leaf".into(),
        cache_dir: None,
        target: CompressTarget::recommended(),
        keep_raw: false,
    };
    let bases: Vec<_> = scene
        .models
        .iter()
        .map(|m| {
            model_basis(m, &opts, Some(&CpuSolver), &mut |_| {})
                .unwrap()
                .unwrap()
                .0
        })
        .collect();
    let instances: Vec<GlobalInstance> = scene
        .instances
        .iter()
        .map(|i| GlobalInstance {
            density: bases[i.model as usize].density.as_ref(),
            to_world: i.transform(),
        })
        .collect();
    let medium = sylva_lb::Preset::Leaf.params();
    let g = GlobalLight::solve(
        &instances,
        &medium,
        &GlobalGridOptions::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let to_sun = scene.sun.to_sun().as_vec3();
    let s = scales(&g, to_sun);
    assert!((s[2].0 - 1.0).abs() < 0.05, "the open tree: {s:?}");
    assert!(
        s[1].0 < 0.85 * s[2].0,
        "shaded {:?} vs open {:?}",
        s[1],
        s[2]
    );
    assert!(s[0].0 > 0.9, "nothing shades the beech: {:?}", s[0]);

    // The fragments' light: the shaded tree's with the global grid, against the same
    // instance without it and the open tree.
    // The instances as traced (no kd-trees needed for lookups).
    let traced: Vec<sylva_trace::TraceInstance> = scene
        .instances
        .iter()
        .map(|i| sylva_trace::TraceInstance {
            model: i.model,
            to_world: i.transform(),
            to_model: i.transform().inverse(),
            world_bounds: i.world_bounds(&scene.models[i.model as usize]),
        })
        .collect();
    let stored = || {
        bases
            .iter()
            .map(|b| Some(StoredBasis::Compressed(b.compressed.clone())))
            .collect::<Vec<_>>()
    };
    let ill = RelitIllumination::new(to_sun, SunWeights::ThreeBasis, 0.0);
    let with = RelitLight::new(stored(), &scene.models, &traced, Some(g), ill).unwrap();
    let without = RelitLight::new(stored(), &scene.models, &traced, None, ill).unwrap();
    let d = bases[1].density.as_ref().unwrap();
    let placement = sylva_lb::relight::Placement::new(d.dims, d.bounds);
    let crown_mean = |l: &RelitLight, i: usize| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for site in 0..d.dims.sites() {
            if d.density[site] > 0.0 {
                let (x, y, z) = d.dims.coords(site);
                let pm = placement.model_point([x as f32, y as f32, z as f32]);
                let v = l.sample_instance(i, Vec3::from_array(pm)).unwrap();
                sum += sylva_core::colour::luminance(v.to_array()) as f64;
                n += 1;
            }
        }
        sum / n as f64
    };
    let (shaded, alone) = (crown_mean(&with, 1), crown_mean(&without, 1));
    assert!(shaded < 0.85 * alone, "{shaded} vs alone {alone}");
    assert!(
        shaded < crown_mean(&with, 2),
        "shaded {shaded} vs the open tree"
    );
}
