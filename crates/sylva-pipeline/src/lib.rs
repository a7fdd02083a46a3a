//! The render pipeline as a library: load a scene ([`load_scene`], with a sun override), light
//! every model with LB (cached, on any [`LbSolver`]) and build the acceleration structure
//! ([`PreparedScene::new`]), then render frames of any camera and image region
//! ([`PreparedScene::render`]). Stages are `tracing` spans ([`sylva_render::stages`]); progress goes
//! to a [`Progress`] the caller implements (the CLI draws bars); nothing here prints.
//!
//! LB light comes one of two ways: solved per model for the scene's sun ([`ModelGridLight`],
//! cached per sun), or, with a [`RelightPlan`], combined per instance from each model's 19
//! base solutions and scaled by the coarse global grid ([`RelitLight`], paper 004); then
//! [`PreparedScene::set_sun`] moves the sun with no LB solve. Shadow rays go through the
//! top-level kd-tree or the sun-aligned grid ([`ShadowMethod`]).
//!
//! From a scene name to a PNG (docs/render.md, "The pipeline as a library"; compiled as a
//! doc-test, so it stays true):
//!
//! ```no_run
//! use std::path::Path;
//! use sylva_lb::CpuSolver;
//! use sylva_light::{Light, Silent};
//! use sylva_pipeline::{
//!     load_scene, tone_map_modes, write_images, LbPlan, PrepareOptions, PreparedScene,
//! };
//! use sylva_render::{Mode, ToneMap};
//!
//! let scene = load_scene("catalpa", None)?; // span "scene build"
//! let opts = PrepareOptions {
//!     lb: Some(LbPlan {
//!         solver: &CpuSolver, // or sylva_lb_gpu::select_solver(..)'s GPU solver
//!         grid: None,         // the scene's [lb] grid
//!         cache_dir: Some(Path::new("cache")),
//!         light: Light::Physical,
//!     }),
//!     largest_frame: Some((512, 512, 1)), // memory checked before any work
//!     ..PrepareOptions::default()
//! };
//! let prepared = PreparedScene::new(scene, &opts, &Silent)?; // LB light + kd-trees
//! let camera = prepared.camera(512, 512); // or any Camera
//! let frame = prepared.render(&prepared.settings(camera, 1, 1), &Silent)?;
//! let images = tone_map_modes(&frame, &[Mode::Full], &ToneMap::default());
//! write_images(Path::new("out.png"), frame.width, frame.height, &images, false)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod bands;
pub mod bases;
pub mod bench;
pub mod brf_images;
pub mod budget;
pub mod forest;
pub mod frame;
mod jobs;
pub mod models;
pub mod options;
pub mod physical;
pub mod report;
pub mod sequence;
pub mod spp;

pub use bases::precompute_relighting;
pub use forest::{forest_densities, light_forest, uses_forest, ForestDensities};
pub use frame::{RankWork, SplitFrame, UnitLayout};
pub use models::light_models;
pub use options::{
    costly_grid_warning, relight_light, BasisChoice, LightChoice, LightSettings, OptionError,
};
pub use physical::{precompute_physical, PhysicalBasisPlan, PhysicalRelighting};
pub use report::{basis_jobs, basis_scene_line, scene_line, written_line, RenderSummary};
pub use sylva_core::jobs::{Local, Runner};

use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::Serialize;
use sylva_core::cache::{Cache, CacheKey, CacheKind};
use sylva_core::{MemoryError, Sun};
use sylva_geom::{Camera, Scene};
use sylva_lb::{LbSolver, ParamError, Preset};
use sylva_scene::SceneError;
use sylva_trace::{KdTracer, RayQuery, SceneAccel, TraceError, TraversalConfig};
use sylva_trace_gpu::{GpuTracer, TraceGpuError};
use sylva_wgpu::GpuContext;

use sylva_lb::relight::{CompressTarget, RelightError};
use sylva_light::forest::ForestLight;
use sylva_light::indirect::{IndirectLight, ModelGridLight};
use sylva_light::lighting::{
    preset_medium, Illumination, Light, LightingError, LightingOptions, LightingSource, MediumKey,
    ModelLighting, ModelMediumKey, CACHE_VERSION, PAPER_OCCUPANCY,
};
use sylva_light::media::{prepare_medium, Media, MediumSolve};
pub use sylva_light::progress::{Progress, Silent};
use sylva_light::relight::{
    basis_density, BasisCacheOptions, GlobalGridOptions, GlobalInstance, GlobalLight, GlobalReport,
    ModelBasis, PhysicalRelitLight, PhysicalTarget, RelitIllumination, RelitLight, StoredBasis,
    StoredPhysicalBasis, SunWeights, GLOBAL_EXTENSION,
};
pub use sylva_light::relight::{BakeSummary, DEFAULT_BAKE_BUDGET};
use sylva_render::gpu_frame::{FrameError, GpuFrame};
use sylva_render::output::{encode_exr, encode_png, OutputError};
use sylva_render::render::{
    memory_needed, output_memory_needed, tile_count, Frame, Mode, RenderError, RenderSettings,
    Renderer,
};
use sylva_render::shade::{shade_materials, transmission_from_g, ShadeMaterial, ShadingParams};
use sylva_render::stages::stage;
use sylva_render::tonemap::{srgb8, ToneMap};
use sylva_trace::{SunGrid, SunGridQuery};

/// Largest image edge in pixels ([`sylva_core::limits::IMAGE_EDGE`], as in scene files).
pub const MAX_EDGE: u32 = *sylva_core::limits::IMAGE_EDGE.end();

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("the sun is {elevation:.1}° below the horizon: sylva lights scenes by the sun, so it must be at or above the horizon (elevation ≥ 0)")]
    SunBelowHorizon { elevation: f64 },
    #[error("resolution {width}x{height}: width and height must be 1 to {MAX_EDGE}")]
    Resolution { width: u32, height: u32 },
    #[error("scene {scene}: LB preset of {what}")]
    Preset {
        scene: String,
        /// `model 'NAME'` or `medium 'NAME'`.
        what: String,
        #[source]
        source: ParamError,
    },
    #[error("{0}")]
    Shading(String),
    #[error(transparent)]
    Memory(#[from] MemoryError),
    #[error("LB lighting of model '{model}'")]
    Lighting {
        model: String,
        #[source]
        source: LightingError,
    },
    #[error("medium '{medium}'")]
    Medium {
        medium: String,
        #[source]
        source: LightingError,
    },
    #[error("relighting scene {scene}")]
    Relit {
        scene: String,
        #[source]
        source: LightingError,
    },
    #[error("the global grid of scene {scene}")]
    Global {
        scene: String,
        #[source]
        source: LightingError,
    },
    #[error(
        "the scene's LB light was solved for one sun; moving the sun needs base solutions \
         (prepare with a relight plan, or run `sylva basis` first)"
    )]
    NeedsBasis,
    #[error(
        "--light {0}: these base solutions are the paper light's (004's boundary solves); the \
         physical light's are its light parts (precompute_physical, docs/relight.md)"
    )]
    BasisLight(&'static str),
    #[error(transparent)]
    Relight(#[from] RelightError),
    #[error(transparent)]
    Trace(#[from] TraceError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error("putting the scene on the GPU")]
    TraceGpu(#[from] TraceGpuError),
    #[error("the GPU failed while tracing ({0}); those rays were traced on the CPU, but the frame is not returned as a GPU frame")]
    GpuFailed(String),
    #[error(transparent)]
    Gpu(#[from] sylva_wgpu::GpuError),
    #[error("the plane-parallel light (003 §5)")]
    SppLight(#[source] sylva_spp::trees::TreeError),
    #[error(transparent)]
    Spp(#[from] sylva_spp::trees::TreeError),
    /// A job, the processes running them or the data between them failed.
    #[error(transparent)]
    Jobs(#[from] sylva_core::jobs::JobError),
    #[error(transparent)]
    Output(#[from] sylva_core::OutputError),
    #[error(transparent)]
    Budget(#[from] sylva_budget::BudgetError),
}

impl From<sylva_core::wire::WireError> for PipelineError {
    fn from(e: sylva_core::wire::WireError) -> PipelineError {
        PipelineError::Jobs(e.into())
    }
}

/// Where [`precompute_relighting`] leaves the relighting when several processes make it: at
/// the root alone (`sylva basis`: the root stores it), or on every process (a relit render).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RelightingAt {
    Root,
    Everywhere,
}

/// A scene by file or built-in name ([`load_scene`]), or else one tree of a built-in species
/// (`sylva spp trees red_maple`, `sylva bench spp`).
pub fn load_scene_or_species(name: &str) -> Result<Scene, PipelineError> {
    match load_scene(name, None) {
        Err(PipelineError::Scene(SceneError::NotFound(_))) => {
            Ok(sylva_scene::builtin_scenes::species_scene(name)?)
        }
        other => other,
    }
}

/// Loads a scene file or built-in scene by name and builds it; `sun` replaces its sun.
pub fn load_scene(name_or_path: &str, sun: Option<Sun>) -> Result<Scene, PipelineError> {
    let _span = tracing::info_span!(stage::SCENE_BUILD).entered();
    let mut scene = sylva_scene::load(name_or_path)?;
    if let Some(sun) = sun {
        scene.sun = sun;
    }
    // Below the horizon the ground hides the sun, but the LB boundary would light the
    // plants from below: refuse rather than render that.
    if scene.sun.to_sun().y < 0.0 {
        return Err(PipelineError::SunBelowHorizon {
            elevation: -scene.sun.elevation_deg(),
        });
    }
    Ok(scene)
}

/// The image size: `width` and `height` as given, the scene camera's where neither is, and
/// with only one of them the other from the camera's aspect ratio.
pub fn resolution(
    width: Option<u32>,
    height: Option<u32>,
    camera: &Camera,
) -> Result<(u32, u32), PipelineError> {
    let (w0, h0) = (camera.width as f64, camera.height as f64);
    let (w, h) = match (width, height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (w, ((w as f64 * h0 / w0).round() as u32).max(1)),
        (None, Some(h)) => (((h as f64 * w0 / h0).round() as u32).max(1), h),
        (None, None) => (camera.width, camera.height),
    };
    if w == 0 || h == 0 || w > MAX_EDGE || h > MAX_EDGE {
        return Err(PipelineError::Resolution {
            width: w,
            height: h,
        });
    }
    Ok((w, h))
}

/// LB lighting of every model.
#[derive(Clone, Copy)]
pub struct LbPlan<'a> {
    /// Where the solves run.
    pub solver: &'a dyn LbSolver,
    /// Sites along each model's longest edge; `None`: the scene's `[lb] grid`.
    pub grid: Option<usize>,
    /// The lighting cache; `None`: always solve, write nothing.
    pub cache_dir: Option<&'a std::path::Path>,
    /// The light model the grids are solved for (docs/light.md).
    pub light: Light,
}

/// When to use base solutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BasisUse {
    /// When every model's compressed basis is in the cache (and then no LB solve at all);
    /// otherwise the LB light is solved for the scene's sun as without a plan.
    IfCached,
    /// Always: missing bases are solved (and cached).
    Always,
}

/// Relighting from base solutions (paper 004).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelightPlan {
    pub basis: BasisUse,
    /// How the sun's direction becomes weights.
    pub sun: SunWeights,
    /// Ambient `B_0` scale (free-space value added to the sun's 1).
    pub ambient: f64,
    /// The coarse global grid; `None`: instances keep their fine light unscaled.
    pub global: Option<GlobalGridOptions>,
    /// What the cached bases are compressed to (the paper light's).
    pub target: CompressTarget,
    /// What the physical light's parts are compressed to (`None`: kept as solved).
    pub physical: Option<PhysicalTarget>,
    /// Also keep the uncompressed bases (for [`PreparedScene::use_uncompressed`]).
    pub keep_raw: bool,
}

impl Default for RelightPlan {
    /// Bases when cached, three-basis weights, no ambient, the global grid, the recommended
    /// compression.
    fn default() -> Self {
        RelightPlan {
            basis: BasisUse::IfCached,
            sun: SunWeights::ThreeBasis,
            ambient: 0.0,
            global: Some(GlobalGridOptions::default()),
            target: CompressTarget::recommended(),
            physical: Some(PhysicalTarget::recommended()),
            keep_raw: false,
        }
    }
}

/// What finds the occluders of shadow rays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ShadowMethod {
    /// The top-level kd-tree over the instances' boxes, as closest hits use.
    KdTree,
    /// The sun-aligned tile grid of 004 §4.1, rebuilt when the sun moves: the default, a few
    /// per cent faster on the canopy and equal on one tree (docs/PERFORMANCE.md). On a GPU
    /// tracer the GPU's kd-trees answer shadow rays whatever this says.
    #[default]
    SunGrid,
}

impl ShadowMethod {
    pub fn parse(s: &str) -> Option<ShadowMethod> {
        Some(match s {
            "kd" | "kdtree" | "kd-tree" => ShadowMethod::KdTree,
            "grid" | "sun-grid" => ShadowMethod::SunGrid,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            ShadowMethod::KdTree => "kd-tree",
            ShadowMethod::SunGrid => "sun-grid",
        }
    }
}

/// How [`PreparedScene::new`] prepares a scene.
#[derive(Clone, Copy)]
pub struct PrepareOptions<'a> {
    /// What runs the LB solves: this process ([`Local`], the default) or, under MPI, every
    /// process of the job (`sylva_mpi::QueueRunner`), each calling with the same options.
    pub runner: &'a dyn Runner,
    /// LB lighting; `None`: no indirect light on plants (the local-light mode needs none).
    pub lb: Option<LbPlan<'a>>,
    /// How the tracer walks its kd-trees (on either device).
    pub traversal: TraversalConfig,
    /// Trace rays on this GPU ([`GpuTracer`]); `None`: on the CPU ([`KdTracer`]).
    pub trace_gpu: Option<&'a GpuContext>,
    /// With `trace_gpu`, shade on the GPU too ([`GpuFrame`]: the whole frame in one kernel);
    /// otherwise (and for scenes with media) the GPU answers ray queries and the CPU shades.
    pub shade_on_gpu: bool,
    /// The light model (docs/light.md); the LB plan's is set to it.
    pub light: Light,
    /// Scale of the LB indirect light (1: as computed).
    pub indirect: f32,
    /// Paper light: sky light on the ground as a fraction of the sun's.
    pub sky_ambient: f32,
    /// Physical light: final-gather rays per camera sample on plants ([`sylva_render::gather`]).
    pub gather_rays: u32,
    /// The largest frame that will be rendered, `(width, height, rays per pixel)`: its memory
    /// is checked before any LB or acceleration work.
    pub largest_frame: Option<(u32, u32, u32)>,
    /// Images made from that frame (one per mode; `--mode all` makes four): their memory
    /// is checked with the frame's.
    pub output_images: usize,
    /// Relighting from base solutions (with `lb`); `None`: LB solved for the scene's sun.
    pub relight: Option<RelightPlan>,
    pub shadows: ShadowMethod,
    /// The physical light's coarse forest grid ([`sylva_light::forest`]) for scenes of more than
    /// one instance; `None`: each instance keeps its model's light in the open.
    pub forest: Option<GlobalGridOptions>,
    /// Where the models' kd-trees are cached (the LB cache's directory: `--cache-dir`);
    /// `None`: built on every preparation.
    pub accel_cache: Option<&'a Path>,
}

impl Default for PrepareOptions<'_> {
    fn default() -> Self {
        let s = ShadingParams::default();
        PrepareOptions {
            runner: &Local,
            lb: None,
            traversal: TraversalConfig::default(),
            trace_gpu: None,
            shade_on_gpu: true,
            light: s.light,
            indirect: s.indirect,
            sky_ambient: s.sky_ambient,
            gather_rays: s.gather_rays,
            largest_frame: None,
            output_images: 1,
            relight: None,
            shadows: ShadowMethod::default(),
            forest: Some(GlobalGridOptions::default()),
            accel_cache: None,
        }
    }
}

/// What answers a frame's ray queries: the CPU tracer, or the GPU tracer (which keeps the
/// CPU tracer over the same kd-trees).
pub enum Tracer {
    Cpu(Box<KdTracer>),
    Gpu(Box<GpuTracer>),
}

impl Tracer {
    /// The CPU tracer: the scene's kd-trees and their traversal (on the GPU too: it built
    /// them).
    pub fn cpu(&self) -> &KdTracer {
        match self {
            Tracer::Cpu(t) => t.as_ref(),
            Tracer::Gpu(t) => t.cpu(),
        }
    }

    pub fn query(&self) -> &dyn RayQuery {
        match self {
            Tracer::Cpu(t) => t.as_ref(),
            Tracer::Gpu(t) => t.as_ref(),
        }
    }

    /// `"cpu"` or `"gpu"`.
    pub fn device(&self) -> &'static str {
        match self {
            Tracer::Cpu(_) => "cpu",
            Tracer::Gpu(_) => "gpu",
        }
    }

    /// The GPU adapter's name (none on the CPU).
    pub fn adapter(&self) -> Option<String> {
        match self {
            Tracer::Cpu(_) => None,
            Tracer::Gpu(t) => Some(t.context().adapter_name().to_string()),
        }
    }

    /// One line for reports.
    pub fn describe(&self) -> String {
        match self {
            Tracer::Cpu(_) => format!("CPU, {} threads", rayon::current_num_threads()),
            Tracer::Gpu(t) => format!(
                "GPU {}, scene {} on the device",
                t.context().describe(),
                sylva_core::format_bytes(t.scene().device_bytes())
            ),
        }
    }

    pub fn gpu(&self) -> Option<&GpuTracer> {
        match self {
            Tracer::Cpu(_) => None,
            Tracer::Gpu(t) => Some(t),
        }
    }
}

/// The light around `scene`'s plants under its own sun of intensity 1
/// ([`illumination`]): what the LB grids are solved for.
pub fn scene_illumination(scene: &Scene) -> Illumination {
    illumination(
        scene,
        scene_to_sun(scene),
        ShadingParams::default().sun_irradiance,
    )
}

/// The light around `scene`'s plants: its sun ([`Scene::sun_rgb`], a 6500 K black body
/// unless bands set it) of irradiance `sun_irradiance` towards
/// `to_sun`, its sky and its ground.
pub fn illumination(scene: &Scene, to_sun: Vec3, sun_irradiance: f32) -> Illumination {
    let sun_colour = Vec3::from_array(scene.sun_rgb());
    Illumination {
        sun_to: to_sun,
        sun: sun_colour * sun_irradiance,
        sky: Vec3::from_array(scene.sky_color),
        ground: scene
            .ground
            .enabled
            .then(|| Vec3::from_array(scene.ground.color)),
    }
}

/// Every model's base solutions (compressed, and uncompressed when kept) and the global
/// grid: what [`precompute_relighting`] makes and [`PreparedScene::new`] relights with.
pub struct Relighting {
    pub compressed: Vec<Option<StoredBasis>>,
    pub raw: Vec<Option<StoredBasis>>,
    pub global: Option<GlobalLight>,
    /// Models whose basis came from the cache.
    pub cached: usize,
}

/// A scene ready to render: its LB lighting and acceleration structure built.
pub struct PreparedScene {
    pub scene: Scene,
    /// What traces the rays (the kd-trees, on the CPU or also on a GPU).
    pub tracer: Tracer,
    /// Per-model LB grids solved for the sun (none without LB, or when relit).
    pub light: ModelGridLight,
    /// The frame kernel when frames are shaded on the GPU (not for scenes with media:
    /// [`PreparedScene::gpu_shading_note`] says why not).
    pub gpu_frame: Option<GpuFrame>,
    /// The scene's media, ready to draw (LB-lit with an LB plan, else sun only).
    pub media: Media,
    /// Why frames traced on a GPU are shaded on the CPU, when they are.
    gpu_shading_note: Option<&'static str>,
    /// Whether frames are to be shaded on the GPU when the tracer is one
    /// ([`PrepareOptions::shade_on_gpu`]).
    shade_on_gpu: bool,
    /// Per-instance light from base solutions, when the scene was prepared with them.
    pub relit: Option<RelitLight>,
    /// The physical light relit from its base solutions, when the scene was prepared with
    /// them (a relight plan on the physical light).
    pub physical: Option<PhysicalRelitLight>,
    /// The stored fields not in use: the uncompressed bases while the compressed ones are,
    /// and the other way round ([`PreparedScene::use_uncompressed`]); the paper light's, and
    /// the physical light's.
    spare_bases: Vec<Option<StoredBasis>>,
    spare_physical: Vec<Option<StoredPhysicalBasis>>,
    /// Bytes of the physical light's parts uncompressed, when it is relit.
    pub physical_raw_bytes: u64,
    /// Bytes the physical light relit may decode per sun ([`PreparedScene::set_bake_budget`]).
    bake_budget: u64,
    uncompressed: bool,
    shadows: ShadowMethod,
    /// The sun-aligned shadow grid (CPU tracer only: a GPU tracer answers shadow rays with
    /// its kd-trees).
    sun_grid: Option<SunGrid>,
    /// Unit vector towards the sun.
    pub to_sun: Vec3,
    pub shading: ShadingParams,
    /// The models' materials decoded for shading.
    pub materials: Vec<Vec<ShadeMaterial>>,
    /// Models whose LB lighting came from the cache.
    pub lb_models_cached: usize,
    /// The physical light's forest grid, when the scene was lit through it.
    pub forest: Option<ForestLight>,
    /// Seconds the physical light's base solutions took, when they were solved now (or as
    /// their compressed cache entries recorded), and its forest grid's parts.
    pub basis_solve_seconds: Option<f64>,
    pub forest_basis_seconds: Option<f64>,
}

/// The unit vector towards the scene's sun.
pub fn scene_to_sun(scene: &Scene) -> Vec3 {
    let s = scene.sun.to_sun();
    Vec3::new(s.x as f32, s.y as f32, s.z as f32)
}

/// The lighting options of `lb` for `scene` (with the scene's preset: a model's own is
/// [`Scene::model_preset`]).
pub fn lighting_options(scene: &Scene, lb: &LbPlan) -> LightingOptions {
    LightingOptions {
        grid: lb.grid.unwrap_or(scene.lb.grid as usize),
        light: lb.light,
        preset: scene.lb.preset.clone(),
        cache_dir: lb.cache_dir.map(PathBuf::from),
    }
}

/// The scene's media ready to draw: each lit by its two LB solves (sun and sky, cached) when
/// `opts.lb` is given, else by the sun alone.
fn prepare_media(
    scene: &Scene,
    opts: &PrepareOptions,
    to_sun: Vec3,
    shading: &ShadingParams,
    progress: &dyn Progress,
) -> Result<Media, PipelineError> {
    // The same sun and sky as the plants' (the physical light's [`Illumination`]).
    let illum = illumination(scene, to_sun, shading.sun_irradiance);
    let (sun_colour, sky) = (illum.sun, illum.sky);
    let mut media = Media::default();
    {
        // The media's LB solves count as LB precompute (a second span after the models').
        let solves = opts.lb.is_some() && !scene.media.is_empty();
        let _span = solves.then(|| tracing::info_span!(stage::LB_PRECOMPUTE).entered());
        for medium in &scene.media {
            let _m = solves
                .then(|| tracing::info_span!(stage::LB_MODEL, model = %medium.name).entered());
            let lb = opts.lb.as_ref().map(|lb| MediumSolve {
                solver: lb.solver,
                cache_dir: lb.cache_dir,
            });
            if lb.is_some() {
                progress.start(&format!("LB {}", medium.name), 6);
            }
            let prepared = prepare_medium(
                medium,
                to_sun,
                sun_colour,
                sky,
                lb,
                &mut |solve, c, step, max| {
                    progress.set(((solve * 3 + c) * max + step) as u64, 6 * max as u64)
                },
            );
            progress.finish();
            let (volume, reports) = prepared.map_err(|source| PipelineError::Medium {
                medium: medium.name.clone(),
                source,
            })?;
            if !reports.is_empty() {
                progress.medium_lit(medium, &reports);
            }
            media.volumes.push(volume);
        }
    }
    Ok(media)
}

/// The LB light solved for a scene's own sun ([`solve_per_sun`]).
struct PerSunLight {
    models: Vec<ModelLighting>,
    /// Models whose light came from the cache.
    cached: usize,
    /// The forest grid's weights, when the scene is lit through it.
    forest: Option<ForestLight>,
}

/// Every model's LB light solved for `scene`'s sun (from the cache when it can): through the
/// physical light's forest grid `forest` when the scene uses one ([`uses_forest`]), else per
/// model in the open. What [`PreparedScene::new`] lights a scene with when it does not
/// relight, and what [`PreparedScene::per_sun_light`] solves for another sun.
fn solve_per_sun(
    scene: &Scene,
    lb: &LbPlan,
    forest: Option<&GlobalGridOptions>,
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<PerSunLight, PipelineError> {
    match forest {
        Some(gopts) if uses_forest(scene, lb.light, Some(gopts)) => {
            // Part of the LB stage (the voxelizing, or the cached densities, and the
            // neighbours' foliage), timed as such.
            let densities = {
                let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
                forest_densities(scene, lb, gopts, progress)?
            };
            let (models, cached, f) = light_forest(scene, lb, gopts, densities, runner, progress)?;
            Ok(PerSunLight {
                models,
                cached,
                forest: Some(f),
            })
        }
        _ => {
            let (models, cached) = light_models(scene, lb, runner, progress)?;
            Ok(PerSunLight {
                models,
                cached,
                forest: None,
            })
        }
    }
}

impl PreparedScene {
    /// Checks the frame's memory and the shading constants, lights every model (from the
    /// cache when it can: [`light_models`], [`light_forest`] or [`precompute_relighting`], as
    /// `opts` asks, the solves run by `opts.runner`) and builds the kd-trees. Under MPI every
    /// process calls it with the same scene and options and gets the same scene.
    pub fn new(
        scene: Scene,
        opts: &PrepareOptions,
        progress: &dyn Progress,
    ) -> Result<PreparedScene, PipelineError> {
        let shading = Self::check(&scene, opts)?;
        let runner = opts.runner;
        let none = || (0..scene.models.len()).map(|_| None).collect();
        let lb = opts.lb.as_ref().map(|lb| LbPlan {
            light: opts.light,
            ..*lb
        });
        let mut relit_parts = None;
        let mut physical = None;
        match (&lb, &opts.relight) {
            (Some(lb), Some(plan)) if lb.light == Light::Physical => {
                check_physical_plan(plan)?;
                physical = precompute_physical(
                    &scene,
                    lb,
                    &PhysicalBasisPlan {
                        basis: plan.basis,
                        target: plan.physical,
                        keep_raw: plan.keep_raw,
                    },
                    opts.forest.as_ref(),
                    runner,
                    progress,
                )?;
            }
            (Some(lb), Some(plan)) => {
                relit_parts = precompute_relighting(
                    &scene,
                    lb,
                    plan,
                    runner,
                    RelightingAt::Everywhere,
                    progress,
                )?;
            }
            _ => {}
        }
        let mut forest = None;
        let (lighting, cached) = match (&lb, &relit_parts, &physical) {
            (_, Some(parts), _) => (none(), parts.cached),
            (_, _, Some(p)) => (none(), p.cached),
            (Some(lb), None, None) => {
                let lit = solve_per_sun(&scene, lb, opts.forest.as_ref(), runner, progress)?;
                forest = lit.forest;
                (lit.models.into_iter().map(Some).collect(), lit.cached)
            }
            (None, _, _) => (none(), 0),
        };
        let mut prepared = Self::build(
            scene,
            opts,
            shading,
            lighting,
            cached,
            relit_parts,
            physical,
            forest.as_ref(),
            progress,
        )?;
        prepared.forest = forest;
        Ok(prepared)
    }

    /// What [`PreparedScene::new`] checks before any LB or acceleration work: the largest
    /// frame's memory, the scene's LB preset and the shading constants; the shading they
    /// give.
    pub fn check(scene: &Scene, opts: &PrepareOptions) -> Result<ShadingParams, PipelineError> {
        if let Some((w, h, rpp)) = opts.largest_frame {
            sylva_core::check_memory(
                &format!(
                    "a {w}x{h} frame at {rpp} rays/pixel and its {} image(s)",
                    opts.output_images
                ),
                memory_needed(w, h, rpp) + output_memory_needed(w, h, opts.output_images),
            )?;
        }
        for k in 0..scene.models.len() {
            Preset::parse(scene.model_preset(k)).map_err(|source| PipelineError::Preset {
                scene: scene.name.clone(),
                what: format!("model '{}'", scene.models[k].name),
                source,
            })?;
        }
        let preset = Preset::parse(&scene.lb.preset).map_err(|source| PipelineError::Preset {
            scene: scene.name.clone(),
            what: "[lb]".into(),
            source,
        })?;
        // The paper light's leaf T/R; the physical light's come from each material's optics.
        let g = preset.params().colours.map(|c| c.g as f32);
        let shading = ShadingParams {
            light: opts.light,
            indirect: opts.indirect,
            sky_ambient: opts.sky_ambient,
            gather_rays: opts.gather_rays,
            leaf_transmission: transmission_from_g(g),
            ..ShadingParams::default()
        };
        shading.validate().map_err(PipelineError::Shading)?;
        Ok(shading)
    }

    // The lighting comes in its three forms (per-model grids, their forest weights, relit
    // parts), each optional.
    #[allow(clippy::too_many_arguments)]
    fn build(
        scene: Scene,
        opts: &PrepareOptions,
        shading: ShadingParams,
        lighting: Vec<Option<ModelLighting>>,
        lb_models_cached: usize,
        relit_parts: Option<Relighting>,
        mut physical: Option<PhysicalRelighting>,
        forest: Option<&ForestLight>,
        progress: &dyn Progress,
    ) -> Result<PreparedScene, PipelineError> {
        let to_sun = scene_to_sun(&scene);
        let media = prepare_media(&scene, opts, to_sun, &shading, progress)?;
        let tracer = {
            let _span = tracing::info_span!(stage::ACCEL_BUILD).entered();
            let cache = opts.accel_cache.map(Cache::new);
            let (accel, report) = SceneAccel::build_cached(&scene, cache.as_ref())?;
            progress.kd_trees(report.cached, report.built, &report.warnings);
            let cpu = KdTracer::new(accel, opts.traversal);
            match opts.trace_gpu {
                Some(ctx) => Tracer::Gpu(Box::new(GpuTracer::new(ctx.clone(), cpu)?)),
                None => Tracer::Cpu(Box::new(cpu)),
            }
        };
        let mut light =
            ModelGridLight::new(lighting, &scene.models, tracer.cpu().accel.instances());
        if let Some(f) = forest {
            light = light.with_instance_weights(f.weights.clone());
        }
        let materials = shade_materials(&scene.models);
        let (relit, spare_bases) = match relit_parts {
            Some(parts) => {
                let plan = opts.relight.expect("relit parts come from a plan");
                let illumination = RelitIllumination::new(to_sun, plan.sun, plan.ambient);
                let relit = RelitLight::new(
                    parts.compressed,
                    &scene.models,
                    tracer.cpu().accel.instances(),
                    parts.global,
                    illumination,
                )?;
                (Some(relit), parts.raw)
            }
            None => (None, Vec::new()),
        };
        let basis_solve_seconds = physical.as_ref().and_then(|p| p.solve_seconds);
        let forest_basis_seconds = physical.as_ref().and_then(|p| p.forest_seconds);
        let physical_raw_bytes = physical.as_ref().map_or(0, |p| p.raw_bytes);
        let spare_physical: Vec<Option<StoredPhysicalBasis>> = match &mut physical {
            Some(p) => std::mem::take(&mut p.raw)
                .into_iter()
                .map(|b| b.map(StoredPhysicalBasis::Full))
                .collect(),
            None => Vec::new(),
        };
        let physical = match physical {
            Some(p) => Some(
                PhysicalRelitLight::new(
                    p.bases,
                    &scene.models,
                    tracer.cpu().accel.instances(),
                    p.forest,
                    illumination(&scene, to_sun, shading.sun_irradiance),
                )
                .map_err(|source| PipelineError::Relit {
                    scene: scene.name.clone(),
                    source,
                })?,
            ),
            None => None,
        };
        // The frame kernel shades with the light's device side; the media and a light without
        // one say why they cannot be shaded there (the GPU still answers their ray queries).
        let gpu_on = tracer.gpu().is_some() && opts.shade_on_gpu;
        let indirect: &dyn IndirectLight = match (&relit, &physical) {
            (Some(r), _) => r,
            (_, Some(p)) => p,
            _ => &light,
        };
        let device = media.device().and_then(|()| match &physical {
            // The kernel reads compressed bases decoded for the sun.
            Some(p) if gpu_on && relit.is_none() && p.decodes_for_device() => p
                .bake_for_device(DEFAULT_BAKE_BUDGET)
                .and_then(|_| indirect.device()),
            _ => indirect.device(),
        });
        let gpu_shading_note = match &device {
            Err(why) if gpu_on => Some(why.0),
            _ => None,
        };
        let gpu_frame = match (tracer.gpu(), device) {
            (Some(t), Ok(device)) if gpu_on => {
                let _span = tracing::info_span!(stage::ACCEL_BUILD).entered();
                Some(GpuFrame::new(t, &scene, &materials, device)?)
            }
            _ => None,
        };
        let sun_grid = match (&tracer, opts.shadows) {
            (Tracer::Cpu(t), ShadowMethod::SunGrid) => Some(SunGrid::build(&t.accel, to_sun)),
            _ => None,
        };
        Ok(PreparedScene {
            forest: None,
            basis_solve_seconds,
            forest_basis_seconds,
            materials,
            gpu_frame,
            gpu_shading_note,
            shade_on_gpu: opts.shade_on_gpu,
            tracer,
            light,
            media,
            relit,
            physical,
            spare_bases,
            spare_physical,
            physical_raw_bytes,
            uncompressed: false,
            bake_budget: DEFAULT_BAKE_BUDGET,
            shadows: opts.shadows,
            sun_grid,
            to_sun,
            shading,
            lb_models_cached,
            scene,
        })
    }

    /// Bytes the physical light relit may decode per sun for the frames that read it often
    /// (default [`DEFAULT_BAKE_BUDGET`]; 0: none, every lookup decodes the parts). From the
    /// next sun on (a sun already decoded keeps its decoding).
    pub fn set_bake_budget(&mut self, bytes: u64) {
        self.bake_budget = bytes;
    }

    /// What decoding the physical light relit for the current sun did, once a frame made
    /// it worthwhile ([`PhysicalRelitLight::bake_for_frame`]).
    pub fn bake_summary(&self) -> Option<BakeSummary> {
        self.physical
            .as_ref()
            .and_then(PhysicalRelitLight::bake_summary)
    }

    /// The indirect light frames use: the relit light when there is one, else the per-sun
    /// grids.
    pub fn indirect(&self) -> &dyn IndirectLight {
        match (&self.relit, &self.physical) {
            (Some(r), _) => r,
            (_, Some(p)) => p,
            _ => &self.light,
        }
    }

    /// Moves the sun (`to_sun`, towards it, any length): the relit light's weights are made
    /// again and the sun grid rebuilt. No LB solve; without base solutions an error (the
    /// per-sun LB light would need one), unless the scene has no LB light at all.
    pub fn set_sun(&mut self, to_sun: Vec3) -> Result<(), PipelineError> {
        let to_sun = to_sun.normalize_or_zero();
        if !(to_sun.is_finite() && to_sun != Vec3::ZERO) {
            return Err(PipelineError::Shading(format!(
                "sun direction {to_sun} must be a finite, non-zero vector"
            )));
        }
        if to_sun == self.to_sun {
            // Where it is already (a viewer's repeated request): nothing to relight.
            return Ok(());
        }
        match &mut self.relit {
            Some(r) => {
                let ill = RelitIllumination {
                    to_sun,
                    ..r.illumination()
                };
                r.relight(ill)?;
                if let Some(f) = &self.gpu_frame {
                    f.relight(&*r)?;
                }
            }
            None if self.physical.is_some() => {
                let p = self.physical.as_mut().expect("checked");
                let ill = Illumination {
                    sun_to: to_sun,
                    ..p.illumination()
                };
                p.relight(ill).map_err(|source| PipelineError::Relit {
                    scene: self.scene.name.clone(),
                    source,
                })?;
                self.refresh_physical_device(false)?;
            }
            None if (0..self.scene.models.len()).any(|m| self.light.model(m).is_some()) => {
                return Err(PipelineError::NeedsBasis);
            }
            None => {}
        }
        self.to_sun = to_sun;
        self.sun_grid = self.build_sun_grid();
        Ok(())
    }

    /// How the relit light forms its weights: the sun rule and the ambient scale.
    pub fn set_illumination(&mut self, sun: SunWeights, ambient: f64) -> Result<(), PipelineError> {
        let r = self.relit.as_mut().ok_or(PipelineError::NeedsBasis)?;
        r.relight(RelitIllumination::new(self.to_sun, sun, ambient))?;
        if let Some(f) = &self.gpu_frame {
            f.relight(&*r)?;
        }
        Ok(())
    }

    /// Shadow rays through the kd-tree or the sun grid (built now for the current sun).
    pub fn set_shadows(&mut self, method: ShadowMethod) {
        self.shadows = method;
        self.sun_grid = self.build_sun_grid();
    }

    /// The sun grid for the current sun when shadow rays use it (CPU tracer only).
    fn build_sun_grid(&self) -> Option<SunGrid> {
        match (&self.tracer, self.shadows) {
            (Tracer::Cpu(t), ShadowMethod::SunGrid) => Some(SunGrid::build(&t.accel, self.to_sun)),
            _ => None,
        }
    }

    /// Why frames traced on a GPU are shaded on the CPU, when they are: what the media or the
    /// indirect light answer for their device side ([`IndirectLight::device`]).
    pub fn gpu_shading_note(&self) -> Option<&'static str> {
        self.gpu_shading_note
    }

    pub fn shadows(&self) -> ShadowMethod {
        self.shadows
    }

    /// Whether uncompressed bases were kept beside compressed ones ([`RelightPlan::keep_raw`]).
    pub fn has_uncompressed(&self) -> bool {
        (self.relit.is_some() && self.spare_bases.iter().any(Option::is_some))
            || (self.physical.is_some() && self.spare_physical.iter().any(Option::is_some))
    }

    /// Relights from the uncompressed bases (`true`) or the compressed ones (`false`), for
    /// measuring what compression costs in the image. The fields are swapped, not copied.
    pub fn use_uncompressed(&mut self, yes: bool) -> Result<(), PipelineError> {
        if yes == self.uncompressed {
            return Ok(());
        }
        if !self.has_uncompressed() {
            return Err(PipelineError::Shading(
                "the scene was prepared without its uncompressed bases (keep_raw)".into(),
            ));
        }
        if let Some(p) = self.physical.as_mut() {
            let spare = std::mem::take(&mut self.spare_physical);
            self.spare_physical = p.swap_bases(spare).map_err(|source| PipelineError::Relit {
                scene: self.scene.name.clone(),
                source,
            })?;
            self.uncompressed = yes;
            // Other bases: the GPU frame packs them (or their decoding) again.
            self.refresh_physical_device(true)?;
            return Ok(());
        }
        let r = self.relit.as_mut().expect("checked above");
        let spare = std::mem::take(&mut self.spare_bases);
        self.spare_bases = r.swap_bases(spare)?;
        self.uncompressed = yes;
        if self.gpu_frame.is_some() {
            // Other fields: the GPU frame decodes and uploads them again.
            self.rebuild_gpu_frame()?;
        }
        Ok(())
    }

    /// The physical light's device side for its current sun, where frames are shaded on the
    /// GPU: compressed bases decoded for the sun (within the bake budget) and the frame's
    /// light words packed again over the uploaded ones (the frame made again when their size
    /// changed, or `rebuild`); uncompressed ones only their new terms. When the decoding does
    /// not cover every instance, frames are shaded on the CPU and the note says why (the next
    /// sun may fit again).
    fn refresh_physical_device(&mut self, rebuild: bool) -> Result<(), PipelineError> {
        let (Some(t), Some(p)) = (self.tracer.gpu(), &self.physical) else {
            return Ok(());
        };
        if !self.shade_on_gpu || self.media.device().is_err() {
            return Ok(());
        }
        // Compressed bases: decoded for the sun first, or refused beyond the budget.
        let decoded = if p.decodes_for_device() {
            p.bake_for_device(self.bake_budget).map(|_| ())
        } else {
            Ok(())
        };
        let device = match decoded.and_then(|()| p.device()) {
            Ok(d) => d,
            Err(why) => {
                self.gpu_frame = None;
                self.gpu_shading_note = Some(why.0);
                return Ok(());
            }
        };
        let current = match (&self.gpu_frame, rebuild) {
            (Some(f), false) if device.pool_per_sun() => f.repack(device)?,
            (Some(f), false) => {
                f.relight(device)?;
                true
            }
            _ => false,
        };
        if !current {
            let _span = tracing::info_span!(stage::ACCEL_BUILD).entered();
            self.gpu_frame = None;
            self.gpu_frame = Some(GpuFrame::new(t, &self.scene, &self.materials, device)?);
        }
        self.gpu_shading_note = None;
        Ok(())
    }

    /// The GPU frame made again for the current relit light (its fields or its ambient
    /// changed).
    fn rebuild_gpu_frame(&mut self) -> Result<(), PipelineError> {
        let (Some(t), Some(r)) = (self.tracer.gpu(), &self.relit) else {
            return Ok(());
        };
        self.gpu_frame = None;
        self.gpu_frame = Some(GpuFrame::new(t, &self.scene, &self.materials, r)?);
        Ok(())
    }

    /// The scene's camera at `width × height`.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        Camera {
            width,
            height,
            ..self.scene.camera
        }
    }

    /// The whole image of `camera` with the prepared shading.
    pub fn settings(&self, camera: Camera, rays_per_pixel: u32, seed: u64) -> RenderSettings {
        RenderSettings::full(camera, rays_per_pixel, seed, self.shading)
    }

    /// The renderer over this scene's tracer, its indirect light (relit or per-sun grids) and
    /// media, lit by the 6500 K sun.
    pub fn renderer(&self) -> Renderer<'_> {
        self.renderer_over(self.tracer.query(), self.indirect())
    }

    /// The renderer over this scene's tracer with another indirect light (the plane-parallel
    /// light of `sylva-spp`, or paper 000's per-sun grids beside the relit light), lit by the
    /// 6500 K sun.
    pub fn renderer_with<'a>(&'a self, light: &'a dyn IndirectLight) -> Renderer<'a> {
        self.renderer_over(self.tracer.query(), light)
    }

    /// The renderer answering its ray queries with `query`, lit indirectly by `light`.
    fn renderer_over<'s>(
        &'s self,
        query: &'s dyn RayQuery,
        light: &'s dyn IndirectLight,
    ) -> Renderer<'s> {
        let sun_colour = Vec3::from_array(self.scene.sun_rgb());
        Renderer::new(
            &self.scene,
            query,
            light,
            &self.materials,
            self.to_sun,
            sun_colour,
            self.shading.sun_irradiance,
        )
        .with_media(&self.media)
    }

    /// Renders one frame (any camera, any region of its image), reporting tiles as they
    /// finish each pass (3 × [`tile_count`] units). Shadow rays go as [`ShadowMethod`] says.
    pub fn render(
        &self,
        settings: &RenderSettings,
        progress: &dyn Progress,
    ) -> Result<Frame, PipelineError> {
        self.render_frame(None, settings, progress)
    }

    /// [`PreparedScene::render`] with another indirect light. The GPU frame shades with the
    /// scene's own LB grids, so another light is shaded on the CPU (rays still go to the
    /// GPU tracer when there is one).
    pub fn render_with(
        &self,
        light: &dyn IndirectLight,
        settings: &RenderSettings,
        progress: &dyn Progress,
    ) -> Result<Frame, PipelineError> {
        self.render_frame(Some(light), settings, progress)
    }

    fn render_frame(
        &self,
        light: Option<&dyn IndirectLight>,
        settings: &RenderSettings,
        progress: &dyn Progress,
    ) -> Result<Frame, PipelineError> {
        let _span = tracing::info_span!(stage::FRAME).entered();
        progress.start("render", 3 * tile_count(settings.region));
        let advance = |n| progress.advance(n);
        let frame = match (light, &self.gpu_frame, self.tracer.gpu()) {
            (None, Some(gpu_frame), Some(tracer)) => {
                // Pixels the kernel hands back are rendered by the CPU tracer and shading.
                let cpu = self.renderer_over(self.tracer.cpu(), self.indirect());
                match gpu_frame.render(tracer, &cpu, settings, &advance) {
                    Ok(f) => Ok(f),
                    Err(FrameError::Render(e)) => Err(e),
                    Err(FrameError::Gpu(e)) => return Err(e.into()),
                }
            }
            (light, _, _) => {
                if light.is_none() {
                    self.decode_light_for(settings);
                }
                let light = light.unwrap_or(self.indirect());
                match (&self.tracer, &self.sun_grid) {
                    (Tracer::Cpu(cpu), Some(grid)) => {
                        let query = SunGridQuery::new(cpu, grid);
                        self.renderer_over(&query, light).render(settings, &advance)
                    }
                    _ => self
                        .renderer_over(self.tracer.query(), light)
                        .render(settings, &advance),
                }
            }
        };
        progress.finish();
        if let Some(e) = self.tracer.gpu().and_then(GpuTracer::take_error) {
            return Err(PipelineError::GpuFailed(e));
        }
        Ok(frame?)
    }

    /// Before a frame shaded on the CPU with the scene's own light: the relit light decoded
    /// once for this sun when the frame reads it often enough
    /// ([`PhysicalRelitLight::bake_for_frame`]). Counted over the whole image, not the
    /// frame's region, so every part of a frame split across processes or strips decides
    /// alike (a decoded compressed light differs from its lookups within the codec's error).
    pub(crate) fn decode_light_for(&self, settings: &RenderSettings) {
        if let Some(p) = &self.physical {
            let lookups = u64::from(settings.camera.width)
                * u64::from(settings.camera.height)
                * u64::from(settings.rays_per_pixel)
                * (1 + u64::from(settings.shading.gather_rays));
            p.bake_for_frame(lookups, self.bake_budget);
        }
    }

    /// Bytes of the LB light (per-sun grids or stored bases in use) and the media's volumes.
    pub fn lighting_bytes(&self) -> u64 {
        self.indirect().memory_bytes() + self.media.memory_bytes()
    }

    /// The LB light solved for the sun towards `to_sun` as a scene that does not relight is
    /// lit ([`PreparedScene::new`] without a relight plan: per model for the sun in the
    /// world's frame, through the forest grid `forest` when the scene uses one), from `lb`'s
    /// cache when it can. What relit frames are measured against (`sylva bench relight
    /// --against-direct`); render it with [`PreparedScene::render_with`] after
    /// [`PreparedScene::set_sun`] to the same sun.
    pub fn per_sun_light(
        &self,
        to_sun: Vec3,
        lb: &LbPlan,
        forest: Option<&GlobalGridOptions>,
        progress: &dyn Progress,
    ) -> Result<ModelGridLight, PipelineError> {
        let to_sun = to_sun.normalize_or_zero();
        let mut scene = self.scene.clone();
        scene.sun = Sun::from_direction(to_sun.x as f64, to_sun.y as f64, to_sun.z as f64)
            .map_err(|e| PipelineError::Shading(format!("sun direction {to_sun}: {e}")))?;
        if scene.sun.to_sun().y < 0.0 {
            return Err(PipelineError::SunBelowHorizon {
                elevation: -scene.sun.elevation_deg(),
            });
        }
        let lit = solve_per_sun(&scene, lb, forest, &Local, progress)?;
        let light = ModelGridLight::new(
            lit.models.into_iter().map(Some).collect(),
            &scene.models,
            self.tracer.cpu().accel.instances(),
        );
        Ok(match lit.forest {
            Some(f) => light.with_instance_weights(f.weights),
            None => light,
        })
    }
}

/// What a relight plan may ask of the physical light: its sun's parts are weighed by the
/// polyhedron face (the exact weights are the paper light's boundary sun's) and its sky is
/// the scene's (the paper light's ambient `B_0` has no meaning there).
fn check_physical_plan(plan: &RelightPlan) -> Result<(), PipelineError> {
    if plan.sun != SunWeights::ThreeBasis {
        return Err(PipelineError::Shading(format!(
            "--sun-weights {}: the physical light's sun parts are weighed by the face its \
             direction crosses (three-basis); the exact weights are the paper light's \
             (--light paper)",
            plan.sun.name()
        )));
    }
    if plan.ambient != 0.0 {
        return Err(PipelineError::Shading(format!(
            "--ambient {}: the physical light's sky is the scene's own (sky_color); the \
             ambient base solution is the paper light's (--light paper)",
            plan.ambient
        )));
    }
    Ok(())
}

/// The lighting options of `lb` for `scene` and, per model, how its basis is made and kept
/// (each model's medium is its own preset's, [`Scene::model_preset`]). Base solutions are the
/// paper light's: any other light is refused.
pub fn relight_options(
    scene: &Scene,
    lb: &LbPlan,
    plan: &RelightPlan,
) -> Result<(LightingOptions, Vec<BasisCacheOptions>), PipelineError> {
    if lb.light != Light::Paper {
        return Err(PipelineError::BasisLight(lb.light.name()));
    }
    let lopts = lighting_options(scene, lb);
    let bopts = (0..scene.models.len())
        .map(|k| BasisCacheOptions {
            target: plan.target,
            keep_raw: plan.keep_raw,
            ..BasisCacheOptions::new(&lopts.for_model(scene, k))
        })
        .collect();
    Ok((lopts, bopts))
}

/// Every model's basis (in scene order; `cached` of them from the cache) and, as `plan`
/// asks, the scene's global grid (from the cache, or solved and cached): the relighting a
/// scene is prepared with. The end of the one-process and the distributed precompute alike.
pub fn finish_relighting(
    scene: &Scene,
    lopts: &LightingOptions,
    plan: &RelightPlan,
    mut bases: Vec<ModelBasis>,
    cached: usize,
    progress: &dyn Progress,
) -> Result<Relighting, PipelineError> {
    assert_eq!(bases.len(), scene.models.len(), "one basis per model");
    let global = match plan.global {
        Some(gopts) => Some(global_grid(scene, lopts, &gopts, &mut bases, progress)?),
        None => None,
    };
    let mut compressed = Vec::with_capacity(bases.len());
    let mut raw = Vec::with_capacity(bases.len());
    for b in bases {
        compressed.push(Some(StoredBasis::Compressed(b.compressed)));
        raw.push(b.raw.map(StoredBasis::Full));
    }
    Ok(Relighting {
        compressed,
        raw,
        global,
        cached,
    })
}

/// A scene's global grid ([`global_key`]).
pub const GLOBAL_GRID: CacheKind = CacheKind {
    name: "global grid",
    version: CACHE_VERSION,
};

/// Everything a scene's global grid depends on: its models (as their fine grids depend on
/// them: geometry, materials, grid size, medium), the coarse grid's own medium and size, and
/// every instance's model and transform.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct GlobalGridKey {
    models: Vec<GlobalModelKey>,
    /// The coarse grid's medium: the scene's preset, its parameters when it names one.
    preset: String,
    medium: Option<MediumKey>,
    sites: usize,
    instances: Vec<InstanceKey>,
}

/// A model of the global grid: its fine grid's inputs, or the preset name that has none (the
/// solve then fails with that name).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) enum GlobalModelKey {
    Fine(Box<ModelMediumKey>),
    UnknownPreset(String),
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct InstanceKey {
    model: u32,
    position: [f32; 3],
    rotation_deg: f32,
    scale: f32,
}

impl GlobalGridKey {
    fn new(scene: &Scene, lopts: &LightingOptions, gopts: &GlobalGridOptions) -> GlobalGridKey {
        let medium = |preset: &str| Preset::parse(preset).map(|p| p.params()).ok();
        GlobalGridKey {
            models: scene
                .models
                .iter()
                .enumerate()
                .map(|(k, model)| {
                    let preset = scene.model_preset(k);
                    match medium(preset) {
                        Some(m) => GlobalModelKey::Fine(Box::new(ModelMediumKey::new(
                            model,
                            lopts.grid,
                            &m,
                            PAPER_OCCUPANCY,
                        ))),
                        None => GlobalModelKey::UnknownPreset(preset.to_string()),
                    }
                })
                .collect(),
            preset: lopts.preset.clone(),
            medium: medium(&lopts.preset).map(|m| MediumKey::new(&m)),
            sites: gopts.sites,
            instances: scene
                .instances
                .iter()
                .map(|i| InstanceKey {
                    model: i.model,
                    position: i.position.to_array(),
                    rotation_deg: i.rotation_deg,
                    scale: i.scale,
                })
                .collect(),
        }
    }
}

/// The cache key of a scene's global grid ([`GlobalGridKey`]).
pub fn global_key(scene: &Scene, lopts: &LightingOptions, gopts: &GlobalGridOptions) -> CacheKey {
    CacheKey::new(GLOBAL_GRID, &GlobalGridKey::new(scene, lopts, gopts))
}

/// The global grid from the cache, or solved (voxelizing the models whose density grids this
/// run did not make) and cached.
fn global_grid(
    scene: &Scene,
    lopts: &LightingOptions,
    gopts: &GlobalGridOptions,
    bases: &mut [ModelBasis],
    progress: &dyn Progress,
) -> Result<GlobalLight, PipelineError> {
    let t0 = std::time::Instant::now();
    let key = global_key(scene, lopts, gopts);
    let cache = lopts.cache_dir.as_ref().map(Cache::new);
    let path = cache.as_ref().map(|c| {
        c.entry(
            &format!("{}-global", sylva_core::file_stem(&scene.name, "scene")),
            key,
            GLOBAL_EXTENSION,
        )
    });
    let mut solve = || -> Result<GlobalLight, PipelineError> {
        solve_global_grid(scene, lopts, gopts, bases, progress)
    };
    let (g, source, cache_warning) = match (&cache, &path) {
        (Some(cache), Some(p)) => {
            let got = cache.get_or_compute(
                p,
                |p| GlobalLight::read(p, key, scene.instances.len()),
                solve,
                |g, p| g.write(p, key),
            )?;
            (got.value, got.outcome.into(), got.write_warning)
        }
        _ => (solve()?, LightingSource::Computed, None),
    };
    progress.global_grid(&GlobalReport {
        what: "global grid",
        source,
        seconds: t0.elapsed().as_secs_f64(),
        dims: g.dims,
        path,
        cache_warning,
    });
    Ok(g)
}

/// Solves the global grid, voxelizing the models whose density grids this run did not make.
fn solve_global_grid(
    scene: &Scene,
    lopts: &LightingOptions,
    gopts: &GlobalGridOptions,
    bases: &mut [ModelBasis],
    progress: &dyn Progress,
) -> Result<GlobalLight, PipelineError> {
    let err = |source| PipelineError::Global {
        scene: scene.name.clone(),
        source,
    };
    for (b, model) in bases.iter_mut().zip(&scene.models) {
        if b.density.is_none() {
            b.density = Some(basis_density(model, lopts.grid).map_err(err)?);
        }
    }
    let medium = preset_medium(&lopts.preset).map_err(err)?;
    let instances: Vec<GlobalInstance> = scene
        .instances
        .iter()
        .map(|i| GlobalInstance {
            density: bases[i.model as usize].density.as_ref(),
            to_world: i.transform(),
        })
        .collect();
    progress.start("global grid", 18);
    let g = GlobalLight::solve(&instances, &medium, gopts, &mut |done, total| {
        progress.set(done as u64, total as u64)
    });
    progress.finish();
    g.map_err(err)
}

/// One mode's image: linear HDR and tone-mapped 8-bit sRGB, pixel for pixel.
#[derive(Debug, Clone)]
pub struct ModeImage {
    pub mode: Mode,
    pub hdr: Vec<[f32; 3]>,
    pub ldr: Vec<[u8; 3]>,
}

/// The images of `modes`, tone mapped with `tm`. Several modes share the full image's
/// exposure so they compare (000 Fig. 2); one mode is exposed for itself.
pub fn tone_map_modes(frame: &Frame, modes: &[Mode], tm: &ToneMap) -> Vec<ModeImage> {
    let _span = tracing::info_span!(stage::TONE_MAPPING).entered();
    let full = frame.compose(Mode::Full);
    let exposure = tm.measure(&full);
    modes
        .iter()
        .map(|&mode| {
            let hdr = if mode == Mode::Full {
                full.clone()
            } else {
                frame.compose(mode)
            };
            let stats = if modes.len() > 1 {
                exposure
            } else {
                tm.measure(&hdr)
            };
            let ldr = tm.apply_with(&hdr, stats).into_iter().map(srgb8).collect();
            ModeImage { mode, hdr, ldr }
        })
        .collect()
}

/// `out.png` → `out-<mode>.png` for modes other than full, and for every mode of a set.
pub fn mode_path(base: &Path, mode: Mode, several: bool) -> PathBuf {
    if mode == Mode::Full && !several {
        return base.to_path_buf();
    }
    let stem = base.file_stem().unwrap_or_default().to_string_lossy();
    let ext = base
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "png".into());
    base.with_file_name(format!("{stem}-{}.{ext}", mode.name()))
}

/// The files [`write_images`] wrote for one mode.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenImage {
    pub mode: Mode,
    pub png: PathBuf,
    pub exr: Option<PathBuf>,
}

/// The files [`write_images`] writes for `modes` from `base`: each mode's PNG and, with
/// `hdr`, its EXR.
pub fn image_paths(base: &Path, modes: &[Mode], hdr: bool) -> Vec<PathBuf> {
    let several = modes.len() > 1;
    let mut paths = Vec::new();
    for &mode in modes {
        let png = mode_path(base, mode, several);
        if hdr {
            paths.push(png.with_extension("exr"));
        }
        paths.push(png);
    }
    paths
}

/// Refuses an image name `path` that is not a PNG (a render writes PNGs, and with `--hdr`
/// an EXR beside each).
pub fn check_png_name(path: &Path) -> Result<(), OptionError> {
    let ext = path.extension().map(|e| e.to_ascii_lowercase());
    if ext.as_deref() != Some(std::ffi::OsStr::new("png")) {
        return Err(OptionError(format!(
            "{}: the output is a PNG file (name it .png; --hdr adds an .exr beside it)",
            path.display()
        )));
    }
    Ok(())
}

/// Checks the files [`write_images`] will write from `base` before the render: none named
/// twice, none an input, each writable.
pub fn plan_images(base: &Path, modes: &[Mode], hdr: bool) -> Result<(), sylva_core::OutputError> {
    sylva_core::OutputSet::new::<&Path>(&[]).plan(&image_paths(base, modes, hdr))
}

/// Writes each mode's PNG (named by [`mode_path`] from `base`) and, with `hdr`, its EXR
/// beside it, as one output set: every file is replaced, or (on an error or Ctrl-C) none.
pub fn write_images(
    base: &Path,
    width: u32,
    height: u32,
    images: &[ModeImage],
    hdr: bool,
) -> Result<Vec<WrittenImage>, OutputError> {
    let _span = tracing::info_span!(stage::IMAGE_OUTPUT).entered();
    let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
    let modes: Vec<Mode> = images.iter().map(|i| i.mode).collect();
    set.plan(&image_paths(base, &modes, hdr))?;
    let mut written = Vec::with_capacity(images.len());
    for image in images {
        let png = mode_path(base, image.mode, images.len() > 1);
        let exr = if hdr {
            let exr = png.with_extension("exr");
            // One encoded image in memory at a time.
            set.write_bytes(&exr, &encode_exr(&exr, width, height, &image.hdr)?)?;
            Some(exr)
        } else {
            None
        };
        set.write_bytes(&png, &encode_png(&png, width, height, &image.ldr)?)?;
        written.push(WrittenImage {
            mode: image.mode,
            png,
            exr,
        });
    }
    set.commit()?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_core::cache::assert_each_field_changes_the_key;
    use sylva_light::lighting::{model_medium_variants, sample_model_medium_key};

    #[test]
    fn global_grid_key_changes_with_every_field() {
        let instance = InstanceKey {
            model: 0,
            position: [1.0, 0.0, -2.0],
            rotation_deg: 30.0,
            scale: 1.0,
        };
        let base = GlobalGridKey {
            models: vec![
                GlobalModelKey::Fine(Box::new(sample_model_medium_key())),
                GlobalModelKey::UnknownPreset("granite".into()),
            ],
            preset: "leaf".into(),
            medium: Some(MediumKey::new(&Preset::Leaf.params())),
            sites: 64,
            instances: vec![instance.clone(); 2],
        };
        let instances = |f: &dyn Fn(&mut InstanceKey)| {
            let mut i = instance.clone();
            f(&mut i);
            GlobalGridKey {
                instances: vec![instance.clone(), i],
                ..base.clone()
            }
        };
        let mut variants: Vec<(String, GlobalGridKey)> = vec![
            (
                "preset".into(),
                GlobalGridKey {
                    preset: "dogrose".into(),
                    ..base.clone()
                },
            ),
            (
                "medium".into(),
                GlobalGridKey {
                    medium: Some(MediumKey::new(&Preset::Dogrose.params())),
                    ..base.clone()
                },
            ),
            (
                "sites".into(),
                GlobalGridKey {
                    sites: 65,
                    ..base.clone()
                },
            ),
            (
                "unknown preset".into(),
                GlobalGridKey {
                    models: vec![
                        base.models[0].clone(),
                        GlobalModelKey::UnknownPreset("basalt".into()),
                    ],
                    ..base.clone()
                },
            ),
            (
                "instance count".into(),
                GlobalGridKey {
                    instances: vec![instance.clone()],
                    ..base.clone()
                },
            ),
            ("instance model".into(), instances(&|i| i.model = 1)),
            (
                "instance position".into(),
                instances(&|i| i.position[1] = 0.5),
            ),
            (
                "instance rotation".into(),
                instances(&|i| i.rotation_deg = 31.0),
            ),
            ("instance scale".into(), instances(&|i| i.scale = 1.5)),
        ];
        for (name, m) in model_medium_variants() {
            variants.push((
                format!("model: {name}"),
                GlobalGridKey {
                    models: vec![GlobalModelKey::Fine(Box::new(m)), base.models[1].clone()],
                    ..base.clone()
                },
            ));
        }
        let named: Vec<(&str, GlobalGridKey)> = variants
            .iter()
            .map(|(n, k)| (n.as_str(), k.clone()))
            .collect();
        assert_each_field_changes_the_key(GLOBAL_GRID, &base, &named);
    }
}
