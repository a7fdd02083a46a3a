//! The lattice-Boltzmann lighting solver on GPUs, through wgpu compute shaders (WGSL), as
//! paper 002 §3.1 ran it with OpenCL.
//!
//! Owns adapter choice ([`GpuContext`]: hardware only, or any adapter including software
//! ones such as Mesa's lavapipe), the generated kernels ([`shader`]), the device-side lattice
//! ([`GpuLattice`]) and the three-colour driver ([`solve_lighting_gpu`]). The physics is
//! sylva-lb's: Ω is built on the host by `sylva_lb::collision` and uploaded in the cubic
//! factorised form of `sylva_lb::kernel::CubicOmega`; the site codes (green ρ, brown -ρ,
//! shell 0), `f_0` zeroing, boundary shell, stop rules and [`sylva_lb::SolveReport`] are the
//! CPU solver's, which is the oracle the tests compare against.
//!
//! State: two copies (ping-pong) of 19 values per site, direction-major with z fastest,
//! f32 or f16 ([`Precision`]); each copy is split over several storage bindings when one
//! binding cannot hold it (128 MiB on lavapipe). See docs/gpu.md.

pub mod context;
pub mod lattice;
pub mod shader;

pub use context::{AdapterChoice, ContextOptions, GpuContext};
/// The wgpu version this crate is built on (for [`ContextOptions::backends`]).
pub use wgpu;

pub use lattice::{device_memory_needed, solve_lighting_gpu, GpuLattice, Precision};

use thiserror::Error;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error("no {} adapter found (adapters seen: {seen}); {}", if *hardware_only { "hardware GPU" } else { "GPU" }, if *hardware_only { "use --device gpu to allow a software adapter such as lavapipe" } else { "install a Vulkan driver (e.g. mesa-vulkan-drivers for lavapipe) or use --device cpu" })]
    NoAdapter { hardware_only: bool, seen: String },
    #[error("cannot open a device on adapter '{adapter}': {message}")]
    Device { adapter: String, message: String },
    #[error("adapter '{0}' lacks SHADER_F16: f16 state storage is unavailable, use f32")]
    F16Unsupported(String),
    #[error("grid too large for this GPU: {0}")]
    TooLarge(String),
    #[error("GPU out of memory allocating {what}: {message}")]
    OutOfMemory { what: String, message: String },
    #[error("GPU error while {what}: {message}")]
    Wgpu { what: String, message: String },
    #[error(transparent)]
    Solve(#[from] sylva_lb::SolveError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
}
