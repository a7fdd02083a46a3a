//! A small checked binary container for sylva's own cache files: a fixed header (magic,
//! format version, lengths, CRC-32), `key=value` metadata lines and a binary payload, written
//! atomically. The payload's layout is the caller's; [`ByteWriter`] and [`ByteReader`] encode
//! it little-endian, and the reader reports a short payload as an error instead of panicking.
//!
//! Layout, little-endian:
//!
//! | offset | size | field |
//! | --- | --- | --- |
//! | 0 | 8 | magic (the caller's) |
//! | 8 | 4 | format version (the caller's) |
//! | 12 | 4 | metadata length in bytes (at most 1 MiB) |
//! | 16 | 8 | payload length in bytes |
//! | 24 | 4 | CRC-32 of bytes 0..24, the metadata and the payload |
//! | 28 | 4 | reserved, 0 |
//! | 32 | … | metadata: UTF-8 `key=value` lines |
//! | … | … | payload |

use std::io::Read;
use std::path::{Path, PathBuf};

use thiserror::Error;

const HEADER_LEN: usize = 32;
const MAX_METADATA: usize = 1 << 20;

#[derive(Debug, Error)]
pub enum ContainerError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not a {what} (bad magic)")]
    Magic { path: PathBuf, what: &'static str },
    #[error("{path} has format version {found}; this sylva reads version {expected}")]
    Version {
        path: PathBuf,
        found: u32,
        expected: u32,
    },
    #[error("{path} is truncated: the header says {expected} bytes, the file has {found}")]
    Truncated {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
    #[error("{path} has {extra} unexpected bytes after the payload")]
    Trailing { path: PathBuf, extra: u64 },
    #[error(
        "{path} is corrupted: checksum {found:08x} does not match the header's {expected:08x}"
    )]
    Checksum {
        path: PathBuf,
        expected: u32,
        found: u32,
    },
    #[error("{path}: invalid header: {what}")]
    Header { path: PathBuf, what: String },
    #[error(transparent)]
    Memory(#[from] crate::MemoryError),
    #[error(transparent)]
    Input(crate::InputError),
}

/// What a container holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Container {
    pub metadata: Vec<(String, String)>,
    pub payload: Vec<u8>,
}

impl Container {
    /// The value of metadata key `key`.
    pub fn metadata_value(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

fn metadata_text(meta: &[(String, String)]) -> String {
    let mut s = String::new();
    for (k, v) in meta {
        // Keys and values are one line each; '=' separates the first key from its value.
        let clean = |t: &str| t.replace(['\n', '\r'], " ");
        s.push_str(&clean(&k.replace('=', "_")));
        s.push('=');
        s.push_str(&clean(v));
        s.push('\n');
    }
    s
}

/// Writes a container atomically (temporary file, fsync, rename).
pub fn write_container(
    path: &Path,
    magic: &[u8; 8],
    version: u32,
    metadata: &[(String, String)],
    payload: &[u8],
) -> std::io::Result<()> {
    let head = container_head(magic, version, metadata, payload)?;
    crate::atomic_write_with(path, |w| {
        w.write_all(&head)?;
        w.write_all(payload)
    })
}

/// The bytes of a container before its payload (header and metadata), for writers that place
/// the file themselves (an [`crate::OutputSet`]): the file is these bytes, then `payload`.
pub fn container_head(
    magic: &[u8; 8],
    version: u32,
    metadata: &[(String, String)],
    payload: &[u8],
) -> std::io::Result<Vec<u8>> {
    let meta = metadata_text(metadata);
    if meta.len() > MAX_METADATA {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} bytes of metadata (at most {MAX_METADATA})", meta.len()),
        ));
    }
    let mut h = Vec::with_capacity(HEADER_LEN);
    h.extend_from_slice(magic);
    h.extend_from_slice(&version.to_le_bytes());
    h.extend_from_slice(&(meta.len() as u32).to_le_bytes());
    h.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    let mut crc = crc32fast::Hasher::new();
    crc.update(&h);
    crc.update(meta.as_bytes());
    crc.update(payload);
    h.extend_from_slice(&crc.finalize().to_le_bytes());
    h.extend_from_slice(&0u32.to_le_bytes());
    h.extend_from_slice(meta.as_bytes());
    Ok(h)
}

/// What [`read_container_head`] reads: everything but the payload past its first bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct ContainerHead {
    pub metadata: Vec<(String, String)>,
    /// The payload's first bytes (as many as asked for, or the whole payload if shorter).
    pub head: Vec<u8>,
    pub payload_bytes: u64,
    pub metadata_bytes: usize,
    pub file_bytes: u64,
    pub checksum: u32,
}

/// The opened, checked header of a container: the file at the start of its payload.
struct Opened {
    file: std::fs::File,
    size: u64,
    payload_len: u64,
    meta_len: usize,
    expected_crc: u32,
    crc: crc32fast::Hasher,
    metadata: Vec<(String, String)>,
}

/// Reads a container written by [`write_container`] with the same magic and version; `what`
/// names the kind of file in errors ("compressed basis file"). A short, long or corrupted
/// file is refused naming it, before the payload is allocated beyond the file's real size.
pub fn read_container(
    path: &Path,
    magic: &[u8; 8],
    version: u32,
    what: &'static str,
) -> Result<Container, ContainerError> {
    let Opened {
        mut file,
        payload_len,
        expected_crc,
        mut crc,
        metadata,
        ..
    } = open_container(path, magic, version, what)?;
    crate::check_memory(&format!("reading {}", path.display()), payload_len)?;
    let mut payload = vec![0u8; payload_len as usize];
    file.read_exact(&mut payload)
        .map_err(|source| ContainerError::Io {
            path: path.into(),
            source,
        })?;
    crc.update(&payload);
    check_crc(path, crc, expected_crc)?;
    Ok(Container { metadata, payload })
}

/// Reads a container's metadata and the first `head` bytes of its payload, and verifies its
/// checksum streaming the rest (nothing past `head` is kept): what a file's summary needs.
pub fn read_container_head(
    path: &Path,
    magic: &[u8; 8],
    version: u32,
    what: &'static str,
    head: usize,
) -> Result<ContainerHead, ContainerError> {
    let Opened {
        mut file,
        size,
        payload_len,
        meta_len,
        expected_crc,
        mut crc,
        metadata,
    } = open_container(path, magic, version, what)?;
    let io = |source| ContainerError::Io {
        path: path.into(),
        source,
    };
    let mut first = vec![0u8; (payload_len.min(head as u64)) as usize];
    file.read_exact(&mut first).map_err(io)?;
    crc.update(&first);
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        crc.update(&buf[..n]);
    }
    check_crc(path, crc, expected_crc)?;
    Ok(ContainerHead {
        metadata,
        head: first,
        payload_bytes: payload_len,
        metadata_bytes: meta_len,
        file_bytes: size,
        checksum: expected_crc,
    })
}

fn check_crc(path: &Path, crc: crc32fast::Hasher, expected: u32) -> Result<(), ContainerError> {
    let found = crc.finalize();
    if found != expected {
        return Err(ContainerError::Checksum {
            path: path.into(),
            expected,
            found,
        });
    }
    Ok(())
}

/// Opens a container and checks its header (magic, version, lengths against the file's
/// size) and metadata; the CRC has consumed everything before the payload.
fn open_container(
    path: &Path,
    magic: &[u8; 8],
    version: u32,
    what: &'static str,
) -> Result<Opened, ContainerError> {
    let io = |source| ContainerError::Io {
        path: path.into(),
        source,
    };
    // Regular files only (a FIFO would block); the header bounds the size, checked below.
    let (mut file, size) = crate::open_file(path, u64::MAX, what).map_err(|e| match e {
        crate::InputError::Io { path, source } => ContainerError::Io { path, source },
        e => ContainerError::Input(e),
    })?;
    let mut h = [0u8; HEADER_LEN];
    let mut got = 0;
    while got < HEADER_LEN {
        match file.read(&mut h[got..]).map_err(io)? {
            0 => break,
            n => got += n,
        }
    }
    if got >= 8 && &h[..8] != magic {
        return Err(ContainerError::Magic {
            path: path.into(),
            what,
        });
    }
    if got < HEADER_LEN {
        return Err(ContainerError::Truncated {
            path: path.into(),
            expected: HEADER_LEN as u64,
            found: size,
        });
    }
    let u32_at = |at: usize| u32::from_le_bytes(h[at..at + 4].try_into().expect("4 bytes"));
    let found = u32_at(8);
    if found != version {
        return Err(ContainerError::Version {
            path: path.into(),
            found,
            expected: version,
        });
    }
    let meta_len = u32_at(12) as usize;
    let payload_len = u64::from_le_bytes(h[16..24].try_into().expect("8 bytes"));
    if meta_len > MAX_METADATA {
        return Err(ContainerError::Header {
            path: path.into(),
            what: format!("metadata of {meta_len} bytes (at most {MAX_METADATA})"),
        });
    }
    let expected = (HEADER_LEN as u64)
        .saturating_add(meta_len as u64)
        .saturating_add(payload_len);
    if size < expected {
        return Err(ContainerError::Truncated {
            path: path.into(),
            expected,
            found: size,
        });
    }
    if size > expected {
        return Err(ContainerError::Trailing {
            path: path.into(),
            extra: size - expected,
        });
    }
    let mut meta = vec![0u8; meta_len];
    file.read_exact(&mut meta).map_err(io)?;
    let mut crc = crc32fast::Hasher::new();
    crc.update(&h[..24]);
    crc.update(&meta);
    let text = String::from_utf8(meta).map_err(|_| ContainerError::Header {
        path: path.into(),
        what: "metadata is not UTF-8".into(),
    })?;
    let metadata = text
        .lines()
        .filter(|l| !l.is_empty())
        .map(|l| match l.split_once('=') {
            Some((k, v)) => (k.to_string(), v.to_string()),
            None => (l.to_string(), String::new()),
        })
        .collect();
    Ok(Opened {
        file,
        size,
        payload_len,
        meta_len,
        expected_crc: u32_at(24),
        crc,
        metadata,
    })
}

/// Little-endian payload encoding.
#[derive(Debug, Default)]
pub struct ByteWriter {
    pub bytes: Vec<u8>,
}

impl ByteWriter {
    pub fn new() -> ByteWriter {
        ByteWriter::default()
    }

    pub fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }

    pub fn u32(&mut self, v: u32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u64(&mut self, v: u64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    pub fn f32(&mut self, v: f32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    /// A length (u64) and the bytes.
    pub fn u8s(&mut self, v: &[u8]) {
        self.u64(v.len() as u64);
        self.bytes.extend_from_slice(v);
    }

    /// A length (u64) and the values.
    pub fn u16s(&mut self, v: &[u16]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(2 * v.len());
        for x in v {
            self.bytes.extend_from_slice(&x.to_le_bytes());
        }
    }

    /// A length (u64) and the values.
    pub fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(4 * v.len());
        for x in v {
            self.bytes.extend_from_slice(&x.to_le_bytes());
        }
    }

    /// A length (u64) and the values.
    pub fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(4 * v.len());
        for x in v {
            self.bytes.extend_from_slice(&x.to_le_bytes());
        }
    }

    /// A length (u64) and the values.
    pub fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        self.bytes.reserve(8 * v.len());
        for x in v {
            self.bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
}

/// Reads what a [`ByteWriter`] wrote; running out of bytes is an error naming what was being
/// read, and a stated length is checked against the bytes left before anything is allocated.
#[derive(Debug)]
pub struct ByteReader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> ByteReader<'a> {
    pub fn new(bytes: &'a [u8]) -> ByteReader<'a> {
        ByteReader { bytes, at: 0 }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        if self.bytes.len() - self.at < n {
            return Err(format!(
                "payload ends inside {what} (at byte {}, {} more needed, {} left)",
                self.at,
                n,
                self.bytes.len() - self.at
            ));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    pub fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }

    pub fn u32(&mut self, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }

    pub fn u64(&mut self, what: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8, what)?.try_into().expect("8 bytes"),
        ))
    }

    pub fn f32(&mut self, what: &str) -> Result<f32, String> {
        Ok(f32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }

    /// A length that must fit in the bytes left at `size` bytes per element.
    fn len(&mut self, size: usize, what: &str) -> Result<usize, String> {
        let n = self.u64(what)?;
        if n > (self.remaining() / size) as u64 {
            return Err(format!(
                "{what}: {n} elements of {size} bytes stated, {} bytes left",
                self.remaining()
            ));
        }
        Ok(n as usize)
    }

    pub fn u8s(&mut self, what: &str) -> Result<Vec<u8>, String> {
        let n = self.len(1, what)?;
        Ok(self.take(n, what)?.to_vec())
    }

    pub fn u16s(&mut self, what: &str) -> Result<Vec<u16>, String> {
        let n = self.len(2, what)?;
        let b = self.take(2 * n, what)?;
        Ok(b.chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect())
    }

    pub fn u32s(&mut self, what: &str) -> Result<Vec<u32>, String> {
        let n = self.len(4, what)?;
        let b = self.take(4 * n, what)?;
        Ok(b.chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect())
    }

    pub fn f32s(&mut self, what: &str) -> Result<Vec<f32>, String> {
        let n = self.len(4, what)?;
        let b = self.take(4 * n, what)?;
        Ok(b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect())
    }

    pub fn f64s(&mut self, what: &str) -> Result<Vec<f64>, String> {
        let n = self.len(8, what)?;
        let b = self.take(8 * n, what)?;
        Ok(b.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect())
    }

    /// Errors unless every byte was read.
    pub fn finish(&self) -> Result<(), String> {
        if self.remaining() != 0 {
            return Err(format!(
                "{} bytes left over after the payload",
                self.remaining()
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAGIC: &[u8; 8] = b"SYLVATST";

    #[test]
    fn round_trip_and_damage_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.bin");
        let mut w = ByteWriter::new();
        w.u8(7);
        w.u32(0xdead_beef);
        w.f32s(&[1.5, -2.0]);
        w.u16s(&[1, 65535]);
        w.u8s(&[9, 8]);
        w.u32s(&[3]);
        w.f64s(&[0.1, -1e300]);
        let meta = vec![("a".to_string(), "b=c".to_string())];
        write_container(&path, MAGIC, 3, &meta, &w.bytes).unwrap();
        let c = read_container(&path, MAGIC, 3, "test file").unwrap();
        assert_eq!(c.metadata_value("a"), Some("b=c"));
        let mut r = ByteReader::new(&c.payload);
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.u32("b").unwrap(), 0xdead_beef);
        assert_eq!(r.f32s("c").unwrap(), vec![1.5, -2.0]);
        assert_eq!(r.u16s("d").unwrap(), vec![1, 65535]);
        assert_eq!(r.u8s("e").unwrap(), vec![9, 8]);
        assert_eq!(r.u32s("f").unwrap(), vec![3]);
        assert_eq!(r.f64s("g").unwrap(), vec![0.1, -1e300]);
        r.finish().unwrap();
        let e = r.u8("past the end").unwrap_err();
        assert!(e.contains("past the end"), "{e}");

        let good = std::fs::read(&path).unwrap();
        let shown = path.display().to_string();
        let refused = |bytes: &[u8]| {
            std::fs::write(&path, bytes).unwrap();
            let e = read_container(&path, MAGIC, 3, "test file").unwrap_err();
            assert!(e.to_string().contains(&shown), "{e}");
            e
        };
        let mut flipped = good.clone();
        let last = flipped.len() - 3;
        flipped[last] ^= 1;
        assert!(matches!(refused(&flipped), ContainerError::Checksum { .. }));
        assert!(matches!(
            refused(&good[..good.len() - 1]),
            ContainerError::Truncated { .. }
        ));
        assert!(matches!(
            refused(&good[..10]),
            ContainerError::Truncated { .. }
        ));
        assert!(matches!(refused(b""), ContainerError::Truncated { .. }));
        let mut long = good.clone();
        long.push(0);
        assert!(matches!(refused(&long), ContainerError::Trailing { .. }));
        assert!(matches!(
            refused(b"SOMETHINGELSE_AT_ALL_LONG_ENOUGH_FOR_A_HEADER"),
            ContainerError::Magic { .. }
        ));
        let mut other = good.clone();
        other[8] = 4;
        assert!(matches!(refused(&other), ContainerError::Version { .. }));
        // A huge stated payload is refused by size, not allocated.
        let mut huge = good.clone();
        huge[16..24].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(matches!(refused(&huge), ContainerError::Truncated { .. }));
        // A stated element count beyond the bytes left is an error, not an allocation.
        let mut w = ByteWriter::new();
        w.u64(1 << 40);
        let e = ByteReader::new(&w.bytes).f32s("values").unwrap_err();
        assert!(e.contains("values"), "{e}");
    }
}
