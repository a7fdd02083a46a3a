//! What `sylva lb info` shows of a grid file ([`GridInfo`]): kind, size, precision, bounds,
//! metadata, each channel's range and mean, and a density grid's occupancy; and the headerless
//! raw density files `sylva lb solve --raw` reads ([`read_raw`]).

use std::fmt;
use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::grid::{DensityGrid, Dims, GridError, RawElement};
use crate::grid_file::{read_header_verified, GridFile, GridFileError, GridHeader, GridKind};

/// One channel's values.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelStats {
    pub name: &'static str,
    pub min: f32,
    pub max: f32,
    pub mean: f64,
}

/// A grid file described: its verified header and its values.
#[derive(Debug, Clone, PartialEq)]
pub struct GridInfo {
    pub path: PathBuf,
    pub header: GridHeader,
    pub channels: Vec<ChannelStats>,
    /// A density grid's mean density and occupied sites ([`DensityGrid::occupancy`]).
    pub occupancy: Option<(f64, usize)>,
}

impl GridInfo {
    /// Reads `path` (checksum verified; truncated or corrupted files are refused).
    pub fn read(path: &Path) -> Result<GridInfo, GridFileError> {
        let header = read_header_verified(path)?;
        let file = GridFile::read(path)?;
        let channels = header
            .kind
            .channel_names()
            .iter()
            .zip(&file.channels)
            .map(|(name, ch)| {
                let (mut min, mut max, mut sum) = (f32::INFINITY, f32::NEG_INFINITY, 0.0f64);
                for &v in ch {
                    min = min.min(v);
                    max = max.max(v);
                    sum += v as f64;
                }
                ChannelStats {
                    name,
                    min,
                    max,
                    mean: sum / ch.len() as f64,
                }
            })
            .collect();
        let occupancy = match header.kind {
            GridKind::Density => Some(file.into_density(path)?.occupancy()),
            _ => None,
        };
        Ok(GridInfo {
            path: path.to_path_buf(),
            header,
            channels,
            occupancy,
        })
    }
}

impl fmt::Display for GridInfo {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        let h = &self.header;
        writeln!(o, "{}", self.path.display())?;
        writeln!(o, "  kind:      {} grid", h.kind.name())?;
        writeln!(o, "  size:      {} ({} sites)", h.dims, h.dims.sites())?;
        writeln!(o, "  element:   {}", h.element.name())?;
        let (min, max) = (h.bounds.min, h.bounds.max);
        writeln!(
            o,
            "  bounds:    ({}, {}, {}) .. ({}, {}, {})",
            min[0], min[1], min[2], max[0], max[1], max[2]
        )?;
        writeln!(
            o,
            "  file:      {} ({}), checksum {:08x} ok",
            h.file_bytes,
            sylva_core::format_bytes(h.file_bytes),
            h.checksum
        )?;
        for (k, v) in &h.metadata {
            writeln!(o, "  {k:<10} {v}")?;
        }
        for c in &self.channels {
            writeln!(
                o,
                "  {:<14} min {:.5}  max {:.5}  mean {:.5}",
                c.name, c.min, c.max, c.mean
            )?;
        }
        if let Some((mean, occupied)) = self.occupancy {
            writeln!(o, "  occupied:  {occupied} sites, mean density {mean:.5}")?;
        }
        Ok(())
    }
}

/// Why a raw density file was refused; each message names the file.
#[derive(Debug, Error)]
pub enum RawFileError {
    #[error(transparent)]
    Input(#[from] sylva_core::InputError),
    #[error("{path}: a {dims} grid of {element} needs {want} bytes, the file has {size}")]
    Size {
        path: PathBuf,
        dims: Dims,
        element: &'static str,
        want: u64,
        size: u64,
    },
    #[error("{path}")]
    Grid {
        path: PathBuf,
        #[source]
        source: GridError,
    },
}

/// A headerless raw file of densities in site order (x slowest, z fastest): a regular file
/// of exactly the bytes a `dims` grid of `element` needs, checked before it is read.
pub fn read_raw(path: &Path, dims: Dims, element: RawElement) -> Result<DensityGrid, RawFileError> {
    let want = (dims.sites() * element.size()) as u64;
    let (_, size) = sylva_core::open_file(path, u64::MAX, "raw grid files")?;
    if size != want {
        return Err(RawFileError::Size {
            path: path.to_path_buf(),
            dims,
            element: element.name(),
            want,
            size,
        });
    }
    let bytes = sylva_core::read_file(path, want, "raw grid files")?;
    DensityGrid::from_raw(dims, &bytes, element).map_err(|source| RawFileError::Grid {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Bounds;

    /// The statistics are the channels' own minimum, maximum and mean, and the occupancy the
    /// grid's, read back from a written file; a raw file of the wrong size is refused.
    #[test]
    fn info_reads_back_what_was_written() {
        let dims = Dims::new(3, 3, 4).unwrap();
        let density: Vec<f32> = (0..dims.sites()).map(|i| (i % 4) as f32 / 4.0).collect();
        let wood = vec![0.25; dims.sites()];
        let grid = DensityGrid::new(dims, Bounds::UNIT, density.clone(), wood).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.sgrid");
        GridFile::from_density(&grid, vec![("source".into(), "test".into())])
            .write(&path)
            .unwrap();
        let info = GridInfo::read(&path).unwrap();
        assert_eq!(info.channels.len(), 2);
        let d = &info.channels[0];
        assert_eq!((d.min, d.max), (0.0, 0.75));
        let mean = density.iter().map(|&v| v as f64).sum::<f64>() / density.len() as f64;
        assert!((d.mean - mean).abs() < 1e-12);
        assert_eq!(info.occupancy, Some(grid.occupancy()));
        let text = info.to_string();
        assert!(text.contains("  kind:      density grid\n"), "{text}");
        assert!(text.contains("  source     test\n"), "{text}");

        let raw = dir.path().join("r.bin");
        std::fs::write(&raw, vec![255u8; dims.sites()]).unwrap();
        let g = read_raw(&raw, dims, RawElement::U8).unwrap();
        assert!(g.density.iter().all(|&d| d == 1.0));
        let e = read_raw(&raw, dims, RawElement::F32).unwrap_err();
        assert!(
            e.to_string().contains("needs 144 bytes, the file has 36"),
            "{e}"
        );
    }
}
