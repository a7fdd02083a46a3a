//! Parallel light over a scene, and 003 eq. 29: the depth and thickness of every leaf mesh
//! from the number of surfaces the light rays through it cross.
//!
//! A [`Beam`] is a rectangle perpendicular to the light's direction of travel that covers the
//! projection of every instance's world box, placed upstream of the scene. Eq. 29 counts, for
//! each light ray that meets a mesh, the crossings before the mesh (`n+`) and after it (`n−`)
//! along the whole line ([`SceneMeshes::crossings`]: a leaf or a stem tube is one crossing),
//! and averages them over the rays that meet the mesh: `d = n+ / σt`, `w = (n+ + n−) / σt`.
//! The mesh itself is in neither count, so a lone leaf has `d = w = 0`. With σt = 1 (all
//! the models' depths are in units of `1/σt`, and the paper notes σt cancels), depth and
//! thickness are mean numbers of surfaces.

use super::meshes::SceneMeshes;
use super::TreeError;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use sylva_trace::{Ray, SceneAccel, TraceStats, TraversalConfig};

/// Parallel light over a rectangle perpendicular to its direction of travel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    /// Unit direction the light travels in.
    pub dir: Vec3,
    /// Unit axes of the rectangle (`u`, `v`, `dir` right-handed).
    pub u_axis: Vec3,
    pub v_axis: Vec3,
    /// Centre of the rectangle, `back` upstream of the scene's centre.
    pub centre: Vec3,
    /// Half extents along `u_axis` and `v_axis`.
    pub half_u: f32,
    pub half_v: f32,
}

/// Two unit vectors completing `dir` (unit) to a right-handed orthonormal frame.
pub fn frame(dir: Vec3) -> (Vec3, Vec3) {
    // Duff et al. 2017, "Building an orthonormal basis, revisited".
    let sign = 1f32.copysign(dir.z);
    let a = -1.0 / (sign + dir.z);
    let b = dir.x * dir.y * a;
    let u = Vec3::new(1.0 + sign * dir.x * dir.x * a, sign * b, -sign * dir.x);
    let v = Vec3::new(b, sign + dir.y * dir.y * a, -dir.y);
    (u, v)
}

impl Beam {
    /// The beam along `dir` (the direction light travels in) covering every instance of
    /// `accel`, with a margin of 1 % of the extent on each side.
    pub fn covering(accel: &SceneAccel, dir: Vec3) -> Result<Beam, TreeError> {
        let len = dir.length();
        if !(len.is_finite() && len > 0.0) {
            return Err(TreeError::invalid(
                "light direction",
                format!("{dir}"),
                "must be a finite, non-zero vector",
            ));
        }
        let dir = dir / len;
        let (u_axis, v_axis) = frame(dir);
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for inst in accel.instances() {
            for c in inst.world_bounds.corners() {
                let p = Vec3::new(c.dot(u_axis), c.dot(v_axis), c.dot(dir));
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(TreeError::NoLeaves("the scene has no instances".into()));
        }
        let margin = 0.01 * (hi - lo).max_element().max(1e-3);
        let (lo, hi) = (lo - Vec3::splat(margin), hi + Vec3::splat(margin));
        let mid = (lo + hi) * 0.5;
        // Upstream of everything along the light.
        let centre = u_axis * mid.x + v_axis * mid.y + dir * (lo.z - margin);
        Ok(Beam {
            dir,
            u_axis,
            v_axis,
            centre,
            half_u: 0.5 * (hi.x - lo.x),
            half_v: 0.5 * (hi.y - lo.y),
        })
    }

    /// Area of the rectangle: with unit irradiance across the beam, the power it carries.
    pub fn area(&self) -> f64 {
        4.0 * self.half_u as f64 * self.half_v as f64
    }

    /// The light ray through rectangle coordinates `(u, v)` (`|u| ≤ half_u`, `|v| ≤ half_v`).
    pub fn ray(&self, u: f32, v: f32) -> Ray {
        Ray::new(self.centre + self.u_axis * u + self.v_axis * v, self.dir)
    }
}

/// Eq. 29 tallies per leaf mesh: how many light rays met it and the sums of their `n+`, `n−`.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthCounts {
    /// Light rays that met each mesh.
    pub rays: Vec<u32>,
    /// Sum over those rays of the crossings before the mesh.
    pub before: Vec<u64>,
    /// Sum over those rays of the crossings after the mesh.
    pub after: Vec<u64>,
    /// Spacing of the ray grid across the beam.
    pub spacing: f32,
    /// Rays traced.
    pub ray_count: u64,
}

impl DepthCounts {
    /// Eq. 29's depth `d` of mesh `m` (σt = 1), `None` when no light ray met it.
    pub fn depth(&self, m: usize) -> Option<f64> {
        (self.rays[m] > 0).then(|| self.before[m] as f64 / self.rays[m] as f64)
    }

    /// Eq. 29's thickness `w` of mesh `m` (σt = 1), `None` when no light ray met it.
    pub fn thickness(&self, m: usize) -> Option<f64> {
        (self.rays[m] > 0).then(|| (self.before[m] + self.after[m]) as f64 / self.rays[m] as f64)
    }
}

/// Rays across `beam` on a square grid of `spacing` (ray `(i, j)` at the centre of its cell),
/// each followed through the whole scene; `progress(n)` hears every finished row of `n`
/// rays. The tallies are integers, so the result does not depend on the thread count.
pub fn count_depths(
    accel: &SceneAccel,
    meshes: &SceneMeshes,
    beam: &Beam,
    spacing: f32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<DepthCounts, TreeError> {
    let (nu, nv) = grid_size(beam, spacing)?;
    let total = meshes.total();
    sylva_core::check_memory("the depth tallies of every leaf mesh", total as u64 * 20)?;
    let rays: Vec<AtomicU32> = (0..total).map(|_| AtomicU32::new(0)).collect();
    let before: Vec<AtomicU64> = (0..total).map(|_| AtomicU64::new(0)).collect();
    let after: Vec<AtomicU64> = (0..total).map(|_| AtomicU64::new(0)).collect();
    (0..nv).into_par_iter().for_each_init(
        || (Vec::new(), Vec::new()),
        |(hits, crossings), j| {
            let v = -beam.half_v + (j as f32 + 0.5) * spacing;
            let mut stats = TraceStats::default();
            for i in 0..nu {
                let u = -beam.half_u + (i as f32 + 0.5) * spacing;
                accel.all_hits(
                    &beam.ray(u, v),
                    TraversalConfig::default(),
                    &mut stats,
                    hits,
                );
                meshes.crossings(hits, crossings);
                let k_total = crossings.len() as u64;
                for (k, &(inst, group, _)) in crossings.iter().enumerate() {
                    if let Some(m) = meshes.leaf_id(inst, group) {
                        let m = m as usize;
                        rays[m].fetch_add(1, Ordering::Relaxed);
                        before[m].fetch_add(k as u64, Ordering::Relaxed);
                        after[m].fetch_add(k_total - 1 - k as u64, Ordering::Relaxed);
                    }
                }
            }
            progress(nu as u64);
        },
    );
    Ok(DepthCounts {
        rays: rays.into_iter().map(AtomicU32::into_inner).collect(),
        before: before.into_iter().map(AtomicU64::into_inner).collect(),
        after: after.into_iter().map(AtomicU64::into_inner).collect(),
        spacing,
        ray_count: nu as u64 * nv as u64,
    })
}

/// Rays along u and v of a grid of `spacing` over `beam` (at most 2^31 in all).
pub fn grid_size(beam: &Beam, spacing: f32) -> Result<(usize, usize), TreeError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(TreeError::invalid(
            "ray spacing",
            spacing.to_string(),
            "must be a finite number > 0",
        ));
    }
    let nu = (2.0 * beam.half_u / spacing).ceil().max(1.0) as f64;
    let nv = (2.0 * beam.half_v / spacing).ceil().max(1.0) as f64;
    if nu * nv > (1u64 << 31) as f64 {
        return Err(TreeError::invalid(
            "ray spacing",
            spacing.to_string(),
            "gives more than 2^31 light rays over the scene; use a coarser spacing",
        ));
    }
    Ok((nu as usize, nv as usize))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trees::synthetic::{plates, single_instance};

    #[test]
    fn stacked_plates_have_exact_depths_and_thicknesses() {
        // Three wide plates: every vertical ray meets all three; eq. 29 without the mesh
        // itself gives depths 0, 1, 2 and thickness 2 for each.
        let models = vec![plates(2.0, &[3.0, 2.0, 1.0])];
        let accel = SceneAccel::from_parts(&models, &single_instance(), None).unwrap();
        let meshes = SceneMeshes::new(&models, &accel);
        let beam = Beam::covering(&accel, Vec3::NEG_Y).unwrap();
        assert!(
            (beam.area() - 4.0 * 1.02 * 1.02).abs() < 1e-3,
            "{}",
            beam.area()
        );
        let counts = count_depths(&accel, &meshes, &beam, 0.05, &|_| {}).unwrap();
        for (m, want) in [0.0, 1.0, 2.0].into_iter().enumerate() {
            assert_eq!(counts.depth(m), Some(want));
            assert_eq!(counts.thickness(m), Some(2.0));
            assert!(counts.rays[m] > 1000);
        }
        // From below the order turns over.
        let up = Beam::covering(&accel, Vec3::Y).unwrap();
        let counts = count_depths(&accel, &meshes, &up, 0.1, &|_| {}).unwrap();
        assert_eq!(counts.depth(0), Some(2.0));
        assert_eq!(counts.depth(2), Some(0.0));
        assert!(count_depths(&accel, &meshes, &beam, 0.0, &|_| {}).is_err());
        assert!(Beam::covering(&accel, Vec3::ZERO).is_err());
    }

    #[test]
    fn frame_is_orthonormal() {
        for d in [
            Vec3::X,
            Vec3::NEG_Y,
            Vec3::new(0.3, -0.8, 0.52).normalize(),
            Vec3::NEG_Z,
        ] {
            let (u, v) = frame(d);
            assert!(u.dot(v).abs() < 1e-6 && u.dot(d).abs() < 1e-6 && v.dot(d).abs() < 1e-6);
            assert!((u.length() - 1.0).abs() < 1e-6 && (v.length() - 1.0).abs() < 1e-6);
            assert!((u.cross(v) - d).length() < 1e-5, "right-handed");
        }
    }
}
