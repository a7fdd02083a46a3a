//! The cumulus generator: determinism, the parcel model's flat base and water profile, the
//! grid's rules (values in [0, 1], an empty shell) and parameter checks.

use sylva_grow::cloud::{cumulus, CloudError, Cumulus, CumulusParams};

fn small(seed: u64) -> Cumulus {
    cumulus(&CumulusParams::for_grid([96, 48, 48], seed)).unwrap()
}

fn at(c: &Cumulus, x: usize, y: usize, z: usize) -> f32 {
    c.density[(x * c.dims[1] + y) * c.dims[2] + z]
}

#[test]
fn same_seed_same_cloud_other_seed_other_cloud() {
    let a = small(3);
    let b = small(3);
    assert_eq!(a.density, b.density, "bit for bit");
    let c = small(4);
    assert_ne!(a.density, c.density);
    // Different thread counts: each site is a pure function of the bubbles.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| small(3));
    assert_eq!(one.density, a.density);
}

#[test]
fn values_lie_in_the_unit_range_and_the_shell_is_empty() {
    let c = small(1);
    let [nx, ny, nz] = c.dims;
    assert_eq!(c.density.len(), nx * ny * nz);
    assert!(c
        .density
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    for x in 0..nx {
        for y in 0..ny {
            for z in 0..nz {
                if x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 {
                    assert_eq!(at(&c, x, y, z), 0.0, "shell site ({x}, {y}, {z})");
                }
            }
        }
    }
    let occupied = c.density.iter().filter(|&&v| v > 0.01).count();
    let fraction = occupied as f64 / c.density.len() as f64;
    assert!((0.03..0.6).contains(&fraction), "cloud fills {fraction}");
}

#[test]
fn the_base_is_flat_at_the_condensation_level() {
    // The default dew-point spread of 2.4 K puts the LCL at 125 m/K × 2.4 = 300 m.
    let p = CumulusParams::default();
    let c = cumulus(&p).unwrap();
    assert!((c.base * c.cell_m - 300.0).abs() < 1e-9);
    let [nx, ny, nz] = c.dims;
    let base = c.base;
    // Nothing condenses below the base (one cell of anti-aliasing), and the underside is a
    // plane: the level where most cloudy columns start is the base, and more columns start
    // there than in the ten levels above it together (the rest start higher, under the
    // bulging sides and caps).
    let mut first_level = vec![0usize; ny];
    for x in 0..nx {
        for z in 0..nz {
            let mut first = None;
            for y in 0..ny {
                let v = at(&c, x, y, z);
                if v > 0.0 {
                    assert!(y as f64 >= base - 1.0, "density {v} at y {y}, base {base}");
                }
                if v > 0.02 && first.is_none() {
                    first = Some(y);
                }
            }
            if let Some(y) = first {
                first_level[y] += 1;
            }
        }
    }
    let mode = (0..ny).max_by_key(|&y| first_level[y]).unwrap();
    assert!(
        (mode as f64 - base).abs() <= 1.5,
        "most columns start at {mode}, base {base}"
    );
    let above: usize = first_level[mode + 1..mode + 11].iter().sum();
    assert!(
        first_level[mode] > above,
        "{} at the base, {above} just above",
        first_level[mode]
    );
}

#[test]
fn liquid_water_grows_above_the_base_and_towers_differ() {
    let c = cumulus(&CumulusParams::default()).unwrap();
    let [nx, ny, nz] = c.dims;
    // Mean density of cloudy sites per level: the adiabatic water grows with height above
    // the base before entrainment dilutes it.
    let level_mean = |y: usize| {
        let (mut s, mut n) = (0.0f64, 0usize);
        for x in 0..nx {
            for z in 0..nz {
                let v = at(&c, x, y, z);
                if v > 0.01 {
                    s += v as f64;
                    n += 1;
                }
            }
        }
        s / n.max(1) as f64
    };
    let b = c.base.ceil() as usize;
    let (low, mid) = (level_mean(b + 2), level_mean(b + 20));
    assert!(
        mid > 2.0 * low,
        "level means {low} at the base, {mid} 20 cells up"
    );
    // Thermals stop at different heights (the tallest tower is the strongest), all above
    // the base and inside the grid.
    let tops: Vec<f64> = c.thermals.iter().map(|t| t.top / c.cell_m).collect();
    let (lo, hi) = tops
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &t| (a.min(t), b.max(t)));
    assert!(hi - lo > 5.0, "tops {tops:?}");
    assert!(lo > c.base && hi < ny as f64, "tops {tops:?}");
    // Nothing above the tallest top (the sub-bubbles of its dome aside, a few cells).
    for x in 0..nx {
        for z in 0..nz {
            for y in (hi.ceil() as usize + 8).min(ny)..ny {
                assert_eq!(at(&c, x, y, z), 0.0);
            }
        }
    }
}

#[test]
fn bad_parameters_are_refused_by_name() {
    let bad = |p: CumulusParams| cumulus(&p).unwrap_err().to_string();
    let d = CumulusParams::default;
    assert!(bad(CumulusParams {
        dims: [8, 128, 128],
        ..d()
    })
    .contains("8×128×128"));
    assert!(bad(CumulusParams {
        cell_m: f64::NAN,
        ..d()
    })
    .contains("cell_m"));
    assert!(bad(CumulusParams {
        lapse_rate: 12.0,
        ..d()
    })
    .contains("lapse_rate"));
    assert!(bad(CumulusParams {
        radius_m: [200.0, 100.0],
        ..d()
    })
    .contains("radius_m"));
    assert!(bad(CumulusParams { thermals: 0, ..d() }).contains("thermals"));
    // Air too dry for the thermals: the LCL is out of their reach.
    let e = cumulus(&CumulusParams {
        dew_point_spread: 6.0,
        ..d()
    })
    .unwrap_err();
    assert!(matches!(e, CloudError::NoCloud { .. }), "{e}");
    // ... or out of the grid.
    let e = cumulus(&CumulusParams {
        dew_point_spread: 12.0,
        ..d()
    })
    .unwrap_err();
    assert!(e.to_string().contains("1500 m (the cloud's base)"), "{e}");
}
