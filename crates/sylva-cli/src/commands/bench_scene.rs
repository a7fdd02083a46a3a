//! `sylva bench scene`: times generating each built-in species and building a scene.

use super::output::emit_report;

#[derive(clap::Args)]
pub struct BenchSceneArgs {
    /// Scene to build (a file or a built-in scene).
    #[arg(default_value = "beech")]
    pub scene: String,
    /// Runs per measurement; the median is reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: BenchSceneArgs) -> anyhow::Result<()> {
    let b = sylva_scene::bench::scene_build(&args.scene, args.runs)?;
    emit_report(&b, args.json)
}
