//! The device side of the indirect light (pbrt-v4's pattern: a light's CPU lookup and what a
//! GPU reads of it side by side, tied by a parity test), so a light is added in one place and
//! the GPU frame (sylva-render's `gpu_frame.rs` and `shade.wgsl`) names no light type. Each
//! light packs itself, beside its CPU implementation, into plain words ([`DeviceLight`]): no GPU
//! types, so this crate needs no GPU. A light the kernel cannot read says why
//! ([`IndirectLight::device`] answers [`NoDevice`]), and its frames are shaded on the CPU.
//!
//! The words, as shade.wgsl reads them (offsets are absolute word indices in the frame's pool
//! of shading words, which the light appends to):
//! * per model an LB light record: [`LIGHT_HEADER`] words, then its data. The header: nx, ny,
//!   nz, where the values start; the placement's origin, sites per unit and last site per
//!   axis (3 words each); the model's bounds, min and max; then 9 words: a grid's free field
//!   (physical light: 1, open sky (3), open bottom (3)) and its forest-grid parts (where they
//!   start, [`NONE`]: none; where the instances' weights start), or a relit record's kind
//!   (0 every field at every site, 1 Haar split, 2 Haar packed), field count, site count, Haar
//!   blocks along y and z, and where the Haar starts, counts, indices or packed words, and
//!   values or steps begin;
//! * the ground index ([`DeviceGround`]): per cell where its instance list starts
//!   (nx·nz + 1 words), then the lists;
//! * the sun words ([`SunWords`], a buffer of their own, rewritten when the sun moves).
//!
//! [`IndirectLight::device`]: crate::IndirectLight::device

use glam::Vec3;
use sylva_geom::Aabb;
use sylva_lb::relight::Placement;
use sylva_lb::Dims;

/// "No such entry" in the words.
pub const NONE: u32 = u32::MAX;
/// Words of an LB light record's header (shade.wgsl: LIGHT_OPEN, RELIT_KIND and what follows
/// them).
pub const LIGHT_HEADER: u32 = 28;
/// Where a grid record's free field (1: physical light; open sky, open bottom) sits in its
/// header (shade.wgsl: LIGHT_OPEN).
pub(crate) const LIGHT_OPEN: usize = 19;
/// Where a grid record's parts (their offset, NONE: none) and the instances' weights of them
/// sit in its header (shade.wgsl: LIGHT_PARTS).
pub(crate) const LIGHT_PARTS: usize = 26;
/// Where a relit record's kind (0 fields, 1 Haar split, 2 Haar packed) sits in its header
/// (shade.wgsl: RELIT_KIND).
pub(crate) const RELIT_KIND: usize = 19;
/// Words of an instance's entry in the relit sun words (first term, count, constant,
/// padding) and of one term (field, weight per colour).
pub(crate) const RELIT_ENTRY: usize = 8;
pub(crate) const RELIT_TERM: usize = 4;

/// Which of shade.wgsl's lookups reads a light (`ShadeParams.tables.w`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// One grid per model, solved for the sun (`lighting_sample`, `parts_sample`).
    Grids,
    /// Base solutions combined per instance for the current sun (`relit_sample`).
    Relit,
}

impl DeviceKind {
    /// The value the shader switches on.
    pub fn code(self) -> u32 {
        match self {
            DeviceKind::Grids => 0,
            DeviceKind::Relit => 1,
        }
    }
}

/// Why a light (or the media) has no device side: frames with it are shaded on the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct NoDevice(pub &'static str);

/// Where the ground index sits in the pool, and its grid (shade.wgsl: `ShadeParams.ground`,
/// `ground_box`, `ground_cell`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceGround {
    /// Where the cells' list starts (nx·nz + 1 words) and where the lists begin.
    pub starts: u32,
    pub lists: u32,
    pub nx: u32,
    pub nz: u32,
    /// Origin x, origin z, end x, end z.
    pub bounds: [f32; 4],
    /// 1 / cell size.
    pub inv_cell: f32,
}

/// What [`DeviceLight::pack`] put in the pool.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PackedLight {
    /// Per model, where its LB light record starts ([`NONE`]: no LB light on it; models past
    /// the list have none).
    pub records: Vec<u32>,
    /// The ground index, when the light shades the ground.
    pub ground: Option<DeviceGround>,
}

/// What changes on the device when the sun moves: the words of the sun buffer
/// (shade.wgsl: `relit_word_at`; empty when the light keeps nothing per sun) and the
/// luminance the ground's shade is measured against (`ShadeParams.k2.w`).
#[derive(Debug, Clone, PartialEq)]
pub struct SunWords {
    pub words: Vec<u32>,
    pub free_space: f32,
}

/// A light as the GPU frame kernel reads it. Implementations sit beside the light's CPU
/// lookup ([`crate::IndirectLight`]); a test per light unpacks the words as shade.wgsl does
/// and finds the CPU's light (`device::tests`), and the pipeline's GPU tests compare whole
/// frames.
pub trait DeviceLight: Sync {
    /// Which lookup reads it.
    fn kind(&self) -> DeviceKind;

    /// Words [`DeviceLight::pack`] appends at most (for memory checks).
    fn pool_words(&self) -> u64;

    /// Appends the light's words to `pool` (after what is there: offsets in the words are
    /// absolute) and says where they are.
    fn pack(&self, pool: &mut Vec<u32>) -> PackedLight;

    /// The sun words for the current sun (after the light's own update, e.g.
    /// [`crate::RelitLight::relight`]).
    fn sun_words(&self) -> SunWords;

    /// Words the sun words can take, whatever the sun (the sun buffer's size).
    fn sun_capacity(&self) -> usize;

    /// Whether what [`DeviceLight::pack`] appends changes with the sun (a light decoded per
    /// sun), so that moving the sun packs it again, not only its sun words.
    fn pool_per_sun(&self) -> bool {
        false
    }
}

/// Appends to the pool: words, f32 bits, vectors, record headers.
pub(crate) struct Packer<'a> {
    pub words: &'a mut Vec<u32>,
}

impl<'a> Packer<'a> {
    pub fn new(words: &'a mut Vec<u32>) -> Packer<'a> {
        Packer { words }
    }

    /// Where the next word goes.
    pub fn at(&self) -> u32 {
        self.words.len() as u32
    }

    pub fn f(&mut self, v: f32) {
        self.words.push(v.to_bits());
    }

    pub fn v3(&mut self, v: Vec3) {
        self.f(v.x);
        self.f(v.y);
        self.f(v.z);
    }

    /// Sets word `at` (written before).
    pub fn set(&mut self, at: u32, v: u32) {
        self.words[at as usize] = v;
    }

    /// Bytes as words, 4 per word, the first in the low byte.
    pub fn bytes(&mut self, bytes: &[u8]) {
        self.words.extend(bytes.chunks(4).map(|c| {
            c.iter()
                .enumerate()
                .fold(0u32, |w, (k, &b)| w | (b as u32) << (8 * k))
        }));
    }

    /// A relit record's header ([`Packer::light_header`]) for `fields` scalar fields per site
    /// on `dims` at `placement`; its kind (word `RELIT_KIND`) is 0, every field at every
    /// site, until the caller sets another. Returns where it starts.
    pub fn relit_header(
        &mut self,
        dims: Dims,
        placement: &Placement,
        bounds: Aabb,
        fields: usize,
    ) -> u32 {
        let mut extra = [0u32; 9];
        extra[1] = fields as u32;
        extra[2] = dims.sites() as u32;
        self.light_header(
            dims,
            (
                Vec3::from_array(placement.origin()),
                Vec3::from_array(placement.inv_cell()),
            ),
            bounds,
            extra,
        )
    }

    /// An LB light record's header ([`LIGHT_HEADER`] words): dims, where its values start
    /// (right after the header), the placement (origin, sites per unit, last site per axis),
    /// the model's bounds, then `extra`. Returns where it starts.
    pub fn light_header(
        &mut self,
        dims: Dims,
        placement: (Vec3, Vec3),
        bounds: Aabb,
        extra: [u32; 9],
    ) -> u32 {
        let start = self.at();
        let last = Vec3::new(
            (dims.nx - 1) as f32,
            (dims.ny - 1) as f32,
            (dims.nz - 1) as f32,
        );
        self.words.extend([
            dims.nx as u32,
            dims.ny as u32,
            dims.nz as u32,
            start + LIGHT_HEADER,
        ]);
        self.v3(placement.0);
        self.v3(placement.1);
        self.v3(last);
        self.v3(bounds.min);
        self.v3(bounds.max);
        self.words.extend(extra);
        start
    }
}

/// Each light packed, then read back as shade.wgsl reads it (the functions below mirror the
/// shader's, word for word), against the light's CPU lookup: the values at sites exactly,
/// lookups between them and the ground's shade within rounding. No GPU needed; the pipeline's
/// GPU tests compare whole frames.
#[cfg(test)]
mod tests {
    use super::*;
    use crate::indirect::{IndirectLight, ModelGridLight, NoIndirectLight};
    use crate::lighting::PartWeights;
    use crate::lighting::{physical_environment, preset_medium, Illumination, ModelLighting};
    use crate::relight::{RelitIllumination, RelitLight, StoredBasis, SunWeights};
    use glam::{Affine3A, Quat, UVec3};
    use sylva_geom::{Material, MaterialKind, Mesh, Model, Optics};
    use sylva_lb::relight::{compress, BasisOptions, BasisSet, Codec, CompressTarget, Region};
    use sylva_lb::relight::{Precision, CHANNELS};
    use sylva_lb::{Bounds, LightingGrid};
    use sylva_trace::TraceInstance;

    /// Words of the frame's own data before the light's, so offsets must be absolute.
    const BEFORE: usize = 37;

    /// A light's words as the GPU frame holds them.
    struct Device {
        pool: Vec<u32>,
        packed: PackedLight,
        sun: SunWords,
        kind: DeviceKind,
        /// The frame shades with the physical light (shade.wgsl: `tables.z == PHYSICAL`).
        physical: bool,
    }

    fn upload(light: &dyn IndirectLight) -> Device {
        upload_as(light, false)
    }

    fn upload_as(light: &dyn IndirectLight, physical: bool) -> Device {
        let d = light.device().expect("a device side");
        let mut pool = vec![0xdead_beef; BEFORE];
        let packed = d.pack(&mut pool);
        assert!(
            (pool.len() - BEFORE) as u64 <= d.pool_words(),
            "{} words packed, {} announced",
            pool.len() - BEFORE,
            d.pool_words()
        );
        let sun = d.sun_words();
        assert!(sun.words.len() <= d.sun_capacity());
        Device {
            pool,
            packed,
            sun,
            kind: d.kind(),
            physical,
        }
    }

    /// shade.wgsl's reads, on the packed words.
    impl Device {
        fn f(&self, i: u32) -> f32 {
            f32::from_bits(self.pool[i as usize])
        }

        fn v3(&self, i: u32) -> Vec3 {
            Vec3::new(self.f(i), self.f(i + 1), self.f(i + 2))
        }

        fn w(&self, i: u32) -> u32 {
            self.pool[i as usize]
        }

        fn sun_f(&self, i: u32) -> f32 {
            f32::from_bits(self.sun.words[i as usize])
        }

        fn sun_v3(&self, i: u32) -> Vec3 {
            Vec3::new(self.sun_f(i), self.sun_f(i + 1), self.sun_f(i + 2))
        }

        /// `corner`: the lookup's lower corner and fractions.
        fn corner(&self, g: u32, p: Vec3) -> (UVec3, Vec3) {
            let (origin, inv_cell, last) = (self.v3(g + 4), self.v3(g + 7), self.v3(g + 10));
            let f = ((p - origin) * inv_cell).max(Vec3::ZERO).min(last);
            let i = f.floor().min(last - Vec3::ONE);
            (i.as_uvec3(), f - i)
        }

        /// `footprint`: the 8 sites and their weights.
        fn footprint(&self, g: u32, p: Vec3) -> ([u32; 8], [f32; 8]) {
            let (ny, nz) = (self.w(g + 1), self.w(g + 2));
            let (i, t) = self.corner(g, p);
            let base = (i.x * ny + i.y) * nz + i.z;
            let (mut sites, mut weights) = ([0u32; 8], [0f32; 8]);
            for k in 0..8u32 {
                let (dx, dy, dz) = (k >> 2, (k >> 1) & 1, k & 1);
                sites[k as usize] = base + (dx * ny + dy) * nz + dz;
                let w = |d: u32, t: f32| if d == 1 { t } else { 1.0 - t };
                weights[k as usize] = w(dx, t.x) * w(dy, t.y) * w(dz, t.z);
            }
            (sites, weights)
        }

        fn lighting_sample(&self, g: u32, p: Vec3) -> Vec3 {
            let values = self.w(g + 3);
            let (sites, w) = self.footprint(g, p);
            (0..8).fold(Vec3::ZERO, |o, k| o + self.v3(values + 3 * sites[k]) * w[k])
        }

        fn parts_sample(&self, g: u32, parts: u32, weights: u32, i: u32, p: Vec3) -> Vec3 {
            let (sites, wt) = self.footprint(g, p);
            let w = weights + 12 * i;
            let (sun, top, side, ground) =
                (self.v3(w), self.v3(w + 3), self.v3(w + 6), self.v3(w + 9));
            (0..8).fold(Vec3::ZERO, |o, k| {
                let v = parts + 12 * sites[k];
                let c = self.v3(v) * sun
                    + self.v3(v + 3) * top
                    + self.v3(v + 6) * side
                    + self.v3(v + 9) * ground;
                o + c * wt[k]
            })
        }

        fn byte_at(&self, at: u32, k: u32) -> u32 {
            (self.w(at + k / 4) >> (8 * (k % 4))) & 0xff
        }

        fn relit_sample(&self, g: u32, i: u32, p: Vec3) -> Vec3 {
            let (first, count) = (
                self.sun.words[8 * i as usize],
                self.sun.words[8 * i as usize + 1],
            );
            self.relit_terms(g, first, count, self.sun_v3(8 * i + 2), p)
        }

        fn relit_terms(&self, g: u32, first: u32, count: u32, constant: Vec3, p: Vec3) -> Vec3 {
            let mut out = constant;
            let kind = self.w(g + RELIT_KIND as u32);
            let term_w = |term: u32| self.sun_v3(term + 1);
            if kind == 0 {
                let (fields, sites) = (self.w(g + 3), self.w(g + RELIT_KIND as u32 + 2));
                let (fp, wt) = self.footprint(g, p);
                for k in 0..count {
                    let term = first + 4 * k;
                    let field = fields + self.sun.words[term as usize] * sites;
                    let v = (0..8).fold(0.0, |v, c| v + wt[c] * self.f(field + fp[c]));
                    out += term_w(term) * v;
                }
                return out;
            }
            let h = |k: u32| self.w(g + RELIT_KIND as u32 + k);
            let (nf, blocks_y, blocks_z) = (h(1), h(3), h(4));
            let (starts, counts, coef_a, coef_b) = (h(5), h(6), h(7), h(8));
            let (c, t) = self.corner(g, p);
            let b = c / 3;
            let o = c - 3 * b;
            let block = (b.x * blocks_y + b.y) * blocks_z + b.z;
            let kernel = haar_kernel(o, t);
            let mut pos = self.w(starts + block);
            let mut next = 0;
            for k in 0..count {
                let term = first + 4 * k;
                let f = self.sun.words[term as usize];
                while next < f {
                    pos += self.byte_at(counts, block * nf + next);
                    next += 1;
                }
                let n = self.byte_at(counts, block * nf + f);
                let mut v = 0.0;
                if kind == 1 {
                    for j in pos..pos + n {
                        v += self.f(coef_b + j) * kernel[self.byte_at(coef_a, j) as usize];
                    }
                } else {
                    for j in pos..pos + n {
                        let w16 = (self.w(coef_a + j / 2) >> (16 * (j % 2))) & 0xffff;
                        let q = ((w16 << 16) as i32 >> 22) as f32;
                        v += q * kernel[(w16 & 63) as usize];
                    }
                    v *= self.f(coef_b + f);
                }
                pos += n;
                next = f + 1;
                out += term_w(term) * v;
            }
            out
        }

        /// `plant_light` at model-space point `pm` of instance `i` (of model `model`).
        fn plant(&self, model: u32, i: u32, pm: Vec3) -> Option<Vec3> {
            let g = *self.packed.records.get(model as usize)?;
            if g == NONE {
                return None;
            }
            if self.kind == DeviceKind::Relit {
                return Some(self.relit_sample(g, i, pm));
            }
            let parts = self.w(g + LIGHT_PARTS as u32);
            Some(if parts != NONE {
                let weights = self.w(g + LIGHT_PARTS as u32 + 1);
                self.parts_sample(g, parts, weights, i, pm)
            } else {
                self.lighting_sample(g, pm)
            })
        }

        /// `instance_ground_sky`, the physical branch where the record has a free field.
        fn instance_ground_sky(&self, g: u32, i: u32, pm: Vec3) -> Vec3 {
            let luminance = |c: Vec3| sylva_core::colour::luminance(c.to_array());
            let origin = self.v3(g + 4);
            let inv_cell_y = self.f(g + 8);
            let cell_y = if inv_cell_y > 0.0 {
                1.0 / inv_cell_y
            } else {
                0.0
            };
            let share = |floor: Vec3, lowest: Vec3, sky: Vec3, bottom: Vec3| {
                let ground = (floor - bottom).max(Vec3::ZERO);
                let sky = sky * 0.5;
                let share = (lowest - 2.0 * ground) * 0.5 / sky.max(Vec3::splat(f32::MIN_POSITIVE));
                Vec3::select(
                    sky.cmpgt(Vec3::ZERO),
                    share.clamp(Vec3::ZERO, Vec3::ONE),
                    Vec3::ONE,
                )
            };
            if self.kind == DeviceKind::Relit && self.physical {
                // relit_physical_ground_sky: the ground terms and the open field.
                let e = 8 * i as usize;
                let (first, count, open) = (
                    self.sun.words[e + 5],
                    self.sun.words[e + 6],
                    self.sun.words[e + 7],
                );
                let (sky, bottom) = (self.sun_v3(open), self.sun_v3(open + 3));
                let floor =
                    self.relit_terms(g, first, count, Vec3::ZERO, Vec3::new(pm.x, origin.y, pm.z));
                let lowest = self.relit_terms(
                    g,
                    first,
                    count,
                    Vec3::ZERO,
                    Vec3::new(pm.x, origin.y + cell_y, pm.z),
                );
                return share(floor, lowest, sky, bottom);
            }
            if self.kind == DeviceKind::Relit {
                return Vec3::splat(luminance(self.relit_sample(g, i, pm)) / self.sun.free_space);
            }
            if self.w(g + LIGHT_OPEN as u32) == 1 {
                let (sky, bottom) = (self.v3(g + LIGHT_OPEN as u32 + 1), self.v3(g + 23));
                let floor = self.lighting_sample(g, Vec3::new(pm.x, origin.y, pm.z));
                let lowest = self.lighting_sample(g, Vec3::new(pm.x, origin.y + cell_y, pm.z));
                return share(floor, lowest, sky, bottom);
            }
            Vec3::splat(luminance(self.lighting_sample(g, pm)).clamp(0.0, 1.0))
        }

        /// `ground_sky` at world point `p`; instance `i` placed by `placed[i]`.
        fn ground_sky(&self, placed: &[TraceInstance], p: Vec3) -> Vec3 {
            let mut f = Vec3::ONE;
            let Some(ground) = self.packed.ground else {
                return f;
            };
            let [x0, z0, x1, z1] = ground.bounds;
            if !(p.x >= x0 && p.z >= z0 && p.x <= x1 && p.z <= z1) {
                return f;
            }
            let cell = |v: f32, o: f32, n: u32| {
                (((v - o) * ground.inv_cell).floor().max(0.0) as u32).min(n - 1)
            };
            let c = cell(p.z, z0, ground.nz) * ground.nx + cell(p.x, x0, ground.nx);
            for k in self.w(ground.starts + c)..self.w(ground.starts + c + 1) {
                let i = self.w(ground.lists + k);
                let Some(&g) = self.packed.records.get(placed[i as usize].model as usize) else {
                    continue;
                };
                if g == NONE {
                    continue;
                }
                let (bmin, bmax) = (self.v3(g + 13), self.v3(g + 16));
                let pm = placed[i as usize].to_model.transform_point3(p);
                let margin = 0.05 * (bmax.y - bmin.y) + 1e-3;
                if pm.x >= bmin.x
                    && pm.x <= bmax.x
                    && pm.z >= bmin.z
                    && pm.z <= bmax.z
                    && pm.y >= bmin.y - margin
                {
                    let lb = self.instance_ground_sky(g, i, pm);
                    let edge = (pm.x - bmin.x)
                        .min(bmax.x - pm.x)
                        .min(pm.z - bmin.z)
                        .min(bmax.z - pm.z);
                    let width = 0.2 * (bmax.x - bmin.x).min(bmax.z - bmin.z);
                    let w = if width > 0.0 {
                        (edge / width).clamp(0.0, 1.0)
                    } else {
                        1.0
                    };
                    f *= Vec3::ONE - w * (Vec3::ONE - lb.clamp(Vec3::ZERO, Vec3::ONE));
                }
            }
            f
        }
    }

    /// `haar_kernel`: the 64 weights of a footprint at local corner `o` with fractions `t`.
    fn haar_kernel(o: UVec3, t: Vec3) -> [f32; 64] {
        let mut e = [[0f32; 2]; 3];
        let mut f = [[[0f32; 2]; 2]; 3];
        for a in 0..3 {
            for s in 0..2u32 {
                let v = o[a] + s;
                let w = if s == 1 { t[a] } else { 1.0 - t[a] };
                let (cell, pos) = ((v >> 1) as usize, v & 1);
                e[a][0] += w;
                e[a][1] += w * if cell == 0 { 1.0 } else { -1.0 };
                f[a][cell][0] += w;
                f[a][cell][1] += w * if pos == 0 { 1.0 } else { -1.0 };
            }
        }
        let mut k = [0f32; 64];
        for q in 0..8 {
            k[q] = e[0][q >> 2] * e[1][(q >> 1) & 1] * e[2][q & 1];
        }
        for c in 0..8 {
            let (cx, cy, cz) = (c >> 2, (c >> 1) & 1, c & 1);
            for q in 1..8 {
                k[8 + 7 * c + q - 1] = f[0][cx][q >> 2] * f[1][cy][(q >> 1) & 1] * f[2][cz][q & 1];
            }
        }
        k
    }

    const DIMS: [usize; 3] = [9, 10, 8];

    /// A model whose bounds are [-1, 1] × [0, 2] × [-1, 1] (two leaf triangles), and the grid
    /// bounds around it.
    fn model() -> (Model, Bounds) {
        let mut mesh = Mesh::default();
        let n = Vec3::Y;
        let v: Vec<u32> = [
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(1.0, 2.0, -1.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(-1.0, 2.0, 1.0),
        ]
        .iter()
        .map(|&p| mesh.push_vertex(p, n, [0.0, 0.0]))
        .collect();
        mesh.push_triangle(v[0], v[1], v[2], 0);
        mesh.push_triangle(v[0], v[2], v[3], 0);
        let leaf = Material {
            name: "leaf".into(),
            kind: MaterialKind::Leaf,
            base_color: [0.2, 0.4, 0.1],
            texture: None,
            two_sided: true,
            optics: Optics::FOREST_LEAF,
        };
        let bounds = Bounds {
            min: [-1.2, -0.1, -1.1],
            max: [1.1, 2.2, 1.3],
        };
        (Model::new("plate", mesh, vec![leaf]), bounds)
    }

    /// Three instances of model 0 (turned, scaled, overlapping), one of model 1 (no light)
    /// and one of model 0 apart.
    fn instances(bounds: sylva_geom::Aabb) -> Vec<TraceInstance> {
        let place = |model: u32, at: Vec3, turn: f32, scale: f32| {
            let to_world = Affine3A::from_scale_rotation_translation(
                Vec3::splat(scale),
                Quat::from_rotation_y(turn),
                at,
            );
            let mut world_bounds = sylva_geom::Aabb {
                min: Vec3::INFINITY,
                max: Vec3::NEG_INFINITY,
            };
            for k in 0..8 {
                let c = Vec3::select(
                    glam::BVec3::new(k & 4 != 0, k & 2 != 0, k & 1 != 0),
                    bounds.max,
                    bounds.min,
                );
                world_bounds.grow(to_world.transform_point3(c));
            }
            TraceInstance {
                model,
                to_world,
                to_model: to_world.inverse(),
                world_bounds,
            }
        };
        vec![
            place(0, Vec3::ZERO, 0.0, 1.0),
            place(0, Vec3::new(1.3, 0.0, 0.7), 0.7, 1.2),
            place(1, Vec3::new(-0.5, 0.0, 1.6), 2.0, 0.9),
            place(0, Vec3::new(-1.1, 0.0, 1.2), 3.5, 0.8),
            // Apart from the others: its ground cells list it alone.
            place(0, Vec3::new(4.5, 0.0, -1.5), 1.0, 1.0),
        ]
    }

    /// A smooth, varied field over the grid (`salt` picks one of many).
    fn field(salt: usize) -> Vec<f32> {
        let dims = Dims::new(DIMS[0], DIMS[1], DIMS[2]).unwrap();
        let s = salt as f32;
        (0..dims.sites())
            .map(|i| {
                let (x, y, z) = dims.coords(i);
                let (x, y, z) = (x as f32, y as f32, z as f32);
                0.6 + 0.3 * (0.7 * x + 0.31 * s).sin() * (0.5 * y - 0.2 * s).cos()
                    + 0.1 * (0.9 * z + 0.13 * s * s).sin()
            })
            .collect()
    }

    fn grid(salt: usize, bounds: Bounds) -> LightingGrid {
        LightingGrid {
            dims: Dims::new(DIMS[0], DIMS[1], DIMS[2]).unwrap(),
            bounds,
            colours: std::array::from_fn(|c| field(3 * salt + c)),
        }
    }

    /// Points inside and around each lit instance's model (world), with the model points the
    /// CPU looks up there.
    fn points(placed: &[TraceInstance]) -> Vec<(u32, Vec3)> {
        let mut out = Vec::new();
        for (i, inst) in placed.iter().enumerate() {
            for k in 0..60 {
                let t = k as f32;
                let pm = Vec3::new(
                    1.4 * (0.37 * t).sin(),
                    1.1 + 1.3 * (0.53 * t + 1.0).sin(),
                    1.4 * (0.71 * t + 2.0).cos(),
                );
                out.push((i as u32, inst.to_world.transform_point3(pm)));
            }
        }
        out
    }

    /// Ground points over the instances and beyond them.
    fn ground_points() -> Vec<Vec3> {
        (0..400)
            .map(|k| {
                let (x, z) = ((k % 20) as f32, (k / 20) as f32);
                Vec3::new(-3.0 + 0.4 * x, 0.0, -2.8 + 0.31 * z)
            })
            .collect()
    }

    fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
        (a - b)
            .abs()
            .cmple(Vec3::splat(tol) * a.abs().max(b.abs()).max(Vec3::ONE))
            .all()
    }

    /// The device words give the CPU's light at every point and the CPU's ground shade.
    fn agrees(light: &dyn IndirectLight, placed: &[TraceInstance], tol: f32) -> Device {
        agrees_as(light, placed, tol, false)
    }

    fn agrees_as(
        light: &dyn IndirectLight,
        placed: &[TraceInstance],
        tol: f32,
        physical: bool,
    ) -> Device {
        let dev = upload_as(light, physical);
        let mut lit = 0;
        for (i, world) in points(placed) {
            let inst = &placed[i as usize];
            let cpu = light.plant(i, inst, world);
            let pm = inst.to_model.transform_point3(world);
            let gpu = dev.plant(inst.model, i, pm);
            assert_eq!(cpu.is_some(), gpu.is_some(), "instance {i}");
            if let (Some(c), Some(g)) = (cpu, gpu) {
                assert!(close(c, g, tol), "instance {i} at {pm}: CPU {c}, words {g}");
                lit += 1;
            }
        }
        assert_eq!(lit, 4 * 60, "lit points");
        let mut shaded = 0;
        for p in ground_points() {
            let (c, g) = (light.ground_sky(p), dev.ground_sky(placed, p));
            assert!(close(c, g, tol), "ground at {p}: CPU {c}, words {g}");
            shaded += (c.max_element() < 0.999) as usize;
        }
        assert!(shaded > 20, "{shaded} ground points in shade");
        dev
    }

    #[test]
    fn per_sun_grids_read_back_as_the_cpu_looks_them_up() {
        let (plate, bounds) = model();
        let models = [plate.clone(), plate];
        let placed = instances(models[0].bounds);
        // The paper light: RGB per site, exactly as stored.
        let paper = ModelLighting::from_normalised(&grid(0, bounds));
        let light = ModelGridLight::new(vec![Some(paper.clone()), None], &models, &placed);
        let dev = agrees(&light, &placed, 1e-6);
        assert_eq!(dev.kind, DeviceKind::Grids);
        assert_eq!(dev.packed.records[1], NONE);
        let g = dev.packed.records[0];
        assert!(g as usize >= BEFORE);
        let values = dev.w(g + 3);
        for (x, y, z) in [(0, 0, 0), (3, 7, 2), (8, 9, 7)] {
            let i = Dims::new(DIMS[0], DIMS[1], DIMS[2]).unwrap().index(x, y, z) as u32;
            assert_eq!(dev.v3(values + 3 * i).to_array(), paper.site(x, y, z));
        }
        assert_eq!(dev.w(g + LIGHT_OPEN as u32), 0);
        assert_eq!(dev.w(g + LIGHT_PARTS as u32), NONE);
        assert!(dev.sun.words.is_empty());

        // The physical light, its four parts weighed per instance (the forest grid): its
        // free field measures the ground's shade.
        let parts = [0, 1, 2, 3].map(|k| grid(k + 1, bounds));
        let env = physical_environment(&Illumination {
            sun_to: Vec3::new(0.3, 0.8, -0.2),
            sun: Vec3::new(1.0, 0.95, 0.9),
            sky: Vec3::new(0.2, 0.25, 0.35),
            ground: Some(Vec3::splat(0.2)),
        })
        .unwrap();
        let physical = ModelLighting::physical_parts(parts.each_ref(), &env);
        let free = physical.parts().unwrap().free;
        let weights: Vec<PartWeights> = (0..placed.len())
            .map(|i| {
                let s = 1.0 - 0.15 * i as f32;
                PartWeights {
                    sun: free.sun * s,
                    sky_top: free.sky_top * (s + 0.1),
                    sky: free.sky * 0.8,
                    ground: free.ground * (1.2 - 0.1 * i as f32),
                }
            })
            .collect();
        let light = ModelGridLight::new(vec![Some(physical.clone()), None], &models, &placed);
        let dev = agrees(&light, &placed, 1e-5);
        assert_eq!(dev.w(dev.packed.records[0] + LIGHT_OPEN as u32), 1);
        let light = light.with_instance_weights(weights.clone());
        let dev = agrees(&light, &placed, 1e-5);
        let g = dev.packed.records[0];
        let (at, w) = (
            dev.w(g + LIGHT_PARTS as u32),
            dev.w(g + LIGHT_PARTS as u32 + 1),
        );
        assert_ne!(at, NONE);
        // One site's parts and one instance's weights, as stored.
        let site = 5 * 17 + 3;
        let stored: Vec<f32> = (0..12).map(|k| dev.f(at + 12 * site + k)).collect();
        let expect: Vec<f32> = (0..4)
            .flat_map(|k| parts[k].colours.iter().map(move |c| c[site as usize]))
            .collect();
        assert_eq!(stored, expect);
        assert_eq!(dev.v3(w + 12 * 3 + 9), weights[3].ground);
    }

    #[test]
    fn no_light_packs_nothing() {
        let dev = upload(&NoIndirectLight);
        assert_eq!(dev.pool.len(), BEFORE);
        assert!(dev.packed.records.is_empty() && dev.packed.ground.is_none());
        assert_eq!(dev.plant(0, 0, Vec3::ZERO), None);
    }

    /// A basis set of smooth synthetic fields on the model's grid.
    fn basis(bounds: Bounds) -> BasisSet {
        let dims = Dims::new(DIMS[0], DIMS[1], DIMS[2]).unwrap();
        BasisSet::new(
            dims,
            bounds,
            preset_medium("leaf").unwrap(),
            BasisOptions::papers(dims),
            (0..CHANNELS).map(field).collect(),
        )
        .unwrap()
    }

    #[test]
    fn relit_fields_read_back_as_the_cpu_combines_them() {
        let (plate, bounds) = model();
        let models = [plate.clone(), plate];
        let placed = instances(models[0].bounds);
        let set = basis(bounds);
        let dims = set.dims;
        let compressed = |target: CompressTarget| {
            StoredBasis::Compressed(compress(&set, &Region::all(dims), &target).unwrap())
        };
        let stored = [
            (StoredBasis::Full(set.clone()), 0),
            // Split Haar coefficients (f32 values), packed ones, dense fields (PCA).
            (
                compressed(CompressTarget {
                    precision: Precision::F32,
                    ..CompressTarget::new(Codec::Haar { threshold: 0.002 })
                }),
                1,
            ),
            (compressed(CompressTarget::recommended()), 2),
            (compressed(CompressTarget::new(Codec::Pca { rank: 12 })), 0),
        ];
        for (b, kind) in stored {
            let ill =
                RelitIllumination::new(Vec3::new(0.3, 0.8, -0.2), SunWeights::ThreeBasis, 0.2);
            let mut light =
                RelitLight::new(vec![Some(b.clone()), None], &models, &placed, None, ill).unwrap();
            let dev = agrees(&light, &placed, 2e-5);
            assert_eq!(dev.kind, DeviceKind::Relit);
            let g = dev.packed.records[0];
            assert_eq!(dev.w(g + RELIT_KIND as u32), kind, "{:?}", b.dims());
            assert_eq!(dev.sun.free_space, 1.2);
            if let StoredBasis::Full(set) = &b {
                // Every channel at every site as stored.
                let (fields, sites) = (dev.w(g + 3), dims.sites());
                assert_eq!(dev.w(g + RELIT_KIND as u32 + 2) as usize, sites);
                for (c, ch) in set.channels().iter().enumerate().step_by(7) {
                    let at = (fields as usize + c * sites)..(fields as usize + (c + 1) * sites);
                    assert!(dev.pool[at].iter().zip(ch).all(|(w, v)| *w == v.to_bits()));
                }
            }
            // The sun moves: the new sun words (alone) give the new light.
            light
                .relight(RelitIllumination::new(
                    Vec3::new(-0.5, 0.6, 0.4),
                    SunWeights::Exact,
                    0.3,
                ))
                .unwrap();
            let moved = upload(&light);
            assert_eq!(moved.pool, dev.pool, "the pool stays when the sun moves");
            assert_ne!(moved.sun.words, dev.sun.words);
            agrees(&light, &placed, 2e-5);
        }
    }

    #[test]
    fn the_physical_light_relit_reads_back_as_the_cpu_combines_it() {
        use crate::relight::physical::{PhysicalRelitLight, SUN_PARTS};
        use crate::relight::physical_basis::{
            CompressedPhysicalBasis, PhysicalBasis, PhysicalTarget, StoredPhysicalBasis,
        };
        let (plate, bounds) = model();
        let models = [plate.clone(), plate];
        let placed = instances(models[0].bounds);
        // Dim parts, so that the ground under the trees is in shade.
        let dim = |mut g: LightingGrid| {
            g.colours.iter_mut().flatten().for_each(|v| *v *= 0.01);
            g
        };
        let sun: Vec<LightingGrid> = (0..SUN_PARTS).map(|k| dim(grid(k + 1, bounds))).collect();
        let (sky, ground) = (dim(grid(20, bounds)), dim(grid(21, bounds)));
        // The sky through the top is part of the sky through every face.
        let mut skytop = dim(grid(22, bounds));
        for (t, s) in skytop.colours.iter_mut().zip(&sky.colours) {
            for (t, s) in t.iter_mut().zip(s) {
                *t = 0.4 * s;
            }
        }
        let basis = PhysicalBasis::new(&sun, &sky, &ground, &skytop).unwrap();
        let lit = |sun_to: Vec3| Illumination {
            sun_to,
            sun: Vec3::new(1.0, 0.95, 0.9),
            sky: Vec3::new(0.2, 0.25, 0.35),
            ground: Some(Vec3::splat(0.2)),
        };
        // As solved, and compressed: the kernel reads compressed bases decoded for the sun.
        let dims = basis.dims();
        let density = sylva_lb::DensityGrid {
            dims,
            bounds,
            density: vec![0.5; dims.sites()],
            wood: vec![0.0; dims.sites()],
        };
        let compressed =
            CompressedPhysicalBasis::compress(&basis, &density, &PhysicalTarget::recommended())
                .unwrap();
        let mut light = PhysicalRelitLight::new(
            vec![
                Some(StoredPhysicalBasis::Compressed(Box::new(compressed))),
                None,
            ],
            &models,
            &placed,
            None,
            lit(Vec3::new(0.3, 0.8, -0.2)),
        )
        .unwrap();
        let why = light.device().err().expect("not decoded for the sun yet");
        assert!(why.0.contains("decoded"), "{why}");
        assert!(light.pool_per_sun());
        // A budget below one grid decodes nothing: refused, saying why.
        let one = crate::relight::BakedLight::memory_needed(dims);
        let why = light
            .bake_for_device(one - 1)
            .expect_err("beyond the budget");
        assert!(why.0.contains("bake budget"), "{why}");
        assert_eq!(light.bake_summary(), None, "nothing decoded");
        assert!(light.device().is_err());
        // Decoded: the CPU's lookups and the device's words read the same grids. Without a
        // forest grid an instance's plants and ground share one; the four instances of
        // model 0, each turned its own way, share none.
        let mut moved_words = None;
        for sun in [Vec3::new(0.3, 0.8, -0.2), Vec3::new(-0.5, 0.6, 0.4)] {
            light.relight(lit(sun)).unwrap();
            assert!(light.device().is_err(), "the sun moved: decode again");
            let summary = light
                .bake_for_device(crate::relight::DEFAULT_BAKE_BUDGET)
                .unwrap();
            assert_eq!((summary.instances, summary.of), (4, 4));
            assert_eq!(summary.grids, 4, "one per instance of model 0");
            let dev = agrees_as(&light, &placed, 1e-6, true);
            let g = dev.packed.records[0];
            assert_eq!(
                dev.w(g + RELIT_KIND as u32),
                0,
                "decoded fields at every site"
            );
            assert_eq!(dev.w(g + RELIT_KIND as u32 + 1), 3 * 4);
            assert_eq!(dev.packed.records[1], NONE);
            // Each instance's three terms pick its grid's fields, one colour each.
            let e = 8 * 3;
            let first = dev.sun.words[e];
            assert_eq!(dev.sun.words[e + 1], 3);
            let fields: Vec<u32> = (0..3)
                .map(|k| dev.sun.words[(first + 4 * k) as usize])
                .collect();
            assert_eq!(fields[1], fields[0] + 1);
            assert_eq!(dev.sun_v3(first + 1), Vec3::X);
            assert_eq!(
                dev.sun.words[e + 5],
                first + 12,
                "ground terms after the plants'"
            );
            if let Some(before) = moved_words.replace(dev.pool.clone()) {
                // Another sun decodes other grids, of the same size.
                assert_eq!(before.len(), dev.pool.len());
                assert_ne!(before, dev.pool);
            }
        }
        let (stored, tol) = (StoredPhysicalBasis::Full(basis), 1e-5);
        let mut light = PhysicalRelitLight::new(
            vec![Some(stored), None],
            &models,
            &placed,
            None,
            lit(Vec3::new(0.3, 0.8, -0.2)),
        )
        .unwrap();
        let dev = agrees_as(&light, &placed, tol, true);
        assert_eq!(dev.kind, DeviceKind::Relit);
        let g = dev.packed.records[0];
        assert_eq!(dev.w(g + RELIT_KIND as u32), 0, "every field at every site");
        assert_eq!(dev.packed.records[1], NONE);
        // The sun moves: the new sun words alone give the new light and ground.
        light.relight(lit(Vec3::new(-0.5, 0.6, 0.4))).unwrap();
        let moved = agrees_as(&light, &placed, tol, true);
        assert_eq!(moved.pool, dev.pool, "the pool stays when the sun moves");
        assert_ne!(moved.sun.words, dev.sun.words);
    }
}
