//! The tree machinery of 003 §4-5 on models with known answers: deep opacity maps and eq. 31
//! against counting through the whole scene, a slab-shaped "tree" against the slab models
//! (eq. 29 against the Poisson expectation, G → 1 inside, the Monte Carlo against the full
//! plane-parallel model), and the whole Table 3 run (determinism, its JSON, bad input).

use glam::Vec3;
use sylva_geom::{Instance, Model};
use sylva_lb::CpuSolver;
use sylva_light::Silent;
use sylva_spp::trees::beam::{count_depths, Beam};
use sylva_spp::trees::experiment::{self, ExperimentConfig, LbPlan, MIN_CATEGORY_MESHES};
use sylva_spp::trees::meshes::SceneMeshes;
use sylva_spp::trees::opacity_map::MapResolution;
use sylva_spp::trees::photons::{trace_photons, PhotonConfig};
use sylva_spp::trees::synthetic::{horizontal_leaves, leaf_slab, plates, single_instance};
use sylva_spp::trees::system::{SppSystem, SystemConfig};
use sylva_spp::{FullModel, Slab};
use sylva_trace::{Ray, SceneAccel, TraceStats, TraversalConfig};

fn at(position: Vec3) -> Instance {
    Instance {
        model: 0,
        position,
        rotation_deg: 0.0,
        scale: 1.0,
    }
}

/// Surfaces (leaf or tube groups) a line along `dir` crosses before reaching `x`.
fn crossings_before(accel: &SceneAccel, meshes: &SceneMeshes, x: Vec3, dir: Vec3) -> usize {
    let mut hits = Vec::new();
    let mut out = Vec::new();
    let ray = Ray::segment(x - dir * 100.0, dir, 0.0, 100.0);
    accel.all_hits(
        &ray,
        TraversalConfig::default(),
        &mut TraceStats::default(),
        &mut hits,
    );
    meshes.crossings(&hits, &mut out);
    out.len()
}

#[test]
fn eq_31_through_translated_copies_equals_counting_through_the_scene() {
    // Two stacks of three wide plates, one above and beside the other; for points between
    // plates and directions steep enough to stay inside them, the sum of the prototype's map
    // over the instances (eq. 31) is the number of plates the line crosses.
    let models: Vec<Model> = vec![plates(20.0, &[3.0, 2.0, 1.0])];
    let instances = vec![at(Vec3::ZERO), at(Vec3::new(1.0, 3.5, -0.5))];
    let accel = SceneAccel::from_parts(&models, &instances, None).unwrap();
    let meshes = SceneMeshes::new(&models, &accel);
    // Fine maps: a tilted plate's crossings spread over a texel and the layer interpolation
    // blurs them; texels of 0.16 m keep that far from the points.
    let config = SystemConfig {
        directions: 22,
        map: MapResolution {
            texels: 128,
            layers: 128,
            samples: 2,
        },
        ..SystemConfig::default()
    };
    let mut system = SppSystem::build(&models, &instances, &accel, &meshes, config).unwrap();
    assert_eq!(
        system.prototypes().len(),
        1,
        "translated copies share one prototype"
    );
    assert_eq!(system.cells(), 2 * 16 * 16 * 16);
    let points = [
        Vec3::new(0.0, 2.5, 0.0),
        Vec3::new(0.7, 1.5, -0.3),
        Vec3::new(-0.4, 0.5, 0.6),
        Vec3::new(1.0, 5.0, -0.5),
        Vec3::new(0.5, 7.5, 0.0),
    ];
    let mut checked = 0;
    for (j, &s) in system.directions().to_vec().iter().enumerate() {
        if s.y.abs() < 0.8 {
            continue;
        }
        for &x in &points {
            let want = crossings_before(&accel, &meshes, x, s) as f32;
            let (d, w) = system.depth(x, j);
            assert!(
                (d - want).abs() < 1e-3,
                "dir {s} at {x}: eq. 31 {d}, counted {want}"
            );
            assert!((w - 6.0).abs() < 1e-3, "thickness {w}");
            checked += 1;
        }
    }
    assert!(checked >= 10, "{checked}");
    // Along the light (straight down) at full resolution.
    system
        .set_light(&models, &accel, &meshes, Vec3::NEG_Y)
        .unwrap();
    let (d, w) = system.light_depth(Vec3::new(0.0, 2.5, 0.0));
    assert!((d - 4.0).abs() < 1e-3 && (w - 6.0).abs() < 1e-3, "{d} {w}");
    let (d, w) = system.light_depth(Vec3::new(0.0, 9.0, 0.0));
    assert!(
        d.abs() < 1e-3 && (w - 6.0).abs() < 1e-3,
        "above everything: {d} {w}"
    );
    // Far to the side no plate is crossed.
    assert_eq!(system.light_depth(Vec3::new(40.0, 2.5, 0.0)), (0.0, 0.0));
    // The sky: a point under six plates sees less of it than one under three.
    system.update_sky();
    assert!(system.sky(0, Vec3::new(0.0, 0.5, 0.0)) < system.sky(1, Vec3::new(1.0, 4.0, -0.5)));
}

/// A slab-shaped tree: `count` leaves of side `side` in a `2 half × thickness × 2 half` box.
/// Returns the scene parts and σ, the mean number of leaves a line crosses per unit length.
fn slab_tree(
    half: f32,
    side: f32,
    tau: f64,
    seed: u64,
) -> (Vec<Model>, SceneAccel, SceneMeshes, f64) {
    let thickness = 1.0f32;
    let volume = 4.0 * (half * half) as f64 * thickness as f64;
    let count = (tau * volume / (0.5 * (side as f64).powi(2))).round() as usize;
    let models = vec![leaf_slab(half, 0.0, thickness, side, count, seed)];
    let accel = SceneAccel::from_parts(&models, &single_instance(), None).unwrap();
    let meshes = SceneMeshes::new(&models, &accel);
    let sigma = count as f64 * 0.5 * (side as f64).powi(2) / volume;
    (models, accel, meshes, sigma)
}

#[test]
fn a_slab_shaped_tree_behaves_like_the_slab() {
    // Leaves with random positions and orientations: a line crosses σ ℓ of them on average
    // over a length ℓ (Poisson), so eq. 29 must give d ≈ σ·depth and w ≈ σ·thickness; the
    // plane-parallel condition holds inside, so G ≈ 1 there and falls towards the edges; and
    // the photons' leaf irradiance is the full plane-parallel model's (fluence/2 + direct).
    let (models, accel, meshes, sigma) = slab_tree(3.0, 0.1, 4.0, 11);
    let beam = Beam::covering(&accel, Vec3::NEG_Y).unwrap();
    let counts = count_depths(&accel, &meshes, &beam, 0.025, &|_| {}).unwrap();
    let mut system = SppSystem::build(
        &models,
        &single_instance(),
        &accel,
        &meshes,
        SystemConfig::default(),
    )
    .unwrap();
    system
        .set_light(&models, &accel, &meshes, Vec3::NEG_Y)
        .unwrap();
    let tally = trace_photons(
        &accel,
        &meshes,
        &beam,
        &PhotonConfig::with_albedo(400_000, 4, 0.95),
        &|_| {},
    )
    .unwrap();
    let full = FullModel::new(Slab::new(1.0, 0.95, 0.0, sigma, 1.0).unwrap()).unwrap();
    let mm = &meshes.models[0];
    let bins = 4;
    // Per depth bin of the central meshes: n, Σd, Σw, ΣE, Σ|cos|, ΣG; and G at the edges.
    let mut sums = vec![[0.0f64; 6]; bins];
    let (mut edge_g, mut edge_n) = (0.0, 0.0);
    for m in 0..mm.leaf_count {
        let c = mm.centroid[m];
        let (Some(d), Some(w)) = (counts.depth(m), counts.thickness(m)) else {
            continue;
        };
        if mm.area[m] <= 0.0 {
            continue;
        }
        let g = system.g(0, c) as f64;
        if c.x.abs() > 2.8 && c.z.abs() < 1.0 {
            edge_g += g;
            edge_n += 1.0;
        }
        if c.x.abs() > 1.2 || c.z.abs() > 1.2 {
            continue;
        }
        let b = ((1.0 - c.y) * bins as f32).clamp(0.0, bins as f32 - 1.0) as usize;
        let e = tally.total_hits(m) as f64 * tally.power_per_photon / mm.area[m] as f64;
        let s = &mut sums[b];
        for (k, v) in [1.0, d, w, e, mm.mean_abs_cos(m, Vec3::NEG_Y) as f64, g]
            .into_iter()
            .enumerate()
        {
            s[k] += v;
        }
    }
    let mut inside_g = 0.0;
    for (b, s) in sums.iter().enumerate() {
        let n = s[0];
        assert!(n > 200.0, "bin {b}: {n} meshes");
        let z = (b as f64 + 0.5) / bins as f64 * sigma;
        let (d, w, e, cos, g) = (s[1] / n, s[2] / n, s[3] / n, s[4] / n, s[5] / n);
        // Eq. 29 against the Poisson expectation (a bin is a quarter of the slab deep).
        assert!((d - z).abs() < 0.15, "bin {b}: d {d} vs σz {z}");
        assert!((w - sigma).abs() < 0.2, "bin {b}: w {w} vs σ {sigma}");
        // The full model's leaf irradiance: half its diffuse fluence plus the beam on the
        // leaves' projected area.
        let (down, up) = full.hemispheric_totals(z).unwrap();
        let want = 0.5 * (down + up) + cos * (-z).exp();
        assert!(
            (e - want).abs() < 0.07 * want,
            "bin {b}: Monte Carlo {e} vs full model {want}"
        );
        inside_g += g / bins as f64;
    }
    assert!(inside_g > 0.97, "G inside the slab {inside_g}");
    // Within a few tenths of a mean free path of the side, light arriving sideways is missing.
    assert!(
        edge_n > 50.0 && edge_g / edge_n < inside_g - 0.1,
        "G at the edge {}",
        edge_g / edge_n
    );
}

fn small_config(lb: Option<LbPlan<'_>>) -> ExperimentConfig<'_> {
    ExperimentConfig {
        albedo: 0.9,
        photons: 60_000,
        seed: 3,
        light: [0.2, -1.0, 0.1],
        rays_per_leaf: 8.0,
        system: SystemConfig {
            map: MapResolution {
                texels: 32,
                layers: 32,
                samples: 1,
            },
            light_map: MapResolution {
                texels: 64,
                layers: 32,
                samples: 1,
            },
            grid: 8,
            ..SystemConfig::default()
        },
        lb,
    }
}

#[test]
fn table_3_run_is_deterministic_and_consistent() {
    let (models, _, _, _) = slab_tree(1.5, 0.15, 3.0, 5);
    let scene = sylva_geom::Scene {
        name: "slab tree".into(),
        origin: "test".into(),
        model_origins: vec![sylva_geom::ModelOrigin::Species("synthetic".into())],
        models,
        instances: single_instance(),
        ground: sylva_geom::Ground {
            enabled: false,
            size: None,
            color: [0.2; 3],
        },
        sun: sylva_core::Sun::default(),
        sky_color: [0.5; 3],
        camera: sylva_geom::Camera {
            position: Vec3::new(0.0, 1.0, -6.0),
            look_at: Vec3::ZERO,
            fov_deg: 40.0,
            width: 64,
            height: 64,
            rays_per_pixel: 1,
        },
        lb: sylva_geom::LbSettings::default(),
        sun_color: None,
        bands: None,
        // Every model with the scene's preset, no media.
        model_presets: Vec::new(),
        media: Vec::new(),
    };
    let scene = experiment::repeated(&scene, 2, Some(3.2)).unwrap();
    assert_eq!(scene.instances.len(), 4);
    let solver = CpuSolver;
    let cfg = small_config(Some(LbPlan {
        solver: &solver,
        grid: 16,
    }));
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| experiment::run(&scene, &cfg, &Silent).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.categories, b.categories, "same result on 1 and 2 threads");
    assert_eq!(a.errors, b.errors);
    assert_eq!(a.instances, 4);
    assert_eq!(a.prototypes, 1);
    assert!(a.categories.iter().all(|c| c.meshes >= MIN_CATEGORY_MESHES));
    assert!(a.compared_meshes + a.unmet_meshes <= a.leaf_meshes);
    let e = a.errors;
    for v in [e.sppg, e.spp, e.ss, e.lb.unwrap(), e.mc_noise] {
        assert!(v.is_finite() && v >= 0.0, "{e:?}");
    }
    // Single scattering misses the scattered light: below the Monte Carlo everywhere on
    // average, and SPPG lies between SS and SPP (0 ≤ G ≤ 1).
    let m = a.means;
    assert!(m.ss < m.mc && m.mc_direct <= m.mc);
    assert!(m.ss <= m.sppg + 1e-12 && m.sppg <= m.spp + 1e-12, "{m:?}");
    // The unscattered light: the model's e^{-d} against the photons' first hits agree on
    // average within 25 % (e^{-mean n+} is not the mean over rays of [n+ = 0]).
    assert!((m.ss - m.mc_direct).abs() < 0.25 * m.mc_direct, "{m:?}");
    // Photons end somewhere.
    let bal = a.balance;
    let sum = bal.escaped + bal.absorbed_leaves + bal.absorbed_wood + bal.unfinished;
    assert!((sum - 1.0).abs() < 1e-12);
    let json = serde_json::to_value(&a).unwrap();
    assert!(json["errors"]["sppg"].is_number() && json["categories"].is_array());
}

#[test]
fn horizontal_leaves_turn_each_leaf_flat_where_it_hangs() {
    // Randomly oriented square leaves, plus a wood quad of its own and one sharing a vertex
    // with the first leaf: every free leaf ends horizontal with its centroid and area kept,
    // wood and the leaf joined to it stay as they were.
    let slab = leaf_slab(1.0, 0.0, 1.0, 0.2, 200, 5);
    let mut mesh = slab.mesh.clone();
    let w: Vec<u32> = [[3.0, 0.0, 0.0], [3.5, 0.0, 0.0], [3.5, 1.0, 0.2]]
        .iter()
        .map(|&p| mesh.push_vertex(Vec3::from_array(p), Vec3::X, [0.0, 0.0]))
        .collect();
    mesh.push_triangle(w[0], w[1], w[2], 1);
    mesh.push_triangle(0, w[0], w[1], 1);
    let wood = sylva_geom::Material {
        name: "wood".into(),
        kind: sylva_geom::MaterialKind::Wood,
        base_color: [0.3, 0.2, 0.1],
        texture: None,
        two_sided: false,
        optics: sylva_geom::Optics::OPAQUE,
    };
    let model = Model::new("test", mesh, vec![slab.materials[0].clone(), wood]);
    let flat = horizontal_leaves(&model);
    assert_eq!(flat.mesh.indices, model.mesh.indices);
    let corners = |m: &Model, t: usize| {
        m.mesh.indices[t].map(|i| Vec3::from_array(m.mesh.positions[i as usize]))
    };
    let leaf_tris = model
        .mesh
        .material_ids
        .iter()
        .filter(|&&id| id == 0)
        .count();
    assert_eq!(leaf_tris, 400);
    // Leaf k is triangles 2k and 2k + 1 (4 vertices of its own).
    for k in 0..200 {
        let (mut area, mut c0, mut c1) = (0.0, Vec3::ZERO, Vec3::ZERO);
        let mut area1 = 0.0;
        for t in [2 * k, 2 * k + 1] {
            let [a, b, c] = corners(&model, t);
            let [a1, b1, c1_] = corners(&flat, t);
            let n = (b1 - a1).cross(c1_ - a1);
            let (s, s1) = (0.5 * (b - a).cross(c - a).length(), 0.5 * n.length());
            area += s;
            area1 += s1;
            c0 += (a + b + c) / 3.0 * s;
            c1 += (a1 + b1 + c1_) / 3.0 * s1;
            if k > 0 {
                assert!(n.normalize().y.abs() > 0.9999, "leaf {k}: normal {n}");
                let vn = Vec3::from_array(flat.mesh.normals[flat.mesh.indices[t][0] as usize]);
                assert!(vn.y.abs() > 0.9999, "leaf {k}: vertex normal {vn}");
            }
        }
        assert!(
            (area1 - area).abs() < 1e-5 * area.max(1e-3),
            "leaf {k}: area"
        );
        assert!(
            (c1 / area1 - c0 / area).length() < 1e-5,
            "leaf {k}: centroid"
        );
    }
    // The leaf that shares a vertex with wood, and the wood, did not move.
    for v in (0..4).chain(800..803) {
        assert_eq!(
            flat.mesh.positions[v], model.mesh.positions[v],
            "vertex {v}"
        );
    }
    // The experiment's mean |n·s0| is 1/2 for isotropic leaves and 1 once they are flat.
    let accel_cos = |m: &Model| {
        let models = vec![m.clone()];
        let accel = SceneAccel::from_parts(&models, &single_instance(), None).unwrap();
        let meshes = SceneMeshes::new(&models, &accel);
        let mm = &meshes.models[0];
        (0..mm.leaf_count)
            .map(|k| mm.mean_abs_cos(k, Vec3::NEG_Y) as f64)
            .sum::<f64>()
            / mm.leaf_count as f64
    };
    let (c_iso, c_flat) = (accel_cos(&model), accel_cos(&flat));
    assert!(
        (c_iso - 0.5).abs() < 0.06,
        "isotropic leaves: mean |n·s0| {c_iso}"
    );
    assert!(
        c_flat > 0.995 - 1.0 / 200.0,
        "flat leaves: mean |n·s0| {c_flat}"
    );
}

#[test]
fn bad_input_is_an_error() {
    let models = vec![plates(1.0, &[1.0])];
    let scene = sylva_geom::Scene {
        name: "plate".into(),
        origin: "test".into(),
        model_origins: vec![sylva_geom::ModelOrigin::Species("synthetic".into())],
        models,
        instances: single_instance(),
        ground: sylva_geom::Ground {
            enabled: false,
            size: None,
            color: [0.2; 3],
        },
        sun: sylva_core::Sun::default(),
        sky_color: [0.5; 3],
        camera: sylva_geom::Camera {
            position: Vec3::new(0.0, 1.0, -6.0),
            look_at: Vec3::ZERO,
            fov_deg: 40.0,
            width: 64,
            height: 64,
            rays_per_pixel: 1,
        },
        lb: sylva_geom::LbSettings::default(),
        sun_color: None,
        bands: None,
        // Every model with the scene's preset, no media.
        model_presets: Vec::new(),
        media: Vec::new(),
    };
    let ok = small_config(None);
    assert!(experiment::run(&scene, &ok, &Silent).is_ok());
    for bad in [
        ExperimentConfig { albedo: 1.5, ..ok },
        ExperimentConfig {
            albedo: f64::NAN,
            ..ok
        },
        ExperimentConfig { photons: 0, ..ok },
        ExperimentConfig {
            light: [0.0, 0.0, 0.0],
            ..ok
        },
        ExperimentConfig {
            light: [f32::NAN, -1.0, 0.0],
            ..ok
        },
        ExperimentConfig {
            rays_per_leaf: -1.0,
            ..ok
        },
        ExperimentConfig {
            system: SystemConfig {
                directions: 0,
                ..ok.system
            },
            ..ok
        },
    ] {
        let err = experiment::run(&scene, &bad, &Silent).unwrap_err();
        assert!(!err.to_string().is_empty());
    }
    assert!(experiment::repeated(&scene, 0, None).is_err());
    assert!(experiment::repeated(&scene, 2, Some(f32::NAN)).is_err());
    let mut empty = scene.clone();
    empty.instances.clear();
    assert!(experiment::run(&empty, &ok, &Silent).is_err());
}

#[test]
fn the_spp_light_is_the_slab_model_inside_a_slab_shaped_tree() {
    use sylva_light::IndirectLight;
    use sylva_spp::trees::shading::TreeSpp;
    use sylva_spp::trees::system::SppLight;
    // A slab-shaped tree 4 mean free paths thick (top at y = 1), lit from above. Over many
    // columns (one column's leaf count is Poisson, and a column keeps its count at every
    // height, so few columns share one error at all depths), the light map's depth at `h`
    // below the top is `σh` and its thickness `σ`; the renderer's SPP light is eq. 19's
    // diffuse field at each column's depth and thickness (per colour of the leaf preset)
    // times G (not the field of the mean slab: it is not linear in the thickness), and it
    // falls with depth. The sky under the slab is what gets through it.
    let (models, accel, meshes, sigma) = slab_tree(3.0, 0.1, 4.0, 11);
    let mut system = SppSystem::build(
        &models,
        &single_instance(),
        &accel,
        &meshes,
        SystemConfig::default(),
    )
    .unwrap();
    system
        .set_light(&models, &accel, &meshes, Vec3::NEG_Y)
        .unwrap();
    system.update_sky();
    let light = SppLight::with_preset(&system, "leaf").unwrap();
    let inst = &accel.instances()[0];
    let params = sylva_lb::Preset::Leaf.params();
    let n = 16;
    let column = |i: usize| -2.0 + 4.0 * i as f32 / (n - 1) as f32;
    let mut previous = Vec3::splat(f32::INFINITY);
    for y in [0.85f32, 0.6, 0.35, 0.15] {
        let expected_depth = sigma * (1.0 - y as f64);
        let (mut got, mut want) = (Vec3::ZERO, Vec3::ZERO);
        let (mut depth, mut thickness) = (0.0, 0.0);
        for i in 0..n {
            for k in 0..n {
                let p = Vec3::new(column(i), y, column(k));
                got += light.plant(0, inst, p).unwrap();
                let (d, w) = system.light_depth(p);
                depth += d as f64;
                thickness += w as f64;
                let g = system.g(0, p).clamp(0.0, 1.0) as f64;
                let mut c = [0.0f32; 3];
                for (c, cp) in c.iter_mut().zip(&params.colours) {
                    let spp = TreeSpp::new(cp.sigma_s / cp.sigma_t()).unwrap();
                    let (ep, em) = spp.diffuse(d as f64, w as f64).unwrap();
                    *c = (2.0 * g * (ep + em)) as f32;
                }
                want += Vec3::from_array(c);
            }
        }
        let count = (n * n) as f64;
        let (depth, thickness) = (depth / count, thickness / count);
        assert!(
            (depth - expected_depth).abs() < 0.15 && (thickness / sigma - 1.0).abs() < 0.05,
            "y {y}: map depth {depth}, thickness {thickness}; expected {expected_depth}, {sigma}"
        );
        assert!(
            ((got - want).abs() / want).max_element() < 1e-4,
            "y {y}: SPP light {got}, slab model {want}"
        );
        assert!(got.cmplt(previous).all(), "not falling with depth at y {y}");
        previous = got;
    }
    // Straight down through the slab the sky's light gets through as e^{−d} averaged over
    // the downward sample directions: e^{−σ} ≈ 2 % straight down, more obliquely through
    // the sides, but far below the open sky's 1.
    let under = light.ground_sky(Vec3::new(0.0, 0.0, 0.0));
    assert!(under.max_element() < 0.1, "sky under the slab {under}");
    assert_eq!(light.ground_sky(Vec3::new(20.0, 0.0, 0.0)), Vec3::ONE);
    assert!(SppLight::with_preset(&system, "no such preset").is_err());
    // No device side: the GPU frame kernel cannot read it, and it says why.
    let why = light
        .device()
        .err()
        .expect("the SPP light has no device side");
    assert!(why.0.contains("plane-parallel"), "{why}");
}
