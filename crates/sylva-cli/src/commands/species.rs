//! `sylva species list|show`: the built-in species and Arbaro files.

use super::output::emit;
use super::scene::{outln, outs, thousands};
use anyhow::Context;
use std::path::Path;
use sylva_grow::species::BUILTIN_NAMES;
use sylva_grow::weber_penn::LEAF;
use sylva_grow::{arbaro, Species};

#[derive(clap::Args)]
pub struct SpeciesArgs {
    #[command(subcommand)]
    pub command: SpeciesCommand,
}

#[derive(clap::Subcommand)]
pub enum SpeciesCommand {
    /// The built-in species with their triangle counts.
    List {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// A species' parameters, look and triangle count.
    Show {
        /// A built-in species name or an Arbaro species file (.xml).
        name: String,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Print the parameters as an Arbaro species file.
        #[arg(long, conflicts_with = "json")]
        xml: bool,
    },
}

fn resolve(name: &str) -> anyhow::Result<Species> {
    if let Some(s) = Species::builtin(name) {
        return Ok(s);
    }
    let path = Path::new(name);
    if path.exists() {
        let a = arbaro::load_file(path)?;
        return Ok(Species::from_params(
            &a.name,
            a.params,
            a.seed.unwrap_or(0),
            path.display().to_string(),
        ));
    }
    anyhow::bail!(
        "no built-in species '{name}' and no such Arbaro file (built-in species: {})",
        BUILTIN_NAMES.join(", ")
    )
}

pub fn run(args: SpeciesArgs) -> anyhow::Result<()> {
    match args.command {
        SpeciesCommand::List { json } => list(json),
        SpeciesCommand::Show { name, json, xml } => show(&name, json, xml),
    }
}

fn list(json: bool) -> anyhow::Result<()> {
    let mut o = String::new();
    let mut rows = Vec::new();
    for s in Species::all_builtin() {
        let mesh = s
            .generate_mesh()
            .with_context(|| format!("generating {}", s.name))?;
        rows.push((s, mesh.triangle_count(), mesh.bounds().size()));
    }
    if json {
        let v: Vec<_> = rows
            .iter()
            .map(|(s, tris, size)| {
                serde_json::json!({
                    "name": s.name,
                    "triangles": tris,
                    "reference_triangles": s.reference_triangles,
                    "size_m": size.to_array(),
                    "source": s.source,
                })
            })
            .collect();
        outln!(o, "{}", serde_json::to_string_pretty(&v)?);
        return emit(&o);
    }
    outln!(
        o,
        "{:<18} {:>11} {:>13} {:>8}  source",
        "species",
        "triangles",
        "paper",
        "height"
    );
    for (s, tris, size) in &rows {
        let paper = s
            .reference_triangles
            .map(|r| thousands(r as u64))
            .unwrap_or_else(|| "-".into());
        outln!(
            o,
            "{:<18} {:>11} {:>13} {:>7.1}m  {}",
            s.name,
            thousands(*tris as u64),
            paper,
            size.y,
            s.source
        );
    }
    emit(&o)
}

fn show(name: &str, json: bool, xml: bool) -> anyhow::Result<()> {
    let mut o = String::new();
    let s = resolve(name)?;
    if xml {
        outs!(o, "{}", arbaro::to_xml(&s.name, &s.params));
        return emit(&o);
    }
    let mesh = s
        .generate_mesh()
        .with_context(|| format!("generating {}", s.name))?;
    let leaf = mesh.triangles_with_material(LEAF);
    let b = mesh.bounds();
    if json {
        let params: serde_json::Map<String, serde_json::Value> = s
            .params
            .entries()
            .into_iter()
            .map(|(k, v)| (k, v.into()))
            .collect();
        let v = serde_json::json!({
            "name": s.name,
            "source": s.source,
            "seed": s.seed,
            "triangles": mesh.triangle_count(),
            "leaf_triangles": leaf,
            "wood_triangles": mesh.triangle_count() - leaf,
            "reference_triangles": s.reference_triangles,
            "vertices": mesh.vertex_count(),
            "bounds_min": b.min.to_array(),
            "bounds_max": b.max.to_array(),
            "leaf_outline": s.leaf_outline,
            "leaf_color_srgb": s.leaf_color,
            "leaf_transmission": s.leaf_transmission,
            "bark_pattern": s.bark_pattern,
            "bark_color_srgb": s.bark_color,
            "params": params,
        });
        outln!(o, "{}", serde_json::to_string_pretty(&v)?);
        return emit(&o);
    }
    outln!(o, "species {} ({})", s.name, s.source);
    outln!(
        o,
        "  triangles   {} ({} leaf, {} wood){}",
        thousands(mesh.triangle_count() as u64),
        thousands(leaf as u64),
        thousands((mesh.triangle_count() - leaf) as u64),
        s.reference_triangles
            .map(|r| format!("; paper: {}", thousands(r as u64)))
            .unwrap_or_default()
    );
    let size = b.size();
    outln!(
        o,
        "  size        {:.1} × {:.1} × {:.1} m (x × y × z)",
        size.x,
        size.y,
        size.z
    );
    outln!(
        o,
        "  leaves      {:?}, sRGB {:?}; bark {:?}, sRGB {:?}; seed {}",
        s.leaf_outline,
        s.leaf_color,
        s.bark_pattern,
        s.bark_color,
        s.seed
    );
    outln!(
        o,
        "  leaf T/R    {:.3}, {:.3}, {:.3} (transmittance / reflectance, R, G, B)",
        s.leaf_transmission[0],
        s.leaf_transmission[1],
        s.leaf_transmission[2]
    );
    outln!(o, "  parameters (Arbaro names):");
    for (k, v) in s.params.entries() {
        outln!(o, "    {k:<16} {v}");
    }
    emit(&o)
}
