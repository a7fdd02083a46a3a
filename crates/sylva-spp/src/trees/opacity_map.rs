//! Deep opacity maps (003 §5.1, after Yuksel & Keyser 2008): for one prototype model and one
//! direction, the number of surfaces a line along that direction crosses before each point.
//!
//! The map is a grid over the prototype's box seen along the direction: square texels across
//! it, and layers along it. Each texel traces `samples²` parallel lines through the model (all
//! hits, [`sylva_trace::ModelAccel::all_hits`]; a leaf or a stem tube counts once, as in eq.
//! 29) and stores, at every layer boundary, the mean number of crossings before it. The
//! count before a point is interpolated bilinearly across texels (texel centres are the
//! nodes) and linearly between layers; before the box it is 0, beyond it the line's total,
//! and outside the map's rectangle 0 (no surface there). The paper builds these on the GPU
//! by rasterising; tracing gives the same counts, with the alpha test of the renderer.

use super::beam::frame;
use super::meshes::ModelMeshes;
use super::TreeError;
use glam::Vec3;
use rayon::prelude::*;
use sylva_geom::{Instance, Model};
use sylva_trace::{ModelAccel, Ray, TraceStats, TraversalConfig};

/// How a map samples its model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapResolution {
    /// Texels along the longer side of the map's rectangle.
    pub texels: usize,
    /// Layers along the direction.
    pub layers: usize,
    /// Lines per texel along each side (`samples²` per texel).
    pub samples: usize,
}

impl MapResolution {
    /// Checks the sizes (1..=4096 texels, 1..=4096 layers, 1..=16 samples).
    pub fn validate(&self) -> Result<(), TreeError> {
        for (name, value, hi) in [
            ("map texels", self.texels, 4096),
            ("map layers", self.layers, 4096),
            ("map samples per texel", self.samples, 16),
        ] {
            if !(1..=hi).contains(&value) {
                return Err(TreeError::invalid(
                    name,
                    value.to_string(),
                    "is out of range (texels and layers 1 to 4096, samples 1 to 16)",
                ));
            }
        }
        Ok(())
    }
}

/// One prototype's deep opacity map in one direction, in the prototype's model space.
#[derive(Debug, Clone)]
pub struct DeepOpacityMap {
    /// Unit direction of the lines (model space).
    dir: Vec3,
    u_axis: Vec3,
    v_axis: Vec3,
    /// Rectangle corner and first layer boundary, in the (u, v, along) coordinates.
    min: Vec3,
    texel: f32,
    layer: f32,
    nu: usize,
    nv: usize,
    layers: usize,
    /// `(layers + 1)` cumulative counts per texel, texel `(i, j)` at `(j * nu + i)`.
    counts: Vec<f32>,
}

impl DeepOpacityMap {
    /// Builds the map of `model` (its tree in `accel`, its groups in `meshes`) along `dir`
    /// (model space; normalised here).
    pub fn build(
        model: &Model,
        accel: &ModelAccel,
        meshes: &ModelMeshes,
        dir: Vec3,
        res: MapResolution,
    ) -> Result<DeepOpacityMap, TreeError> {
        res.validate()?;
        let dir = dir.normalize_or_zero();
        if dir == Vec3::ZERO || !dir.is_finite() {
            return Err(TreeError::invalid(
                "map direction",
                format!("{dir}"),
                "must be finite and non-zero",
            ));
        }
        let (u_axis, v_axis) = frame(dir);
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for c in model.bounds.corners() {
            let p = Vec3::new(c.dot(u_axis), c.dot(v_axis), c.dot(dir));
            lo = lo.min(p);
            hi = hi.max(p);
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(TreeError::NoLeaves(format!(
                "model '{}' is empty",
                model.name
            )));
        }
        // A little margin so surfaces on the box's faces fall inside.
        let margin = 1e-3 * (hi - lo).max_element().max(1e-6);
        let (lo, hi) = (lo - Vec3::splat(margin), hi + Vec3::splat(margin));
        let ext = hi - lo;
        let texel = ext.x.max(ext.y) / res.texels as f32;
        let nu = ((ext.x / texel).ceil() as usize).clamp(1, res.texels);
        let nv = ((ext.y / texel).ceil() as usize).clamp(1, res.texels);
        let layer = ext.z / res.layers as f32;
        let stride = res.layers + 1;
        sylva_core::check_memory(
            &format!("a deep opacity map of '{}'", model.name),
            (nu * nv * stride * 4) as u64,
        )?;
        let s = res.samples;
        let per_line = 1.0 / (s * s) as f32;
        let mut counts = vec![0.0f32; nu * nv * stride];
        counts
            .par_chunks_mut(nu * stride)
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new(), vec![0u32; stride]),
                |(hits, crossings, tally), (j, row)| {
                    let mut stats = TraceStats::default();
                    for i in 0..nu {
                        tally.iter_mut().for_each(|t| *t = 0);
                        for a in 0..s {
                            for b in 0..s {
                                let u = lo.x + (i as f32 + (a as f32 + 0.5) / s as f32) * texel;
                                let v = lo.y + (j as f32 + (b as f32 + 0.5) / s as f32) * texel;
                                let origin = u_axis * u + v_axis * v + dir * lo.z;
                                let ray = Ray::segment(origin, dir, 0.0, ext.z);
                                accel.all_hits(&ray, TraversalConfig::default(), &mut stats, hits);
                                crossings.clear();
                                for h in hits.iter() {
                                    let g = meshes.triangle_group[h.triangle as usize];
                                    if crossings.last().is_some_and(|&(last, _)| last == g) {
                                        continue;
                                    }
                                    crossings.push((g, h.t));
                                }
                                // Crossing at t counts for every boundary strictly beyond it.
                                for &(_, t) in crossings.iter() {
                                    let k = ((t / layer).floor() as isize + 1).max(0) as usize;
                                    if k < stride {
                                        tally[k] += 1;
                                    }
                                }
                            }
                        }
                        let out = &mut row[i * stride..(i + 1) * stride];
                        let mut run = 0u32;
                        for k in 0..stride {
                            run += tally[k];
                            out[k] = run as f32 * per_line;
                        }
                    }
                },
            );
        Ok(DeepOpacityMap {
            dir,
            u_axis,
            v_axis,
            min: lo,
            texel,
            layer,
            nu,
            nv,
            layers: res.layers,
            counts,
        })
    }

    /// The map's direction (model space, unit).
    pub fn dir(&self) -> Vec3 {
        self.dir
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        (self.counts.capacity() * 4 + std::mem::size_of::<Self>()) as u64
    }

    /// Mean crossings before model-space point `p` along the map's direction, and along the
    /// whole line through `p`: `(before, total)`.
    #[inline]
    pub fn depth_and_total(&self, p: Vec3) -> (f32, f32) {
        let u = (p.dot(self.u_axis) - self.min.x) / self.texel;
        let v = (p.dot(self.v_axis) - self.min.y) / self.texel;
        if !(u >= 0.0 && v >= 0.0 && u <= self.nu as f32 && v <= self.nv as f32) {
            return (0.0, 0.0);
        }
        // Texel centres are the nodes.
        let fu = (u - 0.5).clamp(0.0, (self.nu - 1) as f32);
        let fv = (v - 0.5).clamp(0.0, (self.nv - 1) as f32);
        let (i0, j0) = (fu.floor() as usize, fv.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(self.nu - 1), (j0 + 1).min(self.nv - 1));
        let (tu, tv) = (fu - i0 as f32, fv - j0 as f32);
        let z = ((p.dot(self.dir) - self.min.z) / self.layer).clamp(0.0, self.layers as f32);
        let k0 = (z.floor() as usize).min(self.layers.saturating_sub(1));
        let tz = z - k0 as f32;
        let stride = self.layers + 1;
        let at = |i: usize, j: usize| {
            let base = (j * self.nu + i) * stride;
            let c = &self.counts[base..base + stride];
            (c[k0] + (c[k0 + 1] - c[k0]) * tz, c[self.layers])
        };
        let (a, ta) = at(i0, j0);
        let (b, tb) = at(i1, j0);
        let (c, tc) = at(i0, j1);
        let (d, td) = at(i1, j1);
        let lerp2 = |a: f32, b: f32, c: f32, d: f32| {
            let x0 = a + (b - a) * tu;
            let x1 = c + (d - c) * tu;
            x0 + (x1 - x0) * tv
        };
        (lerp2(a, b, c, d), lerp2(ta, tb, tc, td))
    }
}

/// A prototype of 003 §5.1: a model under one rotation about the vertical (scale does not
/// change counts), with its maps in the sample directions and, once lit, in the light's.
#[derive(Debug, Clone)]
pub struct Prototype {
    pub model: u32,
    pub rotation_deg: f32,
    /// World → prototype model space, without translation and scale (a rotation).
    pub world_to_model: glam::Quat,
    /// Maps in the sample directions, in their order.
    pub maps: Vec<DeepOpacityMap>,
    /// The maps along the light, when a light is set: at the sample maps' resolution (for the
    /// grid points' G) and at the light maps' (for shading).
    pub light_maps: Option<[DeepOpacityMap; 2]>,
}

/// The prototypes of a scene's instances: one per (model, rotation) pair, in order of first
/// use; returns them (without maps) and each instance's prototype.
pub fn prototypes_of(instances: &[Instance]) -> (Vec<Prototype>, Vec<u32>) {
    let mut protos: Vec<Prototype> = Vec::new();
    let mut of = Vec::with_capacity(instances.len());
    for inst in instances {
        let found = protos.iter().position(|p| {
            p.model == inst.model && p.rotation_deg.to_bits() == inst.rotation_deg.to_bits()
        });
        let k = found.unwrap_or_else(|| {
            protos.push(Prototype {
                model: inst.model,
                rotation_deg: inst.rotation_deg,
                world_to_model: glam::Quat::from_rotation_y(inst.rotation_deg.to_radians())
                    .inverse(),
                maps: Vec::new(),
                light_maps: None,
            });
            protos.len() - 1
        });
        of.push(k as u32);
    }
    (protos, of)
}
