//! The physical light relit (issue 27, docs/relight.md): the default light moved with the
//! sun, no LB solve per sun.
//!
//! A model's physical light is linear in its sources (docs/light.md, "Forests"): the sun's
//! part `S` (its first collisions and the sunlit floor), a unit sky's through the top face
//! `D_top` and through the sides `D_side`, a unit ground's `G`. Only `S` depends on the sun's
//! direction. Per model, [`PhysicalBasis`] holds `S_j` for a unit sun travelling along each
//! of [`SUN_PARTS`] directions ([`sun_directions`]: the 13 lattice directions with `c_y ≤ 0`
//! and two rings between their elevations, [`super::sun_parts`]) beside the three diffuse
//! parts: 28 parts, solved once.
//!
//! Per instance and sun, the sun's direction in the instance's model space (its rotation
//! included) picks the face of the parts' triangulated hull it crosses, and its barycentric
//! weights weigh the face's three `S_j` (as 004 §3.1 weighs its polyhedron's); times the
//! sun's irradiance and the forest's transmittance `τ`; the diffuse parts take the forest
//! grid's weights ([`crate::forest::ForestBases`], relit the same way) or, for a lone model,
//! the sky's radiance and the open ground's. At a part's direction this is the direct solve
//! up to rounding (tested); between them the sun's first-collision pattern is interpolated,
//! the error docs/relight.md measures.
//!
//! The exact weights of the paper light (`max(0, n_j · d)`) are not used: they are exact for
//! a boundary sun, while the physical sun enters as its first collisions along the exact
//! direction, which no lattice direction's solve holds.

use std::collections::HashMap;
use std::sync::OnceLock;

use glam::{Affine3A, Vec3};
use sylva_geom::{Aabb, Model};
use sylva_lb::relight::{BlockBudget, BlockCache, Placement};
use sylva_lb::LightingGrid;
use sylva_trace::TraceInstance;

pub use super::physical_basis::{
    BakedLight, CompressedPhysicalBasis, PartTerms, PhysicalBasis, PhysicalTarget, PhysicalTerms,
    StoredPhysicalBasis, PARTS,
};
pub use super::sun_parts::{
    lattice_direction, overhead_part, sun_directions, sun_part_weights, LATTICE_SUN_DIRECTIONS,
    SUN_PARTS,
};
use crate::device::{
    DeviceKind, DeviceLight, NoDevice, PackedLight, Packer, SunWords, LIGHT_HEADER, NONE,
    RELIT_ENTRY, RELIT_TERM,
};
use crate::forest::{free_weights, ForestBases};
use crate::indirect::{ground_shade, GroundIndex, IndirectLight, ModelGridLight};
use crate::lighting::{
    open_field, physical_environment, physical_ground_sky, Illumination, LightingError,
    ModelLighting, OpenField, PartWeights,
};

/// The illumination sun part `part` is solved under: a unit sun travelling along its
/// direction ([`sun_directions`]), `scene`'s sky and ground (the floor's albedo).
pub fn sun_part_illumination(scene: &Illumination, part: usize) -> Illumination {
    let d = sun_directions()[part];
    Illumination {
        sun_to: -Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32),
        sun: Vec3::ONE,
        ..*scene
    }
}

/// An instance's combination of its model's parts: the sun's parts of the face its
/// direction (`travel`, in the model's space) crosses, times the sun's `irradiance` and the
/// forest's `w.sun`; the diffuse parts by `w`'s sky and ground weights.
pub fn instance_terms(
    travel: [f64; 3],
    irradiance: Vec3,
    w: &PartWeights,
) -> Result<PartTerms, LightingError> {
    let mut terms: PartTerms = sun_part_weights(travel)?
        .into_iter()
        .map(|(part, b)| (part, w.sun * irradiance * b as f32))
        .collect();
    terms.extend([
        (SUN_PARTS, w.sky_top),
        (SUN_PARTS + 1, w.sky),
        (SUN_PARTS + 2, w.ground),
    ]);
    terms.retain(|(_, w)| *w != Vec3::ZERO);
    Ok(terms)
}

/// Per instance: its model, world → model, its terms for the plants and for the ground
/// (projected onto its model's stored basis).
#[derive(Debug, Clone)]
struct InstanceLight {
    model: u32,
    to_model: Affine3A,
    terms: PhysicalTerms,
    /// Under the free weights (the model's light alone), as the per-sun grids' ground
    /// lookup reads its model's grid.
    ground: PhysicalTerms,
    /// Both as parts' weights, for the device side over uncompressed bases (which reads
    /// every part).
    plant_parts: PartTerms,
    ground_parts: PartTerms,
}

/// The current sun's light decoded at every site ([`PhysicalRelitLight::bake_for_frame`]).
#[derive(Debug)]
struct Baked {
    /// The grids decoded, each with its model: one per model and terms, shared by the
    /// instances of that model whose plants' (or ground's) terms are those; without a forest
    /// grid an instance's plants and ground have the same terms, so one grid serves both.
    grids: Vec<(u32, BakedLight)>,
    /// Per instance, the grid its plants' lookups read and the one its ground's read (`None`:
    /// not decoded, its lookups decode the basis).
    plants: Vec<Option<usize>>,
    ground: Vec<Option<usize>>,
    summary: BakeSummary,
}

/// [`PhysicalRelitLight::bake_for_frame`] decodes when a frame's lookups are at least
/// `1 / BAKE_SITES_PER_LOOKUP` of the sites to decode, for bases whose lookups otherwise
/// decode their footprint (uncompressed parts, PCA codecs). A decoded lookup saves 0.21 µs of a
/// compressed one (4.40 against 47.3 M lookups/s, `benches/relight_lookup.rs`) and a site
/// decodes in about 21 ns in a real frame (a catalpa's 28 parts at grid 128: 1.6 M sites in
/// 30-40 ms), so decoding pays from about one lookup per 10 sites; the count takes every
/// pixel as a lookup where about half miss the plants and the ground under them. At 8 a 512²
/// frame at one sample reads a catalpa at grid 128 decoded (measured alike either way:
/// docs/PERFORMANCE.md); a viewer's preview (a fifth of the size) does not.
const BAKE_SITES_PER_LOOKUP: u64 = 8;

/// The same for bases of Haar sets (the default codecs), whose lookups otherwise read blocks
/// decoded on first use ([`BlockCache`]): a frame decodes every site only when it reads at
/// least as many lookups as there are sites. A frame at one sample reads a crown's visible
/// surface and the ground under it, a tenth of its blocks, each decoded once: the catalpa's
/// 512² relit frame at K = 0 went from 1.14-1.16 to 1.04-1.05 times the static frame's
/// (docs/PERFORMANCE.md); the default gather (K = 8) reads it everywhere and decodes it all.
const BAKE_SITES_PER_LOOKUP_BLOCKS: u64 = 1;

/// A grid [`PhysicalRelitLight::bake_for_frame`] may decode: the terms of `terms.0`'s plants
/// (`terms.1`: of its ground), and every lookup that reads them (instance, whether its
/// ground's).
struct BakeGroup {
    model: u32,
    terms: (usize, bool),
    uses: Vec<(usize, bool)>,
}

/// Bytes of decoded light [`PhysicalRelitLight::bake_for_frame`] may hold by default: a lone tree at
/// grid 128 takes 19 MB, so a dozen distinct instances fit.
pub const DEFAULT_BAKE_BUDGET: u64 = 256 << 20;

/// What [`PhysicalRelitLight::bake_for_frame`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BakeSummary {
    /// Instances whose lookups (plants' and ground's) read decoded light.
    pub instances: usize,
    /// Of all instances with a basis.
    pub of: usize,
    /// Grids decoded (one per model and terms: instances of one model with equal terms
    /// share one, and so do an instance's plants and ground without a forest grid).
    pub grids: usize,
    pub bytes: u64,
    pub seconds: f64,
}

/// Why compressed bases are not shaded on the GPU when their grids decoded for the sun do not
/// fit the bake budget.
const BEYOND_BUDGET: &str = "the physical light's compressed bases, decoded for the sun, do not \
     fit the bake budget for every instance (--codec none shades the uncompressed bases on the GPU)";

/// A key equal for equal terms (their bits).
fn terms_key(terms: &PhysicalTerms) -> Vec<u32> {
    let mut key = Vec::new();
    match terms {
        PhysicalTerms::Full(t) => {
            for (part, w) in t {
                key.push(*part as u32);
                key.extend(w.to_array().map(f32::to_bits));
            }
        }
        PhysicalTerms::Compressed(sun, diffuse) => {
            for set in [sun, diffuse] {
                key.extend(set.constant().map(f32::to_bits));
                for (f, w) in set.terms() {
                    key.push(*f);
                    key.extend(w.map(f32::to_bits));
                }
                key.push(u32::MAX);
            }
        }
    }
    key
}

/// The physical light of every instance for the current sun from its model's
/// [`PhysicalBasis`], weighed by the forest grid's relit weights ([`ForestBases`]) when
/// there is a forest. Moving the sun ([`PhysicalRelitLight::relight`]) makes the weights
/// again: no LB solve.
pub struct PhysicalRelitLight {
    models: Vec<Option<StoredPhysicalBasis>>,
    model_bounds: Vec<Aabb>,
    instances: Vec<InstanceLight>,
    placed: Vec<(u32, Affine3A)>,
    ground_index: GroundIndex,
    forest: Option<ForestBases>,
    illumination: Illumination,
    /// Per instance, its part weights for the current sun (the forest's, or the free ones).
    weights: Vec<PartWeights>,
    open: OpenField,
    /// The current sun's light decoded, once a frame asked for it.
    baked: OnceLock<Baked>,
    /// The current sun's light decoded block by block as lookups reach it, for the
    /// instances `baked` does not hold (made on the first such lookup).
    blocks: OnceLock<LazyBlocks>,
}

/// Per group of lookups ([`BakeGroup`]: one model and terms) within the budget, the blocks
/// its lookups decoded; per instance, the cache its plants' and its ground's lookups read
/// (`None`: over the budget, or a basis without Haar blocks: they decode their footprint).
#[derive(Debug)]
struct LazyBlocks {
    caches: Vec<BlockCache>,
    plants: Vec<Option<usize>>,
    ground: Vec<Option<usize>>,
}

impl PhysicalRelitLight {
    /// `bases[m]` is model `m`'s basis (`None`: no indirect light on it); `instances` as
    /// traced; `forest` the forest grid's parts over these instances, if any. Lit by
    /// `illumination` (world frame) at once.
    pub fn new(
        bases: Vec<Option<StoredPhysicalBasis>>,
        models: &[Model],
        instances: &[TraceInstance],
        forest: Option<ForestBases>,
        illumination: Illumination,
    ) -> Result<PhysicalRelitLight, LightingError> {
        if bases.len() != models.len() {
            return Err(LightingError::Illumination(format!(
                "{} bases for {} models",
                bases.len(),
                models.len()
            )));
        }
        let ground_index = if bases.iter().any(Option::is_some) {
            GroundIndex::new(instances)
        } else {
            GroundIndex::default()
        };
        let env = physical_environment(&illumination)?;
        let mut light = PhysicalRelitLight {
            models: bases,
            model_bounds: models.iter().map(|m| m.bounds).collect(),
            instances: instances
                .iter()
                .map(|i| InstanceLight {
                    model: i.model,
                    to_model: i.to_model,
                    terms: PhysicalTerms::default(),
                    ground: PhysicalTerms::default(),
                    plant_parts: Vec::new(),
                    ground_parts: Vec::new(),
                })
                .collect(),
            placed: instances.iter().map(|i| (i.model, i.to_model)).collect(),
            ground_index,
            forest,
            illumination,
            weights: Vec::new(),
            open: open_field(&env),
            baked: OnceLock::new(),
            blocks: OnceLock::new(),
        };
        light.relight(illumination)?;
        Ok(light)
    }

    /// Lights every instance under `illumination` (world frame; its sun above the horizon):
    /// the forest's weights combined for its sun, each instance's terms for the sun in its
    /// model space. No LB solve.
    pub fn relight(&mut self, illumination: Illumination) -> Result<(), LightingError> {
        let env = physical_environment(&illumination)?;
        if env.sun_travel[1] > 0.0 {
            return Err(LightingError::Illumination(
                "the sun is below the horizon: nothing to relight with".into(),
            ));
        }
        let free = free_weights(&env);
        self.weights = match &self.forest {
            Some(f) => f.light(&env)?.weights,
            None => vec![free; self.instances.len()],
        };
        if self.weights.len() != self.instances.len() {
            return Err(LightingError::Global(format!(
                "the forest grid was solved for {} instances, the scene has {}",
                self.weights.len(),
                self.instances.len()
            )));
        }
        let travel = Vec3::from_array(env.sun_travel.map(|v| v as f32));
        for (inst, w) in self.instances.iter_mut().zip(&self.weights) {
            let t = inst
                .to_model
                .transform_vector3(travel)
                .as_dvec3()
                .to_array();
            let (terms, ground) = (
                instance_terms(t, illumination.sun, w)?,
                instance_terms(t, illumination.sun, &free)?,
            );
            if let Some(b) = &self.models[inst.model as usize] {
                inst.terms = b.project(&terms);
                inst.ground = b.project(&ground);
            }
            inst.plant_parts = terms;
            inst.ground_parts = ground;
        }
        self.baked = OnceLock::new();
        self.blocks = OnceLock::new();
        self.open = open_field(&env);
        self.illumination = illumination;
        Ok(())
    }

    pub fn illumination(&self) -> Illumination {
        self.illumination
    }

    /// The grids lookups read, one per model and terms (an instance's plants and its
    /// ground each read one), the most read first (ties in order of first use), and the
    /// instances with a basis.
    fn bake_groups(&self) -> (Vec<BakeGroup>, usize) {
        let mut index: HashMap<(u32, Vec<u32>), usize> = HashMap::new();
        let mut groups: Vec<BakeGroup> = Vec::new();
        let mut of = 0;
        for (i, inst) in self.instances.iter().enumerate() {
            if self.models[inst.model as usize].is_none() {
                continue;
            }
            of += 1;
            for (ground, terms) in [(false, &inst.terms), (true, &inst.ground)] {
                let g = *index
                    .entry((inst.model, terms_key(terms)))
                    .or_insert_with(|| {
                        groups.push(BakeGroup {
                            model: inst.model,
                            terms: (i, ground),
                            uses: Vec::new(),
                        });
                        groups.len() - 1
                    });
                groups[g].uses.push((i, ground));
            }
        }
        // Stable: ties keep their order of first use.
        groups.sort_by_key(|g| std::cmp::Reverse(g.uses.len()));
        (groups, of)
    }

    /// The groups whose grids fit `budget` bytes, the most read first, and their sites.
    fn chosen_groups(&self, budget: u64) -> (Vec<BakeGroup>, usize, u64) {
        let (groups, of) = self.bake_groups();
        let mut chosen = Vec::new();
        let (mut bytes, mut sites) = (0u64, 0u64);
        for group in groups {
            let Some(basis) = self.models[group.model as usize].as_ref() else {
                continue;
            };
            let b = BakedLight::memory_needed(basis.dims());
            if bytes + b > budget {
                continue;
            }
            bytes += b;
            sites += basis.dims().sites() as u64;
            chosen.push(group);
        }
        (chosen, of, sites)
    }

    /// Decodes the `chosen` groups' grids for the current sun (once: a sun already decoded
    /// keeps its grids).
    fn bake_chosen(&self, chosen: Vec<BakeGroup>, of: usize) -> &Baked {
        self.baked.get_or_init(|| {
            let t = std::time::Instant::now();
            let n = self.instances.len();
            let mut baked = Baked {
                grids: Vec::new(),
                plants: vec![None; n],
                ground: vec![None; n],
                summary: BakeSummary {
                    of,
                    ..BakeSummary::default()
                },
            };
            for group in chosen {
                let basis = self.models[group.model as usize]
                    .as_ref()
                    .expect("grouped instances have a basis");
                let (i, ground) = group.terms;
                let terms = if ground {
                    &self.instances[i].ground
                } else {
                    &self.instances[i].terms
                };
                // Memory refused: this group's lookups decode the parts.
                let Ok(light) = basis.bake(terms) else {
                    continue;
                };
                baked.summary.bytes += light.bytes();
                let at = baked.grids.len();
                baked.grids.push((group.model, light));
                for (i, ground) in group.uses {
                    let slot = if ground {
                        &mut baked.ground[i]
                    } else {
                        &mut baked.plants[i]
                    };
                    *slot = Some(at);
                }
            }
            baked.summary.grids = baked.grids.len();
            baked.summary.instances = (0..n)
                .filter(|&i| baked.plants[i].is_some() && baked.ground[i].is_some())
                .count();
            baked.summary.seconds = t.elapsed().as_secs_f64();
            baked
        })
    }

    /// Before a frame of about `lookups` plant lookups (pixels × samples × (1 + gather
    /// rays)): decodes the current sun's light at every site for as many instances as
    /// `budget` bytes hold (the most read grids first: the instances of one model with equal
    /// terms share one, and their plants and ground one without a forest grid) when the
    /// frame reads it at least once per [`BAKE_SITES_PER_LOOKUP`] sites (per site with Haar
    /// bases: [`BAKE_SITES_PER_LOOKUP_BLOCKS`]), so their lookups read
    /// 3 values instead of every part's (or, compressed, a Haar kernel per field). Once per
    /// sun: the next [`PhysicalRelitLight::relight`] drops it. `None` when nothing is decoded
    /// (not worth it, nothing fits, or memory refused: lookups decode the parts).
    pub fn bake_for_frame(&self, lookups: u64, budget: u64) -> Option<BakeSummary> {
        if let Some(b) = self.baked.get() {
            return Some(b.summary);
        }
        // Without decoding, Haar bases' lookups read blocks decoded on first use.
        let per = match self
            .models
            .iter()
            .flatten()
            .all(|b| b.block_count().is_some())
        {
            true => BAKE_SITES_PER_LOOKUP_BLOCKS,
            false => BAKE_SITES_PER_LOOKUP,
        };
        // A frame too small for even the smallest grid (a preview) skips the grouping.
        let smallest = self
            .models
            .iter()
            .flatten()
            .map(|b| b.dims().sites() as u64)
            .min()?;
        if lookups.saturating_mul(per) < smallest {
            return None;
        }
        let (chosen, of, sites) = self.chosen_groups(budget);
        if chosen.is_empty() || lookups.saturating_mul(per) < sites {
            return None;
        }
        Some(self.bake_chosen(chosen, of).summary)
    }

    /// Decodes the current sun's light for the GPU frame, whatever the frame: the kernel
    /// reads compressed bases only decoded ([`DeviceLight`] here), so every grid lookups read
    /// is decoded (the grids [`PhysicalRelitLight::bake_for_frame`] chooses, so the CPU's
    /// frames read what the GPU's do). Refused, decoding nothing, when they do not all fit
    /// `budget` bytes: the frames are shaded on the CPU, which decodes what a frame needs.
    pub fn bake_for_device(&self, budget: u64) -> Result<BakeSummary, NoDevice> {
        let covered = |s: BakeSummary| {
            if s.instances < s.of {
                Err(NoDevice(BEYOND_BUDGET))
            } else {
                Ok(s)
            }
        };
        if let Some(b) = self.baked.get() {
            return covered(b.summary);
        }
        let (chosen, of, _) = self.chosen_groups(budget);
        let mut read = vec![[false; 2]; self.instances.len()];
        for (i, ground) in chosen.iter().flat_map(|g| &g.uses) {
            read[*i][*ground as usize] = true;
        }
        if read.iter().filter(|r| r[0] && r[1]).count() < of {
            return Err(NoDevice(BEYOND_BUDGET));
        }
        covered(self.bake_chosen(chosen, of).summary)
    }

    /// Whether the GPU reads this light decoded per sun ([`PhysicalRelitLight::bake_for_device`]):
    /// some basis is compressed, and the kernel reads no physical codec.
    pub fn decodes_for_device(&self) -> bool {
        self.models
            .iter()
            .flatten()
            .any(|b| matches!(b, StoredPhysicalBasis::Compressed(_)))
    }

    /// What the current sun's decoding did, once a frame made it.
    pub fn bake_summary(&self) -> Option<BakeSummary> {
        self.baked.get().map(|b| b.summary)
    }

    /// Whether the forest grid weighs the instances.
    pub fn has_forest(&self) -> bool {
        self.forest.is_some()
    }

    /// Per instance, its part weights for the current sun.
    pub fn weights(&self) -> &[PartWeights] {
        &self.weights
    }

    /// The per-sun light of the current sun as the scene would be lit without bases: per
    /// model one grid of its four parts (the sun's for the sun in the world frame, as a
    /// per-sun solve takes it), weighed per instance as the forest grid says. For measuring
    /// what relighting costs per frame against the static light (`sylva bench relight`);
    /// compressed bases are decoded for it.
    pub fn static_light(
        &self,
        models: &[Model],
        instances: &[TraceInstance],
    ) -> Result<ModelGridLight, LightingError> {
        let env = physical_environment(&self.illumination)?;
        let travel = env.sun_travel;
        let sun = sun_part_weights(travel).unwrap_or_default();
        let e = self.illumination.sun;
        let mut lighting = Vec::with_capacity(self.models.len());
        for b in &self.models {
            let Some(b) = b else {
                lighting.push(None);
                continue;
            };
            let b = b.to_full()?;
            let grid = |f: &dyn Fn(&[[f32; 3]; PARTS]) -> Vec3| LightingGrid {
                dims: b.dims(),
                bounds: b.bounds(),
                colours: std::array::from_fn(|c| b.sites().iter().map(|v| f(v)[c]).collect()),
            };
            let s = grid(&|v| {
                sun.iter()
                    .map(|&(k, w)| Vec3::from_array(v[k]) * e * w as f32)
                    .sum()
            });
            let part = |k: usize| grid(&|v| Vec3::from_array(v[SUN_PARTS + k]));
            let (top, side, ground) = (part(0), part(1), part(2));
            lighting.push(Some(ModelLighting::physical_parts(
                [&s, &top, &side, &ground],
                &env,
            )));
        }
        let light = ModelGridLight::new(lighting, models, instances);
        Ok(match &self.forest {
            Some(_) => light.with_instance_weights(self.weights.clone()),
            None => light,
        })
    }

    /// Relights from `bases` (one per model, as [`PhysicalRelitLight::new`] takes them: the
    /// uncompressed parts in place of the compressed ones, or back) and returns the ones in
    /// use until now. For measuring what compression costs in the image.
    pub fn swap_bases(
        &mut self,
        bases: Vec<Option<StoredPhysicalBasis>>,
    ) -> Result<Vec<Option<StoredPhysicalBasis>>, LightingError> {
        if bases.len() != self.models.len() {
            return Err(LightingError::Illumination(format!(
                "{} bases for {} models",
                bases.len(),
                self.models.len()
            )));
        }
        let old = std::mem::replace(&mut self.models, bases);
        self.relight(self.illumination)?;
        Ok(old)
    }

    /// Model `m`'s basis.
    pub fn model(&self, m: usize) -> Option<&StoredPhysicalBasis> {
        self.models.get(m).and_then(Option::as_ref)
    }

    /// The light of instance `instance` at model-space point `p` (`None`: no basis).
    #[inline]
    pub fn sample_instance(&self, instance: usize, p: Vec3) -> Option<Vec3> {
        let inst = self.instances.get(instance)?;
        if let Some(b) = self.baked.get() {
            if let Some(g) = b.plants[instance] {
                return Some(b.grids[g].1.sample(p));
            }
        }
        let basis = self.models[inst.model as usize].as_ref()?;
        let lazy = self.lazy_blocks();
        Some(match lazy.plants[instance] {
            Some(c) => basis.sample_blocks(p, &inst.terms, &lazy.caches[c]),
            None => basis.sample(p, &inst.terms),
        })
    }

    /// Instance `i`'s ground terms (its model's light alone) at model-space point `p` of
    /// `basis`: decoded for the sun when it is, as its plants'.
    #[inline]
    fn ground_light(&self, i: usize, basis: &StoredPhysicalBasis, p: Vec3) -> Vec3 {
        if let Some(b) = self.baked.get() {
            if let Some(g) = b.ground[i] {
                return b.grids[g].1.sample(p);
            }
        }
        let terms = &self.instances[i].ground;
        let lazy = self.lazy_blocks();
        match lazy.ground[i] {
            Some(c) => basis.sample_blocks(p, terms, &lazy.caches[c]),
            None => basis.sample(p, terms),
        }
    }

    /// The block caches of the current sun, made on the first lookup that needs them: one
    /// per group of lookups ([`PhysicalRelitLight::bake_groups`]: a model and its terms) of
    /// a basis with Haar blocks, the most read first while their chunk indices take at most a
    /// quarter of [`DEFAULT_BAKE_BUDGET`]; the blocks they keep share the rest (past it a
    /// block is decoded for its lookup and not kept: the same value, [`BlockCache`]). Which
    /// lookups read blocks is chosen before any is read, so a frame does not depend on the
    /// order threads reach them.
    fn lazy_blocks(&self) -> &LazyBlocks {
        self.blocks.get_or_init(|| {
            let n = self.instances.len();
            let mut lazy = LazyBlocks {
                caches: Vec::new(),
                plants: vec![None; n],
                ground: vec![None; n],
            };
            let (groups, _) = self.bake_groups();
            let mut index = 0u64;
            let mut counts = Vec::new();
            for group in groups {
                let Some(count) = self.models[group.model as usize]
                    .as_ref()
                    .and_then(StoredPhysicalBasis::block_count)
                else {
                    continue;
                };
                let need = BlockCache::index_bytes(count);
                if index + need > DEFAULT_BAKE_BUDGET / 4 {
                    continue;
                }
                index += need;
                counts.push(count);
                let at = counts.len() - 1;
                for (i, ground) in group.uses {
                    let slot = match ground {
                        true => &mut lazy.ground[i],
                        false => &mut lazy.plants[i],
                    };
                    *slot = Some(at);
                }
            }
            let budget = BlockBudget::new(DEFAULT_BAKE_BUDGET - index);
            lazy.caches = counts
                .into_iter()
                .map(|count| BlockCache::new(count, budget.clone()))
                .collect();
            lazy
        })
    }

    /// Blocks the current sun's lookups decoded one by one so far (a frame that decoded
    /// every site reads none).
    pub fn blocks_decoded(&self) -> usize {
        self.blocks
            .get()
            .map_or(0, |l| l.caches.iter().map(BlockCache::decoded).sum())
    }
}

impl IndirectLight for PhysicalRelitLight {
    fn plant(&self, instance: u32, placed: &TraceInstance, world: Vec3) -> Option<Vec3> {
        self.sample_instance(instance as usize, placed.to_model.transform_point3(world))
    }

    /// As the per-sun grids' ([`crate::lighting::ModelLighting::ground_sky`]): the share of
    /// the open sky's light under each tree from its grid's two lowest layers, the model's
    /// light alone.
    fn ground_sky(&self, point: Vec3) -> Vec3 {
        ground_shade(
            &self.ground_index,
            &self.placed,
            &self.model_bounds,
            point,
            |i, model, pm| {
                let basis = self.models[model as usize].as_ref()?;
                let origin = Vec3::from_array(basis.placement().origin());
                let inv = Vec3::from_array(basis.placement().inv_cell());
                let cell_y = if inv.y > 0.0 { 1.0 / inv.y } else { 0.0 };
                let floor = self.ground_light(i, basis, Vec3::new(pm.x, origin.y, pm.z));
                let lowest = self.ground_light(i, basis, Vec3::new(pm.x, origin.y + cell_y, pm.z));
                Some(physical_ground_sky(floor, lowest, &self.open))
            },
        )
    }

    fn memory_bytes(&self) -> u64 {
        self.models
            .iter()
            .flatten()
            .map(StoredPhysicalBasis::bytes)
            .sum()
    }

    fn gatherable(&self) -> bool {
        true
    }

    /// Uncompressed bases as stored (every part at every site); compressed ones decoded
    /// for the current sun ([`PhysicalRelitLight::bake_for_device`]): the kernel reads no
    /// physical codec, and a compressed set's lookups (a block's kept coefficients against
    /// the footprint) are not its decoded sites' trilinear ones, so the GPU reads the grids
    /// the CPU's lookups read once decoded. Refused when the decoding does not cover every
    /// instance (the bake budget), or was not made for this sun.
    fn device(&self) -> Result<&dyn DeviceLight, NoDevice> {
        if !self.decodes_for_device() {
            return Ok(self);
        }
        match self.baked.get() {
            None => Err(NoDevice(
                "the physical light's compressed bases are read on the GPU decoded for the sun, \
                 and they were not decoded for this sun",
            )),
            Some(b) if b.summary.instances < b.summary.of => Err(NoDevice(BEYOND_BUDGET)),
            Some(_) => Ok(self),
        }
    }
}

/// Words of a model's relit record: the header, then every field at every site.
fn device_words(basis: &StoredPhysicalBasis) -> u64 {
    LIGHT_HEADER as u64 + (3 * PARTS * basis.dims().sites()) as u64
}

/// A relit record of kind 0 (every field at every site, field `3 part + colour`, site after
/// site; a compressed basis decoded), the paper light's uncompressed layout: shade.wgsl's
/// `relit_terms` reads both. `bounds`: the model's. Returns where it starts.
fn pack_basis(basis: &PhysicalBasis, p: &mut Packer, bounds: Aabb) -> u32 {
    let start = p.relit_header(basis.dims(), basis.placement(), bounds, 3 * PARTS);
    for field in 0..3 * PARTS {
        let (part, colour) = (field / 3, field % 3);
        p.words
            .extend(basis.sites().iter().map(|v| v[part][colour].to_bits()));
    }
    start
}

/// `terms` over the device's scalar fields (`3 part + colour`): a part's weight per colour
/// becomes a term per colour, its weight on that colour alone.
fn field_terms(terms: &PartTerms, words: &mut Vec<u32>) -> u32 {
    let mut n = 0;
    for &(part, w) in terms {
        for c in 0..3 {
            if w[c] != 0.0 {
                let mut only = [0.0f32; 3];
                only[c] = w[c];
                words.push((3 * part + c) as u32);
                words.extend(only.map(f32::to_bits));
                n += 1;
            }
        }
    }
    n
}

/// A kind-0 relit record of the grids decoded for the sun of one model (`grids`: its slots'
/// grids in order): field `3 slot + colour`, site after site. Returns where it starts.
fn pack_baked(grids: &[&BakedLight], p: &mut Packer, placement: &Placement, bounds: Aabb) -> u32 {
    let start = p.relit_header(grids[0].dims(), placement, bounds, 3 * grids.len());
    for g in grids {
        for colour in 0..3 {
            p.words
                .extend(g.values().iter().map(|v| v[colour].to_bits()));
        }
    }
    start
}

/// A decoded grid's terms (its slot in its model's record): one per colour, its field's
/// weight 1 on that colour alone, so the kernel's sum is the grid's trilinear lookup.
fn slot_terms(slot: usize, words: &mut Vec<u32>) -> u32 {
    for c in 0..3 {
        let mut only = [0.0f32; 3];
        only[c] = 1.0;
        words.push((3 * slot + c) as u32);
        words.extend(only.map(f32::to_bits));
    }
    3
}

impl PhysicalRelitLight {
    /// The grids decoded for the device: per model its grids (indices into `baked.grids`),
    /// and per grid its slot in its model's record.
    fn device_slots(&self, baked: &Baked) -> (Vec<Vec<usize>>, Vec<usize>) {
        let mut per_model = vec![Vec::new(); self.models.len()];
        let mut slots = Vec::with_capacity(baked.grids.len());
        for (g, (model, _)) in baked.grids.iter().enumerate() {
            let list: &mut Vec<usize> = &mut per_model[*model as usize];
            slots.push(list.len());
            list.push(g);
        }
        (per_model, slots)
    }

    /// The decoded grids the device reads, when it reads them (compressed bases).
    fn device_baked(&self) -> Option<&Baked> {
        if self.decodes_for_device() {
            self.baked.get()
        } else {
            None
        }
    }
}

/// The GPU side: the kernel's relit lookup (`relit_sample`) over kind-0 records, with the
/// physical light's ground (shade.wgsl `relit_physical_ground_sky`: the share of the open
/// sky's light under a tree from its grid's two lowest layers, as [`IndirectLight::ground_sky`]
/// here). Uncompressed bases: per model every part at every site, each instance's terms over
/// them. Compressed ones: per model its grids decoded for the sun, each instance's plants and
/// ground reading their grid's three fields, as the CPU's lookups read the same grids. Parity:
/// `device::tests` unpacks the words as the shader reads them; the pipeline's GPU tests
/// compare whole frames.
impl DeviceLight for PhysicalRelitLight {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Relit
    }

    fn pool_words(&self) -> u64 {
        let records: u64 = match self.device_baked() {
            Some(b) => {
                let (per_model, _) = self.device_slots(b);
                per_model
                    .iter()
                    .filter(|g| !g.is_empty())
                    .map(|g| {
                        LIGHT_HEADER as u64
                            + (3 * g.len()) as u64 * b.grids[g[0]].1.dims().sites() as u64
                    })
                    .sum()
            }
            None => self.models.iter().flatten().map(device_words).sum(),
        };
        records + self.ground_index.words()
    }

    fn pack(&self, pool: &mut Vec<u32>) -> PackedLight {
        let mut p = Packer::new(pool);
        let records = match self.device_baked() {
            Some(b) => {
                let (per_model, _) = self.device_slots(b);
                per_model
                    .iter()
                    .zip(&self.models)
                    .zip(&self.model_bounds)
                    .map(|((grids, basis), &bounds)| match basis {
                        Some(basis) if !grids.is_empty() => {
                            let grids: Vec<&BakedLight> =
                                grids.iter().map(|&g| &b.grids[g].1).collect();
                            pack_baked(&grids, &mut p, basis.placement(), bounds)
                        }
                        // No instance reads it (or no basis: no LB light).
                        _ => NONE,
                    })
                    .collect()
            }
            None => self
                .models
                .iter()
                .zip(&self.model_bounds)
                .map(|(b, &bounds)| match b {
                    Some(StoredPhysicalBasis::Full(b)) => pack_basis(b, &mut p, bounds),
                    // Compressed: decoded above (and no basis: no LB light).
                    _ => NONE,
                })
                .collect(),
        };
        PackedLight {
            records,
            ground: self.ground_index.pack(pool),
        }
    }

    /// Per instance an entry: its plants' terms (first, count), no constant, its ground's
    /// terms (first, count) and where the open field (sky, bottom: 6 words) is; the open
    /// field once after the entries, then the terms (field, weight per colour).
    fn sun_words(&self) -> SunWords {
        let n = self.instances.len();
        let mut words = vec![0u32; RELIT_ENTRY * n];
        let open = words.len() as u32;
        words.extend(self.open.sky.to_array().map(f32::to_bits));
        words.extend(self.open.bottom.to_array().map(f32::to_bits));
        let baked = self.device_baked().map(|b| (b, self.device_slots(b).1));
        for (i, inst) in self.instances.iter().enumerate() {
            let e = RELIT_ENTRY * i;
            words[e + 7] = open;
            if self.models[inst.model as usize].is_none() {
                continue;
            }
            let first = words.len() as u32;
            let count = match &baked {
                Some((b, slots)) => b.plants[i].map_or(0, |g| slot_terms(slots[g], &mut words)),
                None => field_terms(&inst.plant_parts, &mut words),
            };
            let ground_first = words.len() as u32;
            let ground_count = match &baked {
                Some((b, slots)) => b.ground[i].map_or(0, |g| slot_terms(slots[g], &mut words)),
                None => field_terms(&inst.ground_parts, &mut words),
            };
            words[e] = first;
            words[e + 1] = count;
            words[e + 5] = ground_first;
            words[e + 6] = ground_count;
        }
        SunWords {
            words,
            // The physical ground reads its open field, not a free-space luminance.
            free_space: 1.0,
        }
    }

    /// Every part of every instance's model in every colour, twice (plants and ground),
    /// and the open field (a decoded grid's three terms are fewer).
    fn sun_capacity(&self) -> usize {
        self.instances
            .iter()
            .map(|inst| {
                RELIT_ENTRY
                    + self.models[inst.model as usize]
                        .as_ref()
                        .map_or(0, |_| 2 * RELIT_TERM * 3 * PARTS)
            })
            .sum::<usize>()
            + 6
    }

    /// The grids decoded for the sun change with it.
    fn pool_per_sun(&self) -> bool {
        self.decodes_for_device()
    }
}
