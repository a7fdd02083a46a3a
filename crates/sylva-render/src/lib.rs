//! The renderer of sylva (SPEC §2, paper 000 §3-4.3): frames of any camera and image region
//! from traced rays and a light ([`sylva_light::IndirectLight`]), on the CPU or a GPU.
//!
//! * [`render`]: primary rays, shadow rays (through a [`sylva_trace::RayQuery`]) and
//!   shading over 8×8 tiles; the modes of 000 Fig. 2.
//! * [`shade`]: local sunlight (two-sided leaves reflecting and transmitting) and the
//!   indirect, albedo and sky parts the comparison modes combine.
//! * [`gather`]: the final gather on plants: its ray directions.
//! * [`gpu_frame`]: the same frame on a GPU, one kernel per band (`shade.wgsl` mirrors the
//!   CPU's shading function by function).
//! * [`tonemap`]: Reinhard's global operator and sRGB encoding.
//! * [`output`]: PNG (8-bit sRGB), animated PNG and EXR (linear) files, written atomically.
//! * [`stages`]: the stages as `tracing` spans and [`StageClock`], which times them.
//!
//! May import the leaf crates, the tracers and `sylva-light`; never scene files or the
//! pipeline (`sylva-pipeline` drives the renderer).

pub mod gather;
pub mod gpu_frame;
pub mod output;
pub mod render;
pub mod sequence;
pub mod shade;
pub mod stages;
pub mod tonemap;

pub use render::{
    mean_luminance, plant_coverage, Frame, FrameTimings, Mode, Region, RenderError, RenderSettings,
    Renderer,
};
pub use shade::{Radiance, ShadingParams};
pub use stages::{stage, StageClock};
pub use tonemap::ToneMap;
