//! The GPU solver as an [`LbSolver`] backend, and [`select_solver`]: a user's `cpu|gpu|auto`
//! and `f32|f16` turned into the backend that runs (here, where both backends are visible).

use sylva_lb::backend::{CpuSolver, LbBenchmark, LbSolver, LbSolverError};
use sylva_lb::{
    Boundary, DensityGrid, Floor, LightingGrid, MediumParams, Schedule, SolveOptions, SolveReport,
    VolumeSource,
};
use sylva_wgpu::{open_device, Device, GpuContext};

use crate::lattice::{solve_lighting_gpu, GpuLattice, Precision};
use crate::LbGpuError;

impl From<LbGpuError> for LbSolverError {
    fn from(e: LbGpuError) -> LbSolverError {
        match e {
            LbGpuError::Solve(e) => LbSolverError::Solve(e),
            e => LbSolverError::Device(Box::new(e)),
        }
    }
}

/// The LB solver on an opened GPU, storing its state at `precision`.
pub struct GpuSolver {
    ctx: GpuContext,
    precision: Precision,
}

impl GpuSolver {
    /// Fails when `precision` is f16 and the adapter lacks `SHADER_F16`.
    pub fn new(ctx: GpuContext, precision: Precision) -> Result<GpuSolver, LbGpuError> {
        if precision == Precision::F16 && !ctx.supports_f16() {
            return Err(LbGpuError::F16Unsupported(ctx.adapter_name().to_string()));
        }
        Ok(GpuSolver { ctx, precision })
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }
}

impl LbSolver for GpuSolver {
    fn solve_lighting_rgb(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundaries: &[Boundary; 3],
        floor: Option<&Floor>,
        source: Option<&VolumeSource>,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), LbSolverError> {
        sylva_lb::count_solve();
        Ok(solve_lighting_gpu(
            &self.ctx,
            grid,
            medium,
            boundaries,
            floor,
            source,
            opts,
            self.precision,
            progress,
        )?)
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
        let opts = SolveOptions {
            max_steps: steps,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        };
        let mut runs = Vec::with_capacity(repeats);
        {
            let mut lattice =
                GpuLattice::new(&self.ctx, grid, medium, 0, boundary, self.precision)?;
            for r in 0..repeats {
                lattice.reset(boundary)?;
                let report = lattice.run(&opts, &mut |s, _| progress(r * steps + s))?;
                runs.push(report.seconds);
            }
        }
        // Device-to-device copies of 256 MiB buffers (far beyond any GPU cache), with the
        // lattice freed first.
        let copy_gbs = self
            .ctx
            .copy_bandwidth_gbs(256 << 20, 5)
            .map_err(LbGpuError::from)?;
        Ok(LbBenchmark {
            runs,
            kernel: format!("wgsl-{}", self.precision.name()),
            bytes_per_update: self.precision.bytes_per_update() as usize,
            copy_gbs,
        })
    }

    fn device(&self) -> &'static str {
        "gpu"
    }

    fn adapter(&self) -> Option<String> {
        Some(self.ctx.adapter_name().to_string())
    }

    fn describe(&self) -> String {
        format!(
            "GPU {}, {} state",
            self.ctx.describe(),
            self.precision.name()
        )
    }

    fn cache_tag(&self) -> String {
        format!("gpu-{}", self.precision.name())
    }

    /// The GPU kernels have no extrapolation and no coarse start
    /// (`SolveError::ExtrapolateOnGpu`).
    fn schedule(&self) -> Schedule {
        Schedule::Papers
    }
}

/// The backend [`select_solver`] chose, and a note for the user (a software adapter, or
/// `auto` falling back to the CPU because a GPU would not open).
pub struct SelectedSolver {
    pub solver: Box<dyn LbSolver>,
    pub note: Option<String>,
}

/// The LB backend for `device` (see [`sylva_wgpu::open_device`]) storing its state at
/// `precision`. f16 is a GPU format: asking for it where the CPU runs is an error.
pub fn select_solver(device: Device, precision: Precision) -> Result<SelectedSolver, LbGpuError> {
    let opened = open_device(device)?;
    Ok(SelectedSolver {
        solver: solver_on(opened.gpu, precision)?,
        note: opened.note,
    })
}

/// The LB backend on an opened GPU (`None`: the CPU), for callers that share the device
/// with other GPU work (the render's ray tracer). f16 on the CPU is an error.
pub fn solver_on(
    gpu: Option<GpuContext>,
    precision: Precision,
) -> Result<Box<dyn LbSolver>, LbGpuError> {
    Ok(match gpu {
        Some(ctx) => Box::new(GpuSolver::new(ctx, precision)?),
        None if precision == Precision::F16 => return Err(LbGpuError::F16OnCpu),
        None => Box::new(CpuSolver),
    })
}
