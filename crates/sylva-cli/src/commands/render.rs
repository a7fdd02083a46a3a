//! `sylva render [SCENE]`: the render pipeline of `sylva_render` (scene, LB lighting per
//! model, kd-trees, frame, tone mapping, PNG and EXR) with progress bars and a per-stage
//! summary.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use sylva_core::Sun;
use sylva_geom::{Bands, Scene};
use sylva_lb::relight::Precision;
use sylva_lb::LbSolver;
use sylva_light::relight::{BasisReport, GlobalGridOptions, SunWeights};
use sylva_light::report::LightEvent;
use sylva_light::{Progress, Silent};
use sylva_pipeline::bands::BandImages;
use sylva_pipeline::{
    check_png_name, costly_grid_warning, load_scene, plan_images, resolution, scene_line,
    tone_map_modes, write_images, written_line, BasisChoice, LbPlan, LightSettings, PrepareOptions,
    PreparedScene, RenderSummary, Runner, ShadowMethod,
};
use sylva_render::{Mode, ShadingParams, ToneMap};
use sylva_trace::TraversalConfig;

use super::progress::Bars;
use super::sun_time::SunTimeArgs;

/// `--leaf-optics`: which leaf optics the LB, the frames and the export form from a
/// species' measured leaf (docs/light.md, "Leaf optics").
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum, Default)]
pub enum LeafOpticsArg {
    /// The species' measured mean reflectance and transmittance; the texture shapes only the
    /// pattern (texel / mean texel).
    #[default]
    Measured,
    /// The look before issue 29: the texture's colour is the reflectance, the transmittance
    /// that times the measured T / R.
    Texture,
}

impl From<LeafOpticsArg> for sylva_geom::LeafOptics {
    fn from(a: LeafOpticsArg) -> Self {
        match a {
            LeafOpticsArg::Measured => sylva_geom::LeafOptics::Measured,
            LeafOpticsArg::Texture => sylva_geom::LeafOptics::Texture,
        }
    }
}

/// Whether the LB light of plants comes from base solutions (paper 004): the physical light's
/// (25 sun parts and 3 diffuse parts per model) or, with --light paper, 004's (docs/relight.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BasisArg {
    /// Base solutions when every model's are cached (`sylva basis`; the physical light's
    /// or, with --light paper, 004's), else solved for the sun; the SPP light solves for the
    /// sun.
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
     canopy, shade, cloud, teapot, demo_cloud, woodland; `sylva scene list`).";

/// The help of `--light` for the commands that relight (`basis`, `relight`).
const RELIGHT_LIGHT_HELP: &str = "Light model: physical (the default: per model 25 sun parts \
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
    /// [default: physical]
    #[arg(long, value_parser = ["physical", "paper", "spp"])]
    pub light: Option<String>,
    /// Physical light: final-gather rays per camera sample on a plant, 0 to 256: the light
    /// arriving at a leaf is traced one bounce (sky, ground, other leaves lit by the sun and
    /// their LB light); 0 takes the LB light at the leaf itself, several times faster and less
    /// exact (docs/light.md, "The final gather"). [default: 128 per pixel shared by its
    /// samples: 8 up to 16 rays/pixel, 4 at 32, 2 from 64 on]
    #[arg(
        long,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u32).range(0..=i64::from(sylva_render::gather::MAX_GATHER_RAYS))
    )]
    pub gather_rays: Option<u32>,
    /// LB light from base solutions (always: the physical light's 28 parts per model or,
    /// with --light paper, 004's bases), solved for the sun (never), or (auto) the bases
    /// when all are cached, else solved for the sun.
    #[arg(long, value_enum, default_value = "auto")]
    pub basis: BasisArg,
}

impl Default for RenderLightArgs {
    /// What `basis` and `relight` render with: their light is set by [`relight_light`].
    fn default() -> Self {
        RenderLightArgs {
            light: None,
            gather_rays: None,
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
    /// How long each LB solve runs: coarse (a half-resolution solve first, then 1 × the
    /// grid's longest edge in steps, extrapolated along the slowest mode; the CPU's default),
    /// extrapolated (1.5 × from an empty grid, extrapolated) or papers (2 ×, plain steps; the
    /// GPU's, whose kernels do not extrapolate). Cache entries are kept per schedule.
    #[arg(long, value_enum)]
    pub lb_schedule: Option<super::device::ScheduleArg>,
    /// Physical light: leaves as measured (each species' mean reflectance and transmittance,
    /// the texture shaping only the pattern) or as their texture (its colour the reflectance:
    /// the look before issue 29, to compare). Imported meshes keep their own materials; the
    /// paper light shades with the texture either way.
    #[arg(long, value_enum, default_value = "measured")]
    pub leaf_optics: LeafOpticsArg,
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
    /// Haar), haar:T, pca:K or pcahaar:K:T. The physical light: one codec for its 25 sun
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

impl FrameArgs {
    /// The frame options of a command that relights (`relight`, `view`): its own view, LB,
    /// relighting and grid options, the scene's sun (the command moves it), `light` and
    /// `gather_rays`, the rest as `render`'s defaults.
    pub fn relit(
        scene: &str,
        view: &ViewArgs,
        light: &Option<String>,
        gather_rays: Option<u32>,
        (lb, relit, grid): (&LbArgs, &RelitArgs, &GridArgs),
    ) -> FrameArgs {
        FrameArgs {
            scene: scene.to_string(),
            view: view.clone(),
            sun: SunArgs::default(),
            light: RenderLightArgs {
                light: light.clone(),
                gather_rays,
                ..RenderLightArgs::default()
            },
            lb: lb.clone(),
            relit: relit.clone(),
            grid: grid.clone(),
        }
    }
}

/// The light as `--light`, `--basis` and the relighting options ask for it.
pub fn light_settings(
    light: Option<String>,
    basis: BasisArg,
    relit: &RelitArgs,
    grid: &GridArgs,
) -> LightSettings {
    LightSettings {
        light,
        basis: match basis {
            BasisArg::Auto => BasisChoice::Auto,
            BasisArg::Always => BasisChoice::Always,
            BasisArg::Never => BasisChoice::Never,
        },
        sun: match relit.sun_weights {
            SunWeightsArg::Three => SunWeights::ThreeBasis,
            SunWeightsArg::Exact => SunWeights::Exact,
        },
        ambient: relit.ambient,
        global_grid: (!grid.no_global).then_some(grid.global_grid),
        codec: grid.codec.clone(),
        precision: match grid.basis_precision {
            BasisPrecisionArg::F16 => Precision::F16,
            BasisPrecisionArg::F32 => Precision::F32,
            BasisPrecisionArg::Packed => Precision::Packed,
        },
    }
}

impl From<&FrameArgs> for LightSettings {
    fn from(a: &FrameArgs) -> LightSettings {
        light_settings(a.light.light.clone(), a.light.basis, &a.relit, &a.grid)
    }
}

impl FrameArgs {
    pub fn shadow_method(&self) -> ShadowMethod {
        match self.view.shadows {
            ShadowsArg::Kd => ShadowMethod::KdTree,
            ShadowsArg::Grid => ShadowMethod::SunGrid,
        }
    }
}

/// Says an LB report: its warnings to stderr (on the root), its line as `say` does.
pub fn say_report(r: &LightEvent, root: bool, say: &dyn Fn(String)) {
    if let (Some(w), true) = (r.warning(), root) {
        eprintln!("{w}");
    }
    say(r.line());
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
    /// Also hands every line printed to this (`view`: the page shows the preparation).
    pub echo: Option<&'a (dyn Fn(String) + Sync)>,
    /// The band group to render when the scene has `[bands]` (`render`: each in turn);
    /// `None`: the scene in RGB, its bands left out (other commands).
    pub band_group: Option<usize>,
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
        echo,
        band_group,
    } = req;
    let root = runner.is_root();
    // Machine-readable runs keep stdout for their JSON.
    let say = |s: String| {
        if let Some(echo) = echo {
            echo(s.clone());
        }
        if !root {
        } else if to == Say::Stdout {
            println!("{s}")
        } else {
            eprintln!("{s}")
        }
    };
    let sun = match sun {
        Some(sun) => Some(sun),
        None => Sun::given(a.sun.sun.as_deref(), a.sun.elevation, a.sun.azimuth)?,
    };
    let traversal = TraversalConfig::checked(a.view.stack).map_err(anyhow::Error::msg)?;
    let mut scene = load_scene(&a.scene, sun)?;
    if scene.bands.is_some() {
        match band_group {
            Some(g) => say(apply_band_group(&mut scene, g, a.lb.leaf_optics)?),
            None => say(format!(
                "{}: its [bands] are rendered by `sylva render`; this command shows it in RGB",
                scene.origin
            )),
        }
    }
    scene
        .set_leaf_optics(a.lb.leaf_optics.into())
        .map_err(anyhow::Error::msg)?;
    let (width, height) = resolution(a.view.width, a.view.height, &scene.camera)?;
    let rays_per_pixel = rays_per_pixel.unwrap_or(scene.camera.rays_per_pixel);
    if let Some(check) = check_size {
        check(width, height)?;
    }
    say(scene_line(&scene, width, height));
    let gpu = super::device::open_gpu(a.lb.device)?;
    let solver: Option<Box<dyn LbSolver>> = if need_lb {
        let solver = super::device::solver_for(gpu.as_ref(), a.lb.device, a.lb.precision)?;
        let solver = super::device::on_schedule(solver, a.lb.lb_schedule)?;
        say(super::device::solver_line(&*solver));
        Some(solver)
    } else {
        None
    };
    let choice = LightSettings::from(a).choose(force_basis, keep_raw, need_lb)?;
    let light = choice.light;
    let opts = PrepareOptions {
        runner,
        lb: solver.as_deref().map(|solver| LbPlan {
            solver,
            grid: a.lb.lb_grid,
            cache_dir: (!a.lb.no_cache).then_some(a.lb.cache_dir.as_path()),
            light,
        }),
        traversal,
        trace_gpu: gpu.as_ref(),
        shade_on_gpu: !a.view.cpu_shading,
        light,
        indirect: a.view.indirect,
        sky_ambient: a.view.sky_ambient,
        gather_rays: a
            .light
            .gather_rays
            .unwrap_or_else(|| sylva_render::gather::rays_per_sample(rays_per_pixel)),
        largest_frame: Some((width, height, rays_per_pixel)),
        output_images,
        relight: choice.relight,
        shadows: a.shadow_method(),
        forest: choice.forest,
        accel_cache: (!a.lb.no_cache).then_some(a.lb.cache_dir.as_path()),
    };
    // Before any LB work: a coarse grid far costlier than the default's says so.
    let forest = opts.forest.as_ref().filter(|_| need_lb);
    if let (Some(w), true) = (
        costly_grid_warning(&scene, opts.relight.as_ref(), forest, light)?,
        root,
    ) {
        eprintln!("{w}");
    }
    let basis = Mutex::new(Vec::new());
    let progress = Bars::new(|r: LightEvent| {
        if let LightEvent::Basis(_, b) = &r {
            basis.lock().expect("basis reports").push((*b).clone());
        }
        say_report(&r, root, &say);
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
    for line in scene.describe(instance_weights) {
        say(line);
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

/// Puts band group `g` of `scene`'s `[bands]` into its three channels
/// ([`sylva_geom::Scene::apply_band_group`]; the bands' leaves need measured leaf optics) and
/// says which bands went where (`render` and `export`).
pub fn apply_band_group(scene: &mut Scene, g: usize, leaf_optics: LeafOpticsArg) -> Result<String> {
    let Some(bands) = scene.bands.clone() else {
        bail!("{} has no [bands]", scene.origin);
    };
    if leaf_optics != LeafOpticsArg::Measured {
        bail!(
            "{}: [bands] give each band's leaf reflectance and transmittance; use \
             --leaf-optics measured (the default)",
            scene.origin
        );
    }
    scene
        .apply_band_group(g)
        .map_err(|e| anyhow::anyhow!("{}: bands: {e}", scene.origin))?;
    let names = bands.group(g).map(|b| bands.names[b].as_str());
    Ok(format!(
        "band group {g} ({} in all): {} in the red, green and blue channels",
        bands.groups(),
        names.join(", ")
    ))
}

/// `sylva-out/NAME.png`: where a render goes without `-o`.
fn default_output(scene_name: &str) -> PathBuf {
    PathBuf::from(format!(
        "sylva-out/{}.png",
        sylva_core::file_stem(scene_name, "scene")
    ))
}

/// A scene's band groups: the first prepared, and how to prepare each of the others.
struct BandGroups<'a> {
    bands: &'a Bands,
    first: Prepared,
    prepare: &'a dyn Fn(usize) -> Result<Prepared>,
}

/// `render` of a scene with `[bands]`: one frame per band group (three bands each, on every
/// rank under MPI), then the bands as the layers of one EXR and three of them as a
/// false-colour PNG.
fn render_bands(
    a: &RenderArgs,
    groups: BandGroups<'_>,
    tm: &ToneMap,
    runner: &dyn Runner,
    t_all: Instant,
) -> Result<()> {
    let bands = groups.bands;
    let name = groups.first.scene.scene.name.clone();
    // Every band's image is kept until the last group is rendered.
    let (w, h) = (groups.first.width, groups.first.height);
    sylva_core::check_memory(
        &format!("{} band images of {w}x{h}", bands.len()),
        bands.len() as u64 * u64::from(w) * u64::from(h) * 4,
    )?;
    let mut images: Option<BandImages> = None;
    let mut next = Some(groups.first);
    for g in 0..bands.groups() {
        let p = match next.take() {
            Some(p) => p,
            None => (groups.prepare)(g)?,
        };
        let prepared = &p.scene;
        let rpp = a.rpp.unwrap_or(prepared.scene.camera.rays_per_pixel);
        let camera = prepared.camera(p.width, p.height);
        let settings = prepared.settings(camera, rpp, a.frame.view.seed);
        let bars = Bars::new(|_: LightEvent| {});
        let progress: &dyn Progress = if runner.is_root() { &bars } else { &Silent };
        let t = Instant::now();
        // Ranks other than the root get no frame: they go on to the next group.
        let Some(d) = prepared.render_split(runner, &settings, progress)? else {
            continue;
        };
        let mut names: Vec<&str> = bands.group(g).map(|b| bands.names[b].as_str()).to_vec();
        names.dedup(); // a last group repeats its last band in the spare channels
        println!(
            "bands {}: {}x{} at {rpp} rays/pixel, frame {:.2} s",
            names.join(", "),
            d.frame.width,
            d.frame.height,
            t.elapsed().as_secs_f64()
        );
        images
            .get_or_insert_with(|| BandImages::new(bands, d.frame.width, d.frame.height))
            .add_group(g, &d.frame);
    }
    let Some(images) = images else {
        return Ok(()); // the root writes the images
    };
    let base = a.output.clone().unwrap_or_else(|| default_output(&name));
    let written = images.write(&base, tm)?;
    println!(
        "wrote {} (a layer per band: {}) and {} (false colour: {}) in {:.1} s",
        written.exr.display(),
        bands.names.join(", "),
        written.png.display(),
        images.false_colour_legend(),
        t_all.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn run(a: RenderArgs, runner: &dyn Runner) -> Result<()> {
    let modes = Mode::parse_set(&a.mode).with_context(|| {
        format!(
            "--mode '{}': expected full, local, ambient, lb or all",
            a.mode
        )
    })?;
    let tm = ToneMap {
        key: a.key,
        white: a.white,
    };
    tm.validate().map_err(anyhow::Error::msg)?;
    a.output.as_deref().map(check_png_name).transpose()?;
    sylva_core::limits::check_rays_per_pixel(a.rpp).map_err(anyhow::Error::msg)?;
    // Named twice or an input: refused now, not after the render.
    (a.output.as_deref())
        .map(|o| plan_images(o, &modes, a.hdr))
        .transpose()?;
    // The sun of a moment: placed (or refused: below the horizon) before any work.
    let moment = a.sun_time.moment()?;
    let sun = match &moment {
        Some(m) => {
            let (sun, angles) = m.sun()?;
            if runner.is_root() {
                println!("{}", angles.describe(m, &sun));
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
    let request = |band_group| PrepareRequest {
        need_lb: !spp && modes.iter().any(|m| m.needs_lb()),
        rays_per_pixel: a.rpp,
        output_images: modes.len(),
        instance_weights: a.forest_weights,
        sun,
        band_group,
        ..PrepareRequest::default()
    };
    let p = prepare(&a.frame, request(Some(0)), runner)?;
    if let Some(bands) = p.scene.scene.bands.clone() {
        if spp || modes != [Mode::Full] {
            bail!(
                "{}: a scene with [bands] renders each band's full light with the LB \
                 (not --mode {} or --light spp)",
                p.scene.scene.origin,
                a.mode
            );
        }
        let groups = BandGroups {
            bands: &bands,
            first: p,
            prepare: &|g| prepare(&a.frame, request(Some(g)), runner),
        };
        return render_bands(&a, groups, &tm, runner, t_all);
    }
    let prepared = &p.scene;
    let rpp = a.rpp.unwrap_or(prepared.scene.camera.rays_per_pixel);
    let camera = prepared.camera(p.width, p.height);
    let settings = prepared.settings(camera, rpp, a.frame.view.seed);
    let bars = Bars::new(|_: LightEvent| {});
    let mut spp_seconds = None;
    let (frame, split) = if spp {
        let f = prepared.render_spp(&settings, &bars)?;
        if let Some(why) = f.cpu_shading {
            println!("shading on the CPU: {why}");
        }
        spp_seconds = Some(f.light_seconds);
        (f.frame, None)
    } else {
        let progress: &dyn Progress = if runner.is_root() { &bars } else { &Silent };
        match prepared.render_split(runner, &settings, progress)? {
            Some(d) if runner.processes() > 1 => {
                let split = d.summary();
                (d.frame, Some(split))
            }
            Some(d) => (d.frame, None),
            // The root writes the image.
            None => return Ok(()),
        }
    };

    let base = a
        .output
        .clone()
        .unwrap_or_else(|| default_output(&prepared.scene.name));
    let images = tone_map_modes(&frame, &modes, &tm);
    let written = write_images(&base, frame.width, frame.height, &images, a.hdr)?;
    for (image, files) in images.iter().zip(&written) {
        println!("{}", written_line(image, files, &frame));
    }
    let summary = RenderSummary {
        prepared,
        frame: &frame,
        rays_per_pixel: rpp,
        clock,
        spp_seconds,
        total_seconds: t_all.elapsed().as_secs_f64(),
        split,
    };
    print!("{summary}");
    Ok(())
}
