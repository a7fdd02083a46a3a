//! Where independent jobs run: this process ([`Local`]), or the processes of a distributed
//! job (`sylva_mpi::QueueRunner`, the work queue over MPI). The pipeline plans its
//! precomputation and frames as jobs `0..n`, a [`Runner`] runs them, and the pipeline
//! assembles the results at the root, so one process and many give the same bytes.
//!
//! The contract: every process calls the same methods in the same order with the same
//! arguments (checked where cheap, [`Runner::agree`]), and a job's result depends only on the
//! job, never on which process or how many threads ran it.

use std::time::Instant;

/// Why a job or the runner failed. A job's own error is carried as its message (the caller
/// knows what the job was); the transport's as its own.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    /// A job failed on the process that ran it.
    #[error("{0}")]
    Job(String),
    /// The processes were started with different inputs.
    #[error("processes disagree: {0}")]
    Disagree(String),
    /// The transport between processes failed, or another process ended the run.
    #[error("{0}")]
    Transport(String),
}

impl From<crate::wire::WireError> for JobError {
    fn from(e: crate::wire::WireError) -> JobError {
        JobError::Transport(e.0)
    }
}

/// One job's result as the root receives it: the bytes, which process ran it and how long
/// it took there.
#[derive(Debug, Clone, PartialEq)]
pub struct JobResult {
    pub bytes: Vec<u8>,
    pub process: usize,
    pub seconds: f64,
}

/// What a job computes on the process that takes it: its result as bytes.
pub type JobWork<'a> = dyn FnMut(usize) -> Result<Vec<u8>, JobError> + 'a;

/// Runs independent jobs and shares data from the root (process 0, which owns caches,
/// progress and outputs) with the other processes.
pub trait Runner: Sync {
    /// This process, `0..processes()`; 0 is the root.
    fn index(&self) -> usize;

    /// How many processes take part.
    fn processes(&self) -> usize;

    /// Whether this process is the root.
    fn is_root(&self) -> bool {
        self.index() == 0
    }

    /// Runs jobs `0..jobs`, `work(j)` on whichever process takes job `j` (a process runs
    /// its jobs one at a time, in increasing order, so `work` may keep what consecutive
    /// jobs share). The root gets `Some` of every result in job order, with `on_done(j)`
    /// called (from any thread) as each arrives; the other processes get `None`.
    fn run(
        &self,
        jobs: usize,
        work: &mut JobWork<'_>,
        on_done: &(dyn Fn(usize) + Sync),
    ) -> Result<Option<Vec<JobResult>>, JobError>;

    /// The root's `data` on every process.
    fn share(&self, data: &mut Vec<u8>) -> Result<(), JobError>;

    /// Fails unless every process has the root's `value` of `what`.
    fn agree(&self, what: &str, value: &str) -> Result<(), JobError> {
        let mut data = value.as_bytes().to_vec();
        self.share(&mut data)?;
        let root = String::from_utf8_lossy(&data);
        if root != value {
            return Err(JobError::Disagree(format!(
                "process {} has {what} {value}, the root has {root}",
                self.index()
            )));
        }
        Ok(())
    }
}

/// Every job in this process, one after the other in job order (each job may use every
/// thread itself).
#[derive(Debug, Clone, Copy, Default)]
pub struct Local;

impl Runner for Local {
    fn index(&self) -> usize {
        0
    }

    fn processes(&self) -> usize {
        1
    }

    fn run(
        &self,
        jobs: usize,
        work: &mut JobWork<'_>,
        on_done: &(dyn Fn(usize) + Sync),
    ) -> Result<Option<Vec<JobResult>>, JobError> {
        let mut results = Vec::with_capacity(jobs);
        for j in 0..jobs {
            let t = Instant::now();
            let bytes = work(j)?;
            results.push(JobResult {
                bytes,
                process: 0,
                seconds: t.elapsed().as_secs_f64(),
            });
            on_done(j);
        }
        Ok(Some(results))
    }

    fn share(&self, _data: &mut Vec<u8>) -> Result<(), JobError> {
        Ok(())
    }
}

/// The root's `value()` on every process: computed at the root, then encoded, shared and
/// decoded on the others (in one process, just computed). A failure at the root reaches the
/// others as [`JobError::Job`] naming `what`, so none is left waiting for data that will not
/// come.
pub fn from_root<T, E>(
    runner: &dyn Runner,
    what: &str,
    value: impl FnOnce() -> Result<T, E>,
    encode: impl FnOnce(&T) -> Vec<u8>,
    decode: impl FnOnce(&[u8]) -> Result<T, E>,
) -> Result<T, E>
where
    E: From<JobError> + std::fmt::Display,
{
    if runner.processes() == 1 {
        return value();
    }
    if runner.is_root() {
        let value = value();
        let mut data = match &value {
            Ok(v) => [&[1u8][..], &encode(v)].concat(),
            Err(e) => [&[0u8][..], e.to_string().as_bytes()].concat(),
        };
        runner.share(&mut data)?;
        return value;
    }
    let mut data = Vec::new();
    runner.share(&mut data)?;
    match data.split_first() {
        Some((1, rest)) => decode(rest),
        Some((0, message)) => Err(JobError::Job(format!(
            "the root process failed making {what}: {}",
            String::from_utf8_lossy(message)
        ))
        .into()),
        _ => Err(JobError::Transport(format!("{what}: an empty message from the root")).into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn local_runs_every_job_in_order_and_reports_each() {
        let done = AtomicUsize::new(0);
        let mut seen = Vec::new();
        let results = Local
            .run(
                4,
                &mut |j| {
                    seen.push(j);
                    Ok(vec![j as u8; j])
                },
                &|_| {
                    done.fetch_add(1, Ordering::SeqCst);
                },
            )
            .unwrap()
            .unwrap();
        assert_eq!(seen, [0, 1, 2, 3]);
        assert_eq!(done.load(Ordering::SeqCst), 4);
        let bytes: Vec<_> = results.iter().map(|r| r.bytes.clone()).collect();
        assert_eq!(bytes, [vec![], vec![1], vec![2, 2], vec![3, 3, 3]]);
    }

    #[test]
    fn a_failing_job_stops_the_run_with_its_message() {
        let mut ran = 0;
        let err = Local
            .run(
                5,
                &mut |j| {
                    ran += 1;
                    if j == 2 {
                        Err(JobError::Job("model 'rose': no leaves".into()))
                    } else {
                        Ok(Vec::new())
                    }
                },
                &|_| {},
            )
            .unwrap_err();
        assert_eq!(ran, 3);
        assert_eq!(err.to_string(), "model 'rose': no leaves");
    }

    #[test]
    fn from_root_in_one_process_is_the_value_itself() {
        let got: Result<u32, JobError> = from_root(
            &Local,
            "a count",
            || Ok(3),
            |_| panic!("nothing is encoded in one process"),
            |_| panic!("nothing is decoded in one process"),
        );
        assert_eq!(got.unwrap(), 3);
    }
}
