//! The sites where light matters: where a renderer looks the lighting up.
//!
//! A plant's LB light is read at surface points of the plant, which lie in occupied cells; a
//! trilinear lookup there reads the cell's corner sites, one site beyond the medium. The ground
//! under a tree reads the lowest layers of its grid. Compression spends its bits there
//! (elsewhere it keeps coarse block means) and its error is measured there.

use crate::grid::{DensityGrid, Dims};

/// A set of sites of one grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Region {
    pub dims: Dims,
    mask: Vec<bool>,
}

impl Region {
    /// Every site.
    pub fn all(dims: Dims) -> Region {
        Region {
            dims,
            mask: vec![true; dims.sites()],
        }
    }

    /// Sites within `margin` sites (along every axis, diagonals included) of a site whose
    /// density is above 0. `margin = 1` covers every lookup at a point inside the medium.
    pub fn near_medium(grid: &DensityGrid, margin: usize) -> Region {
        let dims = grid.dims;
        let mut mask: Vec<bool> = grid.density.iter().map(|&d| d > 0.0).collect();
        // A cube of half-width `margin` is the product of three intervals: dilate axis by axis.
        let n = [dims.nx, dims.ny, dims.nz];
        for axis in 0..3 {
            let stride = match axis {
                0 => dims.ny * dims.nz,
                1 => dims.nz,
                _ => 1,
            };
            let src = mask.clone();
            for (i, m) in mask.iter_mut().enumerate() {
                if *m {
                    continue;
                }
                let c = [dims.coords(i).0, dims.coords(i).1, dims.coords(i).2][axis];
                let lo = c.saturating_sub(margin);
                let hi = c.saturating_add(margin).min(n[axis] - 1);
                *m = (lo..=hi).any(|k| src[i - c * stride + k * stride]);
            }
        }
        Region { dims, mask }
    }

    /// This region plus the lowest `layers` planes of sites along y (+y is up), where the
    /// ground under a plant looks its grid up.
    pub fn with_floor(mut self, layers: usize) -> Region {
        for (i, m) in self.mask.iter_mut().enumerate() {
            if self.dims.coords(i).1 < layers {
                *m = true;
            }
        }
        self
    }

    #[inline]
    pub fn contains(&self, index: usize) -> bool {
        self.mask[index]
    }

    /// Site indices in the region, ascending.
    pub fn sites(&self) -> Vec<usize> {
        (0..self.mask.len()).filter(|&i| self.mask[i]).collect()
    }

    pub fn count(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_is_a_cube_of_the_margin() {
        let dims = Dims::new(9, 8, 7).unwrap();
        let mut g = DensityGrid::empty(dims);
        g.density[dims.index(4, 3, 3)] = 0.5;
        g.density[dims.index(1, 1, 1)] = 0.1;
        for margin in 0..3 {
            let r = Region::near_medium(&g, margin);
            for i in 0..dims.sites() {
                let (x, y, z) = dims.coords(i);
                let near = |(a, b, c): (usize, usize, usize)| {
                    x.abs_diff(a) <= margin && y.abs_diff(b) <= margin && z.abs_diff(c) <= margin
                };
                assert_eq!(
                    r.contains(i),
                    near((4, 3, 3)) || near((1, 1, 1)),
                    "margin {margin} site ({x},{y},{z})"
                );
            }
        }
        let floor = Region::near_medium(&g, 0).with_floor(2);
        assert_eq!(floor.count(), 2 * 9 * 7 + 1);
        assert_eq!(Region::all(dims).count(), dims.sites());
        assert_eq!(Region::near_medium(&g, 0).sites().len(), 2);
    }
}
