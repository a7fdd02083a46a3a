//! `sylva bench trace SCENE`: acceleration build time and frame time (primary rays, shadow
//! rays, shading) at 1 and 4 rays per pixel, with LB lighting from the cache; the measuring
//! is `sylva_pipeline::bench`'s.

use anyhow::Result;
use sylva_light::Silent;
use sylva_pipeline::bench::scaling::TileCosts;
use sylva_pipeline::bench::{self, RankSplit, ScalingModel, TimedFrame, TraceBench, TraceRun};
use sylva_pipeline::Runner;
use sylva_render::stage;

use super::output::emit;
use super::render::{prepare, FrameArgs, PrepareRequest, Say};

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

impl BenchTraceArgs {
    fn request(&self) -> PrepareRequest<'static> {
        PrepareRequest {
            need_lb: !self.no_lb,
            rays_per_pixel: Some(4),
            output_images: 1,
            say: Say::Stderr,
            ..PrepareRequest::default()
        }
    }
}

pub fn run(a: BenchTraceArgs, runner: &dyn Runner) -> Result<()> {
    let several = runner.processes() > 1;
    if a.tile_costs && several {
        anyhow::bail!("--tile-costs times tiles in one process: run it without mpirun");
    }
    let clock = super::stage_clock();
    clock.reset();
    let prepared = prepare(&a.frame, a.request(), runner)?;
    let run = TraceRun {
        runs: a.runs,
        mpi_ranks: several.then(|| runner.processes()),
        lb: !a.no_lb,
        accel_build_seconds: clock.seconds(stage::ACCEL_BUILD),
        lb_seconds: clock.seconds(stage::LB_PRECOMPUTE),
    };
    let p = &prepared.scene;
    let camera = p.camera(prepared.width, prepared.height);
    // One frame: alone, or across the ranks (`None` on ranks other than 0).
    let mut frame = |settings: &sylva_render::RenderSettings| -> Result<Option<TimedFrame>> {
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
        let settings = p.settings(camera, rpp, a.frame.view.seed);
        measures.extend(bench::measure_frames(
            &settings, a.runs, !several, &mut frame,
        )?);
    }
    let Ok(measures) = <[_; 2]>::try_from(measures) else {
        return Ok(()); // rank 0 reports
    };
    let scaling = match a.tile_costs {
        true => {
            let times = bench::tile_times(p, &p.settings(camera, 1, a.frame.view.seed), a.runs)?;
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
    let report = TraceBench::new(p, (prepared.width, prepared.height), measures, run, scaling);
    if a.json {
        return emit(&format!("{}\n", super::output::pretty_json(&report)?));
    }
    emit(&report.to_string())
}
