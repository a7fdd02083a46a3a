//! Relighting (paper 004 §3.1 and §4.2, SPEC §3): per density grid, 19 base solutions that
//! any sun direction combines linearly, and their compression.
//!
//! * [`polyhedron`]: the 32-face polyhedron spanned by the 18 lattice directions, the face a
//!   sun direction crosses with its barycentric weights, and the exact weights
//!   `max(0, n_i · d)`.

pub mod polyhedron;

pub use polyhedron::{exact_weights, face_hit, faces, DirectionError, Face, FaceHit};
