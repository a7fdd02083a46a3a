//! The LB solver as a backend: one interface ([`LbSolver`]) over the CPU solver of this crate
//! ([`CpuSolver`]) and the GPU solver of `sylva-lb-gpu`, so that whoever lights a grid (the
//! `lb solve` command, the renderer's per-model lighting, a precompute of several boundary
//! conditions) neither knows nor cares where it runs. Picking one from a device name lives
//! in `sylva-lb-gpu` (`select_solver`), which sees both.

use crate::bandwidth::copy_bandwidth_gbs;
use crate::kernel::KernelIsa;
use crate::lattice::Q;
use crate::solver::{
    solve_lighting_rgb_on, Boundary, Floor, Lattice, Schedule, SolveError, SolveOptions,
    SolveReport, VolumeSource,
};
use crate::{DensityGrid, LightingGrid, MediumParams};

/// The colours of a medium: R, G, B.
pub const COLOURS: usize = 3;

static SOLVES_STARTED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Three-colour solves begun in this process, on any backend: what `sylva view` shows to
/// prove that moving the sun solves nothing.
pub fn solves_started() -> u64 {
    SOLVES_STARTED.load(std::sync::atomic::Ordering::Relaxed)
}

/// Counts one solve; every [`LbSolver`] implementation calls it as its solve begins.
pub fn count_solve() {
    SOLVES_STARTED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
}

/// Why a backend could not solve: the solver's own checks, or the device's failure.
#[derive(Debug, thiserror::Error)]
pub enum LbSolverError {
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// A device error (GPU out of memory, lost device, grid beyond its limits), as the
    /// backend words it.
    #[error(transparent)]
    Device(Box<dyn std::error::Error + Send + Sync>),
}

/// What [`LbSolver::benchmark`] measured: one colour on one grid, several timed runs.
#[derive(Debug, Clone, PartialEq)]
pub struct LbBenchmark {
    /// Seconds per run of the requested steps.
    pub runs: Vec<f64>,
    /// The kernel that ran (`avx2+fma`, `wgsl-f32`, ...).
    pub kernel: String,
    /// Bytes moved per site update (state read and written, density read).
    pub bytes_per_update: usize,
    /// The device's copy bandwidth measured in the same call, GB/s (read + write counted).
    pub copy_gbs: f64,
}

/// Lights density grids with the lattice-Boltzmann solver somewhere (CPU or GPU). Results
/// agree across backends within the GPU's documented tolerance (docs/gpu.md); a backend is
/// deterministic on its own.
pub trait LbSolver: Send + Sync {
    /// The three-colour solve of [`crate::solve_lighting`]: same inputs, same stop rules,
    /// same reports. `progress(colour, step, residual)` follows it.
    fn solve_lighting(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundary: Boundary,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), LbSolverError> {
        self.solve_lighting_rgb(grid, medium, &[boundary; 3], None, None, opts, progress)
    }

    /// The three-colour solve with a boundary per colour (sky and ground light have colours
    /// of their own), an optional floor (the ground's light from the bottom face) and an
    /// optional volume source (light emitted inside the medium):
    /// [`crate::solver::solve_lighting_rgb`].
    #[allow(clippy::too_many_arguments)]
    fn solve_lighting_rgb(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundaries: &[Boundary; 3],
        floor: Option<&Floor>,
        source: Option<&VolumeSource>,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), LbSolverError>;

    /// Colour `colour` (0, 1, 2: R, G, B) of [`LbSolver::solve_lighting`] alone: its site
    /// totals and report, bit for bit what the three-colour solve gives for that colour. For
    /// solving a model's colours in different processes (the work queue of `sylva-mpi`).
    /// `progress(step, residual)`.
    ///
    /// The default solves a medium whose three colours are all `colour`'s: the shared colour
    /// loop ([`crate::solver::solve_colours`]) solves it once and copies it.
    fn solve_colour(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        colour: usize,
        boundary: Boundary,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, f64),
    ) -> Result<(Vec<f32>, SolveReport), LbSolverError> {
        assert!(colour < COLOURS, "colour {colour} of {COLOURS}");
        let one = MediumParams {
            colours: [medium.colours[colour]; COLOURS],
            brown: medium.brown.map(|b| [b[colour]; COLOURS]),
            ..medium.clone()
        };
        let (lighting, reports) =
            self.solve_lighting(grid, &one, boundary, opts, &mut |_, s, r| progress(s, r))?;
        let [totals, _, _] = lighting.colours;
        Ok((totals, reports[0]))
    }

    /// `repeats` timed runs of `steps` steps of colour 0 of `medium` on `grid` (reset between
    /// runs), and the device's copy bandwidth: what `sylva bench lb` reports.
    /// `progress(done_steps)` counts over all runs.
    fn benchmark(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        boundary: Boundary,
        steps: usize,
        repeats: usize,
        progress: &mut dyn FnMut(usize),
    ) -> Result<LbBenchmark, LbSolverError>;

    /// `"cpu"` or `"gpu"`.
    fn device(&self) -> &'static str;

    /// The GPU adapter's name; `None` on the CPU.
    fn adapter(&self) -> Option<String> {
        None
    }

    /// One line for summaries: device, kernel or adapter, threads or state precision.
    fn describe(&self) -> String;

    /// What a result depends on besides its inputs, for cache keys: results of different
    /// tags may differ in the last bits (`"cpu"`, `"gpu-f32"`, `"gpu-f16"`).
    fn cache_tag(&self) -> String;

    /// How long a renderer's solves run on this backend (lighting, bases, media): the CPU
    /// starts from a half-resolution solve and extrapolates (half the papers' steps, ending
    /// about as close to the steady state); a backend that cannot runs the papers' schedule.
    /// Cache keys name it.
    fn schedule(&self) -> Schedule;
}

/// A backend run on another [`Schedule`] than its own (`--lb-schedule`): each solve is the
/// backend's, for whatever options it is given; only [`LbSolver::schedule`] differs (and with
/// it the cache keys, which name the schedule).
pub struct OnSchedule {
    solver: Box<dyn LbSolver>,
    schedule: Schedule,
}

impl OnSchedule {
    pub fn new(solver: Box<dyn LbSolver>, schedule: Schedule) -> OnSchedule {
        OnSchedule { solver, schedule }
    }
}

impl LbSolver for OnSchedule {
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
        self.solver
            .solve_lighting_rgb(grid, medium, boundaries, floor, source, opts, progress)
    }

    fn solve_colour(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
        colour: usize,
        boundary: Boundary,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, f64),
    ) -> Result<(Vec<f32>, SolveReport), LbSolverError> {
        self.solver
            .solve_colour(grid, medium, colour, boundary, opts, progress)
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
        self.solver
            .benchmark(grid, medium, boundary, steps, repeats, progress)
    }

    fn device(&self) -> &'static str {
        self.solver.device()
    }

    fn adapter(&self) -> Option<String> {
        self.solver.adapter()
    }

    fn describe(&self) -> String {
        self.solver.describe()
    }

    fn cache_tag(&self) -> String {
        self.solver.cache_tag()
    }

    fn schedule(&self) -> Schedule {
        self.schedule
    }
}

/// The CPU solver of this crate (the widest vector kernel this CPU runs, all rayon threads).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CpuSolver;

impl CpuSolver {
    /// The same solver on a kernel chosen by hand (benchmarks compare kernels): `None` if
    /// this CPU lacks its instructions.
    pub fn with_kernel(kernel: KernelIsa) -> Option<CpuKernelSolver> {
        kernel.is_supported().then_some(CpuKernelSolver { kernel })
    }
}

/// [`CpuSolver`] on a given kernel ([`CpuSolver::with_kernel`]). The AVX-512 and AVX2
/// kernels write the same state bit for bit; the portable one rounds its multiply-adds twice.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuKernelSolver {
    kernel: KernelIsa,
}

impl LbSolver for CpuSolver {
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
        CpuKernelSolver::detected()
            .solve_lighting_rgb(grid, medium, boundaries, floor, source, opts, progress)
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
        CpuKernelSolver::detected().benchmark(grid, medium, boundary, steps, repeats, progress)
    }

    fn device(&self) -> &'static str {
        "cpu"
    }

    fn describe(&self) -> String {
        CpuKernelSolver::detected().describe()
    }

    fn cache_tag(&self) -> String {
        CpuKernelSolver::detected().cache_tag()
    }

    fn schedule(&self) -> Schedule {
        Schedule::CoarseStarted
    }
}

impl CpuKernelSolver {
    fn detected() -> CpuKernelSolver {
        CpuKernelSolver {
            kernel: KernelIsa::detect(),
        }
    }

    pub fn kernel(&self) -> KernelIsa {
        self.kernel
    }
}

impl LbSolver for CpuKernelSolver {
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
        count_solve();
        Ok(solve_lighting_rgb_on(
            self.kernel,
            grid,
            medium,
            boundaries,
            floor,
            source,
            opts,
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
        let mut lattice = Lattice::new(grid, medium, 0, boundary)?;
        lattice.set_kernel(self.kernel);
        let mut runs = Vec::with_capacity(repeats);
        for r in 0..repeats {
            lattice.reset(boundary);
            let report = lattice.run(&opts, &mut |s, _| progress(r * steps + s))?;
            runs.push(report.seconds);
        }
        Ok(LbBenchmark {
            runs,
            kernel: lattice.kernel().name().to_string(),
            // Each update reads and writes the 19 f32 of a site and reads its density.
            bytes_per_update: 2 * Q * 4 + 4,
            // On a buffer far larger than the last-level cache, in the same run.
            copy_gbs: copy_bandwidth_gbs(256 << 20, 7),
        })
    }

    fn device(&self) -> &'static str {
        "cpu"
    }

    fn describe(&self) -> String {
        format!(
            "CPU, kernel {}, {} threads",
            self.kernel.name(),
            rayon::current_num_threads()
        )
    }

    fn cache_tag(&self) -> String {
        "cpu".into()
    }

    fn schedule(&self) -> Schedule {
        Schedule::CoarseStarted
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Dims, Preset};

    #[test]
    fn fused_kernels_solve_alike_and_name_themselves() {
        let dims = Dims::new(8, 7, 19).unwrap();
        let mut grid = DensityGrid::empty(dims);
        for (i, d) in grid.density.iter_mut().enumerate() {
            *d = (i % 5) as f32 / 5.0;
        }
        let medium = Preset::Leaf.params();
        let boundary = Boundary::sun([0.3, -0.9, 0.3], 1.0);
        let opts = SolveOptions::papers(dims);
        let (detected, _) = CpuSolver
            .solve_lighting(&grid, &medium, boundary, &opts, &mut |_, _, _| {})
            .unwrap();
        for isa in KernelIsa::supported() {
            let solver = CpuSolver::with_kernel(isa).expect("supported");
            assert_eq!(solver.kernel(), isa);
            assert!(
                solver.describe().contains(isa.name()),
                "{}",
                solver.describe()
            );
            let (got, _) = solver
                .solve_lighting(&grid, &medium, boundary, &opts, &mut |_, _, _| {})
                .unwrap();
            // The fused kernels (all but the portable one) do the same arithmetic per site.
            if isa != KernelIsa::Portable {
                assert!(
                    got == detected,
                    "{} differs from {}",
                    isa.name(),
                    KernelIsa::detect().name()
                );
            }
        }
        assert!(CpuSolver::with_kernel(KernelIsa::Portable).is_some());
    }

    #[test]
    fn cpu_backend_is_the_solver() {
        let dims = Dims::new(10, 9, 8).unwrap();
        let mut grid = DensityGrid::empty(dims);
        for (i, d) in grid.density.iter_mut().enumerate() {
            *d = (i % 7) as f32 / 7.0;
        }
        let medium = Preset::Leaf.params();
        let boundary = Boundary::sun([0.3, -0.9, 0.3], 1.0);
        let opts = SolveOptions::papers(dims);
        let (want, want_reports) =
            crate::solve_lighting(&grid, &medium, boundary, &opts, &mut |_, _, _| {}).unwrap();
        let solver: &dyn LbSolver = &CpuSolver;
        let mut calls = 0;
        let (got, reports) = solver
            .solve_lighting(&grid, &medium, boundary, &opts, &mut |_, _, _| calls += 1)
            .unwrap();
        assert_eq!(got, want);
        assert_eq!(reports.len(), want_reports.len());
        assert_eq!(calls, 3 * opts.max_steps);
        assert_eq!((solver.device(), solver.adapter()), ("cpu", None));
        assert!(solver.describe().starts_with("CPU, kernel"));

        let mut last = 0;
        let b = solver
            .benchmark(&grid, &medium, boundary, 4, 2, &mut |s| last = s)
            .unwrap();
        assert_eq!(b.runs.len(), 2);
        assert_eq!(last, 2 * 4, "progress counts over all runs");
        assert_eq!(b.bytes_per_update, 156);
        assert!(b.copy_gbs > 0.0 && b.runs.iter().all(|&s| s > 0.0));

        // Each colour alone is that colour of the three-colour solve, bit for bit.
        for c in 0..COLOURS {
            let mut steps = 0;
            let (totals, report) = solver
                .solve_colour(&grid, &medium, c, boundary, &opts, &mut |s, _| steps = s)
                .unwrap();
            assert!(totals == want.colours[c], "colour {c}");
            assert_eq!(report.steps, want_reports[c].steps);
            assert_eq!(steps, opts.max_steps);
        }

        // The solver's checks come back as its errors.
        let bad = SolveOptions {
            max_steps: 0,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        };
        let e = solver
            .solve_lighting(&grid, &medium, boundary, &bad, &mut |_, _, _| {})
            .unwrap_err();
        assert!(matches!(e, LbSolverError::Solve(SolveError::Steps)), "{e}");
    }
}
