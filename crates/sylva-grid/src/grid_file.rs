//! The versioned binary grid file (`.sgrid`) for density and lighting grids: a checked
//! container of sylva-core ([`sylva_core::container`]: header, metadata, CRC-32, atomic
//! writes), magic `SYLVAGRD`, format version 2, whose payload starts with the grid's header.
//!
//! Payload, little-endian:
//!
//! | offset | size | field |
//! | --- | --- | --- |
//! | 0 | 4 | kind: 1 density (channels density, wood fraction), 2 lighting (R, G, B), 3 relighting basis (`B_0` R, G, B, …, `B_18` R, G, B: 57 channels, `sylva_lb::relight::BasisSet`) |
//! | 4 | 12 | nx, ny, nz |
//! | 16 | 4 | channel count |
//! | 20 | 4 | element type: 1 f32, 2 f16 |
//! | 24 | 24 | bounds: min xyz, max xyz (f32) |
//! | 48 | … | channel after channel, each in site order `(x * ny + y) * nz + z` |
//!
//! Version 1 had its own framing (the same fields in an 80-byte header); it is refused by
//! its version, naming the file.

use std::io::Write;
use std::path::{Path, PathBuf};

use half::f16;
use sylva_core::container::{container_head, read_container, read_container_head, ContainerError};
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
pub const VERSION: u32 = 2;
/// Bytes of the grid's header at the start of the payload.
const GRID_HEADER_LEN: usize = 48;
const WHAT: &str = "sylva grid file";

#[derive(Debug, Error)]
pub enum GridFileError {
    /// What the checked container reports: the file cannot be read, is not a grid file, has
    /// another version, is truncated or corrupted.
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
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

    /// The container's head (header and metadata) and payload.
    fn encode(&self) -> std::io::Result<(Vec<u8>, Vec<u8>)> {
        let mut payload = Vec::with_capacity(
            GRID_HEADER_LEN + self.channels.len() * self.dims.sites() * self.element.size(),
        );
        for v in [
            self.kind.code(),
            self.dims.nx as u32,
            self.dims.ny as u32,
            self.dims.nz as u32,
            self.channels.len() as u32,
            self.element.code(),
        ] {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        for v in self.bounds.min.iter().chain(self.bounds.max.iter()) {
            payload.extend_from_slice(&v.to_le_bytes());
        }
        debug_assert_eq!(payload.len(), GRID_HEADER_LEN);
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
        let head = container_head(MAGIC, VERSION, &self.metadata, &payload)?;
        Ok((head, payload))
    }

    /// Writes atomically (temporary file, then rename).
    pub fn write(&self, path: &Path) -> Result<(), GridFileError> {
        self.encode()
            .and_then(|(head, payload)| {
                sylva_core::atomic_write_with(path, |w: &mut dyn Write| {
                    w.write_all(&head)?;
                    w.write_all(&payload)
                })
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
        let (head, payload) = self
            .encode()
            .map_err(|source| sylva_core::OutputError::Io {
                path: path.into(),
                source,
            })?;
        outputs.write(path, |w: &mut dyn Write| {
            w.write_all(&head)?;
            w.write_all(&payload)
        })
    }

    /// Reads and fully validates a grid file.
    pub fn read(path: &Path) -> Result<GridFile, GridFileError> {
        let c = read_container(path, MAGIC, VERSION, WHAT)?;
        let h = grid_header(path, &c.payload, c.payload.len() as u64)?;
        // Decoding f16 doubles the payload; f32 copies it.
        sylva_core::check_memory(
            &format!("reading {}", path.display()),
            (c.payload.len() as u64) * (4 / h.element.size() as u64),
        )
        .map_err(|source| GridFileError::Memory {
            path: path.into(),
            source,
        })?;
        let sites = h.dims.sites();
        let channels = c.payload[GRID_HEADER_LEN..]
            .chunks_exact(sites * h.element.size())
            .map(|c| match h.element {
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
            kind: h.kind,
            dims: h.dims,
            element: h.element,
            bounds: h.bounds,
            metadata: c.metadata,
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

/// The grid's header at the start of a payload of `payload_len` bytes (`head` holds at least
/// its first [`GRID_HEADER_LEN`] bytes when there are that many), checked against the length.
struct GridFields {
    kind: GridKind,
    dims: Dims,
    element: Element,
    bounds: Bounds,
}

fn grid_header(path: &Path, head: &[u8], payload_len: u64) -> Result<GridFields, GridFileError> {
    let bad = |what: String| GridFileError::Header {
        path: path.into(),
        what,
    };
    if head.len() < GRID_HEADER_LEN {
        return Err(bad(format!(
            "a payload of {payload_len} bytes has no grid header ({GRID_HEADER_LEN} bytes)"
        )));
    }
    let u32_at = |at: usize| u32::from_le_bytes(head[at..at + 4].try_into().expect("4 bytes"));
    let kind = match u32_at(0) {
        1 => GridKind::Density,
        2 => GridKind::Lighting,
        3 => GridKind::Basis,
        k => return Err(bad(format!("unknown grid kind {k}"))),
    };
    let (nx, ny, nz) = (u32_at(4), u32_at(8), u32_at(12));
    let dims =
        Dims::new(nx as usize, ny as usize, nz as usize).map_err(|source| GridFileError::Grid {
            path: path.into(),
            source,
        })?;
    let channels = u32_at(16) as usize;
    if channels != kind.channel_names().len() {
        return Err(bad(format!(
            "a {} grid has {} channels, the header says {channels}",
            kind.name(),
            kind.channel_names().len()
        )));
    }
    let element = match u32_at(20) {
        1 => Element::F32,
        2 => Element::F16,
        e => return Err(bad(format!("unknown element type {e}"))),
    };
    let b: [f32; 6] = std::array::from_fn(|i| f32::from_bits(u32_at(24 + 4 * i)));
    if b.iter().any(|v| !v.is_finite()) || (0..3).any(|a| b[a] > b[a + 3]) {
        return Err(bad(format!("bounds {b:?} are not a valid box")));
    }
    let want = (GRID_HEADER_LEN + channels * dims.sites() * element.size()) as u64;
    if payload_len != want {
        return Err(bad(format!(
            "payload length {payload_len} does not match the grid header and {dims} × {channels} channels × {} ({want})",
            element.name()
        )));
    }
    Ok(GridFields {
        kind,
        dims,
        element,
        bounds: Bounds {
            min: [b[0], b[1], b[2]],
            max: [b[3], b[4], b[5]],
        },
    })
}

/// Reads only the header and metadata (for `sylva lb info`); the checksum is verified too,
/// which reads the payload once without keeping it.
pub fn read_header_verified(path: &Path) -> Result<GridHeader, GridFileError> {
    let c = read_container_head(path, MAGIC, VERSION, WHAT, GRID_HEADER_LEN)?;
    let h = grid_header(path, &c.head, c.payload_bytes)?;
    Ok(GridHeader {
        kind: h.kind,
        dims: h.dims,
        element: h.element,
        bounds: h.bounds,
        metadata: c.metadata,
        file_bytes: c.file_bytes,
        checksum: c.checksum,
        metadata_bytes: c.metadata_bytes,
    })
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

        for cut in [0, 5, 30, 40, 32 + 3, bytes.len() - 1] {
            std::fs::write(&p, &bytes[..cut]).unwrap();
            let e = GridFile::read(&p).unwrap_err();
            assert!(
                matches!(
                    e,
                    GridFileError::Container(
                        ContainerError::Truncated { .. } | ContainerError::Magic { .. }
                    )
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
        assert!(
            matches!(e, GridFileError::Container(ContainerError::Checksum { .. })),
            "{e}"
        );
        assert!(matches!(
            read_header_verified(&p).unwrap_err(),
            GridFileError::Container(ContainerError::Checksum { .. })
        ));

        // Another version (1: this format's own framing before the checked container).
        for v in [1, 9] {
            let mut other = bytes.clone();
            other[8] = v;
            std::fs::write(&p, &other).unwrap();
            let e = GridFile::read(&p).unwrap_err();
            assert!(
                matches!(e, GridFileError::Container(ContainerError::Version { found, .. }) if found == v as u32),
                "{e}"
            );
        }

        // A grid header that passes the checksum but not its checks.
        let payload_at = 32 + u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let resealed = |b: &mut Vec<u8>| {
            let mut crc = crc32fast::Hasher::new();
            crc.update(&b[..24]);
            crc.update(&b[32..]);
            let sum = crc.finalize().to_le_bytes();
            b[24..28].copy_from_slice(&sum);
        };
        let mut huge = bytes.clone();
        huge[payload_at + 4..payload_at + 8].copy_from_slice(&100_000u32.to_le_bytes());
        resealed(&mut huge);
        std::fs::write(&p, &huge).unwrap();
        let e = GridFile::read(&p).unwrap_err();
        assert!(matches!(e, GridFileError::Grid { .. }), "{e}");
        let mut kind = bytes.clone();
        kind[payload_at] = 7;
        resealed(&mut kind);
        std::fs::write(&p, &kind).unwrap();
        let e = read_header_verified(&p).unwrap_err();
        assert!(e.to_string().contains("unknown grid kind 7"), "{e}");
        let mut fewer = bytes.clone();
        fewer[payload_at + 4] -= 1;
        resealed(&mut fewer);
        std::fs::write(&p, &fewer).unwrap();
        let e = GridFile::read(&p).unwrap_err();
        assert!(e.to_string().contains("does not match"), "{e}");

        std::fs::write(&p, b"P6\n12 12\n255\n").unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Container(ContainerError::Magic { .. })
        ));
        let mut trailing = bytes.clone();
        trailing.push(0);
        std::fs::write(&p, &trailing).unwrap();
        assert!(matches!(
            GridFile::read(&p).unwrap_err(),
            GridFileError::Container(ContainerError::Trailing { extra: 1, .. })
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
