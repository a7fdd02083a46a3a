//! 003 Table 3: the irradiance of every leaf mesh of a scene from the Monte Carlo reference
//! and from the models (SPPG, SPP, single scattering, and sylva's LB lighting), compared by
//! eq. 30 over depth-thickness categories.
//!
//! Per mesh (003 §4.2):
//!
//! * depth `d` and thickness `w` by eq. 29 ([`super::beam::count_depths`]);
//! * `SS = |n·s0| e^{−d}` (the direct light, "reflection/transmission of I0");
//! * `SPP = E+ + E− + SS` (eq. 19 at `d` in a slab of `w`, its diffuse fluxes `E±` on both
//!   faces of the leaf, [`super::shading`]);
//! * `SPPG = G·SPP + (1 − G)·SS` (eq. 28), G from the instance's grid at the mesh's centroid
//!   ([`super::system`]; eq. 31 and A.3);
//! * `MC`: photons meeting the mesh, per unit area ([`super::photons`]);
//! * `LB`: sylva's LB light at the mesh's centroid as an irradiance (below).
//!
//! Irradiances are two-sided (both faces of a leaf, as the photon count is) per unit
//! irradiance across the beam. Eq. 30 bins the meshes by `(round(d), round(w))` (unit-wide
//! bins: one surface), averages each model within a bin, and reports
//! `sqrt(Σ_bins (⟨L⟩ − ⟨L0⟩)² / Σ_bins ⟨L0⟩²)` with `L0` the Monte Carlo value. Bins of fewer
//! than [`MIN_CATEGORY_MESHES`] meshes are left out: eq. 30 weighs every bin alike, and the
//! Monte Carlo mean of a handful of meshes is mostly noise. SPP and SPPG are also reported
//! with eq. 19's totals read as radiance integrals (half the diffuse light, see
//! [`super::shading`]).
//!
//! **LB as irradiance.** Each prototype's LB grid is solved with the sun in its model space
//! and a medium matching the leaves (σt 1 per lattice step as sylva's leaf preset, σs = the
//! albedo, g = 0 since R = T), and, in a second colour of the same solve, with σs = 0: the
//! light that has not scattered. Both are normalised as the renderer does (free-space sunlight
//! is 1), so they are fluences in units of the beam's. A leaf receives the unscattered beam
//! on its projected area, `|n·s0| φ_unscattered`, and half of the scattered fluence (a
//! randomly oriented pair of faces in a field without direction gets half the fluence):
//! `E_LB = |n·s0| φ_u + (φ − φ_u)/2`. As in sylva's renderer, each model has its own grid:
//! light between trees of a repeated scene is not in it.

use super::beam::{count_depths, Beam, DepthCounts};
use super::meshes::SceneMeshes;
use super::opacity_map::prototypes_of;
use super::photons::{trace_photons, PhotonConfig, PhotonTally};
use super::shading::TreeSpp;
use super::system::{SppSystem, SystemConfig};
use super::TreeError;
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Instant;
use sylva_geom::{Instance, Scene};
use sylva_lb::{Boundary, ColourParams, LbSolver, MediumParams, SolveOptions};
use sylva_light::lighting::ModelLighting;
use sylva_light::Progress;
use sylva_trace::SceneAccel;

/// 003 Table 3 (RMS by eq. 30, albedo 0.95): (SPPG, SPP, SS) for the single tree and for the
/// repeated trees.
pub const PAPER_TABLE3: [(&str, [f64; 3]); 2] = [
    ("single tree", [0.062, 0.65, 0.16]),
    ("multiple trees", [0.092, 0.43, 0.28]),
];

/// Eq. 30 bins with fewer meshes than this are left out.
pub const MIN_CATEGORY_MESHES: usize = 10;

/// The LB column: which solver, on how fine a grid.
#[derive(Clone, Copy)]
pub struct LbPlan<'a> {
    pub solver: &'a dyn LbSolver,
    /// Sites along each model's longest edge.
    pub grid: usize,
}

/// What to run.
#[derive(Clone, Copy)]
pub struct ExperimentConfig<'a> {
    /// Leaf albedo `R + T` (with `R = T`); wood reflects the same.
    pub albedo: f64,
    pub photons: u64,
    pub seed: u64,
    /// The direction the light travels in (world space, x, y, z with +y up).
    pub light: [f32; 3],
    /// Eq. 29's light rays per mean leaf area (sets the spacing of the ray grid).
    pub rays_per_leaf: f64,
    pub system: SystemConfig,
    pub lb: Option<LbPlan<'a>>,
}

impl ExperimentConfig<'_> {
    pub fn validate(&self) -> Result<(), TreeError> {
        if !(self.albedo.is_finite() && (0.0..=1.0).contains(&self.albedo)) {
            return Err(TreeError::invalid(
                "albedo",
                self.albedo.to_string(),
                "must be in [0, 1]",
            ));
        }
        if !(self.rays_per_leaf.is_finite()
            && self.rays_per_leaf > 0.0
            && self.rays_per_leaf <= 1e4)
        {
            return Err(TreeError::invalid(
                "light rays per leaf",
                self.rays_per_leaf.to_string(),
                "must be in (0, 10000]",
            ));
        }
        if let Some(lb) = &self.lb {
            if !(4..=1024).contains(&lb.grid) {
                return Err(TreeError::invalid(
                    "LB grid",
                    lb.grid.to_string(),
                    "must be 4 to 1024 sites along the longest edge",
                ));
            }
        }
        self.system.validate()
    }
}

/// One depth-thickness category of eq. 30: mean two-sided irradiance of its meshes.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Category {
    pub depth: u32,
    pub thickness: u32,
    pub meshes: usize,
    pub mc: f64,
    /// The Monte Carlo's unscattered part.
    pub mc_direct: f64,
    pub sppg: f64,
    pub spp: f64,
    pub ss: f64,
    pub lb: Option<f64>,
    /// Mean G-factor of the meshes.
    pub g: f64,
}

impl Category {
    /// SPP's diffuse part halved: eq. 19's totals read as radiance integrals.
    pub fn spp_radiance_reading(&self) -> f64 {
        0.5 * (self.spp + self.ss)
    }

    /// SPPG with eq. 19's totals read as radiance integrals.
    pub fn sppg_radiance_reading(&self) -> f64 {
        0.5 * (self.sppg + self.ss)
    }
}

/// Eq. 30 for each model against the Monte Carlo.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct Errors {
    pub sppg: f64,
    pub spp: f64,
    pub ss: f64,
    pub lb: Option<f64>,
    /// SPPG and SPP with eq. 19's totals read as radiance integrals (half the diffuse light).
    pub sppg_radiance_reading: f64,
    pub spp_radiance_reading: f64,
    /// Eq. 30 between the two halves of the Monte Carlo run, halved: about the Monte Carlo's
    /// own contribution to the numbers above.
    pub mc_noise: f64,
}

/// Area-weighted mean irradiance over the compared meshes.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct Means {
    pub mc: f64,
    pub mc_direct: f64,
    pub sppg: f64,
    pub spp: f64,
    pub ss: f64,
    pub lb: Option<f64>,
    pub g: f64,
}

/// Where the photons went, as fractions of the photons.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct PhotonBalance {
    pub photons: u64,
    pub escaped: f64,
    pub absorbed_leaves: f64,
    pub absorbed_wood: f64,
    pub unfinished: f64,
    /// Surface interactions per photon, on leaves and on wood.
    pub leaf_hits_per_photon: f64,
    pub wood_hits_per_photon: f64,
}

/// Seconds per stage.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct Timings {
    pub accel: f64,
    pub meshes: f64,
    pub depth_counts: f64,
    pub system: super::system::SystemTimings,
    pub photons: f64,
    pub lb: f64,
    pub total: f64,
}

/// The whole result.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TreeReport {
    pub scene: String,
    pub instances: usize,
    pub prototypes: usize,
    pub albedo: f64,
    /// The direction the light travels in.
    pub light: [f32; 3],
    pub seed: u64,
    pub leaf_meshes: usize,
    /// Meshes with opaque area that light rays met (the compared ones).
    pub compared_meshes: usize,
    /// Meshes with opaque area that no light ray met (edge-on to the light, or hidden
    /// between rays): no depth, not compared.
    pub unmet_meshes: usize,
    /// Eq. 30 bins used (at least [`MIN_CATEGORY_MESHES`] meshes) and the meshes in them.
    pub categories_used: usize,
    pub meshes_in_categories: usize,
    /// Area-weighted mean depth and thickness of the compared meshes (surfaces crossed).
    pub mean_depth: f64,
    pub mean_thickness: f64,
    /// Area-weighted mean `|n·s0|` of the compared meshes: how squarely the leaves face the
    /// light (1: all across it; 1/2 for random orientations). The direct light a leaf gets
    /// per unit area, SS at depth 0.
    pub mean_cos_light: f64,
    pub depth_rays: u64,
    pub ray_spacing: f32,
    pub sample_directions: usize,
    pub grid_cells: usize,
    pub lb_grid: Option<usize>,
    pub errors: Errors,
    pub paper: Option<PaperRow>,
    pub means: Means,
    pub balance: PhotonBalance,
    pub timings: Timings,
    pub categories: Vec<Category>,
}

/// The paper's Table 3 row for comparison.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct PaperRow {
    pub configuration: &'static str,
    pub sppg: f64,
    pub spp: f64,
    pub ss: f64,
}

/// `scene` with its instances copied onto a `k × k` lattice in x and z (003's "repeated the
/// same tree model periodically"), `spacing` apart (default: the wider of the instances'
/// x and z extents, so neighbouring crowns just touch), centred on the original. The camera
/// moves `k` times as far from what it looks at, and the ground grows to hold the lattice.
pub fn repeated(scene: &Scene, k: usize, spacing: Option<f32>) -> Result<Scene, TreeError> {
    if !(1..=64).contains(&k) {
        return Err(TreeError::invalid(
            "repeat",
            k.to_string(),
            "must be 1 to 64 (a k × k lattice)",
        ));
    }
    let b = scene.instance_bounds();
    if b.is_empty() {
        return Err(TreeError::NoLeaves(format!(
            "scene '{}' has no instances",
            scene.name
        )));
    }
    let step = match spacing {
        Some(s) if s.is_finite() && s > 0.0 => s,
        Some(s) => {
            return Err(TreeError::invalid(
                "spacing",
                s.to_string(),
                "must be a finite distance > 0",
            ))
        }
        None => (b.max.x - b.min.x).max(b.max.z - b.min.z),
    };
    let mut out = scene.clone();
    out.instances.clear();
    let centre = 0.5 * (k as f32 - 1.0);
    for a in 0..k {
        for c in 0..k {
            let offset = Vec3::new((a as f32 - centre) * step, 0.0, (c as f32 - centre) * step);
            out.instances
                .extend(scene.instances.iter().map(|i| Instance {
                    position: i.position + offset,
                    ..*i
                }));
        }
    }
    if k > 1 {
        out.name = format!("{}-{k}x{k}", scene.name);
        let c = &mut out.camera;
        c.position = c.look_at + (c.position - c.look_at) * k as f32;
        if let Some(size) = &mut out.ground.size {
            let grow = (k - 1) as f32 * step;
            *size = [size[0] + grow, size[1] + grow];
        }
    }
    Ok(out)
}

/// Eq. 30: `sqrt(Σ (⟨L⟩ − ⟨L0⟩)² / Σ ⟨L0⟩²)` over categories.
pub fn rms_dw(pairs: impl IntoIterator<Item = (f64, f64)>) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (model, reference) in pairs {
        num += (model - reference).powi(2);
        den += reference * reference;
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

/// The LB medium of the comparison: colour 0 scatters with the leaves' albedo (σt = 1, g = 0),
/// colour 1 only absorbs (its total is the unscattered light), colour 2 repeats colour 0 (the
/// solver copies identical colours instead of solving them again).
pub fn lb_medium(albedo: f64) -> Result<MediumParams, TreeError> {
    let scatter = ColourParams::new(1.0 - albedo, albedo, 0.0)?;
    let absorb = ColourParams::new(1.0, 0.0, 0.0)?;
    let leaf = sylva_lb::Preset::Leaf.params();
    let m = MediumParams {
        colours: [scatter, absorb, scatter],
        ..leaf
    };
    m.validate()?;
    Ok(m)
}

/// Per mesh values of the models.
struct MeshValues {
    depth: f64,
    cos: f64,
    thickness: f64,
    area: f64,
    g: f64,
    ss: f64,
    spp: f64,
    sppg: f64,
    lb: Option<f64>,
}

/// Runs the comparison on `scene` (its ground is ignored: photons that miss the trees leave).
pub fn run(
    scene: &Scene,
    cfg: &ExperimentConfig,
    progress: &dyn Progress,
) -> Result<TreeReport, TreeError> {
    cfg.validate()?;
    let t_all = Instant::now();
    let light = Vec3::from_array(cfg.light).normalize_or_zero();
    if light == Vec3::ZERO || !light.is_finite() {
        return Err(TreeError::invalid(
            "light direction",
            format!("{:?}", cfg.light),
            "must be a finite, non-zero vector",
        ));
    }
    let mut timings = Timings::default();

    let t = Instant::now();
    let accel = SceneAccel::from_parts(&scene.models, &scene.instances, None)?;
    timings.accel = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let meshes = SceneMeshes::new(&scene.models, &accel);
    timings.meshes = t.elapsed().as_secs_f64();
    let total = meshes.total();
    if total == 0 {
        return Err(TreeError::NoLeaves(format!(
            "scene '{}' has no leaf triangles",
            scene.name
        )));
    }
    // World-space opaque area of every mesh.
    let mut area = vec![0.0f64; total];
    for (i, inst) in scene.instances.iter().enumerate() {
        let mm = &meshes.models[inst.model as usize];
        let s2 = (inst.scale as f64).powi(2);
        let off = meshes.instance_offset[i] as usize;
        for (k, a) in mm.area.iter().enumerate() {
            area[off + k] = *a as f64 * s2;
        }
    }
    let lit: Vec<f64> = area.iter().copied().filter(|&a| a > 0.0).collect();
    if lit.is_empty() {
        return Err(TreeError::NoLeaves(format!(
            "every leaf of scene '{}' is transparent",
            scene.name
        )));
    }
    let mean_area = lit.iter().sum::<f64>() / lit.len() as f64;

    let beam = Beam::covering(&accel, light)?;
    let spacing = (mean_area / cfg.rays_per_leaf).sqrt() as f32;
    let (nu, nv) = super::beam::grid_size(&beam, spacing)?;
    let t = Instant::now();
    progress.start("light rays", (nu * nv) as u64);
    let counts = count_depths(&accel, &meshes, &beam, spacing, &|n| progress.advance(n));
    progress.finish();
    let counts = counts?;
    timings.depth_counts = t.elapsed().as_secs_f64();

    progress.start("opacity maps", 2);
    let mut system =
        SppSystem::build(&scene.models, &scene.instances, &accel, &meshes, cfg.system)?;
    progress.advance(1);
    system.set_light(&scene.models, &accel, &meshes, light)?;
    system.update_sky();
    progress.finish();
    timings.system = system.timings;

    let t = Instant::now();
    let photon_cfg = PhotonConfig::with_albedo(cfg.photons, cfg.seed, cfg.albedo);
    progress.start("photons", cfg.photons);
    let tally = trace_photons(&accel, &meshes, &beam, &photon_cfg, &|n| {
        progress.advance(n)
    });
    progress.finish();
    let tally = tally?;
    timings.photons = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let lb = match &cfg.lb {
        Some(plan) => Some(lb_lighting(scene, light, cfg.albedo, plan, progress)?),
        None => None,
    };
    timings.lb = t.elapsed().as_secs_f64();

    let spp = TreeSpp::new(cfg.albedo)?;
    let values = mesh_values(
        &accel,
        &meshes,
        &counts,
        &system,
        &spp,
        &area,
        light,
        lb.as_ref(),
    )?;
    let report = assemble(
        scene, cfg, light, &meshes, &counts, &system, &tally, &values, timings, t_all,
    );
    Ok(report)
}

/// Per prototype (model, rotation) the LB light (colour 0: all light, colour 1: unscattered)
/// with the sun in its model space; returns each instance's lighting index and the grids.
fn lb_lighting(
    scene: &Scene,
    light: Vec3,
    albedo: f64,
    plan: &LbPlan,
    progress: &dyn Progress,
) -> Result<(Vec<u32>, Vec<ModelLighting>), TreeError> {
    let medium = lb_medium(albedo)?;
    let (protos, of) = prototypes_of(&scene.instances);
    let mut grids = Vec::with_capacity(protos.len());
    for p in &protos {
        let model = &scene.models[p.model as usize];
        let travel = p.world_to_model * light;
        let placement = sylva_voxel::placement_for(model, plan.grid)?;
        let dims = placement.dims;
        sylva_core::check_memory(
            &format!("the LB lighting of model '{}' on a {dims} grid", model.name),
            sylva_lb::solver::memory_needed(dims) + sylva_voxel::memory_needed(dims),
        )?;
        let density = sylva_voxel::voxelize(
            model,
            &sylva_voxel::VoxelizeOptions {
                grid: plan.grid,
                alpha_test: true,
                // The papers' sub-cell occupancy, which the tables' LB column used.
                occupancy: sylva_voxel::Occupancy::SubCells,
            },
        )?;
        let opts = SolveOptions::papers(dims);
        let max = opts.max_steps as u64;
        progress.start(&format!("LB {}", model.name), 2 * max);
        let solved = plan.solver.solve_lighting(
            &density,
            &medium,
            Boundary::sun(travel.as_dvec3().to_array(), 1.0),
            &opts,
            &mut |c, step, _| progress.set((c.min(1) as u64) * max + step as u64, 2 * max),
        );
        progress.finish();
        let (grid, _) = solved.map_err(|source| TreeError::Lb {
            model: model.name.clone(),
            source,
        })?;
        grids.push(ModelLighting::from_grid(&grid, -travel));
    }
    Ok((of, grids))
}

#[allow(clippy::too_many_arguments)] // the stages' results, once each
fn mesh_values(
    accel: &SceneAccel,
    meshes: &SceneMeshes,
    counts: &DepthCounts,
    system: &SppSystem,
    spp: &TreeSpp,
    area: &[f64],
    light: Vec3,
    lb: Option<&(Vec<u32>, Vec<ModelLighting>)>,
) -> Result<Vec<Option<MeshValues>>, TreeError> {
    let mut out = Vec::with_capacity(meshes.total());
    for (i, inst) in accel.instances().iter().enumerate() {
        let mm = &meshes.models[inst.model as usize];
        let light_model = inst.to_model.transform_vector3(light).normalize();
        for k in 0..mm.leaf_count {
            let m = meshes.instance_offset[i] as usize + k;
            let (Some(d), Some(w)) = (counts.depth(m), counts.thickness(m)) else {
                out.push(None);
                continue;
            };
            if area[m] <= 0.0 {
                out.push(None);
                continue;
            }
            let x = inst.to_world.transform_point3(mm.centroid[k]);
            let cos = mm.mean_abs_cos(k, light_model) as f64;
            let g = system.g(i, x).clamp(0.0, 1.0) as f64;
            let (diffuse, direct) = spp.irradiance(d, w, cos)?;
            let lb_value = lb.map(|(of, grids)| {
                let v = grids[of[i] as usize].sample(mm.centroid[k]);
                let (all, unscattered) = (v.x as f64, v.y as f64);
                cos * unscattered + 0.5 * (all - unscattered).max(0.0)
            });
            out.push(Some(MeshValues {
                depth: d,
                cos,
                thickness: w,
                area: area[m],
                g,
                ss: direct,
                spp: diffuse + direct,
                sppg: direct + g * diffuse,
                lb: lb_value,
            }));
        }
    }
    Ok(out)
}

#[derive(Default, Clone, Copy)]
struct Sums {
    n: usize,
    mc: f64,
    mc_half: [f64; 2],
    mc_direct: f64,
    sppg: f64,
    spp: f64,
    ss: f64,
    lb: f64,
    g: f64,
    depth: f64,
    thickness: f64,
    cos: f64,
}

#[allow(clippy::too_many_arguments)] // the stages' results, once each
fn assemble(
    scene: &Scene,
    cfg: &ExperimentConfig,
    light: Vec3,
    meshes: &SceneMeshes,
    counts: &DepthCounts,
    system: &SppSystem,
    tally: &PhotonTally,
    values: &[Option<MeshValues>],
    mut timings: Timings,
    t_all: Instant,
) -> TreeReport {
    let ppp = tally.power_per_photon;
    let mut bins: BTreeMap<(u32, u32), Sums> = BTreeMap::new();
    let mut weighted = Sums::default();
    let mut total_area = 0.0;
    let (mut compared, mut unmet) = (0usize, 0usize);
    let has_lb = cfg.lb.is_some();
    for (m, v) in values.iter().enumerate() {
        let Some(v) = v else {
            // Meshes with area that no light ray met.
            let (i, k) = meshes.locate(m as u32);
            let mm = &meshes.models[meshes.instance_model[i as usize] as usize];
            unmet += (mm.area[k as usize] > 0.0) as usize;
            continue;
        };
        compared += 1;
        let per_area = ppp / v.area;
        let half = [
            2.0 * tally.hits[0][m] as f64 * per_area,
            2.0 * tally.hits[1][m] as f64 * per_area,
        ];
        let mc = tally.total_hits(m) as f64 * per_area;
        let mc_direct = tally.first_hits[m] as f64 * per_area;
        let key = (v.depth.round() as u32, v.thickness.round() as u32);
        let s = bins.entry(key).or_default();
        let add = |s: &mut Sums, wgt: f64| {
            s.n += 1;
            s.mc += wgt * mc;
            s.mc_half[0] += wgt * half[0];
            s.mc_half[1] += wgt * half[1];
            s.mc_direct += wgt * mc_direct;
            s.sppg += wgt * v.sppg;
            s.spp += wgt * v.spp;
            s.ss += wgt * v.ss;
            s.lb += wgt * v.lb.unwrap_or(0.0);
            s.g += wgt * v.g;
            s.depth += wgt * v.depth;
            s.thickness += wgt * v.thickness;
            s.cos += wgt * v.cos;
        };
        add(s, 1.0);
        add(&mut weighted, v.area);
        total_area += v.area;
    }
    let categories: Vec<Category> = bins
        .iter()
        .filter(|(_, s)| s.n >= MIN_CATEGORY_MESHES)
        .map(|(&(d, w), s)| {
            let n = s.n as f64;
            Category {
                depth: d,
                thickness: w,
                meshes: s.n,
                mc: s.mc / n,
                mc_direct: s.mc_direct / n,
                sppg: s.sppg / n,
                spp: s.spp / n,
                ss: s.ss / n,
                lb: has_lb.then(|| s.lb / n),
                g: s.g / n,
            }
        })
        .collect();
    let rms = |f: &dyn Fn(&Category) -> f64| rms_dw(categories.iter().map(|c| (f(c), c.mc)));
    let halves = rms_dw(
        bins.values()
            .filter(|s| s.n >= MIN_CATEGORY_MESHES)
            .map(|s| {
                let n = s.n as f64;
                (s.mc_half[0] / n, s.mc_half[1] / n)
            }),
    );
    let errors = Errors {
        sppg: rms(&|c| c.sppg),
        spp: rms(&|c| c.spp),
        ss: rms(&|c| c.ss),
        lb: has_lb.then(|| rms(&|c| c.lb.unwrap_or(0.0))),
        sppg_radiance_reading: rms(&|c| c.sppg_radiance_reading()),
        spp_radiance_reading: rms(&|c| c.spp_radiance_reading()),
        // Half of the RMS difference between two independent halves: each half has twice
        // the variance of the whole, their difference four times.
        mc_noise: 0.5 * halves,
    };
    let a = total_area.max(f64::MIN_POSITIVE);
    let means = Means {
        mc: weighted.mc / a,
        mc_direct: weighted.mc_direct / a,
        sppg: weighted.sppg / a,
        spp: weighted.spp / a,
        ss: weighted.ss / a,
        lb: has_lb.then(|| weighted.lb / a),
        g: weighted.g / a,
    };
    let p = tally.photons as f64;
    let balance = PhotonBalance {
        photons: tally.photons,
        escaped: tally.escaped as f64 / p,
        absorbed_leaves: tally.absorbed_leaves as f64 / p,
        absorbed_wood: tally.absorbed_wood as f64 / p,
        unfinished: tally.unfinished as f64 / p,
        leaf_hits_per_photon: tally.leaf_hits as f64 / p,
        wood_hits_per_photon: tally.wood_hits as f64 / p,
    };
    let paper = match scene.instances.len() {
        0 => None,
        1 => Some(PAPER_TABLE3[0]),
        _ => Some(PAPER_TABLE3[1]),
    }
    .map(|(configuration, [sppg, spp, ss])| PaperRow {
        configuration,
        sppg,
        spp,
        ss,
    });
    timings.total = t_all.elapsed().as_secs_f64();
    TreeReport {
        scene: scene.name.clone(),
        instances: scene.instances.len(),
        prototypes: system.prototypes().len(),
        albedo: cfg.albedo,
        light: light.to_array(),
        seed: cfg.seed,
        leaf_meshes: meshes.total(),
        compared_meshes: compared,
        unmet_meshes: unmet,
        categories_used: categories.len(),
        meshes_in_categories: categories.iter().map(|c| c.meshes).sum(),
        mean_depth: weighted.depth / a,
        mean_thickness: weighted.thickness / a,
        mean_cos_light: weighted.cos / a,
        depth_rays: counts.ray_count,
        ray_spacing: counts.spacing,
        sample_directions: system.directions().len(),
        grid_cells: system.cells(),
        lb_grid: cfg.lb.map(|l| l.grid),
        errors,
        paper,
        means,
        balance,
        timings,
        categories,
    }
}
