//! `sylva spp trees SCENE`: 003 Table 3 on a scene's trees: the irradiance of every leaf
//! mesh from a Monte Carlo reference and from SPPG, SPP, single scattering and sylva's LB
//! lighting, compared by eq. 30.

use anyhow::{Context, Result};
use std::path::PathBuf;
use sylva_spp::trees::experiment::{self, ExperimentConfig, LbPlan};
use sylva_spp::trees::opacity_map::MapResolution;
use sylva_spp::trees::system::SystemConfig;

use super::progress::Bars;

#[derive(clap::Args)]
pub struct TreesArgs {
    /// Scene file (.toml), built-in scene name, or built-in species name (one tree of it):
    /// `catalpa`, `red_maple`, `sparse_maple` (003's 18K-triangle tree).
    scene: String,
    /// Repeat the scene's trees on a K × K lattice (003's "multiple trees": `--repeat 3`).
    #[arg(long, default_value_t = 1)]
    repeat: usize,
    /// Lattice spacing in metres for --repeat (default: the trees' wider horizontal extent,
    /// so neighbouring crowns just touch).
    #[arg(long)]
    spacing: Option<f32>,
    /// Leaf albedo R + T (R = T); wood reflects the same (003 Table 3: 0.95).
    #[arg(long, default_value_t = 0.95, allow_hyphen_values = true)]
    albedo: f64,
    /// Light elevation in degrees (90: from straight above, as in 003 §4.2).
    #[arg(long, default_value_t = 90.0, allow_hyphen_values = true)]
    elevation: f64,
    /// Light azimuth in degrees from +x towards +z.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    azimuth: f64,
    /// Monte Carlo photons (default: 10 per leaf mesh of the scene, at least 2 000 000).
    #[arg(long)]
    photons: Option<u64>,
    /// Seed of the Monte Carlo run (the result depends on it only, not on the thread count).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Eq. 29: light rays per mean leaf area.
    #[arg(long, default_value_t = 16.0)]
    rays_per_leaf: f64,
    /// Sample directions of the deep opacity maps (003: 16; Table 4: 22).
    #[arg(long, default_value_t = 16)]
    directions: usize,
    /// Points along each edge of an instance's G-factor grid (003: about 16).
    #[arg(long, default_value_t = 16)]
    grid: usize,
    /// Texels along a sample-direction map's longer side (about two per grid cell).
    #[arg(long, default_value_t = 32)]
    map_texels: usize,
    /// Turn every leaf horizontal where it hangs (the crown's planophile limit,
    /// `trees::synthetic::horizontal_leaves`): separates the leaves' angles from the crown's
    /// shape. A diagnostic, not 003's setup.
    #[arg(long)]
    horizontal_leaves: bool,
    /// Without the LB column (no LB solve).
    #[arg(long)]
    no_lb: bool,
    /// LB grid sites along each model's longest edge (default: the scene's [lb] grid).
    #[arg(long)]
    lb_grid: Option<usize>,
    /// Where the LB solver runs.
    #[arg(long, value_enum, default_value = "auto")]
    device: super::device::DeviceArg,
    /// Also list every depth-thickness category (text output).
    #[arg(long)]
    categories: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Write the output to this file (atomically) instead of standard output.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(a: TreesArgs) -> Result<()> {
    let sun =
        sylva_core::Sun::from_angles(a.elevation, a.azimuth).context("--elevation/--azimuth")?;
    let travel = sun.travel();
    let mut base = sylva_pipeline::load_scene_or_species(&a.scene)?;
    if a.horizontal_leaves {
        for m in &mut base.models {
            *m = sylva_spp::trees::synthetic::horizontal_leaves(m);
        }
        base.name = format!("{}-horizontal-leaves", base.name);
    }
    let scene = experiment::repeated(&base, a.repeat, a.spacing)?;
    let photons = a
        .photons
        .unwrap_or_else(|| sylva_spp::report::default_photons(&scene));
    let solver = if a.no_lb {
        None
    } else {
        Some(super::device::open_solver(
            a.device,
            super::device::PrecisionArg::F32,
        )?)
    };
    let cfg = ExperimentConfig {
        albedo: a.albedo,
        photons,
        seed: a.seed,
        light: [travel.x as f32, travel.y as f32, travel.z as f32],
        rays_per_leaf: a.rays_per_leaf,
        system: SystemConfig {
            directions: a.directions,
            grid: a.grid,
            map: MapResolution {
                texels: a.map_texels,
                ..SystemConfig::default().map
            },
            ..SystemConfig::default()
        },
        lb: solver.as_deref().map(|s| LbPlan {
            solver: s,
            grid: a.lb_grid.unwrap_or(scene.lb.grid as usize),
        }),
    };
    let bars = Bars::new(|_| {});
    let report = experiment::run(&scene, &cfg, &bars)
        .with_context(|| format!("tree experiment on scene '{}'", scene.name))?;
    let text = if a.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        sylva_spp::report::tree_text(&report, a.categories)
    };
    super::output::emit_to(&text, a.out)
}
