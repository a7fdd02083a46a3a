//! The Weber & Penn (1995) stem recursion: trunk, clones (splits), child stems and leaves,
//! turned into tapered tube meshes (wood) and leaf quads (leaf).
//!
//! Determinism: the trunk is grown with one random stream; every level-1 branch (with its whole
//! subtree) gets its own stream derived from the seed and its index, so branches can be grown
//! in parallel and concatenated in index order with the same result on any thread count.

use super::params::Params;
use crate::rng::Rng;
use glam::{Quat, Vec3};
use rayon::prelude::*;
use std::f32::consts::TAU;
use std::sync::atomic::{AtomicUsize, Ordering};
use sylva_geom::Mesh;

/// Material id of bark triangles.
pub const WOOD: u8 = 0;
/// Material id of leaf triangles.
pub const LEAF: u8 = 1;

/// Refuses runaway parameter sets (e.g. many splits per segment) before they exhaust memory.
pub const DEFAULT_MAX_TRIANGLES: usize = 20_000_000;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GenerateError {
    #[error("the tree would exceed {limit} triangles (lower Leaves, nBranches, nSegSplits or nCurveRes)")]
    TooManyTriangles { limit: usize },
    #[error(transparent)]
    Param(#[from] super::params::ParamError),
    /// A leaf whose measured optics its texture cannot carry.
    #[error("{0}")]
    Optics(String),
}

/// Shape ratio of Weber & Penn, for `shape` 0-8 at position `ratio` in [0, 1].
pub fn shape_ratio(shape: u32, ratio: f64, p: &Params) -> f64 {
    let r = ratio.clamp(0.0, 1.0);
    match shape {
        0 => 0.2 + 0.8 * r,
        1 => 0.2 + 0.8 * (std::f64::consts::PI * r).sin(),
        2 => 0.2 + 0.8 * (0.5 * std::f64::consts::PI * r).sin(),
        3 => 1.0,
        4 => 0.5 + 0.5 * r,
        5 => {
            if r <= 0.7 {
                r / 0.7
            } else {
                (1.0 - r) / 0.3
            }
        }
        6 => 1.0 - 0.8 * r,
        7 => {
            if r <= 0.7 {
                0.5 + 0.5 * r / 0.7
            } else {
                0.5 + 0.5 * (1.0 - r) / 0.3
            }
        }
        _ => envelope(1.0 - r, p),
    }
}

/// The pruning envelope's relative width at relative height `h` above the base (0..1), in
/// [0, 1]: widest (1) at `PruneWidthPeak`. Clamped because negative `PrunePower*` values
/// would otherwise grow without bound towards the ends.
fn envelope(h: f64, p: &Params) -> f64 {
    let g = &p.general;
    if !(0.0..=1.0).contains(&h) {
        return 0.0;
    }
    let peak = g.prune_width_peak;
    let w = if h < peak {
        (h / peak.max(1e-9)).powf(g.prune_power_high)
    } else {
        ((1.0 - h) / (1.0 - peak).max(1e-9)).powf(g.prune_power_low)
    };
    if w.is_finite() {
        w.clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// Cross-section sides per level: more with `Smooth`, fewer for finer stems.
fn stem_sides(p: &Params, level: usize) -> usize {
    let base = [16.0, 8.0, 5.0, 4.0][level.min(3)];
    let n = (base * (0.5 + p.general.smooth)).round() as usize;
    let n = n.max(3);
    if level == 0 && p.general.lobes > 0.0 {
        n.max(4 * p.general.lobes as usize)
    } else {
        n
    }
}

/// A stem to grow: where it starts and the quantities Weber & Penn derive from its parent.
#[derive(Debug, Clone)]
struct StemSeed {
    level: usize,
    origin: Vec3,
    /// Orientation: the stem grows along the rotated +y.
    rot: Quat,
    length: f64,
    radius: f64,
    /// Distance of the stem's base along its parent.
    offset: f64,
    parent_length: f64,
    /// nLength ± nLengthV drawn for this stem (its children's count depends on it).
    length_child_max: f64,
}

/// Tree-wide quantities.
struct Tree<'a> {
    p: &'a Params,
    levels: usize,
    scale_tree: f64,
    base_length: f64,
    leaf_length: f32,
    leaf_width: f32,
    max_triangles: usize,
    /// Triangles emitted by all growers so far: stops runaway trees early on any thread.
    emitted: AtomicUsize,
    /// Stem walks started plus level-1 stems queued. Every walk that does not split emits at
    /// least 6 triangles and at least half the walks do not split, so the final triangle count
    /// is at least 1.5 × this: a bound that catches split cascades before they emit anything.
    stem_work: AtomicUsize,
}

/// Grows stems into one mesh with one random stream.
struct Grower<'t, 'a> {
    tree: &'t Tree<'a>,
    rng: Rng,
    mesh: Mesh,
    /// Level-1 stems found while growing the trunk; grown later, each with its own stream.
    deferred: Option<Vec<StemSeed>>,
}

impl Tree<'_> {
    /// Radius of `stem` at fraction `z` of its length (taper, trunk flare), before lobes.
    fn radius_at(&self, stem: &StemSeed, z: f64) -> f64 {
        let taper = self.p.levels[stem.level].taper;
        let unit_taper = if taper < 1.0 {
            taper
        } else if taper < 2.0 {
            2.0 - taper
        } else {
            0.0
        };
        let taper_z = stem.radius * (1.0 - unit_taper * z);
        let mut r = if taper < 1.0 {
            taper_z
        } else {
            let z2 = (1.0 - z) * stem.length;
            let depth = if taper < 2.0 || z2 < taper_z {
                1.0
            } else {
                taper - 2.0
            };
            let z3 = if taper < 2.0 {
                z2
            } else {
                (z2 - 2.0 * taper_z * (z2 / (2.0 * taper_z) + 0.5).floor()).abs()
            };
            if taper < 2.0 && z3 >= taper_z {
                taper_z
            } else {
                let s = (taper_z * taper_z - (z3 - taper_z).powi(2)).max(0.0).sqrt();
                (1.0 - depth) * taper_z + depth * s
            }
        };
        if stem.level == 0 {
            let y = (1.0 - 8.0 * z).max(0.0);
            r *= self.p.general.flare * (100f64.powf(y) - 1.0) / 100.0 + 1.0;
        }
        r.max(stem.radius * 0.02)
    }

    /// Whether a point lies inside the pruning envelope.
    fn inside_envelope(&self, pt: Vec3) -> bool {
        let g = &self.p.general;
        let h = (pt.y as f64 - g.base_size * self.scale_tree)
            / (self.scale_tree * (1.0 - g.base_size)).max(1e-9);
        let r = ((pt.x * pt.x + pt.z * pt.z) as f64).sqrt() / self.scale_tree;
        h <= 1.0 && r <= g.prune_width * envelope(h.max(0.0), self.p) + 1e-9
    }
}

impl<'t, 'a> Grower<'t, 'a> {
    fn check_budget(&self) -> Result<(), GenerateError> {
        // The running total only grows, so exceeding it early implies the final count would:
        // the outcome does not depend on thread timing.
        let work_bound = self.tree.stem_work.load(Ordering::Relaxed) as f64 * 1.5;
        if self.tree.emitted.load(Ordering::Relaxed) > self.tree.max_triangles
            || work_bound > self.tree.max_triangles as f64
        {
            return Err(GenerateError::TooManyTriangles {
                limit: self.tree.max_triangles,
            });
        }
        Ok(())
    }

    fn grow(&mut self, stem: &StemSeed) -> Result<(), GenerateError> {
        let tree = self.tree;
        // Children (or leaves) this stem carries, spread over its segments.
        let carries_leaves = stem.level + 1 == tree.levels;
        let total_children = if carries_leaves {
            let pos = if stem.level == 0 {
                1.0
            } else {
                shape_ratio(
                    tree.p.general.leaf_distrib as u32,
                    stem.offset / stem.parent_length,
                    tree.p,
                )
            };
            tree.p.general.leaves.abs() * pos * tree.p.general.leaf_quality
        } else {
            let cp = &tree.p.levels[stem.level + 1];
            match stem.level {
                0 => cp.branches,
                1 => {
                    cp.branches
                        * (0.2
                            + 0.8 * (stem.length / stem.parent_length)
                                / stem.length_child_max.max(1e-9))
                }
                _ => cp.branches * (1.0 - 0.5 * stem.offset / stem.parent_length),
            }
        };
        let mut state = WalkState {
            child_error: 0.0,
            split_error: 0.0,
            child_rotation: self.rng.range(0.0, 360.0),
        };
        self.walk(
            stem,
            stem.origin,
            stem.rot,
            0,
            true,
            total_children,
            carries_leaves,
            &mut state,
        )
    }

    /// Grows `stem` from segment `seg_start` at `pos`/`rot` to its tip; clones recurse.
    #[allow(clippy::too_many_arguments)]
    fn walk(
        &mut self,
        stem: &StemSeed,
        mut pos: Vec3,
        mut rot: Quat,
        seg_start: usize,
        check_split_first: bool,
        total_children: f64,
        carries_leaves: bool,
        state: &mut WalkState,
    ) -> Result<(), GenerateError> {
        let tree = self.tree;
        tree.stem_work.fetch_add(1, Ordering::Relaxed);
        self.check_budget()?;
        let p = tree.p;
        let lp = &p.levels[stem.level];
        let res = lp.curve_res as usize;
        let seg_len = (stem.length / res as f64) as f32;
        // Sub-rings per segment: the trunk needs more for its flare.
        let sub = if stem.level == 0 { 3 } else { 1 };
        let mut rings: Vec<(Vec3, Quat, f64)> = vec![(pos, rot, seg_start as f64 / res as f64)];
        for seg in seg_start..res {
            // Splits at the start of this segment (base splits only on the trunk's first).
            if seg > seg_start || check_split_first {
                let n = if seg == 0 {
                    if stem.level == 0 {
                        lp.base_splits as usize
                    } else {
                        0
                    }
                } else {
                    let want = lp.seg_splits + state.split_error;
                    let n = want.round().max(0.0);
                    state.split_error = want - n;
                    n as usize
                };
                if n > 0 {
                    self.emit_tube(stem, &rings);
                    let axis = rot * Vec3::Y;
                    let declination = axis.y.clamp(-1.0, 1.0).acos().to_degrees() as f64;
                    let base_az = self.rng.range(0.0, 360.0);
                    for k in 0..=n {
                        let angle_split = (lp.split_angle + self.rng.var(lp.split_angle_v)
                            - if seg == 0 { 0.0 } else { declination })
                        .max(0.0);
                        let az = if seg == 0 {
                            base_az + 360.0 * k as f64 / (n + 1) as f64
                        } else if k == 0 {
                            0.0
                        } else {
                            let r = self.rng.uniform();
                            let spread = 20.0 + 0.75 * (30.0 + (declination - 90.0).abs()) * r * r;
                            if k % 2 == 1 {
                                spread
                            } else {
                                -spread
                            }
                        };
                        let tilted = rot * Quat::from_rotation_x(angle_split.to_radians() as f32);
                        let clone_rot = Quat::from_rotation_y(az.to_radians() as f32) * tilted;
                        self.walk(
                            stem,
                            pos,
                            clone_rot,
                            seg,
                            false,
                            total_children,
                            carries_leaves,
                            state,
                        )?;
                    }
                    return Ok(());
                }
            }
            // Curvature of this segment.
            let mut bend = if lp.curve_back == 0.0 {
                lp.curve / res as f64
            } else if seg < res.div_ceil(2) {
                lp.curve / (res as f64 / 2.0)
            } else {
                lp.curve_back / (res as f64 / 2.0)
            };
            bend += self.rng.var(lp.curve_v.abs()) / res as f64;
            if seg > 0 || stem.level > 0 {
                rot = (rot * Quat::from_rotation_x(bend.to_radians() as f32)).normalize();
            }
            if stem.level >= 2 && p.general.attraction_up != 0.0 {
                // Bend towards (or, negative, away from) the vertical, strongest when horizontal.
                let axis = rot * Vec3::Y;
                let decl = axis.y.clamp(-1.0, 1.0).acos();
                let turn = (p.general.attraction_up as f32 * decl * decl.sin().abs() / res as f32)
                    .clamp(-decl, std::f32::consts::PI - decl);
                let side = axis.cross(Vec3::Y);
                if side.length_squared() > 1e-8 {
                    rot = (Quat::from_axis_angle(side.normalize(), turn) * rot).normalize();
                }
            }
            let dir = rot * Vec3::Y;
            let next = pos + dir * seg_len;
            // Children or leaves in this segment.
            let seg_z0 = seg as f64 / res as f64;
            let seg_z1 = (seg + 1) as f64 / res as f64;
            let share = if stem.level == 0 && !carries_leaves {
                // Branches only above the bare base of the trunk.
                let bz = p.general.base_size;
                let overlap = (seg_z1.min(1.0) - seg_z0.max(bz)).max(0.0);
                total_children * overlap / (1.0 - bz).max(1e-9)
            } else {
                total_children / res as f64
            };
            let want = share + state.child_error;
            if want.is_nan() || want >= tree.max_triangles as f64 {
                // No stem may carry more children than the budget.
                return Err(GenerateError::TooManyTriangles {
                    limit: tree.max_triangles,
                });
            }
            let count = want.round().max(0.0);
            state.child_error = want - count;
            let count = count as usize;
            for j in 0..count {
                let t = (j as f64 + 0.5) / count as f64;
                let (lo, hi) = if stem.level == 0 && !carries_leaves {
                    (seg_z0.max(p.general.base_size), seg_z1)
                } else {
                    (seg_z0, seg_z1)
                };
                let z = lo + (hi - lo) * t;
                let at = pos + dir * (seg_len * ((z - seg_z0) / (seg_z1 - seg_z0)) as f32);
                if carries_leaves {
                    self.add_leaf(stem, at, rot, state);
                } else {
                    self.add_child(stem, at, rot, z, state)?;
                }
            }
            pos = next;
            for s in 1..=sub {
                let f = s as f32 / sub as f32;
                let z = seg_z0 + (seg_z1 - seg_z0) * f as f64;
                rings.push((pos - dir * seg_len * (1.0 - f), rot, z));
            }
            self.check_budget()?;
        }
        self.emit_tube(stem, &rings);
        self.check_budget()
    }

    /// Rotation about the parent for the next child.
    fn next_rotation(&mut self, level: usize, state: &mut WalkState) -> f64 {
        let lp = &self.tree.p.levels[level.min(3)];
        if lp.rotate >= 0.0 {
            state.child_rotation += lp.rotate + self.rng.var(lp.rotate_v);
        } else {
            // Alternating (opposite) arrangement.
            state.child_rotation += 180.0 + lp.rotate + self.rng.var(lp.rotate_v);
        }
        state.child_rotation
    }

    fn down_angle(&mut self, level: usize, parent: &StemSeed, offset: f64) -> f64 {
        let lp = &self.tree.p.levels[level.min(3)];
        if lp.down_angle_v >= 0.0 {
            lp.down_angle + self.rng.var(lp.down_angle_v)
        } else {
            let ratio = if parent.level == 0 {
                (parent.length - offset) / (parent.length - self.tree.base_length).max(1e-9)
            } else {
                (parent.length - offset) / parent.length.max(1e-9)
            };
            lp.down_angle + lp.down_angle_v * (1.0 - 2.0 * shape_ratio(0, ratio, self.tree.p))
        }
    }

    fn add_child(
        &mut self,
        parent: &StemSeed,
        at: Vec3,
        parent_rot: Quat,
        z: f64,
        state: &mut WalkState,
    ) -> Result<(), GenerateError> {
        let tree = self.tree;
        let p = tree.p;
        let level = parent.level + 1;
        let lp = &p.levels[level];
        let offset = z * parent.length;
        let length_child_max = (lp.length + self.rng.var(lp.length_v)).max(0.0);
        let mut length = if level == 1 {
            let ratio = (parent.length - offset) / (parent.length - tree.base_length).max(1e-9);
            parent.length * length_child_max * shape_ratio(p.general.shape as u32, ratio, p)
        } else {
            length_child_max * (parent.length - 0.6 * offset)
        };
        let rotate = self.next_rotation(level, state);
        let down = self.down_angle(level, parent, offset);
        let rot = (parent_rot
            * Quat::from_rotation_y(rotate.to_radians() as f32)
            * Quat::from_rotation_z(down.to_radians() as f32))
        .normalize();
        if p.general.prune_ratio > 0.0 && length > 0.0 {
            // Shorten until the (straight) tip is inside the envelope, then blend by PruneRatio.
            let dir = rot * Vec3::Y;
            let mut pruned = length;
            for _ in 0..30 {
                if tree.inside_envelope(at + dir * pruned as f32) {
                    break;
                }
                pruned *= 0.85;
            }
            length = length * (1.0 - p.general.prune_ratio) + pruned * p.general.prune_ratio;
        }
        if length <= 1e-4 {
            return Ok(());
        }
        let scale = (lp.scale + self.rng.var(lp.scale_v)).max(1e-6);
        let radius = (parent.radius * (length / parent.length).powf(p.general.ratio_power) * scale)
            .min(tree.radius_at(parent, z))
            .max(1e-5);
        let seed = StemSeed {
            level,
            origin: at,
            rot,
            length,
            radius,
            offset,
            parent_length: parent.length,
            length_child_max,
        };
        match self.deferred.as_mut() {
            Some(list) if level == 1 => {
                tree.stem_work.fetch_add(1, Ordering::Relaxed);
                list.push(seed);
                self.check_budget()?;
            }
            _ => self.grow(&seed)?,
        }
        Ok(())
    }

    fn add_leaf(&mut self, stem: &StemSeed, at: Vec3, stem_rot: Quat, state: &mut WalkState) {
        let tree = self.tree;
        let p = tree.p;
        let level = tree.levels.min(3);
        let rotate = self.next_rotation(level, state);
        let down = self.down_angle(level, stem, 0.0);
        let mut rot = (stem_rot
            * Quat::from_rotation_y(rotate.to_radians() as f32)
            * Quat::from_rotation_z(down.to_radians() as f32))
        .normalize();
        // LeafBend: turn the leaf about its axis so its face looks up.
        if p.general.leaf_bend > 0.0 {
            let axis = rot * Vec3::Y;
            let normal = rot * Vec3::Z;
            let want = (Vec3::Y - axis * axis.y).normalize_or_zero();
            if want != Vec3::ZERO {
                let angle = normal.cross(want).dot(axis).atan2(normal.dot(want));
                rot = (Quat::from_axis_angle(axis, angle * p.general.leaf_bend as f32) * rot)
                    .normalize();
            }
        }
        let axis = rot * Vec3::Y;
        let side = rot * Vec3::X;
        let normal = rot * Vec3::Z;
        let (len, half_w) = (tree.leaf_length, 0.5 * tree.leaf_width);
        let base = at + axis * (len * p.general.leaf_stem_len as f32 * 0.3);
        let m = &mut self.mesh;
        let a = m.push_vertex(base - side * half_w, normal, [0.0, 0.0]);
        let b = m.push_vertex(base + side * half_w, normal, [1.0, 0.0]);
        let c = m.push_vertex(base + side * half_w + axis * len, normal, [1.0, 1.0]);
        let d = m.push_vertex(base - side * half_w + axis * len, normal, [0.0, 1.0]);
        m.push_triangle(a, b, c, LEAF);
        m.push_triangle(a, c, d, LEAF);
        self.tree.emitted.fetch_add(2, Ordering::Relaxed);
    }

    /// Appends the tube through `rings` (centre, frame, z along the stem).
    fn emit_tube(&mut self, stem: &StemSeed, rings: &[(Vec3, Quat, f64)]) {
        if rings.len() < 2 {
            return;
        }
        let tree = self.tree;
        let sides = stem_sides(tree.p, stem.level);
        let lobes = tree.p.general.lobes as f32;
        let lobe_depth = tree.p.general.lobe_depth as f32;
        // Bark repeats every BARK_TILE metres along the stem and about every BARK_TILE around it.
        const BARK_TILE: f32 = 0.5;
        let around = ((TAU * stem.radius as f32 / BARK_TILE).round()).max(1.0);
        let m = &mut self.mesh;
        let first = m.positions.len() as u32;
        for (center, rot, z) in rings {
            let r = tree.radius_at(stem, *z) as f32;
            let v = (*z * stem.length) as f32 / BARK_TILE;
            for s in 0..=sides {
                let a = TAU * s as f32 / sides as f32;
                let radial = *rot * Vec3::new(a.cos(), 0.0, a.sin());
                let rr = if stem.level == 0 && lobes > 0.0 {
                    r * (1.0 + lobe_depth * (lobes * a).sin())
                } else {
                    r
                };
                m.push_vertex(
                    *center + radial * rr,
                    radial,
                    [around * s as f32 / sides as f32, v],
                );
            }
        }
        let row = sides as u32 + 1;
        for k in 0..rings.len() as u32 - 1 {
            for s in 0..sides as u32 {
                let a = first + k * row + s;
                let b = a + 1;
                let c = a + row;
                let d = c + 1;
                m.push_triangle(a, c, b, WOOD);
                m.push_triangle(b, c, d, WOOD);
            }
        }
        self.tree
            .emitted
            .fetch_add(2 * sides * (rings.len() - 1), Ordering::Relaxed);
    }
}

struct WalkState {
    child_error: f64,
    split_error: f64,
    child_rotation: f64,
}

/// Generates the tree for `params` and `seed`: wood triangles carry [`WOOD`], leaves [`LEAF`].
/// The trunk base is at the origin, growing along +y.
pub fn generate(params: &Params, seed: u64) -> Result<Mesh, GenerateError> {
    generate_with_limit(params, seed, DEFAULT_MAX_TRIANGLES)
}

/// [`generate`] with an explicit triangle budget.
pub fn generate_with_limit(
    params: &Params,
    seed: u64,
    max_triangles: usize,
) -> Result<Mesh, GenerateError> {
    params.validate()?;
    let g = &params.general;
    let mut rng = Rng::derive(seed, u64::MAX);
    let scale_tree = (g.scale + rng.var(g.scale_v)).max(1e-3);
    let z_scale = (g.z_scale + rng.var(g.z_scale_v)).max(1e-3);
    let l0 = &params.levels[0];
    let trunk_length = ((l0.length + rng.var(l0.length_v)) * scale_tree).max(1e-3);
    let trunk_radius = trunk_length * g.ratio * (l0.scale + rng.var(l0.scale_v)).max(1e-6);
    let quality = g.leaf_quality.sqrt();
    let tree = Tree {
        p: params,
        levels: params.levels(),
        scale_tree,
        base_length: g.base_size * trunk_length,
        leaf_length: (g.leaf_scale / quality) as f32,
        leaf_width: (g.leaf_scale * g.leaf_scale_x / quality) as f32,
        max_triangles,
        emitted: AtomicUsize::new(0),
        stem_work: AtomicUsize::new(0),
    };
    let trunk = StemSeed {
        level: 0,
        origin: Vec3::ZERO,
        rot: Quat::IDENTITY,
        length: trunk_length,
        radius: trunk_radius,
        offset: 0.0,
        parent_length: trunk_length,
        length_child_max: l0.length,
    };
    let mut grower = Grower {
        tree: &tree,
        rng,
        mesh: Mesh::default(),
        deferred: Some(Vec::new()),
    };
    grower.grow(&trunk)?;
    let branches = grower.deferred.take().unwrap_or_default();
    let mut mesh = grower.mesh;
    let parts: Vec<Result<Mesh, GenerateError>> = branches
        .par_iter()
        .enumerate()
        .map(|(i, b)| {
            let mut g = Grower {
                tree: &tree,
                rng: Rng::derive(seed, i as u64),
                mesh: Mesh::default(),
                deferred: None,
            };
            g.grow(b)?;
            Ok(g.mesh)
        })
        .collect();
    let mut total = mesh.triangle_count();
    for part in &parts {
        let part = part.as_ref().map_err(Clone::clone)?;
        total += part.triangle_count();
        if total > max_triangles {
            return Err(GenerateError::TooManyTriangles {
                limit: max_triangles,
            });
        }
    }
    mesh.positions
        .reserve(parts.iter().flatten().map(|m| m.vertex_count()).sum());
    for part in parts.into_iter().flatten() {
        mesh.append(&part);
    }
    if z_scale != 1.0 {
        let zs = z_scale as f32;
        for (p, n) in mesh.positions.iter_mut().zip(mesh.normals.iter_mut()) {
            p[1] *= zs;
            // Normals transform with the inverse transpose of the stretch.
            let v = Vec3::new(n[0], n[1] / zs, n[2]).normalize_or_zero();
            *n = v.to_array();
        }
    }
    Ok(mesh)
}
