//! SAH kd-trees over bounded primitives, and their short-stack traversal (000 Fig. 1).
//!
//! One builder serves both levels: a primitive only has to say what part of it lies in a
//! box ([`Clip`]): triangles clip their polygon exactly (Sutherland-Hodgman), instance boxes
//! intersect. Each node evaluates the surface area heuristic over 32 bins per axis (all
//! candidate planes of every reference when a node holds few), so a build is O(n log n);
//! children are built in parallel with `rayon::join` and the result does not depend on the
//! thread count (every decision is a function of the node's references alone).
//!
//! Nodes are 8 bytes: interior nodes hold the axis, the index of the child above the plane
//! (the one below follows its parent) and the split position; leaves hold a count and an
//! offset into the primitive-index list.

use crate::ray::ray_box;
use glam::{BVec4A, Vec3, Vec4};
use serde::Serialize;
use sylva_core::container::{ByteReader, ByteWriter};
use sylva_geom::Aabb;

/// Deepest tree the builder makes; the "unbounded" traversal stack holds this many entries,
/// so it can never drop one.
pub const MAX_DEPTH: usize = 56;

/// Relative margin before a leaf's end within which traversal goes on past a hit.
pub const TERMINATION_SLACK: f32 = 1e-5;

/// Rays traced together by [`KdTree::traverse_packet`].
pub const PACKET: usize = 4;

/// Lane `l` of a packet's per-axis arrays.
#[inline(always)]
pub(crate) fn lane(a: &[[f32; PACKET]; 3], l: usize) -> Vec3 {
    Vec3::new(a[0][l], a[1][l], a[2][l])
}

/// The octant of an inverse direction (0..8), or 8 when it is not finite: lanes of one
/// octant can share a packet traversal.
#[inline(always)]
pub(crate) fn sign_group(inv: Vec3) -> u32 {
    if inv.is_finite() {
        (inv.x < 0.0) as u32 | ((inv.y < 0.0) as u32) << 1 | ((inv.z < 0.0) as u32) << 2
    } else {
        8
    }
}

/// Whether the rays `inv_dir` of the lanes in `mask` can share a packet traversal: finite
/// inverse directions with the same signs.
pub fn packet_compatible(inv_dir: &[[f32; PACKET]; 3], mask: u32) -> bool {
    let mut groups = (0..PACKET)
        .filter(|l| mask >> l & 1 == 1)
        .map(|l| sign_group(lane(inv_dir, l)));
    match groups.next() {
        None => true,
        Some(g) => g != 8 && groups.all(|h| h == g),
    }
}

/// The short stack (000 Fig. 1) as a ring buffer of `cap` entries: a push onto a full stack
/// overwrites the oldest entry, which kd-restart later makes up for.
struct ShortStack<T: Copy> {
    // Uninitialised: a traversal runs once per instance a ray meets, and clearing 56
    // entries each time cost more than the traversal of a small tree.
    items: [std::mem::MaybeUninit<T>; MAX_DEPTH],
    cap: usize,
    /// Next free slot.
    top: usize,
    len: usize,
}

impl<T: Copy> ShortStack<T> {
    #[inline(always)]
    fn new(cap: usize) -> ShortStack<T> {
        ShortStack {
            items: [std::mem::MaybeUninit::uninit(); MAX_DEPTH],
            cap: cap.clamp(1, MAX_DEPTH),
            top: 0,
            len: 0,
        }
    }

    #[inline(always)]
    fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline(always)]
    fn push(&mut self, e: T) {
        self.items[self.top] = std::mem::MaybeUninit::new(e);
        self.top = if self.top + 1 == self.cap {
            0
        } else {
            self.top + 1
        };
        self.len = (self.len + 1).min(self.cap);
    }

    /// The newest entry; call only when not empty.
    #[inline(always)]
    fn pop(&mut self) -> T {
        debug_assert!(self.len > 0);
        self.top = if self.top == 0 {
            self.cap - 1
        } else {
            self.top - 1
        };
        self.len -= 1;
        // SAFETY: the `len + 1` entries below the old `top` (cyclically) were written by
        // pushes, and callers pop only a non-empty stack.
        unsafe { self.items[self.top].assume_init() }
    }
}

/// The stack of the paper (000 §4.1).
pub const DEFAULT_STACK_SIZE: usize = 5;

/// Traversal settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TraversalConfig {
    /// Entries of the short stack (1..=[`MAX_DEPTH`]); when full, a push drops the oldest
    /// entry, and popping an empty stack restarts from the (pushed-down) root.
    pub stack_size: usize,
}

impl TraversalConfig {
    /// A stack as deep as any tree: nothing is ever dropped, no restarts.
    pub const UNBOUNDED: TraversalConfig = TraversalConfig {
        stack_size: MAX_DEPTH,
    };

    /// `--stack N`: a short stack of 1 to [`MAX_DEPTH`] entries, or the error naming the
    /// flag.
    pub fn checked(stack_size: usize) -> Result<TraversalConfig, String> {
        if !(1..=MAX_DEPTH).contains(&stack_size) {
            return Err(format!(
                "--stack {stack_size}: the short stack holds 1 to {MAX_DEPTH} entries"
            ));
        }
        Ok(TraversalConfig::with_stack(stack_size))
    }

    /// `stack_size` clamped to 1..=[`MAX_DEPTH`].
    pub fn with_stack(stack_size: usize) -> TraversalConfig {
        TraversalConfig {
            stack_size: stack_size.clamp(1, MAX_DEPTH),
        }
    }
}

impl Default for TraversalConfig {
    fn default() -> Self {
        TraversalConfig {
            stack_size: DEFAULT_STACK_SIZE,
        }
    }
}

/// Work counters of queries; add them up over rays.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TraceStats {
    pub rays: u64,
    /// Interior kd-tree nodes stepped through (both levels); a packet's step counts once,
    /// as do its leaves and instance entries.
    pub nodes: u64,
    pub leaves: u64,
    pub triangle_tests: u64,
    /// Instances whose model tree a ray entered.
    pub instance_visits: u64,
    /// kd-restarts: pops from an empty short stack before the ray's interval was done.
    pub restarts: u64,
    /// Triangle hits discarded by the alpha test.
    pub alpha_rejects: u64,
    /// Shadow rays answered by an [`crate::OccluderCache`] entry, without a traversal.
    pub occluder_cache_hits: u64,
}

impl std::ops::AddAssign for TraceStats {
    fn add_assign(&mut self, o: TraceStats) {
        self.rays += o.rays;
        self.nodes += o.nodes;
        self.leaves += o.leaves;
        self.triangle_tests += o.triangle_tests;
        self.instance_visits += o.instance_visits;
        self.restarts += o.restarts;
        self.alpha_rejects += o.alpha_rejects;
        self.occluder_cache_hits += o.occluder_cache_hits;
    }
}

/// 8-byte node. Interior: `a = axis | above << 2`, `b = split.to_bits()`; the child below the
/// plane is the next node. Leaf: `a = 3 | count << 2`, `b = offset` into the index list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(C)]
pub struct KdNode {
    a: u32,
    b: u32,
}

impl KdNode {
    #[inline(always)]
    fn is_leaf(self) -> bool {
        self.a & 3 == 3
    }

    /// The two words as stored, `[a, b]`: what a GPU traversal uploads and decodes the same
    /// way.
    #[inline]
    pub fn raw(self) -> [u32; 2] {
        [self.a, self.b]
    }
}

/// Statistics of one built tree.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TreeStats {
    pub primitives: usize,
    pub nodes: usize,
    pub leaves: usize,
    pub empty_leaves: usize,
    /// Primitive references in leaves (≥ primitives: straddlers are referenced twice).
    pub references: usize,
    pub max_depth: usize,
    /// SAH cost of the tree relative to the root box (traversal 1, intersection 1).
    pub sah_cost: f64,
}

/// A built kd-tree: nodes, leaf index lists, root box.
#[derive(Debug, Clone)]
pub struct KdTree {
    nodes: Vec<KdNode>,
    indices: Vec<u32>,
    bounds: Aabb,
    stats: TreeStats,
}

/// What the builder needs from a primitive.
pub trait Clip: Sync {
    /// Number of primitives (ids `0..count`).
    fn count(&self) -> usize;
    /// Bounds of primitive `i`, or `None` to leave it out (degenerate).
    fn bounds(&self, i: usize) -> Option<Aabb>;
    /// Bounds of the part of primitive `i` inside `bx` (closed), `None` when none is.
    /// Must contain the true part; slightly larger is harmless.
    fn clip(&self, i: usize, bx: &Aabb) -> Option<Aabb>;
}

// SAH constants. Node steps and triangle tests cost about the same here (both are mostly a
// cache miss); a higher intersection cost quadruples the references of foliage (leaf quads
// overlap) for no gain in speed. Measured in docs/PERFORMANCE.md.
const COST_TRAVERSE: f32 = 1.0;
const COST_INTERSECT: f32 = 1.0;
const EMPTY_BONUS: f32 = 0.8;
/// Depth limit `8 + DEPTH_FACTOR · log2(n)`; deeper trees only duplicate leaf quads further.
const DEPTH_FACTOR: f64 = 1.0;
const BINS: usize = 32;
/// Below this many references, every reference bound is a candidate plane.
const EXACT_BELOW: usize = 16;
/// Below this many references, children are built on the current thread.
const PARALLEL_ABOVE: usize = 4096;

#[derive(Clone, Copy)]
struct Ref {
    min: [f32; 3],
    max: [f32; 3],
    id: u32,
}

enum Build {
    Leaf(Vec<u32>),
    Inner {
        axis: usize,
        split: f32,
        below: Box<Build>,
        above: Box<Build>,
    },
}

fn half_area(min: Vec3, max: Vec3) -> f32 {
    let d = (max - min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

fn to_aabb(r: &Ref) -> Aabb {
    Aabb {
        min: Vec3::from_array(r.min),
        max: Vec3::from_array(r.max),
    }
}

struct Split {
    axis: usize,
    pos: f32,
    cost: f32,
}

/// SAH cost of splitting `bx` at `pos` on `axis` with `nb` / `na` references below / above.
fn sah(bx: &Aabb, axis: usize, pos: f32, nb: usize, na: usize, inv_area: f32) -> f32 {
    let mut bmax = bx.max;
    bmax[axis] = pos;
    let mut amin = bx.min;
    amin[axis] = pos;
    let pb = half_area(bx.min, bmax) * inv_area;
    let pa = half_area(amin, bx.max) * inv_area;
    let mut c = COST_TRAVERSE + COST_INTERSECT * (pb * nb as f32 + pa * na as f32);
    if nb == 0 || na == 0 {
        c *= EMPTY_BONUS;
    }
    c
}

fn find_split(refs: &[Ref], bx: &Aabb) -> Option<Split> {
    let area = half_area(bx.min, bx.max);
    if area <= 0.0 {
        return None;
    }
    let inv_area = 1.0 / area;
    let mut best: Option<Split> = None;
    let mut consider = |axis: usize, pos: f32, nb: usize, na: usize| {
        // Planes on the box's faces cut nothing off.
        if !(pos > bx.min[axis] && pos < bx.max[axis]) {
            return;
        }
        let c = sah(bx, axis, pos, nb, na, inv_area);
        // Strict `<` and a fixed visiting order make the choice deterministic.
        if best.as_ref().is_none_or(|b| c < b.cost) {
            best = Some(Split { axis, pos, cost: c });
        }
    };
    let n = refs.len();
    if n < EXACT_BELOW {
        // Sweep over sorted events (Wald & Havran): end < planar < start at equal positions.
        let mut events: Vec<(f32, u8)> = Vec::with_capacity(2 * n);
        for axis in 0..3 {
            events.clear();
            for r in refs {
                let (lo, hi) = (r.min[axis], r.max[axis]);
                if lo == hi {
                    events.push((lo, 1));
                } else {
                    events.push((lo, 2));
                    events.push((hi, 0));
                }
            }
            events.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let (mut nb, mut na) = (0usize, n);
            let mut i = 0;
            while i < events.len() {
                let pos = events[i].0;
                let (mut ends, mut planar, mut starts) = (0, 0, 0);
                while i < events.len() && events[i].0 == pos {
                    match events[i].1 {
                        0 => ends += 1,
                        1 => planar += 1,
                        _ => starts += 1,
                    }
                    i += 1;
                }
                na -= ends + planar;
                // Planar references go below.
                consider(axis, pos, nb + planar, na);
                nb += starts + planar;
            }
        }
    } else {
        for axis in 0..3 {
            let lo = bx.min[axis];
            let ext = bx.max[axis] - lo;
            if ext <= 0.0 {
                continue;
            }
            let scale = BINS as f32 / ext;
            let mut starts = [0u32; BINS];
            let mut ends = [0u32; BINS];
            for r in refs {
                let b0 = (((r.min[axis] - lo) * scale) as usize).min(BINS - 1);
                let b1 = (((r.max[axis] - lo) * scale) as usize).min(BINS - 1);
                starts[b0] += 1;
                ends[b1] += 1;
            }
            // Plane k sits between bins k-1 and k: references starting below it count below,
            // references ending at or above it count above.
            let mut nb = 0usize;
            let mut na = n;
            for k in 1..BINS {
                nb += starts[k - 1] as usize;
                na -= ends[k - 1] as usize;
                consider(axis, lo + ext * (k as f32 / BINS as f32), nb, na);
            }
        }
    }
    best
}

struct Builder<'a, C: Clip> {
    prims: &'a C,
    max_depth: usize,
}

impl<C: Clip> Builder<'_, C> {
    fn node(&self, refs: Vec<Ref>, bx: Aabb, depth: usize) -> Build {
        let n = refs.len();
        let leaf = |refs: Vec<Ref>| Build::Leaf(refs.into_iter().map(|r| r.id).collect());
        if n <= 1 || depth >= self.max_depth {
            return leaf(refs);
        }
        let Some(split) = find_split(&refs, &bx) else {
            return leaf(refs);
        };
        if split.cost >= COST_INTERSECT * n as f32 {
            return leaf(refs);
        }
        let (axis, pos) = (split.axis, split.pos);
        let mut below_box = bx;
        below_box.max[axis] = pos;
        let mut above_box = bx;
        above_box.min[axis] = pos;
        let mut below = Vec::with_capacity(n / 2 + 8);
        let mut above = Vec::with_capacity(n / 2 + 8);
        for r in refs {
            let (lo, hi) = (r.min[axis], r.max[axis]);
            if hi < pos || (hi == pos && lo < pos) || (lo == pos && hi == pos) {
                below.push(r);
            } else if lo > pos || (lo == pos && hi > pos) {
                above.push(r);
            } else {
                // Straddles: clip the primitive itself to each side, within its current
                // bounds (which already lie in this node's box).
                let cur = to_aabb(&r);
                for (side, sbx) in [(&mut below, &below_box), (&mut above, &above_box)] {
                    let lim = Aabb {
                        min: cur.min.max(sbx.min),
                        max: cur.max.min(sbx.max),
                    };
                    if let Some(c) = self.prims.clip(r.id as usize, &lim) {
                        let c = Aabb {
                            min: c.min.max(lim.min),
                            max: c.max.min(lim.max),
                        };
                        if !c.is_empty() {
                            side.push(Ref {
                                min: c.min.to_array(),
                                max: c.max.to_array(),
                                id: r.id,
                            });
                        }
                    }
                }
            }
        }
        // A split that moves nothing to either side only duplicates: stop.
        if below.len() == n && above.len() == n {
            let mut ids: Vec<u32> = below.iter().map(|r| r.id).collect();
            ids.sort_unstable();
            return Build::Leaf(ids);
        }
        let (b, a) = if n > PARALLEL_ABOVE {
            rayon::join(
                || self.node(below, below_box, depth + 1),
                || self.node(above, above_box, depth + 1),
            )
        } else {
            (
                self.node(below, below_box, depth + 1),
                self.node(above, above_box, depth + 1),
            )
        };
        Build::Inner {
            axis,
            split: pos,
            below: Box::new(b),
            above: Box::new(a),
        }
    }
}

/// The rules a tree is built by: part of a cached tree's key ([`crate::scene::KD_TREE`]),
/// so a change to the builder's constants makes new entries.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BuildRules {
    cost_traverse: f32,
    cost_intersect: f32,
    empty_bonus: f32,
    depth_factor: f64,
    max_depth: usize,
    /// The builder's revision: raise it when a change alters the trees it makes.
    revision: u32,
}

/// The rules [`KdTree::build`] follows.
pub const BUILD_RULES: BuildRules = BuildRules {
    cost_traverse: COST_TRAVERSE,
    cost_intersect: COST_INTERSECT,
    empty_bonus: EMPTY_BONUS,
    depth_factor: DEPTH_FACTOR,
    max_depth: MAX_DEPTH,
    revision: 1,
};

impl KdTree {
    /// The tree as bytes (a cache entry's payload): its box, statistics, nodes and leaf
    /// index lists.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        for v in self
            .bounds
            .min
            .to_array()
            .into_iter()
            .chain(self.bounds.max.to_array())
        {
            w.f32(v);
        }
        let s = &self.stats;
        for n in [
            s.primitives,
            s.nodes,
            s.leaves,
            s.empty_leaves,
            s.references,
            s.max_depth,
        ] {
            w.u64(n as u64);
        }
        w.u64(s.sah_cost.to_bits());
        let nodes: Vec<u32> = self.nodes.iter().flat_map(|n| n.raw()).collect();
        w.u32s(&nodes);
        w.u32s(&self.indices);
        w.bytes
    }

    /// A tree over `primitives` primitives from [`KdTree::to_bytes`]; `Err` says what is wrong.
    /// Every node is checked as traversal reads it (children after their parent and inside
    /// the tree, leaf lists inside the index list, ids below `primitives`), so a damaged
    /// tree is refused, never walked.
    pub fn from_bytes(bytes: &[u8], primitives: usize) -> Result<KdTree, String> {
        let mut r = ByteReader::new(bytes);
        let mut corners = [0f32; 6];
        for v in &mut corners {
            *v = r.f32("box")?;
        }
        let mut counts = [0usize; 6];
        for v in &mut counts {
            *v = r.u64("statistics")? as usize;
        }
        let sah_cost = f64::from_bits(r.u64("SAH cost")?);
        let raw = r.u32s("nodes")?;
        let indices = r.u32s("leaf indices")?;
        r.finish()?;
        if corners.iter().any(|v| !v.is_finite()) && counts[0] > 0 {
            return Err("the box is not finite".into());
        }
        if raw.is_empty() || raw.len() % 2 != 0 {
            return Err(format!("{} node words", raw.len()));
        }
        let nodes: Vec<KdNode> = raw
            .chunks_exact(2)
            .map(|c| KdNode { a: c[0], b: c[1] })
            .collect();
        let n = nodes.len();
        for (i, node) in nodes.iter().enumerate() {
            if node.is_leaf() {
                let (count, offset) = ((node.a >> 2) as usize, node.b as usize);
                if offset + count > indices.len() {
                    return Err(format!(
                        "leaf {i} lists {count} ids from {offset}, past the {} ids",
                        indices.len()
                    ));
                }
            } else {
                let above = (node.a >> 2) as usize;
                if i + 1 >= n || above <= i + 1 || above >= n {
                    return Err(format!(
                        "node {i}'s children ({}, {above}) are not inside the tree's {n} nodes after it",
                        i + 1
                    ));
                }
                if !f32::from_bits(node.b).is_finite() {
                    return Err(format!("node {i}'s split is not finite"));
                }
            }
        }
        if let Some(&id) = indices.iter().find(|&&id| id as usize >= primitives) {
            return Err(format!("leaf id {id}, the mesh has {primitives} triangles"));
        }
        let stats = TreeStats {
            primitives: counts[0],
            nodes: counts[1],
            leaves: counts[2],
            empty_leaves: counts[3],
            references: counts[4],
            max_depth: counts[5],
            sah_cost,
        };
        if stats.nodes != n || stats.references != indices.len() {
            return Err(format!(
                "the statistics say {} nodes and {} ids, the tree has {n} and {}",
                stats.nodes,
                stats.references,
                indices.len()
            ));
        }
        Ok(KdTree {
            nodes,
            indices,
            bounds: Aabb {
                min: Vec3::new(corners[0], corners[1], corners[2]),
                max: Vec3::new(corners[3], corners[4], corners[5]),
            },
            stats,
        })
    }

    /// Builds the tree over `prims`.
    pub fn build<C: Clip>(prims: &C) -> KdTree {
        let n = prims.count();
        let refs: Vec<Ref> = (0..n)
            .filter_map(|i| {
                prims.bounds(i).map(|b| Ref {
                    min: b.min.to_array(),
                    max: b.max.to_array(),
                    id: i as u32,
                })
            })
            .collect();
        let bounds = refs.iter().fold(Aabb::EMPTY, |b, r| b.union(&to_aabb(r)));
        let kept = refs.len();
        let max_depth = if kept == 0 {
            0
        } else {
            ((8.0 + DEPTH_FACTOR * (kept as f64).log2()) as usize).min(MAX_DEPTH)
        };
        let root = if kept == 0 {
            Build::Leaf(Vec::new())
        } else {
            Builder { prims, max_depth }.node(refs, bounds, 0)
        };
        let mut tree = KdTree {
            nodes: Vec::new(),
            indices: Vec::new(),
            bounds,
            stats: TreeStats {
                primitives: kept,
                ..TreeStats::default()
            },
        };
        let area = half_area(bounds.min, bounds.max);
        let cost = tree.flatten(root, 0, bounds);
        tree.stats.sah_cost = if area > 0.0 { cost / area as f64 } else { 0.0 };
        tree.stats.nodes = tree.nodes.len();
        tree
    }

    /// Appends `b` depth first; returns its SAH cost weighted by box area.
    fn flatten(&mut self, b: Build, depth: usize, bx: Aabb) -> f64 {
        self.stats.max_depth = self.stats.max_depth.max(depth);
        let area = half_area(bx.min, bx.max) as f64;
        match b {
            Build::Leaf(ids) => {
                self.stats.leaves += 1;
                self.stats.empty_leaves += ids.is_empty() as usize;
                self.stats.references += ids.len();
                self.nodes.push(KdNode {
                    a: 3 | ((ids.len() as u32) << 2),
                    b: self.indices.len() as u32,
                });
                self.indices.extend_from_slice(&ids);
                area * COST_INTERSECT as f64 * ids.len() as f64
            }
            Build::Inner {
                axis,
                split,
                below,
                above,
            } => {
                let me = self.nodes.len();
                self.nodes.push(KdNode {
                    a: axis as u32,
                    b: split.to_bits(),
                });
                let mut bb = bx;
                bb.max[axis] = split;
                let mut ab = bx;
                ab.min[axis] = split;
                let cb = self.flatten(*below, depth + 1, bb);
                let above_index = self.nodes.len() as u32;
                self.nodes[me].a |= above_index << 2;
                let ca = self.flatten(*above, depth + 1, ab);
                area * COST_TRAVERSE as f64 + cb + ca
            }
        }
    }

    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The nodes, depth first from the root (index 0); see [`KdNode`] for the encoding.
    pub fn nodes(&self) -> &[KdNode] {
        &self.nodes
    }

    /// The leaves' primitive lists, one after another (a leaf holds `count` entries from
    /// its `offset`).
    pub fn leaf_indices(&self) -> &[u32] {
        &self.indices
    }

    pub fn stats(&self) -> TreeStats {
        self.stats
    }

    /// The tree cut `depth` levels below the root: every node at that depth and every leaf
    /// above it, with its cell, left to right; empty leaves are left out. Every reference
    /// lies in exactly the leaves under one of them.
    pub fn subtrees(&self, depth: usize) -> Vec<(u32, Aabb)> {
        let mut out = Vec::new();
        if self.bounds.is_empty() {
            return out;
        }
        let mut todo = vec![(0u32, self.bounds, 0usize)];
        while let Some((node, cell, d)) = todo.pop() {
            let n = self.nodes[node as usize];
            if n.is_leaf() {
                if n.a >> 2 > 0 {
                    out.push((node, cell));
                }
                continue;
            }
            if d == depth {
                out.push((node, cell));
                continue;
            }
            let axis = (n.a & 3) as usize;
            let split = f32::from_bits(n.b);
            let mut below = cell;
            below.max[axis] = split;
            let mut above = cell;
            above.min[axis] = split;
            todo.push((n.a >> 2, above, d + 1));
            todo.push((node + 1, below, d + 1));
        }
        out
    }

    /// The primitives referenced by the leaves under `node` (with repeats).
    pub fn subtree_primitives(&self, node: u32) -> Vec<u32> {
        let mut out = Vec::new();
        let mut todo = vec![node];
        while let Some(k) = todo.pop() {
            let n = self.nodes[k as usize];
            if n.is_leaf() {
                let (count, off) = ((n.a >> 2) as usize, n.b as usize);
                out.extend_from_slice(&self.indices[off..off + count]);
            } else {
                todo.push(n.a >> 2);
                todo.push(k + 1);
            }
        }
        out
    }

    /// Bytes of nodes and leaf index lists.
    pub fn memory_bytes(&self) -> u64 {
        (self.nodes.capacity() * std::mem::size_of::<KdNode>() + self.indices.capacity() * 4) as u64
    }

    /// Short-stack traversal (000 Fig. 1) of the ray `origin + t·dir` over `t_min ≤ t ≤ t_max`.
    /// Leaves are handed to `leaf` in front-to-back order; it returns the current closest
    /// hit distance (`∞` for none, `-∞` to stop at once). Traversal ends when that distance
    /// lies before the end of the leaf's interval (by a relative 1e-5), or when the interval is
    /// used up.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hot path: a struct would only be unpacked again
    pub fn traverse<F: FnMut(&[u32]) -> f32>(
        &self,
        origin: Vec3,
        inv_dir: Vec3,
        t_min: f32,
        t_max: f32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        leaf: F,
    ) {
        self.traverse_subtree(
            0,
            &self.bounds,
            origin,
            inv_dir,
            t_min,
            t_max,
            cfg,
            stats,
            leaf,
        )
    }

    /// [`KdTree::traverse`] of the subtree under `root` alone, over the part of the ray in
    /// `bounds`: a box that holds every reference of the subtree's leaves (about its cell,
    /// see [`KdTree::subtrees`]). Leaves outside the subtree are never visited; kd-restart
    /// restarts from `root`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hot path, as `traverse`
    pub fn traverse_subtree<F: FnMut(&[u32]) -> f32>(
        &self,
        root: u32,
        bounds: &Aabb,
        origin: Vec3,
        inv_dir: Vec3,
        t_min: f32,
        t_max: f32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        mut leaf: F,
    ) {
        let Some((scene_min, scene_max)) =
            ray_box(origin, inv_dir, bounds.min, bounds.max, t_min, t_max)
        else {
            return;
        };
        let subtree = root;
        let mut stack = ShortStack::<(u32, f32, f32)>::new(cfg.stack_size);
        let mut root = root;
        let mut first = true;
        let o = origin.to_array();
        let inv = inv_dir.to_array();
        let mut tmin;
        let mut tmax = scene_min;
        while tmax < scene_max || first {
            let mut node;
            let mut pushdown;
            if stack.is_empty() {
                if !first {
                    stats.restarts += 1;
                }
                first = false;
                node = root;
                tmin = tmax;
                tmax = scene_max;
                pushdown = true;
            } else {
                (node, tmin, tmax) = stack.pop();
                pushdown = false;
            }
            let mut n = self.nodes[node as usize];
            while !n.is_leaf() {
                stats.nodes += 1;
                let axis = (n.a & 3) as usize;
                let split = f32::from_bits(n.b);
                let t_split = (split - o[axis]) * inv[axis];
                let below = node + 1;
                let above = n.a >> 2;
                let (one, two) = if inv[axis] < 0.0 {
                    (above, below)
                } else {
                    (below, above)
                };
                // Children ordered by direction: `one` holds the ray before the plane. With
                // t_min ≥ 0 the paper's extra `t_split < 0` test is implied by `t_split ≤ t_min`.
                if t_split >= tmax {
                    node = one;
                } else if t_split <= tmin {
                    node = two;
                } else if t_split.is_nan() {
                    // The ray lies in the plane (zero direction, origin on it): both children
                    // cover the same interval, which kd-restart cannot order. Rare; visit
                    // every leaf the ray touches instead.
                    self.traverse_all(
                        subtree, origin, inv_dir, scene_min, scene_max, stats, &mut leaf,
                    );
                    return;
                } else {
                    stack.push((two, t_split, tmax));
                    node = one;
                    tmax = t_split;
                    pushdown = false;
                }
                if pushdown {
                    root = node;
                }
                n = self.nodes[node as usize];
            }
            stats.leaves += 1;
            let count = (n.a >> 2) as usize;
            let off = n.b as usize;
            let best = leaf(&self.indices[off..off + count]);
            // Stop only when the hit lies clearly before the leaf's end: a hit computed a few
            // ulps short of a boundary (e.g. at a vertex on a split plane) may have an equally
            // near rival in the next leaf, and the tie rule must see both.
            if best + TERMINATION_SLACK * tmax.abs() < tmax {
                return;
            }
        }
    }

    /// Short-stack traversal of a packet of [`PACKET`] rays at once (lanes in `mask`): one
    /// walk down the tree serves every lane, so a node is fetched once for the packet rather
    /// than once per ray. The lanes in `mask` must share the sign of every direction
    /// component and have finite `inv_dir` (see [`packet_compatible`]); the near/far order
    /// is then the same for all of them.
    ///
    /// Each lane keeps its own interval, exactly as [`KdTree::traverse`] would for that ray
    /// alone (a lane goes into the children the single-ray rule sends it to), so every lane
    /// sees its leaves front to back. The short stack holds `(node, lanes, intervals)`; when
    /// it underflows, each unfinished lane restarts from where its last leaf ended
    /// (kd-restart per lane). `leaf(prims, lanes, t_min, t_max)` tests the lanes `lanes` of
    /// the leaf (their intervals in `t_min`/`t_max`) and returns every lane's closest hit
    /// distance (`-∞` to finish a lane at once); a lane finishes as in the single-ray rule.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hot path, as `traverse`
    pub fn traverse_packet<
        F: FnMut(&[u32], u32, &[f32; PACKET], &[f32; PACKET]) -> [f32; PACKET],
    >(
        &self,
        origin: &[[f32; PACKET]; 3],
        inv_dir: &[[f32; PACKET]; 3],
        t_min: &[f32; PACKET],
        t_max: &[f32; PACKET],
        mask: u32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        leaf: F,
    ) {
        self.traverse_packet_subtree(
            0,
            &self.bounds,
            origin,
            inv_dir,
            t_min,
            t_max,
            mask,
            cfg,
            stats,
            leaf,
        )
    }

    /// [`KdTree::traverse_packet`] of the subtree under `root` alone, over the part of each
    /// lane's ray in `bounds` (as [`KdTree::traverse_subtree`]).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the hot path, as `traverse`
    pub fn traverse_packet_subtree<
        F: FnMut(&[u32], u32, &[f32; PACKET], &[f32; PACKET]) -> [f32; PACKET],
    >(
        &self,
        root: u32,
        bounds: &Aabb,
        origin: &[[f32; PACKET]; 3],
        inv_dir: &[[f32; PACKET]; 3],
        t_min: &[f32; PACKET],
        t_max: &[f32; PACKET],
        mask: u32,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        mut leaf: F,
    ) {
        // Each lane's interval inside the tree's box.
        let mut scene_min = [0f32; PACKET];
        let mut scene_max = [0f32; PACKET];
        let mut alive = 0u32;
        for l in 0..PACKET {
            if mask >> l & 1 == 0 {
                continue;
            }
            let (o, inv) = (lane(origin, l), lane(inv_dir, l));
            if let Some((a, b)) = ray_box(o, inv, bounds.min, bounds.max, t_min[l], t_max[l]) {
                scene_min[l] = a;
                scene_max[l] = b;
                alive |= 1 << l;
            }
        }
        if alive == 0 {
            return;
        }
        let lead = alive.trailing_zeros() as usize;
        let negative = [
            inv_dir[0][lead] < 0.0,
            inv_dir[1][lead] < 0.0,
            inv_dir[2][lead] < 0.0,
        ];
        // Four lanes in SSE registers: one node step is a handful of vector instructions
        // and two lane masks, with no branch per lane.
        let o4 = origin.map(Vec4::from_array);
        let inv4 = inv_dir.map(Vec4::from_array);
        let scene_max4 = Vec4::from_array(scene_max);
        let mut stack = ShortStack::<(u32, u32, Vec4, Vec4)>::new(cfg.stack_size);
        let mut root = root;
        let mut first = true;
        // Where each lane's processed part of its interval ends.
        let mut done = Vec4::from_array(scene_min);
        loop {
            let mut node;
            let mut lanes;
            let tmin;
            let mut tmax;
            let mut pushdown;
            if stack.is_empty() {
                // Lanes with a part of their interval left.
                let left = if first {
                    alive
                } else {
                    alive & done.cmplt(scene_max4).bitmask()
                };
                if left == 0 {
                    return;
                }
                if !first {
                    stats.restarts += 1;
                }
                first = false;
                node = root;
                lanes = left;
                tmin = done;
                tmax = scene_max4;
                pushdown = true;
            } else {
                let pushed;
                (node, pushed, tmin, tmax) = stack.pop();
                // Lanes finished since the push drop out.
                lanes = pushed & alive;
                pushdown = false;
                if lanes == 0 {
                    continue;
                }
            }
            let mut n = self.nodes[node as usize];
            while !n.is_leaf() {
                stats.nodes += 1;
                let axis = (n.a & 3) as usize;
                let split = f32::from_bits(n.b);
                let below = node + 1;
                let above = n.a >> 2;
                let (one, two) = if negative[axis] {
                    (above, below)
                } else {
                    (below, above)
                };
                // The single-ray rule per lane: `d ≥ t_max` near only, else `d ≤ t_min` far
                // only, else both.
                let d = (Vec4::splat(split) - o4[axis]) * inv4[axis];
                let ge_max = d.cmpge(tmax).bitmask();
                let le_min = d.cmple(tmin).bitmask();
                let near = lanes & (ge_max | !le_min);
                let far = lanes & !ge_max;
                if far == 0 {
                    node = one;
                } else if near == 0 {
                    node = two;
                } else {
                    stack.push((two, far, tmin.max(d), tmax));
                    node = one;
                    lanes = near;
                    tmax = tmax.min(d);
                    pushdown = false;
                }
                if pushdown {
                    root = node;
                }
                n = self.nodes[node as usize];
            }
            stats.leaves += 1;
            let count = (n.a >> 2) as usize;
            let off = n.b as usize;
            let (lo, hi) = (tmin.to_array(), tmax.to_array());
            let best = Vec4::from_array(leaf(&self.indices[off..off + count], lanes, &lo, &hi));
            let in_leaf = BVec4A::new(
                lanes & 1 != 0,
                lanes & 2 != 0,
                lanes & 4 != 0,
                lanes & 8 != 0,
            );
            done = Vec4::select(in_leaf, tmax, done);
            // The single-ray termination rule, per lane.
            let finished = (best + TERMINATION_SLACK * tmax.abs())
                .cmplt(tmax)
                .bitmask()
                & lanes;
            alive &= !finished;
            if alive == 0 {
                return;
            }
        }
    }

    /// Visits every leaf the segment touches, without early exit except when `leaf` returns
    /// `-∞`; skips subtrees that start beyond the current closest hit.
    #[allow(clippy::too_many_arguments)]
    fn traverse_all<F: FnMut(&[u32]) -> f32>(
        &self,
        root: u32,
        origin: Vec3,
        inv_dir: Vec3,
        t_min: f32,
        t_max: f32,
        stats: &mut TraceStats,
        leaf: &mut F,
    ) {
        let mut best = f32::INFINITY;
        let mut stack: Vec<(u32, f32, f32)> = vec![(root, t_min, t_max)];
        while let Some((mut node, tmin, mut tmax)) = stack.pop() {
            if best + TERMINATION_SLACK * tmin.abs() < tmin {
                continue;
            }
            let mut n = self.nodes[node as usize];
            while !n.is_leaf() {
                stats.nodes += 1;
                let axis = (n.a & 3) as usize;
                let t_split = (f32::from_bits(n.b) - origin[axis]) * inv_dir[axis];
                let below = node + 1;
                let above = n.a >> 2;
                let (one, two) = if inv_dir[axis] < 0.0 {
                    (above, below)
                } else {
                    (below, above)
                };
                if t_split >= tmax {
                    node = one;
                } else if t_split <= tmin {
                    node = two;
                } else if t_split.is_nan() {
                    stack.push((two, tmin, tmax));
                    node = one;
                } else {
                    stack.push((two, t_split, tmax));
                    node = one;
                    tmax = t_split;
                }
                n = self.nodes[node as usize];
            }
            stats.leaves += 1;
            let (count, off) = ((n.a >> 2) as usize, n.b as usize);
            best = leaf(&self.indices[off..off + count]);
            if best == f32::NEG_INFINITY {
                return;
            }
        }
    }

    /// Every leaf the segment touches, without a stack limit (for tests): the indices of the
    /// leaves' primitives, in traversal order, with duplicates.
    pub fn leaves_along(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Vec<u32> {
        let mut out = Vec::new();
        let mut stats = TraceStats::default();
        self.traverse(
            origin,
            crate::ray::inverse_dir(dir),
            t_min,
            t_max,
            TraversalConfig::UNBOUNDED,
            &mut stats,
            |p| {
                out.extend_from_slice(p);
                f32::INFINITY
            },
        );
        out
    }
}
