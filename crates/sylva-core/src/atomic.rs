//! Atomic file writes and output sets. A file is written to a temporary file beside its target
//! and renamed into place, so a crash never leaves half a file; an [`OutputSet`] writes all of
//! a command's files first and renames them together at the end, so a failure or Ctrl-C
//! replaces none of them. While any temporary file exists, Ctrl-C (SIGINT, SIGTERM) only
//! marks the process interrupted ([`crate::interrupt`]): the writers stop at their next write,
//! and the temporaries are removed.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use tempfile::{NamedTempFile, TempPath};
use thiserror::Error;

use crate::interrupt::{self, StagingGuard};

/// Writes `bytes` to `path` atomically (temporary file in the same directory, fsync, rename).
pub fn atomic_write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    atomic_write_with(path, |w| w.write_all(bytes))
}

/// Streams a file into place atomically: `fill` writes into a buffered temporary file that
/// replaces `path` only once `fill` succeeded and the data reached the disk.
pub fn atomic_write_with<F>(path: &Path, fill: F) -> io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    crate::input::check_not_input(path).map_err(io::Error::other)?;
    // Declared first, so dropped last: the temporary is gone before a signal may end the
    // process again.
    let _staging = StagingGuard::new();
    let tmp = write_temporary(path, fill)?;
    interrupt::check()?;
    tmp.persist(path).map_err(|e| e.error)
}

/// Writes `fill`'s bytes to a new temporary file beside `path` and syncs it. The temporary is
/// removed when the returned path is dropped unpersisted, and on any error, Ctrl-C included.
fn write_temporary<F>(path: &Path, fill: F) -> io::Result<TempPath>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "path has no file name"))?;
    let prefix = format!(".{}.", name.to_string_lossy());
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    // The mode File::create gives (tempfile's default is 0600): outputs are ordinary files.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let mut w = BufWriter::with_capacity(1 << 20, Interruptible(builder.tempfile_in(dir)?));
    fill(&mut w)?;
    let tmp = w.into_inner().map_err(|e| e.into_error())?.0;
    interrupt::check()?;
    tmp.as_file().sync_all()?;
    Ok(tmp.into_temp_path())
}

/// A writer that fails once the process is interrupted, so long writes stop promptly.
struct Interruptible(NamedTempFile);

impl Write for Interruptible {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        interrupt::check()?;
        self.0.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.0.flush()
    }
}

/// A file of an [`OutputSet`] that cannot be written.
#[derive(Debug, Error)]
pub enum OutputError {
    #[error("{}: named twice among this command's outputs", .0.display())]
    Duplicate(PathBuf),
    #[error("{}: is an input of this command ({}); writing it would destroy it: choose another output", path.display(), input.display())]
    IsInput { path: PathBuf, input: PathBuf },
    #[error("cannot write {}: it is a directory; name a file (e.g. {})", .0.display(), .0.join("out.png").display())]
    IsDirectory(PathBuf),
    #[error("cannot write {}: {} is a file, not a directory", path.display(), parent.display())]
    ParentNotDirectory { path: PathBuf, parent: PathBuf },
    #[error("cannot write {}: no file can be created in the directory {}: {source}", path.display(), dir.display())]
    NotWritable {
        path: PathBuf,
        dir: PathBuf,
        source: io::Error,
    },
    #[error("cannot write {}: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
}

/// `companion`, or else `file` with extension `ext` (a grid's preview beside it).
pub fn companion_path(file: &Path, companion: Option<&Path>, ext: &str) -> PathBuf {
    companion.map_or_else(|| file.with_extension(ext), Path::to_path_buf)
}

/// The output files of one command: checked up front against each other and against the
/// command's inputs, written one by one to temporary files, and renamed into place together
/// by [`OutputSet::commit`]. Dropped without a commit (an error, Ctrl-C), it removes its
/// temporaries (each [`TempPath`] removes its file when dropped) and leaves every existing
/// file as it was.
#[derive(Debug)]
pub struct OutputSet {
    inputs: Vec<(PathBuf, PathBuf)>,
    planned: Vec<(PathBuf, PathBuf)>,
    /// Each temporary and the file it becomes. Before `_staging`: fields drop in order, so the
    /// temporaries are gone before a signal may end the process again.
    staged: Vec<(TempPath, PathBuf)>,
    /// Directories [`OutputSet::plan`] found writable, so each is probed once.
    writable: Vec<PathBuf>,
    _staging: Option<StagingGuard>,
}

use crate::input::identity;

impl OutputSet {
    /// An empty set protecting `inputs` (files the command reads besides those read through
    /// [`crate::read_file`], which are protected already; missing ones are ignored).
    pub fn new<P: AsRef<Path>>(inputs: &[P]) -> OutputSet {
        for p in inputs {
            crate::protect_input(p.as_ref());
        }
        OutputSet {
            inputs: inputs
                .iter()
                .map(|p| (identity(p.as_ref()), p.as_ref().to_path_buf()))
                .collect(),
            planned: Vec::new(),
            staged: Vec::new(),
            writable: Vec::new(),
            _staging: None,
        }
    }

    /// Adds the files a command will write, refusing a file named twice, one that is an input,
    /// a directory, and one whose directory is a file or cannot take a new file. Call it
    /// before the long work, so a bad output name fails at once and before any file of the
    /// set is written.
    pub fn plan<P: AsRef<Path>>(&mut self, outputs: &[P]) -> Result<(), OutputError> {
        for p in outputs {
            let p = p.as_ref();
            let id = identity(p);
            if let Some((_, input)) = self.inputs.iter().find(|(i, _)| *i == id) {
                return Err(OutputError::IsInput {
                    path: p.to_path_buf(),
                    input: input.clone(),
                });
            }
            if crate::input::check_not_input(p).is_err() {
                return Err(OutputError::IsInput {
                    path: p.to_path_buf(),
                    input: p.to_path_buf(),
                });
            }
            if self.planned.iter().any(|(i, _)| *i == id) {
                return Err(OutputError::Duplicate(p.to_path_buf()));
            }
            self.check_writable(p)?;
            self.planned.push((id, p.to_path_buf()));
        }
        Ok(())
    }

    /// Refuses `path` where a file cannot go: a directory of that name, a file where one of
    /// its directories should be, or a directory that cannot take a new file. The nearest
    /// existing directory is probed with a temporary file (removed at once): permission bits
    /// do not tell (root, ACLs, read-only mounts).
    fn check_writable(&mut self, path: &Path) -> Result<(), OutputError> {
        if path.is_dir() {
            return Err(OutputError::IsDirectory(path.to_path_buf()));
        }
        let mut dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        // The directories `write` would create are checked at their nearest existing one.
        while !dir.exists() {
            match dir.parent() {
                Some(d) if !d.as_os_str().is_empty() => dir = d,
                _ => {
                    dir = Path::new(".");
                    break;
                }
            }
        }
        if !dir.is_dir() {
            return Err(OutputError::ParentNotDirectory {
                path: path.to_path_buf(),
                parent: dir.to_path_buf(),
            });
        }
        let key = identity(dir);
        if self.writable.contains(&key) {
            return Ok(());
        }
        tempfile::Builder::new()
            .prefix(".sylva-probe.")
            .tempfile_in(dir)
            .map_err(|e| OutputError::NotWritable {
                path: path.to_path_buf(),
                dir: dir.to_path_buf(),
                // tempfile appends "at path ..." with its random name: keep the system's reason.
                source: io::Error::new(e.kind(), strip_tempfile_path(&e)),
            })?;
        self.writable.push(key);
        Ok(())
    }

    /// Writes `path` (planned here if it was not) to a temporary file beside it.
    pub fn write<F>(&mut self, path: &Path, fill: F) -> Result<(), OutputError>
    where
        F: FnOnce(&mut dyn Write) -> io::Result<()>,
    {
        let id = identity(path);
        if !self.planned.iter().any(|(i, _)| *i == id) {
            self.plan(&[path])?;
        }
        if self.staged.iter().any(|(_, p)| identity(p) == id) {
            return Err(OutputError::Duplicate(path.to_path_buf()));
        }
        self._staging.get_or_insert_with(StagingGuard::new);
        let tmp = write_temporary(path, fill).map_err(|source| OutputError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        self.staged.push((tmp, path.to_path_buf()));
        Ok(())
    }

    /// [`OutputSet::write`] of bytes in memory.
    pub fn write_bytes(&mut self, path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
        self.write(path, |w| w.write_all(bytes))
    }

    /// Checks, before the work, the outputs a command line names: a file and its companion
    /// (by default the file with extension `ext`: a grid's preview PNG), or the companion
    /// alone. Names the work chooses wait for it; nothing is kept planned.
    pub fn check_named(
        file: Option<&Path>,
        companion: Option<&Path>,
        ext: &str,
    ) -> Result<(), OutputError> {
        let named: Vec<PathBuf> = match (file, companion) {
            (Some(f), c) => vec![f.to_path_buf(), companion_path(f, c, ext)],
            (None, Some(c)) => vec![c.to_path_buf()],
            (None, None) => Vec::new(),
        };
        OutputSet::new::<&Path>(&[]).plan(&named)
    }

    /// Renames every written file into place (unless the process was interrupted: then none)
    /// and returns their paths in the order written.
    pub fn commit(mut self) -> Result<Vec<PathBuf>, OutputError> {
        if let Err(source) = interrupt::check() {
            let path = self
                .staged
                .first()
                .map(|(_, p)| p.clone())
                .unwrap_or_default();
            return Err(OutputError::Io { path, source });
        }
        let staged = std::mem::take(&mut self.staged);
        let mut done = Vec::with_capacity(staged.len());
        // After a failed rename the remaining temporaries are dropped, which removes them.
        for (tmp, path) in staged {
            match tmp.persist(&path) {
                Ok(()) => done.push(path),
                Err(e) => {
                    return Err(OutputError::Io {
                        path,
                        source: e.error,
                    })
                }
            }
        }
        Ok(done)
    }
}

/// The message of an error from `tempfile` without the " at path ..." it appends.
fn strip_tempfile_path(e: &io::Error) -> String {
    let text = e.to_string();
    match text.find(" at path ") {
        Some(k) => text[..k].to_string(),
        None => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/out.bin");
        atomic_write(&p, b"first").unwrap();
        atomic_write(&p, b"second").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"second");
        // No temporary files remain.
        let names: Vec<_> = fs::read_dir(p.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1);
    }

    #[cfg(unix)]
    #[test]
    fn outputs_get_the_mode_of_an_ordinary_new_file() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let (plain, atomic) = (dir.path().join("plain"), dir.path().join("atomic"));
        fs::write(&plain, b"x").unwrap();
        atomic_write(&atomic, b"x").unwrap();
        let mode = |p: &Path| fs::metadata(p).unwrap().permissions().mode();
        assert_eq!(mode(&atomic), mode(&plain));
    }

    #[test]
    fn failed_fill_leaves_old_file_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.bin");
        atomic_write(&p, b"good").unwrap();
        let err = atomic_write_with(&p, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("boom"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read(&p).unwrap(), b"good");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_set_replaces_all_its_files_or_none() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.png"), dir.path().join("a.exr"));
        fs::write(&a, b"old a").unwrap();
        fs::write(&b, b"old b").unwrap();
        // The second file fails: the first, already written, must not replace the old one.
        let mut set = OutputSet::new::<&Path>(&[]);
        set.write_bytes(&a, b"new a").unwrap();
        assert!(set
            .write(&b, |w| {
                w.write_all(b"half")?;
                Err(io::Error::other("disk full"))
            })
            .is_err());
        drop(set);
        assert_eq!(fs::read(&a).unwrap(), b"old a");
        assert_eq!(fs::read(&b).unwrap(), b"old b");
        assert_eq!(
            fs::read_dir(dir.path()).unwrap().count(),
            2,
            "temporaries left"
        );
        // Both succeed: both replaced.
        let mut set = OutputSet::new::<&Path>(&[]);
        set.write_bytes(&a, b"new a").unwrap();
        set.write_bytes(&b, b"new b").unwrap();
        assert_eq!(set.commit().unwrap(), vec![a.clone(), b.clone()]);
        assert_eq!(fs::read(&b).unwrap(), b"new b");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    /// A file and its companion are checked together: the default companion differs by its
    /// extension, a companion named as the file itself is refused, and nothing is written.
    #[test]
    fn named_outputs_and_their_companions_are_checked_before_the_work() {
        let dir = tempfile::tempdir().unwrap();
        let grid = dir.path().join("g.sgrid");
        assert_eq!(companion_path(&grid, None, "png"), dir.path().join("g.png"));
        OutputSet::check_named(Some(&grid), None, "png").unwrap();
        let e = OutputSet::check_named(Some(&grid), Some(&grid), "png").unwrap_err();
        assert!(matches!(e, OutputError::Duplicate(_)), "{e}");
        let e = OutputSet::check_named(None, Some(dir.path()), "png").unwrap_err();
        assert!(
            e.to_string().contains(&dir.path().display().to_string()),
            "{e}"
        );
        OutputSet::check_named(None, None, "png").unwrap();
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn inputs_and_repeated_outputs_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.sgrid");
        fs::write(&input, b"grid").unwrap();
        // The same file by another spelling.
        let other = dir.path().join("sub/../in.sgrid");
        fs::create_dir(dir.path().join("sub")).unwrap();
        let mut set = OutputSet::new(&[&input]);
        let e = set.plan(&[&other]).unwrap_err();
        assert!(matches!(e, OutputError::IsInput { .. }), "{e}");
        assert!(e.to_string().contains("is an input of this command"), "{e}");
        let out = dir.path().join("l.png");
        set.plan(&[&out]).unwrap();
        let e = set.plan(&[dir.path().join("./l.png")]).unwrap_err();
        assert!(matches!(e, OutputError::Duplicate(_)), "{e}");
        assert_eq!(fs::read(&input).unwrap(), b"grid");
    }

    #[test]
    fn outputs_that_cannot_be_written_are_refused_when_planned() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // A directory named like the image.
        fs::create_dir(d.join("dir.png")).unwrap();
        let e = OutputSet::new::<&Path>(&[])
            .plan(&[d.join("dir.png")])
            .unwrap_err();
        assert!(matches!(e, OutputError::IsDirectory(_)), "{e}");
        assert!(e.to_string().contains("is a directory"), "{e}");
        // A file where a directory should be, directly or further up.
        fs::write(d.join("afile"), b"x").unwrap();
        for p in [d.join("afile/x.png"), d.join("afile/sub/x.png")] {
            let e = OutputSet::new::<&Path>(&[]).plan(&[&p]).unwrap_err();
            assert!(matches!(e, OutputError::ParentNotDirectory { .. }), "{e}");
            assert!(
                e.to_string().contains(&format!(
                    "{} is a file, not a directory",
                    d.join("afile").display()
                )),
                "{e}"
            );
        }
        // Missing directories are fine: `write` creates them.
        let mut set = OutputSet::new::<&Path>(&[]);
        set.plan(&[d.join("new/deeper/x.png"), d.join("new/y.png")])
            .unwrap();
        assert!(!d.join("new").exists(), "planning must not create anything");
        // The probe leaves nothing behind.
        let mut names: Vec<_> = fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        assert_eq!(names, ["afile", "dir.png"]);
    }

    /// /sys refuses new files even to root, where permission bits would not.
    #[cfg(target_os = "linux")]
    #[test]
    fn an_unwritable_directory_is_refused_with_the_systems_reason() {
        if !Path::new("/sys/kernel").is_dir() {
            eprintln!("skipping: no /sys on this system");
            return;
        }
        let e = OutputSet::new::<&Path>(&[])
            .plan(&[Path::new("/sys/x.png")])
            .unwrap_err();
        assert!(matches!(e, OutputError::NotWritable { .. }), "{e}");
        let text = e.to_string();
        assert!(
            text.contains("directory /sys") && !text.contains("at path"),
            "{text}"
        );
    }
}
