//! The "meshes" of 003 §4.2: the small pieces of a tree whose irradiance the models are
//! compared on. Here a mesh is a connected group of leaf triangles (triangles sharing a
//! vertex): one leaf quad of a grown tree; in a model imported without shared vertices, one
//! triangle. Wood is grouped the same way (one stem tube per group); wood groups are surfaces
//! light meets, never compared meshes.
//!
//! Per leaf mesh: its opaque area (the alpha-tested part of its triangles, measured by
//! sampling the texture's opacity on a grid of points in each triangle), its area-weighted
//! centroid, and its triangles, whose normals give the mean `|n·s|` towards any direction.

use glam::Vec3;
use sylva_geom::{MaterialKind, Model};
use sylva_trace::ModelAccel;

/// Sample points per triangle edge for the opaque-area estimate (`n²` points per triangle).
const AREA_SAMPLES_PER_EDGE: usize = 8;

/// One model's triangles grouped into connected pieces; leaf groups come first.
#[derive(Debug, Clone)]
pub struct ModelMeshes {
    /// Group of every triangle: leaf meshes are `0..leaf_count`, wood groups follow.
    pub triangle_group: Vec<u32>,
    /// Number of leaf meshes.
    pub leaf_count: usize,
    /// Number of groups, leaf and wood.
    pub group_count: usize,
    /// Triangles of leaf mesh `m`: `leaf_triangles[leaf_start[m]..leaf_start[m + 1]]`.
    pub leaf_start: Vec<u32>,
    pub leaf_triangles: Vec<u32>,
    /// Opaque area of each triangle of `leaf_triangles`, in the same order (model units²).
    pub triangle_area: Vec<f32>,
    /// Unit normal of each triangle of `leaf_triangles`, model space.
    pub triangle_normal: Vec<Vec3>,
    /// Opaque area of each leaf mesh (model units², one side).
    pub area: Vec<f32>,
    /// Opaque-area-weighted centroid of each leaf mesh, model space.
    pub centroid: Vec<Vec3>,
}

impl ModelMeshes {
    /// Groups `model`'s triangles and measures its leaf meshes; `accel` (built from `model`)
    /// answers the alpha test.
    pub fn new(model: &Model, accel: &ModelAccel) -> ModelMeshes {
        let mesh = &model.mesh;
        let tri_count = mesh.triangle_count();
        let is_leaf = |t: usize| {
            model
                .materials
                .get(mesh.material_ids[t] as usize)
                .is_some_and(|m| m.kind == MaterialKind::Leaf)
        };
        // Union-find over vertices; a triangle joins its three, within one material kind.
        let mut parent: Vec<u32> = (0..mesh.vertex_count() as u32).collect();
        fn find(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                let next = parent[parent[x as usize] as usize];
                parent[x as usize] = next;
                x = next;
            }
            x
        }
        for tri in &mesh.indices {
            let a = find(&mut parent, tri[0]);
            for &v in &tri[1..] {
                let b = find(&mut parent, v);
                if a != b {
                    // Lower root wins: the grouping depends on the mesh only.
                    let (lo, hi) = (a.min(b), a.max(b));
                    parent[hi as usize] = lo;
                }
            }
        }
        // Number groups by first appearance, leaves first.
        let mut root_group = vec![u32::MAX; parent.len()];
        let mut triangle_group = vec![u32::MAX; tri_count];
        let mut next = 0u32;
        let mut leaf_count = 0;
        for pass_leaf in [true, false] {
            for (t, tri) in mesh.indices.iter().enumerate() {
                if is_leaf(t) != pass_leaf {
                    continue;
                }
                let r = find(&mut parent, tri[0]) as usize;
                if root_group[r] == u32::MAX {
                    root_group[r] = next;
                    next += 1;
                }
                triangle_group[t] = root_group[r];
            }
            if pass_leaf {
                leaf_count = next as usize;
                // A vertex shared by a leaf and a wood triangle joins them: the wood pass
                // numbers roots afresh, so such wood triangles get a wood group of their own.
                root_group.iter_mut().for_each(|g| *g = u32::MAX);
            }
        }
        let group_count = next as usize;

        // Leaf triangles by mesh (counting sort keeps triangle order within a mesh).
        let mut leaf_start = vec![0u32; leaf_count + 1];
        for (t, &g) in triangle_group.iter().enumerate() {
            if is_leaf(t) {
                leaf_start[g as usize + 1] += 1;
            }
        }
        for m in 0..leaf_count {
            leaf_start[m + 1] += leaf_start[m];
        }
        let mut fill = leaf_start.clone();
        let mut leaf_triangles = vec![0u32; leaf_start[leaf_count] as usize];
        for (t, &g) in triangle_group.iter().enumerate() {
            if is_leaf(t) {
                leaf_triangles[fill[g as usize] as usize] = t as u32;
                fill[g as usize] += 1;
            }
        }

        let corners =
            |t: u32| mesh.indices[t as usize].map(|i| Vec3::from_array(mesh.positions[i as usize]));
        let mut triangle_area = Vec::with_capacity(leaf_triangles.len());
        let mut triangle_normal = Vec::with_capacity(leaf_triangles.len());
        let mut centroids = Vec::with_capacity(leaf_triangles.len());
        for &t in &leaf_triangles {
            let [a, b, c] = corners(t);
            let cross = (b - a).cross(c - a);
            let area = 0.5 * cross.length();
            let (opaque, centre) = opaque_fraction(accel, t, a, b, c);
            triangle_area.push(area * opaque);
            triangle_normal.push(cross.normalize_or_zero());
            centroids.push(centre);
        }
        let mut area = vec![0.0f32; leaf_count];
        let mut centroid = vec![Vec3::ZERO; leaf_count];
        for m in 0..leaf_count {
            let range = leaf_start[m] as usize..leaf_start[m + 1] as usize;
            let total: f32 = triangle_area[range.clone()].iter().sum();
            area[m] = total;
            centroid[m] = if total > 0.0 {
                range
                    .clone()
                    .map(|k| centroids[k] * triangle_area[k])
                    .sum::<Vec3>()
                    / total
            } else {
                range.clone().map(|k| centroids[k]).sum::<Vec3>() / range.len().max(1) as f32
            };
        }
        ModelMeshes {
            triangle_group,
            leaf_count,
            group_count,
            leaf_start,
            leaf_triangles,
            triangle_area,
            triangle_normal,
            area,
            centroid,
        }
    }

    /// Whether group `g` is a leaf mesh.
    pub fn is_leaf_group(&self, g: u32) -> bool {
        (g as usize) < self.leaf_count
    }

    /// Opaque-area-weighted mean of `|n·dir|` over leaf mesh `m`'s triangles (`dir` in model
    /// space, unit): the projected area towards `dir` per unit of the mesh's area.
    pub fn mean_abs_cos(&self, m: usize, dir: Vec3) -> f32 {
        let range = self.leaf_start[m] as usize..self.leaf_start[m + 1] as usize;
        let (mut sum, mut total) = (0.0f32, 0.0f32);
        for k in range {
            sum += self.triangle_area[k] * self.triangle_normal[k].dot(dir).abs();
            total += self.triangle_area[k];
        }
        if total > 0.0 {
            sum / total
        } else {
            0.0
        }
    }

    /// Leaf meshes with some opaque area (the others can never be hit).
    pub fn visible_leaves(&self) -> usize {
        self.area.iter().filter(|&&a| a > 0.0).count()
    }
}

/// Fraction of triangle `t` that is opaque under the alpha rule, from the centroids of its
/// `n²` congruent sub-triangles, and the centroid of the opaque samples (the triangle's
/// centroid when none is opaque).
fn opaque_fraction(accel: &ModelAccel, t: u32, a: Vec3, b: Vec3, c: Vec3) -> (f32, Vec3) {
    let n = AREA_SAMPLES_PER_EDGE;
    let mut opaque = 0usize;
    let mut centre = Vec3::ZERO;
    let inv = 1.0 / n as f32;
    for i in 0..n {
        for j in 0..n - i {
            // Upright sub-triangle (i, j) and, where it exists, the inverted one beside it.
            let mut samples = [(0.0f32, 0.0f32); 2];
            samples[0] = ((i as f32 + 1.0 / 3.0) * inv, (j as f32 + 1.0 / 3.0) * inv);
            let k = if i + j + 1 < n {
                samples[1] = ((i as f32 + 2.0 / 3.0) * inv, (j as f32 + 2.0 / 3.0) * inv);
                2
            } else {
                1
            };
            for &(u, v) in &samples[..k] {
                if accel.is_opaque_at(t, u, v) {
                    opaque += 1;
                    centre += a * (1.0 - u - v) + b * u + c * v;
                }
            }
        }
    }
    if opaque == 0 {
        return (0.0, (a + b + c) / 3.0);
    }
    (opaque as f32 / (n * n) as f32, centre / opaque as f32)
}

/// The leaf meshes of a whole scene: every instance's copy of its model's meshes, numbered
/// instance after instance (global mesh ids).
#[derive(Debug, Clone)]
pub struct SceneMeshes {
    /// Per unique model.
    pub models: Vec<ModelMeshes>,
    /// Model of each instance.
    pub instance_model: Vec<u32>,
    /// First global mesh id of each instance; one more entry at the end (the total).
    pub instance_offset: Vec<u32>,
}

impl SceneMeshes {
    /// Groups every model of `accel` (its models are `models`, in order).
    pub fn new(models: &[Model], accel: &sylva_trace::SceneAccel) -> SceneMeshes {
        use rayon::prelude::*;
        let per_model: Vec<ModelMeshes> = models
            .par_iter()
            .zip(accel.models().par_iter())
            .map(|(m, a)| ModelMeshes::new(m, a))
            .collect();
        let instance_model: Vec<u32> = accel.instances().iter().map(|i| i.model).collect();
        let mut instance_offset = Vec::with_capacity(instance_model.len() + 1);
        let mut next = 0u32;
        for &m in &instance_model {
            instance_offset.push(next);
            next += per_model[m as usize].leaf_count as u32;
        }
        instance_offset.push(next);
        SceneMeshes {
            models: per_model,
            instance_model,
            instance_offset,
        }
    }

    /// Number of leaf meshes in the scene.
    pub fn total(&self) -> usize {
        *self.instance_offset.last().unwrap_or(&0) as usize
    }

    /// The group of a hit's triangle.
    #[inline]
    pub fn group(&self, instance: u32, triangle: u32) -> u32 {
        self.models[self.instance_model[instance as usize] as usize].triangle_group
            [triangle as usize]
    }

    /// The global leaf mesh id of group `group` of `instance`, `None` for wood.
    #[inline]
    pub fn leaf_id(&self, instance: u32, group: u32) -> Option<u32> {
        let m = &self.models[self.instance_model[instance as usize] as usize];
        m.is_leaf_group(group)
            .then(|| self.instance_offset[instance as usize] + group)
    }

    /// `(instance, mesh within its model)` of global mesh `id`.
    pub fn locate(&self, id: u32) -> (u32, u32) {
        let i = self.instance_offset.partition_point(|&o| o <= id) - 1;
        (i as u32, id - self.instance_offset[i])
    }

    /// The surfaces a line crosses, from its sorted hits ([`sylva_trace::SceneAccel::all_hits`]):
    /// consecutive hits on one group of one instance (the two triangles of a leaf quad, the
    /// two walls of a stem tube) are one crossing. Each crossing is `(instance, group, t)`
    /// with the `t` of its first hit.
    pub fn crossings(&self, hits: &[sylva_trace::Hit], out: &mut Vec<(u32, u32, f32)>) {
        out.clear();
        for h in hits {
            let g = self.group(h.instance, h.triangle);
            if out
                .last()
                .is_some_and(|&(i, last, _)| i == h.instance && last == g)
            {
                continue;
            }
            out.push((h.instance, g, h.t));
        }
    }
}
