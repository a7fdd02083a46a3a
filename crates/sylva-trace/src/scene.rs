//! The two-level structure of a scene: one [`ModelAccel`] per unique model, a top-level SAH
//! kd-tree over the instances' world-space boxes, and the ground plane.
//!
//! A ray reaching an instance in a top-level leaf is carried into model space by the
//! instance's inverse affine transform without renormalising its direction, so `t` is the
//! same number at both levels and hits of different instances compare directly. An instance
//! is tested over the ray's whole remaining interval (not only the leaf's), so one that spans
//! several leaves is tested once per leaf at most and a hit found early is never lost.
//!
//! Instance boxes are tight ([`ModelAccel::world_bounds`]); in a top-level leaf every
//! instance's world box is slab-tested before its transform, and the ones the ray meets are
//! entered nearest first, stopping at the first that starts beyond the closest hit.

use crate::kdtree::{
    lane, packet_compatible, sign_group, BuildRules, Clip, KdTree, TraceStats, TraversalConfig,
    TreeStats, BUILD_RULES, PACKET,
};
use crate::model::{Best, ModelAccel};
use crate::ray::{inverse_dir, ray_box, Hit, Ray};
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;
use sylva_core::cache::{Cache, CacheKey, CacheKind, CacheOutcome};
use sylva_core::container::{read_container, write_container};
use sylva_geom::{Aabb, Instance, Model, Scene};

/// A model's kd-tree in the cache ([`SceneAccel::build_cached`]).
pub const KD_TREE: CacheKind = CacheKind {
    name: "kd-tree",
    version: 1,
};
/// Extension of kd-tree cache entries.
pub const KD_TREE_EXTENSION: &str = "skd";
const KD_MAGIC: &[u8; 8] = b"SYLVAKDT";
const KD_FILE_VERSION: u32 = 1;

/// What a model's kd-tree depends on: its triangles (the mesh's geometry fingerprint and
/// sizes) and the builder's rules.
#[derive(Debug, Clone, PartialEq, Serialize)]
struct KdTreeKey {
    rules: BuildRules,
    geometry: u64,
    vertices: usize,
    triangles: usize,
}

/// What [`SceneAccel::build_cached`] did with the models' trees.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TreeCacheReport {
    /// Trees read from the cache.
    pub cached: usize,
    /// Trees built (no cache, no entry, or a bad one).
    pub built: usize,
    /// Why an entry could not be used (it was built again) or kept, naming the file.
    pub warnings: Vec<String>,
}

/// The cache entry of `model`'s kd-tree under `key`.
fn kd_tree_path(cache: &Cache, model: &Model, key: CacheKey) -> std::path::PathBuf {
    cache.entry(
        &format!("{}-kdtree", sylva_core::file_stem(&model.name, "model")),
        key,
        KD_TREE_EXTENSION,
    )
}

/// `model`'s tree from `cache` when a valid entry holds it, else built and stored; whether
/// it was read, and any warning.
fn cached_tree(model: &Model, cache: &Cache) -> (KdTree, bool, Vec<String>) {
    let mesh = &model.mesh;
    let key = CacheKey::new(
        KD_TREE,
        &KdTreeKey {
            rules: BUILD_RULES,
            geometry: mesh.geometry_hash(),
            vertices: mesh.positions.len(),
            triangles: mesh.indices.len(),
        },
    );
    let path = kd_tree_path(cache, model, key);
    let read = |p: &Path| {
        let c = read_container(p, KD_MAGIC, KD_FILE_VERSION, "kd-tree cache entry")
            .map_err(|e| e.to_string())?;
        key.check(p, c.metadata_value(sylva_core::cache::KEY_METADATA))?;
        KdTree::from_bytes(&c.payload, mesh.indices.len())
            .map_err(|e| format!("{}: {e}", p.display()))
    };
    let got = cache
        .get_or_compute(
            &path,
            read,
            || Ok::<_, std::convert::Infallible>(ModelAccel::build_tree(model)),
            |tree, p| {
                write_container(
                    p,
                    KD_MAGIC,
                    KD_FILE_VERSION,
                    &[key.metadata()],
                    &tree.to_bytes(),
                )
                .map_err(|e| e.to_string())
            },
        )
        .unwrap_or_else(|never| match never {});
    let warnings = got.warning("kd-tree built again").into_iter().collect();
    (got.value, got.outcome == CacheOutcome::Hit, warnings)
}

#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    #[error("instance {instance} refers to model {model}, but the scene has {models} models")]
    BadModel {
        instance: usize,
        model: u32,
        models: usize,
    },
    #[error("instance {instance}: transform is not invertible or not finite (scale {scale}, position {position:?})")]
    BadTransform {
        instance: usize,
        scale: f32,
        position: [f32; 3],
    },
    #[error("model '{name}': {triangles} triangles exceed the kd-tree's limit of 2^30")]
    TooLarge { name: String, triangles: usize },
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("camera: {0}")]
    Camera(String),
}

/// The last few instances a ray (or which lanes of a packet) was tested against: instances
/// span several top-level leaves, and kd-restarts revisit leaves. A single ray is lane 0.
struct Mailbox {
    ids: [u32; MAILBOX],
    lanes: [u32; MAILBOX],
    next: usize,
}

/// Entries of a [`Mailbox`]: a ray meets more parts than instances.
const MAILBOX: usize = 16;

impl Mailbox {
    fn new() -> Mailbox {
        Mailbox {
            ids: [u32::MAX; MAILBOX],
            lanes: [0; MAILBOX],
            next: 0,
        }
    }

    /// The lanes that have tested instance `id`.
    #[inline(always)]
    fn tested(&self, id: u32) -> u32 {
        (0..MAILBOX).fold(0, |m, k| {
            if self.ids[k] == id {
                m | self.lanes[k]
            } else {
                m
            }
        })
    }

    /// Records that `lanes` have tested instance `id`.
    #[inline(always)]
    fn insert(&mut self, id: u32, lanes: u32) {
        if let Some(k) = self.ids.iter().position(|&x| x == id) {
            self.lanes[k] |= lanes;
            return;
        }
        self.ids[self.next] = id;
        self.lanes[self.next] = lanes;
        self.next = (self.next + 1) % MAILBOX;
    }

    /// For a single ray: records `id`, `false` when it was seen recently.
    #[inline(always)]
    fn first_visit(&mut self, id: u32) -> bool {
        if self.ids.contains(&id) {
            return false;
        }
        self.insert(id, 1);
        true
    }
}

/// The last few occluders `(instance, triangle)` that shadow rays met: keep one per run of
/// neighbouring rays (a tile), pass it to [`SceneAccel::any_hit_cached`].
#[derive(Debug, Clone)]
pub struct OccluderCache {
    entries: [(u32, u32); OccluderCache::SIZE],
    next: usize,
}

impl OccluderCache {
    const SIZE: usize = 4;

    pub fn new() -> OccluderCache {
        OccluderCache {
            entries: [(u32::MAX, 0); OccluderCache::SIZE],
            next: 0,
        }
    }

    fn remember(&mut self, e: (u32, u32)) {
        self.entries[self.next] = e;
        self.next = (self.next + 1) % OccluderCache::SIZE;
    }
}

impl Default for OccluderCache {
    fn default() -> Self {
        OccluderCache::new()
    }
}

/// Instances of one top-level leaf that closest-hit queries order by entry distance (more
/// are entered in leaf order first).
pub const SORTED_INSTANCES: usize = 16;

/// An instance as the tracer sees it.
#[derive(Debug, Clone, Copy)]
pub struct TraceInstance {
    pub model: u32,
    pub to_world: Affine3A,
    pub to_model: Affine3A,
    pub world_bounds: Aabb,
}

/// Bytes held by a [`SceneAccel`], by part.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AccelMemory {
    /// Model kd-trees, triangle data and alpha data (all models).
    pub models: u64,
    /// Top-level tree and instance records.
    pub top: u64,
}

impl AccelMemory {
    pub fn total(&self) -> u64 {
        self.models + self.top
    }
}

/// A scene ready for ray queries.
#[derive(Debug, Clone)]
pub struct SceneAccel {
    models: Vec<ModelAccel>,
    instances: Vec<TraceInstance>,
    /// The instances' world boxes again, packed (24 B each, the whole scene's fit in L1/L2):
    /// every instance in a top-level leaf is tested against its box before its transform.
    boxes: Vec<[Vec3; 2]>,
    top: KdTree,
    /// Every instance's parts ([`ModelAccel::parts`]) as `[instance, part]`, their world
    /// boxes, and a kd-tree over those boxes: closest-hit queries enter the model trees
    /// part by part, nearest first, so a ray through a crowd of overlapping crown boxes
    /// skips their empty parts and stops at the first part beyond its hit.
    parts: Vec<[u32; 2]>,
    part_boxes: Vec<[Vec3; 2]>,
    part_top: KdTree,
    /// Half extents (x, z) of the ground rectangle on y = 0, when there is one.
    ground: Option<[f32; 2]>,
}

/// World boxes (of instances, of parts) for the top-level builder.
struct BoxClip<'a>(&'a [[Vec3; 2]]);

impl Clip for BoxClip<'_> {
    fn count(&self) -> usize {
        self.0.len()
    }

    fn bounds(&self, i: usize) -> Option<Aabb> {
        let [min, max] = self.0[i];
        let b = Aabb { min, max };
        (!b.is_empty()).then_some(b)
    }

    fn clip(&self, i: usize, bx: &Aabb) -> Option<Aabb> {
        let [min, max] = self.0[i];
        let b = Aabb { min, max };
        let c = Aabb {
            min: b.min.max(bx.min),
            max: b.max.min(bx.max),
        };
        (!c.is_empty()).then_some(c)
    }
}

/// World box of a part whose model-space box is `b`: its transformed corners, widened for
/// the rounding of the transform as [`ModelAccel::world_bounds`] is, within the instance's
/// box; `None` when empty.
fn part_world_box(b: &Aabb, to_world: &Affine3A, instance: &Aabb) -> Option<[Vec3; 2]> {
    let mut w = Aabb::EMPTY;
    for c in b.corners() {
        w.grow(to_world.transform_point3(c));
    }
    let mag = w.min.abs().max(w.max.abs()).max_element();
    let slack = 4e-7 * mag;
    let min = (w.min - Vec3::splat(slack)).max(instance.min);
    let max = (w.max + Vec3::splat(slack)).min(instance.max);
    (min.cmple(max).all()).then_some([min, max])
}

/// Bytes a model's structure will take, roughly (for the memory check).
fn estimate_bytes(triangles: usize) -> u64 {
    // Triangle data 40 B, ~2 references of 4 B, ~1 node of 8 B per triangle, build scratch.
    triangles as u64 * (40 + 8 + 8 + 2 * 28)
}

/// Refuses models the trees cannot index and a scene whose trees would not fit in memory.
fn check_models(models: &[Model]) -> Result<(), TraceError> {
    for m in models {
        if m.triangle_count() >= 1 << 30 {
            return Err(TraceError::TooLarge {
                name: m.name.clone(),
                triangles: m.triangle_count(),
            });
        }
    }
    let total: usize = models.iter().map(Model::triangle_count).sum();
    sylva_core::check_memory("kd-trees of the scene's models", estimate_bytes(total))?;
    Ok(())
}

impl SceneAccel {
    /// Builds the scene's structures: the models in parallel, then the top level.
    pub fn build(scene: &Scene) -> Result<SceneAccel, TraceError> {
        SceneAccel::from_parts(&scene.models, &scene.instances, scene.ground_half_extents())
    }

    /// Builds from models and instances; `ground` is the half extents (x, z) of a ground
    /// rectangle on y = 0 centred on the origin.
    pub fn from_parts(
        models: &[Model],
        instances: &[Instance],
        ground: Option<[f32; 2]>,
    ) -> Result<SceneAccel, TraceError> {
        check_models(models)?;
        let built: Vec<ModelAccel> = models.par_iter().map(ModelAccel::build).collect();
        SceneAccel::around(built, instances, ground)
    }

    /// [`SceneAccel::build`], each model's kd-tree read from `cache` when it holds one for
    /// the same triangles and builder (else built and stored there); what it did.
    pub fn build_cached(
        scene: &Scene,
        cache: Option<&Cache>,
    ) -> Result<(SceneAccel, TreeCacheReport), TraceError> {
        SceneAccel::from_parts_cached(
            &scene.models,
            &scene.instances,
            scene.ground_half_extents(),
            cache,
        )
    }

    /// [`SceneAccel::from_parts`] with the models' kd-trees cached as
    /// [`SceneAccel::build_cached`] caches them.
    pub fn from_parts_cached(
        models: &[Model],
        instances: &[Instance],
        ground: Option<[f32; 2]>,
        cache: Option<&Cache>,
    ) -> Result<(SceneAccel, TreeCacheReport), TraceError> {
        let Some(cache) = cache else {
            let accel = SceneAccel::from_parts(models, instances, ground)?;
            let report = TreeCacheReport {
                built: models.len(),
                ..TreeCacheReport::default()
            };
            return Ok((accel, report));
        };
        check_models(models)?;
        let trees: Vec<(KdTree, bool, Vec<String>)> =
            models.par_iter().map(|m| cached_tree(m, cache)).collect();
        let mut report = TreeCacheReport::default();
        let mut built = Vec::with_capacity(trees.len());
        for (m, (tree, hit, warnings)) in models.iter().zip(trees) {
            match hit {
                true => report.cached += 1,
                false => report.built += 1,
            }
            report.warnings.extend(warnings);
            built.push(ModelAccel::with_tree(m, tree));
        }
        let accel = SceneAccel::around(built, instances, ground)?;
        Ok((accel, report))
    }

    /// The scene around its models' built structures.
    fn around(
        built: Vec<ModelAccel>,
        instances: &[Instance],
        ground: Option<[f32; 2]>,
    ) -> Result<SceneAccel, TraceError> {
        let models = built.len();
        let mut inst = Vec::with_capacity(instances.len());
        for (k, i) in instances.iter().enumerate() {
            let Some(m) = built.get(i.model as usize) else {
                return Err(TraceError::BadModel {
                    instance: k,
                    model: i.model,
                    models,
                });
            };
            let to_world = i.transform();
            let to_model = to_world.inverse();
            let finite = to_world.matrix3.is_finite()
                && to_world.translation.is_finite()
                && to_model.matrix3.is_finite()
                && to_model.translation.is_finite()
                && i.scale > 0.0;
            if !finite {
                return Err(TraceError::BadTransform {
                    instance: k,
                    scale: i.scale,
                    position: i.position.to_array(),
                });
            }
            inst.push(TraceInstance {
                model: i.model,
                to_world,
                to_model,
                world_bounds: m.world_bounds(&to_world),
            });
        }
        let boxes: Vec<[Vec3; 2]> = inst
            .iter()
            .map(|i| [i.world_bounds.min, i.world_bounds.max])
            .collect();
        let top = KdTree::build(&BoxClip(&boxes));
        let (parts, part_boxes): (Vec<[u32; 2]>, Vec<[Vec3; 2]>) = inst
            .iter()
            .enumerate()
            .flat_map(|(k, i)| {
                let model = &built[i.model as usize];
                model
                    .parts()
                    .iter()
                    .enumerate()
                    .filter_map(move |(p, part)| {
                        let b = part_world_box(&part.bounds, &i.to_world, &i.world_bounds)?;
                        Some(([k as u32, p as u32], b))
                    })
            })
            .unzip();
        let part_top = KdTree::build(&BoxClip(&part_boxes));
        Ok(SceneAccel {
            models: built,
            instances: inst,
            boxes,
            top,
            parts,
            part_boxes,
            part_top,
            ground,
        })
    }

    pub fn models(&self) -> &[ModelAccel] {
        &self.models
    }

    pub fn instances(&self) -> &[TraceInstance] {
        &self.instances
    }

    pub fn top_stats(&self) -> TreeStats {
        self.top.stats()
    }

    /// The top-level tree: its leaves hold instance ids.
    pub fn top_tree(&self) -> &KdTree {
        &self.top
    }

    pub fn ground(&self) -> Option<[f32; 2]> {
        self.ground
    }

    pub fn memory(&self) -> AccelMemory {
        AccelMemory {
            models: self.models.iter().map(ModelAccel::memory_bytes).sum(),
            top: self.top.memory_bytes()
                + self.part_top.memory_bytes()
                + (self.instances.capacity() * std::mem::size_of::<TraceInstance>()
                    + (self.boxes.capacity() + self.part_boxes.capacity())
                        * std::mem::size_of::<[Vec3; 2]>()
                    + self.parts.capacity() * std::mem::size_of::<[u32; 2]>())
                    as u64,
        }
    }

    /// `t` where the ray meets the ground rectangle with `t_min < t ≤ ray.t_max`.
    pub fn ground_hit(&self, ray: &Ray) -> Option<f32> {
        self.ground_t(ray, ray.t_max)
    }

    fn ground_t(&self, ray: &Ray, t_max: f32) -> Option<f32> {
        let [hx, hz] = self.ground?;
        if ray.dir.y == 0.0 {
            return None;
        }
        let t = -ray.origin.y / ray.dir.y;
        let p = ray.at(t);
        (t > ray.t_min && t <= t_max && p.x.abs() <= hx && p.z.abs() <= hz).then_some(t)
    }

    /// The closest hit with `t_min < t ≤ t_max` (ties: lowest instance, then triangle; the
    /// ground loses ties), or `None`. Invalid rays (see [`Ray::is_valid`]) hit nothing.
    pub fn closest_hit(
        &self,
        ray: &Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) -> Option<Hit> {
        stats.rays += 1;
        if !ray.is_valid() {
            return None;
        }
        let mut best = self.ground_best(ray);
        let (o, d) = (ray.origin, ray.dir);
        let inv_d = inverse_dir(d);
        let mut visits = 0u64;
        let mut mailbox = Mailbox::new();
        let mut inner = TraceStats::default();
        self.part_top
            .traverse(o, inv_d, ray.t_min, best.t, cfg, stats, |prims| {
                let mut enter = |k: u32, best: &mut Best| {
                    // A part met in an earlier leaf was already tested over the whole
                    // interval.
                    if !mailbox.first_visit(k) {
                        return;
                    }
                    visits += 1;
                    let [i, part] = self.parts[k as usize];
                    let inst = &self.instances[i as usize];
                    let mo = inst.to_model.transform_point3(o);
                    let md = inst.to_model.transform_vector3(d);
                    let model = &self.models[inst.model as usize];
                    let part = &model.parts()[part as usize];
                    model.closest_in(part, mo, md, ray.t_min, i, best, cfg, &mut inner);
                };
                // Only parts whose box the ray meets before the closest hit (the leaf's
                // region is larger than the ray's path through a box), nearest entry first:
                // a near part's hit then cuts the far ones' traversals short or skips them.
                let mut cand = [(0f32, 0u32); SORTED_INSTANCES];
                let t_max = best.t;
                let n = self.entries(
                    &self.part_boxes,
                    prims,
                    o,
                    inv_d,
                    ray.t_min,
                    t_max,
                    &mut cand,
                    |k| enter(k, &mut best),
                );
                for &(t0, i) in &cand[..n] {
                    // Equal entry still enters: a hit at exactly `best.t` may win the tie.
                    if t0 > best.t {
                        break;
                    }
                    enter(i, &mut best);
                }
                best.t
            });
        *stats += inner;
        stats.instance_visits += visits;
        best.hit()
    }

    /// The closest candidate before any instance is tested: the ground hit, or nothing up
    /// to `ray.t_max`.
    fn ground_best(&self, ray: &Ray) -> Best {
        match self.ground_t(ray, ray.t_max) {
            Some(t) => {
                let p = ray.at(t);
                Best {
                    t,
                    instance: Hit::GROUND,
                    triangle: 0,
                    u: p.x,
                    v: p.z,
                }
            }
            None => Best::nothing(ray.t_max),
        }
    }

    /// [`SceneAccel::closest_hit`] for up to [`PACKET`] rays at once (the lanes set in
    /// `mask`; the others give `None`). Rays from one point in nearly the same direction
    /// (the samples of a pixel, neighbouring pixels) share their walk through both tree
    /// levels; every lane's hit is exactly the one `closest_hit` finds for it alone. Rays
    /// whose direction signs differ are split into groups that agree.
    pub fn closest_hit_packet(
        &self,
        rays: &[Ray; PACKET],
        mask: u32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) -> [Option<Hit>; PACKET] {
        let mut out = [None; PACKET];
        let mut valid = 0u32;
        for (l, ray) in rays.iter().enumerate() {
            if mask >> l & 1 == 1 && ray.is_valid() {
                valid |= 1 << l;
            }
        }
        let mut o = [[0f32; PACKET]; 3];
        let mut inv = [[0f32; PACKET]; 3];
        for (l, ray) in rays.iter().enumerate() {
            let i = inverse_dir(ray.dir);
            for k in 0..3 {
                o[k][l] = ray.origin[k];
                inv[k][l] = i[k];
            }
        }
        if !packet_compatible(&inv, valid) {
            for (l, ray) in rays.iter().enumerate() {
                if mask >> l & 1 == 1 {
                    out[l] = self.closest_hit(ray, cfg, stats);
                }
            }
            return out;
        }
        stats.rays += mask.count_ones() as u64;
        // Invalid lanes are not traversed; their entries only fill the arrays.
        let mut best = rays.map(|ray| self.ground_best(&ray));
        let t_min = rays.map(|ray| ray.t_min);
        let t_max = best.map(|b| b.t);
        let mut visits = 0u64;
        let mut mailbox = Mailbox::new();
        let mut inner = TraceStats::default();
        self.part_top.traverse_packet(
            &o,
            &inv,
            &t_min,
            &t_max,
            valid,
            cfg,
            stats,
            |prims, lanes, _, _| {
                // (first entry over the lanes, part, lanes, each lane's entry)
                let mut cand = [(0f32, 0u32, 0u32, [0f32; PACKET]); SORTED_INSTANCES];
                let mut n = 0;
                for &i in prims {
                    let [bmin, bmax] = self.part_boxes[i as usize];
                    let mut entry = [f32::INFINITY; PACKET];
                    let mut meet = 0u32;
                    for l in 0..PACKET {
                        if lanes >> l & 1 == 0 {
                            continue;
                        }
                        let (ol, il) = (lane(&o, l), lane(&inv, l));
                        if let Some((t0, _)) = ray_box(ol, il, bmin, bmax, t_min[l], best[l].t) {
                            entry[l] = t0;
                            meet |= 1 << l;
                        }
                    }
                    // An instance a lane met in an earlier leaf was already tested over its
                    // whole interval.
                    meet &= !mailbox.tested(i);
                    if meet == 0 {
                        continue;
                    }
                    if n < SORTED_INSTANCES {
                        let first = entry.iter().copied().fold(f32::INFINITY, f32::min);
                        cand[n] = (first, i, meet, entry);
                        n += 1;
                    } else {
                        visits += 1;
                        mailbox.insert(i, meet);
                        self.enter_packet(i, rays, &t_min, meet, &mut best, cfg, &mut inner);
                    }
                }
                cand[..n].sort_by(|a, b| a.0.total_cmp(&b.0));
                for (_, i, meet, entry) in &cand[..n] {
                    // Equal entry still enters: a hit at exactly `best.t` may win the tie.
                    let mut go = 0u32;
                    for l in 0..PACKET {
                        if meet >> l & 1 == 1 && entry[l] <= best[l].t {
                            go |= 1 << l;
                        }
                    }
                    if go == 0 {
                        continue;
                    }
                    visits += 1;
                    mailbox.insert(*i, go);
                    self.enter_packet(*i, rays, &t_min, go, &mut best, cfg, &mut inner);
                }
                best.map(|b| b.t)
            },
        );
        *stats += inner;
        stats.instance_visits += visits;
        for l in 0..PACKET {
            if valid >> l & 1 == 1 {
                out[l] = best[l].hit();
            }
        }
        out
    }

    /// Tests part `k` (of [`SceneAccel::parts`]) for the lanes `lanes` of a packet, in model space, grouping the
    /// lanes by the signs of their model-space directions (a rotation can separate them).
    #[allow(clippy::too_many_arguments)] // the hot path
    #[allow(clippy::needless_range_loop)] // lanes index several parallel arrays
    fn enter_packet(
        &self,
        k: u32,
        rays: &[Ray; PACKET],
        t_min: &[f32; PACKET],
        lanes: u32,
        best: &mut [Best; PACKET],
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) {
        let [i, part] = self.parts[k as usize];
        let inst = &self.instances[i as usize];
        let model = &self.models[inst.model as usize];
        let part = &model.parts()[part as usize];
        let mut mo = [[0f32; PACKET]; 3];
        let mut md = [[0f32; PACKET]; 3];
        let mut inv = [[0f32; PACKET]; 3];
        let mut group = [0u32; PACKET]; // sign pattern of each lane, 8 = not finite
        for l in 0..PACKET {
            if lanes >> l & 1 == 0 {
                continue;
            }
            // The same arithmetic as `closest_hit`.
            let o = inst.to_model.transform_point3(rays[l].origin);
            let d = inst.to_model.transform_vector3(rays[l].dir);
            let iv = inverse_dir(d);
            for k in 0..3 {
                mo[k][l] = o[k];
                md[k][l] = d[k];
                inv[k][l] = iv[k];
            }
            group[l] = sign_group(iv);
        }
        let mut left = lanes;
        while left != 0 {
            let lead = left.trailing_zeros() as usize;
            let g = group[lead];
            if g == 8 {
                left &= !(1 << lead);
                model.closest_in(
                    part,
                    lane(&mo, lead),
                    lane(&md, lead),
                    t_min[lead],
                    i,
                    &mut best[lead],
                    cfg,
                    stats,
                );
                continue;
            }
            let mut m = 0u32;
            for l in 0..PACKET {
                if left >> l & 1 == 1 && group[l] == g {
                    m |= 1 << l;
                }
            }
            left &= !m;
            model.closest_packet(part, &mo, &md, &inv, t_min, m, i, best, cfg, stats);
        }
    }

    /// Whether anything opaque lies on the ray with `t_min < t ≤ t_max` (shadow rays).
    pub fn any_hit(&self, ray: &Ray, cfg: TraversalConfig, stats: &mut TraceStats) -> bool {
        self.any_hit_cached(ray, cfg, stats, &mut OccluderCache::new())
    }

    /// [`SceneAccel::any_hit`], trying the occluders in `cache` first and remembering the
    /// one a traversal finds. Neighbouring shadow rays (parallel, a pixel apart) are often
    /// stopped by the same leaf; a cached triangle that stops this ray is an exact answer,
    /// because any opaque hit in the interval means "shadowed". The result never depends
    /// on what the cache holds; only the work does.
    pub fn any_hit_cached(
        &self,
        ray: &Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> bool {
        self.any_hit_from(ray, None, cfg, stats, cache)
    }

    /// [`SceneAccel::any_hit_cached`] for a ray that starts on instance `from` (a shadow
    /// ray from a surface point): that instance is tested first, then the others in the
    /// usual order. In a forest the boxes of neighbouring trees overlap, so a shadow ray
    /// often starts inside several boxes at once, and nearest-box-first order can then
    /// enter a neighbour before the tree the ray starts in, which is the likeliest
    /// occluder. The answer does not depend on `from` (any opaque hit means "shadowed");
    /// only the work does. An id out of range is ignored.
    pub fn any_hit_from(
        &self,
        ray: &Ray,
        from: Option<u32>,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> bool {
        stats.rays += 1;
        if !ray.is_valid() {
            return false;
        }
        if self.ground_t(ray, ray.t_max).is_some() || self.cached_occluder(ray, stats, cache) {
            return true;
        }

        let (o, d) = (ray.origin, ray.dir);
        let inv_d = inverse_dir(d);
        let mut found = None;
        let mut visits = 0u64;
        let mut mailbox = Mailbox::new();
        let mut inner = TraceStats::default();
        // The instance the ray starts on first (the mailbox then skips it below).
        if let Some(i) = from.filter(|&i| (i as usize) < self.instances.len()) {
            mailbox.insert(i, 1);
            visits += 1;
            found = self.instance_any_hit(i, ray, cfg, &mut inner);
        }
        if found.is_none() {
            self.top
                .traverse(o, inv_d, ray.t_min, ray.t_max, cfg, stats, |prims| {
                    let mut enter = |i: u32| {
                        if found.is_some() || !mailbox.first_visit(i) {
                            return;
                        }
                        visits += 1;
                        found = self.instance_any_hit(i, ray, cfg, &mut inner);
                    };
                    // Nearest box first: of the trees not yet tested, the ones the ray
                    // starts in or meets soonest.
                    let mut cand = [(0f32, 0u32); SORTED_INSTANCES];
                    let n = self.entries(
                        &self.boxes,
                        prims,
                        o,
                        inv_d,
                        ray.t_min,
                        ray.t_max,
                        &mut cand,
                        &mut enter,
                    );
                    for &(_, i) in &cand[..n] {
                        enter(i);
                    }
                    if found.is_some() {
                        f32::NEG_INFINITY
                    } else {
                        f32::INFINITY
                    }
                });
        }
        *stats += inner;
        stats.instance_visits += visits;
        if let Some(e) = found {
            cache.remember(e);
        }
        found.is_some()
    }

    /// [`SceneAccel::any_hit_from`] with the instances a ray may meet given by a caller
    /// (`candidates`: a superset, such as the sun grid's tile of the ray's origin,
    /// `crate::sun_grid::SunGrid::any_hit`) instead of the top-level tree; they are entered in
    /// the same order with the same tests, so the answer is the same. `None` takes the kd
    /// path.
    pub fn any_hit_among(
        &self,
        candidates: Option<&[u32]>,
        ray: &Ray,
        from: Option<u32>,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> bool {
        let Some(candidates) = candidates else {
            return self.any_hit_from(ray, from, cfg, stats, cache);
        };
        stats.rays += 1;
        if !ray.is_valid() {
            return false;
        }
        if self.ground_t(ray, ray.t_max).is_some() || self.cached_occluder(ray, stats, cache) {
            return true;
        }
        let (o, d) = (ray.origin, ray.dir);
        let inv_d = inverse_dir(d);
        let mut found = None;
        let mut visits = 0u64;
        let mut inner = TraceStats::default();
        let first = from.filter(|&i| (i as usize) < self.instances.len());
        if let Some(i) = first {
            visits += 1;
            found = self.instance_any_hit(i, ray, cfg, &mut inner);
        }
        if found.is_none() {
            let mut enter = |i: u32| {
                if found.is_some() || Some(i) == first {
                    return;
                }
                visits += 1;
                found = self.instance_any_hit(i, ray, cfg, &mut inner);
            };
            let mut cand = [(0f32, 0u32); SORTED_INSTANCES];
            let n = self.entries(
                &self.boxes,
                candidates,
                o,
                inv_d,
                ray.t_min,
                ray.t_max,
                &mut cand,
                &mut enter,
            );
            for &(_, i) in &cand[..n] {
                enter(i);
            }
        }
        *stats += inner;
        stats.instance_visits += visits;
        if let Some(e) = found {
            cache.remember(e);
        }
        found.is_some()
    }

    /// The first opaque hit `(instance, triangle)` of the world-space ray on instance `i`,
    /// over the ray's whole segment.
    #[inline(always)]
    fn instance_any_hit(
        &self,
        i: u32,
        ray: &Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) -> Option<(u32, u32)> {
        let inst = &self.instances[i as usize];
        let mo = inst.to_model.transform_point3(ray.origin);
        let md = inst.to_model.transform_vector3(ray.dir);
        self.models[inst.model as usize]
            .any(mo, md, ray.t_min, ray.t_max, cfg, stats)
            .map(|tri| (i, tri))
    }

    /// Whether one of the cached occluders stops the (valid) ray.
    fn cached_occluder(&self, ray: &Ray, stats: &mut TraceStats, cache: &OccluderCache) -> bool {
        let (o, d) = (ray.origin, ray.dir);
        for k in 0..OccluderCache::SIZE {
            // Most recent first.
            let (i, tri) =
                cache.entries[(cache.next + OccluderCache::SIZE - 1 - k) % OccluderCache::SIZE];
            let Some(inst) = self.instances.get(i as usize) else {
                continue;
            };
            let mo = inst.to_model.transform_point3(o);
            let md = inst.to_model.transform_vector3(d);
            if self.models[inst.model as usize].occludes(mo, md, ray.t_min, ray.t_max, tri) {
                stats.occluder_cache_hits += 1;
                return true;
            }
        }
        false
    }

    /// The instances (or parts, with their `boxes`) of a top-level leaf whose world box the
    /// ray meets within
    /// `[t_min, t_max]`: the first [`SORTED_INSTANCES`] go into `cand` as `(entry t, id)`,
    /// sorted by entry (stable, so ties keep leaf order); any further ones are handed to
    /// `overflow` at once. Returns how many went into `cand`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hot path, called per top-level leaf
    fn entries(
        &self,
        boxes: &[[Vec3; 2]],
        prims: &[u32],
        o: Vec3,
        inv_d: Vec3,
        t_min: f32,
        t_max: f32,
        cand: &mut [(f32, u32); SORTED_INSTANCES],
        mut overflow: impl FnMut(u32),
    ) -> usize {
        let mut n = 0;
        for &i in prims {
            let [bmin, bmax] = boxes[i as usize];
            let Some((t0, _)) = ray_box(o, inv_d, bmin, bmax, t_min, t_max) else {
                continue;
            };
            if n < SORTED_INSTANCES {
                cand[n] = (t0, i);
                n += 1;
            } else {
                overflow(i);
            }
        }
        // Insertion sort: leaves hold a handful of instances.
        for k in 1..n {
            let x = cand[k];
            let mut j = k;
            while j > 0 && cand[j - 1].0 > x.0 {
                cand[j] = cand[j - 1];
                j -= 1;
            }
            cand[j] = x;
        }
        n
    }

    /// Every opaque hit on the instances (the ground excluded) with `t_min < t ≤ t_max`,
    /// sorted by `(t, instance, triangle)`, each triangle of each instance once, into `out`
    /// (cleared first). For counting the surfaces a line crosses (paper 003 eq. 29, deep
    /// opacity maps); invalid rays hit nothing.
    pub fn all_hits(
        &self,
        ray: &Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        out: &mut Vec<Hit>,
    ) {
        out.clear();
        stats.rays += 1;
        if !ray.is_valid() {
            return;
        }
        let (o, d) = (ray.origin, ray.dir);
        let inv_d = inverse_dir(d);
        let mut visited: Vec<u32> = Vec::new();
        let mut inner = TraceStats::default();
        self.top
            .traverse(o, inv_d, ray.t_min, ray.t_max, cfg, stats, |prims| {
                for &i in prims {
                    let [bmin, bmax] = self.boxes[i as usize];
                    if ray_box(o, inv_d, bmin, bmax, ray.t_min, ray.t_max).is_none()
                        || visited.contains(&i)
                    {
                        continue;
                    }
                    visited.push(i);
                    let inst = &self.instances[i as usize];
                    let mo = inst.to_model.transform_point3(o);
                    let md = inst.to_model.transform_vector3(d);
                    self.models[inst.model as usize]
                        .all(mo, md, ray.t_min, ray.t_max, i, cfg, &mut inner, out);
                }
                f32::INFINITY
            });
        *stats += inner;
        stats.instance_visits += visited.len() as u64;
        out.sort_unstable_by(|a, b| {
            (a.t, a.instance, a.triangle)
                .partial_cmp(&(b.t, b.instance, b.triangle))
                .expect("finite t")
        });
    }

    /// Reference closest hit: every triangle of every instance, in model space with the same
    /// arithmetic as the trees (so results are bit-identical), same tie rule.
    pub fn brute_closest_hit(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let mut best = self.ground_t(ray, ray.t_max).map(|t| {
            let p = ray.at(t);
            Hit {
                t,
                instance: Hit::GROUND,
                triangle: 0,
                u: p.x,
                v: p.z,
            }
        });
        for (k, inst) in self.instances.iter().enumerate() {
            let local = Ray {
                origin: inst.to_model.transform_point3(ray.origin),
                dir: inst.to_model.transform_vector3(ray.dir),
                ..*ray
            };
            if let Some(mut h) = self.models[inst.model as usize].brute_closest_hit(&local) {
                h.instance = k as u32;
                if best.is_none_or(|b| h.precedes(&b)) {
                    best = Some(h);
                }
            }
        }
        best
    }

    /// Reference any-hit: every triangle of every instance.
    pub fn brute_any_hit(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        self.ground_t(ray, ray.t_max).is_some()
            || self.instances.iter().any(|inst| {
                let local = Ray {
                    origin: inst.to_model.transform_point3(ray.origin),
                    dir: inst.to_model.transform_vector3(ray.dir),
                    ..*ray
                };
                self.models[inst.model as usize].brute_any_hit(&local)
            })
    }

    /// World-space geometric normal of a hit's triangle (unnormalised sign follows the
    /// triangle's winding), for offsetting secondary rays. `Vec3::Y` for the ground.
    pub fn geometric_normal(&self, hit: &Hit) -> Vec3 {
        if hit.is_ground() {
            return Vec3::Y;
        }
        let inst = &self.instances[hit.instance as usize];
        let n = self.models[inst.model as usize].triangle_normal(hit.triangle);
        // Normals transform by the inverse transpose; for rotation + uniform scale that is
        // the rotation itself.
        inst.to_world.transform_vector3(n).normalize_or_zero()
    }
}
