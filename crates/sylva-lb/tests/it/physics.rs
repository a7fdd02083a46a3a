//! The physics of SPEC §1, checked on the real solver.
#![allow(clippy::needless_range_loop)]

use sylva_lb::lattice::{weight, C, Q};
use sylva_lb::shapes::Shape;
use sylva_lb::{
    solve_lighting, Boundary, ColourParams, DensityGrid, Dims, Lattice, MediumParams, Preset,
    SolveOptions,
};

fn medium(c: ColourParams, zero_f0: bool) -> MediumParams {
    MediumParams {
        colours: [c; 3],
        zero_f0_on_green: zero_f0,
        zero_f0_on_brown: zero_f0,
        brown_threshold: 0.5,
        brown: None,
    }
}

fn uniform(dims: Dims, rho: f32) -> DensityGrid {
    let mut g = DensityGrid::empty(dims);
    g.density.fill(rho);
    g
}

/// A deterministic pseudo-random medium with empty, green and brown sites.
fn mixed_grid(dims: Dims, seed: u64) -> DensityGrid {
    let mut g = DensityGrid::empty(dims);
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32
    };
    for i in 0..dims.sites() {
        let r = next();
        if r < 0.3 {
            continue;
        }
        g.density[i] = next();
        g.wood[i] = if r > 0.85 { 1.0 } else { 0.0 };
    }
    g
}

#[test]
fn vector_kernel_matches_dense_reference() {
    // Odd nz exercises the scalar tail of the 8-wide kernel.
    let dims = Dims::new(9, 7, 21).unwrap();
    let grid = mixed_grid(dims, 7);
    for preset in Preset::ALL {
        let m = preset.params();
        for colour in 0..3 {
            let b = Boundary::sun([0.3, -0.8, 0.52], 1.0);
            let mut fast = Lattice::new(&grid, &m, colour, b).unwrap();
            let mut slow = Lattice::new(&grid, &m, colour, b).unwrap();
            let mut portable = Lattice::new(&grid, &m, colour, b).unwrap();
            portable.set_kernel(sylva_lb::kernel::KernelIsa::Portable);
            for _ in 0..25 {
                fast.step();
                portable.step();
                slow.step_reference();
            }
            for x in 0..9 {
                for y in 0..7 {
                    for z in 0..21 {
                        for q in 0..Q {
                            let (a, p, r) = (
                                fast.f(x, y, z, q),
                                portable.f(x, y, z, q),
                                slow.f(x, y, z, q),
                            );
                            // f32 state against an f64 reference over 25 steps: rounding alone reaches ~1e-5.
                            let tol = 5e-5 * r.abs().max(1e-3);
                            assert!(
                                (a - r).abs() <= tol,
                                "{} c{colour} ({x},{y},{z}) f{q}: {a} vs {r}",
                                preset.name()
                            );
                            assert!(
                                (p - r).abs() <= tol,
                                "portable {} ({x},{y},{z}) f{q}: {p} vs {r}",
                                preset.name()
                            );
                        }
                    }
                }
            }
        }
    }
}

/// A volume source of `strength` per site, spread over the directions by lattice weight on
/// green sites and evenly over the moving ones on brown sites.
fn lattice_weighted_source(strength: Vec<f32>) -> sylva_lb::solver::ColourSource {
    sylva_lb::solver::ColourSource {
        strength,
        green: std::array::from_fn(|m| weight(m) as f32),
        brown: std::array::from_fn(|m| if m == 0 { 0.0 } else { 1.0 / 18.0 }),
    }
}

/// Sweeps of every depth (temporal blocking) against single steps, bit for bit, with a floor
/// (the rings' floor rows are refilled per plane) and grids as thin as the sweep's stages.
#[test]
fn sweeps_equal_single_steps() {
    for dims in [
        Dims::new(9, 7, 21).unwrap(),
        Dims::new(12, 10, 16).unwrap(),
        Dims::new(5, 6, 4).unwrap(),
        Dims::new(3, 5, 9).unwrap(),
    ] {
        let grid = mixed_grid(dims, 11);
        let m = Preset::Dogrose.params();
        let b = Boundary::sun([0.3, -0.8, 0.52], 1.0);
        let floor: Vec<f32> = (0..dims.nx * dims.nz)
            .map(|i| 0.2 + (i % 5) as f32 * 0.1)
            .collect();
        for depth in 2..=sylva_lb::solver::SWEEP_STEPS {
            let mut single = Lattice::new(&grid, &m, 2, b).unwrap();
            let mut swept = Lattice::new(&grid, &m, 2, b).unwrap();
            for lat in [&mut single, &mut swept] {
                lat.set_floor(Some(floor.clone()));
                lat.reset(b);
            }
            for _ in 0..3 {
                let totals: Vec<f64> = (0..depth).map(|_| single.step()).collect();
                assert_eq!(swept.step_sweep(depth), totals, "{dims} depth {depth}");
            }
            let (t0, t1) = (single.step(), single.step());
            assert_eq!(swept.step_pair(), (t0, t1));
            assert_eq!(single.site_totals(), swept.site_totals(), "{dims}");
            for x in 0..dims.nx {
                for y in 0..dims.ny {
                    for z in 0..dims.nz {
                        for q in 0..Q {
                            assert_eq!(
                                single.f(x, y, z, q),
                                swept.f(x, y, z, q),
                                "{dims} depth {depth} ({x},{y},{z}) f{q}"
                            );
                        }
                    }
                }
            }
        }
    }
}

/// Every kernel this CPU runs against the portable one (the reference), on rows whose length
/// is not a multiple of 8 or 16 (the last chunk overlaps the one before it) and one shorter
/// than 16 (the AVX-512 kernel takes 8-lane chunks there), with green, brown and empty sites
/// and a volume source. The fused kernels (AVX2, AVX-512) do the same arithmetic per site, so
/// their states must be equal bit for bit; against the portable kernel, which rounds each
/// multiply-add twice, they stay within 2e-6 relative. Each kernel must also conserve:
/// the interior total after a step is the total before plus inflow, minus outflow, minus
/// absorption, plus the source ([`Lattice::flows`], in f64).
#[test]
fn every_kernel_agrees_with_the_portable_one() {
    use sylva_lb::kernel::KernelIsa;
    for isa in KernelIsa::ALL {
        if !isa.is_supported() {
            eprintln!(
                "SKIPPED: kernel {}: this CPU lacks its instructions",
                isa.name()
            );
        }
    }
    let kernels = KernelIsa::supported();
    for dims in [Dims::new(11, 9, 37).unwrap(), Dims::new(7, 6, 13).unwrap()] {
        let grid = mixed_grid(dims, 5);
        let strength: Vec<f32> = (0..dims.sites())
            .map(|i| {
                let (x, y, z) = dims.coords(i);
                if dims.on_shell(x, y, z) {
                    0.0
                } else {
                    ((i * 7) % 11) as f32 / 40.0
                }
            })
            .collect();
        let source = lattice_weighted_source(strength);
        for preset in [Preset::Leaf, Preset::Dogrose] {
            let m = preset.params();
            let b = Boundary::sun([0.3, -0.8, 0.52], 1.0);
            let mut lattices: Vec<Lattice> = kernels
                .iter()
                .map(|&isa| {
                    let mut lat = Lattice::new(&grid, &m, 1, b).unwrap();
                    lat.set_kernel(isa);
                    lat.set_source(Some(source.clone()));
                    lat
                })
                .collect();
            let interior_total = |lat: &Lattice| -> f64 {
                let totals = lat.site_totals();
                (0..dims.sites())
                    .filter(|&i| {
                        let (x, y, z) = dims.coords(i);
                        !dims.on_shell(x, y, z)
                    })
                    .map(|i| totals[i] as f64)
                    .sum()
            };
            // Rounds of a single step (checked for balance) and a two-step sweep: both run
            // the kernel.
            for round in 0..6 {
                for (lat, isa) in lattices.iter_mut().zip(&kernels) {
                    let before = interior_total(lat);
                    let f = lat.flows();
                    let reported = lat.step();
                    let want = before + f.inflow - f.outflow - f.absorbed + f.sourced;
                    let got = interior_total(lat);
                    assert!(
                        (got - want).abs() <= 1e-5 * want.abs(),
                        "{} {dims} round {round}: total {got}, balance {want}",
                        isa.name()
                    );
                    assert!(
                        (reported - before).abs() <= 1e-5 * before.abs(),
                        "{} {dims}: reported total {reported}, sites {before}",
                        isa.name()
                    );
                    lat.step_pair();
                }
            }
            let reference = lattices.last().unwrap();
            assert_eq!(kernels.last(), Some(&KernelIsa::Portable));
            let mut worst = 0.0f32;
            for (lat, isa) in lattices.iter().zip(&kernels) {
                let fused = lattices.first().unwrap();
                for x in 0..dims.nx {
                    for y in 0..dims.ny {
                        for z in 0..dims.nz {
                            for q in 0..Q {
                                let (got, want) = (lat.f(x, y, z, q), reference.f(x, y, z, q));
                                let err = (got - want).abs() / want.abs().max(1e-3);
                                worst = worst.max(err);
                                assert!(
                                    err <= 2e-6,
                                    "{} {} {dims} ({x},{y},{z}) f{q}: {got} vs portable {want}",
                                    isa.name(),
                                    preset.name()
                                );
                                if *isa != KernelIsa::Portable {
                                    assert_eq!(
                                        got.to_bits(),
                                        fused.f(x, y, z, q).to_bits(),
                                        "{} against {} {dims} ({x},{y},{z}) f{q}",
                                        isa.name(),
                                        kernels[0].name()
                                    );
                                }
                            }
                        }
                    }
                }
            }
            eprintln!(
                "{} {dims}: kernels {:?} agree; largest relative difference to portable {worst:e}",
                preset.name(),
                kernels.iter().map(|k| k.name()).collect::<Vec<_>>()
            );
        }
    }
}

#[test]
fn empty_space_streams_unchanged() {
    let dims = Dims::cube(12).unwrap();
    let grid = DensityGrid::empty(dims);
    let m = Preset::Leaf.params();
    let mut lat = Lattice::new(&grid, &m, 0, Boundary { values: [0.0; Q] }).unwrap();
    for q in 0..Q {
        lat.set_f(5, 6, 4, q, 1.0 + q as f32);
    }
    lat.step();
    lat.step();
    for (q, c) in C.iter().enumerate() {
        let (x, y, z) = (
            (5 + 2 * c[0]) as usize,
            (6 + 2 * c[1]) as usize,
            (4 + 2 * c[2]) as usize,
        );
        assert_eq!(lat.f(x, y, z, q), 1.0 + q as f32, "direction {q}");
    }
    let total: f32 = lat.site_totals().iter().sum();
    assert_eq!(total, (1..=Q).map(|v| v as f32).sum::<f32>());
}

#[test]
fn no_absorption_full_forward_scattering_is_a_pass_through() {
    let dims = Dims::new(14, 11, 17).unwrap();
    let b = Boundary::sun([0.2, -0.9, 0.39], 1.0);
    let m = medium(ColourParams::new(0.0, 0.8, 1.0).unwrap(), true);
    let opts = SolveOptions::papers(dims);
    let (dense, _) = solve_lighting(&uniform(dims, 1.0), &m, b, &opts, &mut |_, _, _| {}).unwrap();
    let (empty, _) =
        solve_lighting(&DensityGrid::empty(dims), &m, b, &opts, &mut |_, _, _| {}).unwrap();
    for (a, e) in dense.colours[0].iter().zip(&empty.colours[0]) {
        assert!((a - e).abs() <= 1e-6 * e.abs().max(1.0), "{a} vs {e}");
    }
    // And light did get through: the interior is lit.
    assert!(empty.colours[0][dims.index(7, 5, 8)] > 0.1);
}

/// One collision on a density-1 site, through the real kernel: the light the site holds
/// leaves it scattered, `σ_s/σ_t` of what interacted (the preset's albedo), when `f_0` is
/// zeroed; with `f_0` kept the absorbed part stays in the rest direction and nothing is lost.
fn kept_after_one_collision(preset: Preset) -> (f64, f64) {
    kept_after_medium(&preset.params())
}

fn kept_after_medium(m: &MediumParams) -> (f64, f64) {
    let dims = Dims::cube(7).unwrap();
    let mut lat = Lattice::new(&uniform(dims, 1.0), m, 1, Boundary { values: [0.0; Q] }).unwrap();
    let mut before = 0.0f64;
    for q in 1..Q {
        let v = 0.5 + 0.1 * q as f32;
        lat.set_f(3, 3, 3, q, v);
        before += v as f64;
    }
    lat.step();
    let after: f64 = lat.site_totals().iter().map(|&v| v as f64).sum();
    let c = m.colours[1];
    (after / before, c.sigma_s / c.sigma_t())
}

#[test]
fn the_cloud_scatters_with_the_albedo_of_002() {
    // 002 §3.2.1: σ_a = 0.008, σ_s = 0.792 "give a relatively high scattering albedo,
    // σ_s/σ_t = 0.99". At density 1 every direction interacts (ρ σ_t = σ_t of it leaves the
    // direction, σ_s of it scattered back): the site keeps 1 - σ_a of its light.
    let (kept, albedo) = kept_after_one_collision(Preset::Cloud);
    assert!((albedo - 0.99).abs() < 1e-12);
    let expect = 1.0 - 0.008;
    assert!(
        (kept - expect).abs() < 1e-6,
        "kept {kept}, expected {expect}"
    );
    // The plastic too (002 Table 2: σ_a = 0.01, σ_s = 0.99).
    let (kept, albedo) = kept_after_one_collision(Preset::Pmma);
    assert!((albedo - 0.99).abs() < 1e-12);
    assert!((kept - 0.99).abs() < 1e-6, "PMMA kept {kept}");
    // With f_0 kept the collision conserves the light: the absorbed part stays in f_0.
    let mut m = Preset::Cloud.params();
    m.zero_f0_on_green = false;
    let (kept, _) = kept_after_medium(&m);
    assert!((kept - 1.0).abs() < 1e-6, "kept {kept} with f_0 kept");
}

/// Second moment per axis of the site totals about the centre.
fn second_moment(lat: &Lattice, c: usize) -> f64 {
    let d = lat.dims();
    let totals = lat.site_totals();
    let (mut m0, mut m2) = (0.0f64, 0.0f64);
    for (i, &v) in totals.iter().enumerate() {
        let (x, y, z) = d.coords(i);
        let r2 = [x, y, z]
            .iter()
            .map(|&a| (a as f64 - c as f64).powi(2))
            .sum::<f64>();
        m0 += v as f64;
        m2 += v as f64 * r2;
    }
    m2 / m0 / 3.0
}

#[test]
fn point_source_diffuses_with_the_coefficient_of_eq_4() {
    let n = 81;
    let c = n / 2;
    let dims = Dims::cube(n).unwrap();
    let grid = uniform(dims, 1.0);
    for (sigma_s, sigma_a) in [(1.0, 0.0), (0.8, 0.2), (0.4, 0.1)] {
        let p = ColourParams::new(sigma_a, sigma_s, 0.0).unwrap();
        let want = (2.0 / p.sigma_t() - 1.0) / (4.0 * (1.0 + sigma_a));
        let mut lat =
            Lattice::new(&grid, &medium(p, false), 0, Boundary { values: [0.0; Q] }).unwrap();
        lat.set_f(c, c, c, 0, 1.0);
        let (t1, t2) = (30, 60);
        for _ in 0..t1 {
            lat.step();
        }
        let m1 = second_moment(&lat, c);
        for _ in t1..t2 {
            lat.step();
        }
        let m2 = second_moment(&lat, c);
        let d = (m2 - m1) / (2.0 * (t2 - t1) as f64);
        assert!(
            (d - want).abs() < 0.01 * want,
            "σ_s = {sigma_s}, σ_a = {sigma_a}: D = {d}, eq. 4 gives {want}"
        );
    }
}

#[test]
fn symmetric_setup_gives_symmetric_result() {
    let n = 25;
    let dims = Dims::cube(n).unwrap();
    let grid = Shape::Sphere.grid(dims);
    let m = Preset::Leaf.params();
    let b = Boundary::sun([0.0, -1.0, 0.0], 1.0);
    let (g, _) =
        solve_lighting(&grid, &m, b, &SolveOptions::papers(dims), &mut |_, _, _| {}).unwrap();
    for col in &g.colours {
        for x in 0..n {
            for y in 0..n {
                for z in 0..n {
                    let v = col[dims.index(x, y, z)];
                    for w in [
                        col[dims.index(n - 1 - x, y, z)],
                        col[dims.index(x, y, n - 1 - z)],
                        col[dims.index(z, y, x)],
                    ] {
                        assert!(
                            (v - w).abs() <= 1e-5 * v.abs().max(1e-3),
                            "({x},{y},{z}): {v} vs {w}"
                        );
                    }
                }
            }
        }
    }
    // The top of the sphere is brighter than its bottom.
    let top = g.colours[1][dims.index(n / 2, n / 2 + 9, n / 2)];
    let bottom = g.colours[1][dims.index(n / 2, n / 2 - 9, n / 2)];
    assert!(top > 2.0 * bottom, "top {top}, bottom {bottom}");
}

#[test]
fn steady_state_balances_inflow_against_absorption_and_outflow() {
    let dims = Dims::new(30, 34, 26).unwrap();
    let grid = Shape::Crown.grid(dims);
    for preset in [Preset::Leaf, Preset::Dogrose] {
        let m = preset.params();
        for colour in 0..3 {
            let b = Boundary::sun([0.4, -0.8, 0.3], 1.0);
            let mut lat = Lattice::new(&grid, &m, colour, b).unwrap();
            let report = lat
                .run(
                    &SolveOptions {
                        max_steps: 5000,
                        tolerance: Some(1e-9),
                        extrapolate: false,
                        coarse_start: false,
                    },
                    &mut |_, _| {},
                )
                .unwrap();
            assert_eq!(report.stop, sylva_lb::StopReason::Converged);
            let f = lat.flows();
            assert!(f.absorbed > 0.01 * f.inflow, "{f:?}");
            let imbalance = (f.inflow - f.absorbed - f.outflow).abs() / f.inflow;
            assert!(
                imbalance < 0.005,
                "{} colour {colour}: {f:?} imbalance {imbalance}",
                preset.name()
            );
        }
    }
}

#[test]
fn same_result_on_one_and_two_threads() {
    let dims = Dims::new(20, 24, 36).unwrap();
    let grid = mixed_grid(dims, 3);
    let m = Preset::Dogrose.params();
    let b = Boundary::sun([-0.5, -0.7, 0.5], 2.0);
    let opts = SolveOptions {
        max_steps: 40,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| solve_lighting(&grid, &m, b, &opts, &mut |_, _, _| {}).unwrap())
    };
    let (a, ra) = run(1);
    let (b2, rb) = run(2);
    assert_eq!(a, b2);
    assert_eq!(
        ra.iter().map(|r| r.residual).collect::<Vec<_>>(),
        rb.iter().map(|r| r.residual).collect::<Vec<_>>()
    );
}

/// The site totals after `opts` on a lattice from `lattice`, on `threads` threads, and the
/// steps run.
fn solve_on(
    threads: usize,
    lattice: impl Fn() -> Lattice + Send + Sync,
    opts: SolveOptions,
) -> (Vec<f32>, usize) {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| {
            let mut lat = lattice();
            let report = lat.run(&opts, &mut |_, _| {}).unwrap();
            (lat.site_totals(), report.steps)
        })
}

/// `steps` plain steps, from empty or from the coarse start.
fn plain_steps(steps: usize, coarse_start: bool) -> SolveOptions {
    SolveOptions {
        max_steps: steps,
        tolerance: None,
        extrapolate: false,
        coarse_start,
    }
}

/// The relative RMS distance of site totals `f` from `steady` over `grid`'s medium.
fn distance_over_medium(grid: &DensityGrid, steady: &[f32], f: &[f32]) -> f64 {
    let medium = (0..grid.dims.sites()).filter(|&i| grid.density[i] > 0.0);
    let (d, n) = medium.fold((0.0, 0.0), |(d, n), i| {
        let (a, b) = (f64::from(f[i]), f64::from(steady[i]));
        (d + (a - b) * (a - b), n + b * b)
    });
    (d / n).sqrt()
}

#[test]
fn extrapolated_solves_approach_the_same_steady_state_faster() {
    // A crown of leaves lit by the sun: the steady state from a long plain run, then the
    // extrapolated schedule (1.5 × the longest edge) against as many plain steps and the
    // papers' 2 ×. Extrapolation must land several times closer than the plain steps it
    // took, near the papers' end point, with the same bits on any thread count.
    let dims = Dims::cube(32).unwrap();
    let grid = Shape::Crown.grid(dims);
    let m = Preset::Leaf.params();
    let sun = Boundary::sun([0.3, -0.9, 0.3], 1.0);
    let lattice = || Lattice::new(&grid, &m, 1, sun).unwrap();
    let solve = |opts: SolveOptions, threads: usize| solve_on(threads, lattice, opts);
    let (steady, _) = solve(plain_steps(32 * 32, false), 2);
    let error = |f: &[f32]| distance_over_medium(&grid, &steady, f);
    let (x, steps) = solve(SolveOptions::extrapolated(dims), 2);
    assert_eq!(steps, 48);
    let (same_steps, _) = solve(plain_steps(48, false), 2);
    let (papers, _) = solve(SolveOptions::papers(dims), 2);
    let (ex, ep, epapers) = (error(&x), error(&same_steps), error(&papers));
    assert!(
        ex < 0.25 * ep && ex < 4.0 * epapers,
        "extrapolated {ex:.2e}, as many plain steps {ep:.2e}, the papers' {epapers:.2e}"
    );
    assert_eq!(solve(SolveOptions::extrapolated(dims), 1).0, x);
}

#[test]
fn coarse_started_solves_end_nearer_the_steady_state() {
    // The crown lit by the sun, and the same crown lit by a volume source and a floor (as
    // the physical light's parts are), each started from its half-resolution solve. Its
    // 1 × the longest edge must end far nearer the steady state than as many plain steps
    // from an empty grid, and the coarse start alone must help those plain steps; the bits
    // do not depend on the thread count.
    let dims = Dims::new(64, 40, 44).unwrap();
    let grid = Shape::Crown.grid(dims);
    let m = Preset::Leaf.params();
    let sun = Boundary::sun([0.3, -0.9, 0.3], 1.0);
    let strength: Vec<f32> = (0..dims.sites())
        .map(|i| {
            let (x, y, z) = dims.coords(i);
            if dims.on_shell(x, y, z) {
                0.0
            } else {
                0.05 * grid.density[i] * (1.0 + (x % 3) as f32)
            }
        })
        .collect();
    let source = lattice_weighted_source(strength);
    let floor: Vec<f32> = (0..dims.nx * dims.nz)
        .map(|i| 0.1 + (i % 7) as f32 * 0.02)
        .collect();
    let dark = Boundary { values: [0.0; Q] };
    for (case, boundary, lit_inside) in [("sun", sun, false), ("source and floor", dark, true)] {
        let lattice = || {
            let mut lat = Lattice::new(&grid, &m, 1, boundary).unwrap();
            if lit_inside {
                lat.set_source(Some(source.clone()));
                lat.set_floor(Some(floor.clone()));
                lat.reset(boundary);
            }
            lat
        };
        let solve = |opts: SolveOptions, threads: usize| solve_on(threads, lattice, opts);
        let plain = plain_steps;
        let (steady, _) = solve(plain(64 * 16, false), 2);
        let error = |f: &[f32]| distance_over_medium(&grid, &steady, f);
        let (coarse, steps) = solve(SolveOptions::coarse_started(dims), 2);
        assert_eq!(steps, 64, "{case}");
        let (extrapolated, _) = solve(SolveOptions::extrapolated(dims), 2);
        let (from_empty, _) = solve(plain(64, false), 2);
        let (from_coarse, _) = solve(plain(64, true), 2);
        let (ec, ex) = (error(&coarse), error(&extrapolated));
        let (ee, epc) = (error(&from_empty), error(&from_coarse));
        eprintln!(
            "{case}: coarse-started {ec:.2e}, extrapolated {ex:.2e}; 64 plain steps from \
             empty {ee:.2e}, from the coarse start {epc:.2e}"
        );
        assert!(
            ec < 0.1 * ee && epc < 0.25 * ee,
            "{case}: coarse-started {ec:.2e}; 64 plain steps from empty {ee:.2e}, from the \
             coarse start {epc:.2e}"
        );
        assert_eq!(
            solve(SolveOptions::coarse_started(dims), 1).0,
            coarse,
            "{case}"
        );
    }
}

#[test]
fn a_coarse_start_interpolates_linear_light_exactly() {
    // Prolongation is trilinear: a state linear in the coarse coordinates comes out as the
    // same linear function at the fine sites' coarse coordinates, (i + 1/2) / 2.
    let dims = Dims::new(20, 17, 14).unwrap();
    let grid = Shape::Crown.grid(dims);
    let m = Preset::Leaf.params();
    let mut fine = Lattice::new(&grid, &m, 1, Boundary::sun([0.0, -1.0, 0.0], 1.0)).unwrap();
    let mut coarse = fine.restricted();
    let cd = coarse.dims();
    assert_eq!(cd, sylva_lb::solver::coarse_dims(dims));
    assert_eq!((cd.nx, cd.ny, cd.nz), (11, 10, 8));
    let light = |x: f32, y: f32, z: f32, m: usize| 1.0 + 0.5 * x - 0.25 * y + 0.125 * z + m as f32;
    for x in 1..cd.nx - 1 {
        for y in 1..cd.ny - 1 {
            for z in 1..cd.nz - 1 {
                for q in 0..Q {
                    coarse.set_f(x, y, z, q, light(x as f32, y as f32, z as f32, q));
                }
            }
        }
    }
    fine.prolong_from(&coarse);
    // Fine sites whose coarse neighbours are all interior (the shell holds the boundary).
    let inside = |i: usize, n: usize| {
        let c = (i as f32 + 0.5) / 2.0;
        c >= 1.0 && c <= (n - 2) as f32
    };
    let mut checked = 0;
    for x in (1..dims.nx - 1).filter(|&x| inside(x, cd.nx)) {
        for y in (1..dims.ny - 1).filter(|&y| inside(y, cd.ny)) {
            for z in (1..dims.nz - 1).filter(|&z| inside(z, cd.nz)) {
                for q in 0..Q {
                    let at = |i: usize| (i as f32 + 0.5) / 2.0;
                    let want = light(at(x), at(y), at(z), q);
                    let got = fine.f(x, y, z, q);
                    assert!(
                        (got - want).abs() < 1e-5,
                        "({x}, {y}, {z}) {q}: {got} vs {want}"
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 1000, "{checked}");
}

#[test]
fn a_coarse_site_crosses_twice_the_optical_depth() {
    // Restriction keeps the medium's extinction per length: a coarse step crosses two fine
    // cells, so uniform density ρ becomes 1 - (1 - ρ)²; a uniform source doubles per step.
    let dims = Dims::new(14, 10, 12).unwrap();
    let rho = 0.3f32;
    let interior = |i: usize| {
        let (x, y, z) = dims.coords(i);
        !dims.on_shell(x, y, z)
    };
    let grid = DensityGrid::new(
        dims,
        sylva_lb::Bounds::UNIT,
        (0..dims.sites())
            .map(|i| if interior(i) { rho } else { 0.0 })
            .collect(),
        vec![0.0; dims.sites()],
    )
    .unwrap();
    let m = Preset::Leaf.params();
    let mut fine = Lattice::new(&grid, &m, 1, Boundary::sun([0.0, -1.0, 0.0], 1.0)).unwrap();
    fine.set_source(Some(sylva_lb::solver::ColourSource {
        strength: (0..dims.sites())
            .map(|i| if interior(i) { 0.01 } else { 0.0 })
            .collect(),
        green: std::array::from_fn(|m| weight(m) as f32),
        brown: [0.0; Q],
    }));
    let coarse = fine.restricted();
    let cd = coarse.dims();
    let want = 1.0 - (1.0 - rho) * (1.0 - rho);
    for i in 0..cd.sites() {
        let (x, y, z) = cd.coords(i);
        let (code, strength) = (coarse.code(i), coarse.source_strength(i));
        if cd.on_shell(x, y, z) {
            assert_eq!((code, strength), (0.0, 0.0));
        } else {
            assert!(
                (code - want).abs() < 1e-6,
                "({x}, {y}, {z}): {code} vs {want}"
            );
            assert!(
                (strength - 0.02).abs() < 1e-7,
                "({x}, {y}, {z}): {strength}"
            );
        }
    }
}

#[test]
fn sun_solution_is_the_weighted_sum_of_base_solutions() {
    // LB is linear (SPEC §3): a sun boundary equals Σ_i max(0, n_i·d) B_i.
    let dims = Dims::cube(16).unwrap();
    let grid = Shape::Crown.grid(dims);
    let m = Preset::Leaf.params();
    let opts = SolveOptions {
        max_steps: 48,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let sun = Boundary::sun([0.3, -0.9, 0.3], 1.0);
    let solve = |b: Boundary| {
        let mut lat = Lattice::new(&grid, &m, 1, b).unwrap();
        lat.run(&opts, &mut |_, _| {}).unwrap();
        lat.site_totals()
    };
    let full = solve(sun);
    let mut sum = vec![0.0f32; full.len()];
    for (j, &w) in sun.values.iter().enumerate().skip(1) {
        if w > 0.0 {
            for (s, v) in sum.iter_mut().zip(solve(Boundary::basis(j))) {
                *s += w * v;
            }
        }
    }
    for (a, b) in full.iter().zip(&sum) {
        assert!((a - b).abs() <= 1e-5 * a.abs().max(1e-3), "{a} vs {b}");
    }
    assert!(weight(1) > weight(7));
}

#[test]
fn bad_parameters_are_refused() {
    let dims = Dims::cube(8).unwrap();
    let grid = DensityGrid::empty(dims);
    let mut m = Preset::Leaf.params();
    m.colours[1].g = f64::NAN;
    let e = Lattice::new(&grid, &m, 0, Boundary::sun([0.0, -1.0, 0.0], 1.0))
        .err()
        .unwrap();
    assert!(e.to_string().contains("green g"), "{e}");
    let m = Preset::Leaf.params();
    let mut b = Boundary::sun([0.0, -1.0, 0.0], 1.0);
    b.values[3] = f32::INFINITY;
    assert!(Lattice::new(&grid, &m, 0, b).is_err());
    let mut lat = Lattice::new(&grid, &m, 0, Boundary::basis(0)).unwrap();
    assert!(lat
        .run(
            &SolveOptions {
                max_steps: 0,
                tolerance: None,
                extrapolate: false,
                coarse_start: false,
            },
            &mut |_, _| {}
        )
        .is_err());
    assert!(lat
        .run(
            &SolveOptions {
                max_steps: 5,
                tolerance: Some(-1.0),
                extrapolate: false,
                coarse_start: false,
            },
            &mut |_, _| {}
        )
        .is_err());
}
