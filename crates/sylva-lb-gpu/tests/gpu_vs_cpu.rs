//! The GPU solver against the CPU solver (the oracle): same grids, same parameters, same
//! step counts and stop rules, results within 1e-5 relative in f32.
//!
//! These run on whatever adapter there is, software ones (lavapipe, as in CI) included.
//! Where no adapter exists at all they say SKIPPED (fail under `SYLVA_REQUIRE_GPU=1`, as in CI).

use sylva_lb::lattice::Q;
use sylva_lb::{
    solve_lighting, Boundary, ColourParams, DensityGrid, Dims, Floor, Lattice, LbSolver,
    LbSolverError, MediumParams, Preset, Schedule, SolveOptions, StopReason, VolumeSource,
};
use sylva_lb_gpu::{
    select_solver, solve_lighting_gpu, AdapterChoice, ContextOptions, Device, GpuContext, GpuError,
    GpuLattice, GpuSolver, LbGpuError, Precision,
};
use sylva_testkit::gpu_context;

fn context() -> Option<GpuContext> {
    gpu_context(&ContextOptions::new(AdapterChoice::Any))
}

/// A deterministic medium with empty, green and brown sites in a non-cubic grid.
fn mixed_grid(dims: Dims) -> DensityGrid {
    let mut g = DensityGrid::empty(dims);
    let mut state = 0x9e37_79b9_u32;
    for i in 0..dims.sites() {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let r = (state % 1000) as f32 / 1000.0;
        let (x, _, _) = dims.coords(i);
        // A third empty, the rest leafy; a trunk-like slab of wood.
        if r > 0.33 {
            g.density[i] = r;
            if x == dims.nx / 2 {
                g.wood[i] = 0.8;
            }
        }
    }
    g
}

fn anisotropic_medium(zero_f0_on_brown: bool) -> MediumParams {
    MediumParams {
        // Forward, the backward limit and the forward limit (the g = ±1 special cases).
        colours: [
            ColourParams {
                sigma_a: 0.1,
                sigma_s: 0.85,
                g: 0.6,
            },
            ColourParams {
                sigma_a: 0.05,
                sigma_s: 0.9,
                g: -1.0,
            },
            ColourParams {
                sigma_a: 0.2,
                sigma_s: 0.7,
                g: 1.0,
            },
        ],
        zero_f0_on_green: true,
        zero_f0_on_brown,
        brown_threshold: 0.5,
        brown: None,
    }
}

fn sun() -> Boundary {
    Boundary::sun([0.3, -0.9, 0.2], 1.0)
}

/// Largest |a - b| relative to |b|, with a floor of 1e-3 of the largest value so that
/// sites with almost no light do not dominate.
fn max_relative_error(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64));
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).abs() / (y.abs() as f64).max(1e-3 * scale))
        .fold(0.0, f64::max)
}

#[test]
fn three_colours_agree_with_the_cpu_on_green_brown_and_empty_sites() {
    let Some(ctx) = context() else { return };
    let dims = Dims::new(14, 12, 10).unwrap();
    let grid = mixed_grid(dims);
    let opts = SolveOptions {
        max_steps: 24,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    for brown_rule in [true, false] {
        let medium = anisotropic_medium(brown_rule);
        let (cpu, cpu_reports) =
            solve_lighting(&grid, &medium, sun(), &opts, &mut |_, _, _| {}).unwrap();
        let (gpu, gpu_reports) = solve_lighting_gpu(
            &ctx,
            &grid,
            &medium,
            &[sun(); 3],
            None,
            None,
            &opts,
            Precision::F32,
            &mut |_, _, _| {},
        )
        .unwrap();
        for c in 0..3 {
            let err = max_relative_error(&gpu.colours[c], &cpu.colours[c]);
            eprintln!("colour {c}, zero f0 on brown {brown_rule}: max relative error {err:.2e}");
            assert!(err < 1e-5, "colour {c}: {err}");
            assert_eq!(gpu_reports[c].steps, cpu_reports[c].steps);
            assert_eq!(gpu_reports[c].stop, cpu_reports[c].stop);
            // The residual is the relative change of two totals, each summed in f32: a
            // hardware GPU's contracted multiply-adds move each total by about an ulp, so the
            // residual by a couple of f32 ulps absolute, however small it is.
            let (rg, rc) = (gpu_reports[c].residual, cpu_reports[c].residual);
            let floor = if ctx.is_software() {
                1e-9
            } else {
                4.0 * f32::EPSILON as f64
            };
            assert!((rg - rc).abs() <= 1e-4 * rc.abs() + floor, "{rg} vs {rc}");
        }
        // The light really went somewhere: interior sites are lit, and differ by colour.
        assert!(cpu.colours[0].iter().any(|&v| v > 0.01));
        assert_ne!(cpu.colours[0], cpu.colours[1]);
    }
}

#[test]
fn per_colour_boundaries_and_bark_parameters_agree_with_the_cpu() {
    // The physical light (docs/light.md): brown sites with their own albedo and asymmetry,
    // and a boundary per colour (sun plus coloured sky and ground).
    let Some(ctx) = context() else { return };
    let dims = Dims::new(12, 14, 10).unwrap();
    let grid = mixed_grid(dims);
    let opts = SolveOptions {
        max_steps: 20,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let medium = MediumParams {
        brown: Some([0.2, 0.15, 0.1].map(|s| ColourParams {
            sigma_a: 1.0 - s,
            sigma_s: s,
            g: -4.0 / 9.0,
        })),
        ..anisotropic_medium(true)
    };
    let sky = [0.5f32, 0.7, 0.9];
    let boundaries: [Boundary; 3] = std::array::from_fn(|c| {
        let mut b = sun();
        for (m, v) in b.values.iter_mut().enumerate().skip(1) {
            *v += sky[c] * (m as f32 / 18.0);
        }
        b
    });
    // A ground whose light varies over the floor (a plant's shadow on it).
    let floor = Floor {
        nx: dims.nx,
        nz: dims.nz,
        radiance: std::array::from_fn(|c| {
            (0..dims.nx * dims.nz)
                .map(|i| 0.1 * (c + 1) as f32 * (1.0 + (i % 7) as f32 / 7.0))
                .collect()
        }),
    };
    let (cpu, _) = sylva_lb::solve_lighting_rgb(
        &grid,
        &medium,
        &boundaries,
        Some(&floor),
        None,
        &opts,
        &mut |_, _, _| {},
    )
    .unwrap();
    let (gpu, _) = solve_lighting_gpu(
        &ctx,
        &grid,
        &medium,
        &boundaries,
        Some(&floor),
        None,
        &opts,
        Precision::F32,
        &mut |_, _, _| {},
    )
    .unwrap();
    for c in 0..3 {
        let err = max_relative_error(&gpu.colours[c], &cpu.colours[c]);
        assert!(err < 1e-5, "colour {c}: {err}");
    }
    // The bark parameters matter: the same solve with the default brown sites differs.
    let (default_brown, _) = sylva_lb::solve_lighting_rgb(
        &grid,
        &anisotropic_medium(true),
        &boundaries,
        Some(&floor),
        None,
        &opts,
        &mut |_, _, _| {},
    )
    .unwrap();
    assert!(max_relative_error(&default_brown.colours[0], &cpu.colours[0]) > 1e-3);
}

#[test]
fn a_volume_source_agrees_with_the_cpu() {
    // The physical light's sun enters as light scattered at its first collision
    // (sylva_lb::light::first_collision_source): a strength per site and colour, a profile
    // per direction for green and brown sites, added after every collision. Checked with
    // the step counts whose bookkeeping differs (the first step needs no launch), a floor
    // and per-colour boundaries, and a convergence stop.
    let Some(ctx) = context() else { return };
    let dims = Dims::new(12, 14, 10).unwrap();
    let grid = mixed_grid(dims);
    let medium = anisotropic_medium(true);
    let boundaries: [Boundary; 3] =
        std::array::from_fn(|c| Boundary::sun([0.2, -0.9, 0.3], 0.2 * (c + 1) as f64));
    let floor = Floor {
        nx: dims.nx,
        nz: dims.nz,
        radiance: std::array::from_fn(|c| vec![0.05 * (c + 1) as f32; dims.nx * dims.nz]),
    };
    let source = VolumeSource {
        strength: std::array::from_fn(|c| {
            (0..dims.sites())
                .map(|i| {
                    let (x, y, z) = dims.coords(i);
                    if dims.on_shell(x, y, z) || grid.density[i] == 0.0 {
                        0.0
                    } else {
                        0.3 * grid.density[i] * (1.0 + c as f32 + (i % 5) as f32 / 5.0)
                    }
                })
                .collect()
        }),
        green: std::array::from_fn(|c| std::array::from_fn(|m| ((m + c) % 4) as f32 / 36.0)),
        brown: std::array::from_fn(|c| std::array::from_fn(|m| ((m * 3 + c) % 5) as f32 / 50.0)),
    };
    let on_gpu = |source: Option<&VolumeSource>, opts: &SolveOptions| {
        solve_lighting_gpu(
            &ctx,
            &grid,
            &medium,
            &boundaries,
            Some(&floor),
            source,
            opts,
            Precision::F32,
            &mut |_, _, _| {},
        )
        .unwrap()
    };
    for opts in [1, 2, 3, 17]
        .map(|n| SolveOptions {
            max_steps: n,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        })
        .into_iter()
        .chain([SolveOptions {
            max_steps: 400,
            tolerance: Some(1e-4),
            extrapolate: false,
            coarse_start: false,
        }])
    {
        let (cpu, cpu_reports) = sylva_lb::solve_lighting_rgb(
            &grid,
            &medium,
            &boundaries,
            Some(&floor),
            Some(&source),
            &opts,
            &mut |_, _, _| {},
        )
        .unwrap();
        let (gpu, gpu_reports) = on_gpu(Some(&source), &opts);
        for c in 0..3 {
            let err = max_relative_error(&gpu.colours[c], &cpu.colours[c]);
            assert!(err < 1e-5, "{opts:?} colour {c}: {err}");
            assert_eq!(gpu_reports[c].steps, cpu_reports[c].steps, "{opts:?}");
        }
    }
    // The source matters: without it the light differs.
    let opts = SolveOptions {
        max_steps: 17,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let (with, _) = on_gpu(Some(&source), &opts);
    let (without, _) = on_gpu(None, &opts);
    assert!(max_relative_error(&with.colours[1], &without.colours[1]) > 1e-2);
}

#[test]
fn every_step_count_maps_onto_the_cpu_state() {
    // The GPU keeps post-collision values and needs no launch for the first step: check the
    // bookkeeping at 0, 1, 2, 3 and 5 steps, against the CPU lattice's state.
    let Some(ctx) = context() else { return };
    let dims = Dims::new(7, 8, 9).unwrap();
    let grid = mixed_grid(dims);
    let medium = Preset::Leaf.params();
    let mut cpu = Lattice::new(&grid, &medium, 2, sun()).unwrap();
    let mut gpu = GpuLattice::new(&ctx, &grid, &medium, 2, sun(), Precision::F32).unwrap();
    let err = max_relative_error(&gpu.site_totals().unwrap(), &cpu.site_totals());
    assert_eq!(err, 0.0, "before any step");
    // A residual is the relative change of two totals summed in f32 (in another order on
    // the GPU): it carries their rounding, a few f32 ulps absolute however small it is.
    let close =
        |g: f64, c: f64| g == c || (g - c).abs() <= 1e-4 * c.abs() + 4.0 * f32::EPSILON as f64;
    for every_step in [true, false] {
        // Monitoring every step reports each step's residual; by default a run without a
        // tolerance sums only its last two steps' totals (the report's residual).
        gpu.set_monitor_every_step(every_step);
        for steps in [1, 2, 3, 5, 40] {
            cpu.reset(sun());
            gpu.reset(sun()).unwrap();
            let opts = SolveOptions {
                max_steps: steps,
                tolerance: None,
                extrapolate: false,
                coarse_start: false,
            };
            let mut cpu_residuals = Vec::new();
            let mut gpu_residuals = Vec::new();
            let cpu_report = cpu.run(&opts, &mut |_, r| cpu_residuals.push(r)).unwrap();
            let gpu_report = gpu.run(&opts, &mut |_, r| gpu_residuals.push(r)).unwrap();
            let err = max_relative_error(&gpu.site_totals().unwrap(), &cpu.site_totals());
            assert!(err < 1e-5, "{steps} steps: {err}");
            assert_eq!(cpu_residuals.len(), gpu_residuals.len());
            assert_eq!(gpu_report.steps, cpu_report.steps);
            assert!(
                close(gpu_report.residual, cpu_report.residual),
                "{steps} steps: final residual {} vs {}",
                gpu_report.residual,
                cpu_report.residual
            );
            if every_step {
                for (g, c) in gpu_residuals.iter().zip(&cpu_residuals) {
                    assert!(
                        close(*g, *c),
                        "{steps} steps: residuals {gpu_residuals:?} vs {cpu_residuals:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn tolerance_stops_after_the_same_step_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let dims = Dims::new(10, 10, 10).unwrap();
    let grid = mixed_grid(dims);
    let medium = Preset::Dogrose.params();
    let opts = SolveOptions {
        max_steps: 400,
        tolerance: Some(1e-3),
        extrapolate: false,
        coarse_start: false,
    };
    let mut cpu = Lattice::new(&grid, &medium, 0, sun()).unwrap();
    let mut gpu = GpuLattice::new(&ctx, &grid, &medium, 0, sun(), Precision::F32).unwrap();
    let c = cpu.run(&opts, &mut |_, _| {}).unwrap();
    let g = gpu.run(&opts, &mut |_, _| {}).unwrap();
    assert_eq!(c.stop, StopReason::Converged);
    assert_eq!((g.steps, g.stop), (c.steps, c.stop));
    assert!(c.steps < opts.max_steps && g.residual < 1e-3);
    let err = max_relative_error(&gpu.site_totals().unwrap(), &cpu.site_totals());
    assert!(err < 1e-5, "{err}");
}

#[test]
fn a_state_split_over_many_bindings_gives_the_same_result() {
    let Some(whole) = context() else { return };
    let dims = Dims::new(9, 11, 13).unwrap();
    let grid = mixed_grid(dims);
    let medium = anisotropic_medium(true);
    // Room for two directions per binding (the stride rounds sites up to 128).
    let direction = (dims.sites() as u64).div_ceil(128) * 128 * 4;
    let mut opts = ContextOptions::new(AdapterChoice::Any);
    opts.max_binding_bytes = Some(2 * direction);
    let split = gpu_context(&opts).expect("the same adapter again");
    assert_eq!(
        split.limits().max_storage_buffer_binding_size,
        2 * direction
    );
    let run = |ctx: &GpuContext| {
        let mut lat = GpuLattice::new(ctx, &grid, &medium, 0, sun(), Precision::F32).unwrap();
        lat.run(
            &SolveOptions {
                max_steps: 9,
                tolerance: None,
                extrapolate: false,
                coarse_start: false,
            },
            &mut |_, _| {},
        )
        .unwrap();
        (lat.parts(), lat.site_totals().unwrap())
    };
    let (one, a) = run(&whole);
    let (many, b) = run(&split);
    assert_eq!(one, 1);
    assert_eq!(many, Q.div_ceil(2));
    // Same arithmetic, only the bindings differ: bit-identical.
    assert_eq!(a, b);
    let mut cpu = Lattice::new(&grid, &medium, 0, sun()).unwrap();
    cpu.run(
        &SolveOptions {
            max_steps: 9,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        },
        &mut |_, _| {},
    )
    .unwrap();
    let err = max_relative_error(&b, &cpu.site_totals());
    assert!(err < 1e-5, "{err}");

    // One direction per binding: 19 parts, 40 storage buffers per stage, where allowed.
    let mut opts = ContextOptions::new(AdapterChoice::Any);
    opts.max_binding_bytes = Some(direction);
    let single = gpu_context(&opts).expect("the same adapter again");
    match GpuLattice::new(&single, &grid, &medium, 0, sun(), Precision::F32) {
        Ok(lat) => assert_eq!(lat.parts(), Q),
        Err(LbGpuError::TooLarge(msg)) => {
            assert!(msg.contains("storage buffers per shader stage"), "{msg}")
        }
        Err(e) => panic!("{e}"),
    }
    // Less than one direction per binding cannot work: a clear error, not a panic.
    let mut opts = ContextOptions::new(AdapterChoice::Any);
    opts.max_binding_bytes = Some(direction / 2);
    let tiny = gpu_context(&opts).expect("the same adapter again");
    match GpuLattice::new(&tiny, &grid, &medium, 0, sun(), Precision::F32) {
        Err(LbGpuError::TooLarge(msg)) => assert!(msg.contains("per storage binding"), "{msg}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("a binding smaller than one direction was accepted"),
    }
}

#[test]
fn a_grid_larger_than_one_binding_agrees_with_the_cpu() {
    let Some(ctx) = context() else { return };
    // 122³ × 19 × 4 B = 138 MB per copy, above lavapipe's 128 MiB per binding.
    let dims = Dims::cube(122).unwrap();
    let mut grid = DensityGrid::empty(dims);
    grid.density.fill(0.7);
    let medium = Preset::Cloud.params();
    let state_bytes = (dims.sites() as u64 * Q as u64 * 4) as f64;
    let opts = SolveOptions {
        max_steps: 4,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let mut gpu = GpuLattice::new(&ctx, &grid, &medium, 0, sun(), Precision::F32).unwrap();
    let binding = ctx.limits().max_storage_buffer_binding_size as f64;
    eprintln!(
        "{dims}: {:.0} MB per state copy, {:.0} MB per binding, {} parts",
        state_bytes / 1e6,
        binding / 1e6,
        gpu.parts()
    );
    if state_bytes > binding {
        assert!(gpu.parts() >= 2);
    }
    gpu.run(&opts, &mut |_, _| {}).unwrap();
    let mut cpu = Lattice::new(&grid, &medium, 0, sun()).unwrap();
    cpu.run(&opts, &mut |_, _| {}).unwrap();
    let err = max_relative_error(&gpu.site_totals().unwrap(), &cpu.site_totals());
    assert!(err < 1e-5, "{err}");
}

/// Measured bound for f16 storage against f32 storage (docs/gpu.md): 11-bit values,
/// rounded once per step.
const F16_BOUND: f64 = 2e-3;

#[test]
fn f16_storage_stays_within_its_documented_error() {
    let Some(ctx) = context() else { return };
    let dims = Dims::new(16, 16, 16).unwrap();
    let grid = mixed_grid(dims);
    let medium = Preset::Leaf.params();
    if !ctx.supports_f16() {
        // A clear refusal, not a silent fallback to f32.
        match GpuLattice::new(&ctx, &grid, &medium, 0, sun(), Precision::F16) {
            Err(LbGpuError::F16Unsupported(_)) => sylva_testkit::skipped(&format!(
                "the f16 error measurement: {} lacks SHADER_F16 (the refusal was checked)",
                ctx.describe()
            )),
            Err(e) => panic!("{e}"),
            Ok(_) => panic!("f16 accepted without SHADER_F16"),
        }
        return;
    }
    let opts = SolveOptions::papers(dims);
    let (a, _) = solve_lighting_gpu(
        &ctx,
        &grid,
        &medium,
        &[sun(); 3],
        None,
        None,
        &opts,
        Precision::F32,
        &mut |_, _, _| {},
    )
    .unwrap();
    let (h, _) = solve_lighting_gpu(
        &ctx,
        &grid,
        &medium,
        &[sun(); 3],
        None,
        None,
        &opts,
        Precision::F16,
        &mut |_, _, _| {},
    )
    .unwrap();
    for c in 0..3 {
        let err = max_relative_error(&h.colours[c], &a.colours[c]);
        eprintln!("f16 vs f32, colour {c}: max relative error {err:.2e}");
        assert!(err < F16_BOUND, "colour {c}: {err}");
        // f16 really is lower precision: the results are not bit-identical.
        assert_ne!(h.colours[c], a.colours[c]);
    }
}

#[test]
fn no_adapter_at_all_is_a_clear_error() {
    let mut opts = ContextOptions::new(AdapterChoice::Any);
    opts.backends = Some(sylva_wgpu::wgpu::Backends::empty());
    match GpuContext::new(&opts) {
        Err(e @ GpuError::NoAdapter { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("no GPU adapter found"), "{msg}");
            assert!(msg.contains("--device cpu"), "{msg}");
        }
        Err(e) => panic!("unexpected error: {e}"),
        Ok(ctx) => panic!("an adapter without backends: {}", ctx.describe()),
    }
}

#[test]
fn bad_input_is_refused() {
    let Some(ctx) = context() else { return };
    let dims = Dims::cube(5).unwrap();
    let grid = mixed_grid(dims);
    let medium = Preset::Leaf.params();
    let mut bad = sun();
    bad.values[3] = f32::NAN;
    assert!(matches!(
        GpuLattice::new(&ctx, &grid, &medium, 0, bad, Precision::F32),
        Err(LbGpuError::Solve(_))
    ));
    let mut lat = GpuLattice::new(&ctx, &grid, &medium, 0, sun(), Precision::F32).unwrap();
    for opts in [
        SolveOptions {
            max_steps: 0,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        },
        SolveOptions {
            max_steps: 5,
            tolerance: Some(f64::NAN),
            extrapolate: false,
            coarse_start: false,
        },
    ] {
        let e = lat.run(&opts, &mut |_, _| {}).unwrap_err();
        assert!(matches!(e, LbGpuError::Solve(_)), "{e}");
    }
}

#[test]
fn backends_behind_the_trait_agree_and_name_themselves() {
    // The CPU is always there; f16 is refused where it runs.
    let cpu = select_solver(Device::Cpu, Precision::F32).unwrap();
    assert_eq!(cpu.solver.device(), "cpu");
    assert_eq!(cpu.solver.cache_tag(), "cpu");
    assert_eq!(cpu.solver.schedule(), Schedule::CoarseStarted);
    assert!(matches!(
        select_solver(Device::Cpu, Precision::F16),
        Err(LbGpuError::F16OnCpu)
    ));
    let Some(ctx) = context() else { return };
    let gpu = GpuSolver::new(ctx, Precision::F32).unwrap();
    assert_eq!(gpu.device(), "gpu");
    assert_eq!(gpu.cache_tag(), "gpu-f32");
    assert_eq!(gpu.schedule(), Schedule::Papers);
    // Each backend runs the schedule it names (the renderer asks for nothing else).
    {
        let dims = Dims::new(12, 10, 9).unwrap();
        let grid = mixed_grid(dims);
        let medium = anisotropic_medium(true);
        let sun = Boundary::sun([0.3, -0.9, 0.2], 1.0);
        for solver in [&*cpu.solver, &gpu as &dyn LbSolver] {
            let opts = solver.schedule().options(dims);
            let (_, reports) = solver
                .solve_lighting(&grid, &medium, sun, &opts, &mut |_, _, _| {})
                .unwrap_or_else(|e| panic!("{}: {e}", solver.describe()));
            assert_eq!(reports[0].steps, opts.max_steps, "{}", solver.describe());
        }
    }
    assert_eq!(gpu.adapter().as_deref(), Some(gpu.context().adapter_name()));
    assert!(gpu.describe().contains("f32 state"), "{}", gpu.describe());
    let dims = Dims::new(12, 10, 9).unwrap();
    let grid = mixed_grid(dims);
    let medium = anisotropic_medium(true);
    let opts = SolveOptions {
        max_steps: 16,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let solvers: [&dyn LbSolver; 2] = [&*cpu.solver, &gpu];
    let [(a, _), (b, _)] = solvers.map(|s| {
        s.solve_lighting(&grid, &medium, sun(), &opts, &mut |_, _, _| {})
            .unwrap()
    });
    for c in 0..3 {
        let err = max_relative_error(&b.colours[c], &a.colours[c]);
        assert!(err < 1e-5, "colour {c}: {err}");
    }
    // Errors of the solver's own checks come back as such through the GPU backend too.
    let bad = SolveOptions {
        max_steps: 0,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let e = gpu
        .solve_lighting(&grid, &medium, sun(), &bad, &mut |_, _, _| {})
        .unwrap_err();
    assert!(matches!(e, LbSolverError::Solve(_)), "{e}");
    // Extrapolated and coarse-started solves are the CPU solver's alone: refused, not run
    // plain (a coarse start without extrapolation too).
    let coarse_plain = SolveOptions {
        extrapolate: false,
        coarse_start: true,
        ..SolveOptions::papers(dims)
    };
    for opts in [SolveOptions::extrapolated(dims), coarse_plain] {
        let e = gpu
            .solve_lighting(&grid, &medium, sun(), &opts, &mut |_, _, _| {})
            .unwrap_err();
        assert!(e.to_string().contains("CPU solver only"), "{e}");
    }
    let mut last = 0;
    let bench = gpu
        .benchmark(&grid, &medium, sun(), 4, 2, &mut |s| last = s)
        .unwrap();
    assert_eq!((bench.runs.len(), last), (2, 8));
    assert_eq!(bench.kernel, "wgsl-f32");
    assert_eq!(bench.bytes_per_update, 156);
}
