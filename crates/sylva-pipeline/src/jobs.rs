//! The pipeline's work as jobs of a [`Runner`]: the models' LB light, the forest's light parts,
//! relighting's bases and a frame's units are planned as jobs `0..n` on every process, run
//! by the runner (this process: [`sylva_core::jobs::Local`]; under MPI the work queue,
//! `sylva_mpi::QueueRunner`), assembled at the root, which owns the cache, and shared from
//! there ([`sylva_core::jobs::from_root`]). One code path, whatever runs it.

use std::error::Error;

use sylva_core::jobs::{from_root, JobError, JobResult, Runner};
use sylva_core::wire::Reader;
use sylva_light::Progress;

use crate::PipelineError;

/// Runs `jobs` through `runner`. A job that fails on this process keeps its own error (a
/// model's lighting error, a memory error), not only its message; one that failed on another
/// carries the whole chain of its message.
pub(crate) fn run_jobs(
    runner: &dyn Runner,
    jobs: usize,
    work: &mut dyn FnMut(usize) -> Result<Vec<u8>, PipelineError>,
    on_done: &(dyn Fn(usize) + Sync),
) -> Result<Option<Vec<JobResult>>, PipelineError> {
    let mut failed = None;
    let outcome = runner.run(
        jobs,
        &mut |j| {
            work(j).map_err(|e| {
                let message = chain(&e);
                failed = Some(e);
                JobError::Job(message)
            })
        },
        on_done,
    );
    match outcome {
        Ok(results) => Ok(results),
        Err(e) => Err(failed.take().unwrap_or(PipelineError::Jobs(e))),
    }
}

/// [`run_jobs`] with one bar `label` at the root when several processes share the jobs, a
/// unit per job (in one process each job reports its own progress).
pub(crate) fn run_jobs_with_bar(
    runner: &dyn Runner,
    label: &str,
    jobs: usize,
    work: &mut dyn FnMut(usize) -> Result<Vec<u8>, PipelineError>,
    progress: &dyn Progress,
) -> Result<Option<Vec<JobResult>>, PipelineError> {
    let several = runner.processes() > 1;
    let bar = several && runner.is_root() && jobs > 0;
    if bar {
        progress.start(label, jobs as u64);
    }
    let outcome = run_jobs(runner, jobs, work, &|_| {
        if several {
            progress.advance(1)
        }
    });
    if bar {
        progress.finish();
    }
    outcome
}

/// `e` and its causes, one after the other.
pub(crate) fn chain(e: &dyn Error) -> String {
    let mut message = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let cause = s.to_string();
        if !message.contains(&cause) {
            message = format!("{message}: {cause}");
        }
        source = s.source();
    }
    message
}

/// The root's count of `what` on every process (what every process reports).
pub(crate) fn root_count(
    runner: &dyn Runner,
    what: &'static str,
    count: usize,
) -> Result<usize, PipelineError> {
    from_root(
        runner,
        what,
        || Ok::<_, PipelineError>(count),
        |&n| (n as u64).to_le_bytes().to_vec(),
        |data| {
            let mut r = Reader::new(data, what);
            let n = r.u64()?;
            r.end()?;
            Ok(n as usize)
        },
    )
}
