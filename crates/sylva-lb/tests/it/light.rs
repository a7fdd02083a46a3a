//! The physical light's operators (docs/light.md) checked against the LB solver itself:
//! the uncollided field is the solve of a medium that scatters nothing, a solve's total is its
//! uncollided part plus the LB transport of the first collisions, free space scatters
//! nothing, and the whole physical light (diffuse boundary, floor, first-collision sun) is
//! linear in the sun's and sky's light.
#![allow(clippy::needless_range_loop)]

use sylva_lb::collision::Omega;
use sylva_lb::lattice::{C, Q};
use sylva_lb::light::{self, Environment};
use sylva_lb::{
    solve_lighting_rgb, Boundary, ColourParams, DensityGrid, Dims, LightingGrid, MediumParams,
    SolveOptions, VolumeSource,
};

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
        g.density[i] = 0.6 * next();
        g.wood[i] = if r > 0.85 { 1.0 } else { 0.0 };
    }
    g
}

/// Leaves that absorb red and blue and scatter green, bark a dull brown.
fn plant_medium() -> MediumParams {
    light::medium_for(&light::PlantOptics {
        leaf_reflectance: [0.06, 0.25, 0.03],
        leaf_transmittance: [0.05, 0.30, 0.015],
        bark_reflectance: [0.3, 0.2, 0.12],
    })
    .unwrap()
}

fn environment(sun: f64, sky: f64) -> Environment {
    Environment {
        sun_travel: [0.35, -0.8, 0.2],
        sun_irradiance: [sun, 0.9 * sun, 0.8 * sun],
        sky_radiance: [0.55 * sky, 0.7 * sky, 0.95 * sky],
        ground_albedo: Some([0.25, 0.2, 0.15]),
    }
}

/// Long enough for these small, absorbing grids to reach their steady state.
fn opts(dims: Dims) -> SolveOptions {
    SolveOptions {
        max_steps: 8 * dims.longest_edge(),
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    }
}

fn solve(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
    source: Option<&VolumeSource>,
) -> LightingGrid {
    let floor = None;
    solve_lighting_rgb(
        grid,
        medium,
        boundaries,
        floor,
        source,
        &opts(grid.dims),
        &mut |_, _, _| {},
    )
    .unwrap()
    .0
}

/// The physical light of docs/light.md: the diffuse boundary and the floor under the plant,
/// and the sun as a first-collision source.
fn physical(grid: &DensityGrid, medium: &MediumParams, env: &Environment) -> LightingGrid {
    let floor = env.floor(grid, medium).unwrap();
    let source =
        light::first_collision_source(grid, medium, env.sun_travel, env.sun_irradiance).unwrap();
    solve_lighting_rgb(
        grid,
        medium,
        &env.diffuse_boundaries(),
        floor.as_ref(),
        Some(&source),
        &opts(grid.dims),
        &mut |_, _, _| {},
    )
    .unwrap()
    .0
}

/// Largest per-site difference over the largest value, all colours.
fn relative_difference(a: &LightingGrid, b: &LightingGrid) -> f64 {
    let mut diff = 0.0f64;
    let mut max = 0.0f64;
    for c in 0..3 {
        for (x, y) in a.colours[c].iter().zip(&b.colours[c]) {
            diff = diff.max((*x as f64 - *y as f64).abs());
            max = max.max(x.abs() as f64).max(y.abs() as f64);
        }
    }
    assert!(max > 0.0, "all zero");
    diff / max
}

#[test]
fn uncollided_is_the_solve_of_a_medium_that_scatters_nothing() {
    let dims = Dims::new(11, 13, 9).unwrap();
    let grid = mixed_grid(dims, 7);
    let env = environment(1.0, 1.0);
    let boundaries = env.boundaries();
    // Same extinction per colour as the plant, nothing scattered.
    let plant = plant_medium();
    let black = |p: ColourParams| ColourParams::new(p.sigma_t(), 0.0, 0.0).unwrap();
    let medium = MediumParams {
        colours: plant.colours.map(black),
        brown: Some(std::array::from_fn(|c| black(plant.brown_colour(c)))),
        ..plant
    };
    let want = solve(&grid, &medium, &boundaries, None);
    let got = light::uncollided(&grid, &plant, &boundaries).unwrap();
    let d = relative_difference(&want, &got);
    assert!(d < 1e-5, "uncollided vs non-scattering solve: {d}");

    // In free space everything is uncollided: the scattering medium's solve equals it.
    let empty = DensityGrid::empty(dims);
    let total = solve(&empty, &plant, &boundaries, None);
    let free = light::uncollided(&empty, &plant, &boundaries).unwrap();
    assert!(relative_difference(&total, &free) < 1e-5);
    let scattered = light::subtract(&total, &free);
    for c in 0..3 {
        assert!(scattered.colours[c].iter().all(|v| v.abs() < 1e-5));
    }
    // Nor does the sun's first-collision source put any light there.
    let s =
        light::first_collision_source(&empty, &plant, env.sun_travel, env.sun_irradiance).unwrap();
    assert!(s.strength.iter().flatten().all(|&v| v == 0.0));
}

#[test]
fn total_is_uncollided_plus_transported_first_collisions() {
    // One boundary direction: its uncollided light travels along that direction only, so the
    // first collisions are a volume source of one profile per site kind, column j of Ω plus
    // the σ_t the uncollided part keeps, at strength ρ U_j.
    let dims = Dims::new(10, 12, 10).unwrap();
    let grid = mixed_grid(dims, 3);
    let medium = plant_medium();
    let j = (1..Q).find(|&m| C[m] == [1, -1, 0]).unwrap();
    let boundaries: [Boundary; 3] = std::array::from_fn(|c| {
        let mut values = [0.0f32; Q];
        values[j] = [1.0, 0.8, 0.6][c];
        Boundary { values }
    });
    let total = solve(&grid, &medium, &boundaries, None);
    let uncollided = light::uncollided(&grid, &medium, &boundaries).unwrap();

    let profile = |p: &ColourParams| -> [f32; Q] {
        let o = Omega::new(p);
        std::array::from_fn(|m| {
            if m == 0 {
                0.0
            } else {
                let v = o.0[m][j] + if m == j { p.sigma_t() } else { 0.0 };
                assert!(v >= -1e-12, "profile {m}: {v}");
                v.max(0.0) as f32
            }
        })
    };
    let source = VolumeSource {
        strength: std::array::from_fn(|c| {
            (0..dims.sites())
                .map(|i| {
                    let (x, y, z) = dims.coords(i);
                    if dims.on_shell(x, y, z) {
                        0.0
                    } else {
                        grid.density[i] * uncollided.colours[c][i]
                    }
                })
                .collect()
        }),
        green: std::array::from_fn(|c| profile(&medium.colours[c])),
        brown: std::array::from_fn(|c| profile(&medium.brown_colour(c))),
    };
    let zero = [Boundary { values: [0.0; Q] }; 3];
    let scattered = solve(&grid, &medium, &zero, Some(&source));
    let sum = LightingGrid {
        colours: std::array::from_fn(|c| {
            uncollided.colours[c]
                .iter()
                .zip(&scattered.colours[c])
                .map(|(u, s)| u + s)
                .collect()
        }),
        ..total.clone()
    };
    // Shell sites hold the boundary in the total and in the uncollided part alike.
    let d = relative_difference(&total, &sum);
    assert!(d < 1e-4, "total vs uncollided + scattered: {d}");
    // And the scattered part is real light, not rounding: a good share of the total.
    let share: f64 = scattered.colours[1].iter().map(|&v| v as f64).sum::<f64>()
        / total.colours[1].iter().map(|&v| v as f64).sum::<f64>();
    assert!(share > 0.02, "scattered share {share}");
}

#[test]
fn physical_light_is_linear_in_sun_and_sky() {
    let dims = Dims::new(9, 11, 9).unwrap();
    let grid = mixed_grid(dims, 11);
    let medium = plant_medium();
    let sun = physical(&grid, &medium, &environment(1.0, 0.0));
    let sky = physical(&grid, &medium, &environment(0.0, 1.0));
    let both = physical(&grid, &medium, &environment(2.0, 0.5));
    let combined = LightingGrid {
        colours: std::array::from_fn(|c| {
            sun.colours[c]
                .iter()
                .zip(&sky.colours[c])
                .map(|(a, b)| 2.0 * a + 0.5 * b)
                .collect()
        }),
        ..both.clone()
    };
    let d = relative_difference(&both, &combined);
    assert!(d < 1e-5, "sun 2, sky 0.5 vs 2 × sun + 0.5 × sky: {d}");
    // Both parts light the interior, and the sun's is scattered light only: nothing on
    // sites its beam never meets a leaf before (free space above the grid's medium is zero
    // only where nothing scatters towards it, so check the total is positive instead).
    for g in [&sun, &sky] {
        assert!(g.colours[1].iter().sum::<f32>() > 0.0);
    }
    // A black ground and no sky: only the sun's scattered light, which the source carries.
    let no_ground = Environment {
        ground_albedo: Some([0.0; 3]),
        ..environment(1.0, 0.0)
    };
    let scattered_only = physical(&grid, &medium, &no_ground);
    let free = physical(&DensityGrid::empty(dims), &medium, &no_ground);
    assert!(free.colours.iter().flatten().all(|v| v.abs() < 1e-6));
    assert!(scattered_only.colours[1].iter().sum::<f32>() > 0.0);
}

#[test]
fn sky_and_ground_fill_their_hemispheres() {
    // A free-space site under a sky of radiance L alone holds 2 L (half the sphere at 4 L w),
    // above an open ground of radiance G the ground adds 2 G.
    let dims = Dims::new(7, 7, 7).unwrap();
    let medium = plant_medium();
    let l = [0.5, 0.7, 0.9];
    let g = [0.2, 0.1, 0.05];
    let b = light::add(&light::sky_boundaries(l), &light::ground_boundaries(g));
    let lit = solve(&DensityGrid::empty(dims), &medium, &b, None);
    let centre = dims.index(3, 3, 3);
    for c in 0..3 {
        let want = 2.0 * (l[c] + g[c]);
        assert!(
            (lit.colours[c][centre] as f64 - want).abs() < 1e-5,
            "colour {c}: {} vs {want}",
            lit.colours[c][centre]
        );
    }
}
