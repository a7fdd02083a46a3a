//! What the distributed work needs from a transport ([`Comm`]): ranks, tagged point-to-point
//! messages of bytes, a broadcast and an abort. MPI provides it (`crate::mpi`, feature `mpi`);
//! [`LocalComm`] provides it between threads of one process, so the queue, the frame split
//! and the distributed lighting are tested without MPI.

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

/// Bytes in, bytes out: the little-endian encoding of this crate's messages.
#[derive(Debug, Default)]
pub struct Writer(pub Vec<u8>);

impl Writer {
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }

    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }

    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
        self
    }

    pub fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.u64(v.len() as u64);
        self.0.extend_from_slice(v);
        self
    }
}

/// Reads what a [`Writer`] wrote; running short is a [`CommError::Protocol`] naming `what`.
pub struct Reader<'a> {
    data: &'a [u8],
    what: &'static str,
}

impl<'a> Reader<'a> {
    pub fn new(data: &'a [u8], what: &'static str) -> Reader<'a> {
        Reader { data, what }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], CommError> {
        if self.data.len() < n {
            return Err(CommError::Protocol(format!(
                "{}: {} bytes short",
                self.what,
                n - self.data.len()
            )));
        }
        let (head, rest) = self.data.split_at(n);
        self.data = rest;
        Ok(head)
    }

    pub fn u64(&mut self) -> Result<u64, CommError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }

    pub fn f64(&mut self) -> Result<f64, CommError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }

    /// `n` f32 values.
    pub fn f32s(&mut self, n: usize) -> Result<Vec<f32>, CommError> {
        let b = self.take(
            n.checked_mul(4)
                .ok_or_else(|| CommError::Protocol(format!("{}: {n} values", self.what)))?,
        )?;
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4")))
            .collect())
    }

    pub fn bytes(&mut self) -> Result<&'a [u8], CommError> {
        let n = self.u64()?;
        let n = usize::try_from(n)
            .map_err(|_| CommError::Protocol(format!("{}: {n} bytes", self.what)))?;
        self.take(n)
    }

    /// Fails unless everything was read.
    pub fn end(&self) -> Result<(), CommError> {
        if self.data.is_empty() {
            Ok(())
        } else {
            Err(CommError::Protocol(format!(
                "{}: {} bytes too many",
                self.what,
                self.data.len()
            )))
        }
    }
}

/// Every rank checks that it agrees with rank 0 on `what` (a fingerprint of its inputs):
/// ranks started with different arguments, scenes or builds would otherwise render different
/// pictures into one image. `Err` on the ranks that differ, naming both values.
pub fn agree(comm: &dyn Comm, what: &str, mine: &str) -> Result<(), crate::DistError> {
    let mut data = mine.as_bytes().to_vec();
    comm.broadcast(0, &mut data)?;
    let root = String::from_utf8_lossy(&data);
    if root != mine {
        return Err(crate::DistError::Disagree(format!(
            "rank {} has {what} {mine}, rank 0 has {root}",
            comm.rank()
        )));
    }
    Ok(())
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
    fn broadcast_and_agreement() {
        let g = LocalComm::group(3);
        std::thread::scope(|s| {
            for c in &g {
                s.spawn(move || {
                    let mut d = if c.rank() == 0 { vec![9, 8] } else { vec![] };
                    c.broadcast(0, &mut d).unwrap();
                    assert_eq!(d, vec![9, 8]);
                    let mine = if c.rank() == 2 { "b" } else { "a" };
                    let r = agree(c, "scene", mine);
                    assert_eq!(r.is_err(), c.rank() == 2, "rank {}", c.rank());
                    if let Err(e) = r {
                        assert_eq!(
                            e.to_string(),
                            "ranks disagree: rank 2 has scene b, rank 0 has a"
                        );
                    }
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
    fn encoding_round_trips_and_short_messages_are_errors() {
        let mut w = Writer::default();
        w.u64(7).f64(-1.5).f32s(&[1.0, f32::NAN]).bytes(b"xy");
        let mut r = Reader::new(&w.0, "test message");
        assert_eq!(r.u64().unwrap(), 7);
        assert_eq!(r.f64().unwrap(), -1.5);
        let f = r.f32s(2).unwrap();
        assert!(f[0] == 1.0 && f[1].is_nan());
        assert_eq!(r.bytes().unwrap(), b"xy");
        r.end().unwrap();
        let e = Reader::new(&w.0[..5], "test message").u64().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unexpected message: test message: 3 bytes short"
        );
        let mut r = Reader::new(&w.0, "test message");
        r.u64().unwrap();
        assert!(r.end().is_err());
    }
}
