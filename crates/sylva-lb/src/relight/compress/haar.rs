//! Haar wavelets on blocks of 3³ sites stored as 4³ (004 §4.2).
//!
//! Block `(bx, by, bz)` owns the sites whose coordinates are `3 b .. 3 b + 2` on each axis and
//! also stores their forward neighbours `3 b + 3` (clamped to the grid), so the 2×2×2
//! footprint of a trilinear lookup whose lower corner it owns never leaves it: one block
//! answers a lookup. 37 of its 64 values repeat a neighbour's; the paper accepts that for
//! decoding speed.
//!
//! **Transform.** Two levels of the 3-D averaging Haar transform (`s = (a + b) / 2`,
//! `d = (a - b) / 2` along each axis). Level 1 turns each of the 8 cells of 2³ sites into its
//! mean and 7 details; level 2 does the same with the 8 cell means. Coefficient index 0 is
//! the block mean, 1..=7 the level-2 details of type `t` (bits x, y, z: 4, 2, 1), and
//! `8 + 7 c + (t - 1)` detail `t` of cell `c`. A site's value is
//! `Σ_t H_t σ(t, cell) + Σ_{t≥1} h_{cell,t} σ(t, position in cell)` with
//! `σ(t, q) = (-1)^popcount(t & q)`.
//!
//! **Threshold.** A coefficient is dropped when its RMS contribution over the block (`|H|` at
//! level 2, `|h| / √8` at level 1, which touches 8 of the 64 sites) is below the threshold
//! times the field's scale. Blocks that do not meet the region use the far threshold for
//! their details (their mean is judged by the threshold).
//!
//! **Storage.** Per block a start into the coefficient arrays and per block and field a count
//! (u8); per kept coefficient its index (u8) and value (f16 or f32), or, packed, both in one
//! u16 (6-bit index, 10-bit value in steps of 1/511 of the field's largest coefficient).
//!
//! **Lookup.** The trilinear weights of a footprint and the Haar basis functions are both
//! products over the axes, so the interpolated value is `Σ_k coef_k K[index_k]` with a
//! 64-entry kernel `K` that depends only on the footprint: it is built once per lookup and
//! serves every field of the block, and each kept coefficient then costs one multiply-add.

// Coefficient, cell and axis loops index several tables at once; indices read clearer.
#![allow(clippy::needless_range_loop)]

use half::f16;
use rayon::prelude::*;

use sylva_core::container::{ByteReader, ByteWriter};

use super::{Precision, Values};
use crate::grid::Dims;
use crate::relight::footprint::Footprint;
use crate::relight::region::Region;
use crate::relight::RelightError;

/// Sites a block owns per axis, and stores (with the forward neighbours).
const OWN: usize = 3;
const SIDE: usize = 4;
/// Values (and coefficients) per block and field.
pub const BLOCK_VALUES: usize = SIDE * SIDE * SIDE;

/// Fields compressed blockwise with Haar wavelets.
#[derive(Debug, Clone, PartialEq)]
pub struct HaarFields {
    dims: Dims,
    fields: usize,
    /// Blocks per axis.
    blocks: [usize; 3],
    /// Per block, the index of its first coefficient; one more entry closes the last block.
    starts: Vec<u32>,
    /// Per block and field (`block * fields + field`): coefficients kept.
    counts: Vec<u8>,
    coefs: Coefs,
}

/// The kept coefficients, block after block, field after field.
#[derive(Debug, Clone, PartialEq)]
enum Coefs {
    /// Per coefficient its index in the block (0..64), and its value.
    Split { indices: Vec<u8>, values: Values },
    /// Per coefficient one u16: the value in the top 10 bits (signed, in steps of the field's
    /// `step`) and the index in the low 6.
    Packed { words: Vec<u16>, steps: Vec<f32> },
}

/// Largest magnitude of a 10-bit signed value.
const PACKED_MAX: f32 = 511.0;

impl Coefs {
    fn len(&self) -> usize {
        match self {
            Coefs::Split { indices, .. } => indices.len(),
            Coefs::Packed { words, .. } => words.len(),
        }
    }

    fn bytes(&self) -> u64 {
        match self {
            Coefs::Split { indices, values } => indices.len() as u64 + values.bytes(),
            Coefs::Packed { words, steps } => (words.len() * 2 + steps.len() * 4) as u64,
        }
    }

    /// Coefficient `i` of field `field`: its index and value.
    #[inline]
    fn get(&self, field: usize, i: usize) -> (usize, f32) {
        match self {
            Coefs::Split { indices, values } => (indices[i] as usize, values.get(i)),
            Coefs::Packed { words, steps } => {
                let w = words[i];
                ((w & 63) as usize, ((w as i16) >> 6) as f32 * steps[field])
            }
        }
    }

    /// `Σ_i value_i · k[index_i]` over coefficients `range` of field `field`.
    #[inline]
    fn dot(&self, field: usize, range: std::ops::Range<usize>, k: &[f32; BLOCK_VALUES]) -> f32 {
        match self {
            Coefs::Split { indices, values } => {
                let idx = &indices[range.clone()];
                match values {
                    Values::F32(v) => idx
                        .iter()
                        .zip(&v[range])
                        .map(|(&i, &c)| c * k[i as usize])
                        .sum(),
                    Values::F16(v) => idx
                        .iter()
                        .zip(&v[range])
                        .map(|(&i, &c)| f16::to_f32(c) * k[i as usize])
                        .sum(),
                }
            }
            Coefs::Packed { words, steps } => {
                let sum: f32 = words[range]
                    .iter()
                    .map(|&w| ((w as i16) >> 6) as f32 * k[(w & 63) as usize])
                    .sum();
                sum * steps[field]
            }
        }
    }
}

/// `σ(t, q) = (-1)^popcount(t & q)`.
#[inline]
fn sign(t: usize, q: usize) -> f32 {
    if (t & q).count_ones().is_multiple_of(2) {
        1.0
    } else {
        -1.0
    }
}

/// Local index of site (x, y, z) in a block's 4³ values.
#[inline]
pub(crate) fn local(x: usize, y: usize, z: usize) -> usize {
    (x * SIDE + y) * SIDE + z
}

/// Forward transform of one block (see the module docs for the coefficient order).
fn forward(v: &[f32; BLOCK_VALUES]) -> [f32; BLOCK_VALUES] {
    let mut out = [0.0f32; BLOCK_VALUES];
    let mut means = [0.0f32; 8];
    for (c, mean) in means.iter_mut().enumerate() {
        let (cx, cy, cz) = (c >> 2, c >> 1 & 1, c & 1);
        let cell: [f32; 8] = std::array::from_fn(|p| {
            v[local(2 * cx + (p >> 2), 2 * cy + (p >> 1 & 1), 2 * cz + (p & 1))]
        });
        for t in 0..8 {
            let h = cell
                .iter()
                .enumerate()
                .map(|(p, &x)| sign(t, p) * x)
                .sum::<f32>()
                / 8.0;
            if t == 0 {
                *mean = h;
            } else {
                out[8 + 7 * c + t - 1] = h;
            }
        }
    }
    for t in 0..8 {
        out[t] = means
            .iter()
            .enumerate()
            .map(|(c, &m)| sign(t, c) * m)
            .sum::<f32>()
            / 8.0;
    }
    out
}

/// Inverse transform of one block from its sparse coefficients: the full decode.
fn inverse(coefs: impl Iterator<Item = (usize, f32)>) -> [f32; BLOCK_VALUES] {
    let mut dense = [0.0f32; BLOCK_VALUES];
    for (k, v) in coefs {
        dense[k] = v;
    }
    let mut out = [0.0f32; BLOCK_VALUES];
    for x in 0..SIDE {
        for y in 0..SIDE {
            for z in 0..SIDE {
                let c = (x >> 1) << 2 | (y >> 1) << 1 | z >> 1;
                let p = (x & 1) << 2 | (y & 1) << 1 | z & 1;
                let mut v = 0.0;
                for t in 0..8 {
                    v += dense[t] * sign(t, c);
                }
                for t in 1..8 {
                    v += dense[8 + 7 * c + t - 1] * sign(t, p);
                }
                out[local(x, y, z)] = v;
            }
        }
    }
    out
}

/// The 8-point Walsh-Hadamard transform in place: `x[q] ← Σ_t x[t] σ(t, q)`.
#[inline]
fn walsh8(x: &mut [f32; 8]) {
    for bit in [1, 2, 4] {
        for i in (0..8).filter(|i| i & bit == 0) {
            let (a, b) = (x[i], x[i | bit]);
            x[i] = a + b;
            x[i | bit] = a - b;
        }
    }
}

/// [`inverse`] of a dense coefficient block in butterflies: the coarse level's 8 means, then
/// each cell's 8 values from its mean and 7 details (216 additions instead of 960).
fn inverse_dense(dense: &[f32; BLOCK_VALUES]) -> [f32; BLOCK_VALUES] {
    let mut coarse: [f32; 8] = std::array::from_fn(|t| dense[t]);
    walsh8(&mut coarse);
    let mut out = [0.0f32; BLOCK_VALUES];
    for (c, &mean) in coarse.iter().enumerate() {
        let mut cell: [f32; 8] = std::array::from_fn(|t| {
            if t == 0 {
                mean
            } else {
                dense[8 + 7 * c + t - 1]
            }
        });
        walsh8(&mut cell);
        let (cx, cy, cz) = (c >> 2, c >> 1 & 1, c & 1);
        for (p, &v) in cell.iter().enumerate() {
            out[local(2 * cx + (p >> 2), 2 * cy + (p >> 1 & 1), 2 * cz + (p & 1))] = v;
        }
    }
    out
}

/// Significance of coefficient `k`: its RMS contribution over the block, per unit value.
#[inline]
fn rms_factor(k: usize) -> f32 {
    if k < 8 {
        1.0
    } else {
        // Touches 8 of 64 sites: sqrt(8 / 64).
        std::f32::consts::FRAC_1_SQRT_2 / 2.0
    }
}

/// The kernel `K` of a footprint whose lower corner is at local coordinates `o` (each 0..=2)
/// with fractions `t`: the interpolated value is `Σ_k coef_k K[k]`.
pub(crate) fn kernel(o: [usize; 3], t: [f32; 3]) -> [f32; BLOCK_VALUES] {
    // Per axis: e[bit] for level-2 functions, f[cell][bit] for level-1 functions.
    let mut e = [[0.0f32; 2]; 3];
    let mut f = [[[0.0f32; 2]; 2]; 3];
    for a in 0..3 {
        for (v, w) in [(o[a], 1.0 - t[a]), (o[a] + 1, t[a])] {
            let (cell, pos) = (v >> 1, v & 1);
            e[a][0] += w;
            e[a][1] += w * if cell == 0 { 1.0 } else { -1.0 };
            f[a][cell][0] += w;
            f[a][cell][1] += w * if pos == 0 { 1.0 } else { -1.0 };
        }
    }
    let mut k = [0.0f32; BLOCK_VALUES];
    for t in 0..8 {
        k[t] = e[0][t >> 2] * e[1][t >> 1 & 1] * e[2][t & 1];
    }
    for c in 0..8 {
        let (cx, cy, cz) = (c >> 2, c >> 1 & 1, c & 1);
        for t in 1..8 {
            k[8 + 7 * c + t - 1] = f[0][cx][t >> 2] * f[1][cy][t >> 1 & 1] * f[2][cz][t & 1];
        }
    }
    k
}

/// What a [`HaarFields`] lookup reads, for kernels on other devices that mirror
/// [`HaarFields::sample_into`] (the GPU frame): blocks per axis, per block its first
/// coefficient, per block and field its count, and the coefficients.
#[derive(Debug)]
pub struct HaarView<'a> {
    pub blocks: [usize; 3],
    pub starts: &'a [u32],
    pub counts: &'a [u8],
    pub coefs: HaarCoefs<'a>,
}

/// The kept coefficients as stored (f16 values widened to f32, exactly).
#[derive(Debug)]
pub enum HaarCoefs<'a> {
    /// Per coefficient its index in the block and its value.
    Split { indices: &'a [u8], values: Vec<f32> },
    /// Per coefficient one u16: the value in the top 10 bits (signed, in steps of its field's
    /// `steps` entry) and the index in the low 6.
    Packed { words: &'a [u16], steps: &'a [f32] },
}

impl HaarFields {
    /// The stored data a lookup reads.
    pub fn view(&self) -> HaarView<'_> {
        HaarView {
            blocks: self.blocks,
            starts: &self.starts,
            counts: &self.counts,
            coefs: match &self.coefs {
                Coefs::Split { indices, values } => HaarCoefs::Split {
                    indices,
                    values: (0..values.len()).map(|i| values.get(i)).collect(),
                },
                Coefs::Packed { words, steps } => HaarCoefs::Packed { words, steps },
            },
        }
    }

    /// Compresses `scales.len()` fields of a `dims` grid, `value(field, site)`, each with its
    /// scale (the threshold is relative to it).
    pub fn encode(
        dims: Dims,
        value: &(dyn Fn(usize, usize) -> f32 + Sync),
        scales: &[f32],
        threshold: f32,
        far_threshold: f32,
        region: &Region,
        precision: Precision,
    ) -> Result<HaarFields, RelightError> {
        let n = [dims.nx, dims.ny, dims.nz];
        // Lower corners run 0..=n-2; a block owns 3 of them per axis.
        let blocks = n.map(|v| (v - 1).div_ceil(OWN));
        let count = blocks[0] * blocks[1] * blocks[2];
        let nf = scales.len();
        // Worst case: every coefficient kept (index byte + value).
        sylva_core::check_memory(
            &format!("Haar compression of {nf} fields on a {dims} grid"),
            (count * nf * BLOCK_VALUES * (1 + precision.size()) + count * (nf + 4)) as u64,
        )?;
        // Blocks in x-slabs, in parallel; slabs concatenated in order, so the result does not
        // depend on the thread count.
        // Per x-slab of blocks: counts, indices, values, and coefficients per block.
        type Slab = (Vec<u8>, Vec<u8>, Vec<f32>, Vec<u32>);
        let slabs: Vec<Slab> = (0..blocks[0])
            .into_par_iter()
            .map(|bx| {
                let (mut counts, mut indices, mut values, mut sizes) =
                    (Vec::new(), Vec::new(), Vec::new(), Vec::new());
                for by in 0..blocks[1] {
                    for bz in 0..blocks[2] {
                        let b = [bx, by, bz];
                        let site = |x: usize, y: usize, z: usize| {
                            let c = [x, y, z];
                            let g: [usize; 3] =
                                std::array::from_fn(|a| (OWN * b[a] + c[a]).min(n[a] - 1));
                            dims.index(g[0], g[1], g[2])
                        };
                        let sites: [usize; BLOCK_VALUES] =
                            std::array::from_fn(|i| site(i / 16, i / 4 % 4, i % 4));
                        let near = sites.iter().any(|&s| region.contains(s));
                        let t = if near { threshold } else { far_threshold };
                        let mut size = 0u32;
                        for (f, &scale) in scales.iter().enumerate() {
                            let v = sites.map(|s| value(f, s));
                            let coefs = forward(&v);
                            // Far blocks drop details by the far threshold, but keep a mean
                            // that the near threshold would keep.
                            let limit = |k: usize| {
                                if k == 0 { threshold } else { t }
                            } * scale;
                            let before = indices.len();
                            for (k, &c) in coefs.iter().enumerate() {
                                let keep = c != 0.0 && c.abs() * rms_factor(k) >= limit(k);
                                if keep {
                                    indices.push(k as u8);
                                    values.push(c);
                                }
                            }
                            let kept = indices.len() - before;
                            counts.push(kept as u8);
                            size += kept as u32;
                        }
                        sizes.push(size);
                    }
                }
                (counts, indices, values, sizes)
            })
            .collect();
        let total: u64 = slabs.iter().map(|s| s.1.len() as u64).sum();
        if total > u32::MAX as u64 {
            return Err(RelightError::Target(format!(
                "{total} Haar coefficients kept: more than this format indexes (2³²); raise the threshold"
            )));
        }
        let mut starts = Vec::with_capacity(count + 1);
        let mut counts = Vec::with_capacity(count * nf);
        let mut indices = Vec::with_capacity(total as usize);
        let mut values = Vec::with_capacity(total as usize);
        let mut at = 0u32;
        for (c, i, v, sizes) in slabs {
            for s in sizes {
                starts.push(at);
                at += s;
            }
            counts.extend(c);
            indices.extend(i);
            values.extend(v);
        }
        starts.push(at);
        let coefs = match precision {
            Precision::Packed => {
                // Per field, steps of 1/511 of its largest kept coefficient.
                let mut largest = vec![0.0f32; nf];
                let mut at = 0usize;
                for (i, &n) in counts.iter().enumerate() {
                    let f = i % nf;
                    for &v in &values[at..at + n as usize] {
                        largest[f] = largest[f].max(v.abs());
                    }
                    at += n as usize;
                }
                let steps: Vec<f32> = largest
                    .iter()
                    .map(|&m| if m > 0.0 { m / PACKED_MAX } else { 1.0 })
                    .collect();
                let mut words = Vec::with_capacity(values.len());
                let mut at = 0usize;
                for (i, &n) in counts.iter().enumerate() {
                    let step = steps[i % nf];
                    for j in at..at + n as usize {
                        let q = (values[j] / step).round().clamp(-PACKED_MAX, PACKED_MAX) as i16;
                        words.push(((q << 6) as u16) | indices[j] as u16);
                    }
                    at += n as usize;
                }
                Coefs::Packed { words, steps }
            }
            _ => Coefs::Split {
                indices,
                values: Values::new(values, precision),
            },
        };
        Ok(HaarFields {
            dims,
            fields: nf,
            blocks,
            starts,
            counts,
            coefs,
        })
    }

    /// Bytes stored: starts, counts and coefficients.
    pub fn bytes(&self) -> u64 {
        (self.starts.len() * 4 + self.counts.len()) as u64 + self.coefs.bytes()
    }

    /// Coefficients kept, all blocks and fields.
    pub fn coefficients(&self) -> usize {
        self.coefs.len()
    }

    /// The block owning lower corner `corner`, and the corner's local coordinates.
    #[inline]
    fn block_of(&self, corner: [usize; 3]) -> (usize, [usize; 3]) {
        let b = corner.map(|c| c / OWN);
        let o = [0, 1, 2].map(|a| corner[a] - OWN * b[a]);
        ((b[0] * self.blocks[1] + b[1]) * self.blocks[2] + b[2], o)
    }

    /// Adds `Σ_terms w · field` interpolated at footprint `fp` to `out`; `terms` sorted by
    /// field (as [`super::ProjectedWeights`] holds them), so one pass over the block's counts
    /// finds every field.
    #[inline]
    pub fn sample_into(&self, fp: &Footprint, terms: &[(u32, [f32; 3])], out: &mut [f32; 3]) {
        let (b, k) = self.block_kernel(fp);
        self.sample_block(b, &k, terms, out);
    }

    /// The block answering a lookup at `fp` and its kernel: the same for every set of fields
    /// on the same grid, so several sets can share them ([`HaarFields::sample_block`]).
    #[inline]
    pub(crate) fn block_kernel(&self, fp: &Footprint) -> (usize, [f32; BLOCK_VALUES]) {
        let (b, o) = self.block_of(fp.corner);
        (b, kernel(o, fp.t))
    }

    /// [`HaarFields::sample_into`] with the block and kernel of [`HaarFields::block_kernel`].
    #[inline]
    pub(crate) fn sample_block(
        &self,
        b: usize,
        k: &[f32; BLOCK_VALUES],
        terms: &[(u32, [f32; 3])],
        out: &mut [f32; 3],
    ) {
        for (f, w, range) in self.term_coefficients(b, terms) {
            let v = self.coefs.dot(f, range, k);
            for c in 0..3 {
                out[c] += w[c] * v;
            }
        }
    }

    /// Per term of `terms` (sorted by field): its field, its weight and the range of block
    /// `b`'s kept coefficients of that field, found in one pass over the block's counts.
    #[inline]
    fn term_coefficients<'a>(
        &'a self,
        b: usize,
        terms: &'a [(u32, [f32; 3])],
    ) -> impl Iterator<Item = (usize, [f32; 3], std::ops::Range<usize>)> + 'a {
        let counts = &self.counts[b * self.fields..(b + 1) * self.fields];
        let (mut pos, mut next) = (self.starts[b] as usize, 0usize);
        terms.iter().map(move |&(f, w)| {
            let f = f as usize;
            pos += counts[next..f].iter().map(|&c| c as usize).sum::<usize>();
            let n = counts[f] as usize;
            let range = pos..pos + n;
            pos += n;
            next = f + 1;
            (f, w, range)
        })
    }

    /// The 4³ values block `b` stores for `field`, decoded in full (the reference for the
    /// footprint lookup).
    fn decode_block(&self, b: usize, field: usize) -> [f32; BLOCK_VALUES] {
        let counts = &self.counts[b * self.fields..(b + 1) * self.fields];
        let pos =
            self.starts[b] as usize + counts[..field].iter().map(|&c| c as usize).sum::<usize>();
        let n = counts[field] as usize;
        inverse((pos..pos + n).map(|i| self.coefs.get(field, i)))
    }

    /// Sites block `b` owns along axis `a`: 3b ..= 3b + 2, and up to the grid's end for the
    /// last block.
    fn span(&self, a: usize, b: usize) -> std::ops::RangeInclusive<usize> {
        let d = self.dims;
        let n = [d.nx, d.ny, d.nz];
        let hi = if b + 1 == self.blocks[a] {
            n[a] - 1
        } else {
            OWN * b + OWN - 1
        };
        OWN * b..=hi
    }

    /// Blocks stored.
    pub fn block_count(&self) -> usize {
        self.blocks.iter().product()
    }

    /// The block a lookup at `fp` reads, and the footprint's lower corner in it (each
    /// coordinate 0 to 2: the footprint's eight sites lie in the block's 4³).
    #[inline]
    pub fn footprint_block(&self, fp: &Footprint) -> (usize, [usize; 3]) {
        self.block_of(fp.corner)
    }

    /// Adds block `b`'s 4³ values of `Σ_terms w · field` to `out` (per colour, [`local`]
    /// order): a lookup in block `b` ([`HaarFields::sample_into`]) is their trilinear
    /// interpolation at the footprint, up to rounding, so lookups can read a block decoded
    /// once. `terms` sorted by field.
    pub fn add_block_combined(
        &self,
        b: usize,
        terms: &[(u32, [f32; 3])],
        out: &mut [[f32; BLOCK_VALUES]; 3],
    ) {
        let mut dense = [[0.0f32; BLOCK_VALUES]; 3];
        let mut details = false;
        for (f, w, range) in self.term_coefficients(b, terms) {
            for i in range {
                let (k, v) = self.coefs.get(f, i);
                details |= k != 0;
                for c in 0..3 {
                    dense[c][k] += w[c] * v;
                }
            }
        }
        // A block of its mean alone (most blocks away from the crown) is that mean at every
        // site: no transform.
        for c in 0..3 {
            if details {
                let v = inverse_dense(&dense[c]);
                for (o, v) in out[c].iter_mut().zip(v) {
                    *o += v;
                }
            } else {
                for o in out[c].iter_mut() {
                    *o += dense[c][0];
                }
            }
        }
    }

    /// Adds `Σ_terms w · field` at every site to `out` (site order as [`Dims::index`]; each
    /// site from the block that owns it, as [`HaarFields::decode_field`]): the combination
    /// of one sun decoded once, so lookups read 3 values per site instead of a kernel over
    /// the block. `terms` sorted by field, as [`super::ProjectedWeights`] holds them. Per
    /// block the kept coefficients are summed into one dense block per colour, then inverted.
    pub fn decode_combined_into(&self, terms: &[(u32, [f32; 3])], out: &mut [[f32; 3]]) {
        let d = self.dims;
        assert_eq!(
            out.len(),
            d.sites(),
            "a combination decoded onto another grid"
        );
        let plane = d.ny * d.nz;
        // One slab of x planes per row of blocks along x: disjoint, so decoded in parallel
        // and the same whatever the thread count.
        let mut slabs = Vec::with_capacity(self.blocks[0]);
        let mut rest = out;
        for bx in 0..self.blocks[0] {
            let xs = self.span(0, bx);
            let (slab, tail) = rest.split_at_mut((xs.end() + 1 - xs.start()) * plane);
            slabs.push((bx, slab));
            rest = tail;
        }
        slabs.into_par_iter().for_each(|(bx, slab)| {
            for by in 0..self.blocks[1] {
                for bz in 0..self.blocks[2] {
                    let b = (bx * self.blocks[1] + by) * self.blocks[2] + bz;
                    let mut values = [[0.0f32; BLOCK_VALUES]; 3];
                    self.add_block_combined(b, terms, &mut values);
                    for x in self.span(0, bx) {
                        for y in self.span(1, by) {
                            let row = ((x - OWN * bx) * d.ny + y) * d.nz;
                            for z in self.span(2, bz) {
                                let l = local(x - OWN * bx, y - OWN * by, z - OWN * bz);
                                for c in 0..3 {
                                    slab[row + z][c] += values[c][l];
                                }
                            }
                        }
                    }
                }
            }
        });
    }

    /// Field `field` at every site, each site taken from the block that owns it as a lower
    /// corner (the last plane of each axis from the last block).
    pub fn decode_field(&self, field: usize) -> Vec<f32> {
        let d = self.dims;
        let mut out = vec![0.0f32; d.sites()];
        let span = |a: usize, b: usize| self.span(a, b);
        for bx in 0..self.blocks[0] {
            for by in 0..self.blocks[1] {
                for bz in 0..self.blocks[2] {
                    let b = (bx * self.blocks[1] + by) * self.blocks[2] + bz;
                    let block = self.decode_block(b, field);
                    for x in span(0, bx) {
                        for y in span(1, by) {
                            for z in span(2, bz) {
                                out[d.index(x, y, z)] =
                                    block[local(x - OWN * bx, y - OWN * by, z - OWN * bz)];
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// `Σ_terms w · field` at footprint `fp` from fully decoded blocks (slow; tests).
    pub fn sample_by_full_decode(
        &self,
        fp: &Footprint,
        terms: &[(u32, [f32; 3])],
        out: &mut [f32; 3],
    ) {
        let (b, o) = self.block_of(fp.corner);
        let tri = fp.weights();
        for &(f, w) in terms {
            let block = self.decode_block(b, f as usize);
            let v: f32 = (0..8)
                .map(|k| {
                    tri[k] * block[local(o[0] + (k >> 2), o[1] + (k >> 1 & 1), o[2] + (k & 1))]
                })
                .sum();
            for c in 0..3 {
                out[c] += w[c] * v;
            }
        }
    }
}

impl HaarFields {
    /// Appends the fields to a compressed basis file's payload.
    pub(super) fn write_to(&self, w: &mut ByteWriter) {
        w.u32(self.fields as u32);
        for b in self.blocks {
            w.u32(b as u32);
        }
        w.u32s(&self.starts);
        w.u8s(&self.counts);
        match &self.coefs {
            Coefs::Split { indices, values } => {
                w.u8(0);
                w.u8s(indices);
                values.write_to(w);
            }
            Coefs::Packed { words, steps } => {
                w.u8(1);
                w.u16s(words);
                w.f32s(steps);
            }
        }
    }

    /// Reads what [`HaarFields::write_to`] wrote for a `dims` grid of `fields` fields, checking
    /// every index a lookup will follow (block starts, counts, coefficient indices), so a
    /// damaged file is an error here and never a panic later.
    pub(super) fn read_from(
        r: &mut ByteReader,
        dims: Dims,
        fields: usize,
    ) -> Result<HaarFields, String> {
        let stored = r.u32("Haar field count")? as usize;
        if stored != fields {
            return Err(format!(
                "Haar store of {stored} fields, the map needs {fields}"
            ));
        }
        let n = [dims.nx, dims.ny, dims.nz];
        let blocks = n.map(|v| (v - 1).div_ceil(OWN));
        for (a, &b) in blocks.iter().enumerate() {
            let got = r.u32("Haar block counts")? as usize;
            if got != b {
                return Err(format!(
                    "{got} Haar blocks along axis {a}, a {dims} grid has {b}"
                ));
            }
        }
        let count = blocks[0] * blocks[1] * blocks[2];
        let starts = r.u32s("Haar block starts")?;
        let counts = r.u8s("Haar coefficient counts")?;
        if starts.len() != count + 1 || counts.len() != count * fields {
            return Err(format!(
                "{} block starts and {} counts for {count} blocks of {fields} fields",
                starts.len(),
                counts.len()
            ));
        }
        if starts[0] != 0 {
            return Err("the first Haar block does not start at 0".into());
        }
        for b in 0..count {
            let kept: u32 = counts[b * fields..(b + 1) * fields]
                .iter()
                .map(|&c| c as u32)
                .sum();
            if counts[b * fields..(b + 1) * fields]
                .iter()
                .any(|&c| c as usize > BLOCK_VALUES)
                || starts[b].checked_add(kept) != Some(starts[b + 1])
            {
                return Err(format!("Haar block {b}: counts and starts disagree"));
            }
        }
        let total = starts[count] as usize;
        let coefs = match r.u8("Haar coefficient format")? {
            0 => {
                let indices = r.u8s("Haar coefficient indices")?;
                let values = Values::read_from(r, "Haar coefficient values")?;
                if indices.len() != total || values.len() != total {
                    return Err(format!(
                        "{} indices and {} values for {total} coefficients",
                        indices.len(),
                        values.len()
                    ));
                }
                if let Some(i) = indices.iter().position(|&i| i as usize >= BLOCK_VALUES) {
                    return Err(format!("Haar coefficient {i} has index {}", indices[i]));
                }
                Coefs::Split { indices, values }
            }
            1 => {
                let words = r.u16s("packed Haar coefficients")?;
                let steps = r.f32s("packed Haar steps")?;
                if words.len() != total || steps.len() != fields {
                    return Err(format!(
                        "{} packed coefficients for {total}, {} steps for {fields} fields",
                        words.len(),
                        steps.len()
                    ));
                }
                if steps.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                    return Err("a packed Haar step is not a positive finite number".into());
                }
                Coefs::Packed { words, steps }
            }
            t => return Err(format!("unknown Haar coefficient format {t}")),
        };
        Ok(HaarFields {
            dims,
            fields,
            blocks,
            starts,
            counts,
            coefs,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pseudo_random(n: usize, seed: u64) -> Vec<f32> {
        let mut r = sylva_core::SplitMix64::new(seed);
        (0..n).map(|_| r.next_f64() as f32).collect()
    }

    /// The butterfly inverse is the direct one, and a combination decoded at every site is
    /// the weighted sum of the fields decoded one by one (on a grid whose sides are not
    /// whole blocks, with coefficients dropped by the threshold and packed).
    #[test]
    fn combined_decode_is_the_sum_of_decoded_fields() {
        for seed in 0..4 {
            let c: [f32; 64] = pseudo_random(64, 20 + seed).try_into().unwrap();
            let (fast, slow) = (inverse_dense(&c), inverse(c.iter().copied().enumerate()));
            for i in 0..64 {
                assert!(
                    (fast[i] - slow[i]).abs() < 1e-5,
                    "{i}: {} vs {}",
                    fast[i],
                    slow[i]
                );
            }
        }
        let dims = Dims::new(11, 7, 9).unwrap();
        let fields = 5;
        let every = 10usize.div_ceil(3) * 6usize.div_ceil(3) * 8usize.div_ceil(3) * fields * 64;
        let noise = pseudo_random(fields * dims.sites(), 3);
        // Half the grid constant (x ≤ 6, two rows of blocks with their means alone).
        let half: Vec<f32> = (0..noise.len())
            .map(|i| {
                let (x, _, _) = dims.coords(i / fields);
                if x <= 6 {
                    0.3 + (i % fields) as f32
                } else {
                    noise[i]
                }
            })
            .collect();
        for (data, precision) in [
            (&noise, Precision::F32),
            (&noise, Precision::Packed),
            (&half, Precision::F32),
        ] {
            let h = HaarFields::encode(
                dims,
                &|f, s| data[s * fields + f],
                &vec![1.0; fields],
                0.05,
                0.05,
                &Region::all(dims),
                precision,
            )
            .unwrap();
            let terms = [
                (0u32, [0.5, 0.0, 2.0]),
                (2, [1.0, 1.0, 1.0]),
                (4, [-0.25, 3.0, 0.0]),
            ];
            let mut out = vec![[1.0f32; 3]; dims.sites()];
            h.decode_combined_into(&terms, &mut out);
            let decoded: Vec<Vec<f32>> = (0..fields).map(|f| h.decode_field(f)).collect();
            let mut worst = 0.0f32;
            for (s, o) in out.iter().enumerate() {
                for c in 0..3 {
                    let want = 1.0
                        + terms
                            .iter()
                            .map(|&(f, w)| w[c] * decoded[f as usize][s])
                            .sum::<f32>();
                    worst = worst.max((o[c] - want).abs());
                }
            }
            assert!(worst < 1e-4, "{precision:?}: off by {worst}");
            // Not a trivial decode: the threshold dropped coefficients, and the values vary.
            assert!(
                h.coefficients() < every,
                "{} of {every} kept",
                h.coefficients()
            );
            assert!(decoded[2].iter().any(|&v| (v - decoded[2][0]).abs() > 0.1));
        }
    }

    #[test]
    fn transform_round_trips_and_kernel_matches_full_decode() {
        let v: [f32; 64] = pseudo_random(64, 5).try_into().unwrap();
        let c = forward(&v);
        let back = inverse(c.iter().copied().enumerate());
        for i in 0..64 {
            assert!(
                (back[i] - v[i]).abs() < 1e-6,
                "{i}: {} vs {}",
                back[i],
                v[i]
            );
        }
        // A constant block is its mean alone.
        let c = forward(&[0.75; 64]);
        assert_eq!(c[0], 0.75);
        assert!(c[1..].iter().all(|&x| x == 0.0));
        // The kernel gives the trilinear interpolation of the decoded block.
        let mut r = sylva_core::SplitMix64::new(9);
        let c = forward(&v);
        for _ in 0..200 {
            let o = [0, 1, 2].map(|_| (r.next_u64() % 3) as usize);
            let t = [0, 1, 2].map(|_| r.next_f64() as f32);
            let k = kernel(o, t);
            let fast: f32 = (0..64).map(|i| c[i] * k[i]).sum();
            let fp = Footprint { corner: o, t };
            let w = fp.weights();
            let slow: f32 = (0..8)
                .map(|j| w[j] * v[local(o[0] + (j >> 2), o[1] + (j >> 1 & 1), o[2] + (j & 1))])
                .sum();
            assert!((fast - slow).abs() < 1e-5, "{o:?} {t:?}: {fast} vs {slow}");
        }
    }
}
