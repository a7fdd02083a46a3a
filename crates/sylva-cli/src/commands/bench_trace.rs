//! `sylva bench trace SCENE`: acceleration build time and frame time (primary rays, shadow
//! rays, shading) at 1 and 4 rays per pixel, with LB lighting from the cache.

use anyhow::Result;
use sylva_render::{stage, FrameTimings, Silent, StageClock};

use super::bench_scene::{median, peak_rss_bytes};
use super::render::{prepare, FrameArgs};
use super::scene::emit;

#[derive(clap::Args, Debug)]
pub struct BenchTraceArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Timed frames per rays-per-pixel setting (after one untimed warm-up); medians reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Without LB lighting (local light only): no precompute on a cold cache.
    #[arg(long)]
    pub no_lb: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Medians over runs of one rays-per-pixel setting.
struct Measured {
    rpp: u32,
    frame: f64,
    primary: f64,
    shadow: f64,
    shading: f64,
    /// A GPU frame's single pass (rays and shading in one kernel).
    fused: f64,
    mrays: f64,
    /// Per pass, where passes are separate (CPU shading).
    primary_mrays: Option<f64>,
    shadow_mrays: Option<f64>,
    timings: FrameTimings,
    restarts: u64,
    occluder_cache_hits: u64,
}

impl Measured {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "rays_per_pixel": self.rpp,
            "frame_seconds": self.frame,
            "primary_seconds": self.primary,
            "shadow_seconds": self.shadow,
            "shading_seconds": self.shading,
            "gpu_frame_seconds": self.fused,
            "mrays_per_second": self.mrays,
            "primary_mrays_per_second": self.primary_mrays,
            "shadow_mrays_per_second": self.shadow_mrays,
            "primary_rays": self.timings.primary_rays,
            "shadow_rays": self.timings.shadow_rays,
            "restarts": self.restarts,
            "occluder_cache_hits": self.occluder_cache_hits,
        })
    }
}

pub fn run(a: BenchTraceArgs) -> Result<()> {
    let clock = StageClock::global();
    clock.reset();
    let prepared = prepare(&a.frame, !a.no_lb, Some(4), false)?;
    let (accel_seconds, lb_seconds) = (
        clock.seconds(stage::ACCEL_BUILD),
        clock.seconds(stage::LB_PRECOMPUTE),
    );
    let p = &prepared.scene;
    let camera = p.camera(prepared.width, prepared.height);
    let mut results = Vec::new();
    for rpp in [1u32, 4] {
        let settings = p.settings(camera, rpp, a.frame.seed);
        p.render(&settings, &Silent)?;
        let mut frames = Vec::new();
        for _ in 0..a.runs {
            frames.push(p.render(&settings, &Silent)?);
        }
        let med = |g: &dyn Fn(&FrameTimings) -> f64| {
            median(frames.iter().map(|f| g(&f.timings)).collect())
        };
        let t = frames[0].timings;
        let m = Measured {
            rpp,
            frame: med(&|t| t.frame_seconds()),
            primary: med(&|t| t.primary_seconds),
            shadow: med(&|t| t.shadow_seconds),
            shading: med(&|t| t.shading_seconds),
            fused: med(&|t| t.fused_seconds),
            mrays: med(&|t| t.mrays_per_second()),
            primary_mrays: (frames[0].timings.primary_seconds > 0.0)
                .then(|| med(&|t| t.primary_rays as f64 / t.primary_seconds * 1e-6)),
            shadow_mrays: (frames[0].timings.shadow_seconds > 0.0)
                .then(|| med(&|t| t.shadow_rays as f64 / t.shadow_seconds * 1e-6)),
            timings: t,
            restarts: frames[0].stats.restarts,
            occluder_cache_hits: frames[0].stats.occluder_cache_hits,
        };
        results.push(m);
    }
    let mem = p.tracer.cpu().accel.memory();
    let threads = rayon::current_num_threads();
    let one = &results[0];
    if a.json {
        let mut v = one.json();
        let o = v.as_object_mut().expect("object");
        o.insert("scene".into(), p.scene.name.clone().into());
        o.insert("width".into(), prepared.width.into());
        o.insert("height".into(), prepared.height.into());
        o.insert("threads".into(), threads.into());
        o.insert("runs".into(), a.runs.into());
        o.insert(
            "stack_size".into(),
            p.tracer.cpu().traversal.stack_size.into(),
        );
        o.insert("device".into(), p.tracer.device().into());
        if let Some(adapter) = p.tracer.adapter() {
            o.insert("adapter".into(), adapter.into());
        }
        if let Some(gpu) = p.tracer.gpu() {
            o.insert("gpu_scene_bytes".into(), gpu.scene().device_bytes().into());
            o.insert("cpu_answered_rays".into(), gpu.cpu_answered().into());
            o.insert("gpu_shading".into(), p.gpu_frame.is_some().into());
            if let Some(f) = &p.gpu_frame {
                o.insert("gpu_shading_bytes".into(), f.device_bytes().into());
                o.insert("cpu_rendered_pixels".into(), f.cpu_pixels().into());
            }
        }
        o.insert("lb".into(), (!a.no_lb).into());
        o.insert("accel_build_seconds".into(), accel_seconds.into());
        o.insert("lb_seconds".into(), lb_seconds.into());
        o.insert("lb_models_cached".into(), p.lb_models_cached.into());
        o.insert("rpp4".into(), results[1].json());
        o.insert(
            "memory".into(),
            serde_json::json!({
                "unique_models": p.scene.models.len(),
                "instances": p.scene.instances.len(),
                "instanced_triangles": p.scene.instanced_triangles(),
                "scene_bytes": p.scene.memory_bytes(),
                "kd_models_bytes": mem.models,
                "kd_top_bytes": mem.top,
                "lighting_bytes": p.lighting_bytes(),
                "peak_rss_bytes": peak_rss_bytes(),
            }),
        );
        return emit(&format!("{}\n", serde_json::to_string_pretty(&v)?));
    }
    let mut o = String::new();
    o += &format!(
        "{} at {}x{}, rays on {}, stack {}, LB {}; medians of {} runs\n",
        p.scene.name,
        prepared.width,
        prepared.height,
        p.tracer.describe(),
        p.tracer.cpu().traversal.stack_size,
        if a.no_lb { "off" } else { "on" },
        a.runs
    );
    o += &format!(
        "acceleration build {:.3} s; LB lighting {:.3} s ({} of {} models from the cache)\n",
        accel_seconds,
        lb_seconds,
        p.lb_models_cached,
        p.scene.models.len()
    );
    for m in &results {
        o += &match (m.primary_mrays, m.shadow_mrays) {
            (Some(p), Some(s)) => format!(
                "{} ray/pixel: frame {:.3} s (primary {:.3}, shadow {:.3}, shading {:.3}); {:.2} Mrays/s (primary {p:.2}, shadow {s:.2}); {} kd-restarts\n",
                m.rpp, m.frame, m.primary, m.shadow, m.shading, m.mrays, m.restarts
            ),
            _ => format!(
                "{} ray/pixel: frame {:.4} s (one GPU pass: rays, shadow rays and shading); {:.2} Mrays/s ({} primary + {} shadow rays)\n",
                m.rpp, m.frame, m.mrays, m.timings.primary_rays, m.timings.shadow_rays
            ),
        };
    }
    o += &format!(
        "memory: {} models ({} instances of {} triangles); scene {}, kd-trees {} + top {}, LB grids {}, peak RSS {}\n",
        p.scene.models.len(),
        p.scene.instances.len(),
        p.scene.instanced_triangles(),
        sylva_core::format_bytes(p.scene.memory_bytes()),
        sylva_core::format_bytes(mem.models),
        sylva_core::format_bytes(mem.top),
        sylva_core::format_bytes(p.lighting_bytes()),
        peak_rss_bytes().map(sylva_core::format_bytes).unwrap_or_else(|| "n/a".into()),
    );
    emit(&o)
}
