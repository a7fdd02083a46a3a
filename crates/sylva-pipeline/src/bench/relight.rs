//! `sylva bench relight`: 004 Table 1 on this machine. The frame time over a sequence of suns
//! (relighting every instance and rendering, shadow rays through the top-level kd-tree and
//! through the sun-aligned grid, alternated), against the static frame of paper 000 (one LB
//! grid per model, solved for one sun) measured in the same run; the base solutions' solve
//! time; the compressed bytes; and the image RMSE between frames relit from the compressed
//! and from the uncompressed bases.

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::colour::linear_to_srgb;
use sylva_core::colour::luminance;
use sylva_core::format_bytes;
use sylva_core::measure::{median, peak_rss_bytes};
use sylva_lb::relight::{BasisSet, BasisWeights, RelightError};
use sylva_light::lighting::{LightingSource, ModelLighting};
use sylva_light::relight::physical::sun_part_weights;
use sylva_light::relight::{sun_path, BasisReport, GlobalGridOptions, StoredBasis};
use sylva_light::relight::{CompressedPhysicalBasis, StoredPhysicalBasis};
use sylva_light::ModelGridLight;
use sylva_render::{plant_coverage, Frame, Mode, RenderSettings, ToneMap};

use crate::{LbPlan, PipelineError, PreparedScene, ShadowMethod, Silent};

/// What to measure.
#[derive(Debug, Clone, Copy)]
pub struct RelightBenchPlan {
    /// Sun positions over 90° about the zenith (004 Table 1: 24).
    pub suns: usize,
    /// Timed passes over the sequence per shadow method (after one untimed pass).
    pub runs: u32,
    /// The shadow method whose frame time is `frame_seconds` and whose frames the RMSE
    /// compares.
    pub shadows: ShadowMethod,
    /// The frame's width and height.
    pub size: (u32, u32),
    /// Seed of the sub-pixel jitter.
    pub seed: u64,
    /// Physical light: also render each sun's frame with the light solved for that sun and
    /// measure the relit frames against it ([`against_direct`]).
    pub against_direct: bool,
}

impl RelightBenchPlan {
    /// Frames [`relight`] renders (for a progress bar).
    pub fn frames(&self) -> u64 {
        let suns = self.suns as u64;
        let direct = if self.against_direct { 3 * suns } else { 0 };
        1 + (self.runs as u64 + 1) * (1 + 2 * suns) + 2 * suns + direct
    }
}

/// `sylva bench relight`'s report.
#[derive(Debug, Clone, Serialize)]
pub struct RelightBench {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub rays_per_pixel: u32,
    pub suns: usize,
    pub runs: u32,
    pub threads: usize,
    pub sun_weights: &'static str,
    pub global_grid: Option<String>,
    pub shadows: &'static str,
    /// Mean over the suns of the per-sun medians, with the chosen shadows.
    pub frame_seconds: f64,
    pub frame_seconds_kd: f64,
    pub frame_seconds_grid: f64,
    /// Median of the paired grid/kd frame times.
    pub grid_over_kd: f64,
    /// Relighting alone (moving the sun), median.
    pub relight_seconds: f64,
    pub static_frame_seconds: f64,
    pub ratio_to_static: f64,
    /// The base solutions' solve time (measured now, or recorded when cached).
    pub basis_seconds: Option<f64>,
    pub basis_seconds_per_model: Vec<Option<f64>>,
    pub basis_cached: bool,
    pub compressed_bytes: u64,
    pub raw_bytes: u64,
    /// The base solutions' compression (`--codec`).
    pub codec: String,
    pub rmse: f64,
    pub rmse_space: &'static str,
    pub rmse_linear: f64,
    pub mean_linear: f64,
    /// Loading, lighting and building the scene, before any of the above.
    pub prepare_seconds: f64,
    pub peak_rss_bytes: Option<u64>,
    pub device: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<String>,
    /// On a GPU the relit frame is one kernel (rays, shadow rays, the per-instance base
    /// combinations); shadow rays go through the kd-trees there, so both methods agree.
    pub gpu_shading: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_shading_bytes: Option<u64>,
}

/// Mean over suns of the per-sun medians.
fn mean_of_medians(times: &[Vec<f64>]) -> f64 {
    times.iter().map(|t| median(t.clone())).sum::<f64>() / times.len().max(1) as f64
}

/// Tone-mapped sRGB values in [0, 1] of `hdr`, exposed with `stats`.
fn display(tm: &ToneMap, hdr: &[[f32; 3]], stats: sylva_render::tonemap::ToneStats) -> Vec<f32> {
    tm.apply_with(hdr, stats)
        .into_iter()
        .flat_map(|p| p.map(|c| linear_to_srgb(c.clamp(0.0, 1.0))))
        .collect()
}

/// Measures relighting on `prepared`, prepared with base solutions, the uncompressed ones
/// kept (`basis`: what their preparation reported, per model), at 1 ray per pixel; `tick`
/// follows every frame. The report's `codec` and `prepare_seconds` are the caller's to fill
/// in (empty and 0 here).
pub fn relight(
    prepared: &mut PreparedScene,
    basis: &[BasisReport],
    plan: RelightBenchPlan,
    tick: &dyn Fn(),
) -> Result<RelightBench, PipelineError> {
    let (w, h) = plan.size;
    let camera = prepared.camera(w, h);
    let settings = prepared.settings(camera, 1, plan.seed);
    let suns = sun_path(plan.suns, prepared.scene.sun.azimuth_deg());
    let relit = prepared.relit.as_ref().ok_or(PipelineError::NeedsBasis)?;
    let sun_weights = relit.illumination().sun;
    let global = relit.global().map(|g| g.dims.to_string());

    let mut compressed_bytes = 0u64;
    let mut raw_bytes = 0u64;
    for m in 0..prepared.scene.models.len() {
        if let Some(StoredBasis::Compressed(c)) = relit.model(m) {
            compressed_bytes += c.bytes();
            raw_bytes += BasisSet::memory_needed(c.dims);
        }
    }
    let basis_per_model: Vec<Option<f64>> = basis.iter().map(|r| r.solve_seconds).collect();
    let basis_seconds: Option<f64> = basis_per_model.iter().copied().sum();
    let basis_cached = basis.iter().all(|r| r.source == LightingSource::Cached);

    // The static frame of paper 000: one grid per model for the scene's sun taken as the
    // model's own (exactly the direct solve's light: the exact combination of the
    // uncompressed bases), kd-tree shadows. Median of the runs after a warm-up.
    prepared.use_uncompressed(true)?;
    let to_sun = prepared.to_sun;
    let static_light = {
        let r = prepared.relit.as_ref().ok_or(PipelineError::NeedsBasis)?;
        let grids: Vec<Option<ModelLighting>> = (0..prepared.scene.models.len())
            .map(|m| match r.model(m) {
                Some(StoredBasis::Full(b)) => {
                    let t = -to_sun;
                    let w = BasisWeights::exact([t.x as f64, t.y as f64, t.z as f64])?;
                    Ok(Some(ModelLighting::from_normalised(&b.relight(&w)?)))
                }
                _ => Ok(None),
            })
            .collect::<Result<_, RelightError>>()?;
        ModelGridLight::new(
            grids,
            &prepared.scene.models,
            prepared.tracer.cpu().accel.instances(),
        )
    };
    prepared.use_uncompressed(false)?;
    let t = time_frames(prepared, &static_light, &suns, &settings, plan, tick)?;
    let (frame_kd, frame_grid, static_seconds) = (t.kd, t.grid, t.static_seconds);
    let frame_seconds = t.chosen(plan.shadows);

    // Image RMSE, compressed against uncompressed bases, over the sequence: tone-mapped
    // sRGB in [0, 1] with the uncompressed frame's exposure (and linear, for reference).
    prepared.set_shadows(plan.shadows);
    let tm = ToneMap::default();
    let (mut sq, mut sq_linear, mut n) = (0.0f64, 0.0f64, 0usize);
    let mut mean_linear = 0.0f64;
    // All compressed frames, then all uncompressed ones: switching the fields is cheap on
    // the CPU but re-uploads them to a GPU.
    let mut compressed = Vec::with_capacity(suns.len());
    for &sun in &suns {
        prepared.set_sun(sun)?;
        compressed.push(prepared.render(&settings, &Silent)?.compose(Mode::Full));
        tick();
    }
    prepared.use_uncompressed(true)?;
    for (&sun, small) in suns.iter().zip(compressed) {
        prepared.set_sun(sun)?;
        let full = prepared.render(&settings, &Silent)?.compose(Mode::Full);
        let stats = tm.measure(&full);
        let (x, y) = (display(&tm, &small, stats), display(&tm, &full, stats));
        for (u, v) in x.iter().zip(&y) {
            sq += ((u - v) as f64).powi(2);
        }
        for (u, v) in small.iter().flatten().zip(full.iter().flatten()) {
            sq_linear += ((u - v) as f64).powi(2);
            mean_linear += *v as f64;
        }
        n += x.len();
        tick();
    }
    prepared.use_uncompressed(false)?;

    Ok(RelightBench {
        scene: prepared.scene.name.clone(),
        width: w,
        height: h,
        rays_per_pixel: 1,
        suns: suns.len(),
        runs: plan.runs,
        threads: rayon::current_num_threads(),
        sun_weights: sun_weights.name(),
        global_grid: global,
        shadows: plan.shadows.name(),
        frame_seconds,
        frame_seconds_kd: frame_kd,
        frame_seconds_grid: frame_grid,
        grid_over_kd: t.grid_over_kd,
        relight_seconds: t.relight_seconds,
        static_frame_seconds: static_seconds,
        ratio_to_static: frame_seconds / static_seconds,
        basis_seconds,
        basis_seconds_per_model: basis_per_model,
        basis_cached,
        compressed_bytes,
        raw_bytes,
        codec: String::new(),
        rmse: (sq / n as f64).sqrt(),
        rmse_space: "tone-mapped sRGB in [0, 1], the uncompressed frame's exposure",
        rmse_linear: (sq_linear / n as f64).sqrt(),
        mean_linear: mean_linear / n as f64,
        prepare_seconds: 0.0,
        peak_rss_bytes: peak_rss_bytes(),
        device: prepared.tracer.device(),
        adapter: prepared.tracer.adapter(),
        gpu_shading: prepared.gpu_frame.is_some(),
        gpu_shading_bytes: prepared.gpu_frame.as_ref().map(|f| f.device_bytes()),
    })
}

impl fmt::Display for RelightBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} at {}x{}, 1 ray/pixel, {} threads; {} suns over 90° about the zenith, {} weights, global grid {}; medians of {} runs per sun",
            self.scene,
            self.width,
            self.height,
            self.threads,
            self.suns,
            self.sun_weights,
            self.global_grid.as_deref().unwrap_or("off"),
            self.runs
        )?;
        writeln!(
            f,
            "relit frame (mean over the suns): {:.3} s with kd-tree shadows, {:.3} s with the sun grid (median of paired grid/kd {:.3}; relighting itself {:.4} s)",
            self.frame_seconds_kd, self.frame_seconds_grid, self.grid_over_kd, self.relight_seconds
        )?;
        writeln!(
            f,
            "static frame (paper 000, same run): {:.3} s; relit/static {:.2}",
            self.static_frame_seconds, self.ratio_to_static
        )?;
        writeln!(
            f,
            "base solutions: {} ({}); compressed {} of {} ({:.1}×)",
            self.basis_seconds
                .map(|s| format!("{s:.1} s of solves"))
                .unwrap_or_else(|| "solve time not recorded".into()),
            if self.basis_cached {
                "recorded in the cache"
            } else {
                "solved now"
            },
            format_bytes(self.compressed_bytes),
            format_bytes(self.raw_bytes),
            self.raw_bytes as f64 / self.compressed_bytes.max(1) as f64
        )?;
        writeln!(
            f,
            "image RMSE compressed vs uncompressed: {:.5} (tone-mapped sRGB, [0, 1]); linear {:.5} (mean {:.4})",
            self.rmse, self.rmse_linear, self.mean_linear
        )
    }
}

/// Frame times over `suns` ([`time_frames`]).
struct Timings {
    kd: f64,
    grid: f64,
    grid_over_kd: f64,
    relight_seconds: f64,
    static_seconds: f64,
}

impl Timings {
    fn chosen(&self, shadows: ShadowMethod) -> f64 {
        match shadows {
            ShadowMethod::KdTree => self.kd,
            ShadowMethod::SunGrid => self.grid,
        }
    }
}

/// The relit frame per sun with both shadow methods back to back (their order alternating,
/// so a pair sees the same load) and the static frame (`static_light` at the scene's sun,
/// kd-tree shadows) once per pass, over one untimed and `plan.runs` timed passes.
fn time_frames(
    prepared: &mut PreparedScene,
    static_light: &dyn sylva_light::IndirectLight,
    suns: &[glam::Vec3],
    settings: &sylva_render::RenderSettings,
    plan: RelightBenchPlan,
    tick: &dyn Fn(),
) -> Result<Timings, PipelineError> {
    let to_sun = prepared.to_sun;
    let static_frame = |p: &PreparedScene| -> Result<Frame, PipelineError> {
        Ok(p.renderer_with(static_light).render(settings, &|_| {})?)
    };
    static_frame(prepared)?;
    tick();
    let mut static_runs = Vec::new();
    let methods = [ShadowMethod::KdTree, ShadowMethod::SunGrid];
    let mut times = vec![vec![Vec::new(); suns.len()]; 2];
    let mut relight_times = vec![Vec::new(); 2];
    let mut pair_ratios = Vec::new();
    for run in 0..=plan.runs {
        prepared.set_sun(to_sun)?;
        let t = Instant::now();
        static_frame(prepared)?;
        if run > 0 {
            static_runs.push(t.elapsed().as_secs_f64());
        }
        tick();
        for (k, &sun) in suns.iter().enumerate() {
            let mut pair = [0.0; 2];
            for i in 0..2 {
                let mi = (i + k + run as usize) % 2;
                prepared.set_shadows(methods[mi]);
                let t0 = Instant::now();
                prepared.set_sun(sun)?;
                let t1 = Instant::now();
                prepared.render(settings, &Silent)?;
                pair[mi] = t0.elapsed().as_secs_f64();
                if run > 0 {
                    times[mi][k].push(pair[mi]);
                    relight_times[mi].push((t1 - t0).as_secs_f64());
                }
                tick();
            }
            if run > 0 {
                pair_ratios.push(pair[1] / pair[0]);
            }
        }
    }
    prepared.set_sun(to_sun)?;
    Ok(Timings {
        kd: mean_of_medians(&times[0]),
        grid: mean_of_medians(&times[1]),
        grid_over_kd: median(pair_ratios),
        relight_seconds: median(relight_times.concat()),
        static_seconds: median(static_runs),
    })
}

/// `sylva bench relight`'s report on the physical light relit from its base solutions.
#[derive(Debug, Clone, Serialize)]
pub struct PhysicalRelightBench {
    pub scene: String,
    pub light: &'static str,
    pub width: u32,
    pub height: u32,
    pub rays_per_pixel: u32,
    pub gather_rays: u32,
    pub suns: usize,
    pub runs: u32,
    pub threads: usize,
    pub forest_grid: bool,
    pub shadows: &'static str,
    /// Mean over the suns of the per-sun medians, with the chosen shadows.
    pub frame_seconds: f64,
    pub frame_seconds_kd: f64,
    pub frame_seconds_grid: f64,
    pub grid_over_kd: f64,
    /// Relighting alone (moving the sun: the forest's weights and every instance's terms).
    pub relight_seconds: f64,
    /// The per-sun light's frame (one grid of four parts per model), same run.
    pub static_frame_seconds: f64,
    pub ratio_to_static: f64,
    /// The base solutions' solve time: solved now, or as recorded in the compressed cache
    /// entries (`None`: parts read from the cache, whose solve time is not recorded).
    pub basis_seconds: Option<f64>,
    /// The forest grid's parts (45 coarse solves, made in every preparation).
    pub forest_basis_seconds: Option<f64>,
    /// Bytes of the models' bases uncompressed (28 parts × 3 colours, f32).
    pub basis_bytes: u64,
    /// The parts' compression (`--codec`: the sun parts' and the diffuse parts'), or `none`.
    pub codec: String,
    /// Bytes of the compressed bases in use (`None`: uncompressed), and of their two sets.
    pub compressed_bytes: Option<u64>,
    pub compressed_sun_bytes: Option<u64>,
    pub compressed_diffuse_bytes: Option<u64>,
    /// Frames relit from the compressed bases against the uncompressed ones over the suns
    /// (with the uncompressed bases kept): image RMSE (tone-mapped sRGB) and plant-pixel
    /// relative RMSE.
    pub rmse: Option<f64>,
    pub plant_rel_rmse: Option<f64>,
    /// Image RMSE of the relit frames (the bases in use) against frames of the light solved
    /// for each sun (`against_direct.image_rmse`), with `--against-direct`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rmse_vs_direct: Option<f64>,
    /// Plant-pixel relative RMSE of the same (`against_direct.plant_rel_rmse`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plant_rel_rmse_vs_direct: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub against_direct: Option<AgainstDirect>,
    /// The same measured with the uncompressed bases (when kept beside compressed ones).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub against_direct_uncompressed: Option<AgainstDirect>,
    /// Loading, solving or reading the bases and building the scene.
    pub prepare_seconds: f64,
    pub peak_rss_bytes: Option<u64>,
    pub device: &'static str,
}

/// How the bench solves the light for one sun ([`PreparedScene::per_sun_light`]): the LB
/// plan and the forest grid the scene was prepared with.
#[derive(Clone, Copy)]
pub struct DirectSolve<'a> {
    pub lb: LbPlan<'a>,
    pub forest: Option<GlobalGridOptions>,
}

/// Measures the physical light relit on `prepared` (prepared with its base solutions): the
/// frame time over `plan.suns` suns against the per-sun light's frame, at 1 ray per pixel;
/// with `plan.against_direct` also the relit frames against the light solved for each sun
/// (`direct`, required then; [`against_direct`]). `prepare_seconds` is the caller's to fill
/// in.
pub fn relight_physical(
    prepared: &mut PreparedScene,
    plan: RelightBenchPlan,
    direct: Option<&DirectSolve>,
    tick: &dyn Fn(),
) -> Result<PhysicalRelightBench, PipelineError> {
    let direct = match (plan.against_direct, direct) {
        (true, None) => {
            return Err(PipelineError::Shading(
                "measuring against direct solves needs the LB plan to solve with".into(),
            ))
        }
        (true, Some(d)) => Some(d),
        (false, _) => None,
    };
    let (w, h) = plan.size;
    let camera = prepared.camera(w, h);
    let settings = prepared.settings(camera, 1, plan.seed);
    let suns = sun_path(plan.suns, prepared.scene.sun.azimuth_deg());
    let p = prepared
        .physical
        .as_ref()
        .ok_or(PipelineError::NeedsBasis)?;
    let relit_err = |source| PipelineError::Relit {
        scene: prepared.scene.name.clone(),
        source,
    };
    let static_light = p
        .static_light(
            &prepared.scene.models,
            prepared.tracer.cpu().accel.instances(),
        )
        .map_err(relit_err)?;
    let models = prepared.scene.models.len();
    let compressed: Vec<&CompressedPhysicalBasis> = (0..models)
        .filter_map(|m| match p.model(m) {
            Some(StoredPhysicalBasis::Compressed(c)) => Some(&**c),
            _ => None,
        })
        .collect();
    let sets = |f: fn((u64, u64)) -> u64| {
        (!compressed.is_empty()).then(|| compressed.iter().map(|c| f(c.set_bytes())).sum())
    };
    let (compressed_sun_bytes, compressed_diffuse_bytes) = (sets(|s| s.0), sets(|s| s.1));
    let compressed_bytes = compressed_sun_bytes
        .zip(compressed_diffuse_bytes)
        .map(|(a, b)| a + b);
    let codec = compressed
        .first()
        .map_or_else(|| "none".to_string(), |c| c.target().name());
    let forest_grid = p.has_forest();
    let t = time_frames(prepared, &static_light, &suns, &settings, plan, tick)?;
    let frame_seconds = t.chosen(plan.shadows);
    prepared.set_shadows(plan.shadows);

    // Compression's error: frames relit from the compressed bases against the uncompressed
    // ones (all of one, then all of the other: each switch relights every instance).
    let (mut rmse, mut plant_rel_rmse) = (None, None);
    if prepared.has_uncompressed() {
        let plant = plant_pixels(prepared, &settings)?;
        let to_sun = prepared.to_sun;
        let mut small = Vec::with_capacity(suns.len());
        for &sun in &suns {
            prepared.set_sun(sun)?;
            small.push(prepared.render(&settings, &Silent)?);
            tick();
        }
        prepared.use_uncompressed(true)?;
        let mut total = PairSums::default();
        for (&sun, c) in suns.iter().zip(&small) {
            prepared.set_sun(sun)?;
            let full = prepared.render(&settings, &Silent)?;
            total.add(&pair_error(c, &full, &plant));
            tick();
        }
        prepared.use_uncompressed(false)?;
        prepared.set_sun(to_sun)?;
        rmse = Some(total.image_rmse());
        plant_rel_rmse = Some(total.plant_rel_rmse());
    }
    let (against, against_uncompressed) = match direct {
        Some(d) => {
            let (a, u) = against_direct(prepared, &suns, d, &settings, tick)?;
            (Some(a), u)
        }
        None => (None, None),
    };
    Ok(PhysicalRelightBench {
        scene: prepared.scene.name.clone(),
        light: "physical",
        width: w,
        height: h,
        rays_per_pixel: 1,
        gather_rays: prepared.shading.gather_rays,
        suns: suns.len(),
        runs: plan.runs,
        threads: rayon::current_num_threads(),
        forest_grid,
        shadows: plan.shadows.name(),
        frame_seconds,
        frame_seconds_kd: t.kd,
        frame_seconds_grid: t.grid,
        grid_over_kd: t.grid_over_kd,
        relight_seconds: t.relight_seconds,
        static_frame_seconds: t.static_seconds,
        ratio_to_static: frame_seconds / t.static_seconds,
        basis_seconds: prepared.basis_solve_seconds,
        forest_basis_seconds: prepared.forest_basis_seconds,
        basis_bytes: prepared.physical_raw_bytes,
        codec,
        compressed_bytes,
        compressed_sun_bytes,
        compressed_diffuse_bytes,
        rmse,
        plant_rel_rmse,
        rmse_vs_direct: against.as_ref().map(|a| a.image_rmse),
        plant_rel_rmse_vs_direct: against.as_ref().map(|a| a.plant_rel_rmse),
        against_direct: against,
        against_direct_uncompressed: against_uncompressed,
        prepare_seconds: 0.0,
        peak_rss_bytes: peak_rss_bytes(),
        device: prepared.tracer.device(),
    })
}

/// Per pixel of `settings`' frames, whether every sample's primary ray hits a plant.
fn plant_pixels(
    prepared: &PreparedScene,
    settings: &RenderSettings,
) -> Result<Vec<bool>, PipelineError> {
    Ok(plant_coverage(prepared.tracer.query(), settings)?
        .into_iter()
        .map(|c| c >= 1.0)
        .collect())
}

/// One sun of [`AgainstDirect`].
#[derive(Debug, Clone, Serialize)]
pub struct SunAgainstDirect {
    /// The sun's elevation and azimuth, degrees.
    pub elevation_deg: f64,
    pub azimuth_deg: f64,
    /// Whether the sun travels along a sun part's direction (a lattice direction or one on
    /// the rings between, in the world's frame), where the relit light of an unrotated
    /// instance is its direct solve.
    pub on_part: bool,
    /// RMSE of the tone-mapped sRGB values in [0, 1] (the direct frame's exposure).
    pub image_rmse: f64,
    /// Over plant pixels: RMS luminance difference over the direct frame's mean luminance.
    pub plant_rel_rmse: f64,
    /// Over plant pixels: relit mean luminance over the direct frame's.
    pub plant_ratio: f64,
}

/// Relit frames against frames of the light solved for each sun ([`against_direct`]).
#[derive(Debug, Clone, Serialize)]
pub struct AgainstDirect {
    /// RMSE over every sun's pixels, tone-mapped sRGB in [0, 1] (8-bit value / 255, not
    /// rounded), each frame pair with its direct frame's exposure.
    pub image_rmse: f64,
    /// Over every sun's plant pixels: RMS luminance difference over the direct frames' mean.
    pub plant_rel_rmse: f64,
    /// Over every sun's plant pixels: relit mean luminance over the direct frames'.
    pub plant_ratio: f64,
    /// Pixels whose every sample's primary ray hits a plant (per frame).
    pub plant_pixels: usize,
    /// Indices into `per_sun` of the suns with the largest plant relative RMSE, largest first
    /// (at most three).
    pub largest: Vec<usize>,
    /// Solving (or reading from the cache) the light of every sun.
    pub direct_seconds: f64,
    pub per_sun: Vec<SunAgainstDirect>,
}

/// Sums of squared differences of one frame pair ([`pair_error`]).
#[derive(Debug, Clone, Copy, Default)]
struct PairSums {
    /// Tone-mapped sRGB: squared differences and values compared.
    image_sq: f64,
    image_n: usize,
    /// Plant pixels: squared luminance differences, relit and direct luminance.
    plant_sq: f64,
    plant_relit: f64,
    plant_direct: f64,
    plant_n: usize,
}

impl PairSums {
    fn add(&mut self, o: &PairSums) {
        self.image_sq += o.image_sq;
        self.image_n += o.image_n;
        self.plant_sq += o.plant_sq;
        self.plant_relit += o.plant_relit;
        self.plant_direct += o.plant_direct;
        self.plant_n += o.plant_n;
    }

    fn image_rmse(&self) -> f64 {
        (self.image_sq / self.image_n.max(1) as f64).sqrt()
    }

    fn plant_rel_rmse(&self) -> f64 {
        let n = self.plant_n.max(1) as f64;
        (self.plant_sq / n).sqrt() / (self.plant_direct / n).max(f64::MIN_POSITIVE)
    }

    fn plant_ratio(&self) -> f64 {
        self.plant_relit / self.plant_direct.max(f64::MIN_POSITIVE)
    }
}

/// The differences of a relit frame from its direct frame: tone-mapped sRGB with the direct
/// frame's exposure over every pixel, linear luminance over the pixels of `plant`.
fn pair_error(relit: &Frame, direct: &Frame, plant: &[bool]) -> PairSums {
    let tm = ToneMap::default();
    let (r, d) = (relit.compose(Mode::Full), direct.compose(Mode::Full));
    let stats = tm.measure(&d);
    let (x, y) = (display(&tm, &r, stats), display(&tm, &d, stats));
    let mut sums = PairSums {
        image_sq: x
            .iter()
            .zip(&y)
            .map(|(u, v)| ((u - v) as f64).powi(2))
            .sum(),
        image_n: x.len(),
        ..PairSums::default()
    };
    for ((a, b), _) in r.iter().zip(&d).zip(plant).filter(|(_, &p)| p) {
        let (la, lb) = (luminance(*a) as f64, luminance(*b) as f64);
        sums.plant_sq += (la - lb).powi(2);
        sums.plant_relit += la;
        sums.plant_direct += lb;
        sums.plant_n += 1;
    }
    sums
}

/// Per-sun and pooled sums of one light's frames against the direct ones.
#[derive(Default)]
struct Tally {
    per_sun: Vec<SunAgainstDirect>,
    total: PairSums,
}

impl Tally {
    fn add(&mut self, sun: glam::Vec3, sums: PairSums) {
        self.total.add(&sums);
        let s = sun.normalize().as_dvec3();
        let travel = [-s.x, -s.y, -s.z];
        self.per_sun.push(SunAgainstDirect {
            elevation_deg: s.y.clamp(-1.0, 1.0).asin().to_degrees(),
            azimuth_deg: s.z.atan2(s.x).to_degrees(),
            on_part: sun_part_weights(travel).is_ok_and(|w| w.len() == 1),
            image_rmse: sums.image_rmse(),
            plant_rel_rmse: sums.plant_rel_rmse(),
            plant_ratio: sums.plant_ratio(),
        });
    }

    fn finish(self, plant_pixels: usize, direct_seconds: f64) -> AgainstDirect {
        let per_sun = self.per_sun;
        let mut largest: Vec<usize> = (0..per_sun.len()).collect();
        largest.sort_by(|&a, &b| {
            per_sun[b]
                .plant_rel_rmse
                .total_cmp(&per_sun[a].plant_rel_rmse)
                .then(a.cmp(&b))
        });
        largest.truncate(3);
        AgainstDirect {
            image_rmse: self.total.image_rmse(),
            plant_rel_rmse: self.total.plant_rel_rmse(),
            plant_ratio: self.total.plant_ratio(),
            plant_pixels,
            largest,
            direct_seconds,
            per_sun,
        }
    }
}

/// The relit frames of `prepared` (its physical light relit from its bases) against frames
/// of the light solved for each of `suns` (towards the sun) as a scene that does not relight
/// is lit ([`PreparedScene::per_sun_light`], from the LB cache when it can), both rendered
/// with `settings`: per sun and over all, the image RMSE (tone-mapped sRGB) and the plant
/// pixels' relative RMSE and mean ratio. At a part's direction the two lights agree for unrotated
/// instances (float noise); between them the difference is the sun parts' interpolation.
/// The bases in use, and (when the uncompressed bases are kept beside compressed ones) the
/// uncompressed bases too.
pub fn against_direct(
    prepared: &mut PreparedScene,
    suns: &[glam::Vec3],
    direct: &DirectSolve,
    settings: &RenderSettings,
    tick: &dyn Fn(),
) -> Result<(AgainstDirect, Option<AgainstDirect>), PipelineError> {
    if prepared.physical.is_none() {
        return Err(PipelineError::NeedsBasis);
    }
    let plant = plant_pixels(prepared, settings)?;
    let both = prepared.has_uncompressed();
    let (mut in_use, mut uncompressed) = (Tally::default(), Tally::default());
    let mut direct_seconds = 0.0;
    let to_sun = prepared.to_sun;
    for &sun in suns {
        let t = Instant::now();
        let light = prepared.per_sun_light(sun, &direct.lb, direct.forest.as_ref(), &Silent)?;
        direct_seconds += t.elapsed().as_secs_f64();
        prepared.set_sun(sun)?;
        let d = prepared.render_with(&light, settings, &Silent)?;
        tick();
        let r = prepared.render(settings, &Silent)?;
        tick();
        in_use.add(sun, pair_error(&r, &d, &plant));
        if both {
            prepared.use_uncompressed(true)?;
            let u = prepared.render(settings, &Silent);
            prepared.use_uncompressed(false)?;
            uncompressed.add(sun, pair_error(&u?, &d, &plant));
            tick();
        }
    }
    prepared.set_sun(to_sun)?;
    let n = plant.iter().filter(|&&p| p).count();
    Ok((
        in_use.finish(n, direct_seconds),
        both.then(|| uncompressed.finish(n, direct_seconds)),
    ))
}

impl fmt::Display for AgainstDirect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "against the light solved per sun ({} suns, {:.1} s of direct solves): image RMSE {:.5} (tone-mapped sRGB, [0, 1]); plant pixels ({}) relative RMSE {:.2} %, mean ratio {:.4}",
            self.per_sun.len(),
            self.direct_seconds,
            self.image_rmse,
            self.plant_pixels,
            100.0 * self.plant_rel_rmse,
            self.plant_ratio
        )?;
        let largest: Vec<String> = self
            .largest
            .iter()
            .map(|&k| {
                let s = &self.per_sun[k];
                format!(
                    "sun {k} (elevation {:.1}°, azimuth {:.1}°): {:.2} %, image {:.5}",
                    s.elevation_deg,
                    s.azimuth_deg,
                    100.0 * s.plant_rel_rmse,
                    s.image_rmse
                )
            })
            .collect();
        writeln!(f, "largest plant error: {}", largest.join("; "))
    }
}

impl fmt::Display for PhysicalRelightBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} (physical light) at {}x{}, 1 ray/pixel, {} gather rays, {} threads; {} suns over 90° about the zenith, forest grid {}; medians of {} runs per sun",
            self.scene,
            self.width,
            self.height,
            self.gather_rays,
            self.threads,
            self.suns,
            if self.forest_grid { "relit" } else { "off" },
            self.runs
        )?;
        writeln!(
            f,
            "relit frame (mean over the suns): {:.3} s with kd-tree shadows, {:.3} s with the sun grid (relighting itself {:.4} s)",
            self.frame_seconds_kd, self.frame_seconds_grid, self.relight_seconds
        )?;
        writeln!(
            f,
            "static frame (per-sun light, same run): {:.3} s; relit/static {:.2}",
            self.static_frame_seconds, self.ratio_to_static
        )?;
        writeln!(
            f,
            "base solutions: {} uncompressed (28 parts per model), {}{}; prepared in {:.1} s",
            format_bytes(self.basis_bytes),
            self.basis_seconds
                .map(|s| format!("{s:.1} s of solves"))
                .unwrap_or_else(|| "solve time not recorded".into()),
            self.forest_basis_seconds
                .map(|s| format!(", forest grid parts {s:.1} s"))
                .unwrap_or_default(),
            self.prepare_seconds
        )?;
        if let (Some(c), Some(sun), Some(diffuse)) = (
            self.compressed_bytes,
            self.compressed_sun_bytes,
            self.compressed_diffuse_bytes,
        ) {
            writeln!(
                f,
                "compressed ({}): {} ({:.1}×; sun parts {}, diffuse parts {})",
                self.codec,
                format_bytes(c),
                self.basis_bytes as f64 / c.max(1) as f64,
                format_bytes(sun),
                format_bytes(diffuse)
            )?;
        }
        if let (Some(r), Some(p)) = (self.rmse, self.plant_rel_rmse) {
            writeln!(
                f,
                "compressed vs uncompressed: image RMSE {r:.5} (tone-mapped sRGB, [0, 1]), plant relative RMSE {:.2} %",
                100.0 * p
            )?;
        }
        if let Some(a) = &self.against_direct {
            write!(f, "{a}")?;
        }
        if let Some(a) = &self.against_direct_uncompressed {
            write!(f, "uncompressed bases, {a}")?;
        }
        Ok(())
    }
}
