//! [`RelitLight`]: the indirect light of every instance as a combination of its model's base
//! solutions, weighted for the sun in the instance's own model space (004 §3.1), scaled by the
//! coarse global grid (004 §3.2). Moving the sun recomputes the per-instance weights (a few
//! hundred small dot products), never an LB solve.

use glam::{Affine3A, Vec3};
use sylva_core::colour::luminance;
use sylva_geom::{Aabb, Model};
use sylva_lb::relight::{
    BasisSet, BasisWeights, CompressedBasis, HaarCoefs, Placement, ProjectedWeights, RelightError,
    StoredFields,
};
use sylva_lb::{Bounds, Dims};
use sylva_trace::TraceInstance;

use super::global::{GlobalLight, InstanceScale};
use super::weights::RelitIllumination;
use crate::device::{DeviceKind, DeviceLight, NoDevice, PackedLight, Packer, SunWords};
use crate::device::{LIGHT_HEADER, NONE, RELIT_ENTRY, RELIT_KIND, RELIT_TERM};
use crate::indirect::{ground_shade, GroundIndex, IndirectLight};

/// A model's stored fields: its base solutions, uncompressed or compressed.
// One per model, held in place: the variants' header sizes do not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum StoredBasis {
    Full(BasisSet),
    Compressed(CompressedBasis),
}

/// Weights made for one [`StoredBasis`] ([`StoredBasis::project`]).
#[derive(Debug, Clone, PartialEq)]
pub enum ProjectedLight {
    Full(BasisWeights),
    Compressed(ProjectedWeights),
}

impl StoredBasis {
    pub fn dims(&self) -> Dims {
        match self {
            StoredBasis::Full(b) => b.dims,
            StoredBasis::Compressed(c) => c.dims,
        }
    }

    pub fn bounds(&self) -> Bounds {
        match self {
            StoredBasis::Full(b) => b.bounds,
            StoredBasis::Compressed(c) => c.bounds,
        }
    }

    /// Bytes of stored fields.
    pub fn bytes(&self) -> u64 {
        match self {
            StoredBasis::Full(b) => BasisSet::memory_needed(b.dims),
            StoredBasis::Compressed(c) => c.bytes(),
        }
    }

    /// Fields a lookup combines: the 57 channels `3 j + colour` uncompressed, the codec's
    /// fields compressed.
    pub fn field_count(&self) -> usize {
        match self {
            StoredBasis::Full(b) => b.channels().len(),
            StoredBasis::Compressed(c) => c.fields(),
        }
    }

    /// `w` in the form a lookup reads (for compressed sets: folded into the fields).
    pub fn project(&self, w: &BasisWeights) -> ProjectedLight {
        match self {
            StoredBasis::Full(_) => ProjectedLight::Full(*w),
            StoredBasis::Compressed(c) => ProjectedLight::Compressed(c.project(w)),
        }
    }

    /// The combination at grid coordinates `g` (trilinear, clamped to the grid). `w` must
    /// come from this set's [`StoredBasis::project`].
    #[inline]
    pub fn sample_grid(&self, g: [f32; 3], w: &ProjectedLight) -> [f32; 3] {
        match (self, w) {
            (StoredBasis::Full(b), ProjectedLight::Full(w)) => b.sample(g, w),
            (StoredBasis::Compressed(c), ProjectedLight::Compressed(w)) => c.sample_grid(g, w),
            _ => panic!("weights projected for another kind of stored basis"),
        }
    }

    /// Words [`StoredBasis::pack`] appends at most: f16 values are widened to f32, at most
    /// 4 × what is stored.
    fn device_words(&self) -> u64 {
        let stored = match self {
            StoredBasis::Full(set) => BasisSet::memory_needed(set.dims),
            StoredBasis::Compressed(c) => 4 * c.bytes(),
        };
        stored / 4 + LIGHT_HEADER as u64
    }

    /// Appends this model's relit record as shade.wgsl's `relit_sample` reads it
    /// ([`crate::device`]): the header, then the stored fields as [`StoredBasis::sample_grid`]
    /// reads them: every field at every site (uncompressed and dense sets), or the Haar
    /// blocks' starts, counts (4 per word) and coefficients (split: indices 4 per word and
    /// f32 values; packed: the u16 words 2 per word and a step per field). `placement`: this
    /// set's, `bounds`: the model's. Returns where it starts.
    fn pack(&self, p: &mut Packer, placement: &Placement, bounds: Aabb) -> u32 {
        let start = p.relit_header(self.dims(), placement, bounds, self.field_count());
        let fields = |p: &mut Packer, fields: &[Vec<f32>]| {
            for f in fields {
                p.words.extend(f.iter().map(|v| v.to_bits()));
            }
        };
        let header = |p: &mut Packer, k: usize, v: u32| p.set(start + k as u32, v);
        match self {
            StoredBasis::Full(set) => fields(p, set.channels()),
            StoredBasis::Compressed(c) => match c.stored_fields() {
                StoredFields::Dense(f) => fields(p, &f),
                StoredFields::Haar(h) => {
                    header(p, RELIT_KIND, 1);
                    header(p, RELIT_KIND + 3, h.blocks[1] as u32);
                    header(p, RELIT_KIND + 4, h.blocks[2] as u32);
                    let at = p.at();
                    header(p, RELIT_KIND + 5, at);
                    p.words.extend_from_slice(h.starts);
                    let at = p.at();
                    header(p, RELIT_KIND + 6, at);
                    p.bytes(h.counts);
                    match h.coefs {
                        HaarCoefs::Split { indices, values } => {
                            let at = p.at();
                            header(p, RELIT_KIND + 7, at);
                            p.bytes(indices);
                            let at = p.at();
                            header(p, RELIT_KIND + 8, at);
                            p.words.extend(values.iter().map(|v| v.to_bits()));
                        }
                        HaarCoefs::Packed { words, steps } => {
                            header(p, RELIT_KIND, 2);
                            let at = p.at();
                            header(p, RELIT_KIND + 7, at);
                            p.words.extend(words.chunks(2).map(|c| {
                                c[0] as u32 | (c.get(1).copied().unwrap_or(0) as u32) << 16
                            }));
                            let at = p.at();
                            header(p, RELIT_KIND + 8, at);
                            p.words.extend(steps.iter().map(|v| v.to_bits()));
                        }
                    }
                }
            },
        }
        start
    }
}

/// A combination of a stored basis's fields: the constant per colour and
/// `(field, weight per colour)` terms, sorted by field.
pub type FieldTerms = ([f32; 3], Vec<(u32, [f32; 3])>);

impl ProjectedLight {
    /// The combination as `constant + Σ weight · field` over the stored fields (the 57
    /// channels `3 j + colour` uncompressed, the codec's fields compressed), zero terms left
    /// out.
    pub fn field_terms(&self) -> FieldTerms {
        match self {
            ProjectedLight::Full(w) => {
                let mut terms = Vec::new();
                for (j, w) in w.terms() {
                    for c in 0..3 {
                        let mut v = [0.0f32; 3];
                        v[c] = w as f32;
                        terms.push(((3 * j + c) as u32, v));
                    }
                }
                ([0.0; 3], terms)
            }
            ProjectedLight::Compressed(w) => (w.constant(), w.terms().to_vec()),
        }
    }
}

/// Per instance: its projected weights, or none (its model has no basis).
#[derive(Debug, Clone)]
struct InstanceLight {
    model: u32,
    to_model: Affine3A,
    weights: Option<ProjectedLight>,
}

/// Indirect light from base solutions, per instance and sun.
#[derive(Debug)]
pub struct RelitLight {
    /// Per model: its stored basis and placement (or none: no indirect light on it).
    models: Vec<Option<(StoredBasis, Placement)>>,
    model_bounds: Vec<Aabb>,
    instances: Vec<InstanceLight>,
    /// `(model, world → model)` per instance, for the ground's shade.
    placed: Vec<(u32, Affine3A)>,
    ground_index: GroundIndex,
    global: Option<GlobalLight>,
    scales: Vec<InstanceScale>,
    illumination: RelitIllumination,
}

impl RelitLight {
    /// `bases[m]` is model `m`'s stored basis (`None`: no indirect light on it); `instances`
    /// as traced; `global` the coarse grid's answer for these instances, if any. The weights
    /// are made for `illumination` at once.
    pub fn new(
        bases: Vec<Option<StoredBasis>>,
        models: &[Model],
        instances: &[TraceInstance],
        global: Option<GlobalLight>,
        illumination: RelitIllumination,
    ) -> Result<RelitLight, RelightError> {
        if bases.len() != models.len() {
            return Err(RelightError::Mismatch(format!(
                "{} bases for {} models",
                bases.len(),
                models.len()
            )));
        }
        if let Some(g) = &global {
            if g.instances() != instances.len() {
                return Err(RelightError::Mismatch(format!(
                    "the global grid was solved for {} instances, the scene has {}",
                    g.instances(),
                    instances.len()
                )));
            }
        }
        let models_placed: Vec<Option<(StoredBasis, Placement)>> = bases
            .into_iter()
            .map(|b| {
                b.map(|b| {
                    let p = Placement::new(b.dims(), b.bounds());
                    (b, p)
                })
            })
            .collect();
        let ground_index = if models_placed.iter().any(Option::is_some) {
            GroundIndex::new(instances)
        } else {
            GroundIndex::default()
        };
        let mut light = RelitLight {
            models: models_placed,
            model_bounds: models.iter().map(|m| m.bounds).collect(),
            instances: instances
                .iter()
                .map(|i| InstanceLight {
                    model: i.model,
                    to_model: i.to_model,
                    weights: None,
                })
                .collect(),
            placed: instances.iter().map(|i| (i.model, i.to_model)).collect(),
            ground_index,
            global,
            scales: Vec::new(),
            illumination,
        };
        light.relight(illumination)?;
        Ok(light)
    }

    /// Makes every instance's weights for `illumination`: the sun taken into its model space,
    /// the global grid's scales applied. No LB solve.
    pub fn relight(&mut self, illumination: RelitIllumination) -> Result<(), RelightError> {
        illumination
            .validate()
            .map_err(|e| RelightError::Mismatch(format!("illumination: {e}")))?;
        self.scales = match &self.global {
            Some(g) => g.scales(&illumination.weights(&Affine3A::IDENTITY)?),
            None => vec![InstanceScale::ONE; self.instances.len()],
        };
        for (inst, scale) in self.instances.iter_mut().zip(&self.scales) {
            inst.weights = match &self.models[inst.model as usize] {
                Some((basis, _)) => {
                    let w = illumination.weights(&inst.to_model)?;
                    Some(basis.project(&scale.apply(&w)?))
                }
                None => None,
            };
        }
        self.illumination = illumination;
        Ok(())
    }

    /// Replaces the stored fields with `bases` (the same models on the same grids, e.g. the
    /// uncompressed sets for the compressed ones) and makes the weights again; returns the
    /// fields it held.
    pub fn swap_bases(
        &mut self,
        bases: Vec<Option<StoredBasis>>,
    ) -> Result<Vec<Option<StoredBasis>>, RelightError> {
        if bases.len() != self.models.len() {
            return Err(RelightError::Mismatch(format!(
                "{} bases for {} models",
                bases.len(),
                self.models.len()
            )));
        }
        for (m, (new, old)) in bases.iter().zip(&self.models).enumerate() {
            let same = match (new, old) {
                (Some(n), Some((o, _))) => n.dims() == o.dims() && n.bounds() == o.bounds(),
                (None, None) => true,
                _ => false,
            };
            if !same {
                return Err(RelightError::Mismatch(format!(
                    "model {m}: the replacement basis is not on the same grid"
                )));
            }
        }
        let old = std::mem::replace(
            &mut self.models,
            bases
                .into_iter()
                .map(|b| {
                    b.map(|b| {
                        let p = Placement::new(b.dims(), b.bounds());
                        (b, p)
                    })
                })
                .collect(),
        );
        self.relight(self.illumination)?;
        Ok(old.into_iter().map(|b| b.map(|b| b.0)).collect())
    }

    pub fn illumination(&self) -> RelitIllumination {
        self.illumination
    }

    /// Per instance, the global grid's scales for the current sun (1 without the grid).
    pub fn scales(&self) -> &[InstanceScale] {
        &self.scales
    }

    pub fn global(&self) -> Option<&GlobalLight> {
        self.global.as_ref()
    }

    /// Model `m`'s stored basis.
    pub fn model(&self, m: usize) -> Option<&StoredBasis> {
        self.models.get(m).and_then(|b| b.as_ref().map(|b| &b.0))
    }

    /// Instances lit.
    pub fn instances(&self) -> usize {
        self.instances.len()
    }

    /// Instance `i`'s combination of its model's fields for the current sun (`None`: its
    /// model has no basis).
    pub fn instance_terms(&self, i: usize) -> Option<FieldTerms> {
        self.instances
            .get(i)?
            .weights
            .as_ref()
            .map(ProjectedLight::field_terms)
    }

    /// The relit light's luminance in free space (`1 + ambient`), what the ground's shade is
    /// measured against.
    fn free_space(&self) -> f32 {
        (1.0 + self.illumination.ambient) as f32
    }

    /// The light of instance `instance` at model-space point `p` (`None`: no basis).
    #[inline]
    pub fn sample_instance(&self, instance: usize, p: Vec3) -> Option<Vec3> {
        let inst = self.instances.get(instance)?;
        let w = inst.weights.as_ref()?;
        let (basis, placement) = self.models[inst.model as usize].as_ref()?;
        let g = placement.grid_coords(p.to_array());
        Some(Vec3::from_array(basis.sample_grid(g, w)))
    }
}

impl IndirectLight for RelitLight {
    fn plant(&self, instance: u32, placed: &TraceInstance, world: Vec3) -> Option<Vec3> {
        self.sample_instance(instance as usize, placed.to_model.transform_point3(world))
    }

    /// As [`crate::ModelGridLight`]'s, with each tree's relit luminance relative to its free
    /// space value (`1 + ambient`), so ambient light does not brighten the shade.
    fn ground_sky(&self, point: Vec3) -> Vec3 {
        let open = self.free_space();
        ground_shade(
            &self.ground_index,
            &self.placed,
            &self.model_bounds,
            point,
            |i, _, pm| {
                self.sample_instance(i, pm)
                    .map(|l| Vec3::splat(luminance(l.to_array()) / open))
            },
        )
    }

    fn memory_bytes(&self) -> u64 {
        self.models.iter().flatten().map(|(b, _)| b.bytes()).sum()
    }

    fn device(&self) -> Result<&dyn DeviceLight, NoDevice> {
        Ok(self)
    }
}

/// The stored fields as [`RelitLight::sample_instance`] reads them (shade.wgsl:
/// `relit_sample`): per model its record ([`StoredBasis::pack`]), the ground index; per sun,
/// each instance's combination of its model's fields.
impl DeviceLight for RelitLight {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Relit
    }

    fn pool_words(&self) -> u64 {
        let records: u64 = self
            .models
            .iter()
            .flatten()
            .map(|(b, _)| b.device_words())
            .sum();
        records + self.ground_index.words()
    }

    fn pack(&self, pool: &mut Vec<u32>) -> PackedLight {
        let mut p = Packer::new(pool);
        let records = self
            .models
            .iter()
            .zip(&self.model_bounds)
            .map(|(b, &bounds)| {
                b.as_ref()
                    .map_or(NONE, |(b, placement)| b.pack(&mut p, placement, bounds))
            })
            .collect();
        PackedLight {
            records,
            ground: self.ground_index.pack(pool),
        }
    }

    /// Per instance an entry (first term, term count, constant per colour), then the terms
    /// (field, weight per colour), for the current sun. Instances without a basis have no
    /// terms.
    fn sun_words(&self) -> SunWords {
        let n = self.instances.len();
        let mut words = vec![0u32; RELIT_ENTRY * n];
        for i in 0..n {
            let Some((constant, terms)) = self.instance_terms(i) else {
                continue;
            };
            let first = words.len() as u32;
            for (field, w) in &terms {
                words.push(*field);
                words.extend(w.map(f32::to_bits));
            }
            let e = RELIT_ENTRY * i;
            words[e] = first;
            words[e + 1] = terms.len() as u32;
            words[e + 2..e + 5].copy_from_slice(&constant.map(f32::to_bits));
        }
        SunWords {
            words,
            free_space: self.free_space(),
        }
    }

    /// Every field of every instance's model.
    fn sun_capacity(&self) -> usize {
        self.instances
            .iter()
            .map(|inst| {
                RELIT_ENTRY
                    + self.models[inst.model as usize]
                        .as_ref()
                        .map_or(0, |(b, _)| RELIT_TERM * b.field_count())
            })
            .sum::<usize>()
            .max(RELIT_ENTRY)
    }
}
