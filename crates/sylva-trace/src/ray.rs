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
//!
//! The relative ε alone is not enough for small triangles seen from far away: `u = s·p / det`
//! with `s` the vector from the triangle to the ray origin rounds by about
//! `f32::EPSILON · |s|·|p| / |det|`, which grows with distance over triangle size. A 10 M
//! triangle sheet seen from 20 m (triangles of 9 mm, a ratio of 2000) let rays through shared
//! edges miss both triangles (issue 19: 4 pixels through the sheet; a float32 model of the test
//! misses 11 % of rays aimed exactly at shared edges at that ratio, 1.7 % at 80 k triangles).
//! So the margin is the larger of ε and [`ROUNDING`] times that rounding bound, for `u` and for
//! `v` (whose bound is `|d|·|q| / |det|`): rays through an edge then hit both triangles, as
//! intended, at any distance.

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

/// Multiple of the rounding bound of the barycentric dot products that the edge test also
/// accepts (see the module docs): 4 closes every crack in the float32 model, with margin.
pub const ROUNDING: f32 = 4.0 * f32::EPSILON;

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
    // A subnormal `det` has no finite inverse: the margins below would be infinite.
    if !inv.is_finite() {
        return None;
    }
    let s = origin - tri.v0;
    let u = s.dot(p) * inv;
    // The larger of the relative margin and the rounding of `s·p` (module docs).
    let margin_u = BARY_EPS.max(ROUNDING * s.abs().dot(p.abs()) * inv.abs());
    if !(-margin_u..=1.0 + margin_u).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = dir.dot(q) * inv;
    let margin = margin_u.max(ROUNDING * dir.abs().dot(q.abs()) * inv.abs());
    if v < -margin || u + v > 1.0 + margin {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 19, item 11: rays aimed exactly at the edge two triangles share must hit one of
    /// them, however small the triangles are against their distance from the ray origin.
    #[test]
    fn rays_through_shared_edges_of_small_far_triangles_never_slip_through() {
        let mut rng = sylva_core::SplitMix64::new(19);
        // A 20 m sheet of n × n cells (2n² triangles), each cell split along its diagonal,
        // seen from 20-30 m away: n = 2236 is the 10 M triangle sheet of the report.
        for n in [200usize, 2236, 5000] {
            let h = 20.0 / n as f32;
            let mut misses = 0;
            for _ in 0..4000 {
                let (i, j) = (
                    (rng.next_f64() * n as f64) as usize,
                    (rng.next_f64() * n as f64) as usize,
                );
                let (x0, z0) = (-10.0 + i as f32 * h, -10.0 + j as f32 * h);
                let a = Vec3::new(x0, 0.0, z0);
                let b = Vec3::new(x0 + h, 0.0, z0);
                let c = Vec3::new(x0 + h, 0.0, z0 + h);
                let d = Vec3::new(x0, 0.0, z0 + h);
                let origin = Vec3::new(
                    (rng.next_f64() * 10.0 - 5.0) as f32,
                    8.0,
                    (-20.0 - rng.next_f64() * 10.0) as f32,
                );
                let hit = |t: TriangleData, on_edge: Vec3| {
                    intersect_triangle(origin, on_edge - origin, &t, 0.0, f32::INFINITY).is_some()
                };
                // The diagonal a-c: the u = 0 edge of (a, b, c), the v = 0 edge of (a, c, d).
                let on_diagonal = a + (c - a) * rng.next_f64() as f32;
                if !hit(TriangleData::new(a, b, c), on_diagonal)
                    && !hit(TriangleData::new(a, c, d), on_diagonal)
                {
                    misses += 1;
                }
                // The cell edge b-c: the u + v = 1 edge of (a, b, c), the u = 0 edge of the
                // next cell's (b, b + (h, 0, h), c).
                let on_side = b + (c - b) * rng.next_f64() as f32;
                let next = TriangleData::new(b, b + Vec3::new(h, 0.0, h), c);
                if !hit(TriangleData::new(a, b, c), on_side) && !hit(next, on_side) {
                    misses += 1;
                }
            }
            assert_eq!(
                misses, 0,
                "{n}×{n} cells: {misses} of 8000 rays slipped through"
            );
        }
    }

    #[test]
    fn the_margin_stays_small_near_the_triangle() {
        // Close up, the margin is the relative ε: a ray 1e-4 outside a unit triangle misses.
        let t = TriangleData::new(Vec3::ZERO, Vec3::X, Vec3::Z);
        let origin = Vec3::new(-1e-4, 1.0, 0.5);
        assert!(intersect_triangle(origin, -Vec3::Y, &t, 0.0, 10.0).is_none());
        let origin = Vec3::new(1e-6, 1.0, 0.5);
        assert!(intersect_triangle(origin, -Vec3::Y, &t, 0.0, 10.0).is_some());
    }
}
