//! `sylva bench relight SCENE`: 004 Table 1 on this machine (`sylva_pipeline::bench`): relit
//! frame times over a sequence of suns against the static frame, the base solutions' cost and
//! the image error of their compression; on the physical light (the default) also against the
//! light solved per sun (`--against-direct`).

use std::time::Instant;

use anyhow::Result;
use sylva_light::Light;
use sylva_pipeline::bench::{self, RelightBenchPlan};
use sylva_pipeline::{LbPlan, LightSettings};

use super::output::{bench_bar, emit_report};
use super::render::{prepare, FrameArgs, PrepareRequest, Say};

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
    /// Physical light: also render every sun's frame with the light solved for that sun (LB
    /// solves, cached) and report the relit frames' error against them: image RMSE
    /// (tone-mapped sRGB) and plant-pixel relative RMSE, per sun and overall.
    #[arg(long)]
    pub against_direct: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

impl BenchRelightArgs {
    /// Base solutions, the uncompressed ones kept for the RMSE.
    fn request(&self) -> PrepareRequest<'static> {
        PrepareRequest {
            need_lb: true,
            rays_per_pixel: Some(1),
            output_images: 1,
            say: Say::Stderr,
            force_basis: true,
            keep_raw: true,
            ..PrepareRequest::default()
        }
    }
}

pub fn run(a: BenchRelightArgs) -> Result<()> {
    let t_prepare = Instant::now();
    let mut p = prepare(&a.frame, a.request(), &sylva_pipeline::Local)?;
    let prepare_seconds = t_prepare.elapsed().as_secs_f64();
    let plan = RelightBenchPlan {
        suns: a.suns as usize,
        runs: a.runs,
        shadows: a.frame.shadow_method(),
        size: (p.width, p.height),
        seed: a.frame.view.seed,
        against_direct: a.against_direct,
    };
    if a.against_direct && p.scene.physical.is_none() {
        anyhow::bail!(
            "--against-direct measures the physical light (the default); the paper light's \
             bench measures its compression"
        );
    }
    let pb = bench_bar(a.json, plan.frames() as usize, "bench relight");
    if p.scene.physical.is_some() {
        let solver = p.solver.as_deref().expect("bench relight lights with LB");
        let direct = bench::DirectSolve {
            lb: LbPlan {
                solver,
                grid: a.frame.lb.lb_grid,
                cache_dir: (!a.frame.lb.no_cache).then_some(a.frame.lb.cache_dir.as_path()),
                light: Light::Physical,
            },
            forest: LightSettings::from(&a.frame).forest_grid(Light::Physical)?,
        };
        let mut report = bench::relight_physical(&mut p.scene, plan, Some(&direct), &|| pb.inc(1))?;
        pb.finish_and_clear();
        report.prepare_seconds = prepare_seconds;
        return emit_report(&report, a.json);
    }
    let mut report = bench::relight(&mut p.scene, &p.basis, plan, &|| pb.inc(1))?;
    pb.finish_and_clear();
    report.codec = a.frame.grid.codec.clone();
    report.prepare_seconds = prepare_seconds;
    emit_report(&report, a.json)
}
