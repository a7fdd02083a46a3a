//! `sylva scene info|list`: what a scene holds.

use super::output::{emit, emit_report};
use anyhow::Context;
use sylva_scene::builtin_scenes;
use sylva_scene::{SceneDesc, SceneInfo};

#[derive(clap::Args)]
pub struct SceneArgs {
    #[command(subcommand)]
    pub command: SceneCommand,
}

#[derive(clap::Subcommand)]
pub enum SceneCommand {
    /// Species, instances, unique and instanced triangle counts, bounds and memory of a scene.
    Info {
        /// A scene file (TOML) or a built-in scene: demo, beech, catalpa, canopy.
        #[arg(default_value = "demo")]
        scene: String,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// The built-in scenes.
    List,
    /// Print a built-in scene's TOML (a starting point for your own).
    Source {
        /// A built-in scene name.
        name: String,
    },
}

pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    match args.command {
        SceneCommand::List => {
            let mut o = String::new();
            for name in builtin_scenes::NAMES {
                let about = builtin_scenes::describe(name).unwrap_or_default();
                o.push_str(&format!("{name:<8} {about}\n"));
            }
            emit(&o)
        }
        SceneCommand::Source { name } => {
            let text = builtin_scenes::source(&name).with_context(|| {
                format!(
                    "no built-in scene '{name}' (built-in scenes: {})",
                    builtin_scenes::NAMES.join(", ")
                )
            })?;
            emit(text)
        }
        SceneCommand::Info { scene, json } => info(&scene, json),
    }
}

fn info(name: &str, json: bool) -> anyhow::Result<()> {
    let scene = SceneDesc::load(name)?.build()?;
    let info = SceneInfo::of(&scene);
    emit_report(&info, json)
}
