//! Reading input files without trusting them: every parser reads through [`read_file`] (or
//! opens through [`open_file`]), which refuses what is not a regular file (a directory, a
//! FIFO that would block, `/dev/zero` that never ends) and files over a size limit, and
//! checks memory before the bytes are read. [`resolve_inside`] keeps the files a model refers
//! to inside the model's folder. Every file read through [`read_file`] is an input of the
//! process: [`crate::atomic_write`] and [`crate::OutputSet`] refuse to replace it, so no
//! output name can destroy a command's own input.

use std::fs::File;
use std::io::{self, Read};
use std::path::{Component, Path, PathBuf};
use std::sync::Mutex;

use thiserror::Error;

use crate::memory::{check_memory, format_bytes, MemoryError};

/// An input file that cannot be read; each variant names the file.
#[derive(Debug, Error)]
pub enum InputError {
    #[error("{}: cannot read: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
    #[error("{}: is a directory, not a file", .0.display())]
    Directory(PathBuf),
    #[error("{}: is not a regular file (a FIFO, device or socket): sylva reads only regular files", .0.display())]
    NotRegular(PathBuf),
    #[error("{}: is {} but {what} are read up to {}", path.display(), format_bytes(*size), format_bytes(*limit))]
    TooLarge {
        path: PathBuf,
        what: &'static str,
        size: u64,
        limit: u64,
    },
    #[error("{}: not UTF-8 text (invalid byte at offset {offset})", path.display())]
    NotText { path: PathBuf, offset: usize },
    #[error("{}: {source}", path.display())]
    Memory { path: PathBuf, source: MemoryError },
    #[error("{}: refers to '{reference}', which lies outside the model's folder {}: only paths inside it are read", file.display(), dir.display())]
    OutsideFolder {
        file: PathBuf,
        dir: PathBuf,
        reference: String,
    },
}

impl InputError {
    /// The message without the leading file name, for errors that name the file already.
    pub fn problem(&self) -> String {
        let full = self.to_string();
        let prefix = format!("{}: ", self.path().display());
        full.strip_prefix(&prefix)
            .map(str::to_string)
            .unwrap_or(full)
    }

    /// The file the problem is in.
    pub fn path(&self) -> &Path {
        match self {
            InputError::Io { path, .. }
            | InputError::TooLarge { path, .. }
            | InputError::NotText { path, .. }
            | InputError::Memory { path, .. } => path,
            InputError::Directory(p) | InputError::NotRegular(p) => p,
            InputError::OutsideFolder { file, .. } => file,
        }
    }
}

/// Inputs of this process, as [`identity`] resolves them.
static INPUTS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The path as the file system resolves it: canonical where the file exists, else the
/// canonical parent joined with the name (and the path itself when neither exists).
pub(crate) fn identity(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    let parent = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match (parent.canonicalize(), p.file_name()) {
        (Ok(d), Some(n)) => d.join(n),
        _ => p.to_path_buf(),
    }
}

/// Marks `path` as an input of this process: no output may replace it. [`read_file`] does
/// this for every file it reads; commands call it for inputs they open otherwise.
pub fn protect_input(path: &Path) {
    let id = identity(path);
    let mut inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
    if !inputs.contains(&id) {
        inputs.push(id);
    }
}

/// `Err` naming the input when writing `path` would replace an input of this process.
pub(crate) fn check_not_input(path: &Path) -> Result<(), String> {
    let id = identity(path);
    let inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
    if inputs.contains(&id) {
        return Err(format!(
            "{} is an input of this command; writing it would destroy it: choose another output",
            path.display()
        ));
    }
    Ok(())
}

/// Opens `path` for reading after checking that it is a regular file of at most `limit`
/// bytes (`what` names the kind of file in the error, e.g. "scene files"); returns the file
/// and its size. Checked before opening: opening a FIFO would block until a writer comes.
pub fn open_file(path: &Path, limit: u64, what: &'static str) -> Result<(File, u64), InputError> {
    let io_err = |source| InputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(io_err)?;
    if meta.is_dir() {
        return Err(InputError::Directory(path.to_path_buf()));
    }
    if !meta.is_file() {
        return Err(InputError::NotRegular(path.to_path_buf()));
    }
    let size = meta.len();
    if size > limit {
        return Err(InputError::TooLarge {
            path: path.to_path_buf(),
            what,
            size,
            limit,
        });
    }
    let file = File::open(path).map_err(io_err)?;
    Ok((file, size))
}

/// The bytes of `path`, a regular file of at most `limit` bytes (see [`open_file`]); memory
/// is checked for them first, and a file that grows while it is read is cut off at the limit
/// and refused.
pub fn read_file(path: &Path, limit: u64, what: &'static str) -> Result<Vec<u8>, InputError> {
    let (file, size) = open_file(path, limit, what)?;
    protect_input(path);
    check_memory(&format!("reading {}", path.display()), size).map_err(|source| {
        InputError::Memory {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let mut bytes = Vec::with_capacity(size as usize);
    file.take(limit.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|source| InputError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    if bytes.len() as u64 > limit {
        return Err(InputError::TooLarge {
            path: path.to_path_buf(),
            what,
            size: bytes.len() as u64,
            limit,
        });
    }
    Ok(bytes)
}

/// [`read_file`] as UTF-8 text.
pub fn read_text_file(path: &Path, limit: u64, what: &'static str) -> Result<String, InputError> {
    String::from_utf8(read_file(path, limit, what)?).map_err(|e| InputError::NotText {
        path: path.to_path_buf(),
        offset: e.utf8_error().valid_up_to(),
    })
}

/// `reference` (a relative path written in `file`) resolved against `dir`, the folder of
/// `file`, refused if it is absolute or climbs out of `dir` (with `..`, or through a
/// symbolic link once the file exists).
pub fn resolve_inside(dir: &Path, reference: &str, file: &Path) -> Result<PathBuf, InputError> {
    let outside = || InputError::OutsideFolder {
        file: file.to_path_buf(),
        dir: if dir.as_os_str().is_empty() {
            PathBuf::from(".")
        } else {
            dir.to_path_buf()
        },
        reference: reference.to_string(),
    };
    let rel = Path::new(reference);
    let mut depth = 0usize;
    for c in rel.components() {
        match c {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir => depth = depth.checked_sub(1).ok_or_else(outside)?,
            Component::RootDir | Component::Prefix(_) => return Err(outside()),
        }
    }
    let joined = dir.join(rel);
    // A link inside the folder may still point out of it.
    if let (Ok(real), Ok(base)) = (joined.canonicalize(), dir_or_cwd(dir).canonicalize()) {
        if !real.starts_with(&base) {
            return Err(outside());
        }
    }
    Ok(joined)
}

fn dir_or_cwd(dir: &Path) -> &Path {
    if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_regular_files_within_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        std::fs::write(&p, "héllo").unwrap();
        assert_eq!(read_text_file(&p, 100, "text files").unwrap(), "héllo");
        let e = read_file(&p, 3, "text files").unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(
                e,
                InputError::TooLarge {
                    size: 6,
                    limit: 3,
                    ..
                }
            ),
            "{msg}"
        );
        assert!(
            msg.contains("a.txt") && msg.contains("text files are read up to 3 B"),
            "{msg}"
        );
        std::fs::write(&p, [0x66, 0xff, 0x66]).unwrap();
        let e = read_text_file(&p, 100, "text files").unwrap_err();
        assert!(matches!(e, InputError::NotText { offset: 1, .. }), "{e}");
    }

    #[test]
    fn refuses_directories_devices_and_fifos() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_file(dir.path(), 100, "scene files").unwrap_err();
        assert!(matches!(e, InputError::Directory(_)), "{e}");
        #[cfg(unix)]
        {
            // /dev/zero never ends: refused before a byte is read.
            let e = read_file(Path::new("/dev/zero"), 100, "scene files").unwrap_err();
            assert!(matches!(e, InputError::NotRegular(_)), "{e}");
            assert!(
                e.to_string()
                    .starts_with("/dev/zero: is not a regular file"),
                "{e}"
            );
            // A FIFO would block in open(); it is refused at once.
            let fifo = dir.path().join("pipe");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            let e = read_file(&fifo, 100, "scene files").unwrap_err();
            assert!(matches!(e, InputError::NotRegular(_)), "{e}");
        }
        let e = read_file(&dir.path().join("missing"), 100, "x").unwrap_err();
        assert!(matches!(e, InputError::Io { .. }) && e.path().ends_with("missing"));
    }

    #[test]
    fn references_stay_inside_the_folder() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("model");
        std::fs::create_dir(&d).unwrap();
        std::fs::write(d.join("a.bin"), b"x").unwrap();
        let f = d.join("m.gltf");
        assert_eq!(resolve_inside(&d, "a.bin", &f).unwrap(), d.join("a.bin"));
        assert_eq!(
            resolve_inside(&d, "sub/../a.bin", &f).unwrap(),
            d.join("sub/../a.bin")
        );
        for bad in ["../a.bin", "../../etc/passwd", "/etc/passwd", "sub/../../x"] {
            let e = resolve_inside(&d, bad, &f).unwrap_err();
            assert!(matches!(e, InputError::OutsideFolder { .. }), "{bad}: {e}");
            assert!(e.to_string().contains("outside the model's folder"), "{e}");
        }
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink("/etc/passwd", d.join("link")).unwrap();
            assert!(resolve_inside(&d, "link", &f).is_err());
        }
    }
}
