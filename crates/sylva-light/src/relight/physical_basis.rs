//! The physical light's base solutions (issue 27, docs/relight.md "The physical light
//! relit"): per model its 28 parts ([`PhysicalBasis`], as solved), and compressed
//! ([`CompressedPhysicalBasis`]): its 25 sun parts as one set of 75 channels and its 3
//! diffuse parts as another of 9 ([`sylva_lb::relight::compress_channels`], today's codecs: Haar,
//! PCA, PCA + Haar, colour-decorrelated Haar), each set with its own codec
//! ([`PhysicalTarget`]): the sun parts are smooth and alike (neighbouring directions light a
//! crown alike), the diffuse parts differ from them and from each other.
//!
//! * **Units.** Each part is measured in units of its own mean over the sites where light
//!   matters ([`region_of`]): a Haar threshold is a fraction of that mean, and PCA weighs
//!   the parts alike.
//! * **Lookups.** An instance's terms (per part, per colour) are projected once per sun onto
//!   each set's fields ([`StoredPhysicalBasis::project`]); a lookup decodes only the
//!   trilinear footprint of the fields with non-zero weight ([`PhysicalTerms`]).
//! * **Cache.** The compressed basis is cached as one entry per model
//!   (`<model>-physical-<key>.spbasis`, sylva's checked container): the key hashes the 28
//!   parts' own cache keys (model, medium, sun direction, sky, ground, solver, neighbours'
//!   foliage) and both targets; the entry records the parts' solve seconds when they were
//!   solved in the run that wrote it. A damaged or stale entry is reported and made again.

use std::path::{Path, PathBuf};

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use sylva_core::cache::{Cache, CacheKey, CacheKind, Lookup, KEY_METADATA};
use sylva_core::container::{read_container, write_container, ByteReader, ByteWriter};
use sylva_geom::Model;
use sylva_lb::relight::{
    compress_channels, BlockCache, Codec, CompressTarget, CompressedChannels, Footprint, Placement,
    Precision, ProjectedWeights, Region,
};
use sylva_lb::{Bounds, DensityGrid, Dims};

use sylva_lb::LightingGrid;

use super::basis_cache::{region_of, SOLVE_SECONDS_METADATA};
use super::sun_parts::SUN_PARTS;
use crate::lighting::{LightingError, CACHE_VERSION};

/// Parts per model: the sun's, then `D_top`, `D_side`, `G`.
pub const PARTS: usize = SUN_PARTS + 3;

/// One model's physical light as its [`PARTS`] linear parts, per site and colour.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicalBasis {
    dims: Dims,
    bounds: Bounds,
    placement: Placement,
    /// Per site: the sun's parts ([`sun_directions`](super::sun_parts::sun_directions) order, a unit sun each), then a unit
    /// sky's through the top, through the sides, a unit ground's; RGB each.
    values: Vec<[[f32; 3]; PARTS]>,
}

/// A combination of a model's parts: `(part, weight per colour)`, zero terms left out.
pub type PartTerms = Vec<(usize, Vec3)>;

impl PhysicalBasis {
    /// From the sun's parts (one grid per [`sun_directions`](super::sun_parts::sun_directions) entry, a unit sun) and the
    /// diffuse ones as solved (`sky` through every face, `ground`, `skytop` through the top:
    /// `crate::lighting::PARTS` 1..3); all on one grid.
    pub fn new(
        sun: &[LightingGrid],
        sky: &LightingGrid,
        ground: &LightingGrid,
        skytop: &LightingGrid,
    ) -> Result<PhysicalBasis, LightingError> {
        if sun.len() != SUN_PARTS {
            return Err(LightingError::Illumination(format!(
                "{} sun parts, not {SUN_PARTS}",
                sun.len()
            )));
        }
        let side = sylva_lb::light::subtract(sky, skytop);
        let grids: Vec<&LightingGrid> = sun.iter().chain([skytop, &side, ground]).collect();
        let (dims, bounds) = (sky.dims, sky.bounds);
        if let Some(g) = grids.iter().find(|g| g.dims != dims || g.bounds != bounds) {
            return Err(LightingError::Illumination(format!(
                "a light part on a {} grid beside a {dims} grid",
                g.dims
            )));
        }
        let values = (0..dims.sites())
            .map(|i| std::array::from_fn(|k| std::array::from_fn(|c| grids[k].colours[c][i])))
            .collect();
        Ok(PhysicalBasis {
            dims,
            bounds,
            placement: Placement::new(dims, bounds),
            values,
        })
    }

    /// From every part's channels as decoded (`3 part + colour`, site order as in
    /// [`LightingGrid`]).
    pub fn from_channels(
        dims: Dims,
        bounds: Bounds,
        channels: &[Vec<f32>],
    ) -> Result<PhysicalBasis, LightingError> {
        if channels.len() != 3 * PARTS || channels.iter().any(|c| c.len() != dims.sites()) {
            return Err(LightingError::Illumination(format!(
                "{} channels for a physical basis of {} on a {dims} grid",
                channels.len(),
                3 * PARTS
            )));
        }
        let values = (0..dims.sites())
            .map(|i| std::array::from_fn(|k| std::array::from_fn(|c| channels[3 * k + c][i])))
            .collect();
        Ok(PhysicalBasis {
            dims,
            bounds,
            placement: Placement::new(dims, bounds),
            values,
        })
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    pub fn placement(&self) -> &Placement {
        &self.placement
    }

    /// Site `s`'s parts (this module's order), RGB each.
    #[inline]
    pub fn site(&self, s: usize) -> &[[f32; 3]; PARTS] {
        &self.values[s]
    }

    /// Every site's parts, in site order.
    pub fn sites(&self) -> &[[[f32; 3]; PARTS]] {
        &self.values
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        (self.values.len() * std::mem::size_of::<[[f32; 3]; PARTS]>()) as u64
    }

    /// Bytes a basis on `dims` holds.
    pub fn memory_needed(dims: Dims) -> u64 {
        dims.sites() as u64 * std::mem::size_of::<[[f32; 3]; PARTS]>() as u64
    }

    /// `Σ w ⊙ part` at model-space point `p` (trilinear, clamped to the grid).
    #[inline]
    pub fn sample(&self, p: Vec3, terms: &[(usize, Vec3)]) -> Vec3 {
        let fp = Footprint::at(self.dims, self.placement.grid_coords(p.to_array()));
        let (sites, wt) = (fp.sites(self.dims), fp.weights());
        let mut out = Vec3::ZERO;
        for k in 0..8 {
            out += combine_site(&self.values[sites[k]], terms) * wt[k];
        }
        out
    }
}

/// `Σ w ⊙ part` at one site: what a lookup weighs at each corner, and what a baked light
/// stores (the same rounding, so both read alike bit for bit).
#[inline]
fn combine_site(v: &[[f32; 3]; PARTS], terms: &[(usize, Vec3)]) -> Vec3 {
    let mut site = Vec3::ZERO;
    for &(part, w) in terms {
        site += Vec3::from_array(v[part]) * w;
    }
    site
}

/// One instance's light for the current sun at every site of its model's grid
/// ([`StoredPhysicalBasis::bake`]).
#[derive(Debug, Clone, PartialEq)]
pub struct BakedLight {
    dims: Dims,
    placement: Placement,
    values: Vec<[f32; 3]>,
}

impl BakedLight {
    /// Bytes a baked light on `dims` holds.
    pub fn memory_needed(dims: Dims) -> u64 {
        dims.sites() as u64 * std::mem::size_of::<[f32; 3]>() as u64
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        Self::memory_needed(self.dims)
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    /// RGB per site, in the grid's site order.
    pub fn values(&self) -> &[[f32; 3]] {
        &self.values
    }

    /// The light at model-space point `p` (trilinear, clamped to the grid).
    #[inline]
    pub fn sample(&self, p: Vec3) -> Vec3 {
        let fp = Footprint::at(self.dims, self.placement.grid_coords(p.to_array()));
        let (sites, wt) = (fp.sites(self.dims), fp.weights());
        let mut out = Vec3::ZERO;
        for k in 0..8 {
            out += Vec3::from_array(self.values[sites[k]]) * wt[k];
        }
        out
    }
}

/// Channels of the sun parts' set and of the diffuse parts' set.
const SUN_CHANNELS: usize = 3 * SUN_PARTS;
const DIFFUSE_CHANNELS: usize = 3 * (PARTS - SUN_PARTS);

/// How a model's physical parts are compressed: the sun parts as one set, the diffuse parts
/// as another.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhysicalTarget {
    pub sun: CompressTarget,
    pub diffuse: CompressTarget,
}

impl PhysicalTarget {
    /// The recommended targets (docs/PERFORMANCE.md, "The physical light relit"): the
    /// colours decorrelated per part and Haar wavelets at threshold 0.004, packed.
    pub fn recommended() -> PhysicalTarget {
        let t = CompressTarget {
            precision: Precision::Packed,
            ..CompressTarget::new(Codec::ColourHaar { threshold: 0.004 })
        };
        PhysicalTarget { sun: t, diffuse: t }
    }

    /// `--codec`: one codec for both sets (`colour:0.004`), or the sun parts' and the
    /// diffuse parts' separated by a comma (`pcahaar:12:0.002,colour:0.004`); `none` keeps
    /// the parts uncompressed (`None`). Each with `precision`; the targets are checked.
    pub fn parse(codec: &str, precision: Precision) -> Result<Option<PhysicalTarget>, String> {
        if codec == "none" {
            return Ok(None);
        }
        let target = |s: &str, channels: usize| -> Result<CompressTarget, String> {
            let t = CompressTarget {
                precision,
                ..CompressTarget::new(Codec::parse(s)?)
            };
            t.validate_for(channels).map_err(|e| e.to_string())?;
            Ok(t)
        };
        let (sun, diffuse) = match codec.split_once(',') {
            Some((a, b)) => (a, b),
            None => (codec, codec),
        };
        Ok(Some(PhysicalTarget {
            sun: target(sun, SUN_CHANNELS)?,
            diffuse: target(diffuse, DIFFUSE_CHANNELS)?,
        }))
    }

    /// The form [`PhysicalTarget::parse`] reads (without the precision).
    pub fn name(&self) -> String {
        let (a, b) = (self.sun.codec.name(), self.diffuse.codec.name());
        if a == b {
            a
        } else {
            format!("{a},{b}")
        }
    }
}

/// A model's physical parts compressed ([`CompressedPhysicalBasis::compress`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedPhysicalBasis {
    dims: Dims,
    bounds: Bounds,
    placement: Placement,
    sun: CompressedChannels,
    diffuse: CompressedChannels,
}

/// Each part's scale: its mean over `region` (all colours), 1 where that is not positive
/// (a part that is zero there, such as the ground's without a ground).
fn part_scales(basis: &PhysicalBasis, region: &Region) -> [f64; PARTS] {
    let sites = region.sites();
    std::array::from_fn(|part| {
        let sum: f64 = sites
            .iter()
            .map(|&s| basis.site(s)[part].iter().map(|&v| v as f64).sum::<f64>())
            .sum();
        let mean = sum / (3 * sites.len().max(1)) as f64;
        if mean.is_finite() && mean > 0.0 {
            mean
        } else {
            1.0
        }
    })
}

impl CompressedPhysicalBasis {
    /// Compresses `basis` to `target`, spending the bits where `density`'s light matters
    /// ([`region_of`]; `density` on the basis's grid).
    pub fn compress(
        basis: &PhysicalBasis,
        density: &DensityGrid,
        target: &PhysicalTarget,
    ) -> Result<CompressedPhysicalBasis, LightingError> {
        let dims = basis.dims();
        if density.dims != dims {
            return Err(LightingError::Illumination(format!(
                "compressing a physical basis on a {dims} grid with a {} density",
                density.dims
            )));
        }
        let region = region_of(density);
        let scales = part_scales(basis, &region);
        let set = |first: usize, channels: usize, target: &CompressTarget| {
            let per_channel: Vec<f64> = (0..channels).map(|c| scales[first + c / 3]).collect();
            compress_channels(
                dims,
                channels,
                &|c, s| basis.site(s)[first + c / 3][c % 3],
                &per_channel,
                &region,
                target,
            )
        };
        Ok(CompressedPhysicalBasis {
            dims,
            bounds: basis.bounds(),
            placement: *basis.placement(),
            sun: set(0, SUN_CHANNELS, &target.sun)?,
            diffuse: set(SUN_PARTS, DIFFUSE_CHANNELS, &target.diffuse)?,
        })
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    pub fn bounds(&self) -> Bounds {
        self.bounds
    }

    /// What the sets were compressed to.
    pub fn target(&self) -> PhysicalTarget {
        PhysicalTarget {
            sun: self.sun.target,
            diffuse: self.diffuse.target,
        }
    }

    /// Bytes held (both sets' fields, their indices and maps).
    pub fn bytes(&self) -> u64 {
        self.sun.bytes() + self.diffuse.bytes()
    }

    /// Bytes of the sun parts' set and of the diffuse parts' set.
    pub fn set_bytes(&self) -> (u64, u64) {
        (self.sun.bytes(), self.diffuse.bytes())
    }

    /// `terms` (parts in [`PhysicalBasis`]'s order, per-colour weights) projected onto the
    /// two sets' fields.
    pub fn project(&self, terms: &[(usize, Vec3)]) -> (ProjectedWeights, ProjectedWeights) {
        let split = |sun: bool| -> Vec<(usize, [f32; 3])> {
            terms
                .iter()
                .filter(|(p, _)| (*p < SUN_PARTS) == sun)
                .map(|&(p, w)| (if sun { p } else { p - SUN_PARTS }, w.to_array()))
                .collect()
        };
        (
            self.sun.project(&split(true)),
            self.diffuse.project(&split(false)),
        )
    }

    /// Decodes every part at every site.
    pub fn decompress(&self) -> Result<PhysicalBasis, LightingError> {
        let sun = self.sun.decompress()?;
        let diffuse = self.diffuse.decompress()?;
        let channels: Vec<Vec<f32>> = sun.into_iter().chain(diffuse).collect();
        PhysicalBasis::from_channels(self.dims, self.bounds, &channels)
    }

    /// The basis as bytes (grid, bounds, both sets), for the cache or another process:
    /// [`CompressedPhysicalBasis::from_bytes`] gives back this basis exactly.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        for n in [self.dims.nx, self.dims.ny, self.dims.nz] {
            w.u32(n as u32);
        }
        for v in self.bounds.min.iter().chain(&self.bounds.max) {
            w.f32(*v);
        }
        w.u8s(&self.sun.to_bytes());
        w.u8s(&self.diffuse.to_bytes());
        w.bytes
    }

    /// The basis [`CompressedPhysicalBasis::to_bytes`] encoded; inconsistent bytes are
    /// refused, the error saying what.
    pub fn from_bytes(bytes: &[u8]) -> Result<CompressedPhysicalBasis, String> {
        let mut r = ByteReader::new(bytes);
        let mut n = [0usize; 3];
        for v in &mut n {
            *v = r.u32("grid size")? as usize;
        }
        let dims = Dims::new(n[0], n[1], n[2]).map_err(|e| e.to_string())?;
        let mut b = [0f32; 6];
        for v in &mut b {
            *v = r.f32("bounds")?;
        }
        if b.iter().any(|v| !v.is_finite()) || (0..3).any(|a| b[a] > b[a + 3]) {
            return Err(format!("bounds {b:?} are not a finite box"));
        }
        let bounds = Bounds {
            min: [b[0], b[1], b[2]],
            max: [b[3], b[4], b[5]],
        };
        let set = |r: &mut ByteReader, what: &str, channels: usize| {
            let set = CompressedChannels::from_bytes(&r.u8s(what)?).map_err(|e| e.to_string())?;
            if set.dims != dims || set.channels() != channels {
                return Err(format!(
                    "{what}: {} channels on a {} grid, expected {channels} on {dims}",
                    set.channels(),
                    set.dims
                ));
            }
            Ok(set)
        };
        let sun = set(&mut r, "the sun parts", SUN_CHANNELS)?;
        let diffuse = set(&mut r, "the diffuse parts", DIFFUSE_CHANNELS)?;
        r.finish()?;
        Ok(CompressedPhysicalBasis {
            dims,
            bounds,
            placement: Placement::new(dims, bounds),
            sun,
            diffuse,
        })
    }
}

/// A model's physical parts as the light reads them: as solved, or compressed.
#[derive(Debug, Clone, PartialEq)]
pub enum StoredPhysicalBasis {
    Full(PhysicalBasis),
    Compressed(Box<CompressedPhysicalBasis>),
}

/// An instance's combination of its model's parts, ready for lookups
/// ([`StoredPhysicalBasis::project`]).
#[derive(Debug, Clone, PartialEq)]
pub enum PhysicalTerms {
    Full(PartTerms),
    /// Projected onto the sun parts' fields and the diffuse parts'.
    Compressed(ProjectedWeights, ProjectedWeights),
}

impl Default for PhysicalTerms {
    fn default() -> Self {
        PhysicalTerms::Full(Vec::new())
    }
}

impl StoredPhysicalBasis {
    pub fn dims(&self) -> Dims {
        match self {
            StoredPhysicalBasis::Full(b) => b.dims(),
            StoredPhysicalBasis::Compressed(c) => c.dims,
        }
    }

    pub fn placement(&self) -> &Placement {
        match self {
            StoredPhysicalBasis::Full(b) => b.placement(),
            StoredPhysicalBasis::Compressed(c) => &c.placement,
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        match self {
            StoredPhysicalBasis::Full(b) => b.bytes(),
            StoredPhysicalBasis::Compressed(c) => c.bytes(),
        }
    }

    /// `terms` made ready for [`StoredPhysicalBasis::sample`] on this basis.
    pub fn project(&self, terms: &PartTerms) -> PhysicalTerms {
        match self {
            StoredPhysicalBasis::Full(_) => PhysicalTerms::Full(terms.clone()),
            StoredPhysicalBasis::Compressed(c) => {
                let (sun, diffuse) = c.project(terms);
                PhysicalTerms::Compressed(sun, diffuse)
            }
        }
    }

    /// The combination `terms` (from this basis's [`StoredPhysicalBasis::project`]) at
    /// model-space point `p` (trilinear, clamped to the grid).
    #[inline]
    pub fn sample(&self, p: Vec3, terms: &PhysicalTerms) -> Vec3 {
        match (self, terms) {
            (StoredPhysicalBasis::Full(b), PhysicalTerms::Full(t)) => b.sample(p, t),
            (StoredPhysicalBasis::Compressed(c), PhysicalTerms::Compressed(sun, diffuse)) => {
                let g = c.placement.grid_coords(p.to_array());
                Vec3::from_array(c.sun.sample_grid_with(sun, &c.diffuse, diffuse, g))
            }
            _ => panic!("terms projected for another kind of physical basis"),
        }
    }

    /// Blocks a [`BlockCache`] of this basis holds: `Some` for a compressed basis whose two
    /// sets are Haar sets (the default codecs), whose lookups can read decoded blocks.
    pub fn block_count(&self) -> Option<usize> {
        match self {
            StoredPhysicalBasis::Compressed(c) => c.sun.block_count_with(&c.diffuse),
            StoredPhysicalBasis::Full(_) => None,
        }
    }

    /// [`StoredPhysicalBasis::sample`] read from `cache`, which holds this basis's blocks for
    /// `terms` alone, each decoded on its first lookup: the same light up to rounding, for a
    /// frame that reads too few sites to decode them all ([`StoredPhysicalBasis::bake`]).
    #[inline]
    pub fn sample_blocks(&self, p: Vec3, terms: &PhysicalTerms, cache: &BlockCache) -> Vec3 {
        match (self, terms) {
            (StoredPhysicalBasis::Compressed(c), PhysicalTerms::Compressed(sun, diffuse)) => {
                let g = c.placement.grid_coords(p.to_array());
                Vec3::from_array(c.sun.sample_blocks_with(sun, &c.diffuse, diffuse, g, cache))
            }
            _ => self.sample(p, terms),
        }
    }

    /// The combination `terms` (from this basis's [`StoredPhysicalBasis::project`]) at every
    /// site: one sun's light for an instance, read by the frames that follow at 3 values per
    /// lookup. From the full parts its lookups equal [`StoredPhysicalBasis::sample`]'s bit
    /// for bit; from compressed ones they equal them at the sites and wherever the footprint
    /// lies in one Haar block (across a block's seam they read the next block's own sites).
    pub fn bake(&self, terms: &PhysicalTerms) -> Result<BakedLight, LightingError> {
        let dims = self.dims();
        sylva_core::check_memory(
            &format!("the relit light decoded for one sun on a {dims} grid"),
            BakedLight::memory_needed(dims),
        )
        .map_err(|e| LightingError::Illumination(e.to_string()))?;
        let values = match (self, terms) {
            (StoredPhysicalBasis::Full(b), PhysicalTerms::Full(t)) => b
                .values
                .par_iter()
                .map(|v| combine_site(v, t).to_array())
                .collect(),
            (StoredPhysicalBasis::Compressed(c), PhysicalTerms::Compressed(sun, diffuse)) => {
                let mut out = vec![[0.0f32; 3]; dims.sites()];
                c.sun.decode_combined_into(sun, &mut out);
                c.diffuse.decode_combined_into(diffuse, &mut out);
                out
            }
            _ => {
                return Err(LightingError::Illumination(
                    "terms projected for another kind of physical basis".into(),
                ))
            }
        };
        Ok(BakedLight {
            dims,
            placement: *self.placement(),
            values,
        })
    }

    /// Every part at every site (a compressed basis decoded).
    pub fn to_full(&self) -> Result<std::borrow::Cow<'_, PhysicalBasis>, LightingError> {
        Ok(match self {
            StoredPhysicalBasis::Full(b) => std::borrow::Cow::Borrowed(b),
            StoredPhysicalBasis::Compressed(c) => std::borrow::Cow::Owned(c.decompress()?),
        })
    }
}

/// A model's compressed physical basis ([`compressed_physical_key`]).
pub const PHYSICAL_COMPRESSED: CacheKind = CacheKind {
    name: "compressed physical basis",
    version: CACHE_VERSION,
};
/// Extension of compressed physical basis cache entries.
pub const PHYSICAL_EXTENSION: &str = "spbasis";
const MAGIC: &[u8; 8] = b"SYLVAPBS";
const VERSION: u32 = 1;
const WHAT: &str = "compressed physical basis file";

/// One set's target in a cache key.
#[derive(Debug, Clone, PartialEq, Serialize)]
struct TargetKey {
    codec: String,
    precision: &'static str,
    far_threshold: f64,
}

impl TargetKey {
    fn new(t: &CompressTarget) -> TargetKey {
        TargetKey {
            codec: t.codec.name(),
            precision: t.precision.name(),
            far_threshold: t.far_threshold,
        }
    }
}

/// Everything a compressed physical basis depends on: its 28 parts (their own cache keys)
/// and both targets, the region and units compression uses.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct CompressedPhysicalKey {
    parts: [u64; PARTS],
    sun: TargetKey,
    diffuse: TargetKey,
    region: &'static str,
    units: &'static str,
}

/// The cache key of the compressed basis of the parts keyed `parts` (in
/// [`PhysicalBasis`]'s order) compressed to `target`.
pub fn compressed_physical_key(parts: &[CacheKey; PARTS], target: &PhysicalTarget) -> CacheKey {
    CacheKey::new(
        PHYSICAL_COMPRESSED,
        &CompressedPhysicalKey {
            parts: parts.map(CacheKey::value),
            sun: TargetKey::new(&target.sun),
            diffuse: TargetKey::new(&target.diffuse),
            region: "near_medium(1).with_floor(2)",
            units: "part mean over the region",
        },
    )
}

/// The cache entry of `model`'s compressed physical basis under `key`.
pub fn physical_path(cache: &Cache, model: &Model, key: CacheKey) -> PathBuf {
    let stem = sylva_core::file_stem(&model.name, "model");
    cache.entry(&format!("{stem}-physical"), key, PHYSICAL_EXTENSION)
}

/// A compressed physical basis read from the cache, and the parts' solve seconds its entry
/// recorded.
pub type CachedPhysical = (CompressedPhysicalBasis, Option<f64>);

/// Reads the entry at `path`: it must hold `key` and a basis on `dims` over `bounds`; `Err`
/// is why it is unusable, naming the file.
fn read_physical(
    path: &Path,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
) -> Result<CachedPhysical, String> {
    let c = read_container(path, MAGIC, VERSION, WHAT).map_err(|e| e.to_string())?;
    key.check(path, c.metadata_value(KEY_METADATA))?;
    let basis = CompressedPhysicalBasis::from_bytes(&c.payload)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    if basis.dims != dims || basis.bounds != bounds {
        return Err(format!(
            "{} holds a {} grid over {:?}..{:?}, the model needs {dims} over {:?}..{:?}",
            path.display(),
            basis.dims,
            basis.bounds.min,
            basis.bounds.max,
            bounds.min,
            bounds.max
        ));
    }
    let seconds = c
        .metadata_value(SOLVE_SECONDS_METADATA)
        .and_then(|v| v.parse().ok());
    Ok((basis, seconds))
}

/// `model`'s compressed physical basis under `key` from the cache in `dir`, on `dims` over
/// `bounds`: a hit, a miss, or a bad entry (why, naming the file).
pub fn lookup_physical(
    dir: &Path,
    model: &Model,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
) -> Lookup<CachedPhysical> {
    let cache = Cache::new(dir);
    let path = physical_path(&cache, model, key);
    cache.lookup(&path, |p| read_physical(p, key, dims, bounds))
}

/// Stores `basis` as `model`'s entry under `key` in the cache in `dir` (atomically), with
/// the parts' solve seconds when known; a warning naming the file when it cannot.
pub fn store_physical(
    dir: &Path,
    model: &Model,
    key: CacheKey,
    basis: &CompressedPhysicalBasis,
    solve_seconds: Option<f64>,
) -> Option<String> {
    let cache = Cache::new(dir);
    let path = physical_path(&cache, model, key);
    let mut metadata = vec![
        ("format".to_string(), WHAT.to_string()),
        key.metadata(),
        ("source".to_string(), model.name.clone()),
        ("codec".to_string(), basis.target().name()),
        (
            "precision".to_string(),
            format!(
                "{},{}",
                basis.sun.target.precision.name(),
                basis.diffuse.target.precision.name()
            ),
        ),
    ];
    if let Some(s) = solve_seconds {
        metadata.push((SOLVE_SECONDS_METADATA.to_string(), s.to_string()));
    }
    cache.store(&path, |p| {
        write_container(p, MAGIC, VERSION, &metadata, &basis.to_bytes()).map_err(|e| e.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic basis on a 14×11×13 grid (a crown's light: smooth in space, each part
    /// its own pattern and level, the colours a little apart, a little noise) and its medium
    /// (a ball in the middle).
    fn synthetic() -> (PhysicalBasis, DensityGrid) {
        let dims = Dims::new(14, 11, 13).unwrap();
        let bounds = Bounds {
            min: [-1.0, 0.0, -1.0],
            max: [1.0, 2.0, 1.0],
        };
        let mut rng = sylva_core::SplitMix64::new(11);
        let channels: Vec<Vec<f32>> = (0..3 * PARTS)
            .map(|ch| {
                let (part, colour) = ((ch / 3) as f32, (ch % 3) as f32);
                (0..dims.sites())
                    .map(|s| {
                        let (x, y, z) = dims.coords(s);
                        let (x, y, z) = (x as f32 / 13.0, y as f32 / 10.0, z as f32 / 12.0);
                        let smooth = (1.0 + part * 0.3)
                            * (0.5 + 0.4 * (3.0 * x + part).sin() * (2.0 * z).cos())
                            * (0.6 + 0.4 * y);
                        smooth * (1.0 - 0.05 * colour) + 0.01 * rng.next_f64() as f32
                    })
                    .collect()
            })
            .collect();
        let basis = PhysicalBasis::from_channels(dims, bounds, &channels).unwrap();
        let mut density = DensityGrid::empty(dims);
        for s in 0..dims.sites() {
            let (x, y, z) = dims.coords(s);
            let d = [x as f32 - 6.5, y as f32 - 5.0, z as f32 - 6.0];
            if d.iter().map(|v| v * v).sum::<f32>() < 16.0 {
                density.density[s] = 0.5;
            }
        }
        (basis, density)
    }

    fn target(codec: Codec, precision: Precision, far_threshold: f64) -> CompressTarget {
        CompressTarget {
            codec,
            precision,
            far_threshold,
        }
    }

    /// Instance terms like the light's: three sun parts and the diffuse ones, per colour.
    fn terms() -> Vec<PartTerms> {
        vec![
            vec![
                (0, Vec3::new(0.5, 0.45, 0.4)),
                (4, Vec3::new(0.2, 0.2, 0.18)),
                (7, Vec3::new(0.1, 0.1, 0.09)),
                (SUN_PARTS, Vec3::splat(0.3)),
                (SUN_PARTS + 1, Vec3::splat(0.2)),
                (SUN_PARTS + 2, Vec3::new(0.05, 0.04, 0.02)),
            ],
            vec![(12, Vec3::ONE), (SUN_PARTS + 2, Vec3::splat(0.5))],
        ]
    }

    /// A baked light reads what the lookups it replaces read: from the full parts bit for
    /// bit everywhere; from compressed ones (the recommended target, Haar blocks) the same
    /// at every site, and between sites within the compression's own error of the parts.
    #[test]
    fn baked_light_reads_as_the_lookups_it_replaces() {
        let (basis, density) = synthetic();
        let c = CompressedPhysicalBasis::compress(&basis, &density, &PhysicalTarget::recommended())
            .unwrap();
        let (full, small) = (
            StoredPhysicalBasis::Full(basis.clone()),
            StoredPhysicalBasis::Compressed(Box::new(c)),
        );
        let dims = basis.dims();
        let mut rng = sylva_core::SplitMix64::new(8);
        for t in terms() {
            let (ft, st) = (full.project(&t), small.project(&t));
            let (fb, sb) = (full.bake(&ft).unwrap(), small.bake(&st).unwrap());
            assert_eq!(fb.bytes(), BakedLight::memory_needed(dims));
            for _ in 0..600 {
                let p = Vec3::new(
                    rng.next_f64() as f32 * 2.4 - 1.2,
                    rng.next_f64() as f32 * 2.4 - 0.2,
                    rng.next_f64() as f32 * 2.4 - 1.2,
                );
                assert_eq!(fb.sample(p), full.sample(p, &ft), "full parts at {p}");
                // Compressed: where light matters (in and next to the ball: the region the
                // codec spends its bits on), as a leaf reads it.
                let p = Vec3::new(0.0, 0.77, -0.08) + (p - Vec3::new(0.0, 1.0, 0.0)) * 0.4;
                let (baked, looked_up, exact) = (sb.sample(p), small.sample(p, &st), fb.sample(p));
                let scale = exact.max_element();
                assert!(
                    (baked - exact).abs().max_element() < 0.05 * scale,
                    "{p}: baked {baked} against the parts' {exact}"
                );
                assert!(
                    (baked - looked_up).abs().max_element() < 0.05 * scale,
                    "{p}: baked {baked} against the lookup's {looked_up}"
                );
            }
            for s in (0..dims.sites()).step_by(7) {
                let (x, y, z) = dims.coords(s);
                if x + 1 == dims.nx || y + 1 == dims.ny || z + 1 == dims.nz {
                    continue;
                }
                // Just past the site, so the footprint's lower corner is the site itself
                // whatever the rounding of model space.
                let g = [x as f32 + 1e-4, y as f32 + 1e-4, z as f32 + 1e-4];
                let p = Vec3::from_array(basis.placement().model_point(g));
                let (baked, looked_up) = (sb.sample(p), small.sample(p, &st));
                assert!(
                    (baked - looked_up).abs().max_element()
                        < 1e-4 * looked_up.max_element().max(1.0),
                    "site {s}: baked {baked}, looked up {looked_up}"
                );
            }
        }
    }

    #[test]
    fn lossless_targets_give_back_the_parts_and_their_lookups() {
        let (basis, density) = synthetic();
        let full = StoredPhysicalBasis::Full(basis.clone());
        let mut rng = sylva_core::SplitMix64::new(3);
        let points: Vec<Vec3> = (0..200)
            .map(|_| {
                Vec3::new(
                    rng.next_f64() as f32 * 2.0 - 1.0,
                    rng.next_f64() as f32 * 2.0,
                    0.3,
                )
            })
            .collect();
        for (sun, diffuse) in [
            (
                Codec::Haar { threshold: 0.0 },
                Codec::Haar { threshold: 0.0 },
            ),
            (Codec::Pca { rank: SUN_CHANNELS }, Codec::Pca { rank: 9 }),
            (
                Codec::PcaHaar {
                    rank: SUN_CHANNELS,
                    threshold: 0.0,
                },
                Codec::ColourHaar { threshold: 0.0 },
            ),
        ] {
            let t = PhysicalTarget {
                sun: target(sun, Precision::F32, 0.0),
                diffuse: target(diffuse, Precision::F32, 0.0),
            };
            let c = CompressedPhysicalBasis::compress(&basis, &density, &t).unwrap();
            assert_eq!(c.target(), t);
            let back = c.decompress().unwrap();
            for s in 0..basis.dims().sites() {
                for (a, b) in back.site(s).iter().zip(basis.site(s)) {
                    for k in 0..3 {
                        assert!((a[k] - b[k]).abs() < 2e-5 * (1.0 + b[k].abs()), "{t:?} {s}");
                    }
                }
            }
            let stored = StoredPhysicalBasis::Compressed(Box::new(c));
            for terms in terms() {
                let (pc, pf) = (stored.project(&terms), full.project(&terms));
                for &p in &points {
                    let (a, b) = (stored.sample(p, &pc), full.sample(p, &pf));
                    assert!((a - b).abs().max_element() < 1e-4 * (1.0 + b.max_element()));
                }
            }
        }
    }

    #[test]
    fn haar_error_stays_within_its_threshold_and_grows_with_it() {
        let (basis, density) = synthetic();
        let scales = part_scales(&basis, &region_of(&density));
        let n = basis.dims().sites();
        let mut last = (0.0, u64::MAX);
        for threshold in [0.002, 0.01, 0.05] {
            // Every block judged by the threshold (no far blocks), f32 values: each dropped
            // coefficient adds at most `threshold × scale` RMS over its block's 64 values,
            // and the Haar functions are orthogonal, so a channel's RMS error over the sites
            // (each from the block owning it, 27 of the 64) is at most
            // 8 · √(64/27) · threshold · scale.
            let t = target(Codec::Haar { threshold }, Precision::F32, threshold);
            let c = CompressedPhysicalBasis::compress(
                &basis,
                &density,
                &PhysicalTarget { sun: t, diffuse: t },
            )
            .unwrap();
            let back = c.decompress().unwrap();
            let mut worst = 0.0f64;
            for ch in 0..3 * PARTS {
                let (part, colour) = (ch / 3, ch % 3);
                let sq: f64 = (0..n)
                    .map(|s| (back.site(s)[part][colour] - basis.site(s)[part][colour]) as f64)
                    .map(|d| d * d)
                    .sum();
                let rms = (sq / n as f64).sqrt();
                let bound = 8.0 * (64.0f64 / 27.0).sqrt() * threshold * scales[part];
                assert!(
                    rms <= bound,
                    "threshold {threshold} channel {ch}: {rms} > {bound}"
                );
                worst = worst.max(rms / scales[part]);
            }
            assert!(worst > 0.0, "threshold {threshold} dropped nothing");
            assert!(
                worst > last.0 && c.bytes() < last.1,
                "{threshold}: {worst} {}",
                c.bytes()
            );
            last = (worst, c.bytes());
        }
    }

    #[test]
    fn compressed_bases_round_trip_through_bytes_and_the_cache() {
        let (basis, density) = synthetic();
        let c = CompressedPhysicalBasis::compress(&basis, &density, &PhysicalTarget::recommended())
            .unwrap();
        assert!(
            c.bytes() < basis.bytes(),
            "{} vs {}",
            c.bytes(),
            basis.bytes()
        );
        let bytes = c.to_bytes();
        assert_eq!(CompressedPhysicalBasis::from_bytes(&bytes).unwrap(), c);
        for cut in [0, 10, bytes.len() / 2, bytes.len() - 1] {
            assert!(CompressedPhysicalBasis::from_bytes(&bytes[..cut]).is_err());
        }
        assert!(CompressedPhysicalBasis::from_bytes(&[bytes.as_slice(), &[0]].concat()).is_err());

        let dir = tempfile::tempdir().unwrap();
        let model = Model::new("crown", sylva_geom::Mesh::default(), Vec::new());
        let key = CacheKey::new(PHYSICAL_COMPRESSED, &1u32);
        let (dims, bounds) = (c.dims(), c.bounds());
        assert!(matches!(
            lookup_physical(dir.path(), &model, key, dims, bounds),
            Lookup::Miss
        ));
        assert_eq!(
            store_physical(dir.path(), &model, key, &c, Some(12.5)),
            None
        );
        match lookup_physical(dir.path(), &model, key, dims, bounds) {
            Lookup::Hit((back, seconds)) => {
                assert_eq!(back, c);
                assert_eq!(seconds, Some(12.5));
            }
            other => panic!("{other:?}"),
        }
        // Another grid, or a damaged file: a bad entry naming the file.
        let other = Dims::new(3, 3, 3).unwrap();
        let Lookup::Bad(why) = lookup_physical(dir.path(), &model, key, other, bounds) else {
            panic!("another grid read as good");
        };
        assert!(why.contains("spbasis") && why.contains("3×3×3"), "{why}");
        let path = physical_path(&Cache::new(dir.path()), &model, key);
        let mut file = std::fs::read(&path).unwrap();
        let at = file.len() - 5;
        file[at] ^= 1;
        std::fs::write(&path, &file).unwrap();
        let Lookup::Bad(why) = lookup_physical(dir.path(), &model, key, dims, bounds) else {
            panic!("a damaged entry read as good");
        };
        assert!(why.contains("spbasis"), "{why}");
    }

    #[test]
    fn each_field_changes_the_key() {
        let t = TargetKey::new(&PhysicalTarget::recommended().sun);
        let base = CompressedPhysicalKey {
            parts: [1; PARTS],
            sun: t.clone(),
            diffuse: t.clone(),
            region: "r",
            units: "u",
        };
        let other = TargetKey {
            codec: "haar:0.01".into(),
            ..t.clone()
        };
        let mut parts = [1; PARTS];
        parts[PARTS - 1] = 2;
        sylva_core::cache::assert_each_field_changes_the_key(
            PHYSICAL_COMPRESSED,
            &base,
            &[
                (
                    "parts",
                    CompressedPhysicalKey {
                        parts,
                        ..base.clone()
                    },
                ),
                (
                    "sun",
                    CompressedPhysicalKey {
                        sun: other.clone(),
                        ..base.clone()
                    },
                ),
                (
                    "diffuse",
                    CompressedPhysicalKey {
                        diffuse: other,
                        ..base.clone()
                    },
                ),
                (
                    "region",
                    CompressedPhysicalKey {
                        region: "s",
                        ..base.clone()
                    },
                ),
                (
                    "units",
                    CompressedPhysicalKey {
                        units: "v",
                        ..base.clone()
                    },
                ),
            ],
        );
    }

    #[test]
    fn targets_parse_one_codec_or_two() {
        let p = Precision::Packed;
        let one = PhysicalTarget::parse("colour:0.004", p).unwrap().unwrap();
        assert_eq!(one, PhysicalTarget::recommended());
        assert_eq!(one.name(), "colour:0.004");
        let two = PhysicalTarget::parse("pcahaar:12:0.002,haar:0.01", Precision::F16)
            .unwrap()
            .unwrap();
        assert_eq!(two.name(), "pcahaar:12:0.002,haar:0.01");
        assert_eq!(two.diffuse.precision, Precision::F16);
        assert_eq!(PhysicalTarget::parse("none", p).unwrap(), None);
        // The sun parts have 75 channels, the diffuse ones 9: a rank above is refused.
        assert!(PhysicalTarget::parse("pca:76,haar:0.01", Precision::F16).is_err());
        let e = PhysicalTarget::parse("pca:12", Precision::F16).unwrap_err();
        assert!(e.contains("1..=9"), "{e}");
        assert!(PhysicalTarget::parse("zip", p).is_err());
    }
}
