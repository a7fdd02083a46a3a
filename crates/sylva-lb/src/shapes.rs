//! Built-in density grids for trying the solver without a model.

use crate::grid::{Bounds, DensityGrid, Dims};

/// A built-in medium.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// A solid ball of density 1, radius 0.4 of the grid.
    Sphere,
    /// A solid cube of density 1, 0.6 of the grid on a side.
    Cube,
    /// A tree-like test object: a brown trunk under an ellipsoidal leafy crown whose density
    /// thins towards its rim.
    Crown,
}

/// A shape name that is none of [`Shape::ALL`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown shape '{0}': expected sphere, cube or crown")]
pub struct UnknownShape(pub String);

impl Shape {
    pub const ALL: [Shape; 3] = [Shape::Sphere, Shape::Cube, Shape::Crown];

    pub fn name(self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Cube => "cube",
            Shape::Crown => "crown",
        }
    }

    /// [`Shape::parse`], or an error naming the shapes.
    pub fn named(s: &str) -> Result<Shape, UnknownShape> {
        Shape::parse(s).ok_or_else(|| UnknownShape(s.to_string()))
    }

    pub fn parse(s: &str) -> Option<Shape> {
        Shape::ALL
            .into_iter()
            .find(|x| x.name().eq_ignore_ascii_case(s))
    }

    /// Fills a grid; shell sites stay empty (they hold the boundary).
    pub fn grid(self, dims: Dims) -> DensityGrid {
        let mut g = DensityGrid::empty(dims);
        // Normalised coordinates in [-1, 1] about the grid centre, y up.
        let norm = |v: usize, n: usize| 2.0 * v as f32 / (n - 1) as f32 - 1.0;
        for x in 1..dims.nx - 1 {
            for y in 1..dims.ny - 1 {
                for z in 1..dims.nz - 1 {
                    let (u, v, w) = (norm(x, dims.nx), norm(y, dims.ny), norm(z, dims.nz));
                    let (rho, wood) = match self {
                        Shape::Sphere => (f32::from(u * u + v * v + w * w <= 0.64), 0.0),
                        Shape::Cube => (
                            f32::from(u.abs() <= 0.6 && v.abs() <= 0.6 && w.abs() <= 0.6),
                            0.0,
                        ),
                        Shape::Crown => crown(u, v, w),
                    };
                    let i = dims.index(x, y, z);
                    g.density[i] = rho;
                    g.wood[i] = wood;
                }
            }
        }
        g.bounds = Bounds {
            min: [-1.0; 3],
            max: [1.0; 3],
        };
        g
    }
}

fn crown(u: f32, v: f32, w: f32) -> (f32, f32) {
    let trunk = u * u + w * w <= 0.08 * 0.08 && v <= 0.1;
    if trunk {
        return (1.0, 1.0);
    }
    let r2 = (u / 0.8).powi(2) + ((v - 0.3) / 0.6).powi(2) + (w / 0.8).powi(2);
    if r2 <= 1.0 {
        (0.3 + 0.4 * (1.0 - r2), 0.0)
    } else {
        (0.0, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_are_symmetric_and_keep_the_shell_empty() {
        let d = Dims::cube(17).unwrap();
        for s in Shape::ALL {
            let g = s.grid(d);
            for x in 0..17 {
                for y in 0..17 {
                    for z in 0..17 {
                        let i = d.index(x, y, z);
                        if d.on_shell(x, y, z) {
                            assert_eq!(g.density[i], 0.0);
                        }
                        // Mirror symmetry in x and z, and x↔z.
                        assert_eq!(g.density[i], g.density[d.index(16 - x, y, z)]);
                        assert_eq!(g.density[i], g.density[d.index(x, y, 16 - z)]);
                        assert_eq!(g.density[i], g.density[d.index(z, y, x)]);
                    }
                }
            }
            assert!(g.occupancy().1 > 0, "{}", s.name());
        }
        let crown = Shape::Crown.grid(d);
        assert!(crown.wood.contains(&1.0));
        assert_eq!(Shape::parse("CROWN"), Some(Shape::Crown));
        assert_eq!(Shape::parse("torus"), None);
    }
}
