//! Where a trilinear lookup reads: model space to grid coordinates, and the 2×2×2 sites around
//! a point.
//!
//! Same placement as the renderer's LB lookup: site `(i, j, k)` sits at
//! `bounds.min + (i, j, k) · cell`, `cell = (max - min) / (dims - 1)` per axis; points outside
//! the grid clamp to the nearest site, NaN to site 0.

use crate::grid::{Bounds, Dims};

/// Model space to grid coordinates for one grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    origin: [f32; 3],
    /// Sites per model-space unit (0 along a degenerate axis).
    inv_cell: [f32; 3],
}

impl Placement {
    pub fn new(dims: Dims, bounds: Bounds) -> Placement {
        let n = [dims.nx, dims.ny, dims.nz];
        Placement {
            origin: bounds.min,
            inv_cell: std::array::from_fn(|a| {
                let extent = bounds.max[a] - bounds.min[a];
                if extent > 0.0 && extent.is_finite() {
                    (n[a] - 1) as f32 / extent
                } else {
                    0.0
                }
            }),
        }
    }

    /// Grid coordinates (in sites) of model-space point `p`, not clamped.
    #[inline]
    pub fn grid_coords(&self, p: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| (p[a] - self.origin[a]) * self.inv_cell[a])
    }

    /// The model-space point of site `(0, 0, 0)`.
    pub fn origin(&self) -> [f32; 3] {
        self.origin
    }

    /// Sites per model-space unit along each axis (0 along a degenerate axis).
    pub fn inv_cell(&self) -> [f32; 3] {
        self.inv_cell
    }

    /// The model-space point at grid coordinates `g` (the inverse of
    /// [`Placement::grid_coords`]; a degenerate axis stays at the origin).
    pub fn model_point(&self, g: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| {
            if self.inv_cell[a] > 0.0 {
                self.origin[a] + g[a] / self.inv_cell[a]
            } else {
                self.origin[a]
            }
        })
    }
}

/// The lower corner of a trilinear lookup and the fractions towards the upper corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Lower corner site; the upper corner is `corner + 1` on every axis (inside the grid).
    pub corner: [usize; 3],
    /// Fractions in [0, 1] per axis.
    pub t: [f32; 3],
}

impl Footprint {
    /// The footprint at grid coordinates `g`, clamped to the grid.
    #[inline]
    pub fn at(dims: Dims, g: [f32; 3]) -> Footprint {
        let n = [dims.nx, dims.ny, dims.nz];
        let mut corner = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let last = (n[a] - 1) as f32;
            // `max` before `min` turns NaN into 0.
            let f = g[a].max(0.0).min(last);
            // Grids have at least 3 sites per axis, so corner + 1 always exists.
            let i = f.floor().min(last - 1.0);
            corner[a] = i as usize;
            t[a] = f - i;
        }
        Footprint { corner, t }
    }

    /// Trilinear weights of the 8 corners, corner `(dx, dy, dz)` at index `4 dx + 2 dy + dz`.
    #[inline]
    pub fn weights(&self) -> [f32; 8] {
        let [tx, ty, tz] = self.t;
        std::array::from_fn(|k| {
            let f = |bit: usize, t: f32| if k >> bit & 1 == 1 { t } else { 1.0 - t };
            f(2, tx) * f(1, ty) * f(0, tz)
        })
    }

    /// Site indices of the 8 corners, in [`Footprint::weights`] order.
    #[inline]
    pub fn sites(&self, dims: Dims) -> [usize; 8] {
        let [x, y, z] = self.corner;
        std::array::from_fn(|k| dims.index(x + (k >> 2), y + (k >> 1 & 1), z + (k & 1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placement_and_clamping() {
        let dims = Dims::new(5, 4, 7).unwrap();
        let bounds = Bounds {
            min: [-1.0, 0.5, 2.0],
            max: [3.0, 2.0, 5.0],
        };
        let p = Placement::new(dims, bounds);
        assert_eq!(p.grid_coords(bounds.min), [0.0; 3]);
        assert_eq!(p.grid_coords(bounds.max), [4.0, 3.0, 6.0]);
        assert_eq!(p.model_point([4.0, 3.0, 6.0]), bounds.max);
        assert_eq!(p.model_point([0.0; 3]), bounds.min);
        let f = Footprint::at(dims, [4.0, 1.25, -3.0]);
        assert_eq!(f.corner, [3, 1, 0]);
        assert_eq!(f.t, [1.0, 0.25, 0.0]);
        let f = Footprint::at(dims, [f32::NAN, 1e30, f32::INFINITY]);
        assert_eq!(f.corner, [0, 2, 5]);
        assert_eq!(f.t, [0.0, 1.0, 1.0]);
        let w = Footprint::at(dims, [0.5, 0.5, 0.5]).weights();
        assert!(w.iter().all(|&v| v == 0.125));
        let f = Footprint::at(dims, [1.25, 1.5, 0.75]);
        assert_eq!(f.corner, [1, 1, 0]);
        let w = f.weights();
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert_eq!(w[0b010], 0.75 * 0.5 * 0.25);
        assert_eq!(f.sites(dims)[0b011], dims.index(1, 2, 1));
    }
}
