//! What the distributed work needs from a transport ([`Comm`]): ranks, tagged point-to-point
//! messages of bytes, a broadcast and an abort. MPI provides it (`crate::mpi`, feature `mpi`);
//! [`LocalComm`] provides it between threads of one process, so the queue and the pipeline's
//! work across processes are tested without MPI.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

/// A message tag. Each protocol in this crate uses its own ([`crate::queue`]).
pub type Tag = u16;

/// Tag of [`LocalComm`]'s broadcasts.
const TAG_BROADCAST: Tag = 0x7f00;

#[derive(Debug, thiserror::Error)]
pub enum CommError {
    /// Another rank aborted the job while this one waited.
    #[error("another rank aborted the job")]
    Aborted,
    /// A message that does not follow the protocol (a bug, or ranks of different builds).
    #[error("unexpected message: {0}")]
    Protocol(String),
    /// The transport itself failed.
    #[error("MPI: {0}")]
    Transport(String),
}

/// One rank's view of a group of processes (or threads) working on one job. Sends never wait
/// for the receiver; receives wait. Methods may be called from any thread, but from one
/// thread at a time (MPI_THREAD_SERIALIZED): the queue hands the transport to its serving
/// thread and takes it back.
pub trait Comm: Sync {
    /// This rank, `0..size`.
    fn rank(&self) -> usize;
    /// The number of ranks.
    fn size(&self) -> usize;
    /// Sends `data` to rank `dest` under `tag`. Returns before it is received.
    fn send(&self, dest: usize, tag: Tag, data: Vec<u8>) -> Result<(), CommError>;
    /// Waits for a message under `tag` from `source` (any rank when `None`): its sender and
    /// bytes. Messages from one sender under one tag arrive in the order sent.
    fn recv(&self, source: Option<usize>, tag: Tag) -> Result<(usize, Vec<u8>), CommError>;
    /// A message that has already arrived, under any tag, if there is one: sender, tag, bytes.
    fn try_recv(&self) -> Result<Option<(usize, Tag, Vec<u8>)>, CommError>;
    /// Rank `root`'s `data` on every rank (every rank calls it, in the same order).
    fn broadcast(&self, root: usize, data: &mut Vec<u8>) -> Result<(), CommError>;
    /// Waits until the messages this rank sent have left its buffers.
    fn flush(&self) -> Result<(), CommError> {
        Ok(())
    }
    /// Ends the whole job: every rank stops. Print the reason first.
    fn abort(&self, code: i32) -> !;
}

struct Message {
    source: usize,
    tag: Tag,
    data: Vec<u8>,
}

#[derive(Default)]
struct Mailbox {
    queue: Mutex<VecDeque<Message>>,
    arrived: Condvar,
}

struct Group {
    boxes: Vec<Mailbox>,
    aborted: AtomicBool,
}

/// Ranks as threads of one process, with in-memory mailboxes: for tests, and for checking the
/// protocols without MPI. [`Comm::abort`] makes every other rank's waiting receive fail with
/// [`CommError::Aborted`] and panics the calling thread.
#[derive(Clone)]
pub struct LocalComm {
    rank: usize,
    group: Arc<Group>,
}

impl LocalComm {
    /// `size` ranks sharing one group; give each to its own thread.
    pub fn group(size: usize) -> Vec<LocalComm> {
        assert!(size > 0, "a group has at least one rank");
        let group = Arc::new(Group {
            boxes: (0..size).map(|_| Mailbox::default()).collect(),
            aborted: AtomicBool::new(false),
        });
        (0..size)
            .map(|rank| LocalComm {
                rank,
                group: group.clone(),
            })
            .collect()
    }

    fn check(&self) -> Result<(), CommError> {
        if self.group.aborted.load(Ordering::SeqCst) {
            Err(CommError::Aborted)
        } else {
            Ok(())
        }
    }
}

impl Comm for LocalComm {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.group.boxes.len()
    }

    fn send(&self, dest: usize, tag: Tag, data: Vec<u8>) -> Result<(), CommError> {
        self.check()?;
        let b = self
            .group
            .boxes
            .get(dest)
            .ok_or_else(|| CommError::Protocol(format!("no rank {dest}")))?;
        b.queue.lock().expect("mailbox").push_back(Message {
            source: self.rank,
            tag,
            data,
        });
        b.arrived.notify_all();
        Ok(())
    }

    fn recv(&self, source: Option<usize>, tag: Tag) -> Result<(usize, Vec<u8>), CommError> {
        let b = &self.group.boxes[self.rank];
        let mut q = b.queue.lock().expect("mailbox");
        loop {
            self.check()?;
            let found = q
                .iter()
                .position(|m| m.tag == tag && source.is_none_or(|s| s == m.source));
            if let Some(i) = found {
                let m = q.remove(i).expect("found");
                return Ok((m.source, m.data));
            }
            // The timeout only bounds how late an abort is noticed.
            q = b
                .arrived
                .wait_timeout(q, Duration::from_millis(20))
                .expect("mailbox")
                .0;
        }
    }

    fn try_recv(&self) -> Result<Option<(usize, Tag, Vec<u8>)>, CommError> {
        self.check()?;
        let b = &self.group.boxes[self.rank];
        let m = b.queue.lock().expect("mailbox").pop_front();
        Ok(m.map(|m| (m.source, m.tag, m.data)))
    }

    fn broadcast(&self, root: usize, data: &mut Vec<u8>) -> Result<(), CommError> {
        if self.rank == root {
            for r in (0..self.size()).filter(|&r| r != root) {
                self.send(r, TAG_BROADCAST, data.clone())?;
            }
        } else {
            *data = self.recv(Some(root), TAG_BROADCAST)?.1;
        }
        Ok(())
    }

    fn abort(&self, code: i32) -> ! {
        self.group.aborted.store(true, Ordering::SeqCst);
        for b in &self.group.boxes {
            let _q = b.queue.lock();
            b.arrived.notify_all();
        }
        panic!("rank {} aborted the job (code {code})", self.rank);
    }
}

pub use sylva_core::wire::{Reader, Writer};

impl From<sylva_core::wire::WireError> for CommError {
    fn from(e: sylva_core::wire::WireError) -> CommError {
        CommError::Protocol(e.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_messages_match_source_and_tag_in_order() {
        let g = LocalComm::group(3);
        g[1].send(0, 5, vec![1]).unwrap();
        g[2].send(0, 5, vec![2]).unwrap();
        g[1].send(0, 6, vec![3]).unwrap();
        g[1].send(0, 5, vec![4]).unwrap();
        assert_eq!(g[0].recv(Some(1), 6).unwrap(), (1, vec![3]));
        assert_eq!(g[0].recv(Some(2), 5).unwrap(), (2, vec![2]));
        assert_eq!(g[0].recv(None, 5).unwrap(), (1, vec![1]));
        assert_eq!(g[0].try_recv().unwrap(), Some((1, 5, vec![4])));
        assert_eq!(g[0].try_recv().unwrap(), None);
        assert!(matches!(
            g[0].send(7, 1, vec![]),
            Err(CommError::Protocol(_))
        ));
    }

    #[test]
    fn broadcast_reaches_every_rank() {
        let g = LocalComm::group(3);
        std::thread::scope(|s| {
            for c in &g {
                s.spawn(move || {
                    let mut d = if c.rank() == 0 { vec![9, 8] } else { vec![] };
                    c.broadcast(0, &mut d).unwrap();
                    assert_eq!(d, vec![9, 8]);
                });
            }
        });
    }

    #[test]
    fn abort_wakes_waiting_ranks() {
        let g = LocalComm::group(2);
        std::thread::scope(|s| {
            let waiting = s.spawn(|| g[1].recv(Some(0), 1));
            let aborting = s.spawn(|| g[0].abort(3));
            assert!(aborting.join().is_err(), "abort panics its thread");
            assert!(matches!(waiting.join().unwrap(), Err(CommError::Aborted)));
        });
    }

    #[test]
    fn a_short_message_is_a_protocol_error_naming_it() {
        let mut w = Writer::default();
        w.u64(7);
        let e: CommError = Reader::new(&w.0[..5], "test message")
            .u64()
            .unwrap_err()
            .into();
        assert_eq!(
            e.to_string(),
            "unexpected message: test message: 3 bytes short"
        );
    }
}
