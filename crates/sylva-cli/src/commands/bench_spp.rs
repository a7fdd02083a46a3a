//! `sylva bench spp SCENE`: the steps of 003's rendering system (Fig. 9) timed on a scene,
//! beside the paper's Table 4: deep opacity maps and instance grids (steps 2-3), the sky
//! (step 4), a new sun (step 5) and a frame with the plane-parallel light (step 6), measured
//! by `sylva_pipeline::bench::spp`.

use anyhow::Result;
use sylva_spp::trees::system::SystemConfig;

#[derive(clap::Args)]
pub struct BenchSppArgs {
    /// Scene file, built-in scene or built-in species (one tree of it).
    #[arg(default_value = "red_maple")]
    scene: String,
    /// Repeat the scene's trees on a K × K lattice (003 Table 4: 16 and 64 instances are
    /// `--repeat 4` and `--repeat 8`).
    #[arg(long, default_value_t = 4)]
    repeat: usize,
    /// Sample directions of the deep opacity maps (003 Table 4: 22).
    #[arg(long, default_value_t = 22)]
    directions: usize,
    /// Points along each edge of an instance's grid.
    #[arg(long, default_value_t = 16)]
    grid: usize,
    /// Frame size (the scene camera's view, moved back to see the whole lattice).
    #[arg(long, default_value_t = 512)]
    width: u32,
    #[arg(long, default_value_t = 512)]
    height: u32,
    /// Timed runs of each step (after one untimed warm-up of the frame); medians reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=50))]
    runs: u32,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(a: BenchSppArgs) -> Result<()> {
    let base = sylva_pipeline::load_scene_or_species(&a.scene)?;
    let scene = sylva_spp::trees::experiment::repeated(&base, a.repeat, None)?;
    let config = SystemConfig {
        directions: a.directions,
        grid: a.grid,
        ..SystemConfig::default()
    };
    let b = sylva_pipeline::bench::spp(scene, config, (a.width, a.height), a.runs)?;
    super::output::print_report(&b, a.json)
}
