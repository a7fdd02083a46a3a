//! Plant area per cell: the physical occupancy (docs/light.md, docs/voxelize.md).
//!
//! Each triangle is split into `k²` congruent sub-triangles (a regular barycentric lattice)
//! and each sub-triangle's area goes to the cell holding its centroid, counted for a leaf only
//! where the nearest texel there is opaque ([`sylva_geom::is_opaque`]). `k` keeps the pieces
//! below an eighth of a cell (and, on alpha-textured leaves, fine enough to resolve the leaf's
//! outline: at least 32). Areas are summed as 2⁻³² cell² fixed-point integers, so the result
//! is the same for any thread count and triangle order.
//!
//! The pieces are counted without visiting each (a catalpa at 128 has 118 M opaque ones): the
//! opaque ones of a leaf come from a mask per uv layout (a plant's leaves share a few), and
//! runs of pieces along a row that lie in one cell are added at once. Both give exactly the
//! sums of the piece-by-piece rule, which the tests keep as the reference.
//!
//! [`AreaGrid::to_density_grid`] turns leaf and bark area into the LB site density: the
//! probability that light crossing a cell meets a leaf or bark
//! ([`sylva_grid::density::collision_probability`]), and the bark share of it as the wood fraction.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;
use sylva_geom::{is_opaque, MaterialKind, Model, Texture, Wrap};
use sylva_grid::{density::collision_probability, DensityGrid};

use crate::{check_model, check_texture_uvs, GridPlacement, VoxelizeError};

/// Fixed-point scale of summed areas (units of cell²).
const FIXED: f64 = 4_294_967_296.0;

/// Sub-triangles per edge on alpha-textured leaves, at least.
const ALPHA_SPLITS: usize = 32;

/// Sub-triangles per edge, at most.
const MAX_SPLITS: usize = 256;

/// Pieces per cell edge, at least.
const PIECES_PER_CELL: f64 = 8.0;

/// Leaf and bark area in every cell of a placement.
#[derive(Debug, Clone, PartialEq)]
pub struct AreaGrid {
    pub placement: GridPlacement,
    /// One-sided opaque leaf area per cell (model units²), site order.
    pub leaf: Vec<f64>,
    /// Bark surface area per cell (model units²).
    pub bark: Vec<f64>,
}

impl AreaGrid {
    pub fn total_leaf_area(&self) -> f64 {
        self.leaf.iter().sum()
    }

    pub fn total_bark_area(&self) -> f64 {
        self.bark.iter().sum()
    }

    /// The LB density grid: per cell the collision probability of its leaf and bark area,
    /// and bark's share of it as the wood fraction.
    pub fn to_density_grid(&self) -> Result<DensityGrid, VoxelizeError> {
        let cell = self.placement.cell;
        let (density, wood): (Vec<f32>, Vec<f32>) = self
            .leaf
            .par_iter()
            .zip(self.bark.par_iter())
            .map(|(&l, &b)| {
                let (p, w) = collision_probability(l, b, cell);
                (p as f32, w as f32)
            })
            .unzip();
        Ok(DensityGrid::new(
            self.placement.dims,
            self.placement.bounds(),
            density,
            wood,
        )?)
    }
}

/// Opacity of a texture's texels, for nearest-texel lookups.
struct Opacity {
    width: u32,
    height: u32,
    wrap: Wrap,
    opaque: Vec<bool>,
}

impl Opacity {
    fn new(t: &Texture) -> Opacity {
        Opacity {
            width: t.width,
            height: t.height,
            wrap: t.wrap,
            opaque: t.pixels.iter().map(|p| is_opaque(*p)).collect(),
        }
    }

    #[inline]
    fn at(&self, u: f64, v: f64) -> bool {
        let (x, y) = sylva_geom::nearest_texel_coords(
            u as f32,
            v as f32,
            self.width,
            self.height,
            self.wrap,
        );
        self.opaque[(y * self.width + x) as usize]
    }
}

enum Kind {
    Bark,
    Leaf(Option<Opacity>),
    Invisible,
}

/// Relative margin (in cells, per cell of distance from the grid's origin) by which pieces
/// must clear a cell's faces to be counted together in [`plant_area`]: far above the
/// rounding of a piece's centroid (about 1e-16 relative).
const CELL_MARGIN: f64 = 1e-9;

/// `v.floor() as i64` without a library call (x86-64's baseline has no rounding
/// instruction), saturating as the cast does and 0 for NaN.
#[inline(always)]
fn floor_to_i64(v: f64) -> i64 {
    let t = v as i64;
    t.saturating_sub(((t as f64) > v) as i64)
}

/// The two families of a triangle's `k²` sub-triangles, as `(offset, rows)`: row `i` of a
/// family holds `rows - i` pieces with centroids `(i + offset, j + offset) / k`; upright
/// pieces (offset 1/3, `k` rows) come first, inverted ones (2/3, `k - 1` rows) after.
fn piece_rows(k: usize) -> [(f64, usize); 2] {
    [(1.0 / 3.0, k), (2.0 / 3.0, k - 1)]
}

/// The barycentric coordinates `(s, r)` of the centroids of a triangle's `k²` sub-triangles,
/// in [`piece_rows`]' order.
fn pieces(k: usize) -> impl Iterator<Item = (f64, f64)> {
    let inv_k = 1.0 / k as f64;
    piece_rows(k).into_iter().flat_map(move |(offset, rows)| {
        (0..rows).flat_map(move |i| {
            (0..rows - i).map(move |j| ((i as f64 + offset) * inv_k, (j as f64 + offset) * inv_k))
        })
    })
}

/// Which of a leaf triangle's [`pieces`] lie on opaque texels.
struct PieceMask {
    bits: Vec<u64>,
}

impl PieceMask {
    fn new(o: &Opacity, uv: [[f32; 2]; 3], k: usize) -> PieceMask {
        let uv = uv.map(|t| t.map(f64::from));
        let mut bits = vec![0u64; (k * k).div_ceil(64)];
        for (n, (s, r)) in pieces(k).enumerate() {
            let u = uv[0][0] + (uv[1][0] - uv[0][0]) * s + (uv[2][0] - uv[0][0]) * r;
            let v = uv[0][1] + (uv[1][1] - uv[0][1]) * s + (uv[2][1] - uv[0][1]) * r;
            if o.at(u, v) {
                bits[n / 64] |= 1 << (n % 64);
            }
        }
        PieceMask { bits }
    }

    /// Opaque pieces among `from..to`.
    fn count_in(&self, from: usize, to: usize) -> usize {
        let (mut n, mut sum) = (from, 0);
        while n < to {
            let (word, bit) = (n / 64, n % 64);
            let take = (64 - bit).min(to - n);
            let bits = self.bits[word] >> bit;
            let bits = if take == 64 {
                bits
            } else {
                bits & ((1 << take) - 1)
            };
            sum += bits.count_ones() as usize;
            n += take;
        }
        sum
    }
}

/// A mask's key: material, the bits of the triangle's uvs, and `k`.
type MaskKey = (u8, [[u32; 2]; 3], usize);

/// The piece masks a worker met last, keyed by material, uvs and `k`. A plant's leaves
/// share a few uv layouts (every leaf quad maps the whole texture), so this saves nearly
/// every texel lookup; a mask is a function of its key alone, so the result does not
/// depend on which worker built it.
#[derive(Default)]
struct MaskCache {
    entries: Vec<(MaskKey, PieceMask)>,
    next: usize,
}

impl MaskCache {
    const CAPACITY: usize = 8;

    fn get(&mut self, o: &Opacity, material: u8, uv: [[f32; 2]; 3], k: usize) -> &PieceMask {
        let key = (material, uv.map(|t| t.map(f32::to_bits)), k);
        if let Some(at) = self.entries.iter().position(|(e, _)| *e == key) {
            return &self.entries[at].1;
        }
        let mask = PieceMask::new(o, uv, k);
        let at = if self.entries.len() < Self::CAPACITY {
            self.entries.push((key, mask));
            self.entries.len() - 1
        } else {
            let at = self.next;
            self.entries[at] = (key, mask);
            self.next = (at + 1) % Self::CAPACITY;
            at
        };
        &self.entries[at].1
    }
}

/// Leaf and bark area per cell of `placement` (`alpha_test`: leaves count only where their
/// texture is opaque).
pub fn plant_area(
    model: &Model,
    placement: &GridPlacement,
    alpha_test: bool,
) -> Result<AreaGrid, VoxelizeError> {
    check_model(model)?;
    let dims = placement.dims;
    sylva_core::check_memory(
        &format!("the plant area of '{}' on a {dims} grid", model.name),
        dims.sites() as u64 * 2 * 8 * 2,
    )?;
    let mesh = &model.mesh;
    let kinds: Vec<Kind> = model
        .materials
        .iter()
        .map(|m| match (m.kind, &m.texture) {
            (MaterialKind::Wood, _) => Kind::Bark,
            (MaterialKind::Leaf, Some(t)) if alpha_test => {
                let o = Opacity::new(t);
                if !o.opaque.iter().any(|&x| x) {
                    Kind::Invisible
                } else if o.opaque.iter().all(|&x| x) {
                    Kind::Leaf(None)
                } else {
                    Kind::Leaf(Some(o))
                }
            }
            // A solid's opaque surface scatters like a leaf site, never a brown one.
            (MaterialKind::Leaf | MaterialKind::Solid, _) => Kind::Leaf(None),
        })
        .collect();
    check_texture_uvs(model, |material| {
        matches!(kinds[material as usize], Kind::Leaf(Some(_)))
    })?;
    let leaf: Vec<AtomicU64> = (0..dims.sites()).map(|_| AtomicU64::new(0)).collect();
    let bark: Vec<AtomicU64> = (0..dims.sites()).map(|_| AtomicU64::new(0)).collect();
    let origin = DVec3::from_array(placement.origin);
    let inv_cell = 1.0 / placement.cell;
    let hi = [dims.nx - 2, dims.ny - 2, dims.nz - 2].map(|n| n as i64);
    // The cell of a point `q` (in cells from the origin) along axis `a`.
    let axis_cell = |v: f64, a: usize| floor_to_i64(v).clamp(1, hi[a]) as usize;
    mesh.indices
        .par_iter()
        .zip(mesh.material_ids.par_iter())
        .with_min_len(256)
        .for_each_init(
            || (Vec::<(usize, u64)>::new(), MaskCache::default()),
            |(sums, masks), (t, &m)| {
                let kind = &kinds[m as usize];
                if matches!(kind, Kind::Invisible) {
                    return;
                }
                let p = t.map(|i| DVec3::from_array(mesh.positions[i as usize].map(f64::from)));
                let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
                let area_cells = 0.5 * e1.cross(e2).length() * inv_cell * inv_cell;
                // Degenerate (zero or NaN area) triangles hold no area.
                if area_cells.is_nan() || area_cells <= 0.0 {
                    return;
                }
                let longest = e1.length().max(e2.length()).max((p[2] - p[1]).length()) * inv_cell;
                let mut k = ((longest * PIECES_PER_CELL).ceil() as usize).clamp(1, MAX_SPLITS);
                let mask = match kind {
                    Kind::Leaf(Some(o)) => {
                        k = k.max(ALPHA_SPLITS);
                        let uv = t.map(|i| mesh.uvs[i as usize]);
                        Some(masks.get(o, m, uv, k))
                    }
                    _ => None,
                };
                let piece = ((area_cells / (k * k) as f64) * FIXED).round() as u64;
                let target = if matches!(kind, Kind::Bark) {
                    &bark
                } else {
                    &leaf
                };
                // Opaque pieces among `from..to`.
                let count = |from: usize, to: usize| -> u64 {
                    mask.map_or(to - from, |m| m.count_in(from, to)) as u64
                };
                let opaque = count(0, k * k);
                if opaque == 0 {
                    return;
                }
                // Pieces are counted a cell at a time, never one by one: centroids lie in
                // the triangle and a cell index is monotone in each coordinate, so pieces
                // whose centroids lie, by a margin far above their rounding, inside one
                // cell all go to the cell each of them would. A triangle inside one cell
                // gives it all its pieces at once; others walk each row of pieces in runs.
                let q = p.map(|v| (v - origin) * inv_cell);
                let far = q.iter().map(|v| v.abs().max_element()).fold(0.0, f64::max);
                let margin = CELL_MARGIN * (1.0 + far + (origin * inv_cell).abs().max_element());
                let one_cell = |lo: DVec3, hi: DVec3| -> Option<usize> {
                    let (lo, hi) = (lo - margin, hi + margin);
                    let cells = [0, 1, 2].map(|a| (axis_cell(lo[a], a), axis_cell(hi[a], a)));
                    cells
                        .iter()
                        .all(|(l, h)| l == h)
                        .then(|| dims.index(cells[0].0, cells[1].0, cells[2].0))
                };
                if let Some(cell) = one_cell(q[0].min(q[1]).min(q[2]), q[0].max(q[1]).max(q[2])) {
                    target[cell].fetch_add(opaque * piece, Ordering::Relaxed);
                    return;
                }
                sums.clear();
                let mut add = |cell: usize, area: u64| {
                    // Consecutive pieces mostly share a cell: look at the last one first.
                    match sums.iter().rposition(|(c, _)| *c == cell) {
                        Some(at) => sums[at].1 += area,
                        None => sums.push((cell, area)),
                    }
                };
                let inv_k = 1.0 / k as f64;
                // From one centroid of a row to the next, in cells.
                let step = e2 * inv_k * inv_cell;
                // Its reciprocal: a run's length is rounded down to whole pieces after a
                // margin of about 1e-6 pieces, far above a product's rounding.
                let per_step = step.recip();
                let mut n0 = 0;
                for (offset, rows) in piece_rows(k) {
                    for i in 0..rows {
                        // As `pieces` orders them: row `i` holds pieces `n0..n0 + rows - i`.
                        let base = p[0] + e1 * ((i as f64 + offset) * inv_k);
                        let centre = |j: usize| base + e2 * ((j as f64 + offset) * inv_k);
                        // Walk the row in runs of pieces that share a cell: piece `j`'s cell
                        // is computed as for any piece, and the run goes on while the
                        // centroids (linear in `j`, `step` apart) stay a margin inside it.
                        let last = rows - i - 1;
                        let mut j = 0;
                        while j <= last {
                            let q = (centre(j) - origin) * inv_cell;
                            let cell = [0, 1, 2].map(|a| axis_cell(q[a], a));
                            let mut end = last;
                            for a in 0..3 {
                                // The clamped end cells reach past the grid.
                                let below = if cell[a] == 1 {
                                    f64::NEG_INFINITY
                                } else {
                                    cell[a] as f64 + margin
                                };
                                let above = if cell[a] as i64 == hi[a] {
                                    f64::INFINITY
                                } else {
                                    (cell[a] + 1) as f64 - margin
                                };
                                let room = match step[a] {
                                    d if d > 0.0 => (above - q[a]) * per_step[a],
                                    d if d < 0.0 => (below - q[a]) * per_step[a],
                                    _ => f64::INFINITY,
                                };
                                // `room < 0`: piece `j` itself lies within the margin. The
                                // cast truncates, which is the floor here.
                                let more = if room >= 0.0 {
                                    room.min(last as f64) as usize
                                } else {
                                    0
                                };
                                end = end.min(j + more);
                            }
                            let opaque = count(n0 + j, n0 + end + 1);
                            if opaque > 0 {
                                add(dims.index(cell[0], cell[1], cell[2]), opaque * piece);
                            }
                            j = end + 1;
                        }
                        n0 += rows - i;
                    }
                }
                for &(cell, a) in sums.iter() {
                    target[cell].fetch_add(a, Ordering::Relaxed);
                }
            },
        );
    let cell2 = placement.cell * placement.cell;
    let to_area = |v: Vec<AtomicU64>| -> Vec<f64> {
        v.into_iter()
            .map(|a| a.into_inner() as f64 / FIXED * cell2)
            .collect()
    };
    Ok(AreaGrid {
        placement: *placement,
        leaf: to_area(leaf),
        bark: to_area(bark),
    })
}
