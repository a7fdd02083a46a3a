//! `sylva spp trees SCENE`: 003 Table 3 on a scene's trees: the irradiance of every leaf
//! mesh from a Monte Carlo reference and from SPPG, SPP, single scattering and sylva's LB
//! lighting, compared by eq. 30.

use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::PathBuf;
use sylva_spp::trees::experiment::{self, ExperimentConfig, LbPlan, TreeReport};
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
    let mut base = load_scene_or_species(&a.scene)?;
    if a.horizontal_leaves {
        for m in &mut base.models {
            *m = sylva_spp::trees::synthetic::horizontal_leaves(m);
        }
        base.name = format!("{}-horizontal-leaves", base.name);
    }
    let scene = experiment::repeated(&base, a.repeat, a.spacing)?;
    let leaf_meshes_hint: u64 = scene
        .instances
        .iter()
        .map(|i| {
            let m = &scene.models[i.model as usize];
            // Leaf quads are two triangles.
            (m.mesh.material_ids.iter().filter(|&&id| {
                m.materials
                    .get(id as usize)
                    .is_some_and(|mat| mat.is_leaf())
            }))
            .count() as u64
                / 2
        })
        .sum();
    let photons = a.photons.unwrap_or((10 * leaf_meshes_hint).max(2_000_000));
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
        report_text(&report, a.categories)
    };
    super::spp::emit(&text, a.out)
}

/// A scene by file or built-in name, or else one tree of a built-in species.
pub fn load_scene_or_species(name: &str) -> Result<sylva_geom::Scene> {
    match sylva_pipeline::load_scene(name, None) {
        Err(sylva_pipeline::PipelineError::Scene(sylva_scene::SceneError::NotFound(_))) => {
            let text = sylva_scene::builtin_scenes::single_tree(name).with_context(|| {
                format!(
                    "'{name}' is no scene file, built-in scene or built-in species (scenes: {}; species: {})",
                    sylva_scene::builtin_scenes::NAMES.join(", "),
                    sylva_grow::species::BUILTIN_NAMES.join(", ")
                )
            })?;
            let desc = sylva_scene::SceneDesc::parse(&text, &format!("species '{name}'"), None)?;
            Ok(desc.build()?)
        }
        other => Ok(other?),
    }
}

fn pct(x: f64) -> String {
    format!("{:6.1}", 100.0 * x)
}

fn report_text(r: &TreeReport, categories: bool) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "003 Table 3 on scene {}: {} instance(s), {} prototype(s), albedo {}, light travelling ({:.3}, {:.3}, {:.3})",
        r.scene, r.instances, r.prototypes, r.albedo, r.light[0], r.light[1], r.light[2]
    );
    let _ = writeln!(
        s,
        "  leaf meshes {} ({} compared, {} met by no light ray); mean depth {:.2}, thickness {:.2} surfaces, |n·s0| {:.2}; {} light rays {:.3} apart; {} directions, {} grid cells",
        r.leaf_meshes, r.compared_meshes, r.unmet_meshes, r.mean_depth, r.mean_thickness, r.mean_cos_light, r.depth_rays, r.ray_spacing, r.sample_directions, r.grid_cells
    );
    let b = &r.balance;
    let _ = writeln!(
        s,
        "  Monte Carlo: {} photons (seed {}); escaped {:.4}, absorbed by leaves {:.4}, by wood {:.4}, unfinished {:.1e}; {:.2} leaf and {:.2} wood interactions per photon",
        b.photons, r.seed, b.escaped, b.absorbed_leaves, b.absorbed_wood, b.unfinished, b.leaf_hits_per_photon, b.wood_hits_per_photon
    );
    let e = &r.errors;
    let _ = writeln!(s, "eq. 30 RMS error against the Monte Carlo, percent:");
    let _ = writeln!(s, "             SPPG     SPP      SS      LB");
    let _ = writeln!(
        s,
        "  sylva     {}  {}  {}  {}",
        pct(e.sppg),
        pct(e.spp),
        pct(e.ss),
        e.lb.map_or("     -".into(), pct)
    );
    if let Some(p) = &r.paper {
        let _ = writeln!(
            s,
            "  paper     {}  {}  {}       -   ({})",
            pct(p.sppg),
            pct(p.spp),
            pct(p.ss),
            p.configuration
        );
    }
    let _ = writeln!(
        s,
        "  (Monte Carlo noise in these numbers: about {:.1} %; {} depth-thickness bins of >= {} meshes, {} meshes)",
        100.0 * e.mc_noise, r.categories_used, experiment::MIN_CATEGORY_MESHES, r.meshes_in_categories
    );
    let _ = writeln!(
        s,
        "  SPPG / SPP with eq. 19's totals read as radiance integrals (half the diffuse light): {} / {}",
        pct(e.sppg_radiance_reading),
        pct(e.spp_radiance_reading)
    );
    let m = &r.means;
    let _ = writeln!(
        s,
        "mean two-sided irradiance per unit beam irradiance (area-weighted): MC {:.4} (direct {:.4}), SPPG {:.4}, SPP {:.4}, SS {:.4}{}; mean G {:.3}",
        m.mc,
        m.mc_direct,
        m.sppg,
        m.spp,
        m.ss,
        m.lb.map_or(String::new(), |v| format!(", LB {v:.4}")),
        m.g
    );
    let t = &r.timings;
    let _ = writeln!(
        s,
        "seconds: kd-trees {:.2}, meshes {:.2}, eq. 29 counts {:.2}, maps {:.2} + grids {:.2} + light maps {:.2} + G {:.2} + sky {:.3}, photons {:.2}, LB {:.2}; total {:.2}",
        t.accel, t.meshes, t.depth_counts, t.system.sample_maps, t.system.grid_depths, t.system.light_maps, t.system.light_grid, t.system.sky, t.photons, t.lb, t.total
    );
    if categories {
        let _ = writeln!(
            s,
            "   d    w  meshes        MC    direct      SPPG       SPP        SS        LB      G"
        );
        for c in &r.categories {
            let _ = writeln!(
                s,
                "{:4} {:4} {:7} {:9.4} {:9.4} {:9.4} {:9.4} {:9.4} {:>9} {:6.3}",
                c.depth,
                c.thickness,
                c.meshes,
                c.mc,
                c.mc_direct,
                c.sppg,
                c.spp,
                c.ss,
                c.lb.map_or("-".into(), |v| format!("{v:.4}")),
                c.g
            );
        }
    }
    s
}
