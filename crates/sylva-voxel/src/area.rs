//! Plant area per cell: the physical occupancy (docs/light.md, docs/voxelize.md).
//!
//! Each triangle is split into `k²` congruent sub-triangles (a regular barycentric lattice)
//! and each sub-triangle's area goes to the cell holding its centroid, counted for a leaf only
//! where the nearest texel there is opaque ([`sylva_geom::is_opaque`]). `k` keeps the pieces
//! below an eighth of a cell (and, on alpha-textured leaves, fine enough to resolve the leaf's
//! outline: at least 32). Areas are summed as 2⁻³² cell² fixed-point integers, so the result
//! is the same for any thread count and triangle order.
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
    let cell_of = |p: DVec3| -> usize {
        let q = (p - origin) * inv_cell;
        let i = |v: f64, h: i64| (v.floor() as i64).clamp(1, h) as usize;
        dims.index(i(q.x, hi[0]), i(q.y, hi[1]), i(q.z, hi[2]))
    };
    mesh.indices
        .par_iter()
        .zip(mesh.material_ids.par_iter())
        .with_min_len(256)
        .for_each_init(Vec::<(usize, u64)>::new, |sums, (t, &m)| {
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
            let alpha = match kind {
                Kind::Leaf(Some(o)) => {
                    k = k.max(ALPHA_SPLITS);
                    let uv = t.map(|i| mesh.uvs[i as usize].map(f64::from));
                    Some((o, uv))
                }
                _ => None,
            };
            let piece = ((area_cells / (k * k) as f64) * FIXED).round() as u64;
            sums.clear();
            // Consecutive pieces mostly share a cell: look there first.
            let mut last = 0usize;
            let inv_k = 1.0 / k as f64;
            // Centroids of the k² sub-triangles: (i + 1/3, j + 1/3) / k for i + j ≤ k - 1
            // (upright) and (i + 2/3, j + 2/3) / k for i + j ≤ k - 2 (inverted).
            for (offset, rows) in [(1.0 / 3.0, k), (2.0 / 3.0, k - 1)] {
                for i in 0..rows {
                    for j in 0..rows - i {
                        let (s, r) = ((i as f64 + offset) * inv_k, (j as f64 + offset) * inv_k);
                        if let Some((o, uv)) = &alpha {
                            let u =
                                uv[0][0] + (uv[1][0] - uv[0][0]) * s + (uv[2][0] - uv[0][0]) * r;
                            let v =
                                uv[0][1] + (uv[1][1] - uv[0][1]) * s + (uv[2][1] - uv[0][1]) * r;
                            if !o.at(u, v) {
                                continue;
                            }
                        }
                        let cell = cell_of(p[0] + e1 * s + e2 * r);
                        if sums.get(last).is_some_and(|(c, _)| *c == cell) {
                            sums[last].1 += piece;
                        } else if let Some(at) = sums.iter().position(|(c, _)| *c == cell) {
                            sums[at].1 += piece;
                            last = at;
                        } else {
                            last = sums.len();
                            sums.push((cell, piece));
                        }
                    }
                }
            }
            let target = if matches!(kind, Kind::Bark) {
                &bark
            } else {
                &leaf
            };
            for &(cell, a) in sums.iter() {
                target[cell].fetch_add(a, Ordering::Relaxed);
            }
        });
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
