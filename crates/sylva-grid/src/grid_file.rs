//! The versioned binary grid file (`.sgrid`) for density and lighting grids.
//!
//! Layout, little-endian:
//!
//! | offset | size | field |
//! | --- | --- | --- |
//! | 0 | 8 | magic `SYLVAGRD` |
//! | 8 | 4 | format version (1) |
//! | 12 | 4 | kind: 1 density (channels density, wood fraction), 2 lighting (R, G, B), 3 relighting basis (`B_0` R, G, B, …, `B_18` R, G, B: 57 channels, `sylva_lb::relight::BasisSet`) |
//! | 16 | 12 | nx, ny, nz |
//! | 28 | 4 | channel count |
//! | 32 | 4 | element type: 1 f32, 2 f16 |
//! | 36 | 24 | bounds: min xyz, max xyz (f32) |
//! | 60 | 4 | metadata length in bytes |
//! | 64 | 8 | payload length in bytes |
//! | 72 | 4 | CRC-32 of bytes 0..72, the metadata and the payload |
//! | 76 | 4 | reserved, 0 |
//! | 80 | … | metadata: UTF-8 `key=value` lines |
//! | … | … | payload: channel after channel, each in site order `(x * ny + y) * nz + z` |

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use half::f16;
use thiserror::Error;

use crate::grid::{Bounds, DensityGrid, Dims, GridError, LightingGrid};

/// Channel names of a relighting basis grid file (`B_0..B_18` × R, G, B), in storage order.
pub const BASIS_CHANNEL_NAMES: [&str; 3 * crate::lattice::Q] = [
    "B0 red",
    "B0 green",
    "B0 blue",
    "B1 red",
    "B1 green",
    "B1 blue",
    "B2 red",
    "B2 green",
    "B2 blue",
    "B3 red",
    "B3 green",
    "B3 blue",
    "B4 red",
    "B4 green",
    "B4 blue",
    "B5 red",
    "B5 green",
    "B5 blue",
    "B6 red",
    "B6 green",
    "B6 blue",
    "B7 red",
    "B7 green",
    "B7 blue",
    "B8 red",
    "B8 green",
    "B8 blue",
    "B9 red",
    "B9 green",
    "B9 blue",
    "B10 red",
    "B10 green",
    "B10 blue",
    "B11 red",
    "B11 green",
    "B11 blue",
    "B12 red",
    "B12 green",
    "B12 blue",
    "B13 red",
    "B13 green",
    "B13 blue",
    "B14 red",
    "B14 green",
    "B14 blue",
    "B15 red",
    "B15 green",
    "B15 blue",
    "B16 red",
    "B16 green",
    "B16 blue",
    "B17 red",
    "B17 green",
    "B17 blue",
    "B18 red",
    "B18 green",
    "B18 blue",
];

pub const MAGIC: &[u8; 8] = b"SYLVAGRD";
pub const VERSION: u32 = 1;
const HEADER_LEN: usize = 80;
const MAX_METADATA: usize = 1 << 20;

#[derive(Debug, Error)]
pub enum GridFileError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Not a regular file (a directory, FIFO or device).
    #[error(transparent)]
    Input(sylva_core::InputError),
    #[error("{path} is not a sylva grid file (bad magic; expected it to start with 'SYLVAGRD')")]
    Magic { path: PathBuf },
    #[error("{path} has format version {found}; this sylva reads version {VERSION}")]
    Version { path: PathBuf, found: u32 },
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
    #[error("{path}: {source}")]
    Grid { path: PathBuf, source: GridError },
    #[error("{path} holds a {found} grid, but a {expected} grid is needed")]
    WrongKind {
        path: PathBuf,
        expected: &'static str,
        found: &'static str,
    },
    #[error("{path}: {source}")]
    Memory {
        path: PathBuf,
        source: sylva_core::MemoryError,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridKind {
    Density,
    Lighting,
    Basis,
}

impl GridKind {
    fn code(self) -> u32 {
        match self {
            GridKind::Density => 1,
            GridKind::Lighting => 2,
            GridKind::Basis => 3,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            GridKind::Density => "density",
            GridKind::Lighting => "lighting",
            GridKind::Basis => "relighting basis",
        }
    }
    pub fn channel_names(self) -> &'static [&'static str] {
        match self {
            GridKind::Density => &["density", "wood fraction"],
            GridKind::Lighting => &["red", "green", "blue"],
            GridKind::Basis => &BASIS_CHANNEL_NAMES,
        }
    }
}

/// Storage precision of the payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Element {
    F32,
    F16,
}

impl Element {
    fn code(self) -> u32 {
        match self {
            Element::F32 => 1,
            Element::F16 => 2,
        }
    }
    pub fn size(self) -> usize {
        match self {
            Element::F32 => 4,
            Element::F16 => 2,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Element::F32 => "f32",
            Element::F16 => "f16",
        }
    }
}

/// A grid file's contents.
#[derive(Debug, Clone, PartialEq)]
pub struct GridFile {
    pub kind: GridKind,
    pub dims: Dims,
    pub element: Element,
    pub bounds: Bounds,
    pub metadata: Vec<(String, String)>,
    pub channels: Vec<Vec<f32>>,
}

/// What `sylva lb info` shows without decoding the payload.
#[derive(Debug, Clone, PartialEq)]
pub struct GridHeader {
    pub kind: GridKind,
    pub dims: Dims,
    pub element: Element,
    pub bounds: Bounds,
    pub metadata: Vec<(String, String)>,
    pub file_bytes: u64,
    pub checksum: u32,
    pub metadata_bytes: usize,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

impl GridFile {
    pub fn from_density(g: &DensityGrid, metadata: Vec<(String, String)>) -> GridFile {
        GridFile {
            kind: GridKind::Density,
            dims: g.dims,
            element: Element::F32,
            bounds: g.bounds,
            metadata,
            channels: vec![g.density.clone(), g.wood.clone()],
        }
    }

    pub fn from_lighting(
        g: &LightingGrid,
        element: Element,
        metadata: Vec<(String, String)>,
    ) -> GridFile {
        GridFile {
            kind: GridKind::Lighting,
            dims: g.dims,
            element,
            bounds: g.bounds,
            metadata,
            channels: g.colours.to_vec(),
        }
    }

    pub fn into_density(self, path: &Path) -> Result<DensityGrid, GridFileError> {
        if self.kind != GridKind::Density {
            return Err(GridFileError::WrongKind {
                path: path.into(),
                expected: "density",
                found: self.kind.name(),
            });
        }
        let mut ch = self.channels.into_iter();
        let (density, wood) = (ch.next().unwrap_or_default(), ch.next().unwrap_or_default());
        DensityGrid::new(self.dims, self.bounds, density, wood).map_err(|source| {
            GridFileError::Grid {
                path: path.into(),
                source,
            }
        })
    }

    pub fn into_lighting(self, path: &Path) -> Result<LightingGrid, GridFileError> {
        if self.kind != GridKind::Lighting {
            return Err(GridFileError::WrongKind {
                path: path.into(),
                expected: "lighting",
                found: self.kind.name(),
            });
        }
        let [r, g, b]: [Vec<f32>; 3] =
            self.channels
                .try_into()
                .map_err(|_| GridFileError::Header {
                    path: path.into(),
                    what: "lighting grid without three channels".into(),
                })?;
        Ok(LightingGrid {
            dims: self.dims,
            bounds: self.bounds,
            colours: [r, g, b],
        })
    }

    fn encode(&self) -> (Vec<u8>, Vec<u8>) {
        let meta = metadata_text(&self.metadata);
        let mut payload =
            Vec::with_capacity(self.channels.len() * self.dims.sites() * self.element.size());
        for ch in &self.channels {
            match self.element {
                Element::F32 => payload.extend_from_slice(bytemuck_f32(ch)),
                Element::F16 => {
                    for &v in ch {
                        payload.extend_from_slice(&f16::from_f32(v).to_le_bytes());
                    }
                }
            }
        }
        let mut h = Vec::with_capacity(HEADER_LEN);
        h.extend_from_slice(MAGIC);
        for v in [
            VERSION,
            self.kind.code(),
            self.dims.nx as u32,
            self.dims.ny as u32,
            self.dims.nz as u32,
            self.channels.len() as u32,
            self.element.code(),
        ] {
            h.extend_from_slice(&v.to_le_bytes());
        }
        for v in self.bounds.min.iter().chain(self.bounds.max.iter()) {
            h.extend_from_slice(&v.to_le_bytes());
        }
        h.extend_from_slice(&(meta.len() as u32).to_le_bytes());
        h.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        let mut crc = crc32fast::Hasher::new();
        crc.update(&h);
        crc.update(meta.as_bytes());
        crc.update(&payload);
        h.extend_from_slice(&crc.finalize().to_le_bytes());
        h.extend_from_slice(&0u32.to_le_bytes());
        debug_assert_eq!(h.len(), HEADER_LEN);
        h.extend_from_slice(meta.as_bytes());
        (h, payload)
    }

    /// Writes atomically (temporary file, then rename).
    pub fn write(&self, path: &Path) -> Result<(), GridFileError> {
        let (head, payload) = self.encode();
        sylva_core::atomic_write_with(path, |w: &mut dyn Write| {
            w.write_all(&head)?;
            w.write_all(&payload)
        })
        .map_err(|source| GridFileError::Io {
            path: path.into(),
            source,
        })
    }

    /// Writes into `outputs` (renamed into place with the command's other outputs).
    pub fn write_into(
        &self,
        outputs: &mut sylva_core::OutputSet,
        path: &Path,
    ) -> Result<(), sylva_core::OutputError> {
        let (head, payload) = self.encode();
        outputs.write(path, |w: &mut dyn Write| {
            w.write_all(&head)?;
            w.write_all(&payload)
        })
    }

    /// Reads and fully validates a grid file.
    pub fn read(path: &Path) -> Result<GridFile, GridFileError> {
        let io = |source| GridFileError::Io {
            path: path.into(),
            source,
        };
        let (mut file, header, mut crc) = open_grid(path)?;
        let payload_len = header.file_bytes - HEADER_LEN as u64 - header.metadata_bytes as u64;
        sylva_core::check_memory(
            &format!("reading {}", path.display()),
            payload_len * (4 / header.element.size() as u64 + 1),
        )
        .map_err(|source| GridFileError::Memory {
            path: path.into(),
            source,
        })?;
        let mut payload = vec![0u8; payload_len as usize];
        file.read_exact(&mut payload).map_err(io)?;
        crc.update(&payload);
        let found = crc.finalize();
        if found != header.checksum {
            return Err(GridFileError::Checksum {
                path: path.into(),
                expected: header.checksum,
                found,
            });
        }
        let sites = header.dims.sites();
        let size = header.element.size();
        let channels = payload
            .chunks_exact(sites * size)
            .map(|c| match header.element {
                Element::F32 => c
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
                    .collect(),
                Element::F16 => c
                    .chunks_exact(2)
                    .map(|b| f16::from_le_bytes(b.try_into().expect("2 bytes")).to_f32())
                    .collect(),
            })
            .collect();
        Ok(GridFile {
            kind: header.kind,
            dims: header.dims,
            element: header.element,
            bounds: header.bounds,
            metadata: header.metadata,
            channels,
        })
    }

    pub fn metadata_value(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

fn bytemuck_f32(v: &[f32]) -> &[u8] {
    // Little-endian targets store f32 exactly as the file does.
    #[cfg(target_endian = "little")]
    {
        // SAFETY: f32 has no padding and any byte pattern is a valid u8.
        unsafe { std::slice::from_raw_parts(v.as_ptr() as *const u8, std::mem::size_of_val(v)) }
    }
    #[cfg(not(target_endian = "little"))]
    compile_error!("grid files assume a little-endian target");
}

/// `key=value` lines; '=' and line breaks in keys, and line breaks in values, become safe.
fn metadata_text(meta: &[(String, String)]) -> String {
    meta.iter()
        .map(|(k, v)| format!("{}={}\n", k.replace(['=', '\n'], "_"), v.replace('\n', " ")))
        .collect()
}

/// Opens a grid file and checks its header and metadata; the file is left at the payload and
/// the CRC has consumed everything before it.
fn open_grid(path: &Path) -> Result<(std::fs::File, GridHeader, crc32fast::Hasher), GridFileError> {
    // The header says how long the file must be; the size is checked against it.
    let (mut file, _) =
        sylva_core::open_file(path, u64::MAX, "grid files").map_err(|e| match e {
            sylva_core::InputError::Io { path, source } => GridFileError::Io { path, source },
            e => GridFileError::Input(e),
        })?;
    let (header, crc) = read_header(path, &mut file)?;
    Ok((file, header, crc))
}

/// Reads and checks the header and metadata, leaving `file` at the payload.
fn read_header(
    path: &Path,
    file: &mut std::fs::File,
) -> Result<(GridHeader, crc32fast::Hasher), GridFileError> {
    let io = |source| GridFileError::Io {
        path: path.into(),
        source,
    };
    let found = file.metadata().map_err(io)?.len();
    let mut h = [0u8; HEADER_LEN];
    let got = read_up_to(file, &mut h).map_err(io)?;
    if got >= 8 && &h[..8] != MAGIC {
        return Err(GridFileError::Magic { path: path.into() });
    }
    if got < HEADER_LEN {
        if got < 8 {
            return Err(GridFileError::Magic { path: path.into() });
        }
        return Err(GridFileError::Truncated {
            path: path.into(),
            expected: HEADER_LEN as u64,
            found,
        });
    }
    let bad = |what: String| GridFileError::Header {
        path: path.into(),
        what,
    };
    let version = u32_at(&h, 8);
    if version != VERSION {
        return Err(GridFileError::Version {
            path: path.into(),
            found: version,
        });
    }
    let kind = match u32_at(&h, 12) {
        1 => GridKind::Density,
        2 => GridKind::Lighting,
        3 => GridKind::Basis,
        k => return Err(bad(format!("unknown grid kind {k}"))),
    };
    let (nx, ny, nz) = (u32_at(&h, 16), u32_at(&h, 20), u32_at(&h, 24));
    let dims =
        Dims::new(nx as usize, ny as usize, nz as usize).map_err(|source| GridFileError::Grid {
            path: path.into(),
            source,
        })?;
    let channels = u32_at(&h, 28) as usize;
    if channels != kind.channel_names().len() {
        return Err(bad(format!(
            "a {} grid has {} channels, the header says {channels}",
            kind.name(),
            kind.channel_names().len()
        )));
    }
    let element = match u32_at(&h, 32) {
        1 => Element::F32,
        2 => Element::F16,
        e => return Err(bad(format!("unknown element type {e}"))),
    };
    let mut b = [0.0f32; 6];
    for (i, v) in b.iter_mut().enumerate() {
        *v = f32_at(&h, 36 + 4 * i);
    }
    if b.iter().any(|v| !v.is_finite()) || (0..3).any(|a| b[a] > b[a + 3]) {
        return Err(bad(format!("bounds {b:?} are not a valid box")));
    }
    let bounds = Bounds {
        min: [b[0], b[1], b[2]],
        max: [b[3], b[4], b[5]],
    };
    let meta_len = u32_at(&h, 60) as usize;
    if meta_len > MAX_METADATA {
        return Err(bad(format!("metadata length {meta_len} is implausible")));
    }
    let payload_len = u64::from_le_bytes(h[64..72].try_into().expect("8 bytes"));
    let want_payload = (channels * dims.sites() * element.size()) as u64;
    if payload_len != want_payload {
        return Err(bad(format!(
            "payload length {payload_len} does not match {dims} × {channels} channels × {} ({want_payload})",
            element.name()
        )));
    }
    let expected = HEADER_LEN as u64 + meta_len as u64 + payload_len;
    if found < expected {
        return Err(GridFileError::Truncated {
            path: path.into(),
            expected,
            found,
        });
    }
    if found > expected {
        return Err(GridFileError::Trailing {
            path: path.into(),
            extra: found - expected,
        });
    }
    let mut meta = vec![0u8; meta_len];
    file.read_exact(&mut meta).map_err(io)?;
    let text = String::from_utf8(meta).map_err(|_| bad("metadata is not UTF-8".into()))?;
    let metadata = text
        .lines()
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect::<Vec<_>>();
    let mut crc = crc32fast::Hasher::new();
    crc.update(&h[..72]);
    crc.update(text.as_bytes());
    Ok((
        GridHeader {
            kind,
            dims,
            element,
            bounds,
            metadata,
            file_bytes: found,
            checksum: u32_at(&h, 72),
            metadata_bytes: meta_len,
        },
        crc,
    ))
}

fn read_up_to(file: &mut std::fs::File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match file.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// Reads only the header and metadata (for `sylva lb info`); the checksum is verified too,
/// which reads the payload once without keeping it.
pub fn read_header_verified(path: &Path) -> Result<GridHeader, GridFileError> {
    let (mut file, header, mut crc) = open_grid(path)?;
    let io = |source| GridFileError::Io {
        path: path.into(),
        source,
    };
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        crc.update(&buf[..n]);
    }
    let found = crc.finalize();
    if found != header.checksum {
        return Err(GridFileError::Checksum {
            path: path.into(),
            expected: header.checksum,
            found,
        });
    }
    Ok(header)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> GridFile {
        let dims = Dims::new(4, 3, 5).unwrap();
        let n = dims.sites();
        GridFile {
            kind: GridKind::Lighting,
            dims,
            element: Element::F32,
            bounds: Bounds {
                min: [-1.0, 0.0, -2.0],
                max: [1.0, 3.0, 2.0],
            },
            metadata: vec![
                ("preset".into(), "leaf".into()),
                ("steps".into(), "10".into()),
            ],
            channels: (0..3)
                .map(|c| (0..n).map(|i| (i * 3 + c) as f32 * 0.01).collect())
                .collect(),
        }
    }

    #[test]
    fn round_trip_f32_and_f16() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.sgrid");
        let g = sample();
        g.write(&p).unwrap();
        assert_eq!(GridFile::read(&p).unwrap(), g);
        let h = read_header_verified(&p).unwrap();
        assert_eq!(h.dims, g.dims);
        assert_eq!(h.metadata, g.metadata);

        let mut g16 = sample();
        g16.element = Element::F16;
        g16.write(&p).unwrap();
        let back = GridFile::read(&p).unwrap();
        for (a, b) in back
            .channels
            .iter()
            .flatten()
            .zip(g16.channels.iter().flatten())
        {
            assert!((a - b).abs() <= b.abs() * 1e-3 + 1e-6);
        }
    }

    #[test]
    fn truncated_and_corrupted_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.sgrid");
        sample().write(&p).unwrap();
        let bytes = std::fs::read(&p).unwrap();

        for cut in [0, 5, 40, HEADER_LEN + 3, bytes.len() - 1] {
            std::fs::write(&p, &bytes[..cut]).unwrap();
            let e = GridFile::read(&p).unwrap_err();
            assert!(
                matches!(
                    e,
                    GridFileError::Truncated { .. } | GridFileError::Magic { .. }
                ),
                "cut {cut}: {e}"
            );
            assert!(e.to_string().contains("g.sgrid"));
        }
        let mut flipped = bytes.clone();
        let last = flipped.len() - 7;
        flipped[last] ^= 0x10;
        std::fs::write(&p, &flipped).unwrap();
        let e = GridFile::read(&p).unwrap_err();
        assert!(matches!(e, GridFileError::Checksum { .. }), "{e}");
        assert!(matches!(
            read_header_verified(&p).unwrap_err(),
            GridFileError::Checksum { .. }
        ));

        let mut bad_version = bytes.clone();
        bad_version[8] = 9;
        std::fs::write(&p, &bad_version).unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Version { found: 9, .. }
        ));

        let mut huge = bytes.clone();
        huge[16..20].copy_from_slice(&100_000u32.to_le_bytes());
        std::fs::write(&p, &huge).unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Grid { .. }
        ));

        std::fs::write(&p, b"P6\n12 12\n255\n").unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Magic { .. }
        ));
        let mut trailing = bytes.clone();
        trailing.push(0);
        std::fs::write(&p, &trailing).unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Trailing { extra: 1, .. }
        ));
    }

    #[test]
    fn kinds_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.sgrid");
        sample().write(&p).unwrap();
        let e = GridFile::read(&p).unwrap().into_density(&p).unwrap_err();
        assert!(
            e.to_string().contains("lighting grid, but a density grid"),
            "{e}"
        );
    }
}
