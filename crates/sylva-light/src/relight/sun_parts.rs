//! The sun's parts of the physical light's base solutions (docs/relight.md, "The physical
//! light relit"): the 13 lattice directions a sun above the horizon travels along, and the
//! weights of a sun's direction over them (the polyhedron face it crosses, 004 §3.1). Shared
//! by the models' bases ([`super::physical`]) and the forest grid's ([`crate::forest`]).

use sylva_lb::lattice::{C, Q};
use sylva_lb::relight::{face_hit, RelightError};

use crate::lighting::LightingError;

/// The sun's parts per model: one per lattice direction with `c_y ≤ 0`.
pub const SUN_PARTS: usize = 13;
/// The lattice directions (1..=18) a sun above the horizon travels along, lattice order.
pub const SUN_DIRECTIONS: [usize; SUN_PARTS] = sun_directions();

const fn sun_directions() -> [usize; SUN_PARTS] {
    let mut out = [0; SUN_PARTS];
    let (mut n, mut k) = (0, 1);
    while k < Q {
        if C[k][1] <= 0 {
            out[n] = k;
            n += 1;
        }
        k += 1;
    }
    out
}

/// The part (index into [`SUN_DIRECTIONS`]) solved with the sun straight down, whose plan
/// also solves the diffuse parts.
pub fn overhead_part() -> usize {
    SUN_DIRECTIONS
        .iter()
        .position(|&k| C[k] == [0, -1, 0])
        .expect("the lattice has a downward direction")
}

/// The sun's parts and their weights for sunlight travelling along `travel` (any length): the
/// polyhedron face it crosses, its barycentric weights (004 §3.1), as indices into
/// [`SUN_DIRECTIONS`]. Empty when the sun is below the horizon (`travel` upward).
pub fn sun_part_weights(travel: [f64; 3]) -> Result<Vec<(usize, f64)>, LightingError> {
    let hit = face_hit(travel).map_err(|e| LightingError::Relight(RelightError::from(e)))?;
    if travel[1] > 0.0 {
        return Ok(Vec::new());
    }
    let mut out = Vec::with_capacity(3);
    for (&v, &w) in hit.vertices.iter().zip(&hit.weights) {
        if w <= 0.0 {
            continue;
        }
        match SUN_DIRECTIONS.iter().position(|&k| k == v) {
            Some(part) => out.push((part, w)),
            // A face of a sun at the horizon may touch an upward direction with weight ~0.
            None if w < 1e-9 => {}
            None => {
                return Err(LightingError::Illumination(format!(
                    "sun travelling along {travel:?}: lattice direction {v} has no sun part"
                )))
            }
        }
    }
    Ok(out)
}
