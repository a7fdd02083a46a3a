//! Density grids (the medium the solver lights) and lighting grids (its result).
//!
//! Both are dense 3-D arrays over `nx × ny × nz` sites indexed `(x * ny + y) * nz + z`: z, the
//! innermost axis, is fastest, as in the solver's state (002 §3.1). +y is up.

use thiserror::Error;

/// Largest edge the tools accept ([`sylva_core::limits::GRID_EDGE`]): far beyond any grid
/// that fits in memory, small enough that index arithmetic can never overflow.
pub const MAX_EDGE: usize = *sylva_core::limits::GRID_EDGE.end();
/// Smallest edge: the outer shell is the boundary, so 3 is the smallest grid with an interior.
pub const MIN_EDGE: usize = *sylva_core::limits::GRID_EDGE.start();

/// Element type of a raw grid file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawElement {
    U8,
    F32,
}

impl RawElement {
    pub fn size(self) -> usize {
        match self {
            RawElement::U8 => 1,
            RawElement::F32 => 4,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            RawElement::U8 => "u8",
            RawElement::F32 => "f32",
        }
    }
}

/// A grid size given on the command line refused, the flag named.
#[derive(Debug, Error, PartialEq)]
pub enum DimsFlagError {
    #[error("{flag} '{text}'")]
    Bad {
        flag: &'static str,
        text: String,
        #[source]
        source: GridError,
    },
    #[error("{flag} '{text}': expected N or NXxNYxNZ, e.g. 128 or 256x128x128")]
    Syntax { flag: &'static str, text: String },
}

#[derive(Debug, Error, PartialEq)]
pub enum GridError {
    #[error("grid size {0}×{1}×{2} is invalid: every edge must be between {MIN_EDGE} and {MAX_EDGE} (the outer shell is the boundary, so 3 is the smallest grid with an interior)")]
    BadDims(usize, usize, usize),
    #[error("{what} has {got} values, but a {dims} grid needs {want}")]
    Length {
        what: String,
        got: usize,
        want: usize,
        dims: Dims,
    },
    #[error("{what} at site ({x}, {y}, {z}) is {value}: values must be finite and in [0, 1]")]
    BadValue {
        what: String,
        x: usize,
        y: usize,
        z: usize,
        value: f32,
    },
}

/// Grid dimensions in sites.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dims {
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
}

impl std::fmt::Display for Dims {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}×{}×{}", self.nx, self.ny, self.nz)
    }
}

impl Dims {
    pub fn new(nx: usize, ny: usize, nz: usize) -> Result<Dims, GridError> {
        let ok = |n: usize| sylva_core::limits::GRID_EDGE.contains(&n);
        if !(ok(nx) && ok(ny) && ok(nz)) {
            return Err(GridError::BadDims(nx, ny, nz));
        }
        Ok(Dims { nx, ny, nz })
    }

    pub fn cube(n: usize) -> Result<Dims, GridError> {
        Dims::new(n, n, n)
    }

    /// Parses `"128"` (a cube) or `"256x128x128"`.
    pub fn parse(s: &str) -> Option<Result<Dims, GridError>> {
        let parts: Vec<usize> = s
            .split(['x', 'X', '×'])
            .map(|p| p.trim().parse().ok())
            .collect::<Option<_>>()?;
        match parts.as_slice() {
            [n] => Some(Dims::cube(*n)),
            [x, y, z] => Some(Dims::new(*x, *y, *z)),
            _ => None,
        }
    }

    /// [`Dims::parse`] of flag `flag`'s value `text`, the flag named in the error.
    pub fn parse_flag(text: &str, flag: &'static str) -> Result<Dims, DimsFlagError> {
        match Dims::parse(text) {
            Some(d) => d.map_err(|source| DimsFlagError::Bad {
                flag,
                text: text.to_string(),
                source,
            }),
            None => Err(DimsFlagError::Syntax {
                flag,
                text: text.to_string(),
            }),
        }
    }

    pub fn sites(&self) -> usize {
        self.nx * self.ny * self.nz
    }

    pub fn longest_edge(&self) -> usize {
        self.nx.max(self.ny).max(self.nz)
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (x * self.ny + y) * self.nz + z
    }

    pub fn coords(&self, index: usize) -> (usize, usize, usize) {
        let z = index % self.nz;
        let y = (index / self.nz) % self.ny;
        (index / (self.nz * self.ny), y, z)
    }

    /// Whether site `index` lies on the outer shell.
    #[inline]
    pub fn on_shell_index(&self, index: usize) -> bool {
        let (x, y, z) = self.coords(index);
        self.on_shell(x, y, z)
    }

    /// Sites of the outer shell hold the boundary values.
    #[inline]
    pub fn on_shell(&self, x: usize, y: usize, z: usize) -> bool {
        x == 0 || y == 0 || z == 0 || x == self.nx - 1 || y == self.ny - 1 || z == self.nz - 1
    }
}

/// Axis-aligned box in model or world space that a grid covers (site centres span it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Bounds {
    /// The unit cube, used for grids that come without a placement.
    pub const UNIT: Bounds = Bounds {
        min: [0.0; 3],
        max: [1.0; 3],
    };
}

/// The medium: per site a density ρ ∈ [0, 1] and the fraction of it that is wood.
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    pub dims: Dims,
    pub bounds: Bounds,
    pub density: Vec<f32>,
    pub wood: Vec<f32>,
}

fn check_values(what: &str, dims: Dims, v: &[f32]) -> Result<(), GridError> {
    if v.len() != dims.sites() {
        return Err(GridError::Length {
            what: what.into(),
            got: v.len(),
            want: dims.sites(),
            dims,
        });
    }
    if let Some((i, &value)) = v
        .iter()
        .enumerate()
        .find(|(_, x)| !(x.is_finite() && (0.0..=1.0).contains(*x)))
    {
        let (x, y, z) = dims.coords(i);
        return Err(GridError::BadValue {
            what: what.into(),
            x,
            y,
            z,
            value,
        });
    }
    Ok(())
}

impl DensityGrid {
    /// An empty medium (all density 0, no wood).
    pub fn empty(dims: Dims) -> DensityGrid {
        DensityGrid {
            dims,
            bounds: Bounds::UNIT,
            density: vec![0.0; dims.sites()],
            wood: vec![0.0; dims.sites()],
        }
    }

    /// A headerless raw grid (`lb solve --raw`): densities in site order (x slowest, z
    /// fastest), `u8` (0..255 maps to 0..1) or little-endian `f32`; no wood, unit bounds.
    /// The byte count must match `dims` exactly.
    pub fn from_raw(
        dims: Dims,
        bytes: &[u8],
        element: RawElement,
    ) -> Result<DensityGrid, GridError> {
        let size = element.size();
        let want = dims.sites() * size;
        if bytes.len() != want {
            return Err(GridError::Length {
                what: format!("a raw {} file ({} bytes)", element.name(), bytes.len()),
                got: bytes.len() / size,
                want: dims.sites(),
                dims,
            });
        }
        let density: Vec<f32> = match element {
            RawElement::F32 => bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            RawElement::U8 => bytes.iter().map(|&b| b as f32 / 255.0).collect(),
        };
        DensityGrid::new(dims, Bounds::UNIT, density, vec![0.0; dims.sites()])
    }

    /// Validates lengths and ranges: density and wood fraction must be finite and in [0, 1].
    pub fn new(
        dims: Dims,
        bounds: Bounds,
        density: Vec<f32>,
        wood: Vec<f32>,
    ) -> Result<DensityGrid, GridError> {
        check_values("density", dims, &density)?;
        check_values("wood fraction", dims, &wood)?;
        Ok(DensityGrid {
            dims,
            bounds,
            density,
            wood,
        })
    }

    /// Sites with density > 0 whose wood fraction exceeds `threshold` (brown sites in the LB).
    pub fn wood_sites(&self, threshold: f32) -> usize {
        self.density
            .iter()
            .zip(&self.wood)
            .filter(|(&d, &w)| d > 0.0 && w > threshold)
            .count()
    }

    /// One line describing the grid: size, occupancy, mean density, brown sites.
    pub fn summary(&self) -> String {
        let (mean, occupied) = self.occupancy();
        format!(
            "{} grid, {occupied} occupied sites ({:.1} %), mean density {mean:.4} ({:.4} over occupied sites), {} wood sites (wood fraction > 0.5)",
            self.dims,
            100.0 * occupied as f64 / self.dims.sites() as f64,
            mean * self.dims.sites() as f64 / occupied.max(1) as f64,
            self.wood_sites(0.5)
        )
    }

    /// Mean density over the grid and number of occupied sites.
    pub fn occupancy(&self) -> (f64, usize) {
        let sum: f64 = self.density.iter().map(|&d| d as f64).sum();
        let n = self.density.iter().filter(|&&d| d > 0.0).count();
        (sum / self.dims.sites() as f64, n)
    }
}

/// Steady-state total density `Σ_m f_m` per site and colour.
#[derive(Debug, Clone, PartialEq)]
pub struct LightingGrid {
    pub dims: Dims,
    pub bounds: Bounds,
    /// R, G, B.
    pub colours: [Vec<f32>; 3],
}

impl LightingGrid {
    pub fn at(&self, x: usize, y: usize, z: usize) -> [f32; 3] {
        let i = self.dims.index(x, y, z);
        [self.colours[0][i], self.colours[1][i], self.colours[2][i]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid flag's value: a cube or three edges; a bad size or syntax names the flag.
    #[test]
    fn grid_flags_parse_or_name_the_flag() {
        assert_eq!(
            Dims::parse_flag("16", "--grid").unwrap(),
            Dims::cube(16).unwrap()
        );
        assert_eq!(
            Dims::parse_flag("8x4x6", "--grid").unwrap(),
            Dims::new(8, 4, 6).unwrap()
        );
        let e = Dims::parse_flag("12x", "--raw-dims").unwrap_err();
        assert_eq!(
            e.to_string(),
            "--raw-dims '12x': expected N or NXxNYxNZ, e.g. 128 or 256x128x128"
        );
        assert!(matches!(
            Dims::parse_flag("2", "--grid"),
            Err(DimsFlagError::Bad { flag: "--grid", .. })
        ));
    }

    #[test]
    fn dims_parse_and_index() {
        let d = Dims::parse("4x5x6").unwrap().unwrap();
        assert_eq!(d.sites(), 120);
        for i in 0..d.sites() {
            let (x, y, z) = d.coords(i);
            assert_eq!(d.index(x, y, z), i);
        }
        assert_eq!(Dims::parse("64").unwrap().unwrap(), Dims::cube(64).unwrap());
        assert!(Dims::parse("4x5").is_none());
        assert!(Dims::parse("abc").is_none());
        assert_eq!(
            Dims::parse("2x8x8").unwrap(),
            Err(GridError::BadDims(2, 8, 8))
        );
        assert!(Dims::cube(100_000).is_err());
    }

    #[test]
    fn density_values_checked() {
        let d = Dims::cube(3).unwrap();
        let mut rho = vec![0.5; 27];
        rho[d.index(1, 2, 0)] = f32::NAN;
        let err = DensityGrid::new(d, Bounds::UNIT, rho, vec![0.0; 27]).unwrap_err();
        assert!(err.to_string().contains("(1, 2, 0)"), "{err}");
        let err = DensityGrid::new(d, Bounds::UNIT, vec![0.5; 26], vec![0.0; 27]).unwrap_err();
        assert!(matches!(err, GridError::Length { .. }));
    }
}
