//! `sylva bench relight SCENE`: 004 Table 1 on this machine. The frame time over the 24
//! suns of `sylva relight` (relighting every instance and rendering, shadow rays through the
//! top-level kd-tree and through the sun-aligned grid, alternated), against the static frame
//! of paper 000 (one LB grid per model, solved for one sun) measured in the same run; the
//! base solutions' solve time; the compressed bytes; and the image RMSE between frames relit
//! from the compressed and from the uncompressed bases.

use std::time::Instant;

use anyhow::Result;
use sylva_core::colour::linear_to_srgb;
use sylva_lb::relight::BasisWeights;
use sylva_light::lighting::ModelLighting;
use sylva_light::relight::{sun_path, StoredBasis};
use sylva_light::{ModelGridLight, Silent};
use sylva_pipeline::ShadowMethod;
use sylva_render::{Frame, Mode, ToneMap};

use super::bench_scene::{median, peak_rss_bytes};
use super::progress::bar;
use super::render::{prepare, FrameArgs, PrepareRequest, Say};
use super::scene::emit;

#[derive(clap::Args, Debug)]
pub struct BenchRelightArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Sun positions over 90° about the zenith (004 Table 1: 24).
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub suns: u32,
    /// Timed passes over the sequence per shadow method (after one untimed pass); per sun the
    /// median, then the mean over the suns.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
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

pub fn run(a: BenchRelightArgs) -> Result<()> {
    let t_prepare = Instant::now();
    let p = prepare(
        &a.frame,
        PrepareRequest {
            need_lb: true,
            rays_per_pixel: Some(1),
            output_images: 1,
            say: Say::Stderr,
            force_basis: true,
            keep_raw: true,
            ..PrepareRequest::default()
        },
        None,
    )?;
    let prepare_seconds = t_prepare.elapsed().as_secs_f64();
    let mut prepared = p.scene;
    let (w, h) = (p.width, p.height);
    let camera = prepared.camera(w, h);
    let settings = prepared.settings(camera, 1, a.frame.seed);
    let suns = sun_path(a.suns as usize, prepared.scene.sun.azimuth_deg());
    let threads = rayon::current_num_threads();
    let relit = prepared.relit.as_ref().expect("forced base solutions");
    let sun_weights = relit.illumination().sun;
    let global = relit.global().map(|g| g.dims.to_string());

    // The bases: bytes, and the solve time (measured now, or recorded when cached).
    let mut compressed_bytes = 0u64;
    let mut raw_bytes = 0u64;
    for m in 0..prepared.scene.models.len() {
        if let Some(StoredBasis::Compressed(c)) = relit.model(m) {
            compressed_bytes += c.bytes();
            raw_bytes += sylva_lb::relight::BasisSet::memory_needed(c.dims);
        }
    }
    let reports = &p.basis;
    let basis_per_model: Vec<Option<f64>> = reports.iter().map(|r| r.solve_seconds).collect();
    let basis_seconds: Option<f64> = basis_per_model.iter().copied().sum();
    let basis_cached = reports
        .iter()
        .all(|r| r.source == sylva_light::lighting::LightingSource::Cached);

    // The static frame of paper 000: one grid per model for the scene's sun taken as the
    // model's own (exactly the direct solve's light: the exact combination of the
    // uncompressed bases), kd-tree shadows. Median of the runs after a warm-up.
    prepared.use_uncompressed(true)?;
    let to_sun = prepared.to_sun;
    let static_light = {
        let r = prepared.relit.as_ref().expect("relit");
        let grids: Vec<Option<ModelLighting>> = (0..prepared.scene.models.len())
            .map(|m| match r.model(m) {
                Some(StoredBasis::Full(b)) => {
                    let t = -to_sun;
                    let w = BasisWeights::exact([t.x as f64, t.y as f64, t.z as f64])?;
                    Ok(Some(ModelLighting::from_normalised(&b.relight(&w)?)))
                }
                _ => Ok(None),
            })
            .collect::<Result<_, sylva_lb::relight::RelightError>>()?;
        ModelGridLight::new(
            grids,
            &prepared.scene.models,
            prepared.tracer.cpu().accel.instances(),
        )
    };
    prepared.use_uncompressed(false)?;
    // Rendered at the scene's sun (the one its grids were made for), kd-tree shadows.
    let static_frame = |p: &sylva_pipeline::PreparedScene| -> Result<Frame> {
        Ok(p.renderer_with(&static_light).render(&settings, &|_| {})?)
    };
    let pb = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        bar(
            1 + (a.runs as u64 + 1) * (1 + 2 * suns.len() as u64) + 2 * suns.len() as u64,
            "bench relight",
        )
    };
    static_frame(&prepared)?;
    pb.inc(1);
    let mut static_runs = Vec::new();

    // Relit frames: per sun both shadow methods back to back (their order alternating), so
    // a pair sees the same load; the static frame once per pass.
    let methods = [ShadowMethod::KdTree, ShadowMethod::SunGrid];
    let mut times = vec![vec![Vec::new(); suns.len()]; 2];
    let mut relight_times = vec![Vec::new(); 2];
    let mut pair_ratios = Vec::new();
    for run in 0..=a.runs {
        prepared.set_sun(to_sun)?;
        let t = Instant::now();
        static_frame(&prepared)?;
        if run > 0 {
            static_runs.push(t.elapsed().as_secs_f64());
        }
        pb.inc(1);
        for (k, &sun) in suns.iter().enumerate() {
            let mut pair = [0.0; 2];
            for i in 0..2 {
                let mi = (i + k + run as usize) % 2;
                prepared.set_shadows(methods[mi]);
                let t0 = Instant::now();
                prepared.set_sun(sun)?;
                let t1 = Instant::now();
                prepared.render(&settings, &Silent)?;
                pair[mi] = t0.elapsed().as_secs_f64();
                if run > 0 {
                    times[mi][k].push(pair[mi]);
                    relight_times[mi].push((t1 - t0).as_secs_f64());
                }
                pb.inc(1);
            }
            if run > 0 {
                pair_ratios.push(pair[1] / pair[0]);
            }
        }
    }
    let frame_kd = mean_of_medians(&times[0]);
    let frame_grid = mean_of_medians(&times[1]);
    let static_seconds = median(static_runs);
    let chosen = a.frame.shadow_method();
    let frame_seconds = if chosen == ShadowMethod::KdTree {
        frame_kd
    } else {
        frame_grid
    };
    let relight_seconds = median(relight_times.concat());

    // Image RMSE, compressed against uncompressed bases, over the sequence: tone-mapped
    // sRGB in [0, 1] with the uncompressed frame's exposure (and linear, for reference).
    prepared.set_shadows(chosen);
    let tm = ToneMap::default();
    let (mut sq, mut sq_linear, mut n) = (0.0f64, 0.0f64, 0usize);
    let mut mean_linear = 0.0f64;
    // All compressed frames, then all uncompressed ones: switching the fields is cheap on
    // the CPU but re-uploads them to a GPU.
    let mut compressed = Vec::with_capacity(suns.len());
    for &sun in &suns {
        prepared.set_sun(sun)?;
        compressed.push(prepared.render(&settings, &Silent)?.compose(Mode::Full));
        pb.inc(1);
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
        pb.inc(1);
    }
    prepared.use_uncompressed(false)?;
    pb.finish_and_clear();
    let rmse = (sq / n as f64).sqrt();
    let rmse_linear = (sq_linear / n as f64).sqrt();
    mean_linear /= n as f64;

    let scene = &prepared.scene;
    let mut v = serde_json::json!({
        "scene": scene.name,
        "width": w,
        "height": h,
        "rays_per_pixel": 1,
        "suns": suns.len(),
        "runs": a.runs,
        "threads": threads,
        "sun_weights": sun_weights.name(),
        "global_grid": global,
        "shadows": chosen.name(),
        "frame_seconds": frame_seconds,
        "frame_seconds_kd": frame_kd,
        "frame_seconds_grid": frame_grid,
        "grid_over_kd": median(pair_ratios.clone()),
        "relight_seconds": relight_seconds,
        "static_frame_seconds": static_seconds,
        "ratio_to_static": frame_seconds / static_seconds,
        "basis_seconds": basis_seconds,
        "basis_seconds_per_model": basis_per_model,
        "basis_cached": basis_cached,
        "compressed_bytes": compressed_bytes,
        "raw_bytes": raw_bytes,
        "codec": a.frame.codec,
        "rmse": rmse,
        "rmse_space": "tone-mapped sRGB in [0, 1], the uncompressed frame's exposure",
        "rmse_linear": rmse_linear,
        "mean_linear": mean_linear,
        "prepare_seconds": prepare_seconds,
        "peak_rss_bytes": peak_rss_bytes(),
    });
    let o = v.as_object_mut().expect("object");
    o.insert("device".into(), prepared.tracer.device().into());
    if let Some(adapter) = prepared.tracer.adapter() {
        o.insert("adapter".into(), adapter.into());
    }
    // On a GPU the relit frame is one kernel (rays, shadow rays, the per-instance base
    // combinations); shadow rays go through the kd-trees there, so both methods agree.
    o.insert("gpu_shading".into(), prepared.gpu_frame.is_some().into());
    if let Some(f) = &prepared.gpu_frame {
        o.insert("gpu_shading_bytes".into(), f.device_bytes().into());
    }
    if a.json {
        return emit(&format!("{}\n", serde_json::to_string_pretty(&v)?));
    }
    let mut o = String::new();
    o += &format!(
        "{} at {w}x{h}, 1 ray/pixel, {threads} threads; {} suns over 90° about the zenith, {} weights, global grid {}; medians of {} runs per sun\n",
        scene.name,
        suns.len(),
        sun_weights.name(),
        global.as_deref().unwrap_or("off"),
        a.runs
    );
    o += &format!(
        "relit frame (mean over the suns): {frame_kd:.3} s with kd-tree shadows, {frame_grid:.3} s with the sun grid (median of paired grid/kd {:.3}; relighting itself {relight_seconds:.4} s)\n",
        median(pair_ratios.clone())
    );
    o += &format!(
        "static frame (paper 000, same run): {static_seconds:.3} s; relit/static {:.2}\n",
        frame_seconds / static_seconds
    );
    o += &format!(
        "base solutions: {} ({}); compressed {} of {} ({:.1}×)\n",
        basis_seconds
            .map(|s| format!("{s:.1} s of solves"))
            .unwrap_or_else(|| "solve time not recorded".into()),
        if basis_cached {
            "recorded in the cache"
        } else {
            "solved now"
        },
        sylva_core::format_bytes(compressed_bytes),
        sylva_core::format_bytes(raw_bytes),
        raw_bytes as f64 / compressed_bytes.max(1) as f64
    );
    o += &format!(
        "image RMSE compressed vs uncompressed: {rmse:.5} (tone-mapped sRGB, [0, 1]); linear {rmse_linear:.5} (mean {mean_linear:.4})\n"
    );
    emit(&o)
}
