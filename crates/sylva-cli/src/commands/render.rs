//! `sylva render [SCENE]`: the render pipeline of `sylva_render` (scene, LB lighting per
//! model, kd-trees, frame, tone mapping, PNG and EXR) with progress bars and a per-stage
//! summary.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use sylva_core::Sun;
use sylva_lb::relight::{Codec, CompressTarget, Precision};
use sylva_lb::LbSolver;
use sylva_light::lighting::{Light, LightingSource};
use sylva_light::relight::{BasisReport, GlobalGridOptions, PhysicalTarget, SunWeights};
use sylva_light::{IndirectLight, Progress, Silent};
use sylva_pipeline::{
    image_paths, load_scene, resolution, tone_map_modes, write_images, BasisUse, LbPlan,
    PrepareOptions, PreparedScene, RelightPlan, Runner, ShadowMethod,
};
use sylva_render::{stage, Mode, ShadingParams, ToneMap};
use sylva_spp::trees::system::{SppLight, SppSystem, SystemConfig};
use sylva_trace::TraversalConfig;

use super::progress::{Bars, Report};
use super::sun_time::SunTimeArgs;

/// Whether the LB light of plants comes from base solutions (paper 004): the physical light's
/// (13 sun parts and 3 diffuse parts per model) or, with --light paper, 004's (docs/relight.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BasisArg {
    /// Under --light paper, base solutions when every model's are cached (`sylva basis`),
    /// else solved for the sun; other lights solve for the sun.
    Auto,
    /// Base solutions, solved and cached where missing (paper 004: any sun, rotated
    /// instances lit correctly, the forest or global grid relit); not the SPP light.
    Always,
    /// Solved for the scene's sun per model (paper 000), cached per sun.
    Never,
}

/// How the sun becomes base-solution weights.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SunWeightsArg {
    /// The polyhedron face's three bases, barycentric weights (004 §3.1).
    Three,
    /// max(0, n_i · d) over all bases: a direct solve's light, up to rounding.
    Exact,
}

/// What finds the occluders of shadow rays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ShadowsArg {
    /// The top-level kd-tree over the instances.
    Kd,
    /// The sun-aligned tile grid of 004 §4.1.
    Grid,
}

/// How cached base solutions are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BasisPrecisionArg {
    F16,
    F32,
    /// 16 bits per kept coefficient, index included (Haar codecs).
    Packed,
}

/// The help of every command's SCENE argument.
pub const SCENE_HELP: &str = "Scene file (.toml) or built-in scene name (demo, beech, catalpa, \
     canopy, shade, cloud, teapot, demo_cloud; `sylva scene list`).";

/// The help of `--light` for the commands that relight (`basis`, `relight`).
const RELIGHT_LIGHT_HELP: &str = "Light model: physical (the default: per model 13 sun parts \
     and 3 diffuse parts, moved with the sun) or paper (004's 19 boundary bases, compressed); \
     spp has no base solutions (docs/relight.md).";

/// How the frame is traced and shaded, whatever the light: `render`, `relight`, the benches.
#[derive(Args, Debug, Clone)]
pub struct ViewArgs {
    /// Image width in pixels (default: the scene camera's; with only --width or --height the
    /// other follows the scene's aspect ratio).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Short-stack entries of the kd-tree traversal (000 Fig. 1 uses 5).
    #[arg(long, default_value_t = sylva_trace::DEFAULT_STACK_SIZE)]
    pub stack: usize,
    /// Scale of the indirect light: the LB light and the traced sky (1: as computed).
    #[arg(long, default_value_t = ShadingParams::default().indirect)]
    pub indirect: f32,
    /// Paper light: sky light on the ground as a fraction of the sun's.
    #[arg(long, default_value_t = ShadingParams::default().sky_ambient)]
    pub sky_ambient: f32,
    /// Seed of the sub-pixel jitter (rays per pixel other than 1 and 4).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// On a GPU, trace the rays there but shade on the CPU (default: the whole frame in one
    /// GPU kernel).
    #[arg(long)]
    pub cpu_shading: bool,
    /// Shadow rays through the sun-aligned grid (004 §4.1) or the top-level kd-tree.
    #[arg(long, value_enum, default_value = "grid")]
    pub shadows: ShadowsArg,
}

/// Where the sun is (`render` and the benches; `relight` moves it along its path).
#[derive(Args, Debug, Clone, Default)]
pub struct SunArgs {
    /// Sun direction (vector towards the sun, x,y,z with y up); default: the scene's sun.
    #[arg(long, conflicts_with_all = ["elevation", "azimuth"])]
    pub sun: Option<String>,
    /// Sun elevation above the horizon in degrees, 0 to 90 (default 50 when only --azimuth
    /// is given).
    #[arg(long, allow_negative_numbers = true)]
    pub elevation: Option<f64>,
    /// Sun azimuth in degrees from +x towards +z (default 30 when only --elevation is given).
    #[arg(long, allow_negative_numbers = true)]
    pub azimuth: Option<f64>,
}

/// The light's options that only `render` (and the benches) use: the other lights' final
/// gather and the choice of base solutions.
#[derive(Args, Debug, Clone)]
pub struct RenderLightArgs {
    /// Light model: physical (one material model for renderer, LB and export: exact direct
    /// sun plus the LB's scattered, sky and ground light; docs/light.md), paper (000: the
    /// preset's LB total light, specular highlights; its images used --indirect 0.5) or spp
    /// (the paper's shading with the plane-parallel light and G-factor of 003 §5 instead of
    /// LB grids: deep opacity maps in 16 directions, 16³ instance grids, leaf albedo from the
    /// scene's [lb] preset; the `lb` mode shows the SPP light alone).
    /// [default: physical; paper for the commands that relight: basis, relight, bench relight]
    #[arg(long, value_parser = ["physical", "paper", "spp"])]
    pub light: Option<String>,
    /// Physical light: final-gather rays per camera sample on a plant, 0 to 256: the light
    /// arriving at a leaf is traced one bounce (sky, ground, other leaves lit by the sun and
    /// their LB light); 0 takes the LB light at the leaf itself, several times faster and less
    /// exact (docs/light.md, "The final gather").
    #[arg(
        long,
        default_value_t = ShadingParams::default().gather_rays,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u32).range(0..=i64::from(sylva_render::gather::MAX_GATHER_RAYS))
    )]
    pub gather_rays: u32,
    /// LB light from base solutions (always: the physical light's 16 parts per model or,
    /// with --light paper, 004's bases), solved for the sun (never), or (auto) solved for the
    /// sun under the physical light, the paper light's bases when all are cached.
    #[arg(long, value_enum, default_value = "auto")]
    pub basis: BasisArg,
}

impl Default for RenderLightArgs {
    /// What `basis` and `relight` render with: their light is set by [`relight_light`].
    fn default() -> Self {
        RenderLightArgs {
            light: None,
            gather_rays: ShadingParams::default().gather_rays,
            basis: BasisArg::Auto,
        }
    }
}

/// `--light` of the commands that relight: the physical light (the default) or the paper
/// light; the SPP light, which has no base solutions, is refused with the reason.
#[derive(Args, Debug, Clone, Default)]
pub struct RelightLightArg {
    #[arg(long, value_parser = ["physical", "paper", "spp"], help = RELIGHT_LIGHT_HELP)]
    pub light: Option<String>,
}

/// The LB solves: grid, cache and solver.
#[derive(Args, Debug, Clone)]
pub struct LbArgs {
    /// LB grid sites along each model's longest edge, 4 to 2048 (default: the scene's [lb]
    /// grid).
    #[arg(long)]
    pub lb_grid: Option<usize>,
    /// Directory of the LB lighting cache.
    #[arg(long, default_value = "sylva-out/cache")]
    pub cache_dir: PathBuf,
    /// Compute LB lighting without reading or writing the cache.
    #[arg(long)]
    pub no_cache: bool,
    /// Where the LB lighting is solved and the rays are traced: cpu, gpu (the best adapter,
    /// a software one such as lavapipe included) or auto (a hardware GPU if present, else the
    /// CPU). LB cache entries are kept per device.
    #[arg(long, value_enum, default_value = "auto")]
    pub device: super::device::DeviceArg,
    /// GPU state storage of the LB solve: f32, or f16 (half the memory traffic).
    #[arg(long, value_enum, default_value = "f32")]
    pub precision: super::device::PrecisionArg,
}

/// How relit light is combined for a sun (frames from base solutions).
#[derive(Args, Debug, Clone)]
pub struct RelitArgs {
    /// How base solutions combine for the sun: three (004's polyhedron face) or exact.
    #[arg(long, value_enum, default_value = "three")]
    pub sun_weights: SunWeightsArg,
    /// Ambient light from the ambient base solution, as a fraction of unobstructed sunlight.
    #[arg(long, default_value_t = 0.0)]
    pub ambient: f64,
}

impl Default for RelitArgs {
    /// What `sylva basis` plans with: it combines nothing (the defaults of the flags).
    fn default() -> Self {
        RelitArgs {
            sun_weights: SunWeightsArg::Three,
            ambient: 0.0,
        }
    }
}

/// The coarse grid over a forest, and how base solutions are stored.
#[derive(Args, Debug, Clone)]
pub struct GridArgs {
    /// Without the coarse global grid (instances do not shade each other's indirect light):
    /// the paper light's relighting grid and the physical light's forest grid.
    #[arg(long)]
    pub no_global: bool,
    /// Sites of the coarse global grid (relighting) or forest grid (physical light) along the
    /// forest's longest edge, 16 to 512.
    #[arg(
        long,
        default_value_t = GlobalGridOptions::default().sites,
        value_parser = parse_global_grid,
        conflicts_with = "no_global"
    )]
    pub global_grid: usize,
    /// Compression of cached base solutions: colour:T (per-basis colour decorrelation +
    /// Haar), haar:T, pca:K or pcahaar:K:T. The physical light: one codec for its 13 sun
    /// parts and 3 diffuse parts, or two separated by a comma (sun parts, then diffuse
    /// parts, e.g. pcahaar:12:0.002,colour:0.004), or none (kept as solved).
    #[arg(long, default_value = "colour:0.004")]
    pub codec: String,
    /// Stored values of compressed base solutions.
    #[arg(long, value_enum, default_value = "packed")]
    pub basis_precision: BasisPrecisionArg,
}

/// `--global-grid N`: sites of a coarse grid, in the range the library accepts.
fn parse_global_grid(s: &str) -> Result<usize, String> {
    let sites: usize = s
        .parse()
        .map_err(|_| format!("'{s}' is not a number of sites"))?;
    GlobalGridOptions { sites }.validate()?;
    Ok(sites)
}

/// Options of `sylva render` and the benches: what the frame looks like.
#[derive(Args, Debug, Clone)]
pub struct FrameArgs {
    #[arg(default_value = "demo", help = SCENE_HELP)]
    pub scene: String,
    #[command(flatten)]
    pub view: ViewArgs,
    #[command(flatten)]
    pub sun: SunArgs,
    #[command(flatten)]
    pub light: RenderLightArgs,
    #[command(flatten)]
    pub lb: LbArgs,
    #[command(flatten)]
    pub relit: RelitArgs,
    #[command(flatten)]
    pub grid: GridArgs,
}

/// The light model's name for a command that relights from base solutions: the physical
/// light by default, or the paper light; the SPP light has none (an error, not another
/// light's bases shaded as it).
pub fn relight_light(light: Option<&str>) -> Result<&'static str> {
    match light {
        None | Some("physical") => Ok("physical"),
        Some("paper") => Ok("paper"),
        Some(l) => bail!(
            "--light {l}: this command relights from base solutions, and the {l} light has \
             none (docs/relight.md): use the physical light (the default) or --light paper"
        ),
    }
}

/// The relighting plan of these options under light `light` (`None`: per-sun LB light).
/// `basis`: `--basis`; `force`: base solutions whatever it says (`auto` then solves missing
/// ones); `keep_raw`: keep the uncompressed bases too. The physical and the paper light have
/// base solutions (`--basis always` with the SPP light is an error); `auto` on the physical
/// light solves for the sun (exact at that sun: docs/relight.md).
pub fn relight_plan(
    basis: BasisArg,
    relit: &RelitArgs,
    grid: &GridArgs,
    force: bool,
    keep_raw: bool,
    light: &str,
) -> Result<Option<RelightPlan>> {
    let paper = light == "paper";
    let basis = match (basis, force) {
        (BasisArg::Never, true) => {
            bail!("--basis never: this command relights from base solutions")
        }
        (BasisArg::Never, false) => return Ok(None),
        (BasisArg::Always, false) if light == "spp" => bail!(
            "--basis always: the SPP light has no base solutions (docs/relight.md); use the \
             physical light (the default) or --light paper"
        ),
        (BasisArg::Auto, false) if !paper => return Ok(None),
        (BasisArg::Auto, false) => BasisUse::IfCached,
        _ => BasisUse::Always,
    };
    if !(relit.ambient.is_finite() && relit.ambient >= 0.0) {
        bail!("--ambient {}: must be a finite number ≥ 0", relit.ambient);
    }
    let global = (!grid.no_global).then_some(GlobalGridOptions {
        sites: grid.global_grid,
    });
    if let Some(g) = &global {
        g.validate()
            .map_err(|e| anyhow::anyhow!("--global-grid: {e}"))?;
    }
    let precision = match grid.basis_precision {
        BasisPrecisionArg::F16 => Precision::F16,
        BasisPrecisionArg::F32 => Precision::F32,
        BasisPrecisionArg::Packed => Precision::Packed,
    };
    // The paper light's bases are one set; the physical light's two (sun parts, diffuse
    // parts), or none.
    let (target, physical) = if paper {
        let codec = Codec::parse(&grid.codec).map_err(|e| {
            anyhow::anyhow!("--codec: {e} (the paper light's bases take one codec, not none)")
        })?;
        let target = CompressTarget {
            precision,
            ..CompressTarget::new(codec)
        };
        target
            .validate()
            .map_err(|e| anyhow::anyhow!("--codec/--basis-precision: {e}"))?;
        (target, None)
    } else {
        let physical = PhysicalTarget::parse(&grid.codec, precision)
            .map_err(|e| anyhow::anyhow!("--codec/--basis-precision: {e}"))?;
        (CompressTarget::recommended(), physical)
    };
    Ok(Some(RelightPlan {
        basis,
        sun: match relit.sun_weights {
            SunWeightsArg::Three => SunWeights::ThreeBasis,
            SunWeightsArg::Exact => SunWeights::Exact,
        },
        ambient: relit.ambient,
        global,
        target,
        physical,
        keep_raw,
    }))
}

/// A warning line before a coarse grid (`plan`'s relighting grid, or the physical light's
/// forest grid `forest`) whose solves cost far more than the default's, if `scene` will solve
/// one; `None` otherwise.
pub fn costly_grid_warning(
    scene: &sylva_geom::Scene,
    plan: Option<&RelightPlan>,
    forest: Option<&GlobalGridOptions>,
    light: Light,
) -> Result<Option<String>> {
    let physical_bases = plan.is_some() && light == Light::Physical;
    let (grid, solves) = match (plan.and_then(|p| p.global.as_ref()), forest) {
        // The physical light's forest grid parts: 13 sun directions, a sky and a ground.
        (_, Some(g)) if physical_bases && sylva_pipeline::uses_forest(scene, light, Some(g)) => {
            (g, 3 * (sylva_light::relight::physical::SUN_PARTS + 2))
        }
        (_, None) if physical_bases => return Ok(None),
        (Some(g), _) => (g, sylva_lb::relight::BASES - 1),
        (None, Some(g)) if sylva_pipeline::uses_forest(scene, light, Some(g)) => (g, 3),
        _ => return Ok(None),
    };
    let b = scene.instance_bounds();
    if b.is_empty() {
        return Ok(None);
    }
    grid.cost_warning(b.max - b.min, solves)
        .map_err(|e| anyhow::anyhow!("--global-grid: {e}"))
        .map(|w| w.map(|w| format!("warning: {w}, where it is not cached")))
}

impl FrameArgs {
    /// The light model's name: `--light`, by default physical ([`relight_light`] for a
    /// command that relights).
    pub fn light_for(&self, relights: bool) -> Result<&str> {
        match (self.light.light.as_deref(), relights) {
            (l, true) => relight_light(l),
            (l, false) => Ok(l.unwrap_or("physical")),
        }
    }

    /// [`relight_plan`] of these options.
    pub fn relight_plan(
        &self,
        force: bool,
        keep_raw: bool,
        light: &str,
    ) -> Result<Option<RelightPlan>> {
        relight_plan(
            self.light.basis,
            &self.relit,
            &self.grid,
            force,
            keep_raw,
            light,
        )
    }

    /// The physical light's coarse forest grid (`--global-grid`, off with `--no-global`);
    /// `None` for other lights.
    pub fn forest_grid(&self, light: Light) -> Result<Option<GlobalGridOptions>> {
        if self.grid.no_global || light != Light::Physical {
            return Ok(None);
        }
        let g = GlobalGridOptions {
            sites: self.grid.global_grid,
        };
        g.validate()
            .map_err(|e| anyhow::anyhow!("--global-grid: {e}"))?;
        Ok(Some(g))
    }

    pub fn shadow_method(&self) -> ShadowMethod {
        match self.view.shadows {
            ShadowsArg::Kd => ShadowMethod::KdTree,
            ShadowsArg::Grid => ShadowMethod::SunGrid,
        }
    }
}

/// One line about an LB report, and whether it is a warning (to stderr).
pub fn report_line(r: Report) -> (String, Option<String>) {
    // A bad entry recomputed, and an entry that could not be written (a read-only cache:
    // the result is good, only not kept).
    let warn = |s: &LightingSource, cache_warning: &Option<String>| {
        let lines: Vec<String> = [
            match s {
                LightingSource::Recomputed { reason } => {
                    Some(format!("warning: {reason}; recomputed"))
                }
                _ => None,
            },
            cache_warning.as_ref().map(|w| format!("warning: {w}")),
        ]
        .into_iter()
        .flatten()
        .collect();
        (!lines.is_empty()).then(|| lines.join("\n"))
    };
    match r {
        Report::Lit(name, report) => {
            let line = match &report.source {
                LightingSource::Cached => format!(
                    "  LB {}: {} grid from cache ({:.2} s)",
                    name, report.dims, report.seconds
                ),
                LightingSource::Computed => format!(
                    "  LB {}: {} grid solved in {:.1} s{}",
                    name,
                    report.dims,
                    report.seconds,
                    report
                        .path
                        .as_ref()
                        .filter(|_| report.cache_warning.is_none())
                        .map(|p| format!(", cached as {}", p.display()))
                        .unwrap_or_default()
                ),
                LightingSource::Recomputed { .. } => format!(
                    "  LB {}: {} grid solved again in {:.1} s",
                    name, report.dims, report.seconds
                ),
            };
            (line, warn(&report.source, &report.cache_warning))
        }
        Report::Basis(model, report) => {
            let how = match &report.source {
                LightingSource::Cached => format!("from cache ({:.2} s)", report.seconds),
                LightingSource::Computed => format!("solved in {:.1} s", report.seconds),
                LightingSource::Recomputed { .. } => {
                    format!("solved again in {:.1} s", report.seconds)
                }
            };
            let line = format!(
                "  basis {}: {} grid {how}{}; {} → {} ({:.1}×){}",
                model.name,
                report.dims,
                report
                    .solve_seconds
                    .map(|s| format!(", 54 solves {s:.1} s"))
                    .unwrap_or_default(),
                sylva_core::format_bytes(report.raw_bytes),
                sylva_core::format_bytes(report.compressed_bytes),
                report.raw_bytes as f64 / report.compressed_bytes.max(1) as f64,
                match (&report.source, &report.path, &report.cache_warning) {
                    (LightingSource::Cached, _, _) | (_, None, _) | (_, _, Some(_)) => {
                        String::new()
                    }
                    (_, Some(p), None) => format!(", cached as {}", p.display()),
                }
            );
            (line, warn(&report.source, &report.cache_warning))
        }
        Report::Global(report) => {
            let how = match &report.source {
                LightingSource::Cached => "from cache",
                LightingSource::Computed => "solved",
                LightingSource::Recomputed { .. } => "solved again",
            };
            (
                format!(
                    "  global grid: {} {how} in {:.2} s",
                    report.dims, report.seconds
                ),
                warn(&report.source, &report.cache_warning),
            )
        }
        Report::Shade(name, own, added) => (
            format!(
                "  {name}: neighbours' foliage inside its boxes adds {:.0} % to its optical depth",
                100.0 * added / own.max(1e-12)
            ),
            None,
        ),
    }
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// The sun of a date, time and place (--lat, --lon, --date, --time, --utc-offset).
    #[command(flatten)]
    pub sun_time: SunTimeArgs,
    /// Output PNG (8-bit sRGB, tone mapped). Default: sylva-out/<scene>.png; with one mode the
    /// name as given, with several (--mode all) every mode adds -<mode>, full included.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Also write the linear HDR image as OpenEXR beside the PNG (same name, .exr).
    #[arg(long)]
    pub hdr: bool,
    /// Rays per pixel (1, 4, or any n; averaged). Default: the scene camera's.
    #[arg(long)]
    pub rpp: Option<u32>,
    /// full: sun + LB light; local: sun only; ambient: sun + a constant ambient matching the
    /// full image's mean luminance; lb: the LB light alone; all: the four images (000 Fig. 2),
    /// tone mapped with the full image's exposure.
    #[arg(long, default_value = "full")]
    pub mode: String,
    /// Reinhard key (the log-average luminance maps to it).
    #[arg(long, default_value_t = 0.18)]
    pub key: f32,
    /// Reinhard white point in scaled luminance (default: the image's brightest pixel).
    #[arg(long)]
    pub white: Option<f32>,
    /// Physical light: also print every instance's forest-grid weights (sun, sky through the
    /// top and the sides, ground, each over its value in the open), one line per instance.
    #[arg(long)]
    pub forest_weights: bool,
}

/// A scene prepared for the frames `a` asks for, and the image size.
pub struct Prepared {
    pub scene: PreparedScene,
    pub width: u32,
    pub height: u32,
    /// Per model, what its base solutions' preparation reported (empty without them).
    pub basis: Vec<BasisReport>,
    /// The LB solver the scene was lit with (none without LB light).
    pub solver: Option<Box<dyn LbSolver>>,
}

/// Where `prepare` prints what it does: stdout, or stderr when stdout is for JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Say {
    #[default]
    Stdout,
    Stderr,
}

/// What a command asks of [`prepare`] besides the frame options, built from its arguments.
#[derive(Clone, Copy, Default)]
pub struct PrepareRequest<'a> {
    /// Light the models with the LB (else the local light only: no LB work).
    pub need_lb: bool,
    /// The most rays per pixel a frame will use (default: the scene camera's); the frame's
    /// memory is checked for it before any LB or kd-tree work.
    pub rays_per_pixel: Option<u32>,
    /// Images written per frame (their memory is checked too).
    pub output_images: usize,
    pub say: Say,
    /// Base solutions whatever `--basis` says: the commands that relight, under the paper
    /// light.
    pub force_basis: bool,
    /// Keep the uncompressed base solutions beside the compressed ones.
    pub keep_raw: bool,
    /// Print the forest grid's weights of every instance (`render --forest-weights`).
    pub instance_weights: bool,
    /// A check of the command's own, given the image size once the scene is known, before
    /// any LB or kd-tree work (`relight`: the disk its frames need).
    pub check_size: Option<&'a dyn Fn(u32, u32) -> Result<()>>,
    /// The sun, in place of the one `FrameArgs` and the scene give (`render --date`).
    pub sun: Option<Sun>,
}

/// Loads the scene, lights every model (from the cache when it can) and builds its
/// kd-trees, printing what it does (where `req.say` says). Under MPI (`runner` over the
/// ranks) the LB solves are shared out across the ranks and only rank 0 prints.
pub fn prepare(a: &FrameArgs, req: PrepareRequest, runner: &dyn Runner) -> Result<Prepared> {
    let PrepareRequest {
        need_lb,
        rays_per_pixel,
        output_images,
        say: to,
        force_basis,
        keep_raw,
        instance_weights,
        check_size,
        sun,
    } = req;
    let root = runner.is_root();
    // Machine-readable runs keep stdout for their JSON.
    let say = |s: String| {
        if !root {
        } else if to == Say::Stdout {
            println!("{s}")
        } else {
            eprintln!("{s}")
        }
    };
    let sun = match sun {
        Some(sun) => Some(sun),
        None => (a.sun.sun.is_some() || a.sun.elevation.is_some() || a.sun.azimuth.is_some())
            .then(|| super::lb::parse_sun(a.sun.sun.as_deref(), a.sun.elevation, a.sun.azimuth))
            .transpose()?,
    };
    if !(1..=sylva_trace::MAX_DEPTH).contains(&a.view.stack) {
        bail!(
            "--stack {}: the short stack holds 1 to {} entries",
            a.view.stack,
            sylva_trace::MAX_DEPTH
        );
    }
    let scene = load_scene(&a.scene, sun)?;
    let (width, height) = resolution(a.view.width, a.view.height, &scene.camera)?;
    let rays_per_pixel = rays_per_pixel.unwrap_or(scene.camera.rays_per_pixel);
    if let Some(check) = check_size {
        check(width, height)?;
    }
    say(format!(
        "scene {}: {} models, {} instances, {} instanced triangles, {} media; {width}x{height}; sun elevation {:.1}° azimuth {:.1}°",
        scene.name,
        scene.models.len(),
        scene.instances.len(),
        scene.instanced_triangles(),
        scene.media.len(),
        scene.sun.elevation_deg(),
        scene.sun.azimuth_deg()
    ));
    let gpu = super::device::open_gpu(a.lb.device)?;
    let solver: Option<Box<dyn LbSolver>> = if need_lb {
        let solver = super::device::solver_for(gpu.as_ref(), a.lb.device, a.lb.precision)?;
        say(format!("LB solver: {}", solver.describe()));
        Some(solver)
    } else {
        None
    };
    let light_name = a.light_for(force_basis)?;
    // The SPP light replaces the paper's LB grids under the paper's shading.
    let light = match light_name {
        "spp" => Light::Paper,
        l => Light::parse(l).context("--light")?,
    };
    // The SPP light needs no LB, but `--basis always` with it is still refused, not ignored.
    let relight = if need_lb || a.light.basis == BasisArg::Always {
        a.relight_plan(force_basis, keep_raw, light_name)?
            .filter(|_| need_lb)
    } else {
        None
    };
    let opts = PrepareOptions {
        runner,
        lb: solver.as_deref().map(|solver| LbPlan {
            solver,
            grid: a.lb.lb_grid,
            cache_dir: (!a.lb.no_cache).then_some(a.lb.cache_dir.as_path()),
            light,
        }),
        traversal: TraversalConfig::with_stack(a.view.stack),
        trace_gpu: gpu.as_ref(),
        shade_on_gpu: !a.view.cpu_shading,
        light,
        indirect: a.view.indirect,
        sky_ambient: a.view.sky_ambient,
        gather_rays: a.light.gather_rays,
        largest_frame: Some((width, height, rays_per_pixel)),
        output_images,
        relight,
        shadows: a.shadow_method(),
        forest: a.forest_grid(light)?,
    };
    // Before any LB work: a coarse grid far costlier than the default's says so.
    if let (Some(w), true) = (
        costly_grid_warning(
            &scene,
            opts.relight.as_ref(),
            opts.forest.as_ref().filter(|_| need_lb),
            light,
        )?,
        root,
    ) {
        eprintln!("{w}");
    }
    let basis = Mutex::new(Vec::new());
    let progress = Bars::new(|r: Report| {
        if let Report::Basis(_, b) = &r {
            basis.lock().expect("basis reports").push((*b).clone());
        }
        let (line, warning) = report_line(r);
        if let (Some(w), true) = (warning, root) {
            eprintln!("{w}");
        }
        say(line);
    });
    if need_lb && runner.processes() > 1 {
        say(format!(
            "MPI: LB solves shared across {} ranks",
            runner.processes()
        ));
    }
    let scene = {
        let progress: &dyn Progress = if root { &progress } else { &Silent };
        PreparedScene::new(scene, &opts, progress)?
    };
    say(format!(
        "ray tracer: {}{}",
        scene.tracer.describe(),
        match (&scene.gpu_frame, scene.tracer.gpu()) {
            (Some(f), _) => format!(
                "; shading on the GPU ({} of shading data)",
                sylva_core::format_bytes(f.device_bytes())
            ),
            (None, Some(_)) => match scene.gpu_shading_note() {
                Some(why) => format!("; shading on the CPU: {why}"),
                None => "; shading on the CPU".into(),
            },
            _ => String::new(),
        }
    ));
    if let Some(p) = &scene.physical {
        say(format!(
            "LB light: the physical light relit from its base solutions ({} sun parts and 3 \
             diffuse parts per model, forest grid {}), shadows {}",
            sylva_light::relight::physical::SUN_PARTS,
            if p.has_forest() { "relit" } else { "off" },
            scene.shadows().name()
        ));
    }
    if let Some(r) = &scene.relit {
        let ill = r.illumination();
        say(format!(
            "LB light: relit from base solutions ({} weights, ambient {}, global grid {}), shadows {}",
            ill.sun.name(),
            ill.ambient,
            r.global()
                .map(|g| g.dims.to_string())
                .unwrap_or_else(|| "off".into()),
            scene.shadows().name()
        ));
    }
    if let Some(f) = &scene.forest {
        // Luminance of each part's weight over its open value, per instance.
        let y = |v: sylva_light::lighting::Vec3| sylva_core::colour::luminance(v.to_array());
        let range =
            |part: fn(&sylva_light::lighting::PartWeights) -> sylva_light::lighting::Vec3| {
                let free = y(part(&f.free));
                let r: Vec<f32> = f
                    .weights
                    .iter()
                    .map(|w| if free > 0.0 { y(part(w)) / free } else { 1.0 })
                    .collect();
                let (lo, hi) = r
                    .iter()
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                        (a.min(v), b.max(v))
                    });
                format!("{lo:.2}–{hi:.2}")
            };
        say(format!(
            "forest grid {}: per instance, of the open's: sun {}, sky through the top {}, \
             through the sides {}, ground {}",
            f.dims,
            range(|w| w.sun),
            range(|w| w.sky_top),
            range(|w| w.sky),
            range(|w| w.ground)
        ));
        if instance_weights {
            for (i, w) in f.weights.iter().enumerate() {
                say(format!(
                    "  instance {i}: sun {:.3} sky top {:.3} sides {:.3} ground {:.3}",
                    y(w.sun),
                    y(w.sky_top) / y(f.free.sky_top).max(f32::MIN_POSITIVE),
                    y(w.sky) / y(f.free.sky).max(f32::MIN_POSITIVE),
                    y(w.ground) / y(f.free.ground).max(f32::MIN_POSITIVE)
                ));
            }
        }
    }
    drop(progress);
    Ok(Prepared {
        scene,
        width,
        height,
        basis: basis.into_inner().expect("basis reports"),
        solver,
    })
}

pub fn run(a: RenderArgs, runner: &dyn Runner) -> Result<()> {
    let modes: Vec<Mode> = match a.mode.as_str() {
        "all" => Mode::ALL.to_vec(),
        m => vec![Mode::parse(m)
            .with_context(|| format!("--mode '{m}': expected full, local, ambient, lb or all"))?],
    };
    let tm = ToneMap {
        key: a.key,
        white: a.white,
    };
    tm.validate().map_err(anyhow::Error::msg)?;
    if let Some(o) = &a.output {
        let ext = o.extension().map(|e| e.to_ascii_lowercase());
        if ext.as_deref() != Some(std::ffi::OsStr::new("png")) {
            bail!(
                "{}: the output is a PNG file (name it .png; --hdr adds an .exr beside it)",
                o.display()
            );
        }
    }
    if let Some(r) = a.rpp {
        let range = sylva_core::limits::RAYS_PER_PIXEL;
        if !range.contains(&r) {
            bail!(
                "--rpp {r}: rays per pixel must be {}",
                sylva_core::limits::describe(&range)
            );
        }
    }
    if let Some(o) = &a.output {
        // Named twice or an input: refused now, not after the render.
        sylva_core::OutputSet::new::<&std::path::Path>(&[]).plan(&image_paths(o, &modes, a.hdr))?;
    }
    // The sun of a moment: placed (or refused: below the horizon) before any work.
    let moment = a.sun_time.moment()?;
    let sun = match &moment {
        Some(m) => {
            let (sun, angles) = m.sun()?;
            if runner.is_root() {
                println!(
                    "sun at {m}: elevation {:.1}°, azimuth {:.1}° from north (world azimuth {:.1}°: north -z, east +x)",
                    angles.elevation_deg,
                    angles.azimuth_deg,
                    sun.azimuth_deg()
                );
            }
            Some(sun)
        }
        None => None,
    };
    let clock = super::stage_clock();
    clock.reset();
    let t_all = Instant::now();
    let spp = a.frame.light.light.as_deref() == Some("spp");
    if spp && runner.processes() > 1 {
        bail!("--light spp renders in one process: run it without mpirun");
    }
    let p = prepare(
        &a.frame,
        PrepareRequest {
            need_lb: !spp && modes.iter().any(|m| m.needs_lb()),
            rays_per_pixel: a.rpp,
            output_images: modes.len(),
            instance_weights: a.forest_weights,
            sun,
            ..PrepareRequest::default()
        },
        runner,
    )?;
    let prepared = &p.scene;
    let rpp = a.rpp.unwrap_or(prepared.scene.camera.rays_per_pixel);
    let camera = prepared.camera(p.width, p.height);
    let settings = prepared.settings(camera, rpp, a.frame.view.seed);
    let bars = Bars::new(|_: Report| {});
    let mut spp_seconds = None;
    let (frame, split) = if spp {
        let t = Instant::now();
        let system = SppSystem::for_scene(
            &prepared.scene,
            &prepared.tracer.cpu().accel,
            SystemConfig::default(),
        )
        .context("the plane-parallel light (003 §5)")?;
        let light = SppLight::with_preset(&system, &prepared.scene.lb.preset)?;
        spp_seconds = Some(t.elapsed().as_secs_f64());
        // The GPU frame kernel reads only lights with a device side; this one says why not.
        if prepared.tracer.gpu().is_some() {
            if let Err(why) = light.device() {
                println!("shading on the CPU: {why}");
            }
        }
        (prepared.render_with(&light, &settings, &bars)?, None)
    } else {
        let progress: &dyn Progress = if runner.is_root() { &bars } else { &Silent };
        match prepared.render_split(runner, &settings, progress)? {
            Some(d) if runner.processes() > 1 => {
                let split = split_summary(&d);
                (d.frame, Some(split))
            }
            Some(d) => (d.frame, None),
            // The root writes the image.
            None => return Ok(()),
        }
    };

    let base = a.output.clone().unwrap_or_else(|| {
        PathBuf::from(format!(
            "sylva-out/{}.png",
            sylva_core::file_stem(&prepared.scene.name, "scene")
        ))
    });
    let images = tone_map_modes(&frame, &modes, &tm);
    let written = write_images(&base, frame.width, frame.height, &images, a.hdr)?;
    for (image, files) in images.iter().zip(&written) {
        let mut wrote = files.png.display().to_string();
        if let Some(exr) = &files.exr {
            wrote = format!("{wrote} and {}", exr.display());
        }
        println!(
            "wrote {wrote} ({} mode, mean luminance {:.4}{})",
            image.mode.name(),
            sylva_render::mean_luminance(&image.hdr),
            if image.mode == Mode::Ambient {
                format!(", ambient {:.4}", frame.matched_ambient())
            } else {
                String::new()
            }
        );
    }
    let t = &frame.timings;
    let mem = prepared.tracer.cpu().accel.memory();
    println!("stage                 seconds");
    for (stage, s) in [
        ("scene build", clock.seconds(stage::SCENE_BUILD)),
        ("LB precompute", clock.seconds(stage::LB_PRECOMPUTE)),
        ("SPP maps and grids", spp_seconds.unwrap_or(0.0)),
        ("acceleration build", clock.seconds(stage::ACCEL_BUILD)),
        ("primary rays", t.primary_seconds),
        ("shadow rays", t.shadow_seconds),
        ("shading", t.shading_seconds),
        ("GPU frame", t.fused_seconds),
        ("tone mapping", clock.seconds(stage::TONE_MAPPING)),
        ("image output", clock.seconds(stage::IMAGE_OUTPUT)),
    ] {
        // A GPU frame is one pass (rays and shading); the CPU's passes are separate.
        let pass = ["primary rays", "shadow rays", "shading"].contains(&stage);
        let gpu = t.fused_seconds > 0.0;
        if (stage == "GPU frame" && !gpu) || (pass && gpu) {
            continue;
        }
        println!("  {stage:<20}{s:>8.3}");
    }
    println!("  {:<20}{:>8.3}", "total", t_all.elapsed().as_secs_f64());
    if let Some(split) = split {
        println!("{split}");
    }
    println!(
        "{}x{} at {rpp} rays/pixel: {} primary + {} shadow rays, {:.2} Mrays/s; frame {:.3} s; {} kd-restarts; kd-trees {}, LB grids {}",
        frame.width,
        frame.height,
        t.primary_rays,
        t.shadow_rays,
        t.mrays_per_second(),
        t.frame_seconds(),
        frame.stats.restarts,
        sylva_core::format_bytes(mem.total()),
        sylva_core::format_bytes(prepared.lighting_bytes()),
    );
    Ok(())
}

/// One line on how a frame was split across MPI ranks.
pub fn split_summary(d: &sylva_pipeline::SplitFrame) -> String {
    let ranks: Vec<String> = d
        .ranks
        .iter()
        .enumerate()
        .map(|(r, w)| format!("rank {r}: {} units {:.3} s", w.units, w.seconds))
        .collect();
    format!(
        "MPI: {} ranks, {} units of {}x{} tiles, frame {:.3} s wall; {}; imbalance {:.1} %",
        d.ranks.len(),
        d.layout.units(),
        d.layout.edge,
        d.layout.edge,
        d.wall_seconds,
        ranks.join(", "),
        100.0 * d.imbalance()
    )
}
