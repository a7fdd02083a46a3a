//! The 32-face polyhedron of 004 §3.1 and the weights it gives a sun direction.
//!
//! The 18 unit lattice directions `n_1..n_18` all lie on the unit sphere, so each is a vertex
//! of their convex hull. The twelve face diagonals form a cuboctahedron (8 triangles, 6
//! squares); each axial direction caps one square with a pyramid of 4 triangles, which gives
//! 8 + 6 · 4 = 32 triangular faces.
//!
//! **Direction convention.** Every function here takes `travel`, the direction the sunlight
//! travels (the negation of the direction towards the sun), like [`Boundary::sun`]: base
//! solution `B_j` is lit by light travelling along `n_j`, so the sun travelling along `n_j`
//! selects `B_j` alone. The length of `travel` does not matter.
//!
//! **Tie rule.** On an edge or a vertex several faces contain the direction; the weights of
//! the vertices they do not share are 0 there, so every choice gives the same combination.
//! [`face_hit`] takes the first face in [`faces`] order whose cone coordinates are all ≥
//! `-1e-12` (so a direction within rounding of an edge always resolves to the same face), then
//! clamps the coordinates to ≥ 0 and normalises them to sum 1. At a lattice direction the
//! other two weights are exactly 0: the coordinates come from integer cross products (see
//! [`Face`]) and cancel exactly.
//!
//! [`Boundary::sun`]: crate::Boundary::sun

use std::sync::OnceLock;

use thiserror::Error;

use crate::lattice::{unit, C, Q};

/// Faces of the polyhedron.
pub const FACE_COUNT: usize = 32;

/// Coordinates below this still count as inside a face (rounding on its edges).
const INSIDE_TOLERANCE: f64 = 1e-12;

#[derive(Debug, Error, PartialEq)]
pub enum DirectionError {
    #[error("sun direction ({}, {}, {}) must be a finite, non-zero vector", .0[0], .0[1], .0[2])]
    Invalid([f64; 3]),
}

/// One triangular face: three lattice directions (indices 1..=18), counter-clockwise seen
/// from outside (outward normal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Face {
    pub vertices: [usize; 3],
    /// `c_b × c_c`, `c_c × c_a`, `c_a × c_b` for vertices a, b, c: the rows of `adj(C)` for
    /// the integer matrix `C = [c_a c_b c_c]`. Integer-valued, so exact.
    cross: [[f64; 3]; 3],
    /// `|c_k| / det C` per vertex: cone coordinate k of `d` is `(cross_k · d) · scale_k`.
    scale: [f64; 3],
}

impl Face {
    fn new(vertices: [usize; 3]) -> Face {
        let c = vertices.map(|v| C[v].map(f64::from));
        let cross = [cross(c[1], c[2]), cross(c[2], c[0]), cross(c[0], c[1])];
        let det = dot(c[0], cross[0]);
        let scale = std::array::from_fn(|k| dot(c[k], c[k]).sqrt() / det);
        Face {
            vertices,
            cross,
            scale,
        }
    }

    /// Cone coordinates α of `d`: `d = Σ_k α_k n_{vertex k}`. All ≥ 0 exactly when the ray
    /// along `d` crosses this face.
    pub fn cone_coordinates(&self, d: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| dot(self.cross[k], d) * self.scale[k])
    }

    /// Unit outward normal of the face's plane.
    pub fn normal(&self) -> [f64; 3] {
        let [a, b, c] = self.vertices.map(unit);
        normalise(cross(sub(b, a), sub(c, a))).expect("a face is a proper triangle")
    }
}

/// The 32 faces: the 8 octant triangles of the cuboctahedron (octants in the order
/// `(+,+,+), (+,+,-), …, (-,-,-)`), then the 4 triangles of each axial pyramid (apexes in
/// lattice order `+x, -x, +y, -y, +z, -z`), each counter-clockwise seen from outside.
pub fn faces() -> &'static [Face; FACE_COUNT] {
    static FACES: OnceLock<[Face; FACE_COUNT]> = OnceLock::new();
    FACES.get_or_init(|| {
        let index = |c: [i32; 3]| {
            C.iter()
                .position(|&x| x == c)
                .expect("every listed vector is a lattice direction")
        };
        let mut triples = Vec::with_capacity(FACE_COUNT);
        for sx in [1, -1] {
            for sy in [1, -1] {
                for sz in [1, -1] {
                    triples.push([[sx, sy, 0], [sx, 0, sz], [0, sy, sz]].map(index));
                }
            }
        }
        for (m, &apex) in C.iter().enumerate().take(7).skip(1) {
            let axis = (0..3).position(|a| apex[a] != 0).expect("axial");
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |other: usize, sign: i32| {
                let mut v = apex;
                v[other] = sign;
                index(v)
            };
            // The square's corners in cyclic order around the axis.
            let square = [corner(b, 1), corner(c, 1), corner(b, -1), corner(c, -1)];
            for k in 0..4 {
                triples.push([m, square[k], square[(k + 1) % 4]]);
            }
        }
        let faces: Vec<Face> = triples
            .into_iter()
            .map(|[a, b, c]| {
                // Outward: det [c_a c_b c_c] > 0 (the origin is inside).
                let f = Face::new([a, b, c]);
                if f.scale[0] > 0.0 {
                    f
                } else {
                    Face::new([a, c, b])
                }
            })
            .collect();
        faces.try_into().expect("32 faces")
    })
}

/// Where a sun direction crosses the polyhedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceHit {
    /// Index into [`faces`].
    pub face: usize,
    /// The face's lattice directions (basis indices 1..=18).
    pub vertices: [usize; 3],
    /// Barycentric weights of the crossing point: each in [0, 1], summing to 1.
    pub weights: [f64; 3],
}

/// The face that the ray from the origin along `travel` crosses, with the barycentric
/// weights of the crossing point (004 §3.1); ties as in the module docs.
pub fn face_hit(travel: [f64; 3]) -> Result<FaceHit, DirectionError> {
    let d = normalise(travel).ok_or(DirectionError::Invalid(travel))?;
    let faces = faces();
    let coords = |f: &Face| f.cone_coordinates(d);
    let min = |a: [f64; 3]| a[0].min(a[1]).min(a[2]);
    let face = faces
        .iter()
        .position(|f| min(coords(f)) >= -INSIDE_TOLERANCE)
        // The faces cover the sphere, so this only guards against the impossible.
        .unwrap_or_else(|| {
            (0..FACE_COUNT)
                .max_by(|&a, &b| min(coords(&faces[a])).total_cmp(&min(coords(&faces[b]))))
                .expect("faces exist")
        });
    let alpha = coords(&faces[face]).map(|a| a.max(0.0));
    let total: f64 = alpha.iter().sum();
    Ok(FaceHit {
        face,
        vertices: faces[face].vertices,
        weights: alpha.map(|a| a / total),
    })
}

/// The exact weights `w_i = max(0, n_i · d)` (i ≥ 1, `w_0 = 0`) of unit-length `travel`: a
/// sun of unit intensity is the combination `Σ_i w_i B_i` (SPEC §3), the same values
/// [`Boundary::sun`](crate::Boundary::sun) puts on the shell.
pub fn exact_weights(travel: [f64; 3]) -> Result<[f64; Q], DirectionError> {
    let d = normalise(travel).ok_or(DirectionError::Invalid(travel))?;
    let mut w = [0.0; Q];
    for (i, v) in w.iter_mut().enumerate().skip(1) {
        *v = dot(unit(i), d).max(0.0);
    }
    Ok(w)
}

/// `v / |v|`, or `None` for a zero or non-finite vector. Scaled by the largest component
/// first, so tiny and huge vectors neither underflow nor overflow.
pub fn normalise(v: [f64; 3]) -> Option<[f64; 3]> {
    let big = v[0].abs().max(v[1].abs()).max(v[2].abs());
    if !(big.is_finite() && big > 0.0) || v.iter().any(|c| c.is_nan()) {
        return None;
    }
    let u = v.map(|c| c / big);
    let len = dot(u, u).sqrt();
    Some(u.map(|c| c / len))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::HashMap;

    fn check_hit(d: [f64; 3]) -> FaceHit {
        let hit = face_hit(d).unwrap();
        let sum: f64 = hit.weights.iter().sum();
        assert!(
            (sum - 1.0).abs() < 1e-12,
            "{d:?}: weights {:?}",
            hit.weights
        );
        for w in hit.weights {
            assert!((0.0..=1.0).contains(&w), "{d:?}: weights {:?}", hit.weights);
        }
        // Σ w_i n_i is the crossing point: parallel to d, same side.
        let mut p = [0.0; 3];
        for (k, &v) in hit.vertices.iter().enumerate() {
            for a in 0..3 {
                p[a] += hit.weights[k] * unit(v)[a];
            }
        }
        let u = normalise(d).unwrap();
        let c = cross(p, u);
        assert!(
            dot(c, c).sqrt() < 1e-12,
            "{d:?}: point {p:?} not on the ray"
        );
        assert!(dot(p, u) > 0.5, "{d:?}: point {p:?} behind the origin");
        // It lies on the face's plane, at least as far out as every other face's plane
        // (the crossing of the convex hull's surface).
        let f = &faces()[hit.face];
        let h = dot(f.normal(), unit(f.vertices[0]));
        assert!((dot(f.normal(), p) - h).abs() < 1e-12);
        for g in faces() {
            let hg = dot(g.normal(), unit(g.vertices[0]));
            assert!(dot(g.normal(), p) <= hg + 1e-12, "{d:?} outside face {g:?}");
        }
        hit
    }

    /// Faces whose closed cone contains `d` (with rounding slack).
    fn containing(d: [f64; 3]) -> Vec<usize> {
        let d = normalise(d).unwrap();
        (0..FACE_COUNT)
            .filter(|&f| {
                faces()[f]
                    .cone_coordinates(d)
                    .iter()
                    .all(|&a| a >= -INSIDE_TOLERANCE)
            })
            .collect()
    }

    #[test]
    fn face_table_is_a_closed_outward_convex_hull() {
        let faces = faces();
        assert_eq!(faces.len(), 32);
        let mut edges: HashMap<(usize, usize), Vec<usize>> = HashMap::new();
        let mut directed = HashMap::new();
        let mut uses = [0; Q];
        for (i, f) in faces.iter().enumerate() {
            let v = f.vertices;
            for k in 0..3 {
                assert!((1..Q).contains(&v[k]));
                uses[v[k]] += 1;
                let (a, b) = (v[k], v[(k + 1) % 3]);
                edges.entry((a.min(b), a.max(b))).or_default().push(i);
                // Consistent orientation: each directed edge appears once.
                assert!(directed.insert((a, b), i).is_none(), "edge {a}->{b} twice");
            }
            // Outward: the normal points away from the origin, and every lattice direction
            // lies on the inner side of the plane; only the face's own three lie on it.
            let n = f.normal();
            let h = dot(n, unit(v[0]));
            assert!(h > 0.0, "face {i} faces inwards");
            let on_plane = (1..Q)
                .filter(|&m| {
                    let s = dot(n, unit(m)) - h;
                    assert!(s <= 1e-12, "face {i}: direction {m} outside");
                    s.abs() <= 1e-12
                })
                .count();
            assert_eq!(on_plane, 3, "face {i} is not a proper hull face");
        }
        // Euler: V - E + F = 18 - 48 + 32 = 2; each edge shared by exactly two faces.
        assert_eq!(edges.len(), 48);
        for (e, fs) in &edges {
            assert_eq!(fs.len(), 2, "edge {e:?} in faces {fs:?}");
        }
        // Axial directions are pyramid apexes (4 faces); a diagonal meets 2 octant triangles and
        // 2 faces of each of the two pyramids it borders.
        for m in 1..Q {
            assert_eq!(uses[m], if m <= 6 { 4 } else { 6 }, "direction {m}");
        }
    }

    #[test]
    fn lattice_directions_select_their_basis_alone() {
        for j in 1..Q {
            for d in [unit(j), C[j].map(|c| 3.0 * c as f64)] {
                let hit = check_hit(d);
                let k = hit.vertices.iter().position(|&v| v == j).unwrap();
                assert_eq!(hit.weights[k], 1.0, "direction {j}");
                for (i, &w) in hit.weights.iter().enumerate() {
                    if i != k {
                        assert_eq!(w, 0.0, "direction {j}");
                    }
                }
                // Ties: the first of the faces meeting at the vertex.
                assert_eq!(hit.face, containing(d)[0], "direction {j}");
            }
        }
    }

    #[test]
    fn edge_midpoints_and_face_centres() {
        let faces = faces();
        let mut edges = std::collections::HashSet::new();
        for (i, f) in faces.iter().enumerate() {
            let [a, b, c] = f.vertices.map(unit);
            // Centre: equal weights, this face and no other.
            let centre = [0, 1, 2].map(|k| a[k] + b[k] + c[k]);
            let hit = check_hit(centre);
            assert_eq!(hit.face, i);
            for w in hit.weights {
                assert!((w - 1.0 / 3.0).abs() < 1e-12);
            }
            assert_eq!(containing(centre), vec![i]);
            for k in 0..3 {
                let (p, q) = (f.vertices[k], f.vertices[(k + 1) % 3]);
                if !edges.insert((p.min(q), p.max(q))) {
                    continue;
                }
                let (u, v) = (unit(p), unit(q));
                let mid = [0, 1, 2].map(|a| u[a] + v[a]);
                let hit = check_hit(mid);
                // Two faces hold the edge; the first wins, and the third vertex gets 0.
                let holders = containing(mid);
                assert_eq!(holders.len(), 2, "edge {p}-{q}: {holders:?}");
                assert_eq!(hit.face, holders[0]);
                for (vk, &w) in hit.vertices.iter().zip(&hit.weights) {
                    if *vk == p || *vk == q {
                        assert!((w - 0.5).abs() < 1e-12, "edge {p}-{q}: {hit:?}");
                    } else {
                        assert!(w < 1e-12, "edge {p}-{q}: {hit:?}");
                    }
                }
            }
        }
        assert_eq!(edges.len(), 48);
    }

    #[test]
    fn axis_aligned_and_odd_directions() {
        for d in [
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, -2.0],
            [1.0, 1.0, 1.0],
            [-1.0, -1.0, -1.0],
            [1e-300, 0.0, 0.0],
            [1e300, -1e300, 0.0],
        ] {
            check_hit(d);
        }
        assert_eq!(
            face_hit([0.0, 0.0, 0.0]),
            Err(DirectionError::Invalid([0.0; 3]))
        );
        assert!(face_hit([f64::NAN, 1.0, 0.0]).is_err());
        assert!(face_hit([f64::INFINITY, 1.0, 0.0]).is_err());
        assert!(exact_weights([0.0; 3]).is_err());
    }

    #[test]
    fn exact_weights_are_the_sun_boundary() {
        let d = [0.3, -0.9, 0.3];
        let w = exact_weights(d).unwrap();
        let b = crate::Boundary::sun(normalise(d).unwrap(), 1.0);
        assert_eq!(w[0], 0.0);
        for i in 1..Q {
            assert!((w[i] - b.values[i] as f64).abs() < 1e-7);
        }
        // Length does not matter.
        let w7 = exact_weights(d.map(|c| c * 7.0)).unwrap();
        for i in 0..Q {
            assert!((w[i] - w7[i]).abs() < 1e-15);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn every_direction_hits_exactly_one_face(
            x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0
        ) {
            prop_assume!(x * x + y * y + z * z > 1e-6);
            let d = [x, y, z];
            let hit = check_hit(d);
            // Away from edges, exactly one face contains the direction; it is the one hit.
            let inner = {
                let u = normalise(d).unwrap();
                (0..FACE_COUNT)
                    .filter(|&f| faces()[f].cone_coordinates(u).iter().all(|&a| a > 1e-9))
                    .collect::<Vec<_>>()
            };
            prop_assert!(inner.len() <= 1);
            if let [f] = inner[..] {
                prop_assert_eq!(hit.face, f);
                prop_assert_eq!(containing(d), vec![f]);
            }
            // The exact weights are the sun boundary's: in [0, 1], positive exactly on the
            // directions with a component along d.
            let w = exact_weights(d).unwrap();
            let u = normalise(d).unwrap();
            for i in 1..Q {
                let along = dot(unit(i), u);
                prop_assert!(w[i] >= 0.0 && w[i] <= 1.0);
                prop_assert_eq!(w[i] > 0.0, along > 0.0);
            }
        }
    }
}
