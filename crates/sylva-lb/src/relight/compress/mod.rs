//! Compression of a basis set (004 §4.2), with lookups that decode only a trilinear footprint.
//!
//! Every codec stores a few scalar *fields* over the grid and a linear map back to the
//! channels: `channel ≈ mean + Σ_f component[channel][f] · field_f`. A paper basis set has 57
//! channels (19 bases × 3 colours, [`CompressedBasis`]); any set of parts of three colours
//! each compresses the same way ([`CompressedChannels`]: the physical light's 25 sun parts,
//! or its 3 diffuse parts), channel `3 part + colour`, each channel measured in units of its
//! own scale (a basis's free-space value; a physical part's mean where light matters).
//!
//! * [`Codec::Haar`]: the fields are the channels themselves (identity map), each
//!   compressed with Haar wavelets on 4³ blocks ([`haar`]).
//! * [`Codec::Pca`]: the fields are the `rank` leading principal components across the
//!   channels ([`pca`]), stored per site.
//! * [`Codec::PcaHaar`]: the component fields, compressed with the Haar codec.
//!
//! **Relighting in the reduced space.** A combination `Σ_j w_j B_j` in colour c is a fixed
//! linear function of the channels, so [`CompressedBasis::project`] turns the weights, once per
//! instance and sun, into per-field weights and a constant ([`ProjectedWeights`]); a lookup is
//! then the interpolated fields with non-zero weight and a dot product (`rank` fields for
//! PCA; 3 per basis for Haar alone, one per colour).
//!
//! **Error.** [`relit_error`] compares relit lookups of the compressed set with the
//! uncompressed ones at random points of a region (where light matters), over many sun
//! directions; combinations normalised to free-space 1, so the RMSE is a fraction of
//! unobstructed sunlight.

mod file;
pub mod haar;
pub mod pca;

pub use file::COMPRESSED_EXTENSION;

use half::f16;
use rayon::prelude::*;

use self::haar::HaarFields;
use super::basis::{BasisOptions, BasisSet, BasisWeights, AMBIENT_FREE_SPACE};
use super::footprint::{Footprint, Placement};
use super::region::Region;
use super::{RelightError, CHANNELS};
use crate::grid::{Bounds, Dims};
use crate::params::MediumParams;

/// How stored values are kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    F16,
    F32,
    /// Haar codecs only: a coefficient's index and value in 16 bits, the value in steps of
    /// 1/511 of the largest coefficient of its field (2 bytes per coefficient instead of 3).
    Packed,
}

impl Precision {
    /// `f16`, `f32` or `packed`.
    pub fn parse(s: &str) -> Option<Precision> {
        Some(match s {
            "f16" => Precision::F16,
            "f32" => Precision::F32,
            "packed" => Precision::Packed,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Precision::F16 => "f16",
            Precision::F32 => "f32",
            Precision::Packed => "packed",
        }
    }

    /// Bytes per stored value (a packed coefficient's index included).
    pub fn size(self) -> usize {
        match self {
            Precision::F16 | Precision::Packed => 2,
            Precision::F32 => 4,
        }
    }
}

/// Stored values in their precision.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Values {
    F16(Vec<f16>),
    F32(Vec<f32>),
}

impl Values {
    fn new(v: Vec<f32>, precision: Precision) -> Values {
        match precision {
            Precision::F32 => Values::F32(v),
            Precision::F16 | Precision::Packed => {
                Values::F16(v.into_iter().map(f16::from_f32).collect())
            }
        }
    }

    #[inline]
    fn get(&self, i: usize) -> f32 {
        match self {
            Values::F16(v) => v[i].to_f32(),
            Values::F32(v) => v[i],
        }
    }

    fn bytes(&self) -> u64 {
        match self {
            Values::F16(v) => v.len() as u64 * 2,
            Values::F32(v) => v.len() as u64 * 4,
        }
    }

    pub(crate) fn len(&self) -> usize {
        match self {
            Values::F16(v) => v.len(),
            Values::F32(v) => v.len(),
        }
    }

    /// A tag (0 f16, 1 f32) and the values.
    pub(crate) fn write_to(&self, w: &mut sylva_core::container::ByteWriter) {
        match self {
            Values::F16(v) => {
                w.u8(0);
                w.u16s(&v.iter().map(|x| x.to_bits()).collect::<Vec<u16>>());
            }
            Values::F32(v) => {
                w.u8(1);
                w.f32s(v);
            }
        }
    }

    /// Reads what [`Values::write_to`] wrote; every value must be finite.
    pub(crate) fn read_from(
        r: &mut sylva_core::container::ByteReader,
        what: &str,
    ) -> Result<Values, String> {
        let v = match r.u8(what)? {
            0 => Values::F16(r.u16s(what)?.into_iter().map(f16::from_bits).collect()),
            1 => Values::F32(r.f32s(what)?),
            t => return Err(format!("{what}: unknown value format {t}")),
        };
        if let Some(i) = (0..v.len()).find(|&i| !v.get(i).is_finite()) {
            return Err(format!("{what}: value {i} is {}", v.get(i)));
        }
        Ok(v)
    }
}

/// Which codec, and how hard it compresses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Codec {
    /// Haar wavelets on each of the 57 channels; `threshold` is the RMS error a dropped
    /// coefficient may add to its block, as a fraction of the channel's free-space value.
    Haar { threshold: f64 },
    /// `rank` principal components per site.
    Pca { rank: usize },
    /// `rank` principal components, their fields compressed with Haar wavelets.
    PcaHaar { rank: usize, threshold: f64 },
    /// Per base solution, its three colours decorrelated (3 components each), then Haar
    /// wavelets on the 57 fields: the minor colour components are small and mostly dropped.
    ColourHaar { threshold: f64 },
}

impl Codec {
    /// `haar:T`, `pca:K`, `pcahaar:K:T` or `colour:T` (see [`Codec::name`]).
    pub fn parse(s: &str) -> Result<Codec, String> {
        let parts: Vec<&str> = s.split(':').collect();
        let bad = || format!("codec '{s}': expected haar:T, pca:K, pcahaar:K:T or colour:T");
        let t = |v: &str| v.parse::<f64>().map_err(|_| bad());
        let k = |v: &str| v.parse::<usize>().map_err(|_| bad());
        Ok(match parts[..] {
            ["haar", a] => Codec::Haar { threshold: t(a)? },
            ["pca", a] => Codec::Pca { rank: k(a)? },
            ["pcahaar", a, b] => Codec::PcaHaar {
                rank: k(a)?,
                threshold: t(b)?,
            },
            ["colour", a] => Codec::ColourHaar { threshold: t(a)? },
            _ => return Err(bad()),
        })
    }

    /// The form [`Codec::parse`] reads.
    pub fn name(&self) -> String {
        match *self {
            Codec::Haar { threshold } => format!("haar:{threshold}"),
            Codec::Pca { rank } => format!("pca:{rank}"),
            Codec::PcaHaar { rank, threshold } => format!("pcahaar:{rank}:{threshold}"),
            Codec::ColourHaar { threshold } => format!("colour:{threshold}"),
        }
    }
}

/// What to compress to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompressTarget {
    pub codec: Codec,
    pub precision: Precision,
    /// The Haar threshold for the details of blocks that do not meet the region (their mean
    /// is kept by the threshold as everywhere). Infinite: block means alone there.
    pub far_threshold: f64,
}

impl CompressTarget {
    /// `codec` with f16 values and block means alone away from the region.
    pub fn new(codec: Codec) -> CompressTarget {
        CompressTarget {
            codec,
            precision: Precision::F16,
            far_threshold: f64::INFINITY,
        }
    }

    /// The recommended target (docs/PERFORMANCE.md, "Relighting"): per-basis colour
    /// decorrelation, Haar wavelets at threshold 0.004, packed coefficients.
    pub fn recommended() -> CompressTarget {
        CompressTarget {
            precision: Precision::Packed,
            ..CompressTarget::new(Codec::ColourHaar { threshold: 0.004 })
        }
    }

    /// Checks the target for a paper basis set (57 channels).
    pub fn validate(&self) -> Result<(), RelightError> {
        self.validate_for(CHANNELS)
    }

    /// Checks the target for a set of `channels` channels (a PCA rank is at most that).
    pub fn validate_for(&self, channels: usize) -> Result<(), RelightError> {
        let bad = |what: String| Err(RelightError::Target(what));
        let threshold_ok = |t: f64| !t.is_nan() && t >= 0.0;
        match self.codec {
            Codec::Haar { threshold }
            | Codec::PcaHaar { threshold, .. }
            | Codec::ColourHaar { threshold }
                if !(threshold.is_finite() && threshold >= 0.0) =>
            {
                return bad(format!(
                    "Haar threshold {threshold} must be a finite number ≥ 0"
                ))
            }
            Codec::Pca { rank } | Codec::PcaHaar { rank, .. }
                if !(1..=channels).contains(&rank) =>
            {
                return bad(format!("rank {rank} must lie in 1..={channels}"))
            }
            _ => {}
        }
        if self.precision == Precision::Packed && matches!(self.codec, Codec::Pca { .. }) {
            return bad("packed values need a Haar codec (PCA alone stores plain fields)".into());
        }
        if !threshold_ok(self.far_threshold) {
            return bad(format!(
                "far threshold {} must be ≥ 0 (infinite: block means alone)",
                self.far_threshold
            ));
        }
        Ok(())
    }
}

/// From fields back to channels.
#[derive(Debug, Clone, PartialEq)]
enum Transform {
    /// Field `f` is channel `f`.
    Identity,
    /// `channel = mean + Σ_f components[channel · rank + f] · field_f`.
    Linear {
        mean: Vec<f32>,
        components: Vec<f32>,
        rank: usize,
    },
}

/// Fields at every site, site-major (`site · fields + field`).
#[derive(Debug, Clone, PartialEq)]
struct DenseFields {
    dims: Dims,
    fields: usize,
    values: Values,
}

impl DenseFields {
    #[inline]
    fn sample_into(&self, fp: &Footprint, terms: &[(u32, [f32; 3])], out: &mut [f32; 3]) {
        let (sites, tri) = (fp.sites(self.dims), fp.weights());
        for &(f, w) in terms {
            let v: f32 = (0..8)
                .map(|k| tri[k] * self.values.get(sites[k] * self.fields + f as usize))
                .sum();
            for c in 0..3 {
                out[c] += w[c] * v;
            }
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
enum Store {
    Dense(DenseFields),
    Haar(HaarFields),
}

/// A combination projected onto a compressed set's fields (made by
/// [`CompressedBasis::project`]): colour c of a lookup is
/// `constant[c] + Σ_terms weights[c] · field`.
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectedWeights {
    /// Fields of the set it was projected for.
    fields: usize,
    constant: [f32; 3],
    /// `(field, per-colour weight)`, sorted by field, zero terms left out.
    terms: Vec<(u32, [f32; 3])>,
}

impl ProjectedWeights {
    /// The part of the combination that does not vary over the grid (the mean's share).
    pub fn constant(&self) -> [f32; 3] {
        self.constant
    }

    /// `(field, per-colour weight)` of every field a lookup reads, sorted by field.
    pub fn terms(&self) -> &[(u32, [f32; 3])] {
        &self.terms
    }
}

/// [`CompressedBasis::stored_fields`]: what a lookup of the projected combination reads.
#[derive(Debug)]
pub enum StoredFields<'a> {
    /// Field after field, every site's value (f16 widened to f32, exactly).
    Dense(Vec<Vec<f32>>),
    /// Haar blocks ([`HaarFields::sample_into`]).
    Haar(haar::HaarView<'a>),
}

/// Fields of some channels and the map back to them: what every codec stores.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Encoded {
    /// Channels the map gives back (`3 part + colour`).
    channels: usize,
    transform: Transform,
    store: Store,
}

impl Encoded {
    /// Compresses `channels` channels of a `dims` grid, `value(channel, site)`, each in units
    /// of its `scales` entry (Haar thresholds and PCA components are taken in these units),
    /// spending the bits on `region`.
    fn encode(
        dims: Dims,
        channels: usize,
        value: &(dyn Fn(usize, usize) -> f32 + Sync),
        scales: &[f64],
        region: &Region,
        target: &CompressTarget,
    ) -> Result<Encoded, RelightError> {
        target.validate_for(channels)?;
        if region.dims != dims {
            return Err(RelightError::Mismatch(format!(
                "region of a {} grid for a {dims} set",
                region.dims
            )));
        }
        if channels == 0 || !channels.is_multiple_of(3) || scales.len() != channels {
            return Err(RelightError::Mismatch(format!(
                "{channels} channels with {} scales: expected three colours per part, one scale each",
                scales.len()
            )));
        }
        if let Some(c) = scales.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(RelightError::Target(format!(
                "channel {c}'s scale {} is not a positive finite number",
                scales[c]
            )));
        }
        let far = target.far_threshold as f32;
        let (transform, store) = match target.codec {
            Codec::Haar { threshold } => {
                let scales: Vec<f32> = scales.iter().map(|&s| s as f32).collect();
                let haar = HaarFields::encode(
                    dims,
                    value,
                    &scales,
                    threshold as f32,
                    far,
                    region,
                    target.precision,
                )?;
                (Transform::Identity, Store::Haar(haar))
            }
            Codec::Pca { .. } | Codec::PcaHaar { .. } | Codec::ColourHaar { .. } => {
                let structure = match target.codec {
                    Codec::Pca { rank } | Codec::PcaHaar { rank, .. } => {
                        pca::Structure::Global { rank }
                    }
                    _ => pca::Structure::PerBasis,
                };
                let p = pca::fit(dims, channels, value, scales, region, structure)?;
                let rank = p.rank;
                let store = match target.codec {
                    Codec::PcaHaar { threshold, .. } | Codec::ColourHaar { threshold } => {
                        let coefs = &p.coefficients;
                        Store::Haar(HaarFields::encode(
                            dims,
                            &|f, s| coefs[s * rank + f],
                            &vec![1.0; rank],
                            threshold as f32,
                            far,
                            region,
                            target.precision,
                        )?)
                    }
                    _ => Store::Dense(DenseFields {
                        dims,
                        fields: rank,
                        values: Values::new(p.coefficients, target.precision),
                    }),
                };
                let transform = Transform::Linear {
                    mean: p.mean,
                    components: p.components,
                    rank,
                };
                (transform, store)
            }
        };
        Ok(Encoded {
            channels,
            transform,
            store,
        })
    }

    fn bytes(&self) -> u64 {
        let store = match &self.store {
            Store::Dense(d) => d.values.bytes(),
            Store::Haar(h) => h.bytes(),
        };
        let transform = match &self.transform {
            Transform::Identity => 0,
            Transform::Linear {
                mean, components, ..
            } => (mean.len() + components.len()) as u64 * 4,
        };
        store + transform
    }

    fn fields(&self) -> usize {
        match &self.transform {
            Transform::Identity => self.channels,
            Transform::Linear { rank, .. } => *rank,
        }
    }

    fn haar_coefficients(&self) -> usize {
        match &self.store {
            Store::Haar(h) => h.coefficients(),
            Store::Dense(_) => 0,
        }
    }

    /// Projects `Σ_part w_part[c] · channel(3 part + c)` onto the fields.
    fn project(&self, terms: impl Iterator<Item = (usize, [f64; 3])>) -> ProjectedWeights {
        match &self.transform {
            Transform::Identity => {
                // Per part, its colours' weights (a part named twice adds up); the fields in
                // order, as a Haar lookup walks them.
                let mut per_part: Vec<Option<[f64; 3]>> = vec![None; self.channels / 3];
                for (j, w) in terms {
                    let p = per_part[j].get_or_insert([0.0; 3]);
                    for c in 0..3 {
                        p[c] += w[c];
                    }
                }
                let mut out = Vec::new();
                for (j, w) in per_part.iter().enumerate() {
                    let Some(w) = w else { continue };
                    for c in (0..3).filter(|&c| w[c] != 0.0) {
                        let mut v = [0.0f32; 3];
                        v[c] = w[c] as f32;
                        out.push(((3 * j + c) as u32, v));
                    }
                }
                ProjectedWeights {
                    fields: self.channels,
                    constant: [0.0; 3],
                    terms: out,
                }
            }
            Transform::Linear {
                mean,
                components,
                rank,
            } => {
                let mut constant = [0.0f64; 3];
                let mut per_field = vec![[0.0f64; 3]; *rank];
                for (j, w) in terms {
                    for c in 0..3 {
                        let ch = 3 * j + c;
                        constant[c] += w[c] * mean[ch] as f64;
                        for (f, p) in per_field.iter_mut().enumerate() {
                            p[c] += w[c] * components[ch * rank + f] as f64;
                        }
                    }
                }
                ProjectedWeights {
                    fields: *rank,
                    constant: constant.map(|v| v as f32),
                    terms: per_field
                        .iter()
                        .enumerate()
                        .filter(|(_, p)| p.iter().any(|&v| v != 0.0))
                        .map(|(f, p)| (f as u32, p.map(|v| v as f32)))
                        .collect(),
                }
            }
        }
    }

    #[inline]
    fn sample_grid(&self, dims: Dims, g: [f32; 3], w: &ProjectedWeights) -> [f32; 3] {
        assert_eq!(
            w.fields,
            self.fields(),
            "weights projected for a compressed set with another number of fields"
        );
        let fp = Footprint::at(dims, g);
        let mut out = w.constant;
        match &self.store {
            Store::Dense(d) => d.sample_into(&fp, &w.terms, &mut out),
            Store::Haar(h) => h.sample_into(&fp, &w.terms, &mut out),
        }
        out
    }

    /// Adds the combination `w` at every site to `out` (its constant included).
    fn decode_combined_into(&self, w: &ProjectedWeights, out: &mut [[f32; 3]]) {
        assert_eq!(
            w.fields,
            self.fields(),
            "weights projected for a compressed set with another number of fields"
        );
        match &self.store {
            Store::Haar(h) => h.decode_combined_into(&w.terms, out),
            Store::Dense(d) => out.par_iter_mut().enumerate().for_each(|(s, o)| {
                for &(f, wf) in &w.terms {
                    let v = d.values.get(s * d.fields + f as usize);
                    for c in 0..3 {
                        o[c] += wf[c] * v;
                    }
                }
            }),
        }
        out.par_iter_mut().for_each(|o| {
            for (v, k) in o.iter_mut().zip(w.constant) {
                *v += k;
            }
        });
    }

    fn sample_grid_by_full_decode(
        &self,
        dims: Dims,
        g: [f32; 3],
        w: &ProjectedWeights,
    ) -> [f32; 3] {
        match &self.store {
            Store::Dense(_) => self.sample_grid(dims, g, w),
            Store::Haar(h) => {
                let mut out = w.constant;
                h.sample_by_full_decode(&Footprint::at(dims, g), &w.terms, &mut out);
                out
            }
        }
    }

    fn stored_fields(&self, dims: Dims) -> StoredFields<'_> {
        match &self.store {
            Store::Haar(h) => StoredFields::Haar(h.view()),
            Store::Dense(d) => StoredFields::Dense(
                (0..self.fields())
                    .map(|f| {
                        (0..dims.sites())
                            .map(|s| d.values.get(s * d.fields + f))
                            .collect()
                    })
                    .collect(),
            ),
        }
    }

    fn decode_field(&self, dims: Dims, f: usize) -> Vec<f32> {
        assert!(f < self.fields(), "field {f} of {}", self.fields());
        match &self.store {
            Store::Haar(h) => h.decode_field(f),
            Store::Dense(d) => (0..dims.sites())
                .map(|s| d.values.get(s * d.fields + f))
                .collect(),
        }
    }

    /// Every channel at every site (Haar: each site from the block that owns it), after the
    /// memory for them is checked (`what` names the set).
    fn decode_channels(&self, dims: Dims, what: &str) -> Result<Vec<Vec<f32>>, RelightError> {
        let n = dims.sites();
        sylva_core::check_memory(
            &format!("decompressing {what} on a {dims} grid"),
            ((self.channels + self.fields()) * n * 4) as u64,
        )?;
        let fields: Vec<Vec<f32>> = (0..self.fields())
            .into_par_iter()
            .map(|f| self.decode_field(dims, f))
            .collect();
        Ok(match &self.transform {
            Transform::Identity => fields,
            Transform::Linear {
                mean,
                components,
                rank,
            } => (0..self.channels)
                .into_par_iter()
                .map(|ch| {
                    (0..n)
                        .map(|s| {
                            let mut v = mean[ch] as f64;
                            for f in 0..*rank {
                                v += components[ch * rank + f] as f64 * fields[f][s] as f64;
                            }
                            v as f32
                        })
                        .collect()
                })
                .collect(),
        })
    }
}

/// A compressed basis set.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedBasis {
    pub dims: Dims,
    pub bounds: Bounds,
    /// The medium and schedule the basis set was solved with.
    pub medium: MediumParams,
    pub options: BasisOptions,
    pub target: CompressTarget,
    encoded: Encoded,
}

/// Each channel's scale in a paper basis set: its free-space value (18 for `B_0`'s colours,
/// 1 for the others).
fn basis_scales() -> Vec<f64> {
    (0..CHANNELS)
        .map(|c| if c < 3 { AMBIENT_FREE_SPACE } else { 1.0 })
        .collect()
}

/// Compresses `basis`, spending the bits on `region` (see [`CompressTarget`]).
pub fn compress(
    basis: &BasisSet,
    region: &Region,
    target: &CompressTarget,
) -> Result<CompressedBasis, RelightError> {
    target.validate()?;
    if region.dims != basis.dims {
        return Err(RelightError::Mismatch(format!(
            "region of a {} grid for a {} basis set",
            region.dims, basis.dims
        )));
    }
    let ch = basis.channels();
    let encoded = Encoded::encode(
        basis.dims,
        CHANNELS,
        &|c, s| ch[c][s],
        &basis_scales(),
        region,
        target,
    )?;
    Ok(CompressedBasis {
        dims: basis.dims,
        bounds: basis.bounds,
        medium: basis.medium.clone(),
        options: basis.options,
        target: *target,
        encoded,
    })
}

impl CompressedBasis {
    /// Bytes of compressed data held (fields, their index, and the map back to channels).
    pub fn bytes(&self) -> u64 {
        self.encoded.bytes()
    }

    /// Fields stored (57 for Haar alone, the rank for PCA).
    pub fn fields(&self) -> usize {
        self.encoded.fields()
    }

    /// Haar coefficients kept (0 without Haar).
    pub fn haar_coefficients(&self) -> usize {
        self.encoded.haar_coefficients()
    }

    /// Projects a combination onto the fields: once per instance and sun.
    pub fn project(&self, weights: &BasisWeights) -> ProjectedWeights {
        let terms: Vec<(usize, f64)> = weights.terms().collect();
        self.encoded
            .project(terms.iter().map(|&(j, w)| (j, [w; 3])))
    }

    /// The relit light at grid coordinates `g` (in sites, clamped to the grid), decoding only
    /// the footprint. `w` must come from this set's [`CompressedBasis::project`].
    #[inline]
    pub fn sample_grid(&self, g: [f32; 3], w: &ProjectedWeights) -> [f32; 3] {
        self.encoded.sample_grid(self.dims, g, w)
    }

    /// The relit light at model-space point `p` (placement as [`BasisSet::placement`]).
    pub fn sample(&self, p: [f32; 3], w: &ProjectedWeights) -> [f32; 3] {
        self.sample_grid(Placement::new(self.dims, self.bounds).grid_coords(p), w)
    }

    /// [`CompressedBasis::sample_grid`] through a full decode of the block (Haar) instead of
    /// the footprint kernel: the reference the fast path is tested against.
    pub fn sample_grid_by_full_decode(&self, g: [f32; 3], w: &ProjectedWeights) -> [f32; 3] {
        self.encoded.sample_grid_by_full_decode(self.dims, g, w)
    }

    /// The stored fields as a lookup reads them (for kernels on other devices that mirror
    /// [`CompressedBasis::sample_grid`]): per-site values, or Haar blocks.
    pub fn stored_fields(&self) -> StoredFields<'_> {
        self.encoded.stored_fields(self.dims)
    }

    /// Field `f` (< [`CompressedBasis::fields`]) at every site, site order as in
    /// [`LightingGrid`] (Haar: each site from the block that owns it). A lookup of the
    /// projected combination is `constant + Σ_terms weights · trilinear(field)`.
    pub fn decode_field(&self, f: usize) -> Vec<f32> {
        self.encoded.decode_field(self.dims, f)
    }

    /// Decodes every channel at every site (Haar: each site from the block that owns it).
    pub fn decompress(&self) -> Result<BasisSet, RelightError> {
        sylva_core::check_memory(
            &format!("decompressing a basis set on a {} grid", self.dims),
            BasisSet::memory_needed(self.dims) + (self.fields() * self.dims.sites() * 4) as u64,
        )?;
        let channels = self.encoded.decode_channels(self.dims, "a basis set")?;
        BasisSet::new(
            self.dims,
            self.bounds,
            self.medium.clone(),
            self.options,
            channels,
        )
    }
}

/// Parts of three colours each over a grid, compressed: channel `3 part + colour`
/// ([`compress_channels`]). The physical light's parts are kept this way.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedChannels {
    pub dims: Dims,
    pub target: CompressTarget,
    encoded: Encoded,
}

/// Compresses `channels` channels (three colours per part) of a `dims` grid,
/// `value(channel, site)`, each in units of its `scales` entry (a Haar threshold is a
/// fraction of it; PCA weighs channels in these units), spending the bits on `region`.
pub fn compress_channels(
    dims: Dims,
    channels: usize,
    value: &(dyn Fn(usize, usize) -> f32 + Sync),
    scales: &[f64],
    region: &Region,
    target: &CompressTarget,
) -> Result<CompressedChannels, RelightError> {
    Ok(CompressedChannels {
        dims,
        target: *target,
        encoded: Encoded::encode(dims, channels, value, scales, region, target)?,
    })
}

impl CompressedChannels {
    /// Channels held (three per part).
    pub fn channels(&self) -> usize {
        self.encoded.channels
    }

    /// Bytes of compressed data held (fields, their index, and the map back to channels).
    pub fn bytes(&self) -> u64 {
        self.encoded.bytes()
    }

    /// Fields stored (the channels for Haar alone, the rank for PCA).
    pub fn fields(&self) -> usize {
        self.encoded.fields()
    }

    /// Projects `Σ_part w_part[c] · channel(3 part + c)` onto the fields (`terms`: part and
    /// per-colour weight): once per instance and sun.
    pub fn project(&self, terms: &[(usize, [f32; 3])]) -> ProjectedWeights {
        self.encoded
            .project(terms.iter().map(|&(j, w)| (j, w.map(f64::from))))
    }

    /// The projected combination at grid coordinates `g` (in sites, clamped to the grid),
    /// decoding only the footprint. `w` must come from this set's
    /// [`CompressedChannels::project`].
    #[inline]
    pub fn sample_grid(&self, g: [f32; 3], w: &ProjectedWeights) -> [f32; 3] {
        self.encoded.sample_grid(self.dims, g, w)
    }

    /// Every channel at every site (Haar: each site from the block that owns it).
    pub fn decompress(&self) -> Result<Vec<Vec<f32>>, RelightError> {
        self.encoded.decode_channels(self.dims, "compressed parts")
    }

    /// Adds the projected combination `w` at every site to `out` (site order as
    /// [`Dims::index`]; Haar: each site from the block that owns it): one sun's light
    /// decoded once for the frames that follow. Lookups of it match
    /// [`CompressedChannels::sample_grid`] at the sites, and between them wherever the
    /// footprint lies in one block.
    pub fn decode_combined_into(&self, w: &ProjectedWeights, out: &mut [[f32; 3]]) {
        assert_eq!(
            out.len(),
            self.dims.sites(),
            "a combination decoded onto another grid"
        );
        self.encoded.decode_combined_into(w, out)
    }

    /// `self`'s combination `w` plus `other`'s combination `v` at grid coordinates `g`: the
    /// sum of the two [`CompressedChannels::sample_grid`]s, the footprint found once and, when
    /// both are Haar sets on one grid, its kernel built once for both.
    #[inline]
    pub fn sample_grid_with(
        &self,
        w: &ProjectedWeights,
        other: &CompressedChannels,
        v: &ProjectedWeights,
        g: [f32; 3],
    ) -> [f32; 3] {
        if let (Store::Haar(a), Store::Haar(b), true) = (
            &self.encoded.store,
            &other.encoded.store,
            self.dims == other.dims,
        ) {
            for (x, set) in [(w, self), (v, other)] {
                assert_eq!(
                    x.fields,
                    set.fields(),
                    "weights projected for a compressed set with another number of fields"
                );
            }
            let fp = Footprint::at(self.dims, g);
            let (block, k) = a.block_kernel(&fp);
            let mut out: [f32; 3] = std::array::from_fn(|c| w.constant[c] + v.constant[c]);
            a.sample_block(block, &k, &w.terms, &mut out);
            b.sample_block(block, &k, &v.terms, &mut out);
            return out;
        }
        let (x, y) = (self.sample_grid(g, w), other.sample_grid(g, v));
        [x[0] + y[0], x[1] + y[1], x[2] + y[2]]
    }
}

/// One combination of two compressed sets (a model's sun parts and diffuse parts) decoded
/// block by block as lookups reach them ([`CompressedChannels::sample_blocks_with`]): a frame
/// that reads few sites decodes only the blocks it reads, each once, where decoding every
/// site would cost more than the frame saves. Each block holds its 4³ values per colour
/// (both sets' terms and constants summed), so a lookup is 8 reads. Sparse: a chunk of
/// [`BLOCK_CHUNK`] block slots is made when a lookup first reaches it, so a cache costs
/// memory only for the blocks read. Every cache of one frame draws on one [`BlockBudget`];
/// past it a block is decoded for its lookup and not kept. A lookup's value is the same
/// either way, and whichever thread decodes first: only the time depends on the budget.
#[derive(Debug)]
pub struct BlockCache {
    chunks: Vec<std::sync::OnceLock<Box<BlockChunk>>>,
    count: usize,
    budget: std::sync::Arc<BlockBudget>,
}

/// Block slots made together in a [`BlockCache`].
pub const BLOCK_CHUNK: usize = 16;

type DecodedBlock = [[f32; haar::BLOCK_VALUES]; 3];
type BlockChunk = [std::sync::OnceLock<Box<DecodedBlock>>; BLOCK_CHUNK];

/// Bytes the [`BlockCache`]s of one sun may keep, shared between them.
#[derive(Debug)]
pub struct BlockBudget {
    left: std::sync::atomic::AtomicI64,
}

impl BlockBudget {
    pub fn new(bytes: u64) -> std::sync::Arc<BlockBudget> {
        std::sync::Arc::new(BlockBudget {
            left: std::sync::atomic::AtomicI64::new(bytes.min(i64::MAX as u64) as i64),
        })
    }

    /// Takes `bytes` if they are left.
    fn take(&self, bytes: u64) -> bool {
        use std::sync::atomic::Ordering;
        let bytes = bytes as i64;
        self.left
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |left| {
                (left >= bytes).then_some(left - bytes)
            })
            .is_ok()
    }

    fn give_back(&self, bytes: u64) {
        self.left
            .fetch_add(bytes as i64, std::sync::atomic::Ordering::Relaxed);
    }

    /// Bytes left.
    pub fn left(&self) -> u64 {
        self.left.load(std::sync::atomic::Ordering::Relaxed).max(0) as u64
    }
}

const CHUNK_BYTES: u64 = std::mem::size_of::<BlockChunk>() as u64;
const BLOCK_BYTES: u64 = std::mem::size_of::<DecodedBlock>() as u64;

impl BlockCache {
    /// An empty cache for `count` blocks drawing on `budget`.
    pub fn new(count: usize, budget: std::sync::Arc<BlockBudget>) -> BlockCache {
        BlockCache {
            chunks: (0..count.div_ceil(BLOCK_CHUNK))
                .map(|_| std::sync::OnceLock::new())
                .collect(),
            count,
            budget,
        }
    }

    /// Bytes an empty cache of `count` blocks holds (its chunk index).
    pub fn index_bytes(count: usize) -> u64 {
        count.div_ceil(BLOCK_CHUNK) as u64
            * std::mem::size_of::<std::sync::OnceLock<Box<BlockChunk>>>() as u64
    }

    /// Blocks decoded and kept so far.
    pub fn decoded(&self) -> usize {
        self.chunks
            .iter()
            .flat_map(|c| c.get())
            .map(|c| c.iter().filter(|b| b.get().is_some()).count())
            .sum()
    }

    /// `read` of block `b`'s values: kept, or `decode`d (and kept while the budget lasts).
    #[inline]
    fn with_block<R>(
        &self,
        b: usize,
        decode: impl Fn() -> DecodedBlock,
        read: impl FnOnce(&DecodedBlock) -> R,
    ) -> R {
        debug_assert!(b < self.count);
        let slot = &self.chunks[b / BLOCK_CHUNK];
        let chunk = match slot.get() {
            Some(c) => c,
            None if self.budget.take(CHUNK_BYTES) => {
                let mut made = false;
                let c = slot.get_or_init(|| {
                    made = true;
                    Box::new(std::array::from_fn(|_| std::sync::OnceLock::new()))
                });
                if !made {
                    self.budget.give_back(CHUNK_BYTES);
                }
                c
            }
            None => return read(&decode()),
        };
        let cell = &chunk[b % BLOCK_CHUNK];
        if let Some(v) = cell.get() {
            return read(v);
        }
        if !self.budget.take(BLOCK_BYTES) {
            return read(&decode());
        }
        let mut made = false;
        let v = cell.get_or_init(|| {
            made = true;
            Box::new(decode())
        });
        if !made {
            self.budget.give_back(BLOCK_BYTES);
        }
        read(v)
    }
}

impl CompressedChannels {
    /// Blocks a [`BlockCache`] of this set and `other` holds: `Some` when both are Haar sets
    /// on one grid (block lookups need the blocks).
    pub fn block_count_with(&self, other: &CompressedChannels) -> Option<usize> {
        match (&self.encoded.store, &other.encoded.store) {
            (Store::Haar(a), Store::Haar(b)) if self.dims == other.dims => {
                debug_assert_eq!(a.block_count(), b.block_count());
                Some(a.block_count())
            }
            _ => None,
        }
    }

    /// [`CompressedChannels::sample_grid_with`] read from `cache`, each block decoded on its
    /// first lookup: the same value up to rounding. `cache` must hold this pair's blocks
    /// ([`CompressedChannels::block_count_with`]) for these weights alone.
    #[inline]
    pub fn sample_blocks_with(
        &self,
        w: &ProjectedWeights,
        other: &CompressedChannels,
        v: &ProjectedWeights,
        g: [f32; 3],
        cache: &BlockCache,
    ) -> [f32; 3] {
        let (Store::Haar(a), Store::Haar(b)) = (&self.encoded.store, &other.encoded.store) else {
            return self.sample_grid_with(w, other, v, g);
        };
        let fp = Footprint::at(self.dims, g);
        let (block, o) = a.footprint_block(&fp);
        let decode = || {
            let mut out: DecodedBlock =
                std::array::from_fn(|c| [w.constant[c] + v.constant[c]; haar::BLOCK_VALUES]);
            a.add_block_combined(block, &w.terms, &mut out);
            b.add_block_combined(block, &v.terms, &mut out);
            out
        };
        cache.with_block(block, decode, |values| {
            let mut out = [0.0f32; 3];
            for (corner, wt) in fp.weights().into_iter().enumerate() {
                let (dx, dy, dz) = (corner >> 2, corner >> 1 & 1, corner & 1);
                let l = haar::local(o[0] + dx, o[1] + dy, o[2] + dz);
                for c in 0..3 {
                    out[c] += wt * values[c][l];
                }
            }
            out
        })
    }
}

/// Travel directions of `n` suns spread evenly over the sky (above the horizon, equal areas
/// on the hemisphere, a Fibonacci spiral): light travelling down.
pub fn sky_directions(n: usize) -> Vec<[f64; 3]> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = (i as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            [-r * phi.cos(), -y, -r * phi.sin()]
        })
        .collect()
}

/// Relit error of a compressed set against the original.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorReport {
    /// Root mean square difference over points, colours and combinations.
    pub rmse: f64,
    /// Largest absolute difference.
    pub max: f64,
    /// Mean of the original values (for scale).
    pub mean: f64,
    /// Lookups compared (points × combinations).
    pub lookups: usize,
}

/// Compares relit lookups of `compressed` with `original` at `points` random points whose
/// lower corner lies in `region` (site plus a uniform offset in the cell), for every
/// combination in `weights`. Deterministic for a given seed, whatever the thread count.
pub fn relit_error(
    original: &BasisSet,
    compressed: &CompressedBasis,
    region: &Region,
    weights: &[BasisWeights],
    points: usize,
    seed: u64,
) -> Result<ErrorReport, RelightError> {
    if region.dims != original.dims || compressed.dims != original.dims {
        return Err(RelightError::Mismatch(format!(
            "grids differ: original {}, compressed {}, region {}",
            original.dims, compressed.dims, region.dims
        )));
    }
    let sites = region.sites();
    if sites.is_empty() || points == 0 || weights.is_empty() {
        return Err(RelightError::Mismatch(
            "no points to compare: empty region, no points or no combinations".into(),
        ));
    }
    let projected: Vec<ProjectedWeights> = weights.iter().map(|w| compressed.project(w)).collect();
    const PER_CHUNK: usize = 1024;
    let chunks = points.div_ceil(PER_CHUNK);
    let parts: Vec<(f64, f64, f64, usize)> = (0..chunks)
        .into_par_iter()
        .map(|k| {
            let mut rng = sylva_core::SplitMix64::for_chunk(seed, k as u64);
            let (mut sq, mut max, mut sum, mut n) = (0.0f64, 0.0f64, 0.0f64, 0usize);
            for _ in k * PER_CHUNK..((k + 1) * PER_CHUNK).min(points) {
                let s = sites[(rng.next_u64() % sites.len() as u64) as usize];
                let (x, y, z) = original.dims.coords(s);
                let g = [x, y, z].map(|c| c as f32 + rng.next_f64() as f32);
                for (w, p) in weights.iter().zip(&projected) {
                    let a = original.sample(g, w);
                    let b = compressed.sample_grid(g, p);
                    for c in 0..3 {
                        let d = (a[c] - b[c]) as f64;
                        sq += d * d;
                        max = max.max(d.abs());
                        sum += a[c] as f64;
                    }
                    n += 1;
                }
            }
            (sq, max, sum, n)
        })
        .collect();
    let (mut sq, mut max, mut sum, mut n) = (0.0, 0.0f64, 0.0, 0);
    for (a, b, c, d) in parts {
        sq += a;
        max = max.max(b);
        sum += c;
        n += d;
    }
    Ok(ErrorReport {
        rmse: (sq / (3 * n) as f64).sqrt(),
        max,
        mean: sum / (3 * n) as f64,
        lookups: n,
    })
}

#[cfg(test)]
mod block_cache_tests {
    use super::*;

    /// Lookups read from blocks decoded on first use equal the footprint lookups of the two
    /// compressed sets (to rounding), on a grid whose sides are not whole blocks and with
    /// coefficients dropped; only the blocks read are decoded; a PCA set has no blocks.
    #[test]
    fn block_lookups_equal_footprint_lookups() {
        let dims = Dims::new(13, 8, 10).unwrap();
        let value = |ch: usize, s: usize| {
            let (x, y, z) = dims.coords(s);
            (0.7 * x as f32 + ch as f32).sin() + 0.05 * (y * z) as f32 + 1.5
        };
        let target = |codec| CompressTarget {
            precision: Precision::Packed,
            ..CompressTarget::new(codec)
        };
        let haar = target(Codec::ColourHaar { threshold: 0.004 });
        let region = Region::all(dims);
        let sun = compress_channels(dims, 6, &value, &[1.0; 6], &region, &haar).unwrap();
        let diffuse =
            compress_channels(dims, 3, &|c, s| value(c + 6, s), &[1.0; 3], &region, &haar).unwrap();
        let w = sun.project(&[(0, [0.5, 0.2, 1.0]), (1, [0.1, 0.0, 0.3])]);
        let v = diffuse.project(&[(0, [1.0, 0.5, 2.0])]);
        let count = sun
            .block_count_with(&diffuse)
            .expect("Haar sets have blocks");
        let cache = BlockCache::new(count, BlockBudget::new(u64::MAX));
        assert_eq!(cache.decoded(), 0);
        let mut r = sylva_core::SplitMix64::new(5);
        let mut worst = 0.0f32;
        // A corner of the grid first: few blocks.
        for k in 0..3000 {
            let span = if k < 100 {
                [2.0, 2.0, 2.0]
            } else {
                [13.0, 8.0, 10.0]
            };
            let g: [f32; 3] = std::array::from_fn(|a| r.next_f64() as f32 * span[a] - 0.5);
            let a = sun.sample_grid_with(&w, &diffuse, &v, g);
            let b = sun.sample_blocks_with(&w, &diffuse, &v, g, &cache);
            for c in 0..3 {
                worst = worst.max((a[c] - b[c]).abs() / (1.0 + a[c].abs()));
            }
            if k == 99 {
                assert!(
                    cache.decoded() <= 8,
                    "{} blocks for a corner",
                    cache.decoded()
                );
            }
        }
        assert!(worst < 1e-5, "block lookups differ by {worst}");
        assert!(cache.decoded() > 8 && cache.decoded() <= count);
        // Past its budget a cache keeps nothing more, and reads the same values.
        let budget = BlockBudget::new(0);
        let spent = BlockCache::new(count, budget.clone());
        let mut r = sylva_core::SplitMix64::new(5);
        for _ in 0..500 {
            let g: [f32; 3] = std::array::from_fn(|_| r.next_f64() as f32 * 12.0 - 0.5);
            let a = sun.sample_blocks_with(&w, &diffuse, &v, g, &cache);
            let b = sun.sample_blocks_with(&w, &diffuse, &v, g, &spent);
            assert_eq!(a, b, "the same value kept or not");
        }
        assert_eq!((spent.decoded(), budget.left()), (0, 0));
        let pca = CompressTarget::new(Codec::Pca { rank: 2 });
        let dense =
            compress_channels(dims, 3, &|c, s| value(c, s), &[1.0; 3], &region, &pca).unwrap();
        assert_eq!(sun.block_count_with(&dense), None);
    }
}
