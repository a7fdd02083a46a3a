//! Rays, hits, the ray/box slab test and the Möller-Trumbore ray/triangle test.
//!
//! # Edge and vertex rule
//!
//! The triangle test is *inclusive and slightly widened*: a ray whose intersection with the
//! triangle's plane has barycentrics `u ≥ -ε, v ≥ -ε, u + v ≤ 1 + ε` (ε = [`BARY_EPS`] =
//! 1e-5, a hundred-thousandth of the triangle) hits. Möller-Trumbore in f32 is not watertight:
//! without the margin, a ray through an edge shared by two triangles can round to a miss on
//! both and slip through the mesh. With it, such a ray hits both (and every triangle around
//! a shared vertex), at `t` values that agree to rounding; the closest-hit query reports the
//! candidate with the smallest `(t, instance, triangle)` in lexicographic order (the lowest id
//! wins an exact tie), in the kd-tree traversal and in brute force alike, whatever the
//! visiting order. Rays parallel to the triangle's plane (`det == 0`, including rays lying in
//! it) never hit; degenerate (zero-area) triangles are left out of the trees and never hit.
//! Margins at this scale are invisible (a leaf of 5 cm grows by 0.5 µm).

use glam::Vec3;

/// A ray `origin + t · dir` for `t_min < t ≤ t_max`. `dir` need not be unit length; `t`
/// is measured in units of `dir` and is the same number in world and model space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub t_min: f32,
    pub t_max: f32,
}

impl Ray {
    /// The half-line from `origin` along `dir` (`t_min = 0`, `t_max = ∞`).
    pub fn new(origin: Vec3, dir: Vec3) -> Ray {
        Ray {
            origin,
            dir,
            t_min: 0.0,
            t_max: f32::INFINITY,
        }
    }

    /// The segment `t_min < t ≤ t_max`.
    pub fn segment(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Ray {
        Ray {
            origin,
            dir,
            t_min,
            t_max,
        }
    }

    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// Finite origin and direction, non-zero direction, `t_min ≤ t_max`, `t_min` not NaN.
    /// Queries on other rays report no hit.
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && self.dir.is_finite()
            && self.dir != Vec3::ZERO
            && self.t_min <= self.t_max
    }
}

/// What a closest-hit query reports. `u`, `v` are the barycentrics of the hit on triangle
/// `[a, b, c]` of the model's mesh: `p = (1 - u - v)·a + u·b + v·c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f32,
    /// Index into the scene's instances, or [`Hit::GROUND`].
    pub instance: u32,
    /// Index into the instance's model's triangles (0 for the ground).
    pub triangle: u32,
    /// For the ground: world x.
    pub u: f32,
    /// For the ground: world z.
    pub v: f32,
}

impl Hit {
    /// The `instance` of a hit on the ground plane.
    pub const GROUND: u32 = u32::MAX;

    pub fn is_ground(&self) -> bool {
        self.instance == Hit::GROUND
    }

    /// Lexicographic `(t, instance, triangle)` order: the tie rule of closest-hit queries.
    pub fn precedes(&self, other: &Hit) -> bool {
        (self.t, self.instance, self.triangle) < (other.t, other.instance, other.triangle)
    }
}

/// `1 / dir` per component; a zero component gives ±∞ (sign of the zero), which the slab
/// test and the kd-tree traversal handle without special cases.
#[inline(always)]
pub fn inverse_dir(dir: Vec3) -> Vec3 {
    Vec3::ONE / dir
}

/// Slab test: the parameter interval where the ray is inside `[min, max]`, clipped to
/// `[t_min, t_max]`, or `None` when it is empty. Boxes are closed: a ray grazing a face or
/// running inside a face's plane hits. `inv_dir` is [`inverse_dir`] of the direction.
#[inline(always)]
pub fn ray_box(
    origin: Vec3,
    inv_dir: Vec3,
    min: Vec3,
    max: Vec3,
    t_min: f32,
    t_max: f32,
) -> Option<(f32, f32)> {
    let mut t0 = t_min;
    let mut t1 = t_max;
    for k in 0..3 {
        if inv_dir[k].is_infinite() {
            // Parallel to the slab: inside it for every t, or never.
            if origin[k] < min[k] || origin[k] > max[k] {
                return None;
            }
            continue;
        }
        let a = (min[k] - origin[k]) * inv_dir[k];
        let b = (max[k] - origin[k]) * inv_dir[k];
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        if lo > t0 {
            t0 = lo;
        }
        if hi < t1 {
            t1 = hi;
        }
    }
    (t0 <= t1).then_some((t0, t1))
}

/// Widening of the barycentric test (see the module docs).
pub const BARY_EPS: f32 = 1e-5;

/// Precomputed triangle for Möller-Trumbore: a vertex and two edges.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct TriangleData {
    pub v0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
}

impl TriangleData {
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> TriangleData {
        TriangleData {
            v0: a,
            e1: b - a,
            e2: c - a,
        }
    }

    /// Zero area (or non-finite): such a triangle can never be hit.
    pub fn is_degenerate(&self) -> bool {
        let n = self.e1.cross(self.e2);
        !(n.is_finite() && n != Vec3::ZERO)
    }
}

/// Möller-Trumbore: `(t, u, v)` when the ray hits the triangle with `t_min < t ≤ t_max`
/// under the widened edge rule of the module docs.
#[inline(always)]
pub fn intersect_triangle(
    origin: Vec3,
    dir: Vec3,
    tri: &TriangleData,
    t_min: f32,
    t_max: f32,
) -> Option<(f32, f32, f32)> {
    let p = dir.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - tri.v0;
    let u = s.dot(p) * inv;
    if !(-BARY_EPS..=1.0 + BARY_EPS).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = dir.dot(q) * inv;
    if v < -BARY_EPS || u + v > 1.0 + BARY_EPS {
        return None;
    }
    let t = tri.e2.dot(q) * inv;
    (t > t_min && t <= t_max).then_some((t, u, v))
}

/// The triangle test on raw vertices (no precomputation).
pub fn intersect_triangle_vertices(
    ray: &Ray,
    a: Vec3,
    b: Vec3,
    c: Vec3,
) -> Option<(f32, f32, f32)> {
    intersect_triangle(
        ray.origin,
        ray.dir,
        &TriangleData::new(a, b, c),
        ray.t_min,
        ray.t_max,
    )
}
