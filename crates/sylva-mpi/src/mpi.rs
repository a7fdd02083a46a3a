//! MPI as a [`Comm`] (feature `mpi`): `MPI_COMM_WORLD` through the C interface of the `mpi`
//! crate. Sends are non-blocking (`MPI_Isend`; the bytes are kept until the send completes),
//! so a rank never waits for its receiver to come and take a result; receives use matched
//! probes (`MPI_Mprobe`/`MPI_Improbe`), so a message's size is known before it is read.
//!
//! MPI is initialised with `MPI_THREAD_SERIALIZED`: the work queue calls MPI from rank 0's
//! serving thread while its main thread only computes, never from two threads at once.
//! A panic on any rank prints its message and aborts the whole job (`MPI_Abort`).

use std::ffi::c_void;
use std::io::Write;
use std::mem::MaybeUninit;
use std::os::raw::c_int;
use std::sync::Mutex;

use mpi::environment::Universe;
use mpi::ffi;
use mpi::traits::Communicator;
use mpi::Threading;

use crate::comm::{Comm, CommError, Tag};

/// Largest piece of a broadcast: MPI counts are C ints.
const CHUNK: usize = 1 << 30;

/// This process's place in `MPI_COMM_WORLD`. Dropping it finalises MPI.
pub struct Mpi {
    rank: usize,
    size: usize,
    /// Sends not known to have completed: the request and the bytes it reads from.
    pending: Mutex<Vec<(ffi::MPI_Request, Vec<u8>)>>,
    _universe: Universe,
}

// SAFETY: MPI handles are plain values; the MPI library is initialised for
// MPI_THREAD_SERIALIZED and this crate calls it from one thread at a time (the queue hands
// the transport to its serving thread while the main thread only computes); `pending` is
// behind a mutex.
unsafe impl Send for Mpi {}
unsafe impl Sync for Mpi {}

fn check(rc: c_int, what: &str) -> Result<(), CommError> {
    // The default error handler (MPI_ERRORS_ARE_FATAL) aborts before this is reached; the
    // check is for libraries configured otherwise.
    if rc == 0 {
        Ok(())
    } else {
        Err(CommError::Transport(format!(
            "{what} failed (error code {rc})"
        )))
    }
}

fn count(n: usize, what: &str) -> Result<c_int, CommError> {
    c_int::try_from(n).map_err(|_| {
        CommError::Transport(format!(
            "{what} of {n} bytes: beyond MPI's count limit of {} bytes",
            c_int::MAX
        ))
    })
}

impl Mpi {
    /// Initialises MPI (thread level serialized) and installs a panic hook that aborts the
    /// job after the panic's message. `Err` if MPI is already initialised or the library
    /// cannot serialise threads.
    pub fn init() -> Result<Mpi, CommError> {
        let (universe, level) = mpi::initialize_with_threading(Threading::Serialized)
            .ok_or_else(|| CommError::Transport("MPI is already initialised".into()))?;
        if level < Threading::Serialized {
            return Err(CommError::Transport(format!(
                "the MPI library offers thread level {level:?}; sylva needs Serialized"
            )));
        }
        let world = universe.world();
        let (rank, size) = (world.rank() as usize, world.size() as usize);
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            default(info);
            eprintln!("sylva: rank {rank} of {size} panicked; aborting the MPI job");
            let _ = std::io::stdout().flush();
            // SAFETY: MPI is initialised; MPI_Abort may be called from any thread.
            unsafe {
                ffi::MPI_Abort(ffi::RSMPI_COMM_WORLD, 101);
            }
        }));
        Ok(Mpi {
            rank,
            size,
            pending: Mutex::new(Vec::new()),
            _universe: universe,
        })
    }

    /// Drops the sends that have completed.
    fn reap(pending: &mut Vec<(ffi::MPI_Request, Vec<u8>)>) -> Result<(), CommError> {
        let mut err = Ok(());
        pending.retain_mut(|(req, _)| {
            let mut done: c_int = 0;
            // SAFETY: `req` is an active request from MPI_Isend whose buffer is alive.
            let rc = unsafe { ffi::MPI_Test(req, &mut done, ffi::RSMPI_STATUS_IGNORE) };
            if let Err(e) = check(rc, "MPI_Test") {
                err = Err(e);
            }
            done == 0
        });
        err
    }

    fn receive(
        &self,
        mut message: ffi::MPI_Message,
        status: &ffi::MPI_Status,
    ) -> Result<(usize, Tag, Vec<u8>), CommError> {
        let mut n: c_int = 0;
        // SAFETY: `status` comes from a matched probe; `message` is its matched message,
        // received once into a buffer of the size the probe reported.
        unsafe {
            check(
                ffi::MPI_Get_count(status, ffi::RSMPI_UINT8_T, &mut n),
                "MPI_Get_count",
            )?;
            let mut data = vec![0u8; n.max(0) as usize];
            check(
                ffi::MPI_Mrecv(
                    data.as_mut_ptr() as *mut c_void,
                    n,
                    ffi::RSMPI_UINT8_T,
                    &mut message,
                    ffi::RSMPI_STATUS_IGNORE,
                ),
                "MPI_Mrecv",
            )?;
            Ok((status.MPI_SOURCE as usize, status.MPI_TAG as Tag, data))
        }
    }
}

impl Comm for Mpi {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn send(&self, dest: usize, tag: Tag, data: Vec<u8>) -> Result<(), CommError> {
        let n = count(data.len(), "a message")?;
        let mut req = MaybeUninit::<ffi::MPI_Request>::uninit();
        // SAFETY: the buffer stays alive (in `pending`, its heap block unmoved) until the
        // request completes.
        let req = unsafe {
            check(
                ffi::MPI_Isend(
                    data.as_ptr() as *const c_void,
                    n,
                    ffi::RSMPI_UINT8_T,
                    dest as c_int,
                    tag as c_int,
                    ffi::RSMPI_COMM_WORLD,
                    req.as_mut_ptr(),
                ),
                "MPI_Isend",
            )?;
            req.assume_init()
        };
        let mut pending = self.pending.lock().expect("pending sends");
        pending.push((req, data));
        Self::reap(&mut pending)
    }

    fn recv(&self, source: Option<usize>, tag: Tag) -> Result<(usize, Vec<u8>), CommError> {
        let mut message = MaybeUninit::<ffi::MPI_Message>::uninit();
        let mut status = MaybeUninit::<ffi::MPI_Status>::uninit();
        // SAFETY: plain out-parameters of a blocking matched probe.
        let (message, status) = unsafe {
            let from = match source {
                Some(s) => s as c_int,
                None => ffi::RSMPI_ANY_SOURCE,
            };
            check(
                ffi::MPI_Mprobe(
                    from,
                    tag as c_int,
                    ffi::RSMPI_COMM_WORLD,
                    message.as_mut_ptr(),
                    status.as_mut_ptr(),
                ),
                "MPI_Mprobe",
            )?;
            (message.assume_init(), status.assume_init())
        };
        let (source, _, data) = self.receive(message, &status)?;
        Ok((source, data))
    }

    fn try_recv(&self) -> Result<Option<(usize, Tag, Vec<u8>)>, CommError> {
        Self::reap(&mut self.pending.lock().expect("pending sends"))?;
        let mut found: c_int = 0;
        let mut message = MaybeUninit::<ffi::MPI_Message>::uninit();
        let mut status = MaybeUninit::<ffi::MPI_Status>::uninit();
        // SAFETY: plain out-parameters; `message` and `status` are read only when found.
        unsafe {
            check(
                ffi::MPI_Improbe(
                    ffi::RSMPI_ANY_SOURCE,
                    ffi::RSMPI_ANY_TAG,
                    ffi::RSMPI_COMM_WORLD,
                    &mut found,
                    message.as_mut_ptr(),
                    status.as_mut_ptr(),
                ),
                "MPI_Improbe",
            )?;
            if found == 0 {
                return Ok(None);
            }
            let status = status.assume_init();
            self.receive(message.assume_init(), &status).map(Some)
        }
    }

    fn broadcast(&self, root: usize, data: &mut Vec<u8>) -> Result<(), CommError> {
        let mut len = data.len() as u64;
        // SAFETY: one u64, then the buffer (sized alike on every rank) in pieces that fit a
        // C int count.
        unsafe {
            check(
                ffi::MPI_Bcast(
                    &mut len as *mut u64 as *mut c_void,
                    1,
                    ffi::RSMPI_UINT64_T,
                    root as c_int,
                    ffi::RSMPI_COMM_WORLD,
                ),
                "MPI_Bcast",
            )?;
            if self.rank != root {
                let len = usize::try_from(len)
                    .map_err(|_| CommError::Protocol(format!("a broadcast of {len} bytes")))?;
                data.clear();
                data.resize(len, 0);
            }
            for piece in data.chunks_mut(CHUNK) {
                check(
                    ffi::MPI_Bcast(
                        piece.as_mut_ptr() as *mut c_void,
                        piece.len() as c_int,
                        ffi::RSMPI_UINT8_T,
                        root as c_int,
                        ffi::RSMPI_COMM_WORLD,
                    ),
                    "MPI_Bcast",
                )?;
            }
        }
        Ok(())
    }

    fn flush(&self) -> Result<(), CommError> {
        let mut pending = self.pending.lock().expect("pending sends");
        for (req, _) in pending.iter_mut() {
            // SAFETY: an active request whose buffer is alive.
            check(
                unsafe { ffi::MPI_Wait(req, ffi::RSMPI_STATUS_IGNORE) },
                "MPI_Wait",
            )?;
        }
        pending.clear();
        Ok(())
    }

    fn abort(&self, code: i32) -> ! {
        let _ = std::io::stdout().flush();
        // SAFETY: MPI is initialised.
        unsafe {
            ffi::MPI_Abort(ffi::RSMPI_COMM_WORLD, code);
        }
        std::process::exit(code)
    }
}

impl Drop for Mpi {
    fn drop(&mut self) {
        // Every send completes before MPI_Finalize (the universe is dropped after this).
        let _ = self.flush();
    }
}
