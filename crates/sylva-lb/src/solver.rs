//! The lattice-Boltzmann solver for one colour, and the three-colour driver.

use std::time::Instant;

use rayon::prelude::*;
use thiserror::Error;

use crate::alloc::AlignedBuf;
use crate::collision::{Omega, ReducedOmega};
use crate::grid::{DensityGrid, Dims, LightingGrid};
use crate::kernel::{
    process_row, row_targets, run_stride, stream_shell_row, CubicOmega, KernelIsa, RowParams,
    RowSource,
};
use crate::lattice::{unit, Q};
use crate::params::{MediumParams, ParamError};

#[derive(Debug, Error)]
pub enum SolveError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("boundary value f_{index} = {value} must be finite and non-negative")]
    Boundary { index: usize, value: f32 },
    #[error("convergence tolerance {0} must be a positive finite number")]
    Tolerance(f64),
    #[error("extrapolated and coarse-started solves run on the CPU solver only: use --device cpu")]
    ExtrapolateOnGpu,
    #[error("step count must be at least 1")]
    Steps,
    #[error("floor: {0}")]
    Floor(String),
    #[error("volume source: {0}")]
    Source(String),
}

/// Fixed directional densities of the shell sites (002 §3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Boundary {
    pub values: [f32; Q],
}

impl Boundary {
    /// Sunlight travelling along unit vector `travel`: `f_i = I · max(0, n_i · d)`, `f_0 = 0`.
    pub fn sun(travel: [f64; 3], intensity: f64) -> Boundary {
        let mut values = [0.0f32; Q];
        for (i, v) in values.iter_mut().enumerate().skip(1) {
            let n = unit(i);
            let d = n[0] * travel[0] + n[1] * travel[1] + n[2] * travel[2];
            *v = (intensity * d.max(0.0)) as f32;
        }
        Boundary { values }
    }

    /// The relighting bases of 004: `B_0` has every `f_i = 1` (i ≥ 1), `B_j` has `f_i = δ_ij`.
    pub fn basis(j: usize) -> Boundary {
        assert!(j < Q, "basis index {j} out of range");
        let mut values = [0.0f32; Q];
        if j == 0 {
            values[1..].fill(1.0);
        } else {
            values[j] = 1.0;
        }
        Boundary { values }
    }

    fn validate(&self) -> Result<(), SolveError> {
        for (index, &value) in self.values.iter().enumerate() {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SolveError::Boundary { index, value });
            }
        }
        Ok(())
    }
}

/// The ground under a grid as its bottom face emits it: per site `(x, z)` of the `y = 0`
/// shell row and per colour, the radiance `L` of the ground there. Those sites send
/// `4 L w_m` along the upward directions `m` (`c_y = 1`) instead of the uniform boundary's
/// values, so the ground's light can be shadowed where a plant stands over it; their other
/// directions keep the boundary's values (none of them enters the interior).
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    pub nx: usize,
    pub nz: usize,
    /// Radiance per colour, site order `x · nz + z`.
    pub radiance: [Vec<f32>; 3],
}

impl Floor {
    /// Checks the size against `dims` and that every value is finite and ≥ 0.
    pub fn validate(&self, dims: Dims) -> Result<(), SolveError> {
        if self.nx != dims.nx || self.nz != dims.nz {
            return Err(SolveError::Floor(format!(
                "a {}×{} floor does not fit a {dims} grid",
                self.nx, self.nz
            )));
        }
        for (c, r) in self.radiance.iter().enumerate() {
            if r.len() != self.nx * self.nz {
                return Err(SolveError::Floor(format!(
                    "colour {c} has {} values, the floor {}",
                    r.len(),
                    self.nx * self.nz
                )));
            }
            if let Some(i) = r.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(SolveError::Floor(format!(
                    "radiance at ({}, {}) is {}: it must be finite and ≥ 0",
                    i / self.nz,
                    i % self.nz,
                    r[i]
                )));
            }
        }
        Ok(())
    }

    /// The value a floor site of radiance `radiance` holds in direction `m`, given the
    /// uniform `boundary`.
    #[inline]
    pub fn value(radiance: f32, m: usize, boundary: &Boundary) -> f32 {
        if crate::lattice::C[m][1] == 1 {
            (4.0 * radiance as f64 * crate::lattice::weight(m)) as f32
        } else {
            boundary.values[m]
        }
    }
}

/// A light source inside the medium, per colour: every step, each interior site `i` adds
/// `strength[i] · profile[m]` to its post-collision value of direction `m` (the brown
/// profile on brown sites, the green one elsewhere). Sunlight scattered at its first
/// collision, computed along the sun's exact direction, enters the LB this way
/// ([`crate::light::first_collision_source`]).
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeSource {
    /// Per colour, per site (site order); 0 on the shell.
    pub strength: [Vec<f32>; 3],
    /// Per colour, the share of a unit strength each direction gets on green sites.
    pub green: [[f32; Q]; 3],
    /// The same on brown sites.
    pub brown: [[f32; Q]; 3],
}

impl VolumeSource {
    /// Checks the size against `dims`, that every value is finite and ≥ 0 and that shell
    /// sites hold none.
    pub fn validate(&self, dims: Dims) -> Result<(), SolveError> {
        for c in 0..3 {
            let s = &self.strength[c];
            if s.len() != dims.sites() {
                return Err(SolveError::Source(format!(
                    "colour {c} has {} strengths, the {dims} grid {} sites",
                    s.len(),
                    dims.sites()
                )));
            }
            if let Some(i) = s.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
                let (x, y, z) = dims.coords(i);
                return Err(SolveError::Source(format!(
                    "strength at ({x}, {y}, {z}) is {}: it must be finite and ≥ 0",
                    s[i]
                )));
            }
            if let Some(i) = (0..dims.sites()).find(|&i| {
                let (x, y, z) = dims.coords(i);
                dims.on_shell(x, y, z) && s[i] != 0.0
            }) {
                let (x, y, z) = dims.coords(i);
                return Err(SolveError::Source(format!(
                    "shell site ({x}, {y}, {z}) has a strength: the shell only holds the boundary"
                )));
            }
            for p in [&self.green[c], &self.brown[c]] {
                if !p.iter().all(|v| v.is_finite() && *v >= 0.0) {
                    return Err(SolveError::Source(format!(
                        "colour {c}: direction profile {p:?} must be finite and ≥ 0"
                    )));
                }
            }
        }
        Ok(())
    }
}

/// One colour's [`VolumeSource`], as a lattice holds it.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourSource {
    pub strength: Vec<f32>,
    pub green: [f32; Q],
    pub brown: [f32; Q],
}

impl VolumeSource {
    /// Colour `c`'s part.
    pub fn colour(&self, c: usize) -> ColourSource {
        ColourSource {
            strength: self.strength[c].clone(),
            green: self.green[c],
            brown: self.brown[c],
        }
    }
}

/// When a solve stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// Upper bound on steps (the papers run exactly 2 × the longest edge).
    pub max_steps: usize,
    /// Stop early once the relative change of total interior density per step falls below
    /// this.
    pub tolerance: Option<f64>,
    /// Extrapolate along the slowest mode on the way ([`Extrapolation`]; the CPU solver
    /// only): [`SolveOptions::extrapolated`]'s 1.5 × the longest edge then end as close to the
    /// steady state as the papers' 2 × do.
    pub extrapolate: bool,
    /// Start from the solution of the same problem on a grid of half the resolution
    /// ([`SolveOptions::coarse_started`]; the CPU solver only) instead of from an empty
    /// grid.
    pub coarse_start: bool,
}

/// The shortest longest edge a coarse-started schedule starts from a coarser grid at;
/// below it [`SolveOptions::coarse_started`] is the extrapolated schedule.
pub const COARSE_START_MIN_EDGE: usize = 64;

impl SolveOptions {
    /// The papers' schedule: 2 × the longest grid edge, no early stop.
    pub fn papers(dims: Dims) -> SolveOptions {
        SolveOptions {
            max_steps: 2 * dims.longest_edge(),
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        }
    }

    /// Three quarters of the papers' steps, extrapolated along the slowest mode: as close to
    /// the steady state as the papers' schedule ends (docs/PERFORMANCE.md, "Extrapolated
    /// solves").
    pub fn extrapolated(dims: Dims) -> SolveOptions {
        let k = Extrapolation::interval(dims);
        SolveOptions {
            max_steps: (3 * dims.longest_edge() / 2).div_ceil(k) * k,
            tolerance: None,
            extrapolate: true,
            coarse_start: false,
        }
    }

    /// Half the papers' steps from the solution on a grid of half the resolution
    /// ([`SolveOptions::coarse_level`]), extrapolated along the slowest mode
    /// from three quarters of the edge on. Interpolated, the coarse light is 10-17 %
    /// (relative RMS over the medium) from the fine steady state, where an empty grid is
    /// 100 %, and the light no longer has to cross the grid: on the catalpa (128 × 108 × 116)
    /// 128 steps so take 0.75-0.80 of the extrapolated schedule's 192 from empty and end
    /// 1.5-4× nearer the steady state under a boundary, 1.5× farther for the sun's
    /// first-collision source (docs/lb.md, "Coarse-started solves"). Grids smaller than
    /// [`COARSE_START_MIN_EDGE`] get [`SolveOptions::extrapolated`].
    pub fn coarse_started(dims: Dims) -> SolveOptions {
        if dims.longest_edge() < COARSE_START_MIN_EDGE {
            return SolveOptions::extrapolated(dims);
        }
        let k = Extrapolation::interval(dims);
        SolveOptions {
            max_steps: dims.longest_edge().div_ceil(k) * k,
            tolerance: None,
            extrapolate: true,
            coarse_start: true,
        }
    }

    /// How the coarse solve a coarse-started one starts from runs: half its longest edge in
    /// plain steps from its own coarse start where it is [`COARSE_START_MIN_EDGE`] long or
    /// more, else [`SolveOptions::extrapolated`] from empty. Its accuracy hardly matters, the
    /// interpolated light being 10-17 % from the fine steady state either way: on the catalpa
    /// at 128, the 65 grid's 72 extrapolated steps instead of these 40 left the fine solve's
    /// end within 6 % of the same distance, at 1.5× the coarse cost.
    pub fn coarse_level(dims: Dims) -> SolveOptions {
        let edge = dims.longest_edge();
        if edge < COARSE_START_MIN_EDGE {
            return SolveOptions::extrapolated(dims);
        }
        let k = Extrapolation::interval(dims);
        SolveOptions {
            max_steps: (edge / 2).div_ceil(k) * k,
            tolerance: None,
            extrapolate: false,
            coarse_start: true,
        }
    }

    /// The stop rule of `--steps` and `--tolerance`: the papers' without either; with only a
    /// tolerance, at most 10 × the longest edge.
    pub fn for_run(steps: Option<usize>, tolerance: Option<f64>, dims: Dims) -> SolveOptions {
        match (steps, tolerance) {
            (Some(s), t) => SolveOptions {
                max_steps: s,
                tolerance: t,
                extrapolate: false,
                coarse_start: false,
            },
            (None, None) => SolveOptions::papers(dims),
            (None, Some(t)) => SolveOptions {
                max_steps: 10 * dims.longest_edge(),
                tolerance: Some(t),
                extrapolate: false,
                coarse_start: false,
            },
        }
    }

    fn validate(&self) -> Result<(), SolveError> {
        if self.max_steps == 0 {
            return Err(SolveError::Steps);
        }
        if let Some(t) = self.tolerance {
            if !(t.is_finite() && t > 0.0) {
                return Err(SolveError::Tolerance(t));
            }
        }
        Ok(())
    }
}

/// How long a renderer's solves run: the schedule a backend uses for lighting, bases and
/// media ([`crate::LbSolver::schedule`]), named in cache keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Schedule {
    /// [`SolveOptions::papers`]: 2 × the longest edge.
    Papers,
    /// [`SolveOptions::extrapolated`]: 1.5 × the longest edge, extrapolated along the
    /// slowest mode (the CPU solver only).
    Extrapolated,
    /// [`SolveOptions::coarse_started`]: 1 × the longest edge from a half-resolution
    /// solve, extrapolated (the CPU solver only).
    CoarseStarted,
}

impl Schedule {
    /// The stop rule over a `dims` grid.
    pub fn options(self, dims: Dims) -> SolveOptions {
        match self {
            Schedule::Papers => SolveOptions::papers(dims),
            Schedule::Extrapolated => SolveOptions::extrapolated(dims),
            Schedule::CoarseStarted => SolveOptions::coarse_started(dims),
        }
    }

    /// The schedule's name in cache keys and reports.
    pub fn name(self) -> &'static str {
        match self {
            Schedule::Papers => "papers:2N",
            Schedule::Extrapolated => "extrapolated:1.5N",
            Schedule::CoarseStarted => "coarse:1N",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// Ran `max_steps`.
    StepLimit,
    /// The relative change fell below the tolerance.
    Converged,
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            StopReason::StepLimit => "step limit",
            StopReason::Converged => "converged",
        })
    }
}

/// What one colour's solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveReport {
    pub steps: usize,
    pub stop: StopReason,
    /// Relative change of total interior density in the last step.
    pub residual: f64,
    pub seconds: f64,
}

/// The run-length rule every backend shares, so that the CPU and the GPU stop after the same
/// step: the relative change of the total density per step, against `opts.tolerance`.
#[derive(Debug, Clone)]
pub struct RunMonitor {
    tolerance: Option<f64>,
    max_steps: usize,
    previous: f64,
    residual: f64,
    steps: usize,
    converged: bool,
    start: Instant,
}

impl RunMonitor {
    pub fn new(opts: &SolveOptions) -> RunMonitor {
        RunMonitor {
            tolerance: opts.tolerance,
            max_steps: opts.max_steps,
            previous: f64::NAN,
            residual: f64::INFINITY,
            steps: 0,
            converged: false,
            start: Instant::now(),
        }
    }

    /// Steps still allowed; 0 once the run has converged.
    pub fn steps_left(&self) -> usize {
        if self.converged {
            0
        } else {
            self.max_steps - self.steps
        }
    }

    /// Records the totals of a batch of steps (each the total of the state a step started
    /// from), calling `progress(step, residual)` for each. A batch is checked as a whole, so a
    /// backend that advances two steps at a time stops after the pair.
    pub fn record(&mut self, totals: &[f64], progress: &mut dyn FnMut(usize, f64)) {
        for &total in totals {
            self.steps += 1;
            if self.previous.is_finite() {
                self.residual = (total - self.previous).abs() / total.abs().max(f64::MIN_POSITIVE);
            }
            self.previous = total;
            progress(self.steps, self.residual);
            self.converged |= self.tolerance.is_some_and(|tol| self.residual < tol);
        }
    }

    pub fn report(&self) -> SolveReport {
        SolveReport {
            steps: self.steps,
            stop: if self.converged {
                StopReason::Converged
            } else {
                StopReason::StepLimit
            },
            residual: self.residual,
            seconds: self.start.elapsed().as_secs_f64(),
        }
    }
}

/// Extrapolation along a solve's slowest mode. A step is affine, `f ← A f + b`, so once the
/// light has crossed the grid the error left decays like the slowest mode, by a ratio `r`
/// every `k` steps; then `f + (f − f_k) · r / (1 − r)` (`f_k` the state `k` steps back) is
/// nearly the steady state. `r` is measured as the ratio of the state's changes over the
/// last two intervals of `k` steps. From 1.25 × the longest edge on, the solve extrapolates
/// every `2k` steps (each needs two clean intervals). On the catalpa (128 × 108 × 116, leaf
/// green) 192 steps so extrapolated end 1.0e-4 (relative RMS over the medium) from the steady
/// state, the papers' 256 plain steps 8.8e-5, 192 plain steps 1.0e-3.
pub struct Extrapolation {
    k: usize,
    next: usize,
    /// The state at the last checkpoint (allocated at the first).
    earlier: Vec<f32>,
    /// The change over the interval before the last checkpoint, once there is one.
    change: Option<f64>,
}

impl Extrapolation {
    /// Steps between the states compared: an eighth of the longest edge, even, at least 2.
    pub fn interval(dims: Dims) -> usize {
        (dims.longest_edge() / 16 * 2).max(2)
    }

    pub fn new(dims: Dims) -> Extrapolation {
        Extrapolation::from(dims, 5 * dims.longest_edge() / 4)
    }

    /// Extrapolates first at `first` steps (rounded up to the interval) rather than at
    /// 1.25 × the longest edge: a coarse-started solve has no light crossing to wait for.
    pub fn from(dims: Dims, first: usize) -> Extrapolation {
        let k = Extrapolation::interval(dims);
        Extrapolation {
            k,
            next: first.div_ceil(k).max(2) * k,
            earlier: Vec::new(),
            change: None,
        }
    }

    /// The first step the next extrapolation looks at: two intervals before it.
    fn first_checkpoint(&self) -> usize {
        self.next.saturating_sub(2 * self.k)
    }

    /// Steps from `done` to the next state it looks at (or further: the sweep's batch
    /// bounds a run before the first checkpoint).
    fn steps_to_checkpoint(&self, done: usize) -> usize {
        if done < self.first_checkpoint() {
            self.first_checkpoint() - done
        } else {
            self.k - done % self.k
        }
    }

    /// After step `done`: looks at the state at checkpoints, and extrapolates where due.
    fn after(&mut self, done: usize, lattice: &mut Lattice) {
        if !done.is_multiple_of(self.k) || done < self.first_checkpoint() {
            return;
        }
        if self.earlier.is_empty() {
            self.earlier = lattice.snapshot();
            return;
        }
        let due = done >= self.next && self.change.is_some();
        let (now, size) = lattice.change_since(&mut self.earlier, !due);
        if !due {
            self.change = Some(now);
            return;
        }
        let r = now / self.change.take().expect("due only with a change");
        // Near 1 the light is still crossing (no slow mode yet); at f32's rounding there is
        // nothing left to extrapolate.
        let factor = if r < 0.9 && now > 1e-6 * size {
            r / (1.0 - r)
        } else {
            0.0
        };
        lattice.extrapolate(&mut self.earlier, factor as f32);
        self.next = done + 2 * self.k;
    }
}

impl SolveReport {
    /// Million lattice-site updates per second.
    pub fn mlups(&self, dims: Dims) -> f64 {
        dims.sites() as f64 * self.steps as f64 / self.seconds.max(1e-12) / 1e6
    }
}

/// Energy moved by one step from the current state (for balance checks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flows {
    /// Density streamed from the shell into the interior.
    pub inflow: f64,
    /// Density streamed from the interior onto the shell (dropped).
    pub outflow: f64,
    /// Density removed by zeroing `f_0`.
    pub absorbed: f64,
    /// Density a volume source added.
    pub sourced: f64,
}

/// Planes of each intermediate state that [`Lattice::step_sweep`] keeps.
const RING: usize = 4;

/// The most steps one sweep over memory advances ([`Lattice::step_sweep`]): the state is read
/// and written once per sweep, and each step beyond the first keeps a ring of [`RING`] planes
/// in cache (5 MB at 128³). Three measured 8 % faster than two on the shared 2-core host
/// (dense 128³, AVX-512, CPU-seconds and wall, medians of 8); four and six were slower than
/// three, their rings crowding the shared L3 (docs/PERFORMANCE.md).
pub const SWEEP_STEPS: usize = 3;

/// Fills the 19 runs of a row block: the boundary everywhere (`whole`, a shell row) or only
/// at the two z-ends (an interior row), zero elsewhere.
fn fill_row(block: &mut [f32], nz: usize, boundary: &Boundary, whole: bool) {
    let stride = run_stride(nz);
    for m in 0..Q {
        let run = &mut block[m * stride + 1..m * stride + 1 + nz];
        let v = boundary.values[m];
        if whole {
            run.fill(v);
        } else {
            run.fill(0.0);
            run[0] = v;
            run[nz - 1] = v;
        }
    }
}

/// Writes the floor's upward values into the `y = 0` row block of plane `x`.
fn fill_floor_row(
    block: &mut [f32],
    nz: usize,
    boundary: &Boundary,
    floor: Option<&[f32]>,
    x: usize,
) {
    let Some(floor) = floor else { return };
    let stride = run_stride(nz);
    for m in 0..Q {
        if crate::lattice::C[m][1] != 1 {
            continue;
        }
        let run = &mut block[m * stride + 1..m * stride + 1 + nz];
        for (z, v) in run.iter_mut().enumerate() {
            *v = Floor::value(floor[x * nz + z], m, boundary);
        }
    }
}

/// The grid a coarse-started solve starts on ([`Lattice::restricted`]): half the interior
/// sites of `dims` along each axis (rounded up), plus the shell.
pub fn coarse_dims(dims: Dims) -> Dims {
    let half = |n: usize| n.saturating_sub(2).div_ceil(2) + 2;
    Dims {
        nx: half(dims.nx),
        ny: half(dims.ny),
        nz: half(dims.nz),
    }
}

/// The largest site density [`Lattice::restricted`] takes the optical depth of: a site of
/// density 1 would have an infinite one.
const MAX_RESTRICTED_DENSITY: f64 = 0.999_999;

/// Bytes of memory a solve over `dims` holds: two states, the site codes and the
/// three-colour result.
pub fn memory_needed(dims: Dims) -> u64 {
    let n = dims.sites() as u64;
    let state = (dims.nx * dims.ny * Q * run_stride(dims.nz)) as u64 * 4;
    let ring = ((SWEEP_STEPS - 1) * RING * dims.ny * Q * run_stride(dims.nz)) as u64 * 4;
    2 * state + ring + n * 4 + 3 * n * 4
}

/// Refuses an LB solve on `dims` that would not fit in memory: the solver's state
/// ([`memory_needed`]) plus the density grid it reads (density and wood, 8 B/site), checked
/// before either is allocated.
pub fn check_solve_memory(dims: Dims) -> Result<(), sylva_core::MemoryError> {
    sylva_core::check_memory(
        &format!("an LB solve on a {dims} grid"),
        memory_needed(dims) + dims.sites() as u64 * 8,
    )
}

/// A raw pointer the planes of a step share; each (row, direction) run of the next state has
/// exactly one source row, so concurrent writes never overlap.
#[derive(Clone, Copy)]
struct SharedState(*mut f32);
unsafe impl Send for SharedState {}
unsafe impl Sync for SharedState {}

impl SharedState {
    /// Going through a method makes closures capture the whole (Sync) wrapper, not the raw
    /// pointer field.
    fn ptr(self) -> *mut f32 {
        self.0
    }
}

/// One colour's lattice: site codes, two states, collision constants.
pub struct Lattice {
    pub(crate) dims: Dims,
    /// Per site: density ρ for green (leaf) and plain medium sites, -ρ for brown (wood) sites,
    /// 0 on the shell (boundary sites only emit).
    pub(crate) codes: Vec<f32>,
    pub(crate) states: [AlignedBuf; 2],
    pub(crate) current: usize,
    /// [`RING`] planes of each intermediate state of [`Lattice::step_sweep`], ring after ring.
    ring: AlignedBuf,
    green: CubicOmega,
    brown: CubicOmega,
    dense_green: Omega,
    dense_brown: Omega,
    keep_f0_green: f32,
    keep_f0_brown: f32,
    isa: KernelIsa,
    pub(crate) boundary: Boundary,
    /// This colour's floor radiance per `(x, z)`, if the bottom face emits one.
    floor: Option<Vec<f32>>,
    /// This colour's volume source, if any.
    pub(crate) source: Option<ColourSource>,
}

impl Lattice {
    /// Builds the lattice for `grid` with colour `colour` of `medium`, interior at zero and
    /// the shell at `boundary`.
    pub fn new(
        grid: &DensityGrid,
        medium: &MediumParams,
        colour: usize,
        boundary: Boundary,
    ) -> Result<Lattice, SolveError> {
        medium.validate()?;
        boundary.validate()?;
        let dims = grid.dims;
        sylva_core::check_memory(
            &format!("an LB solve on a {dims} grid"),
            memory_needed(dims),
        )?;
        let mut codes = vec![0.0f32; dims.sites()];
        codes.par_iter_mut().enumerate().for_each(|(i, c)| {
            let (x, y, z) = dims.coords(i);
            if dims.on_shell(x, y, z) {
                return;
            }
            let rho = grid.density[i];
            *c = if rho > 0.0 && grid.wood[i] as f64 > medium.brown_threshold {
                -rho
            } else {
                rho
            };
        });
        let dense_green = Omega::new(&medium.colours[colour]);
        let dense_brown = Omega::new(&medium.brown_colour(colour));
        let (states, ring) = Lattice::buffers(dims);
        let mut lattice = Lattice {
            dims,
            codes,
            states,
            current: 0,
            ring,
            green: CubicOmega::new(&ReducedOmega::new(&dense_green)),
            brown: CubicOmega::new(&ReducedOmega::new(&dense_brown)),
            dense_green,
            dense_brown,
            keep_f0_green: if medium.zero_f0_on_green { 0.0 } else { 1.0 },
            keep_f0_brown: if medium.zero_f0_on_brown { 0.0 } else { 1.0 },
            isa: KernelIsa::detect(),
            boundary,
            floor: None,
            source: None,
        };
        lattice.reset(boundary);
        Ok(lattice)
    }

    /// The two states and the sweep's ring of a `dims` lattice, zeroed.
    fn buffers(dims: Dims) -> ([AlignedBuf; 2], AlignedBuf) {
        let run = run_stride(dims.nz);
        let len = dims.nx * dims.ny * Q * run;
        (
            [AlignedBuf::zeroed(len), AlignedBuf::zeroed(len)],
            AlignedBuf::zeroed((SWEEP_STEPS - 1) * RING * dims.ny * Q * run),
        )
    }

    /// Interior back to zero, shell to `boundary` (both states), keeping the medium and
    /// the floor.
    pub fn reset(&mut self, boundary: Boundary) {
        self.boundary = boundary;
        let dims = self.dims;
        let nz = dims.nz;
        let stride = run_stride(nz);
        let floor = self.floor.as_deref();
        for state in &mut self.states {
            state
                .par_chunks_mut(Q * stride)
                .enumerate()
                .for_each(|(row, block)| {
                    let (x, y) = (row / dims.ny, row % dims.ny);
                    let whole = x == 0 || y == 0 || x == dims.nx - 1 || y == dims.ny - 1;
                    fill_row(block, nz, &boundary, whole);
                    if y == 0 {
                        fill_floor_row(block, nz, &boundary, floor, x);
                    }
                });
        }
        // Ring planes stand for interior planes: only their shell rows are whole boundary
        // (the floor row is refreshed for each plane as the sweep reaches it).
        for (row, block) in self.ring.chunks_mut(Q * stride).enumerate() {
            let y = row % dims.ny;
            fill_row(block, nz, &boundary, y == 0 || y == dims.ny - 1);
        }
        self.current = 0;
    }

    /// Sets this colour's volume source (`None`: none); it acts from the next step on.
    pub fn set_source(&mut self, source: Option<ColourSource>) {
        if let Some(s) = &source {
            assert_eq!(s.strength.len(), self.dims.sites(), "one strength per site");
        }
        self.source = source;
    }

    /// Sets this colour's floor radiance per `(x, z)` (`None`: the bottom face emits the
    /// boundary); takes effect at the next [`Lattice::reset`].
    pub fn set_floor(&mut self, floor: Option<Vec<f32>>) {
        if let Some(f) = &floor {
            assert_eq!(f.len(), self.dims.nx * self.dims.nz, "one value per (x, z)");
        }
        self.floor = floor;
    }

    /// Runs `isa`'s kernel instead of the widest this CPU has (tests and benchmarks compare
    /// them). Panics if this CPU lacks its instructions.
    pub fn set_kernel(&mut self, isa: KernelIsa) {
        assert!(
            isa.is_supported(),
            "this CPU cannot run the {} LB kernel",
            isa.name()
        );
        self.isa = isa;
    }

    pub fn kernel(&self) -> KernelIsa {
        self.isa
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    /// The code of site `i` (site order): its density, negated on brown sites, 0 on the
    /// shell.
    pub fn code(&self, i: usize) -> f32 {
        self.codes[i]
    }

    /// This colour's volume source strength at site `i` (0 without a source).
    pub fn source_strength(&self, i: usize) -> f32 {
        self.source.as_ref().map_or(0.0, |s| s.strength[i])
    }

    /// State index of `f_m` at (x, y, z).
    #[inline]
    pub fn state_index(&self, x: usize, y: usize, z: usize, m: usize) -> usize {
        ((x * self.dims.ny + y) * Q + m) * run_stride(self.dims.nz) + 1 + z
    }

    /// `f_m` at (x, y, z) in the current state.
    pub fn f(&self, x: usize, y: usize, z: usize, m: usize) -> f32 {
        self.states[self.current][self.state_index(x, y, z, m)]
    }

    /// Sets `f_m` at an interior site of the current state (for custom initial conditions).
    pub fn set_f(&mut self, x: usize, y: usize, z: usize, m: usize, value: f32) {
        assert!(
            !self.dims.on_shell(x, y, z),
            "shell sites hold the boundary"
        );
        let i = self.state_index(x, y, z, m);
        self.states[self.current][i] = value;
    }

    /// A copy of the current state, for [`Lattice::extrapolate`].
    pub fn snapshot(&self) -> Vec<f32> {
        self.states[self.current].to_vec()
    }

    /// Chunks of the state and of a snapshot of it, side by side, in parallel.
    fn with_snapshot<T: Send>(
        &mut self,
        snapshot: &mut [f32],
        each: impl Fn(&mut [f32], &mut [f32]) -> T + Sync + Send,
    ) -> Vec<T> {
        let state = &mut self.states[self.current];
        assert_eq!(state.len(), snapshot.len(), "a snapshot of this lattice");
        state
            .par_chunks_mut(1 << 16)
            .zip(snapshot.par_chunks_mut(1 << 16))
            .map(|(f, e)| each(f, e))
            .collect()
    }

    /// Moves the state along its change since `earlier` (a [`Lattice::snapshot`]):
    /// `f += factor · (f − earlier)`, clamped at 0, and makes `earlier` a copy of the result.
    /// The shell's values never change, so they stay.
    pub fn extrapolate(&mut self, earlier: &mut [f32], factor: f32) {
        self.with_snapshot(earlier, |f, e| {
            for (f, e) in f.iter_mut().zip(e) {
                *f = (*f + factor * (*f - *e)).max(0.0);
                *e = *f;
            }
        });
    }

    /// The L2 norms of the state's change since `earlier` and of the state itself (summed
    /// in fixed chunks: the same bits on any thread count); with `refresh`, `earlier`
    /// becomes a copy of the state in the same pass.
    pub fn change_since(&mut self, earlier: &mut [f32], refresh: bool) -> (f64, f64) {
        let parts = self.with_snapshot(earlier, |f, e| {
            let (mut d, mut n) = (0.0, 0.0);
            for (f, e) in f.iter().zip(e.iter_mut()) {
                let (a, b) = (f64::from(*f), f64::from(*e));
                d += (a - b) * (a - b);
                n += a * a;
                if refresh {
                    *e = *f;
                }
            }
            (d, n)
        });
        let (d, n) = parts
            .iter()
            .fold((0.0, 0.0), |(a, b), &(d, n)| (a + d, b + n));
        (d.sqrt(), n.sqrt())
    }

    /// Σ_m f_m per site of the current state.
    pub fn site_totals(&self) -> Vec<f32> {
        let dims = self.dims;
        let nz = dims.nz;
        let state = &self.states[self.current];
        let mut out = vec![0.0f32; dims.sites()];
        let stride = run_stride(nz);
        out.par_chunks_mut(nz)
            .zip(state.par_chunks(Q * stride))
            .for_each(|(o, block)| {
                for m in 0..Q {
                    for (acc, v) in o.iter_mut().zip(&block[m * stride + 1..]) {
                        *acc += v;
                    }
                }
            });
        out
    }

    /// Floats in one x-plane of the state (ny rows of 19 padded runs).
    fn plane_len(&self) -> usize {
        self.dims.ny * Q * run_stride(self.dims.nz)
    }

    /// Collides and streams row y of plane x, read from `block`, into the three target
    /// planes (x - 1, x, x + 1; null where that plane is on the shell). Returns the row's
    /// interior total before the step.
    ///
    /// # Safety
    /// As [`row_targets`] and [`process_row`]: each (row, direction) run of the targets is
    /// written by this row alone.
    unsafe fn sweep_row(
        &self,
        block: &[f32],
        x: usize,
        y: usize,
        planes: [*mut f32; 3],
        sink: &mut [f32],
    ) -> f64 {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        if x == 0 || y == 0 || x == nx - 1 || y == ny - 1 {
            stream_shell_row(block, planes, ny, nz, y);
            return 0.0;
        }
        let row = x * ny + y;
        let params = RowParams {
            green: &self.green,
            brown: &self.brown,
            keep_f0_green: self.keep_f0_green,
            keep_f0_brown: self.keep_f0_brown,
            boundary: &self.boundary.values,
            source: self.source.as_ref().map(|s| RowSource {
                strength: &s.strength[row * nz..(row + 1) * nz],
                green: &s.green,
                brown: &s.brown,
            }),
        };
        let targets = row_targets(planes, sink.as_mut_ptr(), ny, nz, y);
        process_row(
            self.isa,
            block.as_ptr(),
            nz,
            &self.codes[row * nz..(row + 1) * nz],
            &params,
            &targets,
        ) as f64
    }

    /// Advances one step with the vector kernel; returns the total density of the interior
    /// before the step (the convergence monitor).
    pub fn step(&mut self) -> f64 {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let plane_len = self.plane_len();
        let block_len = Q * run_stride(nz);
        let mut states = std::mem::replace(
            &mut self.states,
            [AlignedBuf::zeroed(0), AlignedBuf::zeroed(0)],
        );
        let (a, b) = states.split_at_mut(1);
        let (src, dst) = if self.current == 0 {
            (&a[0], &mut b[0])
        } else {
            (&b[0], &mut a[0])
        };
        let dst = SharedState(dst.as_mut_ptr());
        let plane = |t: usize| {
            if t == 0 || t >= nx - 1 {
                SharedState(std::ptr::null_mut())
            } else {
                // SAFETY: t < nx, inside the state.
                SharedState(unsafe { dst.ptr().add(t * plane_len) })
            }
        };
        let this = &*self;
        // Planes in parallel, rows in order; per-plane totals in plane order, so the sum is
        // the same for any thread count.
        let totals: Vec<f64> = (0..nx)
            .into_par_iter()
            .map_init(
                || vec![0.0f32; nz + 2],
                |sink, x| {
                    let planes = [plane(x.wrapping_sub(1).min(nx)), plane(x), plane(x + 1)];
                    let mut plane_total = 0.0f64;
                    for y in 0..ny {
                        let row = x * ny + y;
                        let block = &src[row * block_len..(row + 1) * block_len];
                        // Fetch the next row's 19 runs while this one computes: the hardware
                        // prefetchers lose track of 19 interleaved runs per row.
                        if y + 1 < ny {
                            crate::kernel::prefetch(
                                &src[(row + 1) * block_len..(row + 2) * block_len],
                            );
                        }
                        // SAFETY: each (row, m) run of `dst` is written by exactly one source
                        // row, so planes never write the same floats.
                        plane_total += unsafe {
                            this.sweep_row(block, x, y, planes.map(SharedState::ptr), sink)
                        };
                    }
                    plane_total
                },
            )
            .collect();
        self.states = states;
        self.current ^= 1;
        totals.iter().sum()
    }

    /// Advances two steps in one sweep over memory and returns the interior totals before
    /// each: [`Lattice::step_sweep`] of two steps.
    pub fn step_pair(&mut self) -> (f64, f64) {
        let totals = self.step_sweep(2);
        (totals[0], totals[1])
    }

    /// Advances `steps` steps (2 to [`SWEEP_STEPS`]) in one sweep over memory (temporal
    /// blocking) and returns the interior totals before each.
    ///
    /// Step t of plane x reads only plane x and writes planes x - 1..=x + 1 of state t + 1,
    /// so after plane x + 1, plane x of state t + 1 is complete. Sweep stage x therefore runs
    /// step t + s of plane x - 2s for every s < `steps`: step t reads the current state,
    /// each intermediate state t + s lives in a ring of four planes that stays in cache
    /// (plane x - 2s is read while x - 2s + 1..=x - 2s + 3 are written), and the last step
    /// writes back into the current state, whose planes up to x - 1 step t has already
    /// consumed. Main memory sees one read and one write of the state per sweep. The result
    /// is identical to `steps` calls of [`Lattice::step`].
    pub fn step_sweep(&mut self, steps: usize) -> Vec<f64> {
        assert!(
            (2..=SWEEP_STEPS).contains(&steps),
            "a sweep advances 2 to {SWEEP_STEPS} steps, not {steps}"
        );
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let plane_len = self.plane_len();
        let block_len = Q * run_stride(nz);
        let mut state = std::mem::replace(&mut self.states[self.current], AlignedBuf::zeroed(0));
        let mut ring = std::mem::replace(&mut self.ring, AlignedBuf::zeroed(0));
        let a = SharedState(state.as_mut_ptr());
        let r = SharedState(ring.as_mut_ptr());
        let interior = |t: usize| t >= 1 && t < nx - 1;
        let null = SharedState(std::ptr::null_mut());
        // SAFETY (both closures): t < nx, 1 <= s < SWEEP_STEPS and slots < RING lie inside
        // their buffers.
        let a_plane = |t: usize| {
            if interior(t) {
                SharedState(unsafe { a.ptr().add(t * plane_len) })
            } else {
                null
            }
        };
        // Plane t of intermediate state t + s, in ring s.
        let r_plane = |s: usize, t: usize| {
            if interior(t) {
                SharedState(unsafe { r.ptr().add(((s - 1) * RING + t % RING) * plane_len) })
            } else {
                null
            }
        };
        // What step s reads of plane p: the current state, or its intermediate state's ring;
        // shell planes hold the boundary in every state, so they are read from the state.
        let source = |s: usize, p: usize| {
            if s == 0 || !interior(p) {
                unsafe { a.ptr().add(p * plane_len) }
            } else {
                r_plane(s, p).ptr()
            }
        };
        // Where step s writes plane p's results: planes p - 1..=p + 1 of the next ring, or of
        // the state for the last step.
        let targets = |s: usize, p: usize| {
            let plane = |t: usize| {
                if s + 1 == steps {
                    a_plane(t)
                } else {
                    r_plane(s + 1, t)
                }
            };
            [plane(p.wrapping_sub(1)), plane(p), plane(p + 1)].map(SharedState::ptr)
        };
        let mut totals = vec![vec![0.0f64; nx]; steps];
        let this = &*self;
        for x in 0..nx + 2 * (steps - 1) {
            // The ring slot each later step reads this stage stands for plane x - 2s: give
            // its floor row that plane's values (the step before writes the other three).
            for s in 1..steps {
                if self.floor.is_some() && x >= 2 * s && interior(x - 2 * s) {
                    let p = x - 2 * s;
                    // SAFETY: row 0 of ring s's slot for plane p lies inside the ring, and
                    // nothing else touches it during this stage.
                    let row =
                        unsafe { std::slice::from_raw_parts_mut(r_plane(s, p).ptr(), block_len) };
                    fill_floor_row(row, nz, &self.boundary, self.floor.as_deref(), p);
                }
            }
            // Job j: step s of plane p.
            let jobs: Vec<(usize, usize)> = (0..steps)
                .filter_map(|s| x.checked_sub(2 * s).filter(|&p| p < nx).map(|p| (s, p)))
                .collect();
            let rows: Vec<f64> = (0..jobs.len() * ny)
                .into_par_iter()
                .map_init(
                    || vec![0.0f32; nz + 2],
                    |sink, i| {
                        let ((s, p), y) = (jobs[i / ny], i % ny);
                        let src = source(s, p);
                        // SAFETY: the source row is complete and no job of this stage writes
                        // it; jobs write disjoint planes (ring s + 1's slots p - 1..=p + 1,
                        // which ring s + 1's reader, plane p - 2, does not share; state planes
                        // below x - 2s + 4 - 2·steps, which step 0 has consumed), and rows of
                        // one job disjoint runs.
                        unsafe {
                            let block =
                                std::slice::from_raw_parts(src.add(y * block_len), block_len);
                            if y + 1 < ny {
                                crate::kernel::prefetch(std::slice::from_raw_parts(
                                    src.add((y + 1) * block_len),
                                    block_len,
                                ));
                            }
                            this.sweep_row(block, p, y, targets(s, p), sink)
                        }
                    },
                )
                .collect();
            for (j, &(s, p)) in jobs.iter().enumerate() {
                totals[s][p] = rows[j * ny..(j + 1) * ny].iter().sum();
            }
        }
        self.states[self.current] = state;
        self.ring = ring;
        totals.iter().map(|t| t.iter().sum()).collect()
    }

    /// Advances one step with a direct scalar implementation of eq. 2 in f64 (the dense Ω,
    /// site by site): the reference the vector kernel is tested against.
    pub fn step_reference(&mut self) {
        let dims = self.dims;
        let next = self.current ^ 1;
        let src = self.states[self.current].to_vec();
        let mut dst = self.states[next].to_vec();
        for x in 0..dims.nx {
            for y in 0..dims.ny {
                for z in 0..dims.nz {
                    let (post, _) = self.post_collision(&src, x, y, z);
                    for (m, c) in crate::lattice::C.iter().enumerate() {
                        let (tx, ty, tz) = (
                            x as isize + c[0] as isize,
                            y as isize + c[1] as isize,
                            z as isize + c[2] as isize,
                        );
                        let inside = |v: isize, n: usize| v >= 1 && v <= n as isize - 2;
                        if inside(tx, dims.nx) && inside(ty, dims.ny) && inside(tz, dims.nz) {
                            let i = self.state_index(tx as usize, ty as usize, tz as usize, m);
                            dst[i] = post[m] as f32;
                        }
                    }
                }
            }
        }
        self.states[next].copy_from_slice(&dst);
        self.current = next;
    }

    /// Post-collision values of one site in f64, and `f_0` before any zeroing.
    pub(crate) fn post_collision(
        &self,
        state: &[f32],
        x: usize,
        y: usize,
        z: usize,
    ) -> ([f64; Q], f64) {
        let code = self.codes[self.dims.index(x, y, z)] as f64;
        let f: [f64; Q] = std::array::from_fn(|m| state[self.state_index(x, y, z, m)] as f64);
        let (omega, rho, keep) = if code < 0.0 {
            (&self.dense_brown, -code, self.keep_f0_brown)
        } else {
            (
                &self.dense_green,
                code,
                if code > 0.0 { self.keep_f0_green } else { 1.0 },
            )
        };
        let mut post = [0.0; Q];
        for (m, p) in post.iter_mut().enumerate() {
            let acc: f64 = omega.0[m].iter().zip(&f).map(|(o, v)| o * v).sum();
            *p = f[m] + rho * acc;
        }
        if let Some(s) = &self.source {
            let i = self.dims.index(x, y, z);
            let profile = if code < 0.0 { &s.brown } else { &s.green };
            for (m, p) in post.iter_mut().enumerate() {
                *p += s.strength[i] as f64 * profile[m] as f64;
            }
        }
        let raw_f0 = post[0];
        post[0] *= keep as f64;
        (post, raw_f0)
    }

    /// The flows one step from the current state would move (f64, scalar).
    pub fn flows(&self) -> Flows {
        let dims = self.dims;
        let state = &self.states[self.current];
        let mut flows = Flows {
            inflow: 0.0,
            outflow: 0.0,
            absorbed: 0.0,
            sourced: 0.0,
        };
        let inside = |v: isize, n: usize| v >= 1 && v <= n as isize - 2;
        for x in 0..dims.nx {
            for y in 0..dims.ny {
                for z in 0..dims.nz {
                    let shell = dims.on_shell(x, y, z);
                    let code = self.codes[dims.index(x, y, z)];
                    let (post, raw_f0) = self.post_collision(state, x, y, z);
                    if !shell && code != 0.0 {
                        flows.absorbed += raw_f0 - post[0];
                    }
                    if let (Some(s), false) = (&self.source, shell) {
                        let profile = if code < 0.0 { &s.brown } else { &s.green };
                        let i = dims.index(x, y, z);
                        flows.sourced +=
                            s.strength[i] as f64 * profile.iter().map(|&v| v as f64).sum::<f64>();
                    }
                    for (m, c) in crate::lattice::C.iter().enumerate().skip(1) {
                        let t = (
                            x as isize + c[0] as isize,
                            y as isize + c[1] as isize,
                            z as isize + c[2] as isize,
                        );
                        let lands_inside =
                            inside(t.0, dims.nx) && inside(t.1, dims.ny) && inside(t.2, dims.nz);
                        if shell && lands_inside {
                            flows.inflow += post[m];
                        } else if !shell && !lands_inside {
                            flows.outflow += post[m];
                        }
                    }
                }
            }
        }
        flows
    }

    /// Sets the interior of the current state to this problem's light solved on a grid of
    /// half the resolution ([`Lattice::restricted`], run as [`SolveOptions::coarse_level`]),
    /// interpolated ([`Lattice::prolong_from`]).
    fn start_from_coarse(&mut self) -> Result<(), SolveError> {
        let coarse_dims = coarse_dims(self.dims);
        sylva_core::check_memory(
            &format!(
                "the coarse start ({coarse_dims}) of an LB solve on a {} grid",
                self.dims
            ),
            memory_needed(self.dims) + memory_needed(coarse_dims),
        )?;
        let mut coarse = self.restricted();
        coarse.run(&SolveOptions::coarse_level(coarse_dims), &mut |_, _| {})?;
        self.prolong_from(&coarse);
        Ok(())
    }

    /// The same problem on [`coarse_dims`]: coarse site `J` covers the fine interior sites
    /// `2J - 1` and `2J` of each axis. Its optical depth per step is twice the mean of its
    /// sites' (`ρ = 1 - e^{-τ}`: a coarse step crosses two fine cells), brown where brown
    /// sites hold most of the density; a volume source gives twice its sites' mean per step
    /// and the floor its sites' mean. Boundary, collision and kernel are the same.
    pub fn restricted(&self) -> Lattice {
        let fine = self.dims;
        let dims = coarse_dims(fine);
        // The fine interior sites a coarse interior coordinate covers on an axis of `n`.
        let children = |j: usize, n: usize| (2 * j - 1)..(2 * j + 1).min(n - 1);
        let source = self.source.as_ref();
        // Per coarse site: its code and, with a source, its strength.
        let (codes, strength): (Vec<f32>, Vec<f32>) = (0..dims.sites())
            .into_par_iter()
            .map(|i| {
                let (x, y, z) = dims.coords(i);
                if dims.on_shell(x, y, z) {
                    return (0.0, 0.0);
                }
                let (mut tau, mut n, mut green, mut brown, mut s) = (0.0f64, 0, 0.0, 0.0, 0.0);
                for fx in children(x, fine.nx) {
                    for fy in children(y, fine.ny) {
                        for fz in children(z, fine.nz) {
                            let i = fine.index(fx, fy, fz);
                            let c = f64::from(self.codes[i]);
                            tau -= (1.0 - c.abs().min(MAX_RESTRICTED_DENSITY)).ln();
                            if c < 0.0 {
                                brown -= c;
                            } else {
                                green += c;
                            }
                            s += source.map_or(0.0, |src| f64::from(src.strength[i]));
                            n += 1;
                        }
                    }
                }
                let rho = 1.0 - (-2.0 * tau / f64::from(n)).exp();
                let code = if brown > green { -rho } else { rho };
                (code as f32, (2.0 * s / f64::from(n)) as f32)
            })
            .unzip();
        let floor = self.floor.as_ref().map(|f| {
            // Shell columns keep their own value; interior ones average their sites'.
            let cover = |j: usize, n: usize, nc: usize| {
                if j == 0 {
                    0..1
                } else if j == nc - 1 {
                    n - 1..n
                } else {
                    children(j, n)
                }
            };
            let mut out = vec![0.0f32; dims.nx * dims.nz];
            for x in 0..dims.nx {
                for z in 0..dims.nz {
                    let (mut sum, mut n) = (0.0f64, 0u32);
                    for fx in cover(x, fine.nx, dims.nx) {
                        for fz in cover(z, fine.nz, dims.nz) {
                            sum += f64::from(f[fx * fine.nz + fz]);
                            n += 1;
                        }
                    }
                    out[x * dims.nz + z] = (sum / f64::from(n)) as f32;
                }
            }
            out
        });
        let (states, ring) = Lattice::buffers(dims);
        let mut coarse = Lattice {
            dims,
            codes,
            states,
            current: 0,
            ring,
            green: self.green.clone(),
            brown: self.brown.clone(),
            dense_green: self.dense_green.clone(),
            dense_brown: self.dense_brown.clone(),
            keep_f0_green: self.keep_f0_green,
            keep_f0_brown: self.keep_f0_brown,
            isa: self.isa,
            boundary: self.boundary,
            floor,
            source: source.map(|s| ColourSource {
                strength,
                green: s.green,
                brown: s.brown,
            }),
        };
        coarse.reset(self.boundary);
        coarse
    }

    /// Sets every interior site of the current state to `coarse`'s current state
    /// ([`Lattice::restricted`] of this one) interpolated trilinearly, direction by
    /// direction: fine site `i` lies at coarse coordinate `(i + 1/2) / 2`.
    pub fn prolong_from(&mut self, coarse: &Lattice) {
        let (dims, cd) = (self.dims, coarse.dims);
        assert_eq!(cd, coarse_dims(dims), "a lattice restricted from this one");
        let stride = run_stride(dims.nz);
        let cstate = &coarse.states[coarse.current];
        // The lower coarse neighbour and the weight of the upper one.
        let axis = |i: usize, n: usize| {
            let c = ((i as f32 + 0.5) * 0.5).min((n - 1) as f32);
            let lo = (c as usize).min(n - 2);
            (lo, c - lo as f32)
        };
        let zs: Vec<(usize, f32)> = (0..dims.nz).map(|z| axis(z, cd.nz)).collect();
        self.states[self.current]
            .par_chunks_mut(Q * stride)
            .enumerate()
            .for_each(|(row, block)| {
                let (x, y) = (row / dims.ny, row % dims.ny);
                if x == 0 || y == 0 || x == dims.nx - 1 || y == dims.ny - 1 {
                    return;
                }
                let (x0, wx) = axis(x, cd.nx);
                let (y0, wy) = axis(y, cd.ny);
                let corners = [
                    (x0, y0, (1.0 - wx) * (1.0 - wy)),
                    (x0 + 1, y0, wx * (1.0 - wy)),
                    (x0, y0 + 1, (1.0 - wx) * wy),
                    (x0 + 1, y0 + 1, wx * wy),
                ];
                // Bilinear in x and y along the whole coarse run first, then linear in z.
                let mut column = vec![0.0f32; cd.nz];
                for m in 0..Q {
                    column.fill(0.0);
                    for &(cx, cy, w) in &corners {
                        let start = coarse.state_index(cx, cy, 0, m);
                        let coarse_run = &cstate[start..start + cd.nz];
                        for (c, &v) in column.iter_mut().zip(coarse_run) {
                            *c += w * v;
                        }
                    }
                    let run = &mut block[m * stride + 1..m * stride + 1 + dims.nz];
                    for z in 1..dims.nz - 1 {
                        let (z0, wz) = zs[z];
                        let (lo, hi) = (column[z0], column[z0 + 1]);
                        run[z] = lo + wz * (hi - lo);
                    }
                }
            });
    }

    /// Steps until `opts` says stop. `progress(step, residual)` is called after every step.
    pub fn run(
        &mut self,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, f64),
    ) -> Result<SolveReport, SolveError> {
        opts.validate()?;
        let mut monitor = RunMonitor::new(opts);
        let mut extrapolation = if opts.extrapolate {
            sylva_core::check_memory(
                &format!("an extrapolated LB solve on a {} grid", self.dims),
                memory_needed(self.dims) + 2 * (self.states[0].len() * 4) as u64,
            )?;
            Some(if opts.coarse_start {
                Extrapolation::from(self.dims, 3 * self.dims.longest_edge() / 4)
            } else {
                Extrapolation::new(self.dims)
            })
        } else {
            None
        };
        if opts.coarse_start {
            self.start_from_coarse()?;
        }
        // With a tolerance the monitor checks after every pair of steps (the rule the GPU
        // backend shares, so both stop after the same step); without one, after whatever
        // the sweep advanced.
        let batch = if opts.tolerance.is_some() {
            2
        } else {
            SWEEP_STEPS
        };
        let mut done = 0;
        while monitor.steps_left() > 0 {
            // Several steps per sweep over memory where they remain. Each step reports the
            // total of the state it started from, so the change over the previous step is
            // known one step late; that is all the monitor needs.
            let mut steps = monitor.steps_left().min(batch);
            if let Some(x) = &extrapolation {
                steps = steps.min(x.steps_to_checkpoint(done));
            }
            if steps >= 2 {
                monitor.record(&self.step_sweep(steps), progress);
            } else {
                monitor.record(&[self.step()], progress);
            }
            done += steps;
            if let Some(x) = &mut extrapolation {
                x.after(done, self);
            }
        }
        Ok(monitor.report())
    }
}

/// The three colours of `medium`, each solved by `solve(colour, lattice)` once, except that a
/// colour with the same parameters (green and brown) and boundary as an earlier one copies
/// its result. `solve` gets the lattice the previous solve returned (one lattice's memory,
/// reused colour after colour) and returns it with the colour's site totals and report. CPU
/// and GPU solvers share this.
pub fn solve_colours<L, E>(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
    floor: Option<&Floor>,
    source: Option<&VolumeSource>,
    mut solve: impl FnMut(usize, Option<L>) -> Result<(L, Vec<f32>, SolveReport), E>,
) -> Result<(LightingGrid, Vec<SolveReport>), E> {
    let mut colours: [Vec<f32>; 3] = Default::default();
    let mut reports: Vec<SolveReport> = Vec::with_capacity(3);
    let mut lattice: Option<L> = None;
    let same = |p: usize, c: usize| {
        medium.colours[p] == medium.colours[c]
            && medium.brown_colour(p) == medium.brown_colour(c)
            && boundaries[p] == boundaries[c]
            && floor.is_none_or(|f| f.radiance[p] == f.radiance[c])
            && source.is_none_or(|s| {
                s.strength[p] == s.strength[c]
                    && s.green[p] == s.green[c]
                    && s.brown[p] == s.brown[c]
            })
    };
    for c in 0..3 {
        if let Some(prev) = (0..c).find(|&p| same(p, c)) {
            colours[c] = colours[prev].clone();
            reports.push(reports[prev]);
            continue;
        }
        let (lat, totals, report) = solve(c, lattice.take())?;
        colours[c] = totals;
        reports.push(report);
        lattice = Some(lat);
    }
    Ok((
        LightingGrid {
            dims: grid.dims,
            bounds: grid.bounds,
            colours,
        },
        reports,
    ))
}

/// Lights `grid` in all three colours with the sun boundary `boundary`. Colours with
/// identical parameters are solved once. `progress(colour, step, residual)`.
pub fn solve_lighting(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundary: Boundary,
    opts: &SolveOptions,
    progress: &mut dyn FnMut(usize, usize, f64),
) -> Result<(LightingGrid, Vec<SolveReport>), SolveError> {
    solve_lighting_rgb(grid, medium, &[boundary; 3], None, None, opts, progress)
}

/// Lights `grid` in all three colours, colour `c` under `boundaries[c]` (the LB is solved
/// per colour anyway; sky and ground light have colours of their own), with a `floor`, the
/// ground's light from the bottom face, and with a `source`, light emitted inside the
/// medium. Colours with identical parameters, boundaries and sources are solved once.
/// `progress(colour, step, residual)`.
pub fn solve_lighting_rgb(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
    floor: Option<&Floor>,
    source: Option<&VolumeSource>,
    opts: &SolveOptions,
    progress: &mut dyn FnMut(usize, usize, f64),
) -> Result<(LightingGrid, Vec<SolveReport>), SolveError> {
    solve_lighting_rgb_on(
        KernelIsa::detect(),
        grid,
        medium,
        boundaries,
        floor,
        source,
        opts,
        progress,
    )
}

/// [`solve_lighting_rgb`] with `kernel` instead of the widest kernel this CPU runs (the CPU
/// must support it).
#[allow(clippy::too_many_arguments)]
pub fn solve_lighting_rgb_on(
    kernel: KernelIsa,
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
    floor: Option<&Floor>,
    source: Option<&VolumeSource>,
    opts: &SolveOptions,
    progress: &mut dyn FnMut(usize, usize, f64),
) -> Result<(LightingGrid, Vec<SolveReport>), SolveError> {
    medium.validate()?;
    opts.validate()?;
    if let Some(f) = floor {
        f.validate(grid.dims)?;
    }
    if let Some(s) = source {
        s.validate(grid.dims)?;
    }
    solve_colours(
        grid,
        medium,
        boundaries,
        floor,
        source,
        |c, lattice: Option<Lattice>| {
            let boundary = boundaries[c];
            let mut lat = match lattice {
                Some(mut l) => {
                    l.dense_green = Omega::new(&medium.colours[c]);
                    l.dense_brown = Omega::new(&medium.brown_colour(c));
                    l.green = CubicOmega::new(&ReducedOmega::new(&l.dense_green));
                    l.brown = CubicOmega::new(&ReducedOmega::new(&l.dense_brown));
                    l
                }
                None => Lattice::new(grid, medium, c, boundary)?,
            };
            lat.set_kernel(kernel);
            lat.set_floor(floor.map(|f| f.radiance[c].clone()));
            lat.set_source(source.map(|s| s.colour(c)));
            lat.reset(boundary);
            let report = lat.run(opts, &mut |s, r| progress(c, s, r))?;
            let totals = lat.site_totals();
            Ok((lat, totals, report))
        },
    )
}
