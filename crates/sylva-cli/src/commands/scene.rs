//! `sylva scene info|list`: what a scene holds.

use super::output::emit;
use anyhow::Context;
use sylva_scene::builtin_scenes;
use sylva_scene::{SceneDesc, SceneStats};

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

/// Appends a formatted line to a `String`.
macro_rules! outln {
    ($o:expr) => {
        $o.push('\n')
    };
    ($o:expr, $($t:tt)*) => {{
        $o.push_str(&format!($($t)*));
        $o.push('\n');
    }};
}
pub(crate) use outln;

/// Appends formatted text to a `String`.
macro_rules! outs {
    ($o:expr, $($t:tt)*) => {
        $o.push_str(&format!($($t)*))
    };
}
pub(crate) use outs;

/// `1234567` → `"1,234,567"`.
pub fn thousands(n: u64) -> String {
    let s = n.to_string();
    let head = match s.len() % 3 {
        0 => 3.min(s.len()),
        h => h,
    };
    let mut out = s[..head].to_string();
    for group in s.as_bytes()[head..].chunks(3) {
        out.push(',');
        out.push_str(std::str::from_utf8(group).expect("ASCII digits"));
    }
    out
}

pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    match args.command {
        SceneCommand::List => {
            let mut o = String::new();
            for name in builtin_scenes::NAMES {
                outln!(
                    o,
                    "{name:<8} {}",
                    builtin_scenes::describe(name).unwrap_or_default()
                );
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
            let mut o = String::new();
            outs!(o, "{text}");
            emit(&o)
        }
        SceneCommand::Info { scene, json } => info(&scene, json),
    }
}

fn info(name: &str, json: bool) -> anyhow::Result<()> {
    let mut o = String::new();
    let desc = SceneDesc::load(name)?;
    let scene = desc.build()?;
    let stats = SceneStats::of(&scene);
    if json {
        let mut v = serde_json::to_value(&stats)?;
        let obj = v.as_object_mut().expect("stats serialise to an object");
        obj.insert("origin".into(), scene.origin.clone().into());
        obj.insert(
            "sun".into(),
            serde_json::json!({
                "elevation_deg": scene.sun.elevation_deg(),
                "azimuth_deg": scene.sun.azimuth_deg(),
                "direction": scene.sun.to_sun().to_array(),
            }),
        );
        let c = &scene.camera;
        obj.insert(
            "camera".into(),
            serde_json::json!({
                "position": c.position.to_array(),
                "look_at": c.look_at.to_array(),
                "fov_deg": c.fov_deg,
                "resolution": [c.width, c.height],
                "rays_per_pixel": c.rays_per_pixel,
            }),
        );
        obj.insert(
            "lb".into(),
            serde_json::json!({"grid": scene.lb.grid, "preset": scene.lb.preset}),
        );
        let g = &scene.ground;
        obj.insert(
            "ground".into(),
            serde_json::json!({"enabled": g.enabled, "size": g.size, "color": g.color}),
        );
        obj.insert("sky_color".into(), serde_json::to_value(scene.sky_color)?);
        outln!(o, "{}", serde_json::to_string_pretty(&v)?);
        return emit(&o);
    }
    outln!(o, "scene {} ({})", stats.name, scene.origin);
    outln!(
        o,
        "  instances            {}",
        thousands(stats.instances as u64)
    );
    outln!(
        o,
        "  unique triangles     {} in {} models",
        thousands(stats.unique_triangles as u64),
        stats.models.len()
    );
    outln!(
        o,
        "  instanced triangles  {}",
        thousands(stats.instanced_triangles)
    );
    let [a, b, c] = stats.bounds_min;
    let [d, e, f] = stats.bounds_max;
    outln!(
        o,
        "  bounds               ({a:.1}, {b:.1}, {c:.1}) .. ({d:.1}, {e:.1}, {f:.1}) m"
    );
    outln!(
        o,
        "  memory               {} (models and textures, instance records, media)",
        sylva_core::format_bytes(stats.memory_bytes)
    );
    outln!(
        o,
        "  sun                  elevation {:.1}°, azimuth {:.1}°",
        scene.sun.elevation_deg(),
        scene.sun.azimuth_deg()
    );
    let cam = &scene.camera;
    outln!(
        o,
        "  camera               {}×{}, {} ray(s)/pixel, fov {}°, at {:?} looking at {:?}",
        cam.width,
        cam.height,
        cam.rays_per_pixel,
        cam.fov_deg,
        cam.position.to_array(),
        cam.look_at.to_array()
    );
    outln!(
        o,
        "  lb                   grid {}, preset {}",
        scene.lb.grid,
        scene.lb.preset
    );
    if !stats.models.is_empty() {
        outln!(o);
        outln!(
            o,
            "  {:<18} {:<18} {:>9} {:>11} {:>11} {:>11}  {}",
            "model",
            "species",
            "instances",
            "triangles",
            "leaf",
            "wood",
            "preset"
        );
    }
    for m in &stats.models {
        outln!(
            o,
            "  {:<18} {:<18} {:>9} {:>11} {:>11} {:>11}  {}",
            m.name,
            m.species,
            m.instances,
            thousands(m.triangles as u64),
            thousands(m.leaf_triangles as u64),
            thousands(m.wood_triangles as u64),
            m.preset
        );
    }
    if !stats.media.is_empty() {
        outln!(o);
        outln!(
            o,
            "  {:<18} {:<8} {:<13} {:>8} {:>11} {:>6}  box (m)",
            "medium",
            "preset",
            "grid",
            "cell (m)",
            "occupied",
            "mean ρ"
        );
    }
    for m in &stats.media {
        let [a, b, c] = m.bounds_min;
        let [d, e, f] = m.bounds_max;
        outln!(
            o,
            "  {:<18} {:<8} {:<13} {:>8.2} {:>11} {:>6.3}  ({a:.0}, {b:.0}, {c:.0}) .. ({d:.0}, {e:.0}, {f:.0})",
            m.name,
            m.preset,
            format!("{}×{}×{}", m.grid[0], m.grid[1], m.grid[2]),
            m.cell,
            thousands(m.occupied as u64),
            m.mean_density
        );
    }
    emit(&o)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_thousands() {
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(1000), "1,000");
        assert_eq!(thousands(273_376_528), "273,376,528");
    }
}
