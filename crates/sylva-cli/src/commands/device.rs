//! `--device cpu|gpu|auto` and `--precision f32|f16`: which LB backend runs the solver
//! (chosen by `sylva_lb_gpu::select_solver`).

use anyhow::{Context, Result};
use clap::ValueEnum;
use sylva_lb::LbSolver;
use sylva_lb_gpu::{select_solver, Device, LbGpuError, Precision};

/// Where the LB solver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DeviceArg {
    /// The CPU solver (vector kernel, all threads).
    Cpu,
    /// The best GPU adapter there is, a software one (lavapipe) included; an error if there
    /// is none.
    Gpu,
    /// A hardware GPU if one is present, else the CPU.
    Auto,
}

/// How the GPU stores the state (arithmetic is f32 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PrecisionArg {
    F32,
    /// Half the memory traffic, about 3e-4 relative error (docs/gpu.md); needs SHADER_F16.
    F16,
}

/// The LB backend `device` and `precision` ask for; a note about the choice (a software
/// adapter, `auto` falling back to the CPU) goes to stderr.
pub fn open_solver(device: DeviceArg, precision: PrecisionArg) -> Result<Box<dyn LbSolver>> {
    let device = match device {
        DeviceArg::Cpu => Device::Cpu,
        DeviceArg::Gpu => Device::Gpu,
        DeviceArg::Auto => Device::Auto,
    };
    let precision = match precision {
        PrecisionArg::F32 => Precision::F32,
        PrecisionArg::F16 => Precision::F16,
    };
    let selected = match select_solver(device, precision) {
        Ok(s) => s,
        Err(LbGpuError::F16OnCpu) => {
            anyhow::bail!("--precision f16 is a GPU state format; the CPU solver stores f32")
        }
        Err(e) if device == Device::Gpu => return Err(e).context("--device gpu"),
        Err(e) => return Err(e.into()),
    };
    if let Some(note) = &selected.note {
        eprintln!("note: {note}");
    }
    Ok(selected.solver)
}
