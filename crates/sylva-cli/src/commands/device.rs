//! `--device cpu|gpu|auto` and `--precision f32|f16`: which LB backend runs the solver
//! (chosen by `sylva_lb_gpu::select_solver`), and for `render` and `bench trace` also where
//! rays are traced (one device opened for both).

use anyhow::Result;
use clap::ValueEnum;
use sylva_lb::{LbSolver, OnSchedule, Schedule};
use sylva_lb_gpu::{select_solver, solver_on, Device, LbGpuError, Precision};
use sylva_wgpu::{open_device, GpuContext};

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

/// How long each LB solve runs (`--lb-schedule`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ScheduleArg {
    /// A half-resolution solve first, interpolated, then 1 × the grid's longest edge in
    /// steps, extrapolated along the slowest mode (the CPU solver only; its default).
    Coarse,
    /// 1.5 × the grid's longest edge in steps from an empty grid, extrapolated along the
    /// slowest mode (the CPU solver only).
    Extrapolated,
    /// The papers' 2 × the longest edge, plain steps.
    Papers,
}

/// `solver` on the schedule a user asked for (`None`: its own). The GPU kernels do not
/// extrapolate, so asking for it there is an error, not a silent change.
pub fn on_schedule(
    solver: Box<dyn LbSolver>,
    schedule: Option<ScheduleArg>,
) -> Result<Box<dyn LbSolver>> {
    let Some(arg) = schedule else {
        return Ok(solver);
    };
    let schedule = match arg {
        ScheduleArg::Papers => Schedule::Papers,
        ScheduleArg::Extrapolated => Schedule::Extrapolated,
        ScheduleArg::Coarse => Schedule::CoarseStarted,
    };
    if schedule != Schedule::Papers && solver.device() != "cpu" {
        let name = arg.to_possible_value().expect("every schedule has a name");
        let name = name.get_name();
        anyhow::bail!(
            "--lb-schedule {name} runs on the CPU solver only (the GPU kernels do not \
             extrapolate): use --device cpu, or --lb-schedule papers"
        );
    }
    Ok(Box::new(OnSchedule::new(solver, schedule)))
}

/// The summary line naming the LB solver and its schedule.
pub fn solver_line(solver: &dyn LbSolver) -> String {
    let schedule = match solver.schedule() {
        Schedule::Extrapolated => "1.5 × the grid's edge in steps, extrapolated",
        Schedule::CoarseStarted => {
            "1 × the grid's edge in steps from a half-resolution solve (1.5 × from empty below \
             64 sites), extrapolated"
        }
        Schedule::Papers => "the papers' 2 × the grid's edge in steps",
    };
    format!("LB solver: {}; {schedule}", solver.describe())
}

fn device(d: DeviceArg) -> Device {
    match d {
        DeviceArg::Cpu => Device::Cpu,
        DeviceArg::Gpu => Device::Gpu,
        DeviceArg::Auto => Device::Auto,
    }
}

fn precision(p: PrecisionArg) -> Precision {
    match p {
        PrecisionArg::F32 => Precision::F32,
        PrecisionArg::F16 => Precision::F16,
    }
}

fn solver_error(e: LbGpuError, device: Device) -> anyhow::Error {
    match e {
        LbGpuError::F16OnCpu => {
            anyhow::anyhow!("--precision f16 is a GPU state format; the CPU solver stores f32")
        }
        e if device == Device::Gpu => anyhow::Error::new(e).context("--device gpu"),
        e => e.into(),
    }
}

/// The LB backend `device` and `precision` ask for; a note about the choice (a software
/// adapter, `auto` falling back to the CPU) goes to stderr.
pub fn open_solver(
    device_arg: DeviceArg,
    precision_arg: PrecisionArg,
) -> Result<Box<dyn LbSolver>> {
    let d = device(device_arg);
    let selected = select_solver(d, precision(precision_arg)).map_err(|e| solver_error(e, d))?;
    if let Some(note) = &selected.note {
        eprintln!("note: {note}");
    }
    Ok(selected.solver)
}

/// The GPU `device` asks for (`None`: the CPU), opened once for the LB solver and the ray
/// tracer; a note about the choice goes to stderr.
pub fn open_gpu(device_arg: DeviceArg) -> Result<Option<GpuContext>> {
    let d = device(device_arg);
    let opened = open_device(d).map_err(|e| solver_error(e.into(), d))?;
    if let Some(note) = &opened.note {
        eprintln!("note: {note}");
    }
    Ok(opened.gpu)
}

/// The LB backend on `gpu` (or the CPU) storing its state at `precision_arg`.
pub fn solver_for(
    gpu: Option<&GpuContext>,
    device_arg: DeviceArg,
    precision_arg: PrecisionArg,
) -> Result<Box<dyn LbSolver>> {
    solver_on(gpu.cloned(), precision(precision_arg))
        .map_err(|e| solver_error(e, device(device_arg)))
}
