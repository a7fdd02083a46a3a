//! `sylva budget`: the canopy radiation budget of an abstract stand (crowns of flat leaves or
//! a homogeneous layer, `sylva-budget`): per band the fractions of the sunlight absorbed by
//! the canopy, reflected to the sky, transmitted to the ground and absorbed by it, and fAPAR.

use super::output::{bench_bar, emit_to};
use anyhow::{Context, Result};
use std::path::PathBuf;
use sylva_budget::{
    budget_json, budget_text, lb_budget, trace_budget, BrfImage, BrfImageSpec, Budget,
    BudgetConfig, CanopySpec, LbConfig, Stand, SunAngles, ViewAngles,
};
use sylva_pipeline::brf_images::BrfImageFiles;
use sylva_pipeline::budget::BudgetSubject;

/// How `sylva budget` finds the fractions.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Monte Carlo photons through the explicit leaves (the reference; standard errors).
    Mc,
    /// The lattice-Boltzmann light over the leaves binned into cells (`--lb-cell`).
    Lb,
    /// Both, and the lattice's differences to the Monte Carlo.
    Both,
}

#[derive(clap::Args)]
pub struct BudgetArgs {
    /// A canopy file (TOML: `[plot]`, `[crowns]` or `[layer]`, `[leaves]`, `[[bands]]`;
    /// docs/budget.md), a built-in stand: `crowns` (spheres of crown LAI 5 at cover 0.3 over
    /// 100 m × 100 m) or `layer` (a homogeneous layer of LAI 3), or a scene (a file, or a
    /// built-in one such as `demo`): its trees over its ground, each material with its own
    /// leaf optics, in its bands or its red, green and blue channels.
    canopy: String,
    /// The sun's zenith angle, degrees from the vertical (0 to below 90). Default: 30 for a
    /// stand, a scene's own sun for a scene.
    #[arg(long, allow_hyphen_values = true)]
    sun_zenith: Option<f64>,
    /// The sun's azimuth, degrees from +x towards +z (as a scene's `[sun]`). Default: 0 for
    /// a stand, a scene's own sun for a scene.
    #[arg(long, allow_hyphen_values = true)]
    sun_azimuth: Option<f64>,
    /// A scene's plot made cyclic: light leaving a side re-enters on the opposite one, so
    /// the scene stands for an endless forest (a canopy file says it in `[plot] cyclic`).
    #[arg(long)]
    cyclic: bool,
    /// A scene's leaf optics (docs/light.md, "Leaf optics"): `measured` (the default) or
    /// `texture`.
    #[arg(long, value_enum)]
    leaf_optics: Option<super::render::LeafOpticsArg>,
    /// Photons per band (the standard error of a fraction falls as 1/√photons).
    #[arg(long, default_value_t = 1_000_000)]
    photons: u64,
    /// Also the BRF (bidirectional reflectance factor) towards these view directions,
    /// ZENITH:AZIMUTH in degrees, comma-separated, e.g. `--brf 0:0,30:0,30:180` (the sun's own
    /// direction is the hot spot). Each adds a ray per scattering event.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    brf: Vec<String>,
    /// Also the BRF as an image: the plot's top seen from this view, ZENITH:AZIMUTH in
    /// degrees, each pixel the BRF of the stretch of the plot it covers (their mean is the
    /// view's BRF). Written to `--brf-image-out` (an EXR of one layer per band) and a grey
    /// PNG per band beside it.
    #[arg(long, allow_hyphen_values = true)]
    brf_image: Option<String>,
    /// Pixels along the plot's longer side of the BRF image (square pixels on the ground).
    /// A pixel's noise falls as 1/√(photons per pixel): raise `--photons` with the size.
    #[arg(long, default_value_t = 128)]
    brf_image_size: u32,
    /// Where the BRF image goes: this EXR, and `STEM_BAND.png` per band beside it.
    #[arg(long, default_value = "brf.exr")]
    brf_image_out: PathBuf,
    /// Seed of the photons (the stand's own seed is in its file). Results depend on the
    /// seeds only, not on the thread count.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// `mc`: Monte Carlo photons (the reference); `lb`: the lattice-Boltzmann light (cyclic
    /// plots only); `both`, with the lattice's differences to the photons.
    #[arg(long, value_enum, default_value_t = Method::Mc)]
    method: Method,
    /// The lattice's cell edge, metres (rounded so that whole cells tile the plot).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    lb_cell: f64,
    /// Direct-beam rays per column side for the lattice (rays² per column).
    #[arg(long, default_value_t = 4)]
    lb_rays: usize,
    /// The lattice stops once the light leaving through its top and onto the soil changes
    /// by at most this share of a step's input from one step to the next.
    #[arg(long, default_value_t = 1e-6)]
    lb_tolerance: f64,
    /// Print JSON instead of a text table.
    #[arg(long)]
    json: bool,
    /// Write the output to this file (atomically) instead of standard output.
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct BenchBudgetArgs {
    /// A canopy file or a built-in stand (`crowns`, `layer`).
    #[arg(default_value = "crowns")]
    canopy: String,
    #[arg(long, default_value_t = 30.0, allow_hyphen_values = true)]
    sun_zenith: f64,
    /// Photons per band.
    #[arg(long, default_value_t = 1_000_000)]
    photons: u64,
    /// Timed runs (each builds the stand and traces every band); medians reported.
    #[arg(long, default_value_t = 3)]
    runs: u32,
    /// `mc`: time the photons; `lb`: the lattice budget; `both`.
    #[arg(long, value_enum, default_value_t = Method::Mc)]
    method: Method,
    /// The lattice's cell edge, metres.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    lb_cell: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub fn bench(a: BenchBudgetArgs) -> Result<()> {
    let spec = CanopySpec::find(&a.canopy, None)?;
    let cfg = BudgetConfig {
        photons: a.photons,
        seed: 1,
        sun: SunAngles {
            zenith_deg: a.sun_zenith,
            azimuth_deg: 0.0,
        },
        views: Vec::new(),
        image: None,
    };
    cfg.validate()?;
    // The photons' progress (the lattice's runs are not counted in photons).
    let bar = bench_bar(
        a.json || a.method == Method::Lb,
        (a.photons * spec.bands.len() as u64 * u64::from(a.runs.clamp(1, 50))) as usize,
        "photons",
    );
    let lattice = LbConfig {
        cell: a.lb_cell,
        ..LbConfig::default()
    };
    let b = sylva_budget::bench::bench_budget(
        &spec,
        &cfg,
        a.method != Method::Lb,
        (a.method != Method::Mc).then_some(&lattice),
        a.runs,
        &|n| bar.inc(n),
    )?;
    bar.finish_and_clear();
    super::output::print_report(&b, a.json)
}

pub fn run(a: BudgetArgs) -> Result<()> {
    // The views first: a bad one is refused before a scene is built.
    let views = a
        .brf
        .iter()
        .map(|v| ViewAngles::parse_view(v))
        .collect::<Result<Vec<_>, _>>()?;
    let image = a
        .brf_image
        .as_deref()
        .map(|v| {
            ViewAngles::parse_view(v).map(|view| BrfImageSpec {
                view,
                side: a.brf_image_size,
            })
        })
        .transpose()?;
    if let Some(image) = &image {
        image.validate()?;
    }
    let subject = BudgetSubject::find(&a.canopy)?;
    let default_sun = subject.default_sun();
    let (spec, scene) = match subject {
        BudgetSubject::Stand(spec) => {
            if a.cyclic {
                anyhow::bail!(
                    "--cyclic is for scenes: {} says it in its [plot] (cyclic = true, the default)",
                    spec.name
                );
            }
            if a.leaf_optics.is_some() {
                anyhow::bail!(
                    "--leaf-optics is for scenes: {}'s leaves take their bands' leaf_reflectance and leaf_transmittance",
                    spec.name
                );
            }
            (Some(spec), None)
        }
        BudgetSubject::Scene(scene) => {
            if a.method != Method::Mc {
                anyhow::bail!(
                    "{}: the lattice budget is for abstract stands (crowns, layers, canopy files); a scene's budget comes from the photons (--method mc, the default)",
                    scene.origin
                );
            }
            (None, Some(scene))
        }
    };
    let sun = SunAngles {
        zenith_deg: a.sun_zenith.unwrap_or(default_sun.zenith_deg),
        azimuth_deg: a.sun_azimuth.unwrap_or(default_sun.azimuth_deg),
    };
    let cfg = BudgetConfig {
        photons: a.photons,
        seed: a.seed,
        sun,
        views,
        image,
    };
    cfg.validate()?;
    if a.method == Method::Lb && (!cfg.views.is_empty() || cfg.image.is_some()) {
        anyhow::bail!(
            "--brf and --brf-image come from the photons: use --method mc or --method both"
        );
    }
    let lb_cfg = LbConfig {
        cell: a.lb_cell,
        rays: a.lb_rays,
        tolerance: a.lb_tolerance,
        ..LbConfig::default()
    };
    if a.method != Method::Mc {
        lb_cfg.validate()?;
    }
    let quiet = a.json || a.out.is_some();
    let t0 = std::time::Instant::now();
    let stand = match (&spec, scene) {
        (Some(spec), _) => Stand::build(spec)?,
        (None, Some(scene)) => {
            Stand::from_scene(*scene, a.leaf_optics.unwrap_or_default().into(), a.cyclic)?
        }
        (None, None) => unreachable!("a stand or a scene"),
    };
    // The image's files are checked before the long work.
    let image_files = match cfg.image {
        Some(_) => {
            let names: Vec<&str> = stand.bands.iter().map(|b| b.name.as_str()).collect();
            Some(BrfImageFiles::plan(&a.brf_image_out, &names)?)
        }
        None => None,
    };
    let accel = sylva_trace::SceneAccel::from_parts(&stand.models, &stand.instances, None)
        .context("building the stand's kd-trees")?;
    let build_seconds = t0.elapsed().as_secs_f64();
    let lattice = if let (Some(spec), true) = (&spec, a.method != Method::Mc) {
        let spinner = if quiet {
            indicatif::ProgressBar::hidden()
        } else {
            indicatif::ProgressBar::new_spinner()
        };
        let run = lb_budget(
            spec,
            &stand,
            &accel,
            cfg.sun,
            &lb_cfg,
            &|band, step, residual| {
                if step % 16 == 0 {
                    spinner.set_message(format!(
                    "lattice, band {band}: step {step}, change {residual:.1e} of a step's input"
                ));
                    spinner.tick();
                }
            },
        )?;
        spinner.finish_and_clear();
        Some(run)
    } else {
        None
    };
    let mut bands = if a.method == Method::Lb {
        Vec::new()
    } else {
        let bar = bench_bar(
            quiet,
            (a.photons * stand.bands.len() as u64) as usize,
            "photons",
        );
        let bands = trace_budget(&stand, &accel, &stand.bands, stand.cyclic, &cfg, &|n| {
            bar.inc(n)
        })?;
        bar.finish_and_clear();
        bands
    };
    let images: Vec<(String, BrfImage)> = bands
        .iter_mut()
        .filter_map(|b| Some((b.band.clone(), b.image.take()?)))
        .collect();
    let written = match image_files {
        Some(files) => Some(files.write(&images.iter().map(|(_, i)| i).collect::<Vec<_>>())?),
        None => None,
    };
    let budget = Budget::new(&stand, cfg.sun, bands, lattice, build_seconds);
    let text = if a.json {
        format!("{}\n", budget_json(&budget))
    } else {
        budget_text(&budget)
    };
    emit_to(&text, a.out)?;
    if let Some(w) = written {
        let (_, first) = &images[0];
        // Standard output carries the JSON or the table; where the images went is a note.
        eprintln!(
            "BRF image towards {}:{} ({}x{} pixels, {:.1} photons a pixel per band): {} (a layer per band)",
            first.view.zenith_deg,
            first.view.azimuth_deg,
            first.width,
            first.height,
            a.photons as f64 / (first.width as f64 * first.height as f64),
            w.exr.display()
        );
        for ((name, img), (png, white)) in images.iter().zip(&w.pngs) {
            eprintln!(
                "  {name}: mean BRF {:.4}, {} (white = BRF {white:.4})",
                img.mean(),
                png.display()
            );
        }
    }
    Ok(())
}
