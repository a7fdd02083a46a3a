//! `--device cpu|gpu|auto` and `--precision f32|f16` for the LB commands: which backend runs
//! the solver, and the reports that name it.

use anyhow::{bail, Context, Result};
use clap::ValueEnum;
use sylva_lb::{Boundary, DensityGrid, LightingGrid, MediumParams, SolveOptions, SolveReport};
use sylva_lb_gpu::{AdapterChoice, ContextOptions, GpuContext, GpuError, Precision};

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

/// The chosen backend.
pub enum Backend {
    Cpu,
    Gpu {
        ctx: Box<GpuContext>,
        precision: Precision,
    },
}

impl Backend {
    /// Opens the backend `device` asks for. `auto` falls back to the CPU (with a note on
    /// stderr) when there is no hardware GPU or it cannot be opened.
    pub fn open(device: DeviceArg, precision: PrecisionArg) -> Result<Backend> {
        let precision = match precision {
            PrecisionArg::F32 => Precision::F32,
            PrecisionArg::F16 => Precision::F16,
        };
        let gpu = |ctx: GpuContext| Backend::Gpu {
            ctx: Box::new(ctx),
            precision,
        };
        let backend = match device {
            DeviceArg::Cpu => Backend::Cpu,
            DeviceArg::Gpu => {
                let ctx = GpuContext::new(&ContextOptions::new(AdapterChoice::Any))
                    .context("--device gpu")?;
                if ctx.is_software() {
                    eprintln!(
                        "note: {} is a software adapter (the GPU emulated on the CPU): results \
                         are right, speed is not a GPU's",
                        ctx.adapter_name()
                    );
                }
                gpu(ctx)
            }
            DeviceArg::Auto => match GpuContext::new(&ContextOptions::new(AdapterChoice::Hardware))
            {
                Ok(ctx) => gpu(ctx),
                Err(GpuError::NoAdapter { .. }) => Backend::Cpu,
                Err(e) => {
                    eprintln!("note: using the CPU, the GPU could not be opened: {e}");
                    Backend::Cpu
                }
            },
        };
        if matches!(backend, Backend::Cpu) && precision == Precision::F16 {
            bail!("--precision f16 is a GPU state format; the CPU solver stores f32");
        }
        Ok(backend)
    }

    /// "cpu" or "gpu".
    pub fn device(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu { .. } => "gpu",
        }
    }

    /// The adapter's name on the GPU.
    pub fn adapter(&self) -> Option<String> {
        match self {
            Backend::Cpu => None,
            Backend::Gpu { ctx, .. } => Some(ctx.adapter_name().to_string()),
        }
    }

    /// One line for summaries.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!(
                "CPU, kernel {}, {} threads",
                sylva_lb::kernel::KernelIsa::detect().name(),
                rayon::current_num_threads()
            ),
            Backend::Gpu { ctx, precision } => {
                format!("GPU {}, {} state", ctx.describe(), precision.name())
            }
        }
    }

    /// `solve_lighting` on this backend.
    pub fn solve_lighting(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundary: Boundary,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>)> {
        Ok(match self {
            Backend::Cpu => sylva_lb::solve_lighting(grid, medium, boundary, opts, progress)?,
            Backend::Gpu { ctx, precision } => sylva_lb_gpu::solve_lighting_gpu(
                ctx, grid, medium, boundary, opts, *precision, progress,
            )?,
        })
    }
}
