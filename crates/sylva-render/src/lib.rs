//! The renderer of sylva (SPEC §2, paper 000 §3-4.3): from a scene to an image. Owns the
//! render pipeline; the `sylva` command only parses arguments, draws progress and prints.
//!
//! * [`pipeline`]: the pipeline as a library. [`load_scene`] (with a sun override),
//!   [`PreparedScene::new`] (LB lighting of every model, cached, on any
//!   [`sylva_lb::LbSolver`]; the kd-trees, traced on the CPU or a GPU: [`Tracer`]),
//!   [`PreparedScene::render`] (any camera, any image region), [`tone_map_modes`] and
//!   [`write_images`]; progress through [`Progress`].
//! * [`lighting`]: per model, the LB lighting grid (voxelize, solve, cache on disk) and its
//!   trilinear lookup in model space; the light models ([`Light`]: physical, the default, and
//!   paper 000's) and the plant medium from the materials' optics (docs/light.md).
//! * [`media`]: participating media (clouds): the volume tracer, its shadow volume and the
//!   LB light it samples ([`Media`]).
//! * [`relight`]: paper 004 in the renderer: per model the 19 base solutions (jobs on any
//!   solver, compressed, cached), the weights of an instance for the sun in its model space,
//!   the coarse global grid, and [`RelitLight`], which moves the sun without an LB solve.
//! * [`indirect`]: [`IndirectLight`], the light scattered in the canopy as shading needs it,
//!   and [`ModelGridLight`], one LB grid per model.
//! * [`shade`]: local sunlight (two-sided leaves reflecting and transmitting) and the
//!   indirect, albedo and sky parts the comparison modes combine.
//! * [`gather`]: the final gather on plants: its ray directions.
//! * [`render`]: primary rays, shadow rays (through a [`sylva_trace::RayQuery`]) and
//!   shading over 8×8 tiles; the modes of 000 Fig. 2.
//! * [`gpu_frame`]: the same frame on a GPU, one kernel per band (`shade.wgsl` mirrors the
//!   CPU's shading function by function).
//! * [`tonemap`]: Reinhard's global operator and sRGB encoding.
//! * [`output`]: PNG (8-bit sRGB), animated PNG and EXR (linear) files, written atomically.
//! * [`stages`]: the stages as `tracing` spans and [`StageClock`], which times them.

pub mod forest;
pub mod gather;
pub mod gpu_frame;
pub mod indirect;
pub mod lighting;
pub mod media;
pub mod output;
pub mod pipeline;
pub mod relight;
pub mod render;
pub mod shade;
pub mod stages;
pub mod tonemap;

pub use indirect::{IndirectLight, ModelGridLight, NoIndirectLight};
pub use lighting::{Illumination, Light};
pub use media::{Media, MediumVolume, Segment};
pub use pipeline::{
    finish_relighting, forest_densities, global_key, illumination, image_paths, light_models,
    lighting_options, load_scene, mode_path, precompute_relighting, relight_options, resolution,
    scene_illumination, scene_to_sun, tone_map_modes, uses_forest, write_images, BasisUse,
    ForestDensities, LbPlan, ModeImage, PipelineError, PrepareOptions, PreparedScene, Progress,
    RelightPlan, Relighting, ShadowMethod, Silent, Tracer, WrittenImage,
};
pub use relight::{RelitIllumination, RelitLight, SunWeights};
pub use render::{
    mean_luminance, Frame, FrameTimings, Mode, Region, RenderError, RenderSettings, Renderer,
};
pub use shade::{Radiance, ShadingParams};
pub use stages::{stage, StageClock};
pub use tonemap::ToneMap;
