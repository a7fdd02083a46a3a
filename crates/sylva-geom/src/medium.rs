//! Participating media placed in a scene (clouds): a density grid over a world-space box,
//! lit by the LB solver and drawn by the renderer's volume tracer (paper 002 §3.2.1).

use std::sync::Arc;

use crate::mesh::Aabb;
use glam::Vec3;
use sylva_core::Fnv64;

/// Largest edge of a medium's grid, as for LB grids.
pub const MAX_MEDIUM_EDGE: usize = 4096;

/// A density grid placed in the world. Site `(i, j, k)` sits at `bounds.min + (i, j, k) ·
/// cell`; the sites span `bounds` exactly, and cells are cubes: one LB lattice step is the
/// same length along every axis. The outer shell of sites holds the LB boundary, so its
/// density must be 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Medium {
    pub name: String,
    /// Sites along x, y, z (each at least 3).
    pub dims: [usize; 3],
    /// World box spanned by the site centres.
    pub bounds: Aabb,
    /// Density ρ ∈ [0, 1] per site, index `(x · ny + y) · nz + z` (z fastest, as LB grids).
    /// Shared: scenes are cloned, grids are large.
    pub density: Arc<Vec<f32>>,
    /// Name of the LB preset that gives its σ_a, σ_s and g per lattice step (`cloud`).
    pub preset: String,
}

impl Medium {
    /// Checks the grid: sizes, density values (finite, in [0, 1], zero on the shell), a
    /// finite box with cubic cells. The error says what is wrong, in words.
    pub fn new(
        name: impl Into<String>,
        dims: [usize; 3],
        bounds: Aabb,
        density: Vec<f32>,
        preset: impl Into<String>,
    ) -> Result<Medium, String> {
        let name = name.into();
        if dims.iter().any(|&n| !(3..=MAX_MEDIUM_EDGE).contains(&n)) {
            return Err(format!(
                "medium '{name}': grid {}×{}×{} must have 3 to {MAX_MEDIUM_EDGE} sites per edge",
                dims[0], dims[1], dims[2]
            ));
        }
        let sites = dims[0] * dims[1] * dims[2];
        if density.len() != sites {
            return Err(format!(
                "medium '{name}': {} density values for a {}×{}×{} grid ({sites} sites)",
                density.len(),
                dims[0],
                dims[1],
                dims[2]
            ));
        }
        let (min, max) = (bounds.min, bounds.max);
        if !(min.is_finite() && max.is_finite()) || min.cmpge(max).any() {
            return Err(format!(
                "medium '{name}': box {:?}..{:?} must be finite with max > min on every axis",
                min.to_array(),
                max.to_array()
            ));
        }
        let cells =
            (max - min) / (Vec3::new(dims[0] as f32, dims[1] as f32, dims[2] as f32) - Vec3::ONE);
        let h = cells.x;
        if (cells - Vec3::splat(h)).abs().max_element() > 1e-4 * h {
            return Err(format!(
                "medium '{name}': cells are {} × {} × {}: they must be cubes (one LB step has one length)",
                cells.x, cells.y, cells.z
            ));
        }
        let m = Medium {
            name,
            dims,
            bounds,
            density: Arc::new(density),
            preset: preset.into(),
        };
        for (i, &rho) in m.density.iter().enumerate() {
            let (x, y, z) = m.coords(i);
            if !(rho.is_finite() && (0.0..=1.0).contains(&rho)) {
                return Err(format!(
                    "medium '{}': density at site ({x}, {y}, {z}) is {rho}: it must be in [0, 1]",
                    m.name
                ));
            }
            if rho != 0.0 && m.on_shell(x, y, z) {
                return Err(format!(
                    "medium '{}': density at shell site ({x}, {y}, {z}) is {rho}: the outer shell holds the LB boundary and must be empty",
                    m.name
                ));
            }
        }
        Ok(m)
    }

    /// World length of one cell (one LB lattice step).
    pub fn cell(&self) -> f32 {
        (self.bounds.max.x - self.bounds.min.x) / (self.dims[0] - 1) as f32
    }

    pub fn sites(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (x * self.dims[1] + y) * self.dims[2] + z
    }

    pub fn coords(&self, index: usize) -> (usize, usize, usize) {
        let [_, ny, nz] = self.dims;
        (index / (ny * nz), (index / nz) % ny, index % nz)
    }

    pub fn on_shell(&self, x: usize, y: usize, z: usize) -> bool {
        let [nx, ny, nz] = self.dims;
        x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1
    }

    /// Stable hash of the grid (sizes and density bit patterns): equal hashes, equal media.
    /// Part of LB cache keys.
    pub fn density_hash(&self) -> u64 {
        let mut h = Fnv64::new();
        for n in self.dims {
            h.u64(n as u64);
        }
        for &v in self.density.iter() {
            h.f32(v);
        }
        h.finish()
    }

    /// Mean density over the grid and the number of sites with density.
    pub fn occupancy(&self) -> (f64, usize) {
        let sum: f64 = self.density.iter().map(|&d| d as f64).sum();
        let n = self.density.iter().filter(|&&d| d > 0.0).count();
        (sum / self.sites() as f64, n)
    }

    /// Bytes of the density grid.
    pub fn memory_bytes(&self) -> u64 {
        (self.density.len() * 4) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boxed(n: [usize; 3], h: f32) -> Aabb {
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(
                (n[0] - 1) as f32 * h,
                (n[1] - 1) as f32 * h,
                (n[2] - 1) as f32 * h,
            ),
        }
    }

    #[test]
    fn checks_sizes_values_shell_and_cells() {
        let n = [5, 4, 3];
        let mut rho = vec![0.0f32; 60];
        let m = Medium::new("c", n, boxed(n, 0.5), rho.clone(), "cloud").unwrap();
        rho[m.index(2, 1, 1)] = 0.7;
        let m = Medium::new("c", n, boxed(n, 0.5), rho.clone(), "cloud").unwrap();
        assert_eq!(m.cell(), 0.5);
        assert_eq!(m.coords(m.index(3, 2, 1)), (3, 2, 1));
        assert_eq!(m.occupancy().1, 1);

        let e = Medium::new("c", [2, 4, 3], boxed(n, 0.5), vec![0.0; 24], "cloud").unwrap_err();
        assert!(e.contains("3 to 4096"), "{e}");
        let e = Medium::new("c", n, boxed(n, 0.5), vec![0.0; 59], "cloud").unwrap_err();
        assert!(e.contains("59 density values"), "{e}");
        let mut bad = rho.clone();
        bad[m.index(1, 1, 1)] = f32::NAN;
        let e = Medium::new("c", n, boxed(n, 0.5), bad, "cloud").unwrap_err();
        assert!(e.contains("(1, 1, 1) is NaN"), "{e}");
        let mut shell = rho.clone();
        shell[m.index(0, 1, 1)] = 0.1;
        let e = Medium::new("c", n, boxed(n, 0.5), shell, "cloud").unwrap_err();
        assert!(e.contains("shell"), "{e}");
        let mut stretched = boxed(n, 0.5);
        stretched.max.y *= 2.0;
        let e = Medium::new("c", n, stretched, rho.clone(), "cloud").unwrap_err();
        assert!(e.contains("cubes"), "{e}");
        let mut inf = boxed(n, 0.5);
        inf.max.x = f32::INFINITY;
        assert!(Medium::new("c", n, inf, rho, "cloud").is_err());
    }

    #[test]
    fn hash_sees_every_value() {
        let n = [3, 3, 4];
        let a = Medium::new("a", n, boxed(n, 1.0), vec![0.0; 36], "cloud").unwrap();
        let mut rho = vec![0.0; 36];
        rho[a.index(1, 1, 2)] = 1e-6;
        let b = Medium::new("a", n, boxed(n, 1.0), rho, "cloud").unwrap();
        assert_ne!(a.density_hash(), b.density_hash());
        // Same values, other shape.
        let c = Medium::new(
            "a",
            [3, 4, 3],
            boxed([3, 4, 3], 1.0),
            vec![0.0; 36],
            "cloud",
        )
        .unwrap();
        assert_ne!(a.density_hash(), c.density_hash());
    }
}
