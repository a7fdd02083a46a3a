//! The work queue: jobs `0..n` handed out on demand by rank 0, results gathered at rank 0.
//!
//! Rank 0 works on jobs too. A serving thread on rank 0 answers the other ranks' requests and
//! receives their results while its main thread takes jobs from the same counter; it polls
//! (backing off to 1 ms when idle) rather than blocking in a receive, which would spin a core
//! that rank 0's own work needs. Each worker keeps one request outstanding: it asks for its
//! next job as soon as it gets one, so the answer is there when the job is done. With MPI,
//! only one thread calls it at a time (the serving thread, while the main thread only works),
//! which MPI_THREAD_SERIALIZED allows.
//!
//! Any job's result is the same whichever rank runs it, so results never depend on the split;
//! a job's failure is returned on the rank that ran it, which must then abort the job
//! ([`Comm::abort`]): the other ranks are left waiting.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::comm::{Comm, CommError, Reader, Tag, Writer};
use crate::DistError;

const TAG_REQUEST: Tag = 1;
const TAG_JOB: Tag = 2;
const TAG_RESULT: Tag = 3;
/// The answer to a request when every job has been handed out.
const NO_JOB: u64 = u64::MAX;
/// The serving thread's longest sleep between polls when nothing arrives.
const MAX_IDLE: Duration = Duration::from_millis(1);

/// Test hook: `SYLVA_MPI_FAIL_RANK=R` makes rank R fail with an error as it enters the work
/// queue (while the other ranks wait for it), `SYLVA_MPI_FAIL_RANK=R:panic` with a panic:
/// the MPI tests check that the job then ends with the message instead of hanging. Not for
/// users.
pub const FAIL_RANK_ENV: &str = "SYLVA_MPI_FAIL_RANK";

/// Who ran one job, and how long it took there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JobDone {
    pub rank: usize,
    pub seconds: f64,
}

/// Every job's result (in job order) and who ran it: what rank 0 gets from [`run_queue`].
#[derive(Debug)]
pub struct QueueOutcome {
    pub results: Vec<Vec<u8>>,
    pub done: Vec<JobDone>,
}

impl QueueOutcome {
    /// Per rank: jobs run and their seconds.
    pub fn per_rank(&self, ranks: usize) -> Vec<(usize, f64)> {
        let mut out = vec![(0usize, 0f64); ranks];
        for d in &self.done {
            out[d.rank].0 += 1;
            out[d.rank].1 += d.seconds;
        }
        out
    }
}

/// A job's result and who ran it, once it has arrived.
type Slot = Option<(Vec<u8>, JobDone)>;

/// The failure [`FAIL_RANK_ENV`] asks of this rank: `Some(panic?)`.
fn injected_failure(rank: usize) -> Option<bool> {
    let v = std::env::var(FAIL_RANK_ENV).ok()?;
    let (r, how) = v.split_once(':').unwrap_or((&v, "error"));
    (r.trim().parse::<usize>().ok()? == rank).then_some(how == "panic")
}

fn fail_if_asked(rank: usize) -> Result<(), DistError> {
    match injected_failure(rank) {
        Some(true) => panic!("rank {rank}: panic injected by {FAIL_RANK_ENV} (a test hook)"),
        Some(false) => Err(DistError::Injected(format!(
            "rank {rank}: failure injected by {FAIL_RANK_ENV} (a test hook)"
        ))),
        None => Ok(()),
    }
}

/// Runs jobs `0..jobs` across the ranks of `comm` (every rank calls it with the same
/// `jobs`): `run(job)` computes a job's result on whichever rank gets it. Rank 0 gets
/// `Some` of every result, with `on_done(job)` called (from any thread) as each arrives;
/// the other ranks get `None`.
pub fn run_queue(
    comm: &dyn Comm,
    jobs: usize,
    run: &mut dyn FnMut(usize) -> Result<Vec<u8>, DistError>,
    on_done: &(dyn Fn(usize) + Sync),
) -> Result<Option<QueueOutcome>, DistError> {
    fail_if_asked(comm.rank())?;
    // Every queue starts together, with rank 0's job count: a rank done with the previous
    // queue could otherwise ask for work of this one while rank 0 still serves the previous
    // (whose server would take the request as its own and release the rank from this one).
    let mut count = (jobs as u64).to_le_bytes().to_vec();
    comm.broadcast(0, &mut count)?;
    if count != (jobs as u64).to_le_bytes() {
        return Err(CommError::Protocol(format!(
            "a work queue of {jobs} jobs on rank {}, of {} on rank 0",
            comm.rank(),
            Reader::new(&count, "job count").u64()?
        ))
        .into());
    }
    if comm.rank() != 0 {
        work(comm, run)?;
        return Ok(None);
    }
    let slots: Mutex<Vec<Slot>> = Mutex::new((0..jobs).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let store = |job: usize, result: Vec<u8>, done: JobDone| -> Result<(), CommError> {
        let mut s = slots.lock().expect("results");
        match s.get_mut(job) {
            Some(slot @ None) => *slot = Some((result, done)),
            _ => {
                return Err(CommError::Protocol(format!(
                    "result of job {job} of {jobs} from rank {}",
                    done.rank
                )))
            }
        }
        drop(s);
        on_done(job);
        Ok(())
    };
    std::thread::scope(|scope| -> Result<(), DistError> {
        let server =
            (comm.size() > 1).then(|| scope.spawn(|| serve(comm, jobs, &next, &stop, &store)));
        // Stops the serving thread if this one leaves early (an error, a panic).
        struct StopOnDrop<'a>(&'a AtomicBool, bool);
        impl Drop for StopOnDrop<'_> {
            fn drop(&mut self) {
                if self.1 {
                    self.0.store(true, Ordering::SeqCst);
                }
            }
        }
        let mut guard = StopOnDrop(&stop, true);
        loop {
            let job = next.fetch_add(1, Ordering::SeqCst);
            if job >= jobs || stop.load(Ordering::SeqCst) {
                break;
            }
            let t = Instant::now();
            let result = run(job)?;
            let done = JobDone {
                rank: 0,
                seconds: t.elapsed().as_secs_f64(),
            };
            store(job, result, done)?;
        }
        guard.1 = false;
        if let Some(server) = server {
            match server.join() {
                Ok(r) => r?,
                Err(panic) => std::panic::resume_unwind(panic),
            }
        }
        Ok(())
    })?;
    let mut outcome = QueueOutcome {
        results: Vec::with_capacity(jobs),
        done: Vec::with_capacity(jobs),
    };
    for (job, slot) in slots.into_inner().expect("results").into_iter().enumerate() {
        let (result, done) =
            slot.ok_or_else(|| CommError::Protocol(format!("job {job} of {jobs} has no result")))?;
        outcome.results.push(result);
        outcome.done.push(done);
    }
    Ok(Some(outcome))
}

/// Rank 0's serving thread: answers requests from the counter `next` and stores results,
/// until every other rank has been told there is no more work and has sent every result.
fn serve(
    comm: &dyn Comm,
    jobs: usize,
    next: &AtomicUsize,
    stop: &AtomicBool,
    store: &(dyn Fn(usize, Vec<u8>, JobDone) -> Result<(), CommError> + Sync),
) -> Result<(), DistError> {
    let workers = comm.size() - 1;
    let (mut released, mut outstanding) = (0usize, 0usize);
    let mut idle = Duration::from_micros(20);
    while released < workers || outstanding > 0 {
        if stop.load(Ordering::SeqCst) {
            return Ok(());
        }
        let Some((source, tag, data)) = comm.try_recv()? else {
            std::thread::sleep(idle);
            idle = (idle * 2).min(MAX_IDLE);
            continue;
        };
        idle = Duration::from_micros(20);
        match tag {
            TAG_REQUEST => {
                let job = next.fetch_add(1, Ordering::SeqCst);
                let answer = if job < jobs && !stop.load(Ordering::SeqCst) {
                    outstanding += 1;
                    job as u64
                } else {
                    released += 1;
                    NO_JOB
                };
                comm.send(source, TAG_JOB, answer.to_le_bytes().to_vec())?;
            }
            TAG_RESULT => {
                let mut r = Reader::new(&data, "job result");
                let job = r.u64()? as usize;
                let seconds = r.f64()?;
                let result = r.bytes()?.to_vec();
                r.end()?;
                outstanding = outstanding.checked_sub(1).ok_or_else(|| {
                    CommError::Protocol(format!("unrequested result of job {job}"))
                })?;
                store(
                    job,
                    result,
                    JobDone {
                        rank: source,
                        seconds,
                    },
                )?;
            }
            tag => {
                return Err(CommError::Protocol(format!(
                    "tag {tag} from rank {source} during the work queue"
                ))
                .into())
            }
        }
    }
    Ok(())
}

/// A worker rank: asks rank 0 for jobs (one request always ahead) until there are none.
fn work(
    comm: &dyn Comm,
    run: &mut dyn FnMut(usize) -> Result<Vec<u8>, DistError>,
) -> Result<(), DistError> {
    comm.send(0, TAG_REQUEST, Vec::new())?;
    loop {
        let (_, answer) = comm.recv(Some(0), TAG_JOB)?;
        let mut r = Reader::new(&answer, "job answer");
        let job = r.u64()?;
        r.end()?;
        if job == NO_JOB {
            break;
        }
        comm.send(0, TAG_REQUEST, Vec::new())?;
        let t = Instant::now();
        let result = run(job as usize)?;
        let mut w = Writer::default();
        w.u64(job).f64(t.elapsed().as_secs_f64()).bytes(&result);
        drop(result);
        comm.send(0, TAG_RESULT, w.0)?;
    }
    comm.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comm::LocalComm;

    /// Runs `jobs` jobs on `ranks` thread ranks; each job's result is its number squared,
    /// in bytes, after a delay that varies with the job.
    fn squares(ranks: usize, jobs: usize) -> QueueOutcome {
        let group = LocalComm::group(ranks);
        let done = AtomicUsize::new(0);
        let outcomes: Vec<Option<QueueOutcome>> = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    let done = &done;
                    s.spawn(move || {
                        let mut run = |j: usize| {
                            std::thread::sleep(Duration::from_micros(((j * 7) % 5) as u64 * 300));
                            Ok(((j * j) as u64).to_le_bytes().to_vec())
                        };
                        run_queue(c, jobs, &mut run, &|_| {
                            done.fetch_add(1, Ordering::SeqCst);
                        })
                        .unwrap()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(done.load(Ordering::SeqCst), jobs, "on_done once per job");
        let mut it = outcomes.into_iter();
        let root = it.next().unwrap().expect("rank 0 gets the results");
        assert!(it.all(|o| o.is_none()));
        root
    }

    #[test]
    fn every_job_runs_once_and_results_come_back_in_job_order() {
        for (ranks, jobs) in [(1, 5), (2, 40), (3, 40), (3, 1), (4, 0)] {
            let o = squares(ranks, jobs);
            assert_eq!(o.results.len(), jobs);
            for (j, r) in o.results.iter().enumerate() {
                assert_eq!(r, &((j * j) as u64).to_le_bytes(), "job {j}");
            }
            let per_rank = o.per_rank(ranks);
            assert_eq!(per_rank.iter().map(|p| p.0).sum::<usize>(), jobs);
            if ranks > 1 && jobs >= 40 {
                // On demand: every rank takes part.
                assert!(per_rank.iter().all(|p| p.0 > 0), "{per_rank:?}");
            }
        }
    }

    /// Queues one after the other with nothing between them (the pipeline's per-model rounds):
    /// a rank done with one queue must not be released from the next by the first's server.
    #[test]
    fn back_to_back_queues_each_run_every_job() {
        let group = LocalComm::group(3);
        let rounds: Vec<Vec<Option<usize>>> = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    s.spawn(move || {
                        (0..20)
                            .map(|round| {
                                let jobs = 10 + round % 3;
                                // Ranks 0 and 2 slow: rank 1 is done with a queue while
                                // rank 0 still serves it.
                                let mut job = |j: usize| {
                                    if c.rank() != 1 {
                                        std::thread::sleep(std::time::Duration::from_millis(1));
                                    }
                                    Ok(vec![j as u8])
                                };
                                run_queue(c, jobs, &mut job, &|_| {})
                                    .unwrap()
                                    .map(|o| o.results.len())
                            })
                            .collect()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let want: Vec<Option<usize>> = (0..20).map(|round| Some(10 + round % 3)).collect();
        assert_eq!(rounds[0], want);
        assert!(rounds[1..].iter().flatten().all(Option::is_none));
    }

    #[test]
    fn ranks_with_different_job_counts_are_refused() {
        let group = LocalComm::group(2);
        std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    s.spawn(move || {
                        let r = run_queue(c, 3 + c.rank(), &mut |_| Ok(Vec::new()), &|_| {});
                        match (c.rank(), r) {
                            (1, Err(e)) => {
                                let e = e.to_string();
                                assert!(e.contains("4 jobs on rank 1, of 3 on rank 0"), "{e}");
                                c.abort(1)
                            }
                            // Rank 0 waits for rank 1's requests until the abort.
                            (0, Err(DistError::Comm(CommError::Aborted))) => {}
                            (rank, r) => panic!("rank {rank}: {:?}", r.map(|_| ())),
                        }
                    })
                })
                .collect();
            let joined: Vec<bool> = handles.into_iter().map(|h| h.join().is_ok()).collect();
            assert_eq!(joined, [true, false], "rank 1 aborted, rank 0 was released");
        });
    }

    #[test]
    fn a_failing_job_is_returned_on_its_rank_and_abort_releases_the_others() {
        let group = LocalComm::group(3);
        std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    s.spawn(move || {
                        let mut run = |j: usize| {
                            if c.rank() == 1 {
                                return Err(DistError::Injected(format!("job {j} failed")));
                            }
                            std::thread::sleep(Duration::from_millis(2));
                            Ok(vec![])
                        };
                        let r = run_queue(c, 50, &mut run, &|_| {});
                        if let Err(e) = &r {
                            if !matches!(e, DistError::Comm(CommError::Aborted)) {
                                c.abort(1);
                            }
                        }
                        r.map(|_| ())
                    })
                })
                .collect();
            let results: Vec<_> = handles.into_iter().map(|h| h.join()).collect();
            assert!(results[1].is_err(), "the failing rank aborts (panics here)");
            for r in [&results[0], &results[2]] {
                match r {
                    Ok(Err(DistError::Comm(CommError::Aborted))) => {}
                    Ok(Ok(())) => {} // finished before the abort
                    other => panic!("{other:?}"),
                }
            }
        });
    }
}
