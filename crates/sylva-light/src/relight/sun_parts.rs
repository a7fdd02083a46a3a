//! The sun's parts of the physical light's base solutions (docs/relight.md, "The physical
//! light relit"): the directions a unit sun is solved along, and the weights of any sun's
//! direction over them. Shared by the models' bases ([`super::physical`]) and the forest
//! grid's ([`crate::forest`]).
//!
//! **The directions.** The 13 lattice directions a sun above the horizon travels along (004
//! §3.1's polyhedron vertices with `c_y ≤ 0`: the zenith, four at 45° elevation, eight on the
//! horizon), then a ring at 22.5° elevation (8 azimuths, every 45°) and one at 67.5° (the 4
//! azimuths between the 45° ones). The lattice alone samples elevation at 0°, 45° and 90°, so
//! a sun at 35° took a third of its light from a crown lit from the side with no sunlit floor
//! (6 % bright on plants against Mitsuba); with the rings no sun is farther than about 24°
//! from its nearest part. A part is a first-collision source along its exact direction, which
//! needs no lattice direction.
//!
//! **The weights.** The convex hull of the directions and their mirror images below the
//! horizon (so the hull closes without a face through the origin) is triangulated once; a
//! sun's travel direction crosses one face, and its barycentric weights on that face's plane
//! (cone coordinates normalised to sum 1, as 004 §3.1 weighs its polyhedron's faces) weigh
//! the face's three parts. At a part's direction the weight is that part's alone. Where four
//! directions lie on one hull face (the sets are symmetric) the face is split in two.

use std::sync::OnceLock;

use glam::DVec3;
use sylva_lb::lattice::{unit, C, Q};
use sylva_lb::relight::normalise;

use crate::lighting::LightingError;

/// The sun's parts per model: 13 lattice directions and 12 on the two rings.
pub const SUN_PARTS: usize = 13 + RING_LOW + RING_HIGH;
const RING_LOW: usize = 8;
const RING_HIGH: usize = 4;
const LOW_ELEVATION_DEG: f64 = 22.5;
const HIGH_ELEVATION_DEG: f64 = 67.5;

/// Coordinates below this still count as inside a face (rounding on its edges).
const INSIDE_TOLERANCE: f64 = 1e-12;

/// The lattice directions (1..=18) a sun above the horizon travels along, lattice order:
/// parts `0..13`.
pub const LATTICE_SUN_DIRECTIONS: [usize; 13] = lattice_sun_directions();

const fn lattice_sun_directions() -> [usize; 13] {
    let mut out = [0; 13];
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

/// Unit travel direction of a sun at `elevation_deg` above the horizon and `azimuth_deg` from
/// +x towards +z (y is up, so the light travels downward).
fn ring_travel(elevation_deg: f64, azimuth_deg: f64) -> [f64; 3] {
    let (e, a) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
    [-e.cos() * a.cos(), -e.sin(), -e.cos() * a.sin()]
}

/// The unit direction sunlight travels along for each part, in part order.
pub fn sun_directions() -> &'static [[f64; 3]; SUN_PARTS] {
    static DIRECTIONS: OnceLock<[[f64; 3]; SUN_PARTS]> = OnceLock::new();
    DIRECTIONS.get_or_init(|| {
        let mut out = Vec::with_capacity(SUN_PARTS);
        out.extend(LATTICE_SUN_DIRECTIONS.iter().map(|&k| unit(k)));
        out.extend((0..RING_LOW).map(|k| ring_travel(LOW_ELEVATION_DEG, 45.0 * k as f64)));
        out.extend((0..RING_HIGH).map(|k| ring_travel(HIGH_ELEVATION_DEG, 45.0 + 90.0 * k as f64)));
        out.try_into().expect("SUN_PARTS directions")
    })
}

/// The lattice direction (1..=18) part `part` travels along, if it is one.
pub fn lattice_direction(part: usize) -> Option<usize> {
    LATTICE_SUN_DIRECTIONS.get(part).copied()
}

/// The part solved with the sun straight down, whose plan also solves the diffuse parts.
pub fn overhead_part() -> usize {
    LATTICE_SUN_DIRECTIONS
        .iter()
        .position(|&k| C[k] == [0, -1, 0])
        .expect("the lattice has a downward direction")
}

/// One triangle of the hull: three vertices (indices into [`hull_vertices`]), outward.
#[derive(Debug, Clone, Copy)]
struct Face {
    vertices: [usize; 3],
    /// Rows of the inverse of `[a b c]` (columns the vertices): cone coordinate k of `d` is
    /// `rows[k] · d`.
    rows: [DVec3; 3],
}

/// The hull's vertices: the sun parts' directions (part order, so vertex `k < SUN_PARTS` is
/// part `k`), then the mirror images of those above the horizon.
fn hull_vertices() -> &'static Vec<DVec3> {
    static VERTICES: OnceLock<Vec<DVec3>> = OnceLock::new();
    VERTICES.get_or_init(|| {
        let parts = sun_directions().iter().map(|&d| DVec3::from_array(d));
        let mirrored = parts
            .clone()
            .filter(|d| d.y < -1e-9)
            .map(|d| d * DVec3::new(1.0, -1.0, 1.0));
        parts.chain(mirrored).collect()
    })
}

/// The hull's triangles. A triple of vertices whose plane has every other vertex strictly
/// inside is a face; where more lie on a face's plane (the rings and the lattice are
/// symmetric, so a ring's two neighbours and the two below them make a trapezoid), the
/// polygon is fanned from its lowest vertex in angular order. Faces whose vertices are all
/// sun parts come first, so a sun on the horizon (on an edge between a face above and one
/// below) resolves to the sun's side.
fn faces() -> &'static Vec<Face> {
    static FACES: OnceLock<Vec<Face>> = OnceLock::new();
    FACES.get_or_init(|| {
        let v = hull_vertices();
        let n = v.len();
        let mut out = Vec::new();
        let mut push = |tri: [usize; 3]| {
            // Outward: det [a b c] > 0 (the origin is inside).
            let [a, b, c] = tri.map(|k| v[k]);
            let tri = if a.dot(b.cross(c)) > 0.0 {
                tri
            } else {
                [tri[0], tri[2], tri[1]]
            };
            out.push(Face {
                vertices: tri,
                rows: inverse_rows(tri.map(|k| v[k])),
            });
        };
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    let normal = (v[b] - v[a]).cross(v[c] - v[a]);
                    let offset = normal.dot(v[a]);
                    let side = |p: DVec3| (normal.dot(p) - offset) * offset.signum();
                    // Every vertex inside or on the plane, on the origin's side of it.
                    if (0..n).any(|k| side(v[k]) > 1e-9) {
                        continue;
                    }
                    let on: Vec<usize> = (0..n).filter(|&k| side(v[k]) >= -1e-9).collect();
                    if on.len() == 3 {
                        push([a, b, c]);
                        continue;
                    }
                    // A polygon: fan it once, from the triple of its three lowest vertices.
                    if on[..3] != [a, b, c] {
                        continue;
                    }
                    let centre = on.iter().map(|&k| v[k]).sum::<DVec3>() / on.len() as f64;
                    let u = v[a] - centre;
                    let w = normal.cross(u);
                    let angle = |k: usize| {
                        let q = v[k] - centre;
                        q.dot(w).atan2(q.dot(u))
                    };
                    let mut ring = on.clone();
                    ring.sort_by(|&x, &y| angle(x).total_cmp(&angle(y)));
                    let first = ring.iter().position(|&k| k == a).expect("a is on it");
                    ring.rotate_left(first);
                    for k in 1..ring.len() - 1 {
                        push([ring[0], ring[k], ring[k + 1]]);
                    }
                }
            }
        }
        out.sort_by_key(|f| f.vertices.iter().any(|&k| k >= SUN_PARTS));
        out
    })
}

/// Rows of `[a b c]⁻¹` (columns `a`, `b`, `c`): `(b × c, c × a, a × b) / det`.
fn inverse_rows([a, b, c]: [DVec3; 3]) -> [DVec3; 3] {
    let rows = [b.cross(c), c.cross(a), a.cross(b)];
    let det = a.dot(rows[0]);
    rows.map(|r| r / det)
}

/// The sun's parts and their weights for sunlight travelling along `travel` (any length): the
/// hull face it crosses and its barycentric weights (module docs), as part indices. Empty
/// when the sun is below the horizon (`travel` upward).
pub fn sun_part_weights(travel: [f64; 3]) -> Result<Vec<(usize, f64)>, LightingError> {
    let d = normalise(travel).map(DVec3::from_array).ok_or_else(|| {
        LightingError::Illumination(format!(
            "sun direction {travel:?} must be a finite, non-zero vector"
        ))
    })?;
    if d.y > 0.0 {
        return Ok(Vec::new());
    }
    let faces = faces();
    let coords = |f: &Face| f.rows.map(|r| r.dot(d));
    let min = |a: [f64; 3]| a[0].min(a[1]).min(a[2]);
    let face = faces
        .iter()
        .find(|f| min(coords(f)) >= -INSIDE_TOLERANCE)
        // The faces cover the sphere (tested), so this only guards against rounding.
        .unwrap_or_else(|| {
            faces
                .iter()
                .max_by(|a, b| min(coords(a)).total_cmp(&min(coords(b))))
                .expect("the hull has faces")
        });
    // Coordinates within rounding of 0 are 0, so a part's own direction weighs it alone.
    let alpha = coords(face).map(|a| if a > INSIDE_TOLERANCE { a } else { 0.0 });
    let total: f64 = alpha.iter().sum();
    let mut out = Vec::with_capacity(3);
    for (&v, &a) in face.vertices.iter().zip(&alpha) {
        let w = a / total;
        if w <= 0.0 {
            continue;
        }
        match v < SUN_PARTS {
            true => out.push((v, w)),
            // A face of a sun at the horizon may touch a mirrored direction with weight ~0.
            false if w < 1e-9 => {}
            false => {
                return Err(LightingError::Illumination(format!(
                    "sun travelling along {travel:?}: hull vertex {v} has no sun part"
                )))
            }
        }
    }
    let total: f64 = out.iter().map(|x| x.1).sum();
    for (_, w) in &mut out {
        *w /= total;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
        DVec3::from_array(a).dot(DVec3::from_array(b))
    }

    /// A deterministic spread of unit directions (a Fibonacci sphere).
    fn sphere(n: usize) -> impl Iterator<Item = [f64; 3]> {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n).map(move |k| {
            let y = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).sqrt();
            let a = golden * k as f64;
            [r * a.cos(), y, r * a.sin()]
        })
    }

    #[test]
    fn the_hull_is_a_closed_triangulation_of_every_direction() {
        let v = hull_vertices().len();
        assert_eq!(
            v,
            SUN_PARTS + SUN_PARTS - 8,
            "eight parts lie on the horizon"
        );
        // A closed triangulation of a convex polytope's surface: F = 2V - 4, and each edge is
        // shared by exactly two faces.
        assert_eq!(faces().len(), 2 * v - 4);
        let mut edges = std::collections::HashMap::new();
        for f in faces() {
            for k in 0..3 {
                let (a, b) = (f.vertices[k], f.vertices[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&n| n == 2), "{edges:?}");
        assert_eq!(v + faces().len() - edges.len(), 2, "Euler");
        // Every direction is inside exactly one face, up to its edges.
        for d in sphere(4000) {
            let inside = faces()
                .iter()
                .filter(|f| f.rows.iter().all(|r| r.dot(DVec3::from_array(d)) > 1e-9))
                .count();
            let touching = faces()
                .iter()
                .filter(|f| f.rows.iter().all(|r| r.dot(DVec3::from_array(d)) >= -1e-9))
                .count();
            assert!(inside <= 1 && touching >= 1, "{d:?}: {inside} {touching}");
        }
    }

    #[test]
    fn weights_reproduce_the_direction_and_pick_a_part_alone_at_its_own() {
        for d in sphere(2000).filter(|d| d[1] <= 0.0) {
            let w = sun_part_weights(d).unwrap();
            let total: f64 = w.iter().map(|x| x.1).sum();
            assert!((total - 1.0).abs() < 1e-12, "{d:?}: {w:?}");
            assert!(w.len() <= 3 && w.iter().all(|&(p, x)| p < SUN_PARTS && x > 0.0));
            // The weighted directions point along d (the crossing point of the face's plane).
            let mut p = [0.0; 3];
            for &(k, x) in &w {
                for (p, c) in p.iter_mut().zip(sun_directions()[k]) {
                    *p += x * c;
                }
            }
            let p = normalise(p).unwrap();
            assert!(dot(p, d) > 1.0 - 1e-12, "{d:?}: {p:?}");
        }
        for (k, &d) in sun_directions().iter().enumerate() {
            let w = sun_part_weights(d.map(|c| 3.0 * c)).unwrap();
            assert_eq!(w.len(), 1, "part {k}: {w:?}");
            assert_eq!(w[0].0, k);
        }
        assert!(sun_part_weights([0.3, 0.5, 0.1]).unwrap().is_empty());
        assert!(sun_part_weights([0.0, 0.0, 0.0]).is_err());
        assert!(sun_part_weights([f64::NAN, -1.0, 0.0]).is_err());
    }

    #[test]
    fn no_sun_above_the_horizon_is_far_from_a_part() {
        // The largest angle from a sun to its nearest part: 45° with the lattice alone.
        let worst = sphere(20000)
            .filter(|d| d[1] <= 0.0)
            .map(|d| {
                sun_directions()
                    .iter()
                    .map(|&p| dot(p, d).clamp(-1.0, 1.0).acos().to_degrees())
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max);
        assert!(worst < 25.0, "{worst}");
    }

    #[test]
    fn the_lattice_parts_are_the_downward_lattice_directions() {
        assert_eq!(SUN_PARTS, 25);
        for (k, &j) in LATTICE_SUN_DIRECTIONS.iter().enumerate() {
            assert!(C[j][1] <= 0);
            assert_eq!(sun_directions()[k], unit(j));
            assert_eq!(lattice_direction(k), Some(j));
        }
        assert_eq!(lattice_direction(13), None);
        assert_eq!(C[LATTICE_SUN_DIRECTIONS[overhead_part()]], [0, -1, 0]);
        for d in &sun_directions()[13..] {
            assert!((dot(*d, *d) - 1.0).abs() < 1e-12 && d[1] < 0.0);
        }
    }
}
