//! Measures relighting on one density grid: the time to solve its 19 base solutions, and
//! bytes against relit error for each compression codec.
//!
//! ```sh
//! sylva voxelize southern_catalpa -o catalpa.sgrid
//! cargo run --release -p sylva-lb --example relight_measure -- catalpa.sgrid catalpa.sbasis
//! ```
//!
//! The basis set is solved and written to the second path, or read from it when it exists
//! (`--solve` solves again; `--tolerance T` adds a convergence stop, and B_0 is then solved;
//! `--extrapolate` solves with `SolveOptions::extrapolated`, `--coarse-start` with
//! `SolveOptions::coarse_started`).
//! `--steps-study` prints how far fewer steps are from the full schedule. Options: `--preset NAME` (default leaf), `--threads N`,
//! `--points N` (lookups per sun for the error, default 200000), `--suns N` (default 24),
//! `--precision f16|f32|packed` (stored values; PCA alone stays f16 with packed),
//! `--only haar|pca|pcahaar|colour`, `--codecs LIST` (comma-separated `haar:T`, `pca:K`,
//! `pcahaar:K:T`, `colour:T`).

use std::path::PathBuf;
use std::time::Instant;

use sylva_lb::relight::{
    compress, relit_error, sky_directions, BasisOptions, BasisSet, BasisWeights, Codec,
    CompressTarget, Precision, Region,
};
use sylva_lb::{Element, GridFile, Preset};

struct Args {
    density: PathBuf,
    basis: PathBuf,
    preset: String,
    threads: Option<usize>,
    points: usize,
    suns: usize,
    solve: bool,
    only: Option<String>,
    codecs: Option<Vec<Codec>>,
    precision: Precision,
    steps_study: bool,
    tolerance: Option<f64>,
    extrapolate: bool,
    coarse_start: bool,
}

fn parse() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let mut paths = Vec::new();
    let mut args = Args {
        density: PathBuf::new(),
        basis: PathBuf::new(),
        preset: "leaf".into(),
        threads: None,
        points: 200_000,
        suns: 24,
        solve: false,
        only: None,
        codecs: None,
        precision: Precision::F16,
        steps_study: false,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().ok_or(format!("{name} needs a value"));
        let number = |name: &str, v: String| {
            v.parse::<usize>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or(format!("{name} {v}: expected a positive whole number"))
        };
        match a.as_str() {
            "--preset" => args.preset = value("--preset")?,
            "--threads" => args.threads = Some(number("--threads", value("--threads")?)?),
            "--points" => args.points = number("--points", value("--points")?)?,
            "--suns" => args.suns = number("--suns", value("--suns")?)?,
            "--only" => args.only = Some(value("--only")?),
            "--solve" => args.solve = true,
            "--steps-study" => args.steps_study = true,
            "--extrapolate" => args.extrapolate = true,
            "--coarse-start" => args.coarse_start = true,
            "--tolerance" => {
                let v = value("--tolerance")?;
                args.tolerance = Some(
                    v.parse::<f64>()
                        .ok()
                        .filter(|t| t.is_finite() && *t > 0.0)
                        .ok_or(format!("--tolerance {v}: expected a positive number"))?,
                )
            }
            "--precision" => {
                args.precision = match value("--precision")?.as_str() {
                    "f16" => Precision::F16,
                    "f32" => Precision::F32,
                    "packed" => Precision::Packed,
                    p => return Err(format!("--precision {p}: expected f16, f32 or packed")),
                }
            }
            "--codecs" => {
                args.codecs = Some(
                    value("--codecs")?
                        .split(',')
                        .map(Codec::parse)
                        .collect::<Result<_, _>>()?,
                )
            }
            _ if a.starts_with("--") => return Err(format!("unknown option {a}")),
            _ => paths.push(PathBuf::from(a)),
        }
    }
    let [density, basis] = <[PathBuf; 2]>::try_from(paths)
        .map_err(|_| "usage: relight_measure DENSITY.sgrid BASIS.sbasis [options]".to_string())?;
    args.density = density;
    args.basis = basis;
    Ok(args)
}

fn main() {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = args.threads {
        pool = pool.num_threads(n);
    }
    let pool = pool.build().expect("a thread pool");
    if let Err(e) = pool.install(|| run(&args)) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let grid = GridFile::read(&args.density)?.into_density(&args.density)?;
    let medium = Preset::parse(&args.preset)?.params();
    let (mean, occupied) = grid.occupancy();
    println!(
        "{}: {} grid, {occupied} occupied sites (mean density {mean:.4}), preset {}, {} threads",
        args.density.display(),
        grid.dims,
        args.preset,
        rayon::current_num_threads()
    );
    let basis = if args.basis.exists() && !args.solve {
        let t = Instant::now();
        let b = BasisSet::read(&args.basis)?;
        println!(
            "read {} in {:.1} s",
            args.basis.display(),
            t.elapsed().as_secs_f64()
        );
        if b.dims != grid.dims || b.bounds != grid.bounds {
            return Err(format!(
                "{} is a {} basis set; {} is a {} grid: pass --solve",
                args.basis.display(),
                b.dims,
                args.density.display(),
                grid.dims
            )
            .into());
        }
        b
    } else {
        solve(args, &grid, &medium)?
    };
    if args.steps_study {
        return steps_study(&grid, &medium);
    }
    measure_compression(args, &grid, &basis)
}

/// How far from the papers' 2 × edge result a solve is after fewer steps: one colour (green)
/// of a few bases, RMS difference over the region (free space 1), and the residual there.
fn steps_study(
    grid: &sylva_lb::DensityGrid,
    medium: &sylva_lb::MediumParams,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let region = Region::near_medium(grid, 1).with_floor(2);
    let sites = region.sites();
    let full = 2 * grid.dims.longest_edge();
    let chunk = 16;
    println!("| basis | steps | residual | RMS vs {full} steps | max |");
    println!("| --- | --- | --- | --- | --- |");
    for j in [4, 8, 1, 5] {
        let mut lat = sylva_lb::Lattice::new(grid, medium, 1, sylva_lb::Boundary::basis(j))?;
        let mut snapshots = Vec::new();
        for _ in 0..full / chunk {
            let opts = sylva_lb::SolveOptions {
                max_steps: chunk,
                tolerance: None,
                extrapolate: false,
                coarse_start: false,
            };
            let r = lat.run(&opts, &mut |_, _| {})?;
            let totals = lat.site_totals();
            snapshots.push((
                r.residual,
                sites.iter().map(|&s| totals[s]).collect::<Vec<f32>>(),
            ));
        }
        let last = snapshots.last().expect("steps").1.clone();
        for (k, (residual, v)) in snapshots.iter().enumerate() {
            let steps = (k + 1) * chunk;
            if steps < full / 2 || steps == full {
                continue;
            }
            let (mut sq, mut max) = (0.0f64, 0.0f64);
            for (a, b) in v.iter().zip(&last) {
                let d = (a - b) as f64;
                sq += d * d;
                max = max.max(d.abs());
            }
            println!(
                "| B_{j} | {steps} | {residual:.1e} | {:.1e} | {max:.1e} |",
                (sq / v.len() as f64).sqrt()
            );
        }
    }
    Ok(())
}

fn solve(
    args: &Args,
    grid: &sylva_lb::DensityGrid,
    medium: &sylva_lb::MediumParams,
) -> Result<BasisSet, Box<dyn std::error::Error + Send + Sync>> {
    let mut options = BasisOptions::papers(grid.dims);
    if args.extrapolate {
        options.solve = sylva_lb::SolveOptions::extrapolated(grid.dims);
    }
    if args.coarse_start {
        options.solve = sylva_lb::SolveOptions::coarse_started(grid.dims);
    }
    options.solve.tolerance = args.tolerance;
    if args.tolerance.is_some() {
        // Each solve stops on its own: B_0 is then solved, not summed (linearity is only
        // as good as the tolerance).
        options.ambient = sylva_lb::relight::Ambient::Solve;
    }
    // Baseline in the same run: one sun (three colours) with the same schedule.
    let t = Instant::now();
    sylva_lb::solve_lighting(
        grid,
        medium,
        sylva_lb::Boundary::sun([0.3, -0.9, 0.3], 1.0),
        &options.solve,
        &mut |_, _, _| {},
    )?;
    let sun = t.elapsed().as_secs_f64();
    println!(
        "baseline: one sun solve (3 colours) {sun:.2} s; solving the basis: {} steps at most{}, B_0 {}",
        options.solve.max_steps,
        args.tolerance
            .map_or(String::new(), |t| format!(", tolerance {t}")),
        if args.tolerance.is_some() { "solved" } else { "summed" }
    );
    let t = Instant::now();
    let (basis, reports) = BasisSet::solve(grid, medium, &options, &mut |_| {})?;
    let total = t.elapsed().as_secs_f64();
    for r in &reports {
        let colours: Vec<String> = r
            .colours
            .iter()
            .map(|c| format!("{:.2} s {:.0} MLUPS", c.seconds, c.mlups(grid.dims)))
            .collect();
        println!(
            "  B_{:<2} {:6.2} s  {} steps ({})",
            r.basis,
            r.seconds,
            r.colours[0].steps,
            colours.join(", ")
        );
    }
    let mut per: Vec<f64> = reports.iter().map(|r| r.seconds).collect();
    per.sort_by(f64::total_cmp);
    println!(
        "basis total {total:.1} s for {} solves ({} colour solves), median {:.2} s per boundary, {:.2} × the baseline sun",
        reports.len(),
        3 * reports.len(),
        per[per.len() / 2],
        total / sun
    );
    let t = Instant::now();
    basis.write(&args.basis, Element::F32)?;
    println!(
        "wrote {} in {:.1} s",
        args.basis.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(basis)
}

fn measure_compression(
    args: &Args,
    grid: &sylva_lb::DensityGrid,
    basis: &BasisSet,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    // Where the renderer looks: in and next to the medium, and the ground layers.
    let region = Region::near_medium(grid, 1).with_floor(2);
    let raw = BasisSet::memory_needed(basis.dims);
    println!(
        "region: {} of {} sites ({:.1} %); uncompressed {:.1} MB (f32), {:.1} MB (f16)",
        region.count(),
        basis.dims.sites(),
        100.0 * region.count() as f64 / basis.dims.sites() as f64,
        raw as f64 / 1e6,
        raw as f64 / 2e6
    );
    let suns = sky_directions(args.suns);
    let sun: Vec<BasisWeights> = suns
        .iter()
        .map(|&d| BasisWeights::three_basis(d))
        .collect::<Result<_, _>>()?;
    let ambient = [BasisWeights([0.0; 19]).with_ambient(1.0)?];
    println!(
        "relit RMSE: three-basis sun (free space 1) at {} sky directions, and ambient B_0/18 alone; {} random lookups in the region per combination",
        args.suns, args.points
    );
    println!();
    println!("| codec | MB | ratio | coefficients | sun RMSE | sun max | ambient RMSE | compress s | lookups/s (1 thread) |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    let mut codecs = Vec::new();
    for threshold in [5e-4, 1e-3, 2e-3, 4e-3, 8e-3] {
        codecs.push(("haar", Codec::Haar { threshold }));
    }
    for rank in [4, 6, 8, 12, 16, 24] {
        codecs.push(("pca", Codec::Pca { rank }));
    }
    for (rank, threshold) in [
        (8, 1e-3),
        (12, 1e-3),
        (12, 2e-3),
        (16, 1e-3),
        (16, 2e-3),
        (24, 2e-3),
    ] {
        codecs.push(("pcahaar", Codec::PcaHaar { rank, threshold }));
    }
    for threshold in [1e-3, 2e-3, 4e-3, 8e-3] {
        codecs.push(("colour", Codec::ColourHaar { threshold }));
    }
    if let Some(list) = &args.codecs {
        codecs = list.iter().map(|&c| ("custom", c)).collect();
    }
    // Lookup speed: one thread, the first sun, random points of the region.
    let lookup_points: Vec<[f32; 3]> = {
        let sites = region.sites();
        let mut r = sylva_core::SplitMix64::new(5);
        (0..200_000)
            .map(|_| {
                let s = sites[(r.next_u64() % sites.len() as u64) as usize];
                let (x, y, z) = basis.dims.coords(s);
                [x, y, z].map(|v| v as f32 + r.next_f64() as f32)
            })
            .collect()
    };
    let rate = |lookup: &dyn Fn([f32; 3]) -> f32| {
        let t = Instant::now();
        let acc: f32 = lookup_points.iter().map(|&p| lookup(p)).sum();
        std::hint::black_box(acc);
        lookup_points.len() as f64 / t.elapsed().as_secs_f64()
    };
    println!(
        "| uncompressed (f32) | {:.1} | 1.0 | | 0 | 0 | 0 | | {:.2e} |",
        raw as f64 / 1e6,
        rate(&|p| basis.sample(p, &sun[0])[1])
    );
    for (family, codec) in codecs {
        if args.only.as_deref().is_some_and(|o| o != family) {
            continue;
        }
        let t = Instant::now();
        let mut target = CompressTarget::new(codec);
        // PCA alone stores plain fields: packed values are for the Haar codecs.
        if !(matches!(codec, Codec::Pca { .. }) && args.precision == Precision::Packed) {
            target.precision = args.precision;
        }
        let c = compress(basis, &region, &target)?;
        let seconds = t.elapsed().as_secs_f64();
        let e = relit_error(basis, &c, &region, &sun, args.points, 1)?;
        let a = relit_error(basis, &c, &region, &ambient, args.points, 2)?;
        let w = c.project(&sun[0]);
        let rate = rate(&|p| c.sample_grid(p, &w)[1]);
        let codec_name = match codec {
            Codec::Haar { threshold } => format!("Haar t={threshold}"),
            Codec::Pca { rank } => format!("PCA k={rank}"),
            Codec::PcaHaar { rank, threshold } => format!("PCA k={rank} + Haar t={threshold}"),
            Codec::ColourHaar { threshold } => format!("colour PCA + Haar t={threshold}"),
        };
        println!(
            "| {codec_name} | {:.1} | {:.1} | {} | {:.5} | {:.4} | {:.5} | {seconds:.1} | {:.2e} |",
            c.bytes() as f64 / 1e6,
            raw as f64 / c.bytes() as f64,
            c.haar_coefficients(),
            e.rmse,
            e.max,
            a.rmse,
            rate
        );
    }
    Ok(())
}
