//! `sylva lb`: light a density grid with the lattice-Boltzmann solver; describe grid files.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use sylva_core::{companion_path, OutputSet, Sun};
use sylva_geom::params::MediumOverrides;
use sylva_grid::info::{read_raw, GridInfo};
use sylva_lb::report::{lighting_line, SolvedGrid};
use sylva_lb::shapes::Shape;
use sylva_lb::{Boundary, DensityGrid, Dims, Element, GridFile, RawElement, SolveOptions};
use sylva_scene::model_source::{load_scene_model, scene_model_preset};
use sylva_scene::SceneDesc;
use sylva_voxel::parse_grid_flag;

use super::progress::bar;

#[derive(Args)]
pub struct LbArgs {
    #[command(subcommand)]
    command: LbCommand,
}

#[derive(Subcommand)]
enum LbCommand {
    /// Light a density grid: iterate the LB update to steady state and write the lighting
    /// grid (.sgrid) and a PNG preview of three central slices.
    Solve(Box<SolveArgs>),
    /// Describe a grid file (.sgrid): kind, size, precision, bounds, metadata, value ranges.
    /// Truncated or corrupted files are refused.
    Info {
        /// The grid file.
        file: PathBuf,
    },
}

/// Where the medium comes from.
#[derive(Args)]
#[group(required = false, multiple = false)]
struct Source {
    /// A built-in shape: sphere, cube or crown (a brown trunk under a leafy crown).
    #[arg(long, value_name = "SHAPE")]
    shape: Option<String>,
    /// A density grid file (.sgrid, as written by `sylva voxelize` or `sylva lb solve`'s
    /// input side).
    #[arg(long, value_name = "FILE")]
    input: Option<PathBuf>,
    /// A headerless raw file of densities in site order (x slowest, z fastest); needs
    /// --raw-dims and --raw-type.
    #[arg(long, value_name = "FILE", requires_all = ["raw_dims"])]
    raw: Option<PathBuf>,
    /// A model, voxelized first (`sylva voxelize`) with --grid sites along its longest edge
    /// (4 to 2048): a built-in species name, an Arbaro species file (.xml), or a mesh (.obj,
    /// .gltf, .glb).
    #[arg(long, value_name = "SPEC")]
    model: Option<String>,
    /// A scene (file or built-in name): one of its models (--scene-model) voxelized with the
    /// scene's [lb] grid and lit with the model's preset (its own or the scene's [lb] one),
    /// unless --grid or --preset say otherwise.
    #[arg(long, value_name = "SCENE")]
    scene: Option<String>,
}

#[derive(Args)]
pub struct SolveArgs {
    #[command(flatten)]
    source: Source,
    /// Grid size: for --shape N (an N³ grid) or NXxNYxNZ, each edge 3 to 2048; for --model
    /// and --scene N, the sites along the model's longest edge, 4 to 2048 (default 128, or the
    /// scene's [lb] grid).
    #[arg(long)]
    grid: Option<String>,
    /// With --scene: the name of the model to light (needed when the scene has several).
    #[arg(long, value_name = "NAME", requires = "scene")]
    scene_model: Option<String>,
    /// Dimensions of a --raw file: NXxNYxNZ.
    #[arg(long, value_name = "NXxNYxNZ")]
    raw_dims: Option<String>,
    /// Element type of a --raw file: u8 (0..255 maps to 0..1) or f32 (little-endian).
    #[arg(long, default_value = "u8", value_parser = ["u8", "f32"])]
    raw_type: String,
    /// Direction towards the sun as x,y,z (+y up).
    #[arg(long, value_name = "X,Y,Z", conflicts_with_all = ["elevation", "azimuth"])]
    sun: Option<String>,
    /// Sun elevation above the horizon in degrees (default 50).
    #[arg(long, allow_negative_numbers = true)]
    elevation: Option<f64>,
    /// Sun azimuth in degrees from +x towards +z (default 30).
    #[arg(long, allow_negative_numbers = true)]
    azimuth: Option<f64>,
    /// Parameter preset: leaf (000 Table 1), dogrose (002 Table 1), cloud, pmma (default
    /// leaf, or with --scene the model's own preset or the scene's [lb] one).
    #[arg(long)]
    preset: Option<String>,
    /// Absorption σ_a: one value for all colours or R,G,B (overrides the preset).
    #[arg(long, value_name = "V|R,G,B")]
    sigma_a: Option<String>,
    /// Scattering σ_s: one value or R,G,B (overrides the preset).
    #[arg(long, value_name = "V|R,G,B")]
    sigma_s: Option<String>,
    /// Henyey-Greenstein g in [-1, 1]: one value or R,G,B (overrides the preset).
    #[arg(long, value_name = "V|R,G,B", allow_hyphen_values = true)]
    g: Option<String>,
    /// Keep f_0 on green sites instead of zeroing it each step (the absorbed light then
    /// re-scatters: a conservative medium).
    #[arg(long)]
    keep_f0: bool,
    /// Do not zero f_0 on brown (wood) sites.
    #[arg(long)]
    brown_keeps_f0: bool,
    /// Wood fraction above which a site is brown (g = -1).
    #[arg(long, default_value_t = 0.5)]
    brown_threshold: f64,
    /// With --model or --scene, what a site's density is: area (collision probability from
    /// leaf and bark area) or subcells (000's sub-cell count); see `sylva voxelize --help`.
    #[arg(long, value_enum, default_value = "area")]
    occupancy: super::voxelize::OccupancyArg,
    /// Steps to run (default: 2 × the longest edge, as in the papers; with --tolerance,
    /// the most steps allowed, default 10 × the longest edge).
    #[arg(long)]
    steps: Option<usize>,
    /// Stop once the relative change of total density per step is below this.
    #[arg(long)]
    tolerance: Option<f64>,
    /// Extrapolate along the solve's slowest mode (CPU only): 1.5 × the longest edge steps
    /// by default, three quarters of the papers' work, ending 4-8× closer to the steady state
    /// than as many plain steps (docs/lb.md, "Extrapolated solves").
    #[arg(long)]
    extrapolate: bool,
    /// Start from the same solve on a grid of half the resolution, interpolated (CPU only;
    /// the renderer's default): 1 × the longest edge steps by default, extrapolated, in about
    /// 0.8 of --extrapolate's time (docs/lb.md, "Coarse-started solves"). Grids shorter than
    /// 64 sites run --extrapolate's schedule instead.
    #[arg(long, conflicts_with = "extrapolate")]
    coarse_start: bool,
    /// Boundary intensity of the sun.
    #[arg(long, default_value_t = 1.0)]
    intensity: f64,
    /// Output lighting grid (default sylva-out/lb-<source>.sgrid).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Preview image (default: the output path with .png).
    #[arg(long)]
    png: Option<PathBuf>,
    /// Store the lighting grid as f16 (half the size).
    #[arg(long)]
    f16: bool,
    /// Where the solver runs: cpu, gpu (the best adapter, a software one such as lavapipe
    /// included) or auto (a hardware GPU if present, else the CPU).
    #[arg(long, value_enum, default_value = "auto")]
    device: super::device::DeviceArg,
    /// GPU state storage: f32, or f16 (half the memory traffic, ~3e-4 relative error).
    #[arg(long, value_enum, default_value = "f32")]
    precision: super::device::PrecisionArg,
}

pub fn run(args: LbArgs) -> Result<()> {
    match args.command {
        LbCommand::Solve(a) => solve(*a),
        LbCommand::Info { file } => info(&file),
    }
}

impl From<&SolveArgs> for MediumOverrides {
    fn from(a: &SolveArgs) -> MediumOverrides {
        MediumOverrides {
            sigma_a: a.sigma_a.clone(),
            sigma_s: a.sigma_s.clone(),
            g: a.g.clone(),
            keep_f0: a.keep_f0,
            brown_keeps_f0: a.brown_keeps_f0,
            brown_threshold: a.brown_threshold,
        }
    }
}

/// Loads the medium and names it for default output paths.
fn load_source(a: &SolveArgs, scene: Option<&SceneDesc>) -> Result<(DensityGrid, String)> {
    if let Some(spec) = &a.source.model {
        let n = parse_grid_flag(a.grid.as_deref().unwrap_or("128"))?;
        let v = super::voxelize::load_and_voxelize(spec, n, true, a.occupancy.into())?;
        println!("voxelized {}: {}", v.name, v.grid.summary());
        return Ok((v.grid, sylva_core::file_stem(&v.name, "model")));
    }
    if let Some(scene) = scene {
        let n = match &a.grid {
            Some(g) => parse_grid_flag(g)?,
            None => scene.lb.grid as usize,
        };
        let model = load_scene_model(scene, a.scene_model.as_deref())?;
        let spec = format!("{}: {}", scene.name, model.name);
        let v = super::voxelize::voxelize_model(&model, &spec, n, true, a.occupancy.into())?;
        println!("voxelized {spec}: {}", v.grid.summary());
        return Ok((
            v.grid,
            sylva_core::file_stem(&format!("{}-{}", scene.name, model.name), "model"),
        ));
    }
    if let Some(path) = &a.source.input {
        let grid = GridFile::read(path)?.into_density(path)?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "input".into());
        return Ok((grid, name));
    }
    if let Some(path) = &a.source.raw {
        let dims = Dims::parse_flag(a.raw_dims.as_deref().unwrap_or_default(), "--raw-dims")?;
        let element = match a.raw_type.as_str() {
            "f32" => RawElement::F32,
            _ => RawElement::U8,
        };
        return Ok((read_raw(path, dims, element)?, "raw".into()));
    }
    let shape = Shape::named(a.source.shape.as_deref().unwrap_or("crown"))?;
    let dims = Dims::parse_flag(a.grid.as_deref().unwrap_or("128"), "--grid")?;
    sylva_lb::solver::check_solve_memory(dims)?;
    Ok((shape.grid(dims), shape.name().into()))
}

fn solve(a: SolveArgs) -> Result<()> {
    // The scene file is read first (cheap): its [lb] preset decides the parameters.
    let scene = a.source.scene.as_deref().map(SceneDesc::load).transpose()?;
    let preset = match (&a.preset, &scene) {
        (Some(p), _) => p.clone(),
        (None, Some(s)) => scene_model_preset(s, a.scene_model.as_deref())?,
        (None, None) => "leaf".to_string(),
    };
    let m = MediumOverrides::from(&a).apply(&preset)?;
    let sun = Sun::from_flags(a.sun.as_deref(), a.elevation, a.azimuth)?;
    if !(a.intensity.is_finite() && a.intensity > 0.0) {
        bail!("--intensity {} must be a positive number", a.intensity);
    }
    // Outputs named on the command line are checked (writable, not a directory) before the
    // grid is built; default names wait for the grid's name.
    OutputSet::check_named(a.output.as_deref(), a.png.as_deref(), "png")?;
    let t0 = Instant::now();
    let (grid, name) = load_source(&a, scene.as_ref())?;
    let dims = grid.dims;
    let load_s = t0.elapsed().as_secs_f64();
    let opts = if a.coarse_start {
        let schedule = SolveOptions::coarse_started(dims);
        SolveOptions {
            max_steps: a.steps.unwrap_or(schedule.max_steps),
            tolerance: a.tolerance,
            ..schedule
        }
    } else if a.extrapolate {
        SolveOptions {
            max_steps: a
                .steps
                .unwrap_or(SolveOptions::extrapolated(dims).max_steps),
            tolerance: a.tolerance,
            extrapolate: true,
            coarse_start: false,
        }
    } else {
        SolveOptions::for_run(a.steps, a.tolerance, dims)
    };
    let output = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("sylva-out/lb-{name}.sgrid")));
    let png = companion_path(&output, a.png.as_deref(), "png");
    // Inputs are protected (--input and --raw here; scene and model files as they are read),
    // and the grid and its preview are checked against each other, before the solve.
    let inputs: Vec<&Path> = [a.source.input.as_deref(), a.source.raw.as_deref()]
        .into_iter()
        .flatten()
        .collect();
    let mut outputs = OutputSet::new(&inputs);
    outputs.plan(&[&output, &png])?;
    println!("{}", lighting_line(&name, &grid, &preset, &sun));
    let d = sun.travel();
    let backend = super::device::open_solver(a.device, a.precision)?;
    let pb = bar(3 * opts.max_steps as u64, "LB solve");
    let mut last_colour = usize::MAX;
    let t1 = Instant::now();
    let (lighting, reports) = backend.solve_lighting(
        &grid,
        &m,
        Boundary::sun([d.x, d.y, d.z], a.intensity),
        &opts,
        &mut |c, s, r| {
            if c != last_colour {
                last_colour = c;
                pb.set_position((c * opts.max_steps) as u64);
            }
            pb.set_position((c * opts.max_steps + s) as u64);
            // A GPU run without a tolerance measures only its last residual (NaN before).
            if s % 8 == 0 && r.is_finite() {
                pb.set_message(format!(
                    "{} residual {r:.2e}",
                    sylva_lb::params::COLOUR_NAMES[c]
                ));
            }
        },
    )?;
    pb.finish_and_clear();
    let solve_s = t1.elapsed().as_secs_f64();
    let solved = SolvedGrid {
        source: &name,
        preset: &preset,
        medium: &m,
        sun: &sun,
        dims,
        reports: &reports,
    };
    print!("{solved}");
    let element = if a.f16 { Element::F16 } else { Element::F32 };
    solved.write(&lighting, element, &mut outputs, &output, &png)?;
    outputs.commit()?;
    println!(
        "total {:.2} s (setup {load_s:.2} s, solve {solve_s:.2} s, {})",
        t0.elapsed().as_secs_f64(),
        backend.describe()
    );
    println!("wrote {} and {}", output.display(), png.display());
    Ok(())
}

fn info(path: &Path) -> Result<()> {
    print!("{}", GridInfo::read(path)?);
    Ok(())
}
