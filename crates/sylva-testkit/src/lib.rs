//! Test-only helpers shared by sylva's crates (a dev-dependency, never published).
//!
//! A test that needs a GPU, `mpirun` or a browser and finds none must not pass in silence.
//! Through [`missing`] it either fails, when the run demands the back end
//! (`SYLVA_REQUIRE_GPU=1`, `SYLVA_REQUIRE_MPI=1`, `SYLVA_REQUIRE_BROWSER=1`: CI sets all
//! three), or prints a `SKIPPED` line that `cargo test` shows (libtest keeps a passing test's
//! `eprintln!` to itself).
//!
//! Also the fixtures that tests of several crates build by hand: the board of the render tests
//! ([`write_board`]), a folder's files for bit-for-bit comparisons ([`files_by_name`], and with
//! the `lb` feature `basis_cache_entries`) and, with the `scenes` feature, the tracers' random
//! scenes and rays (`scenes`).

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

#[cfg(feature = "gpu")]
mod gpu;
#[cfg(feature = "gpu")]
pub use gpu::gpu_context;
#[cfg(feature = "lb")]
mod basis;
#[cfg(feature = "lb")]
pub use basis::{basis_cache_entries, BasisEntry};
#[cfg(feature = "scenes")]
pub mod scenes;

/// A back end that a test needs and a machine may lack.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Need {
    /// A wgpu adapter (a software one such as lavapipe counts).
    Gpu,
    /// `mpirun`, and a build with the `mpi` feature.
    Mpi,
    /// Chromium and its WebDriver (`chromedriver`), for the viewer's browser test.
    Browser,
}

impl Need {
    /// The environment variable that turns the back end's absence into a failure.
    pub fn variable(self) -> &'static str {
        match self {
            Need::Gpu => "SYLVA_REQUIRE_GPU",
            Need::Mpi => "SYLVA_REQUIRE_MPI",
            Need::Browser => "SYLVA_REQUIRE_BROWSER",
        }
    }

    /// Whether this run demands the back end: its variable is set, to anything but "" or "0".
    pub fn required(self) -> bool {
        std::env::var_os(self.variable()).is_some_and(|v| !v.is_empty() && v != "0")
    }
}

/// The running test cannot check anything because `need` is missing (`why` says how): a
/// panic when the run requires `need`, else a visible `SKIPPED` line (see [`skipped`]).
#[track_caller]
pub fn missing(need: Need, why: &str) {
    if need.required() {
        panic!("{} is set but {why}", need.variable());
    }
    skipped(&format!(
        "{why} (set {}=1 to make this a failure)",
        need.variable()
    ));
}

/// Tells the user that the running test checks nothing, or less than it could, and why.
///
/// Written to the process's standard error itself: libtest captures only the `print!` family,
/// so `cargo test` shows this line even for a test that passes.
pub fn skipped(why: &str) {
    let thread = std::thread::current();
    let test = thread.name().unwrap_or("a test");
    // Nothing to do if even stderr cannot be written.
    let _ = writeln!(std::io::stderr().lock(), "SKIPPED {test}: {why}");
}

/// Whether `mpirun` runs on this machine; when it does not, [`missing`] says so (a failure
/// under `SYLVA_REQUIRE_MPI=1`).
#[track_caller]
pub fn require_mpirun() -> bool {
    let probe = Command::new("mpirun")
        .arg("--version")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    let why = match probe {
        Ok(s) if s.success() => return true,
        Ok(s) => format!("`mpirun --version` failed ({s})"),
        Err(e) => {
            format!("no mpirun to run ({e}; Debian: apt-get install openmpi-bin libopenmpi-dev)")
        }
    };
    missing(Need::Mpi, &why);
    false
}

/// The files of `dir` by name with their bytes, sorted by name: two folders (LB caches, basis
/// sets) are the same, bit for bit, when these are equal.
pub fn files_by_name(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let read = |e: std::io::Result<std::fs::DirEntry>| {
        let e = e.unwrap_or_else(|e| panic!("listing {}: {e}", dir.display()));
        let bytes = std::fs::read(e.path())
            .unwrap_or_else(|err| panic!("reading {}: {err}", e.path().display()));
        (e.file_name().to_string_lossy().into_owned(), bytes)
    };
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("listing {}: {e}", dir.display()))
        .map(read)
        .collect();
    files.sort();
    files
}

/// Writes `board.obj` and `board.mtl` to `dir`: a 2 × 2 square at y = 2 facing up (x and z in
/// [-1, 1]), material `board` with Kd (0.5, 0.4, 0.3). The render tests work its pixels out by
/// hand.
pub fn write_board(dir: &Path) {
    const OBJ: &str = "mtllib board.mtl\n\
        v -1 2 -1\nv 1 2 -1\nv 1 2 1\nv -1 2 1\n\
        usemtl board\nf 1 3 2\nf 1 4 3\n";
    const MTL: &str = "newmtl board\nKd 0.5 0.4 0.3\n";
    for (name, text) in [("board.obj", OBJ), ("board.mtl", MTL)] {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_required_back_end_that_is_missing_fails_the_test() {
        // The variables are process-wide: set and read them in this one test only.
        std::env::set_var(Need::Mpi.variable(), "1");
        let required = std::panic::catch_unwind(|| {
            missing(
                Need::Mpi,
                "a pretend missing mpirun (this line is expected)",
            )
        });
        std::env::set_var(Need::Mpi.variable(), "0");
        let optional = std::panic::catch_unwind(|| {
            missing(
                Need::Mpi,
                "a pretend missing mpirun (this line is expected)",
            )
        });
        std::env::remove_var(Need::Mpi.variable());
        let message = required.expect_err("required and missing must panic");
        let message = message
            .downcast_ref::<String>()
            .expect("a formatted message");
        assert!(
            message.contains("SYLVA_REQUIRE_MPI") && message.contains("a pretend missing mpirun")
        );
        assert!(optional.is_ok(), "SYLVA_REQUIRE_MPI=0 skips");
    }

    #[test]
    fn board_files_are_written_and_listed_by_name() {
        let dir = std::env::temp_dir().join(format!("sylva-testkit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_board(&dir);
        let files = files_by_name(&dir);
        std::fs::remove_dir_all(&dir).unwrap();
        let names: Vec<_> = files.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["board.mtl", "board.obj"]);
        assert!(files[1].1.starts_with(b"mtllib board.mtl\nv -1 2 -1\n"));
    }
}
