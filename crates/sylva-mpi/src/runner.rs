//! The pipeline's [`Runner`] over a [`Comm`]: jobs through the work queue (handed out on
//! demand by rank 0, which works too), the root's data broadcast to every rank.

use sylva_core::jobs::{JobError, JobResult, JobWork, Runner};

use crate::comm::Comm;
use crate::queue::run_queue;
use crate::DistError;

/// The ranks of `comm` as one [`Runner`]: rank 0 is the root.
pub struct QueueRunner<'a> {
    comm: &'a dyn Comm,
}

impl<'a> QueueRunner<'a> {
    pub fn new(comm: &'a dyn Comm) -> QueueRunner<'a> {
        QueueRunner { comm }
    }

    pub fn comm(&self) -> &dyn Comm {
        self.comm
    }
}

fn job_error(e: DistError) -> JobError {
    match e {
        DistError::Job(e) => e,
        DistError::Disagree(d) => JobError::Disagree(d),
        e => JobError::Transport(e.to_string()),
    }
}

impl Runner for QueueRunner<'_> {
    fn index(&self) -> usize {
        self.comm.rank()
    }

    fn processes(&self) -> usize {
        self.comm.size()
    }

    fn run(
        &self,
        jobs: usize,
        work: &mut JobWork<'_>,
        on_done: &(dyn Fn(usize) + Sync),
    ) -> Result<Option<Vec<JobResult>>, JobError> {
        let outcome = run_queue(
            self.comm,
            jobs,
            &mut |j| work(j).map_err(DistError::Job),
            on_done,
        )
        .map_err(job_error)?;
        Ok(outcome.map(|o| {
            o.results
                .into_iter()
                .zip(o.done)
                .map(|(bytes, done)| JobResult {
                    bytes,
                    process: done.rank,
                    seconds: done.seconds,
                })
                .collect()
        }))
    }

    fn share(&self, data: &mut Vec<u8>) -> Result<(), JobError> {
        self.comm
            .broadcast(0, data)
            .map_err(|e| JobError::Transport(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LocalComm;
    use sylva_core::jobs::{from_root, Local};

    /// The same jobs through one process and through 3 ranks: the same results at the root.
    #[test]
    fn three_ranks_give_the_root_what_one_process_computes() {
        let square = |j: usize| Ok((j * j).to_le_bytes().to_vec());
        let want: Vec<Vec<u8>> = Local
            .run(20, &mut |j| square(j), &|_| {})
            .unwrap()
            .unwrap()
            .into_iter()
            .map(|r| r.bytes)
            .collect();
        let group = LocalComm::group(3);
        let got: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| s.spawn(move || QueueRunner::new(c).run(20, &mut |j| square(j), &|_| {})))
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap().unwrap())
                .collect()
        });
        let root: Vec<Vec<u8>> = got[0]
            .clone()
            .unwrap()
            .into_iter()
            .map(|r| r.bytes)
            .collect();
        assert_eq!(root, want);
        assert!(got[1].is_none() && got[2].is_none());
    }

    #[test]
    fn shared_data_and_disagreement() {
        let group = LocalComm::group(2);
        let out: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    s.spawn(move || {
                        let r = QueueRunner::new(c);
                        let mut data = if r.is_root() { vec![7, 8] } else { Vec::new() };
                        r.share(&mut data).unwrap();
                        // The root's value everywhere; a failure at the root reaches the others.
                        let count = |fail: bool| {
                            from_root(
                                &r,
                                "a count",
                                || match fail {
                                    true => Err(JobError::Job("no scene".into())),
                                    false => Ok(41 + r.index() as u64),
                                },
                                |v| v.to_le_bytes().to_vec(),
                                |d| Ok(u64::from_le_bytes(d.try_into().unwrap())),
                            )
                        };
                        let first = count(false).unwrap();
                        let failed = count(r.is_root()).map_err(|e| e.to_string());
                        let agree = r.agree("the scene", &format!("scene {}", r.index()));
                        (data, first, agree.map_err(|e| e.to_string()), failed)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(out[0].0, [7, 8]);
        assert_eq!(out[1].0, [7, 8]);
        assert_eq!((out[0].1, out[1].1), (41, 41));
        assert_eq!(out[0].3, Err("no scene".to_string()));
        assert_eq!(
            out[1].3,
            Err("the root process failed making a count: no scene".to_string())
        );
        assert!(out[0].2.is_ok());
        let e = out[1].2.clone().unwrap_err();
        assert!(
            e.contains("process 1 has the scene scene 1, the root has scene 0"),
            "{e}"
        );
    }
}
