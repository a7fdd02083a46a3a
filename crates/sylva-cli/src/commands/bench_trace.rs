//! `sylva bench trace SCENE`: acceleration build time and frame time (primary rays, shadow
//! rays, shading) at 1 and 4 rays per pixel, with LB lighting from the cache.

use anyhow::Result;
use sylva_light::Silent;
use sylva_mpi::model::TileCosts;
use sylva_mpi::{Comm, DistributedFrame};
use sylva_render::{stage, Frame, FrameTimings, StageClock};

use super::bench_scene::{median, peak_rss_bytes};
use super::render::{prepare, FrameArgs, PrepareRequest, Say};
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
    /// Also time every 8×8 tile alone at 1 ray/pixel (median of --runs) and model the frame
    /// on 1-16 ranks: the paper's fixed strips against units on demand (000 Table 4).
    #[arg(long)]
    pub tile_costs: bool,
}

/// Untimed frames fill at least this long before the timed ones (a single process).
const WARM_UP_SECONDS: f64 = 1.0;

/// 000 Table 3 (1 G80) and Table 4 (2-16 G80s): beech at 896×448, 1 ray/pixel, seconds.
const PAPER_TABLE4: [(usize, f64); 5] =
    [(1, 2.277), (2, 1.162), (4, 0.666), (8, 0.351), (16, 0.170)];

/// Every tile of the frame rendered alone, `runs` times: the median seconds per tile.
fn tile_costs(
    p: &sylva_pipeline::PreparedScene,
    settings: &sylva_render::RenderSettings,
    runs: u32,
) -> Result<TileCosts> {
    let (w, h) = (settings.camera.width, settings.camera.height);
    let tile = sylva_render::render::TILE;
    let (columns, rows) = (w.div_ceil(tile), h.div_ceil(tile));
    let mut seconds = Vec::with_capacity((columns * rows) as usize);
    for row in 0..rows {
        for column in 0..columns {
            let (x0, y0) = (column * tile, row * tile);
            let region = sylva_render::Region {
                x0,
                y0,
                width: tile.min(w - x0),
                height: tile.min(h - y0),
            };
            let one = sylva_render::RenderSettings {
                region,
                ..*settings
            };
            let mut t = Vec::with_capacity(runs as usize);
            for _ in 0..runs {
                let s = std::time::Instant::now();
                p.render(&one, &Silent)?;
                t.push(s.elapsed().as_secs_f64());
            }
            seconds.push(median(t));
        }
    }
    Ok(TileCosts {
        columns,
        rows,
        seconds,
    })
}

/// The scaling model from measured tile costs, as JSON and text.
fn scaling_model(costs: &TileCosts) -> (serde_json::Value, String) {
    let total = costs.total();
    let mean = total / costs.seconds.len() as f64;
    let max = costs.seconds.iter().cloned().fold(0.0, f64::max);
    let mut rows = Vec::new();
    let mut text = format!(
        "tile costs: {} tiles, {:.3} s in all, mean {:.3} ms, max {:.1} × the mean\n  ranks  strips s (speedup)  on demand s (speedup)  paper s (speedup)\n",
        costs.seconds.len(),
        total,
        mean * 1e3,
        max / mean
    );
    for (ranks, paper) in PAPER_TABLE4 {
        let s = costs.split(ranks);
        let paper_speedup = PAPER_TABLE4[0].1 / paper;
        rows.push(serde_json::json!({
            "ranks": ranks,
            "strips_seconds": s.strips,
            "strips_speedup": total / s.strips,
            "on_demand_seconds": s.on_demand,
            "on_demand_speedup": total / s.on_demand,
            "paper_seconds": paper,
            "paper_speedup": paper_speedup,
        }));
        text += &format!(
            "  {ranks:>5}  {:>8.3} ({:>5.2})     {:>8.3} ({:>5.2})        {paper:>6.3} ({paper_speedup:>5.2})\n",
            s.strips,
            total / s.strips,
            s.on_demand,
            total / s.on_demand
        );
    }
    let json = serde_json::json!({
        "tiles": costs.seconds.len(),
        "columns": costs.columns,
        "rows": costs.rows,
        "total_seconds": total,
        "max_over_mean": max / mean,
        "row_seconds": (0..costs.rows)
            .map(|r| costs.seconds[(r * costs.columns) as usize..((r + 1) * costs.columns) as usize].iter().sum::<f64>())
            .collect::<Vec<f64>>(),
        "model": rows,
    });
    (json, text)
}

/// How the frames of one setting were split across MPI ranks: medians over the runs.
struct Split {
    ranks: usize,
    units: usize,
    unit_edge: u32,
    /// Per rank: busy seconds (median over runs) and units of the median run.
    rank_seconds: Vec<f64>,
    rank_units: Vec<usize>,
    imbalance: f64,
}

impl Split {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "ranks": self.ranks,
            "units": self.units,
            "unit_edge_tiles": self.unit_edge,
            "rank_seconds": self.rank_seconds,
            "rank_units": self.rank_units,
            "imbalance": self.imbalance,
        })
    }

    fn text(&self) -> String {
        let per: Vec<String> = self
            .rank_seconds
            .iter()
            .zip(&self.rank_units)
            .map(|(s, u)| format!("{s:.3} s ({u} units)"))
            .collect();
        format!(
            "  {} ranks, {} units of {}x{} tiles: {}; imbalance {:.1} %",
            self.ranks,
            self.units,
            self.unit_edge,
            self.unit_edge,
            per.join(", "),
            100.0 * self.imbalance
        )
    }
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
    /// Of `fused`, the kernel alone on the GPU's clock (0 without timestamps).
    kernel: f64,
    mrays: f64,
    /// Per pass, where passes are separate (CPU shading).
    primary_mrays: Option<f64>,
    shadow_mrays: Option<f64>,
    timings: FrameTimings,
    restarts: u64,
    occluder_cache_hits: u64,
    split: Option<Split>,
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
            "gpu_kernel_seconds": self.kernel,
            "mrays_per_second": self.mrays,
            "primary_mrays_per_second": self.primary_mrays,
            "shadow_mrays_per_second": self.shadow_mrays,
            "primary_rays": self.timings.primary_rays,
            "shadow_rays": self.timings.shadow_rays,
            "restarts": self.restarts,
            "occluder_cache_hits": self.occluder_cache_hits,
            "mpi": self.split.as_ref().map(Split::json),
        })
    }
}

pub fn run(a: BenchTraceArgs, comm: Option<&dyn Comm>) -> Result<()> {
    let clock = StageClock::global();
    clock.reset();
    let prepared = prepare(
        &a.frame,
        PrepareRequest {
            need_lb: !a.no_lb,
            rays_per_pixel: Some(4),
            output_images: 1,
            say: Say::Stderr,
            ..PrepareRequest::default()
        },
        comm,
    )?;
    let (accel_seconds, lb_seconds) = (
        clock.seconds(stage::ACCEL_BUILD),
        clock.seconds(stage::LB_PRECOMPUTE),
    );
    let p = &prepared.scene;
    let camera = p.camera(prepared.width, prepared.height);
    let mut results = Vec::new();
    for rpp in [1u32, 4] {
        let settings = p.settings(camera, rpp, a.frame.seed);
        // One frame: alone, or across the ranks (`None` on ranks other than 0).
        let frame = || -> Result<Option<(Frame, Option<DistributedFrame>)>> {
            Ok(match comm {
                None => Some((p.render(&settings, &Silent)?, None)),
                Some(c) => sylva_mpi::render_frame(c, p, &settings, &Silent)?
                    .map(|d| (d.frame.clone(), Some(d))),
            })
        };
        // Warm-up: one frame, and alone (not under MPI, where frames are collective) as many
        // as fill a second, so a GPU leaves its idle clocks before the timed frames.
        let warm = std::time::Instant::now();
        frame()?;
        while comm.is_none() && warm.elapsed().as_secs_f64() < WARM_UP_SECONDS {
            frame()?;
        }
        let mut frames = Vec::new();
        for _ in 0..a.runs {
            frames.extend(frame()?);
        }
        if frames.is_empty() {
            continue; // not rank 0
        }
        // Across ranks a frame's time is rank 0's wall time, split and gathering included.
        let frame_seconds = |f: &(Frame, Option<DistributedFrame>)| match &f.1 {
            Some(d) => d.wall_seconds,
            None => f.0.timings.frame_seconds(),
        };
        let med = |g: &dyn Fn(&FrameTimings) -> f64| {
            median(frames.iter().map(|f| g(&f.0.timings)).collect())
        };
        let split = frames[0].1.as_ref().map(|d0| {
            let ds: Vec<&DistributedFrame> = frames.iter().filter_map(|f| f.1.as_ref()).collect();
            let ranks = d0.ranks.len();
            let walls: Vec<f64> = ds.iter().map(|d| d.wall_seconds).collect();
            let mid = ds[median_index(&walls)];
            Split {
                ranks,
                units: d0.layout.units(),
                unit_edge: d0.layout.edge,
                rank_seconds: (0..ranks)
                    .map(|r| median(ds.iter().map(|d| d.ranks[r].seconds).collect()))
                    .collect(),
                rank_units: mid.ranks.iter().map(|w| w.units).collect(),
                imbalance: median(ds.iter().map(|d| d.imbalance()).collect()),
            }
        });
        let (f0, _) = &frames[0];
        let m = Measured {
            rpp,
            frame: median(frames.iter().map(frame_seconds).collect()),
            primary: med(&|t| t.primary_seconds),
            shadow: med(&|t| t.shadow_seconds),
            shading: med(&|t| t.shading_seconds),
            fused: med(&|t| t.fused_seconds),
            kernel: med(&|t| t.gpu_kernel_seconds),
            mrays: med(&|t| t.mrays_per_second()),
            primary_mrays: (f0.timings.primary_seconds > 0.0)
                .then(|| med(&|t| t.primary_rays as f64 / t.primary_seconds * 1e-6)),
            shadow_mrays: (f0.timings.shadow_seconds > 0.0)
                .then(|| med(&|t| t.shadow_rays as f64 / t.shadow_seconds * 1e-6)),
            timings: f0.timings,
            restarts: f0.stats.restarts,
            occluder_cache_hits: f0.stats.occluder_cache_hits,
            split,
        };
        results.push(m);
    }
    if results.is_empty() {
        return Ok(()); // rank 0 reports
    }
    let scaling = if a.tile_costs {
        if comm.is_some() {
            anyhow::bail!("--tile-costs times tiles in one process: run it without mpirun");
        }
        let costs = tile_costs(p, &p.settings(camera, 1, a.frame.seed), a.runs)?;
        Some(scaling_model(&costs))
    } else {
        None
    };
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
        o.insert("ranks".into(), comm.map_or(1, |c| c.size()).into());
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
        if let Some((json, _)) = &scaling {
            o.insert("tile_costs".into(), json.clone());
        }
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
        "{} at {}x{}, {}rays on {}, stack {}, LB {}; medians of {} runs\n",
        p.scene.name,
        prepared.width,
        prepared.height,
        comm.map(|c| format!("{} MPI ranks, ", c.size()))
            .unwrap_or_default(),
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
        if let Some(split) = &m.split {
            o += &split.text();
            o.push('\n');
        }
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
    if let Some((_, text)) = &scaling {
        o += text;
    }
    emit(&o)
}

/// The index of the median of `v` (the lower one of an even count).
fn median_index(v: &[f64]) -> usize {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    idx[(v.len() - 1) / 2]
}
