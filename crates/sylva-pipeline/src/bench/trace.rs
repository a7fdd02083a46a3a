//! `sylva bench trace`: frame times at 1 and 4 rays per pixel (primary rays, shadow rays,
//! shading; medians of timed runs after a warm-up), alone or across ranks, the memory, and
//! the per-tile costs behind the scaling model of 000 Table 4.

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::format_bytes;
use sylva_core::measure::{median, median_index, peak_rss_bytes};
use sylva_render::{Frame, RenderSettings};

use super::scaling::TileCosts;
use crate::{PipelineError, PreparedScene, Runner, Silent};

/// Untimed frames fill at least this long before the timed ones (a single process).
const WARM_UP_SECONDS: f64 = 1.0;

/// 000 Table 3 (1 G80) and Table 4 (2-16 G80s): beech at 896×448, 1 ray/pixel, seconds.
pub const PAPER_TABLE4: [(usize, f64); 5] =
    [(1, 2.277), (2, 1.162), (4, 0.666), (8, 0.351), (16, 0.170)];

/// How one frame was split across ranks (what the distributed renderer reports).
#[derive(Debug, Clone)]
pub struct RankSplit {
    /// Rank 0's wall time of the frame, split and gathering included.
    pub wall_seconds: f64,
    pub units: usize,
    pub unit_edge: u32,
    /// Per rank: busy seconds and units rendered.
    pub rank_seconds: Vec<f64>,
    pub rank_units: Vec<usize>,
    pub imbalance: f64,
}

/// A frame and, rendered across ranks, its split.
pub struct TimedFrame {
    pub frame: Frame,
    pub split: Option<RankSplit>,
}

/// How the frames of one setting were split across ranks: medians over the runs.
#[derive(Debug, Clone, Serialize)]
pub struct SplitSummary {
    pub ranks: usize,
    pub units: usize,
    pub unit_edge_tiles: u32,
    /// Per rank: busy seconds (median over runs), and units of the median run.
    pub rank_seconds: Vec<f64>,
    pub rank_units: Vec<usize>,
    pub imbalance: f64,
}

/// Medians over the runs of one rays-per-pixel setting.
#[derive(Debug, Clone, Serialize)]
pub struct FrameMeasure {
    pub rays_per_pixel: u32,
    pub frame_seconds: f64,
    pub primary_seconds: f64,
    pub shadow_seconds: f64,
    pub shading_seconds: f64,
    /// A GPU frame's single pass (rays and shading in one kernel).
    pub gpu_frame_seconds: f64,
    /// Of the GPU frame, the kernel alone on the GPU's clock (0 without timestamps).
    pub gpu_kernel_seconds: f64,
    pub mrays_per_second: f64,
    /// Per pass, where passes are separate (CPU shading).
    pub primary_mrays_per_second: Option<f64>,
    pub shadow_mrays_per_second: Option<f64>,
    pub primary_rays: u64,
    pub shadow_rays: u64,
    pub restarts: u64,
    pub occluder_cache_hits: u64,
    pub mpi: Option<SplitSummary>,
}

/// Seconds to render each tile of a frame alone, row by row (`columns × rows`).
#[derive(Debug, Clone)]
pub struct TileTimes {
    pub columns: u32,
    pub rows: u32,
    pub seconds: Vec<f64>,
}

/// One rank count of the scaling model.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingRow {
    pub ranks: usize,
    pub strips_seconds: f64,
    pub strips_speedup: f64,
    pub on_demand_seconds: f64,
    pub on_demand_speedup: f64,
    pub paper_seconds: f64,
    pub paper_speedup: f64,
}

/// A frame on 1-16 ranks modelled from its tile costs: the paper's fixed strips against
/// units on demand, beside 000 Table 4.
#[derive(Debug, Clone, Serialize)]
pub struct ScalingModel {
    pub tiles: usize,
    pub columns: u32,
    pub rows: u32,
    pub total_seconds: f64,
    pub max_over_mean: f64,
    pub row_seconds: Vec<f64>,
    pub model: Vec<ScalingRow>,
}

impl ScalingModel {
    /// The model of `costs`; `split(ranks)` is a frame's (strips, on demand) seconds on that
    /// many ranks (the distributed renderer's model of its split).
    pub fn new(costs: &TileTimes, split: impl Fn(usize) -> (f64, f64)) -> ScalingModel {
        let total: f64 = costs.seconds.iter().sum();
        let mean = total / costs.seconds.len() as f64;
        let max = costs.seconds.iter().cloned().fold(0.0, f64::max);
        let model = PAPER_TABLE4
            .iter()
            .map(|&(ranks, paper)| {
                let (strips, on_demand) = split(ranks);
                ScalingRow {
                    ranks,
                    strips_seconds: strips,
                    strips_speedup: total / strips,
                    on_demand_seconds: on_demand,
                    on_demand_speedup: total / on_demand,
                    paper_seconds: paper,
                    paper_speedup: PAPER_TABLE4[0].1 / paper,
                }
            })
            .collect();
        let columns = costs.columns as usize;
        ScalingModel {
            tiles: costs.seconds.len(),
            columns: costs.columns,
            rows: costs.rows,
            total_seconds: total,
            max_over_mean: max / mean,
            row_seconds: costs
                .seconds
                .chunks(columns.max(1))
                .map(|r| r.iter().sum())
                .collect(),
            model,
        }
    }
}

impl fmt::Display for ScalingModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mean = self.total_seconds / self.tiles as f64;
        writeln!(
            f,
            "tile costs: {} tiles, {:.3} s in all, mean {:.3} ms, max {:.1} × the mean\n  ranks  strips s (speedup)  on demand s (speedup)  paper s (speedup)",
            self.tiles,
            self.total_seconds,
            mean * 1e3,
            self.max_over_mean
        )?;
        for r in &self.model {
            writeln!(
                f,
                "  {:>5}  {:>8.3} ({:>5.2})     {:>8.3} ({:>5.2})        {:>6.3} ({:>5.2})",
                r.ranks,
                r.strips_seconds,
                r.strips_speedup,
                r.on_demand_seconds,
                r.on_demand_speedup,
                r.paper_seconds,
                r.paper_speedup
            )?;
        }
        Ok(())
    }
}

/// Every tile of the frame rendered alone, `runs` times: the median seconds per tile.
pub fn tile_times(
    p: &PreparedScene,
    settings: &RenderSettings,
    runs: u32,
) -> Result<TileTimes, PipelineError> {
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
            let one = RenderSettings {
                region,
                ..*settings
            };
            let mut t = Vec::with_capacity(runs as usize);
            for _ in 0..runs {
                let s = Instant::now();
                p.render(&one, &Silent)?;
                t.push(s.elapsed().as_secs_f64());
            }
            seconds.push(median(t));
        }
    }
    Ok(TileTimes {
        columns,
        rows,
        seconds,
    })
}

/// One rays-per-pixel setting: a warm-up (one frame, and alone as many as fill a second, so
/// a GPU leaves its idle clocks), then `runs` timed frames. `frame` renders one, alone or
/// across ranks (`None` on ranks other than 0, where the result is `None` too).
pub fn measure_frames<E>(
    settings: &RenderSettings,
    runs: u32,
    alone: bool,
    frame: &mut dyn FnMut(&RenderSettings) -> Result<Option<TimedFrame>, E>,
) -> Result<Option<FrameMeasure>, E> {
    let warm = Instant::now();
    frame(settings)?;
    while alone && warm.elapsed().as_secs_f64() < WARM_UP_SECONDS {
        frame(settings)?;
    }
    let mut frames = Vec::new();
    for _ in 0..runs {
        frames.extend(frame(settings)?);
    }
    let Some(f0) = frames.first() else {
        return Ok(None);
    };
    // Across ranks a frame's time is rank 0's wall time, split and gathering included.
    let frame_seconds = |f: &TimedFrame| match &f.split {
        Some(d) => d.wall_seconds,
        None => f.frame.timings.frame_seconds(),
    };
    let med = |g: &dyn Fn(&sylva_render::FrameTimings) -> f64| {
        median(frames.iter().map(|f| g(&f.frame.timings)).collect())
    };
    let mpi = f0.split.as_ref().map(|d0| {
        let ds: Vec<&RankSplit> = frames.iter().filter_map(|f| f.split.as_ref()).collect();
        let ranks = d0.rank_seconds.len();
        let walls: Vec<f64> = ds.iter().map(|d| d.wall_seconds).collect();
        let mid = ds[median_index(&walls)];
        SplitSummary {
            ranks,
            units: d0.units,
            unit_edge_tiles: d0.unit_edge,
            rank_seconds: (0..ranks)
                .map(|r| median(ds.iter().map(|d| d.rank_seconds[r]).collect()))
                .collect(),
            rank_units: mid.rank_units.clone(),
            imbalance: median(ds.iter().map(|d| d.imbalance).collect()),
        }
    });
    let t0 = &f0.frame.timings;
    Ok(Some(FrameMeasure {
        rays_per_pixel: settings.rays_per_pixel,
        frame_seconds: median(frames.iter().map(frame_seconds).collect()),
        primary_seconds: med(&|t| t.primary_seconds),
        shadow_seconds: med(&|t| t.shadow_seconds),
        shading_seconds: med(&|t| t.shading_seconds),
        gpu_frame_seconds: med(&|t| t.fused_seconds),
        gpu_kernel_seconds: med(&|t| t.gpu_kernel_seconds),
        mrays_per_second: med(&|t| t.mrays_per_second()),
        primary_mrays_per_second: (t0.primary_seconds > 0.0)
            .then(|| med(&|t| t.primary_rays as f64 / t.primary_seconds * 1e-6)),
        shadow_mrays_per_second: (t0.shadow_seconds > 0.0)
            .then(|| med(&|t| t.shadow_rays as f64 / t.shadow_seconds * 1e-6)),
        primary_rays: t0.primary_rays,
        shadow_rays: t0.shadow_rays,
        restarts: f0.frame.stats.restarts,
        occluder_cache_hits: f0.frame.stats.occluder_cache_hits,
        mpi,
    }))
}

/// What the scene holds in memory.
#[derive(Debug, Clone, Serialize)]
pub struct TraceMemory {
    pub unique_models: usize,
    pub instances: usize,
    pub instanced_triangles: u64,
    pub scene_bytes: u64,
    pub kd_models_bytes: u64,
    pub kd_top_bytes: u64,
    pub lighting_bytes: u64,
    pub peak_rss_bytes: Option<u64>,
}

/// `sylva bench trace`'s report: the 1 ray/pixel measure at the top level (as its JSON
/// has it), the 4 rays/pixel one under `rpp4`.
#[derive(Debug, Clone, Serialize)]
pub struct TraceBench {
    #[serde(flatten)]
    pub rpp1: FrameMeasure,
    pub rpp4: FrameMeasure,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    pub ranks: usize,
    pub runs: u32,
    pub stack_size: usize,
    pub device: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_scene_bytes: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_answered_rays: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_shading: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_shading_bytes: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_rendered_pixels: Option<u64>,
    pub lb: bool,
    pub accel_build_seconds: f64,
    pub lb_seconds: f64,
    pub lb_models_cached: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_costs: Option<ScalingModel>,
    pub memory: TraceMemory,
    /// The tracer in words (text only).
    #[serde(skip)]
    pub tracer: String,
    /// Run under MPI (text only).
    #[serde(skip)]
    pub mpi: bool,
}

/// How a trace benchmark ran, beside what it measured.
#[derive(Debug, Clone, Copy)]
pub struct TraceRun {
    /// Timed frames per setting.
    pub runs: u32,
    /// The ranks, under MPI.
    pub mpi_ranks: Option<usize>,
    /// Whether the scene has LB light.
    pub lb: bool,
    /// The pipeline's stage seconds: acceleration build and LB lighting.
    pub accel_build_seconds: f64,
    pub lb_seconds: f64,
}

impl TraceBench {
    /// The report of `p`'s two measures at `width × height`.
    pub fn new(
        p: &PreparedScene,
        (width, height): (u32, u32),
        [rpp1, rpp4]: [FrameMeasure; 2],
        run: TraceRun,
        tile_costs: Option<ScalingModel>,
    ) -> TraceBench {
        let mem = p.tracer.cpu().accel.memory();
        let gpu = p.tracer.gpu();
        let frame = p.gpu_frame.as_ref();
        TraceBench {
            rpp1,
            rpp4,
            scene: p.scene.name.clone(),
            width,
            height,
            threads: rayon::current_num_threads(),
            ranks: run.mpi_ranks.unwrap_or(1),
            runs: run.runs,
            stack_size: p.tracer.cpu().traversal.stack_size,
            device: p.tracer.device(),
            adapter: p.tracer.adapter(),
            gpu_scene_bytes: gpu.map(|g| g.scene().device_bytes()),
            cpu_answered_rays: gpu.map(|g| g.cpu_answered()),
            gpu_shading: gpu.map(|_| frame.is_some()),
            gpu_shading_bytes: gpu.and(frame).map(|f| f.device_bytes()),
            cpu_rendered_pixels: gpu.and(frame).map(|f| f.cpu_pixels()),
            lb: run.lb,
            accel_build_seconds: run.accel_build_seconds,
            lb_seconds: run.lb_seconds,
            lb_models_cached: p.lb_models_cached,
            tile_costs,
            memory: TraceMemory {
                unique_models: p.scene.models.len(),
                instances: p.scene.instances.len(),
                instanced_triangles: p.scene.instanced_triangles(),
                scene_bytes: p.scene.memory_bytes(),
                kd_models_bytes: mem.models,
                kd_top_bytes: mem.top,
                lighting_bytes: p.lighting_bytes(),
                peak_rss_bytes: peak_rss_bytes(),
            },
            tracer: p.tracer.describe(),
            mpi: run.mpi_ranks.is_some(),
        }
    }
}

impl fmt::Display for TraceBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} at {}x{}, {}rays on {}, stack {}, LB {}; medians of {} runs",
            self.scene,
            self.width,
            self.height,
            if self.mpi {
                format!("{} MPI ranks, ", self.ranks)
            } else {
                String::new()
            },
            self.tracer,
            self.stack_size,
            if self.lb { "on" } else { "off" },
            self.runs
        )?;
        writeln!(
            f,
            "acceleration build {:.3} s; LB lighting {:.3} s ({} of {} models from the cache)",
            self.accel_build_seconds,
            self.lb_seconds,
            self.lb_models_cached,
            self.memory.unique_models
        )?;
        for m in [&self.rpp1, &self.rpp4] {
            match (m.primary_mrays_per_second, m.shadow_mrays_per_second) {
                (Some(p), Some(s)) => writeln!(
                    f,
                    "{} ray/pixel: frame {:.3} s (primary {:.3}, shadow {:.3}, shading {:.3}); {:.2} Mrays/s (primary {p:.2}, shadow {s:.2}); {} kd-restarts",
                    m.rays_per_pixel, m.frame_seconds, m.primary_seconds, m.shadow_seconds, m.shading_seconds, m.mrays_per_second, m.restarts
                )?,
                _ => writeln!(
                    f,
                    "{} ray/pixel: frame {:.4} s (one GPU pass: rays, shadow rays and shading); {:.2} Mrays/s ({} primary + {} shadow rays)",
                    m.rays_per_pixel, m.frame_seconds, m.mrays_per_second, m.primary_rays, m.shadow_rays
                )?,
            }
            if let Some(s) = &m.mpi {
                let per: Vec<String> = s
                    .rank_seconds
                    .iter()
                    .zip(&s.rank_units)
                    .map(|(s, u)| format!("{s:.3} s ({u} units)"))
                    .collect();
                writeln!(
                    f,
                    "  {} ranks, {} units of {}x{} tiles: {}; imbalance {:.1} %",
                    s.ranks,
                    s.units,
                    s.unit_edge_tiles,
                    s.unit_edge_tiles,
                    per.join(", "),
                    100.0 * s.imbalance
                )?;
            }
        }
        let m = &self.memory;
        writeln!(
            f,
            "memory: {} models ({} instances of {} triangles); scene {}, kd-trees {} + top {}, LB grids {}, peak RSS {}",
            m.unique_models,
            m.instances,
            m.instanced_triangles,
            format_bytes(m.scene_bytes),
            format_bytes(m.kd_models_bytes),
            format_bytes(m.kd_top_bytes),
            format_bytes(m.lighting_bytes),
            m.peak_rss_bytes.map(format_bytes).unwrap_or_else(|| "n/a".into()),
        )?;
        if let Some(s) = &self.tile_costs {
            write!(f, "{s}")?;
        }
        Ok(())
    }
}
/// `sylva bench trace` on a prepared scene at `width × height`: frames at 1 and 4 rays per
/// pixel (`run.runs` timed each after a warm-up), alone or split across the processes of
/// `runner`, and with `tile_costs` every tile timed alone for the scaling model of 000 Table
/// 4 (one process). `None` on processes other than the root, which reports.
pub fn trace(
    p: &PreparedScene,
    (width, height): (u32, u32),
    seed: u64,
    run: TraceRun,
    runner: &dyn Runner,
    tile_costs: bool,
) -> Result<Option<TraceBench>, PipelineError> {
    let several = runner.processes() > 1;
    let camera = p.camera(width, height);
    // One frame: alone, or across the ranks (`None` on ranks other than 0).
    let mut frame = |settings: &RenderSettings| -> Result<Option<TimedFrame>, PipelineError> {
        Ok(p.render_split(runner, settings, &Silent)?
            .map(|d| TimedFrame {
                split: several.then(|| RankSplit {
                    wall_seconds: d.wall_seconds,
                    units: d.layout.units(),
                    unit_edge: d.layout.edge,
                    rank_seconds: d.ranks.iter().map(|w| w.seconds).collect(),
                    rank_units: d.ranks.iter().map(|w| w.units).collect(),
                    imbalance: d.imbalance(),
                }),
                frame: d.frame,
            }))
    };
    let mut measures = Vec::new();
    for rpp in [1u32, 4] {
        let settings = p.settings(camera, rpp, seed);
        measures.extend(measure_frames(&settings, run.runs, !several, &mut frame)?);
    }
    let Ok(measures) = <[_; 2]>::try_from(measures) else {
        return Ok(None);
    };
    let scaling = match tile_costs {
        true => {
            let times = tile_times(p, &p.settings(camera, 1, seed), run.runs)?;
            let costs = TileCosts {
                columns: times.columns,
                rows: times.rows,
                seconds: times.seconds.clone(),
            };
            Some(ScalingModel::new(&times, |ranks| {
                let s = costs.split(ranks);
                (s.strips, s.on_demand)
            }))
        }
        false => None,
    };
    Ok(Some(TraceBench::new(
        p,
        (width, height),
        measures,
        run,
        scaling,
    )))
}
