//! `sylva bench relight SCENE`: 004 Table 1 on this machine (`sylva_pipeline::bench`): relit
//! frame times over a sequence of suns against the static frame; for the paper light
//! (`--light paper`) also the base solutions' cost and the image error of their compression.

use std::time::Instant;

use anyhow::Result;
use sylva_pipeline::bench::{self, RelightBenchPlan};

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
    };
    let pb = bench_bar(a.json, plan.frames() as usize, "bench relight");
    if p.scene.physical.is_some() {
        let mut report = bench::relight_physical(&mut p.scene, plan, &|| pb.inc(1))?;
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
