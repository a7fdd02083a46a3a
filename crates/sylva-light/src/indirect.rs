//! Indirect light where the renderer needs it: on a plant (the model's LB light at the point:
//! the physical light's scattered, sky and ground light in LB units, or the paper's light
//! normalised so unobstructed sunlight is 1; see [`crate::lighting`]) and on the ground (how
//! much of the sky's light gets through the trees, per colour). [`IndirectLight`] is the interface; [`ModelGridLight`], one
//! LB grid per unique model placed by each instance's transform (000 §4.3), is the static
//! implementation, [`crate::relight::RelitLight`] (base solutions combined per instance and
//! sun, 004; the paper light only) the relit one, and [`NoIndirectLight`] the absence of any.

use glam::{Affine3A, Vec2, Vec3};
use sylva_geom::{Aabb, Model};
use sylva_trace::TraceInstance;

use crate::device::{DeviceGround, DeviceKind, DeviceLight, NoDevice, PackedLight, SunWords};
use crate::device::{Packer, LIGHT_HEADER, NONE};
use crate::lighting::{ModelLighting, PartWeights};

/// Indirect light sources for shading. Implementations are read from many threads at once.
pub trait IndirectLight: Sync {
    /// The RGB LB light at world point `world` on instance `instance` (`placed`: its model
    /// and transforms, as traced); `None` when this plant gets none.
    fn plant(&self, instance: u32, placed: &TraceInstance, world: Vec3) -> Option<Vec3>;

    /// The fraction of the sky's light reaching the ground at world point `p`, per colour
    /// in [0, 1]: 1 in the open.
    fn ground_sky(&self, p: Vec3) -> Vec3;

    /// Bytes held.
    fn memory_bytes(&self) -> u64;

    /// Whether plants' indirect light may be final-gathered ([`crate::gather`]): the light is
    /// the physical light's, whose LB value at a point the gather's hits can shade with.
    fn gatherable(&self) -> bool {
        false
    }

    /// The light's device side (what the GPU frame kernel reads: [`crate::device`]), or why
    /// it has none (its frames are shaded on the CPU).
    fn device(&self) -> Result<&dyn DeviceLight, NoDevice>;
}

/// No indirect light: plants get none, the ground sees the whole sky.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoIndirectLight;

impl IndirectLight for NoIndirectLight {
    fn plant(&self, _: u32, _: &TraceInstance, _: Vec3) -> Option<Vec3> {
        None
    }

    fn ground_sky(&self, _: Vec3) -> Vec3 {
        Vec3::ONE
    }

    fn memory_bytes(&self) -> u64 {
        0
    }

    fn device(&self) -> Result<&dyn DeviceLight, NoDevice> {
        Ok(self)
    }
}

/// No records, no ground index: the kernel finds no LB light anywhere.
impl DeviceLight for NoIndirectLight {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Grids
    }

    fn pool_words(&self) -> u64 {
        0
    }

    fn pack(&self, _: &mut Vec<u32>) -> PackedLight {
        PackedLight::default()
    }

    fn sun_words(&self) -> SunWords {
        SunWords {
            words: Vec::new(),
            free_space: 1.0,
        }
    }

    fn sun_capacity(&self) -> usize {
        0
    }
}

/// One LB lighting grid per unique model (or none), looked up in each instance's model space.
#[derive(Debug)]
pub struct ModelGridLight {
    /// `lighting[m]`: model `m`'s grid.
    lighting: Vec<Option<ModelLighting>>,
    /// Per model, its bounds in model space.
    model_bounds: Vec<Aabb>,
    /// Per instance: model and world → model transform.
    instances: Vec<(u32, Affine3A)>,
    /// Instances over each ground cell, for the LB light under trees.
    ground_index: GroundIndex,
    /// Per instance, the weights of its model's light parts (the physical light's forest
    /// grid, the `forest` module); `None`: every instance as its model in the open.
    weights: Option<Vec<PartWeights>>,
}

impl ModelGridLight {
    /// `lighting[m]` is model `m`'s LB light (`None`: no indirect light on it); `instances`
    /// as traced.
    pub fn new(
        lighting: Vec<Option<ModelLighting>>,
        models: &[Model],
        instances: &[TraceInstance],
    ) -> ModelGridLight {
        assert_eq!(lighting.len(), models.len(), "one lighting per model");
        let ground_index = if lighting.iter().any(Option::is_some) {
            GroundIndex::new(instances)
        } else {
            GroundIndex::default()
        };
        ModelGridLight {
            lighting,
            model_bounds: models.iter().map(|m| m.bounds).collect(),
            instances: instances.iter().map(|i| (i.model, i.to_model)).collect(),
            ground_index,
            weights: None,
        }
    }

    /// Weighs instance `i`'s light parts by `weights[i]` (models whose grids have parts,
    /// [`ModelLighting::parts`]; others keep their light).
    pub fn with_instance_weights(self, weights: Vec<PartWeights>) -> ModelGridLight {
        assert_eq!(
            weights.len(),
            self.instances.len(),
            "one weight per instance"
        );
        ModelGridLight {
            weights: Some(weights),
            ..self
        }
    }

    /// Model `m`'s grid.
    pub fn model(&self, m: usize) -> Option<&ModelLighting> {
        self.lighting.get(m).and_then(Option::as_ref)
    }
}

impl IndirectLight for ModelGridLight {
    fn plant(&self, instance: u32, placed: &TraceInstance, world: Vec3) -> Option<Vec3> {
        let l = self.lighting[placed.model as usize].as_ref()?;
        let p = placed.to_model.transform_point3(world);
        Some(match &self.weights {
            Some(w) => l.sample_weighted(p, &w[instance as usize]),
            None => l.sample(p),
        })
    }

    /// The product, over the trees whose LB grid covers `point`, of the share of the open
    /// sky's light their grid lets through there ([`ModelLighting::ground_sky`]: 1 in free
    /// space, less in a crown's shade).
    fn ground_sky(&self, point: Vec3) -> Vec3 {
        ground_shade(
            &self.ground_index,
            &self.instances,
            &self.model_bounds,
            point,
            |_, model, pm| Some(self.lighting[model as usize].as_ref()?.ground_sky(pm)),
        )
    }

    fn memory_bytes(&self) -> u64 {
        self.lighting
            .iter()
            .flatten()
            .map(ModelLighting::memory_bytes)
            .sum()
    }

    fn gatherable(&self) -> bool {
        self.lighting
            .iter()
            .flatten()
            .any(ModelLighting::is_physical)
    }

    fn device(&self) -> Result<&dyn DeviceLight, NoDevice> {
        Ok(self)
    }
}

/// The grids as [`ModelGridLight::plant`] and [`ModelGridLight::ground_sky`] read them
/// (shade.wgsl: `lighting_sample`, `parts_sample`, `instance_ground_sky`): the instances'
/// part weights when the forest grid set them, per model its record
/// ([`ModelLighting::pack`]), the ground index.
impl DeviceLight for ModelGridLight {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Grids
    }

    fn pool_words(&self) -> u64 {
        let weighed = self.weights.is_some();
        let grids: u64 = self
            .lighting
            .iter()
            .flatten()
            .map(|g| {
                // The parts (12 words per site) when the forest grid weighs them.
                let parts = if weighed && g.parts().is_some() {
                    12
                } else {
                    0
                };
                (3 + parts) * g.dims().sites() as u64 + LIGHT_HEADER as u64
            })
            .sum();
        let weights = self.weights.as_ref().map_or(0, |w| 12 * w.len() as u64);
        grids + weights + self.ground_index.words()
    }

    fn pack(&self, pool: &mut Vec<u32>) -> PackedLight {
        let mut p = Packer::new(pool);
        // Per instance, the forest grid's weights of its model's light parts (12 words:
        // sun, sky through the top, through the sides, ground; RGB each).
        let mut weights_at = NONE;
        if let Some(w) = &self.weights {
            weights_at = p.at();
            for w in w {
                for v in [w.sun, w.sky_top, w.sky, w.ground] {
                    p.v3(v);
                }
            }
        }
        let records = self
            .lighting
            .iter()
            .zip(&self.model_bounds)
            .map(|(l, &bounds)| {
                l.as_ref()
                    .map_or(NONE, |l| l.pack(&mut p, bounds, weights_at))
            })
            .collect();
        PackedLight {
            records,
            ground: self.ground_index.pack(pool),
        }
    }

    /// Nothing per sun: the grids were solved for it.
    fn sun_words(&self) -> SunWords {
        SunWords {
            words: Vec::new(),
            free_space: 1.0,
        }
    }

    fn sun_capacity(&self) -> usize {
        0
    }
}

/// The fraction of the sky's light reaching ground point `point` under the trees, per
/// colour: the product, over the instances whose box covers it (`index`; `instances` as
/// `(model, world → model)`), of `light(instance, model, model-space point)` (the share their
/// LB light lets through there, free space 1; `None`: no LB light), clamped to [0, 1]. Trees
/// stand on the ground, so a model floating above it shades nothing here; a grid ends at its
/// model's box while its shade on the ground would go on, so the shade fades to open sky
/// over the box's outer 20 %.
pub(crate) fn ground_shade(
    index: &GroundIndex,
    instances: &[(u32, Affine3A)],
    model_bounds: &[Aabb],
    point: Vec3,
    light: impl Fn(usize, u32, Vec3) -> Option<Vec3>,
) -> Vec3 {
    let mut f = Vec3::ONE;
    for &i in index.at(point) {
        let (model, to_model) = &instances[i as usize];
        let b = &model_bounds[*model as usize];
        let pm = to_model.transform_point3(point);
        let margin = 0.05 * (b.max.y - b.min.y) + 1e-3;
        if pm.x >= b.min.x
            && pm.x <= b.max.x
            && pm.z >= b.min.z
            && pm.z <= b.max.z
            && pm.y >= b.min.y - margin
        {
            let Some(lb) = light(i as usize, *model, pm) else {
                continue;
            };
            let edge = (pm.x - b.min.x)
                .min(b.max.x - pm.x)
                .min(pm.z - b.min.z)
                .min(b.max.z - pm.z);
            let width = 0.2 * (b.max.x - b.min.x).min(b.max.z - b.min.z);
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

/// A uniform grid over the ground (x, z) listing the instances whose world box covers each
/// cell: the ground's LB lookup visits a handful of trees, not all of them.
#[derive(Debug, Default)]
pub(crate) struct GroundIndex {
    origin: Vec2,
    end: Vec2,
    inv_cell: f32,
    nx: usize,
    nz: usize,
    /// Per cell, row by row in z, the instances whose box covers it.
    cells: Vec<Vec<u32>>,
}

impl GroundIndex {
    /// At most this many cells a side.
    const MAX_CELLS: usize = 256;

    pub(crate) fn new(instances: &[TraceInstance]) -> GroundIndex {
        let boxes: Vec<_> = instances.iter().map(|i| i.world_bounds).collect();
        if boxes.is_empty() {
            return GroundIndex::default();
        }
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        let mut footprint = 0.0f64;
        for b in &boxes {
            lo = lo.min(Vec2::new(b.min.x, b.min.z));
            hi = hi.max(Vec2::new(b.max.x, b.max.z));
            footprint += (b.max.x - b.min.x).max(b.max.z - b.min.z) as f64;
        }
        let extent = (hi - lo).max_element().max(1e-3);
        // Cells about a tree's width, but not more than MAX_CELLS a side.
        let cell = ((footprint / boxes.len() as f64) as f32).max(extent / Self::MAX_CELLS as f32);
        if !(cell.is_finite() && cell > 0.0) {
            return GroundIndex::default();
        }
        let nx = (((hi.x - lo.x) / cell).floor() as usize + 1).min(Self::MAX_CELLS);
        let nz = (((hi.y - lo.y) / cell).floor() as usize + 1).min(Self::MAX_CELLS);
        let mut index = GroundIndex {
            origin: lo,
            end: hi,
            inv_cell: 1.0 / cell,
            nx,
            nz,
            cells: vec![Vec::new(); nx * nz],
        };
        for (i, b) in boxes.iter().enumerate() {
            let (x0, z0) = index.cell_of(b.min.x, b.min.z);
            let (x1, z1) = index.cell_of(b.max.x, b.max.z);
            for z in z0..=z1 {
                for x in x0..=x1 {
                    index.cells[z * nx + x].push(i as u32);
                }
            }
        }
        index
    }

    /// Words [`GroundIndex::pack`] appends.
    pub(crate) fn words(&self) -> u64 {
        if self.cells.is_empty() {
            return 0;
        }
        (self.cells.len() + 1 + self.cells.iter().map(Vec::len).sum::<usize>()) as u64
    }

    /// Appends the index as shade.wgsl's `ground_sky` reads it: per cell where its list of
    /// instances starts (one more word: where the last ends), then the lists. `None` (nothing
    /// appended) when there is no index.
    pub(crate) fn pack(&self, pool: &mut Vec<u32>) -> Option<DeviceGround> {
        if self.cells.is_empty() {
            return None;
        }
        let starts = pool.len() as u32;
        let lists = starts + self.cells.len() as u32 + 1;
        let mut first = 0u32;
        for c in &self.cells {
            pool.push(first);
            first += c.len() as u32;
        }
        pool.push(first);
        for c in &self.cells {
            pool.extend_from_slice(c);
        }
        Some(DeviceGround {
            starts,
            lists,
            nx: self.nx as u32,
            nz: self.nz as u32,
            bounds: [self.origin.x, self.origin.y, self.end.x, self.end.y],
            inv_cell: self.inv_cell,
        })
    }

    fn cell_of(&self, x: f32, z: f32) -> (usize, usize) {
        let c = |v: f32, o: f32, n: usize| {
            (((v - o) * self.inv_cell).floor().max(0.0) as usize).min(n - 1)
        };
        (c(x, self.origin.x, self.nx), c(z, self.origin.y, self.nz))
    }

    /// Instances whose box may cover ground point `p` (a superset).
    pub(crate) fn at(&self, p: Vec3) -> &[u32] {
        if self.cells.is_empty() {
            return &[];
        }
        let q = Vec2::new(p.x, p.z);
        // Also false for NaN.
        let inside = q.cmpge(self.origin).all() && q.cmple(self.end).all();
        if !inside {
            return &[];
        }
        let (x, z) = self.cell_of(q.x, q.y);
        &self.cells[z * self.nx + x]
    }
}
