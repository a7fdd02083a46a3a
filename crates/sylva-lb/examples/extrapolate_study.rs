//! How fast a sun solve approaches its steady state: plain, with extrapolation along the
//! slowest mode, and started from a half-resolution solve (studies for issue 28 item 4).
//!
//! ```sh
//! sylva voxelize southern_catalpa -o catalpa.sgrid
//! cargo run --release -p sylva-lb --example extrapolate_study -- catalpa.sgrid [REFERENCE_STEPS] [COLOUR] [BASIS | source]
//! ```
//!
//! `source` lights the grid as the physical light's sun part does: the sun's first-collision
//! source inside a dark boundary.

use std::time::Instant;

use sylva_lb::{Boundary, GridFile, Lattice, Preset, SolveOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = std::path::PathBuf::from(&args[0]);
    let reference_steps: usize = args.get(1).map_or(Ok(1024), |s| s.parse())?;
    let grid = GridFile::read(&path)?.into_density(&path)?;
    let medium = Preset::parse("leaf")?.params();
    // The catalpa scene's sun: elevation 50°, azimuth 30°.
    let sun = sylva_core::Sun::from_angles(50.0, 30.0)?;
    // Optional: the colour (default 1, green) and a basis boundary or the first-collision
    // source instead of the sun.
    let colour: usize = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let source = args.get(3).map(String::as_str) == Some("source");
    let boundary = match args.get(3) {
        Some(_) if source => Boundary { values: [0.0; 19] },
        Some(j) => Boundary::basis(j.parse()?),
        None => Boundary::sun(sun.travel().to_array(), 1.0),
    };
    let mut lat = Lattice::new(&grid, &medium, colour, boundary)?;
    if source {
        let travel = sun.travel().to_array();
        let s = sylva_lb::light::first_collision_source(&grid, &medium, travel, [1.0; 3])?;
        lat.set_source(Some(s.colour(colour)));
    }
    let medium_sites: Vec<usize> = (0..grid.dims.sites())
        .filter(|&i| grid.density[i] > 0.0)
        .collect();
    let t0 = Instant::now();
    for _ in 0..reference_steps / 2 {
        lat.step_pair();
    }
    let reference = lat.site_totals();
    let scale = (medium_sites
        .iter()
        .map(|&i| (reference[i] as f64).powi(2))
        .sum::<f64>()
        / medium_sites.len() as f64)
        .sqrt();
    eprintln!(
        "reference: {reference_steps} steps in {:.1} s; {} medium sites, RMS {scale:.4}",
        t0.elapsed().as_secs_f64(),
        medium_sites.len()
    );
    let error = |lat: &Lattice| {
        let f = lat.site_totals();
        let rms = (medium_sites
            .iter()
            .map(|&i| ((f[i] - reference[i]) as f64).powi(2))
            .sum::<f64>()
            / medium_sites.len() as f64)
            .sqrt();
        rms / scale
    };
    let checkpoints: Vec<usize> = (4..=12).map(|i| i * 32).collect();
    // How the plain solve approaches the steady state.
    lat.reset(boundary);
    let mut line = String::new();
    for step in (2..=*checkpoints.last().unwrap()).step_by(2) {
        lat.step_pair();
        if checkpoints.contains(&step) {
            line += &format!(" {step}:{:.2e}", error(&lat));
        }
    }
    println!("plain:{line}");
    // The schedules as the solver runs them.
    let dims = grid.dims;
    for (name, opts) in [
        ("papers", SolveOptions::papers(dims)),
        (
            "plain, as many steps as extrapolated",
            SolveOptions {
                extrapolate: false,
                coarse_start: false,
                ..SolveOptions::extrapolated(dims)
            },
        ),
        ("extrapolated", SolveOptions::extrapolated(dims)),
        ("coarse-started", SolveOptions::coarse_started(dims)),
        (
            "coarse-started, 0.875 × the edge",
            SolveOptions {
                max_steps: 7 * dims.longest_edge() / 8,
                ..SolveOptions::coarse_started(dims)
            },
        ),
    ] {
        lat.reset(boundary);
        let t = Instant::now();
        let report = lat.run(&opts, &mut |_, _| {})?;
        println!(
            "{name}: {} steps in {:.2} s, {:.2e} from the steady state",
            report.steps,
            t.elapsed().as_secs_f64(),
            error(&lat)
        );
    }
    Ok(())
}
