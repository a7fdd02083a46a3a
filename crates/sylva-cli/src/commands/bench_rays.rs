//! `sylva bench rays SCENE`: the kd-tree alone on primary, shadow and incoherent rays of one
//! view, optionally exported for `tools/embree/compare.py`; the measuring is
//! `sylva_pipeline::bench::rays`'.

use std::path::PathBuf;

use anyhow::Result;
use sylva_pipeline::bench;
use sylva_pipeline::Runner;

use super::output::emit_report;
use super::render::{prepare, FrameArgs, PrepareRequest, Say};

#[derive(clap::Args, Debug)]
pub struct BenchRaysArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Timed passes over each ray set (after one untimed pass); medians reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Also write the scene, the rays and the kd-tree's answers to this directory (created)
    /// for `tools/embree/compare.py DIR`.
    #[arg(long, value_name = "DIR")]
    pub export: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: BenchRaysArgs, runner: &dyn Runner) -> Result<()> {
    let request = PrepareRequest {
        need_lb: false,
        output_images: 0,
        say: Say::Stderr,
        ..PrepareRequest::default()
    };
    let prepared = prepare(&a.frame, request, runner)?;
    let camera = prepared.scene.camera(prepared.width, prepared.height);
    let report = bench::rays(
        &prepared.scene,
        camera,
        a.frame.view.seed,
        a.runs,
        a.export.as_deref(),
    )?;
    emit_report(&report, a.json)
}
