//! The lattice-Boltzmann lighting solver on GPUs, through wgpu compute shaders (WGSL), as
//! paper 002 §3.1 ran it with OpenCL.
//!
//! Owns the generated kernels ([`shader`]), the device-side lattice
//! ([`GpuLattice`]), the three-colour driver ([`solve_lighting_gpu`]), the solver as an
//! [`sylva_lb::LbSolver`] backend ([`GpuSolver`]) and the choice between it and the CPU
//! ([`select_solver`]). The physics is
//! sylva-lb's: Ω is built on the host by `sylva_lb::collision` and uploaded in the cubic
//! factorised form of `sylva_lb::kernel::CubicOmega`; the site codes (green ρ, brown -ρ,
//! shell 0), `f_0` zeroing, boundary shell, stop rules and [`sylva_lb::SolveReport`] are the
//! CPU solver's, which is the oracle the tests compare against.
//!
//! State: two copies (ping-pong) of 19 values per site, direction-major with z fastest,
//! f32 or f16 ([`Precision`]); each copy is split over several storage bindings when one
//! binding cannot hold it (128 MiB on lavapipe). See docs/gpu.md.

pub mod lattice;
pub mod shader;
pub mod solver;

/// The device side: adapter choice and the opened device (`sylva-wgpu`).
pub use sylva_wgpu::{AdapterChoice, ContextOptions, GpuContext, GpuError};

pub use lattice::{device_memory_needed, solve_lighting_gpu, GpuLattice, Precision};
pub use solver::{select_solver, solver_on, GpuSolver, SelectedSolver};
pub use sylva_wgpu::Device;

use thiserror::Error;

/// What can go wrong solving on a GPU: the device's errors and the solver's own.
#[derive(Debug, Error)]
pub enum LbGpuError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("adapter '{0}' lacks SHADER_F16: f16 state storage is unavailable, use f32")]
    F16Unsupported(String),
    #[error("f16 is a GPU state format; the CPU solver stores f32")]
    F16OnCpu,
    #[error("grid too large for this GPU: {0}")]
    TooLarge(String),
    #[error(transparent)]
    Solve(#[from] sylva_lb::SolveError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
}
