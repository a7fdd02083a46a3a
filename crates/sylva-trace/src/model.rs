//! One model's acceleration structure: its SAH kd-tree over triangles, precomputed
//! Möller-Trumbore data, and what the alpha test needs (per-triangle texture coordinates and
//! an opacity bitmask per leaf texture).
//!
//! # Alpha rule
//!
//! A triangle whose material is a leaf ([`MaterialKind::Leaf`]) with a texture is
//! alpha-tested: at the hit's interpolated texture coordinates, the nearest texel (the
//! texture's own wrap mode) must be opaque ([`sylva_geom::is_opaque`]: alpha byte ≥ 128).
//! A hit on a transparent texel is discarded inside the leaf loop and the traversal goes on,
//! so the ray is never re-traced from the hit. Wood and untextured leaves are opaque.

use crate::kdtree::{lane, Clip, KdTree, TraceStats, TraversalConfig, PACKET};
use crate::ray::{intersect_triangle, inverse_dir, TriangleData};
use glam::{Affine3A, Vec2, Vec3};
use std::sync::Arc;
use sylva_geom::{is_opaque, nearest_texel_coords, Aabb, MaterialKind, Model, Texture, Wrap};

/// Opacity of a texture as one bit per texel ([`is_opaque`]): [`Texture::is_opaque_at`]
/// without the pixels.
#[derive(Debug, Clone)]
pub struct AlphaMask {
    width: u32,
    height: u32,
    wrap: Wrap,
    bits: Vec<u64>,
}

impl AlphaMask {
    pub fn new(tex: &Texture) -> AlphaMask {
        let n = tex.pixels.len();
        let mut bits = vec![0u64; n.div_ceil(64)];
        for (i, p) in tex.pixels.iter().enumerate() {
            if is_opaque(*p) {
                bits[i / 64] |= 1 << (i % 64);
            }
        }
        AlphaMask {
            width: tex.width,
            height: tex.height,
            wrap: tex.wrap,
            bits,
        }
    }

    /// Same texel as `Texture::sample(u, v, Filter::Nearest)`.
    #[inline]
    pub fn opaque(&self, u: f32, v: f32) -> bool {
        let (x, y) = nearest_texel_coords(u, v, self.width, self.height, self.wrap);
        let i = (y * self.width + x) as usize;
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    pub fn memory_bytes(&self) -> u64 {
        self.bits.capacity() as u64 * 8
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn wrap(&self) -> Wrap {
        self.wrap
    }

    /// Texel `y * width + x` is opaque when bit `i % 64` of word `i / 64` is set.
    pub fn bits(&self) -> &[u64] {
        &self.bits
    }
}

/// Precomputed triangle plus its alpha entry (`u32::MAX`: opaque).
#[derive(Debug, Clone, Copy)]
#[repr(C)]
struct Tri {
    data: TriangleData,
    alpha: u32,
}

/// Texture coordinates of an alpha-tested triangle's corners and its mask.
#[derive(Debug, Clone, Copy)]
struct AlphaTri {
    uv: [Vec2; 3],
    mask: u32,
}

/// The closest candidate so far: `(t, instance, triangle)` ordered lexicographically.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Best {
    pub t: f32,
    pub instance: u32,
    pub triangle: u32,
    pub u: f32,
    pub v: f32,
}

impl Best {
    /// Nothing found yet on `t_min < t ≤ t_max`.
    pub(crate) fn nothing(t_max: f32) -> Best {
        Best {
            t: t_max,
            instance: u32::MAX,
            triangle: u32::MAX,
            u: 0.0,
            v: 0.0,
        }
    }

    /// The hit found, if any (`triangle == MAX` marks "nothing yet"; the ground has
    /// triangle 0).
    pub(crate) fn hit(self) -> Option<crate::Hit> {
        (self.triangle != u32::MAX).then_some(crate::Hit {
            t: self.t,
            instance: self.instance,
            triangle: self.triangle,
            u: self.u,
            v: self.v,
        })
    }
}

/// Levels of a model's tree above its parts ([`ModelAccel::parts`]): up to 2^6 parts per
/// model, which the scene's top level holds per instance.
pub const PART_DEPTH: usize = 6;

/// A subtree of a model's tree that the scene's top level holds on its own for every
/// instance: its root node and the box its triangles' parts lie in (within its cell).
#[derive(Debug, Clone, Copy)]
pub struct Part {
    pub node: u32,
    pub bounds: Aabb,
}

/// A model ready for ray queries.
#[derive(Debug, Clone)]
pub struct ModelAccel {
    tree: KdTree,
    /// The tree cut [`PART_DEPTH`] levels down, each part with its tight box.
    parts: Vec<Part>,
    /// Corners of a prism containing every vertex: the convex hull of the vertices' (x, z)
    /// at the lowest and at the highest y (see [`ModelAccel::world_bounds`]).
    hull: Vec<Vec3>,
    tris: Vec<Tri>,
    alpha: Vec<AlphaTri>,
    masks: Vec<AlphaMask>,
}

struct TriClip<'a> {
    positions: &'a [[f32; 3]],
    indices: &'a [[u32; 3]],
}

impl TriClip<'_> {
    fn corners(&self, i: usize) -> [Vec3; 3] {
        self.indices[i].map(|k| Vec3::from_array(self.positions[k as usize]))
    }
}

impl Clip for TriClip<'_> {
    fn count(&self) -> usize {
        self.indices.len()
    }

    fn bounds(&self, i: usize) -> Option<Aabb> {
        let [a, b, c] = self.corners(i);
        if TriangleData::new(a, b, c).is_degenerate() {
            return None;
        }
        Some(Aabb {
            min: a.min(b).min(c),
            max: a.max(b).max(c),
        })
    }

    fn clip(&self, i: usize, bx: &Aabb) -> Option<Aabb> {
        clip_triangle(self.corners(i), bx)
    }
}

/// Bounds of the triangle's part inside `bx` (Sutherland-Hodgman against the six planes),
/// widened so that rounding never loses a sliver and the widened triangle test (see
/// [`crate::ray`]) never hits outside the bounds.
pub fn clip_triangle(tri: [Vec3; 3], bx: &Aabb) -> Option<Aabb> {
    let mut poly: [Vec3; 9] = [Vec3::ZERO; 9];
    let mut tmp: [Vec3; 9] = [Vec3::ZERO; 9];
    poly[..3].copy_from_slice(&tri);
    let mut n = 3usize;
    for axis in 0..3 {
        for (plane, keep_above) in [(bx.min[axis], true), (bx.max[axis], false)] {
            let inside = |p: Vec3| {
                if keep_above {
                    p[axis] >= plane
                } else {
                    p[axis] <= plane
                }
            };
            let mut m = 0usize;
            for k in 0..n {
                let p = poly[k];
                let q = poly[(k + 1) % n];
                let (pi, qi) = (inside(p), inside(q));
                if pi {
                    tmp[m] = p;
                    m += 1;
                }
                if pi != qi {
                    let s = (plane - p[axis]) / (q[axis] - p[axis]);
                    let mut x = p + (q - p) * s;
                    x[axis] = plane;
                    tmp[m] = x;
                    m += 1;
                }
            }
            n = m;
            if n == 0 {
                return None;
            }
            poly[..n].copy_from_slice(&tmp[..n]);
        }
    }
    let mut b = Aabb::EMPTY;
    for p in &poly[..n] {
        b.grow(*p);
    }
    // Rounding of the clipped corners (relative to the coordinates) plus the widening of
    // the triangle test (relative to the triangle), so every hit point lies in the bounds.
    let size = (tri[0].max(tri[1]).max(tri[2]) - tri[0].min(tri[1]).min(tri[2])).max_element();
    let mag = b.min.abs().max(b.max.abs()).max_element();
    let slack = 4e-7 * mag + 2.0 * crate::ray::BARY_EPS * size;
    b.min -= Vec3::splat(slack);
    b.max += Vec3::splat(slack);
    Some(b)
}

/// Corners of the prism `hull(x, z) × [y_min, y_max]` over the vertices that triangles use
/// (Andrew's monotone chain; collinear points dropped). Empty for a model without triangles.
fn hull_prism(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Vec<Vec3> {
    let mut used = vec![false; positions.len()];
    for t in indices {
        for &k in t {
            if let Some(u) = used.get_mut(k as usize) {
                *u = true;
            }
        }
    }
    let (mut y0, mut y1) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut pts: Vec<[f32; 2]> = Vec::new();
    for (p, _) in positions
        .iter()
        .zip(&used)
        .filter(|(p, u)| **u && p.iter().all(|c| c.is_finite()))
    {
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
        pts.push([p[0], p[2]]);
    }
    if pts.is_empty() {
        return Vec::new();
    }
    pts.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup();
    // f64 cross products of f32 differences: the sign is right for any realistic model.
    let cross = |o: [f32; 2], a: [f32; 2], b: [f32; 2]| {
        (a[0] as f64 - o[0] as f64) * (b[1] as f64 - o[1] as f64)
            - (a[1] as f64 - o[1] as f64) * (b[0] as f64 - o[0] as f64)
    };
    let mut hull: Vec<[f32; 2]> = Vec::with_capacity(64);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f32; 2]>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop(); // the chain's last point starts the other chain
    }
    if hull.is_empty() {
        hull.push(pts[0]);
    }
    hull.iter()
        .flat_map(|&[x, z]| [Vec3::new(x, y0, z), Vec3::new(x, y1, z)])
        .collect()
}

/// The parts of `tree` ([`PART_DEPTH`] levels down), each with the box that holds every
/// reference of its leaves: the cell, shrunk to its triangles' boxes widened as
/// [`clip_triangle`] widens a clipped part, so the box holds every hit its leaves report.
fn tree_parts(tree: &KdTree, tris: &[Tri]) -> Vec<Part> {
    use rayon::prelude::*;
    tree.subtrees(PART_DEPTH)
        .par_iter()
        .map(|&(node, cell)| {
            let mut b = Aabb::EMPTY;
            let mut widest = 0f32;
            for p in tree.subtree_primitives(node) {
                let d = &tris[p as usize].data;
                let (a, bb, c) = (d.v0, d.v0 + d.e1, d.v0 + d.e2);
                let (lo, hi) = (a.min(bb).min(c), a.max(bb).max(c));
                let mag = lo.abs().max(hi.abs()).max_element();
                let slack = 4e-7 * mag + 2.0 * crate::ray::BARY_EPS * (hi - lo).max_element();
                widest = widest.max(slack);
                b.grow(lo - Vec3::splat(slack));
                b.grow(hi + Vec3::splat(slack));
            }
            // The cell widened as its triangles are: a hit computed an ulp outside a flat
            // cell (a planar model) must still lie in the box.
            Part {
                node,
                bounds: Aabb {
                    min: b.min.max(cell.min - Vec3::splat(widest)),
                    max: b.max.min(cell.max + Vec3::splat(widest)),
                },
            }
        })
        .filter(|p| !p.bounds.is_empty())
        .collect()
}

impl ModelAccel {
    /// Builds the kd-tree over the model's triangles (in parallel, deterministic).
    pub fn build(model: &Model) -> ModelAccel {
        ModelAccel::with_tree(model, ModelAccel::build_tree(model))
    }

    /// The kd-tree [`ModelAccel::build`] builds over `model`'s triangles (the slow part:
    /// what the cache keeps, [`crate::scene::SceneAccel::build_cached`]).
    pub fn build_tree(model: &Model) -> KdTree {
        let mesh = &model.mesh;
        KdTree::build(&TriClip {
            positions: &mesh.positions,
            indices: &mesh.indices,
        })
    }

    /// The model's acceleration around `tree`, which must be [`ModelAccel::build_tree`]'s
    /// for it (or one read back from it).
    pub fn with_tree(model: &Model, tree: KdTree) -> ModelAccel {
        let mesh = &model.mesh;
        let clip = TriClip {
            positions: &mesh.positions,
            indices: &mesh.indices,
        };
        let mut masks = Vec::new();
        let mut mask_of: Vec<Option<u32>> = Vec::new();
        for m in &model.materials {
            let textured_leaf = m.kind == MaterialKind::Leaf && m.texture.is_some();
            mask_of.push(textured_leaf.then(|| {
                masks.push(AlphaMask::new(m.texture.as_ref().map(Arc::as_ref).unwrap()));
                masks.len() as u32 - 1
            }));
        }
        let mut alpha = Vec::new();
        let tris: Vec<Tri> = (0..mesh.indices.len())
            .map(|i| {
                let [a, b, c] = clip.corners(i);
                let mat = mesh.material_ids.get(i).copied().unwrap_or(0) as usize;
                let a_idx = match mask_of.get(mat).copied().flatten() {
                    Some(mask) => {
                        let uv = mesh.indices[i].map(|k| {
                            Vec2::from_array(mesh.uvs.get(k as usize).copied().unwrap_or([0.0; 2]))
                        });
                        alpha.push(AlphaTri { uv, mask });
                        alpha.len() as u32 - 1
                    }
                    None => u32::MAX,
                };
                Tri {
                    data: TriangleData::new(a, b, c),
                    alpha: a_idx,
                }
            })
            .collect();
        let parts = tree_parts(&tree, &tris);
        ModelAccel {
            tree,
            parts,
            hull: hull_prism(&mesh.positions, &mesh.indices),
            tris,
            alpha,
            masks,
        }
    }

    /// Corners of the prism (convex hull of the vertices' x, z times their y range) that
    /// [`ModelAccel::world_bounds`] transforms.
    pub fn hull_points(&self) -> &[Vec3] {
        &self.hull
    }

    /// World box of the model under `to_world`, containing every transformed vertex and
    /// the widened triangle test's margin. The hull prism is convex and contains the
    /// model, so its transformed corners bound the transformed model for any affine map;
    /// for the instances' rotations about y it is exact up to the margin (the rotated
    /// model box's corners over-state a tree turned by 45° by up to √2 per axis).
    pub fn world_bounds(&self, to_world: &Affine3A) -> Aabb {
        let mut b = Aabb::EMPTY;
        for &p in &self.hull {
            b.grow(to_world.transform_point3(p));
        }
        if b.is_empty() {
            return b;
        }
        // Rounding of the transform (relative to the coordinates) plus the widening of the
        // triangle test (relative to the model), as in `clip_triangle`.
        let mag = b.min.abs().max(b.max.abs()).max_element();
        let slack = 4e-7 * mag + 2.0 * crate::ray::BARY_EPS * (b.max - b.min).max_element();
        b.min -= Vec3::splat(slack);
        b.max += Vec3::splat(slack);
        b
    }

    pub fn tree(&self) -> &KdTree {
        &self.tree
    }

    /// The subtrees the scene's top level holds per instance ([`PART_DEPTH`] levels down;
    /// empty ones left out): together they hold every triangle reference of the tree.
    pub fn parts(&self) -> &[Part] {
        &self.parts
    }

    /// Per triangle (mesh order) its Möller-Trumbore data and its entry in
    /// [`ModelAccel::alpha_triangles`], `u32::MAX` when it is opaque.
    pub fn triangles(&self) -> impl ExactSizeIterator<Item = (&TriangleData, u32)> + '_ {
        self.tris.iter().map(|t| (&t.data, t.alpha))
    }

    /// Per alpha-tested triangle its corners' texture coordinates and its mask in
    /// [`ModelAccel::alpha_masks`].
    pub fn alpha_triangles(&self) -> impl ExactSizeIterator<Item = ([Vec2; 3], u32)> + '_ {
        self.alpha.iter().map(|a| (a.uv, a.mask))
    }

    /// Triangle `triangle`'s alpha test, when it has one: its corners' texture coordinates
    /// and its mask in [`ModelAccel::alpha_masks`].
    pub fn triangle_alpha(&self, triangle: u32) -> Option<([Vec2; 3], u32)> {
        let a = self.tris.get(triangle as usize)?.alpha;
        self.alpha.get(a as usize).map(|a| (a.uv, a.mask))
    }

    /// One opacity bitmask per leaf texture.
    pub fn alpha_masks(&self) -> &[AlphaMask] {
        &self.masks
    }

    pub fn bounds(&self) -> Aabb {
        self.tree.bounds()
    }

    /// Bytes of the tree, the triangle data and the alpha data (the mesh itself excluded).
    pub fn memory_bytes(&self) -> u64 {
        self.tree.memory_bytes()
            + (self.parts.capacity() * std::mem::size_of::<Part>()
                + self.hull.capacity() * std::mem::size_of::<Vec3>()
                + self.tris.capacity() * std::mem::size_of::<Tri>()
                + self.alpha.capacity() * std::mem::size_of::<AlphaTri>()) as u64
            + self.masks.iter().map(AlphaMask::memory_bytes).sum::<u64>()
    }

    /// Model-space geometric normal `e1 × e2` of triangle `i` (not normalised).
    pub fn triangle_normal(&self, triangle: u32) -> Vec3 {
        let d = &self.tris[triangle as usize].data;
        d.e1.cross(d.e2)
    }

    /// Does the alpha test let a hit at barycentrics (u, v) on triangle `tri` stand?
    #[inline]
    fn passes_alpha(&self, alpha: u32, u: f32, v: f32) -> bool {
        if alpha == u32::MAX {
            return true;
        }
        let a = &self.alpha[alpha as usize];
        let uv = a.uv[0] * (1.0 - u - v) + a.uv[1] * u + a.uv[2] * v;
        self.masks[a.mask as usize].opaque(uv.x, uv.y)
    }

    /// Whether triangle `i` (at barycentrics u, v) is opaque under the alpha rule; `true` for
    /// opaque materials. For reference implementations and tests.
    pub fn is_opaque_at(&self, triangle: u32, u: f32, v: f32) -> bool {
        self.passes_alpha(self.tris[triangle as usize].alpha, u, v)
    }

    /// Tests triangle `p` of instance `instance` against the model-space ray and makes it
    /// `best` if it is closer (ties: lower `(instance, triangle)`) and opaque there. Returns
    /// whether the alpha test discarded a hit.
    #[inline(always)]
    fn offer(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        instance: u32,
        p: u32,
        best: &mut Best,
    ) -> bool {
        let tri = &self.tris[p as usize];
        let Some((t, u, v)) = intersect_triangle(origin, dir, &tri.data, t_min, best.t) else {
            return false;
        };
        if t == best.t && (instance, p) >= (best.instance, best.triangle) {
            return false;
        }
        if !self.passes_alpha(tri.alpha, u, v) {
            return true;
        }
        *best = Best {
            t,
            instance,
            triangle: p,
            u,
            v,
        };
        false
    }

    /// Triangle `p` against the segment `t_min < t ≤ t_max` of a model-space ray: `None`
    /// for a miss, `Some(opaque)` for a hit, `opaque` by the alpha rule.
    #[inline(always)]
    fn segment_hit(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, p: u32) -> Option<bool> {
        let tri = self.tris.get(p as usize)?;
        intersect_triangle(origin, dir, &tri.data, t_min, t_max)
            .map(|(_, u, v)| self.passes_alpha(tri.alpha, u, v))
    }

    /// Closest hit in model space, improving `best` (ties: lower triangle id).
    #[inline]
    #[allow(clippy::too_many_arguments)] // the hot path, called per instance a ray meets
    pub(crate) fn closest(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        instance: u32,
        best: &mut Best,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) {
        let root = Part {
            node: 0,
            bounds: self.tree.bounds(),
        };
        self.closest_in(&root, origin, dir, t_min, instance, best, cfg, stats);
    }

    /// [`ModelAccel::closest`] over the leaves of one part (one of [`ModelAccel::parts`], or
    /// the whole tree).
    #[inline]
    #[allow(clippy::too_many_arguments)] // the hot path, called per part a ray meets
    pub(crate) fn closest_in(
        &self,
        part: &Part,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        instance: u32,
        best: &mut Best,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) {
        let inv = inverse_dir(dir);
        let (mut tests, mut rejects) = (0u64, 0u64);
        self.tree.traverse_subtree(
            part.node,
            &part.bounds,
            origin,
            inv,
            t_min,
            best.t,
            cfg,
            stats,
            |prims| {
                tests += prims.len() as u64;
                for &p in prims {
                    rejects += self.offer(origin, dir, t_min, instance, p, best) as u64;
                }
                best.t
            },
        );
        stats.triangle_tests += tests;
        stats.alpha_rejects += rejects;
    }

    /// [`ModelAccel::closest_in`] for the lanes `mask` of a packet (model-space rays that
    /// [`crate::kdtree::packet_compatible`] accepts), improving each lane's `best`; the same
    /// hits, tie rule and alpha rule lane by lane.
    #[inline]
    #[allow(clippy::too_many_arguments)] // the hot path, called per instance a packet meets
    pub(crate) fn closest_packet(
        &self,
        part: &Part,
        origin: &[[f32; PACKET]; 3],
        dir: &[[f32; PACKET]; 3],
        inv: &[[f32; PACKET]; 3],
        t_min: &[f32; PACKET],
        mask: u32,
        instance: u32,
        best: &mut [Best; PACKET],
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) {
        let (mut tests, mut rejects) = (0u64, 0u64);
        let t_max = best.map(|b| b.t);
        self.tree.traverse_packet_subtree(
            part.node,
            &part.bounds,
            origin,
            inv,
            t_min,
            &t_max,
            mask,
            cfg,
            stats,
            |prims, lanes, _, _| {
                for l in 0..PACKET {
                    if lanes >> l & 1 == 0 {
                        continue;
                    }
                    let (o, d) = (lane(origin, l), lane(dir, l));
                    tests += prims.len() as u64;
                    for &p in prims {
                        rejects += self.offer(o, d, t_min[l], instance, p, &mut best[l]) as u64;
                    }
                }
                best.map(|b| b.t)
            },
        );
        stats.triangle_tests += tests;
        stats.alpha_rejects += rejects;
    }

    /// Whether triangle `triangle` alone stops the model-space ray within `t_min < t ≤ t_max`
    /// (same arithmetic and alpha rule as [`ModelAccel::any`]).
    #[inline]
    pub(crate) fn occludes(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        triangle: u32,
    ) -> bool {
        self.segment_hit(origin, dir, t_min, t_max, triangle) == Some(true)
    }

    /// An opaque hit with `t_min < t ≤ t_max`, in model space: the first triangle found.
    #[inline]
    pub(crate) fn any(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) -> Option<u32> {
        let inv = inverse_dir(dir);
        let mut found = None;
        let (mut tests, mut rejects) = (0u64, 0u64);
        self.tree
            .traverse(origin, inv, t_min, t_max, cfg, stats, |prims| {
                for &p in prims {
                    tests += 1;
                    match self.segment_hit(origin, dir, t_min, t_max, p) {
                        Some(true) => {
                            found = Some(p);
                            return f32::NEG_INFINITY;
                        }
                        Some(false) => rejects += 1,
                        None => {}
                    }
                }
                f32::INFINITY
            });
        stats.triangle_tests += tests;
        stats.alpha_rejects += rejects;
        found
    }

    /// Every opaque hit of the model-space ray with `t_min < t ≤ t_max` (same arithmetic and
    /// alpha rule as the closest-hit query), appended to `out` as instance `instance`, each
    /// triangle once, in no particular order.
    #[allow(clippy::too_many_arguments)] // mirrors `closest`
    pub(crate) fn all(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f32,
        t_max: f32,
        instance: u32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        out: &mut Vec<crate::Hit>,
    ) {
        let inv = inverse_dir(dir);
        let start = out.len();
        let (mut tests, mut rejects) = (0u64, 0u64);
        self.tree
            .traverse(origin, inv, t_min, t_max, cfg, stats, |prims| {
                for &p in prims {
                    tests += 1;
                    let tri = &self.tris[p as usize];
                    let Some((t, u, v)) = intersect_triangle(origin, dir, &tri.data, t_min, t_max)
                    else {
                        continue;
                    };
                    if !self.passes_alpha(tri.alpha, u, v) {
                        rejects += 1;
                        continue;
                    }
                    out.push(crate::Hit {
                        t,
                        instance,
                        triangle: p,
                        u,
                        v,
                    });
                }
                // Never stop early: every leaf along the segment is wanted.
                f32::INFINITY
            });
        // A triangle straddling several leaves was found in each (at the same t).
        let found = &mut out[start..];
        found.sort_unstable_by_key(|h| h.triangle);
        let mut kept = start;
        for k in start..out.len() {
            if k == start || out[k].triangle != out[kept - 1].triangle {
                out[kept] = out[k];
                kept += 1;
            }
        }
        out.truncate(kept);
        stats.triangle_tests += tests;
        stats.alpha_rejects += rejects;
    }

    /// Every opaque hit of a model-space ray on this model alone (instance id 0), sorted by
    /// `t` (ties: lower triangle first), each triangle once.
    pub fn all_hits(
        &self,
        ray: &crate::Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        out: &mut Vec<crate::Hit>,
    ) {
        out.clear();
        stats.rays += 1;
        if !ray.is_valid() {
            return;
        }
        self.all(
            ray.origin, ray.dir, ray.t_min, ray.t_max, 0, cfg, stats, out,
        );
        out.sort_unstable_by(|a, b| {
            (a.t, a.triangle)
                .partial_cmp(&(b.t, b.triangle))
                .expect("finite t")
        });
    }

    /// Closest hit of a model-space ray on this model alone (instance id 0).
    pub fn closest_hit(
        &self,
        ray: &crate::Ray,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
    ) -> Option<crate::Hit> {
        stats.rays += 1;
        if !ray.is_valid() {
            return None;
        }
        let mut best = Best::nothing(ray.t_max);
        self.closest(ray.origin, ray.dir, ray.t_min, 0, &mut best, cfg, stats);
        best.hit()
    }

    /// Whether a model-space ray hits this model anywhere in its interval.
    pub fn any_hit(&self, ray: &crate::Ray, cfg: TraversalConfig, stats: &mut TraceStats) -> bool {
        stats.rays += 1;
        ray.is_valid()
            && self
                .any(ray.origin, ray.dir, ray.t_min, ray.t_max, cfg, stats)
                .is_some()
    }

    /// Reference: every triangle tested, same rules (for tests).
    pub fn brute_closest_hit(&self, ray: &crate::Ray) -> Option<crate::Hit> {
        let mut best: Option<crate::Hit> = None;
        for (i, tri) in self.tris.iter().enumerate() {
            let t_max = best.map_or(ray.t_max, |b| b.t);
            if let Some((t, u, v)) =
                intersect_triangle(ray.origin, ray.dir, &tri.data, ray.t_min, t_max)
            {
                if best.is_some_and(|b| t == b.t) || !self.passes_alpha(tri.alpha, u, v) {
                    continue; // equal t: the earlier (lower) id stands
                }
                best = Some(crate::Hit {
                    t,
                    instance: 0,
                    triangle: i as u32,
                    u,
                    v,
                });
            }
        }
        best
    }

    /// Reference any-hit: every triangle tested.
    pub fn brute_any_hit(&self, ray: &crate::Ray) -> bool {
        self.tris.iter().any(|tri| {
            intersect_triangle(ray.origin, ray.dir, &tri.data, ray.t_min, ray.t_max)
                .is_some_and(|(_, u, v)| self.passes_alpha(tri.alpha, u, v))
        })
    }
}
