//! Voxelization (000 §4.2, SPEC §1): a model's triangles become the LB density grid. This
//! crate owns that step and nothing else: models come from `sylva-geom`, the grid type from
//! `sylva-lb`.
//!
//! Cubic cells cover the model's bounding box, `N` sites along its longest edge; each cell is
//! refined into 3 × 3 × 3 sub-cells and a sub-cell counts when a triangle meets it (exact
//! triangle/box overlap, the separating-axis test of Akenine-Möller in the form of Schwarz &
//! Seidel 2010). Density = counted sub-cells / 27; wood fraction = sub-cells met by a wood
//! triangle / counted sub-cells. A leaf triangle with a texture counts in a sub-cell only if the
//! piece of it inside the sub-cell samples an opaque texel ([`sylva_geom::is_opaque`]: alpha ≥ 0.5).
//!
//! Conventions (docs/voxelize.md has the reasoning):
//!
//! * **Placement.** The model's box fills the interior sites exactly along its longest edge: the
//!   cell edge is `L / (N - 2)`, and the outer shell of sites (the LB boundary) stays empty. The
//!   other axes get `ceil(extent / cell) + 2` sites (at least 3), the model centred in them.
//!   [`DensityGrid::bounds`] holds the site centres' span, as everywhere in sylva-lb.
//! * **Closed boxes.** A sub-cell is the closed box `[k, k + 1]` (in sub-cell units): a triangle
//!   lying exactly on a face between two sub-cells counts in both. Shell cells are never filled.
//! * **Alpha.** Exact for nearest-texel sampling: a sub-cell counts iff some point of the
//!   (closed) triangle piece inside it samples an opaque texel, with the texture's wrap mode.
//!   Ties at texel edges resolve towards counting (conservative); see [`TextureCoverage`].
//! * **Determinism.** Sub-cells are bits in one atomic word per cell, set with `fetch_or`, so
//!   the result is independent of the order triangles are processed in and of the thread count.

mod area;
pub mod bench;

pub use area::{plant_area, AreaGrid};

use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;
use sylva_grid::{Bounds, DensityGrid, Dims, GridError};
use thiserror::Error;

use sylva_geom::{is_opaque, MaterialKind, Model, Texture, Wrap};

/// Sub-cells per cell edge.
pub const SUB: usize = 3;
/// Sub-cells per cell.
pub const SUBCELLS: u32 = 27;
/// Sites along the longest edge unless asked otherwise (the papers' 128³).
pub const DEFAULT_GRID: usize = 128;
/// Largest `N` accepted ([`sylva_core::limits::MODEL_GRID`]).
pub const MAX_GRID: usize = *sylva_core::limits::MODEL_GRID.end();
/// Smallest `N`: the two shell sites plus two interior ones.
pub const MIN_GRID: usize = *sylva_core::limits::MODEL_GRID.start();

/// What a cell's density measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Occupancy {
    /// The probability that light crossing the cell meets a leaf or bark, from the leaf and
    /// bark area in it ([`plant_area`]; docs/light.md): the physical medium.
    #[default]
    Area,
    /// The share of the cell's 3 × 3 × 3 sub-cells that a triangle meets (000 §4.2).
    SubCells,
}

impl Occupancy {
    pub fn name(self) -> &'static str {
        match self {
            Occupancy::Area => "area",
            Occupancy::SubCells => "subcells",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VoxelizeOptions {
    /// `N`: sites along the model's longest edge, shell included.
    pub grid: usize,
    /// Leaf triangles with a texture count only where the texture is opaque.
    pub alpha_test: bool,
    /// What the density measures.
    pub occupancy: Occupancy,
}

impl Default for VoxelizeOptions {
    fn default() -> Self {
        VoxelizeOptions {
            grid: DEFAULT_GRID,
            alpha_test: true,
            occupancy: Occupancy::Area,
        }
    }
}

/// A model grid given on the command line (`--grid N`) refused.
#[derive(Debug, Error, PartialEq)]
pub enum GridFlagError {
    #[error("--grid '{text}': a model's grid is one number, the sites along its longest edge")]
    NotANumber {
        text: String,
        #[source]
        source: std::num::ParseIntError,
    },
    #[error(
        "--grid {0}: a model's grid must be {MIN_GRID} to {MAX_GRID} sites along its longest edge"
    )]
    Range(usize),
}

/// `--grid N`: sites along a model's longest edge, [`MIN_GRID`] to [`MAX_GRID`].
pub fn parse_grid_flag(text: &str) -> Result<usize, GridFlagError> {
    let n: usize = text
        .trim()
        .parse()
        .map_err(|source| GridFlagError::NotANumber {
            text: text.to_string(),
            source,
        })?;
    if !(MIN_GRID..=MAX_GRID).contains(&n) {
        return Err(GridFlagError::Range(n));
    }
    Ok(n)
}

#[derive(Debug, Error)]
pub enum VoxelizeError {
    #[error("model '{0}' has no triangles: nothing to voxelize")]
    Empty(String),
    #[error("model '{model}': vertex {vertex} has a non-finite position {position:?}")]
    BadVertex {
        model: String,
        vertex: usize,
        position: [f32; 3],
    },
    #[error("model '{model}': leaf triangle {triangle} has non-finite texture coordinates")]
    BadUv { model: String, triangle: usize },
    #[error("model '{model}': invalid mesh: {problem}")]
    BadMesh { model: String, problem: String },
    #[error("model '{0}' has zero extent (all its vertices coincide): no grid can cover it")]
    ZeroExtent(String),
    #[error("grid size N = {0} is invalid: N (sites along the longest edge, shell included) must be between {MIN_GRID} and {MAX_GRID}")]
    BadGrid(usize),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error(transparent)]
    Grid(#[from] GridError),
}

/// Where a grid sits in model space: cell `(i, j, k)` is the cube
/// `origin + [i, i + 1] × [j, j + 1] × [k, k + 1] · cell`, its site at the cube's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridPlacement {
    pub dims: Dims,
    /// Model-space corner of cell (0, 0, 0), a shell cell.
    pub origin: [f64; 3],
    /// Edge of a cell.
    pub cell: f64,
}

impl GridPlacement {
    /// The placement for a box `min..max`: `n` sites along its longest edge, the box filling the
    /// interior exactly along that edge and centred along the others.
    pub fn fit(min: [f64; 3], max: [f64; 3], n: usize) -> Result<GridPlacement, VoxelizeError> {
        if !(MIN_GRID..=MAX_GRID).contains(&n) {
            return Err(VoxelizeError::BadGrid(n));
        }
        let extent = [0, 1, 2].map(|a| max[a] - min[a]);
        let longest = (0..3)
            .max_by(|&a, &b| extent[a].total_cmp(&extent[b]))
            .expect("three axes");
        let l = extent[longest];
        if !(l > 0.0 && l.is_finite()) {
            return Err(VoxelizeError::ZeroExtent(String::new()));
        }
        let cell = l / (n - 2) as f64;
        let mut sites = [0usize; 3];
        let mut origin = [0f64; 3];
        for a in 0..3 {
            let interior = if a == longest {
                n - 2
            } else {
                // The tolerance keeps an edge equal to the longest at n - 2 cells despite
                // rounding in extent / cell.
                ((extent[a] / cell * (1.0 - 1e-12)).ceil() as usize).clamp(1, n - 2)
            };
            sites[a] = interior + 2;
            origin[a] = if a == longest {
                min[a] - cell
            } else {
                0.5 * (min[a] + max[a]) - 0.5 * sites[a] as f64 * cell
            };
        }
        Ok(GridPlacement {
            dims: Dims::new(sites[0], sites[1], sites[2])?,
            origin,
            cell,
        })
    }

    /// The span of the site centres, as [`DensityGrid::bounds`] means it.
    pub fn bounds(&self) -> Bounds {
        let d = [self.dims.nx, self.dims.ny, self.dims.nz];
        Bounds {
            min: [0, 1, 2].map(|a| (self.origin[a] + 0.5 * self.cell) as f32),
            max: [0, 1, 2].map(|a| (self.origin[a] + (d[a] as f64 - 0.5) * self.cell) as f32),
        }
    }

    /// Model-space point → sub-cell coordinates (sub-cell `k` spans `[k, k + 1]`).
    fn sub_coords(&self, p: [f32; 3]) -> DVec3 {
        let inv = SUB as f64 / self.cell;
        DVec3::new(
            (p[0] as f64 - self.origin[0]) * inv,
            (p[1] as f64 - self.origin[1]) * inv,
            (p[2] as f64 - self.origin[2]) * inv,
        )
    }
}

/// Bit of sub-cell `(sx, sy, sz)` (each 0..3) within its cell's mask.
#[inline]
pub fn subcell_bit(sx: usize, sy: usize, sz: usize) -> u32 {
    1 << ((sx * SUB + sy) * SUB + sz)
}

/// Per cell, which of its 27 sub-cells are met (`any`) and which by wood (`wood ⊆ any`).
#[derive(Debug, Clone, PartialEq)]
pub struct SubcellMasks {
    pub placement: GridPlacement,
    /// Low 32 bits: sub-cells met by any counted triangle; high 32 bits: by a wood triangle.
    /// Bit layout [`subcell_bit`]; cells in site order.
    pub bits: Vec<u64>,
}

impl SubcellMasks {
    pub fn any(&self, cell: usize) -> u32 {
        self.bits[cell] as u32
    }

    pub fn wood(&self, cell: usize) -> u32 {
        (self.bits[cell] >> 32) as u32
    }

    /// Density = counted / 27, wood fraction = wood / counted (0 in empty cells).
    pub fn to_density_grid(&self) -> Result<DensityGrid, VoxelizeError> {
        let (density, wood): (Vec<f32>, Vec<f32>) = self
            .bits
            .par_iter()
            .map(|&b| {
                let any = (b as u32).count_ones();
                let wood = ((b >> 32) as u32).count_ones();
                if any == 0 {
                    (0.0, 0.0)
                } else {
                    (any as f32 / SUBCELLS as f32, wood as f32 / any as f32)
                }
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

/// The model's density grid: `opts.grid` sites along its longest edge (see the module docs).
pub fn voxelize(model: &Model, opts: &VoxelizeOptions) -> Result<DensityGrid, VoxelizeError> {
    let placement = placement_for(model, opts.grid)?;
    match opts.occupancy {
        Occupancy::Area => plant_area(model, &placement, opts.alpha_test)?.to_density_grid(),
        Occupancy::SubCells => {
            voxelize_masks(model, &placement, opts.alpha_test)?.to_density_grid()
        }
    }
}

/// Edge of one cell of `grid` in model units (cells are cubes).
pub fn cell_size(grid: &DensityGrid) -> f32 {
    (grid.bounds.max[0] - grid.bounds.min[0]) / (grid.dims.nx - 1) as f32
}

/// What a density grid file records about how `grid` was made from `model` (named `spec` on
/// the command line) with `opts`: the model, its source, the grid, triangles, model bounds,
/// cell size, occupancy and alpha test.
pub fn grid_metadata(
    model: &Model,
    spec: &str,
    opts: &VoxelizeOptions,
    grid: &DensityGrid,
) -> Vec<(String, String)> {
    let b = model.bounds;
    let v3 = |v: [f32; 3]| format!("{},{},{}", v[0], v[1], v[2]);
    vec![
        ("model".to_string(), model.name.clone()),
        ("source".to_string(), spec.to_string()),
        ("grid_n".to_string(), opts.grid.to_string()),
        ("triangles".to_string(), model.triangle_count().to_string()),
        ("model_min".to_string(), v3(b.min.to_array())),
        ("model_max".to_string(), v3(b.max.to_array())),
        ("cell_size".to_string(), cell_size(grid).to_string()),
        ("occupancy".to_string(), opts.occupancy.name().to_string()),
        ("alpha_test".to_string(), opts.alpha_test.to_string()),
    ]
}

/// The placement [`voxelize`] uses for `model` with `grid` sites along its longest edge,
/// without voxelizing (the mesh is checked the same way).
pub fn placement_for(model: &Model, grid: usize) -> Result<GridPlacement, VoxelizeError> {
    let (min, max) = check_model(model)?;
    GridPlacement::fit(min, max, grid).map_err(|e| match e {
        VoxelizeError::ZeroExtent(_) => VoxelizeError::ZeroExtent(model.name.clone()),
        e => e,
    })
}

/// Checks the mesh and returns the bounding box of its triangles' vertices.
fn check_model(model: &Model) -> Result<([f64; 3], [f64; 3]), VoxelizeError> {
    let mesh = &model.mesh;
    if mesh.indices.is_empty() {
        return Err(VoxelizeError::Empty(model.name.clone()));
    }
    if let Some((vertex, p)) = mesh
        .positions
        .iter()
        .enumerate()
        .find(|(_, p)| p.iter().any(|v| !v.is_finite()))
    {
        return Err(VoxelizeError::BadVertex {
            model: model.name.clone(),
            vertex,
            position: *p,
        });
    }
    mesh.validate(model.materials.len())
        .map_err(|problem| VoxelizeError::BadMesh {
            model: model.name.clone(),
            problem,
        })?;
    let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for t in &mesh.indices {
        for &i in t {
            let p = mesh.positions[i as usize];
            for a in 0..3 {
                min[a] = min[a].min(p[a] as f64);
                max[a] = max[a].max(p[a] as f64);
            }
        }
    }
    Ok((min, max))
}

/// Bytes [`voxelize`] holds at its peak for a grid of `dims`: the mask words, then the two f32
/// channels.
pub fn memory_needed(dims: Dims) -> u64 {
    dims.sites() as u64 * (8 + 8)
}

/// How a material's triangles are counted.
enum Rule {
    /// Every sub-cell a triangle meets (wood, untextured or fully opaque leaves).
    Solid { wood: bool },
    /// Leaves: only where the piece inside the sub-cell samples an opaque texel.
    Alpha(TextureCoverage),
    /// Leaves whose texture has no opaque texel at all.
    Invisible,
}

/// Refuses a model whose texture-sampled triangles (those whose material `samples_texture`
/// says so) carry non-finite UVs: both voxelizers look texels up at those UVs.
pub(crate) fn check_texture_uvs(
    model: &Model,
    samples_texture: impl Fn(u8) -> bool,
) -> Result<(), VoxelizeError> {
    let mesh = &model.mesh;
    if let Some(triangle) = mesh.indices.iter().enumerate().position(|(i, t)| {
        samples_texture(mesh.material_ids[i])
            && t.iter()
                .any(|&v| mesh.uvs[v as usize].iter().any(|x| !x.is_finite()))
    }) {
        return Err(VoxelizeError::BadUv {
            model: model.name.clone(),
            triangle,
        });
    }
    Ok(())
}

/// Sub-cell masks of `model` on an explicit placement (cells outside the shell only).
pub fn voxelize_masks(
    model: &Model,
    placement: &GridPlacement,
    alpha_test: bool,
) -> Result<SubcellMasks, VoxelizeError> {
    check_model(model)?;
    let dims = placement.dims;
    sylva_core::check_memory(
        &format!("voxelizing '{}' on a {dims} grid", model.name),
        memory_needed(dims),
    )?;
    let mesh = &model.mesh;
    let rules: Vec<Rule> = model
        .materials
        .iter()
        .map(|m| match (m.kind, &m.texture) {
            (MaterialKind::Wood, _) => Rule::Solid { wood: true },
            (MaterialKind::Leaf, Some(t)) if alpha_test => {
                let c = TextureCoverage::new(t);
                if c.opaque == 0 {
                    Rule::Invisible
                } else if c.opaque as usize == c.width * c.height {
                    Rule::Solid { wood: false }
                } else {
                    Rule::Alpha(c)
                }
            }
            (MaterialKind::Leaf | MaterialKind::Solid, _) => Rule::Solid { wood: false },
        })
        .collect();
    check_texture_uvs(model, |material| {
        matches!(rules[material as usize], Rule::Alpha(_))
    })?;
    let cells: Vec<AtomicU64> = (0..dims.sites()).map(|_| AtomicU64::new(0)).collect();
    let d = [dims.nx, dims.ny, dims.nz];
    // Sub-cells of the interior cells, inclusive.
    let lo = [SUB as i64; 3];
    let hi = d.map(|n| (SUB * (n - 1)) as i64 - 1);
    let target = Target {
        cells: &cells,
        dims,
        lo,
        hi,
    };
    mesh.indices
        .par_iter()
        .zip(mesh.material_ids.par_iter())
        .with_min_len(1024)
        .for_each_init(Scratch::default, |scratch, (t, &m)| {
            let rule = &rules[m as usize];
            if matches!(rule, Rule::Invisible) {
                return;
            }
            let v = t.map(|i| placement.sub_coords(mesh.positions[i as usize]));
            let Scratch { masks, poly } = scratch;
            match rule {
                Rule::Solid { wood } => target.rasterize(&v, *wood, false, masks, |_| true),
                Rule::Alpha(cov) => {
                    let (w, h) = (cov.width as f64, cov.height as f64);
                    let uv = t.map(|i| {
                        let [u, v] = mesh.uvs[i as usize];
                        [u as f64 * w, v as f64 * h]
                    });
                    match cov.triangle_state(&uv) {
                        Some(false) => {}
                        Some(true) => target.rasterize(&v, false, false, masks, |_| true),
                        None => {
                            let tri = AlphaTriangle::new(&v, &uv);
                            target.rasterize(&v, false, true, masks, |corner| {
                                cov.piece_is_opaque(&tri, corner, poly)
                            })
                        }
                    }
                }
                Rule::Invisible => unreachable!("returned above"),
            }
        });
    Ok(SubcellMasks {
        placement: *placement,
        bits: cells.into_iter().map(AtomicU64::into_inner).collect(),
    })
}

/// Per-thread buffers, reused from triangle to triangle.
#[derive(Default)]
struct Scratch {
    /// Masks of the cells in the current triangle's cell box.
    masks: Vec<u32>,
    poly: ClipBuffers,
}

/// `floor` without a libm call (the baseline x86-64 target has no SSE4.1 `roundsd`); exact
/// for |x| < 2⁶³, which [`GridPlacement`] and [`texel_box`] guarantee.
#[inline]
fn floor(x: f64) -> i64 {
    let t = x as i64;
    t - ((t as f64) > x) as i64
}

#[inline]
fn ceil(x: f64) -> i64 {
    let t = x as i64;
    t + ((t as f64) < x) as i64
}

/// The cell masks being filled.
struct Target<'a> {
    cells: &'a [AtomicU64],
    dims: Dims,
    /// Inclusive sub-cell range of the interior cells.
    lo: [i64; 3],
    hi: [i64; 3],
}

impl Target<'_> {
    /// Sets the bits of every sub-cell the triangle `v` (sub-cell coordinates) meets and for
    /// which `keep(min corner)` holds; with `skip_counted` (leaves only), sub-cells already
    /// counted are not offered to `keep`.
    ///
    /// Walks the columns of sub-cells along the axis the triangle's normal is closest to:
    /// columns the triangle's projection misses are skipped whole, and in the others only the
    /// sub-cells the plane can reach are tested (at most four, usually one or two).
    fn rasterize(
        &self,
        v: &[DVec3; 3],
        wood: bool,
        skip_counted: bool,
        masks: &mut Vec<u32>,
        mut keep: impl FnMut(DVec3) -> bool,
    ) {
        let tmin = v[0].min(v[1]).min(v[2]);
        let tmax = v[0].max(v[1]).max(v[2]);
        // Closed boxes: sub-cell k = [k, k + 1] meets [tmin, tmax] iff tmin - 1 ≤ k ≤ tmax.
        let s0 = [0, 1, 2].map(|a| (ceil(tmin[a]) - 1).max(self.lo[a]));
        let s1 = [0, 1, 2].map(|a| floor(tmax[a]).min(self.hi[a]));
        if (0..3).any(|a| s0[a] > s1[a]) {
            return;
        }
        let sub = SUB as i64;
        let c0 = s0.map(|s| s / sub);
        let c1 = s1.map(|s| s / sub);
        let ce = [0, 1, 2].map(|a| (c1[a] - c0[a] + 1) as usize);
        masks.clear();
        masks.resize(ce[0] * ce[1] * ce[2], 0);
        let test = OverlapTest::new(v);
        let n = test.n;
        // Column axis d and the projection (a, b) across it, as OverlapTest numbers them.
        let (k, a, b, d) = if n.z.abs() >= n.x.abs() && n.z.abs() >= n.y.abs() {
            (0, 0, 1, 2)
        } else if n.x.abs() >= n.y.abs() {
            (1, 1, 2, 0)
        } else {
            (2, 2, 0, 1)
        };
        let (others, nd) = ([(k + 1) % 3, (k + 2) % 3], n[d]);
        // The plane as d = base + ka·a + kb·b (when nd ≠ 0), divided once per triangle.
        let (base, ka, kb) = if nd != 0.0 {
            (n.dot(v[0]) / nd, -n[a] / nd, -n[b] / nd)
        } else {
            (0.0, 0.0, 0.0)
        };
        let (ka_lo, ka_hi, kb_lo, kb_hi) = (ka.min(0.0), ka.max(0.0), kb.min(0.0), kb.max(0.0));
        for ia in s0[a]..=s1[a] {
            for ib in s0[b]..=s1[b] {
                let (pa, pb) = (ia as f64, ib as f64);
                if !test.edges(k, pa, pb) {
                    continue;
                }
                // The plane's extent along d over the column's cross-section, widened a
                // little so rounding can only add candidates (the exact test follows).
                let (mut d0, mut d1) = (s0[d], s1[d]);
                if nd != 0.0 {
                    let at = base + ka * pa + kb * pb;
                    let (lo, hi) = (at + ka_lo + kb_lo, at + ka_hi + kb_hi);
                    let eps = 1e-9 * (1.0 + lo.abs().max(hi.abs()));
                    d0 = d0.max(ceil(lo - eps) - 1);
                    d1 = d1.min(floor(hi + eps));
                }
                for id in d0..=d1 {
                    let mut s = [0i64; 3];
                    s[a] = ia;
                    s[b] = ib;
                    s[d] = id;
                    let p = DVec3::new(s[0] as f64, s[1] as f64, s[2] as f64);
                    if !(test.plane(p)
                        && test.edges_at(others[0], p)
                        && test.edges_at(others[1], p))
                    {
                        continue;
                    }
                    let c = s.map(|x| x / sub);
                    let bit = subcell_bit(
                        (s[0] - c[0] * sub) as usize,
                        (s[1] - c[1] * sub) as usize,
                        (s[2] - c[2] * sub) as usize,
                    );
                    // A leaf adds nothing to a sub-cell already counted (by anything): skip
                    // its costly texture test there. The final masks, an OR over all
                    // triangles, are the same whatever order the triangles come in.
                    if skip_counted {
                        let cell = self.dims.index(c[0] as usize, c[1] as usize, c[2] as usize);
                        if self.cells[cell].load(Ordering::Relaxed) as u32 & bit != 0 {
                            continue;
                        }
                    }
                    if !keep(p) {
                        continue;
                    }
                    let local = (((c[0] - c0[0]) as usize * ce[1]) + (c[1] - c0[1]) as usize)
                        * ce[2]
                        + (c[2] - c0[2]) as usize;
                    masks[local] |= bit;
                }
            }
        }
        let shift = if wood { 32 } else { 0 };
        for (local, &mask) in masks.iter().enumerate() {
            if mask == 0 {
                continue;
            }
            let cz = local % ce[2];
            let cy = (local / ce[2]) % ce[1];
            let cx = local / (ce[2] * ce[1]);
            let bits = (mask as u64) | ((mask as u64) << shift);
            let cell = &self.cells[self.dims.index(
                c0[0] as usize + cx,
                c0[1] as usize + cy,
                c0[2] as usize + cz,
            )];
            // Most cells are met by many triangles: skip the write when the bits are there
            // already, so cores do not fight over the cache line.
            if cell.load(Ordering::Relaxed) & bits != bits {
                cell.fetch_or(bits, Ordering::Relaxed);
            }
        }
    }
}

/// Triangle / unit-box overlap with everything that does not depend on the box precomputed
/// (Schwarz & Seidel 2010, §3.1): the plane test plus, in each of the three axis projections,
/// the three edge functions. Together with the bounding-box test (done by the caller's sub-cell
/// range) this is Akenine-Möller's 13-axis separating-axis test, on closed boxes.
struct OverlapTest {
    n: DVec3,
    d1: f64,
    d2: f64,
    /// Per projection (xy, yz, zx) and edge: normal (2 components) and offset.
    edges: [[(f64, f64, f64); 3]; 3],
}

/// The axes of projection `k` of [`OverlapTest`]: xy, yz, zx.
const PROJ: [(usize, usize); 3] = [(0, 1), (1, 2), (2, 0)];

impl OverlapTest {
    fn new(v: &[DVec3; 3]) -> OverlapTest {
        let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
        let n = e[0].cross(v[2] - v[0]);
        // Critical corner: the box corner furthest along n (box extent 1).
        let c = DVec3::new(
            (n.x > 0.0) as u8 as f64,
            (n.y > 0.0) as u8 as f64,
            (n.z > 0.0) as u8 as f64,
        );
        let d1 = n.dot(c - v[0]);
        let d2 = n.dot(DVec3::ONE - c - v[0]);
        // With n·axis = 0 the projection is a segment; either sign then gives edges of both
        // orientations, which is the segment's own test, so ≥ 0 is a safe choice.
        let sign = |x: f64| if x >= 0.0 { 1.0 } else { -1.0 };
        let orient = [sign(n.z), sign(n.x), sign(n.y)];
        let mut edges = [[(0.0, 0.0, 0.0); 3]; 3];
        for (k, &(a, b)) in PROJ.iter().enumerate() {
            let s = orient[k];
            for i in 0..3 {
                let (na, nb) = (-e[i][b] * s, e[i][a] * s);
                let d = -(na * v[i][a] + nb * v[i][b]) + na.max(0.0) + nb.max(0.0);
                edges[k][i] = (na, nb, d);
            }
        }
        OverlapTest { n, d1, d2, edges }
    }

    /// Does the triangle's plane meet the closed unit box with min corner `p`?
    #[inline]
    fn plane(&self, p: DVec3) -> bool {
        let np = self.n.dot(p);
        let (a, b) = (np + self.d1, np + self.d2);
        !((a < 0.0 && b < 0.0) || (a > 0.0 && b > 0.0))
    }

    /// Does projection `k` of the triangle meet the unit square at `(pa, pb)`?
    #[inline]
    fn edges(&self, k: usize, pa: f64, pb: f64) -> bool {
        self.edges[k]
            .iter()
            .all(|&(na, nb, d)| na * pa + nb * pb + d >= 0.0)
    }

    #[inline]
    fn edges_at(&self, k: usize, p: DVec3) -> bool {
        let (a, b) = PROJ[k];
        self.edges(k, p[a], p[b])
    }
}

/// Where a texture is opaque, for exact coverage queries: a summed-area table of opaque texels.
///
/// Texel `(i, j)` is what nearest sampling returns for `floor(u·W) = i`, `floor(v·H) = j`
/// (wrapped or clamped by the texture's mode), so in texel units (`u·W`, `v·H`) the set of
/// texels a convex region samples is decided row by row: the region's part in the strip
/// `j ≤ v < j + 1` spans an interval of u, and it samples exactly texels `floor(u_min)` to
/// `floor(u_max)` of row `j`. The strip's part is taken closed (`v ≤ j + 1`), so a piece whose
/// only contact with an opaque texel is that texel's edge counts: conservative, and tight up to
/// such ties.
pub struct TextureCoverage {
    width: usize,
    height: usize,
    wrap: Wrap,
    /// `(height + 1) × (width + 1)` prefix sums of opaque texels.
    table: Vec<u32>,
    opaque: u32,
}

/// More texel rows than this in one query (texture coordinates repeating many times within a
/// sub-cell): count the sub-cell if any texel it reaches is opaque (conservative).
const MAX_ROWS: i64 = 4096;

impl TextureCoverage {
    pub fn new(t: &Texture) -> TextureCoverage {
        let (w, h) = (t.width as usize, t.height as usize);
        let mut table = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += is_opaque(t.pixels[y * w + x]) as u32;
                table[(y + 1) * (w + 1) + x + 1] = table[y * (w + 1) + x + 1] + row;
            }
        }
        let opaque = table[(w + 1) * (h + 1) - 1];
        TextureCoverage {
            width: w,
            height: h,
            wrap: t.wrap,
            table,
            opaque,
        }
    }

    /// Texel index ranges (inclusive, at most two) that unwrapped indices `i0..=i1` sample.
    #[inline]
    fn ranges(&self, i0: i64, i1: i64, n: usize) -> ([(usize, usize); 2], usize) {
        let n = n as i64;
        match self.wrap {
            Wrap::Clamp => (
                [(i0.clamp(0, n - 1) as usize, i1.clamp(0, n - 1) as usize); 2],
                1,
            ),
            Wrap::Repeat => {
                if i1 - i0 + 1 >= n {
                    return ([(0, n as usize - 1); 2], 1);
                }
                let (a, b) = (i0.rem_euclid(n) as usize, i1.rem_euclid(n) as usize);
                if a <= b {
                    ([(a, b); 2], 1)
                } else {
                    ([(a, n as usize - 1), (0, b)], 2)
                }
            }
        }
    }

    /// Opaque texels and all texels sampled by unwrapped texel rectangle `[i0, i1] × [j0, j1]`.
    #[inline]
    fn count(&self, i0: i64, i1: i64, j0: i64, j1: i64) -> (u64, u64) {
        let (xs, nx) = self.ranges(i0, i1, self.width);
        let (ys, ny) = self.ranges(j0, j1, self.height);
        let w1 = self.width + 1;
        let (mut opaque, mut all) = (0u64, 0u64);
        for &(x0, x1) in &xs[..nx] {
            for &(y0, y1) in &ys[..ny] {
                let t = |x: usize, y: usize| self.table[y * w1 + x] as i64;
                opaque += (t(x1 + 1, y1 + 1) - t(x0, y1 + 1) - t(x1 + 1, y0) + t(x0, y0)) as u64;
                all += ((x1 - x0 + 1) * (y1 - y0 + 1)) as u64;
            }
        }
        (opaque, all)
    }

    /// Decides a whole triangle (texel-unit coordinates) where its texel box settles it:
    /// `Some(false)` no opaque texel reachable, `Some(true)` every reachable texel opaque.
    fn triangle_state(&self, uv: &[[f64; 2]; 3]) -> Option<bool> {
        let (i0, i1, j0, j1) = texel_box(uv);
        let (opaque, all) = self.count(i0, i1, j0, j1);
        if opaque == 0 {
            Some(false)
        } else if opaque == all {
            Some(true)
        } else {
            None
        }
    }

    /// Does the piece of `tri` inside the closed unit box at `corner` sample an opaque
    /// texel?
    fn piece_is_opaque(&self, tri: &AlphaTriangle, corner: DVec3, buf: &mut ClipBuffers) -> bool {
        // Texture coordinates are affine on the triangle's plane, so over the box they lie in
        // an interval per coordinate; where the texels of that superset of the piece's texture
        // box are all opaque or all transparent, the answer is known without clipping (the
        // piece is not empty: the caller's overlap test said so).
        if let Some((u0, u1, v0, v1)) = tri.uv_range(corner) {
            let (opaque, all) = self.count(floor(u0), floor(u1), floor(v0), floor(v1));
            if opaque == 0 {
                return false;
            }
            if opaque == all {
                return true;
            }
        }
        match buf.clip_to_box(&tri.vertices, corner) {
            Some(piece) => {
                let mut pts = [[0.0; 2]; ClipBuffers::CAP];
                for (p, q) in pts.iter_mut().zip(piece) {
                    *p = [q[3], q[4]];
                }
                self.polygon_is_opaque(&pts[..piece.len()])
            }
            // Nothing left (the triangle only grazes the box and rounding lost the contact),
            // or too many vertices (impossible for a convex piece): decide conservatively.
            None => buf.overflowed && self.opaque > 0,
        }
    }

    /// Does convex polygon `pts` (texel units) sample an opaque texel?
    pub fn polygon_is_opaque(&self, pts: &[[f64; 2]]) -> bool {
        if pts.is_empty() {
            return false;
        }
        let (i0, i1, j0, j1) = texel_box(pts);
        let (opaque, all) = self.count(i0, i1, j0, j1);
        if opaque == 0 {
            return false;
        }
        if opaque == all {
            return true;
        }
        // Quick accept: the vertex centroid lies in the polygon.
        let n = pts.len() as f64;
        let cu = pts.iter().map(|p| p[0]).sum::<f64>() / n;
        let cv = pts.iter().map(|p| p[1]).sum::<f64>() / n;
        let (ci, cj) = (floor(cu), floor(cv));
        if self.count(ci, ci, cj, cj).0 > 0 {
            return true;
        }
        // And the vertices.
        if pts.iter().any(|p| {
            let (i, j) = (floor(p[0]), floor(p[1]));
            self.count(i, i, j, j).0 > 0
        }) {
            return true;
        }
        if j1 - j0 >= MAX_ROWS {
            return true;
        }
        for j in j0..=j1 {
            if let Some((ulo, uhi)) = strip_extent(pts, j as f64, j as f64 + 1.0) {
                if self.count(floor(ulo), floor(uhi), j, j).0 > 0 {
                    return true;
                }
            }
        }
        false
    }
}

/// A textured leaf triangle: vertices with texture coordinates (texel units), and texture
/// coordinates as affine functions of position on its plane, `u(x) = g_u · x + c_u`.
struct AlphaTriangle {
    vertices: [[f64; 5]; 3],
    /// `(g_u, c_u, g_v, c_v)`; `None` for a degenerate triangle.
    affine: Option<(DVec3, f64, DVec3, f64)>,
    /// The triangle's texel-unit box: (u_min, u_max, v_min, v_max).
    uv_box: (f64, f64, f64, f64),
}

impl AlphaTriangle {
    fn new(v: &[DVec3; 3], uv: &[[f64; 2]; 3]) -> AlphaTriangle {
        let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
        let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let det = a * c - b * b;
        // g = α e1 + β e2 with g·e1 = Δ1, g·e2 = Δ2: the in-plane gradient.
        let affine = (det > 1e-12 * a * c).then(|| {
            let grad = |d1: f64, d2: f64| {
                let (al, be) = ((c * d1 - b * d2) / det, (a * d2 - b * d1) / det);
                e1 * al + e2 * be
            };
            let gu = grad(uv[1][0] - uv[0][0], uv[2][0] - uv[0][0]);
            let gv = grad(uv[1][1] - uv[0][1], uv[2][1] - uv[0][1]);
            (gu, uv[0][0] - gu.dot(v[0]), gv, uv[0][1] - gv.dot(v[0]))
        });
        let (us, vs) = (uv.map(|p| p[0]), uv.map(|p| p[1]));
        AlphaTriangle {
            vertices: std::array::from_fn(|k| [v[k].x, v[k].y, v[k].z, uv[k][0], uv[k][1]]),
            affine,
            uv_box: (
                us[0].min(us[1]).min(us[2]),
                us[0].max(us[1]).max(us[2]),
                vs[0].min(vs[1]).min(vs[2]),
                vs[0].max(vs[1]).max(vs[2]),
            ),
        }
    }

    /// A box in texel units holding the texture coordinates of every point of the triangle
    /// inside the unit box at `corner`: interval arithmetic on the affine map over the box,
    /// widened for rounding, cut to the triangle's own box.
    fn uv_range(&self, corner: DVec3) -> Option<(f64, f64, f64, f64)> {
        let (gu, cu, gv, cv) = self.affine?;
        let range = |g: DVec3, c: f64| {
            let base = g.dot(corner) + c;
            let lo = base + g.x.min(0.0) + g.y.min(0.0) + g.z.min(0.0);
            let hi = base + g.x.max(0.0) + g.y.max(0.0) + g.z.max(0.0);
            let eps = 1e-9 * (1.0 + lo.abs().max(hi.abs()));
            (lo - eps, hi + eps)
        };
        let (u0, u1) = range(gu, cu);
        let (v0, v1) = range(gv, cv);
        let b = self.uv_box;
        let r = (u0.max(b.0), u1.min(b.1), v0.max(b.2), v1.min(b.3));
        // Bounded so the conversion to texel indices cannot overflow.
        let ok = [r.0, r.1, r.2, r.3].iter().all(|x| x.is_finite()) && r.0 <= r.1 && r.2 <= r.3;
        ok.then_some((
            r.0.clamp(-1e15, 1e15),
            r.1.clamp(-1e15, 1e15),
            r.2.clamp(-1e15, 1e15),
            r.3.clamp(-1e15, 1e15),
        ))
    }
}

/// Unwrapped texel index box `(i0, i1, j0, j1)` of points in texel units. Coordinates are
/// clamped far outside any texture so the conversion to integers cannot overflow.
fn texel_box(pts: &[[f64; 2]]) -> (i64, i64, i64, i64) {
    let f = |x: f64| floor(x.clamp(-1e15, 1e15));
    let (mut u0, mut u1, mut v0, mut v1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in pts {
        u0 = u0.min(p[0]);
        u1 = u1.max(p[0]);
        v0 = v0.min(p[1]);
        v1 = v1.max(p[1]);
    }
    (f(u0), f(u1), f(v0), f(v1))
}

/// The u-interval of convex polygon `pts` within the closed strip `lo ≤ v ≤ hi`.
fn strip_extent(pts: &[[f64; 2]], lo: f64, hi: f64) -> Option<(f64, f64)> {
    let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut take = |u: f64| {
        a = a.min(u);
        b = b.max(u);
    };
    let n = pts.len();
    for k in 0..n {
        let (p, q) = (pts[k], pts[(k + 1) % n]);
        if (lo..=hi).contains(&p[1]) {
            take(p[0]);
        }
        for line in [lo, hi] {
            let (dp, dq) = (p[1] - line, q[1] - line);
            if (dp < 0.0 && dq > 0.0) || (dp > 0.0 && dq < 0.0) {
                take(p[0] + (q[0] - p[0]) * dp / (dp - dq));
            }
        }
    }
    (a <= b).then_some((a, b))
}

/// Two polygon buffers of (x, y, z, u, v) vertices for clipping a triangle to a box
/// (Sutherland-Hodgman), reused so clipping allocates and zeroes nothing.
pub struct ClipBuffers {
    bufs: [[[f64; 5]; ClipBuffers::CAP]; 2],
    overflowed: bool,
}

impl Default for ClipBuffers {
    fn default() -> Self {
        ClipBuffers {
            bufs: [[[0.0; 5]; ClipBuffers::CAP]; 2],
            overflowed: false,
        }
    }
}

impl ClipBuffers {
    /// A triangle clipped by six planes has at most 9 vertices; the rest is headroom.
    const CAP: usize = 16;

    /// The part of triangle `tri` inside the closed unit box at `corner`; `None` when nothing
    /// is left (or the buffer overflowed, recorded in `overflowed`).
    fn clip_to_box(&mut self, tri: &[[f64; 5]; 3], corner: DVec3) -> Option<&[[f64; 5]]> {
        self.overflowed = false;
        let [a, b] = &mut self.bufs;
        a[..3].copy_from_slice(tri);
        let (mut src, mut dst) = (a, b);
        let mut len = 3;
        for axis in 0..3 {
            for (sign, off) in [(1.0, corner[axis]), (-1.0, corner[axis] + 1.0)] {
                let dist = |p: &[f64; 5]| sign * (p[axis] - off);
                // Planes the polygon lies inside are the common case for small triangles.
                if src[..len].iter().all(|p| dist(p) >= 0.0) {
                    continue;
                }
                let mut out = 0;
                for k in 0..len {
                    let (p, q) = (src[k], src[(k + 1) % len]);
                    let (dp, dq) = (dist(&p), dist(&q));
                    if out + 2 > Self::CAP {
                        self.overflowed = true;
                        return None;
                    }
                    if dp >= 0.0 {
                        dst[out] = p;
                        out += 1;
                    }
                    if (dp > 0.0 && dq < 0.0) || (dp < 0.0 && dq > 0.0) {
                        let t = dp / (dp - dq);
                        dst[out] = std::array::from_fn(|c| p[c] + (q[c] - p[c]) * t);
                        out += 1;
                    }
                }
                if out == 0 {
                    return None;
                }
                len = out;
                std::mem::swap(&mut src, &mut dst);
            }
        }
        Some(&src[..len])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--grid N` within the model grid's range, else an error naming the flag.
    #[test]
    fn grid_flag_is_one_number_in_range() {
        assert_eq!(parse_grid_flag(" 64 "), Ok(64));
        assert_eq!(parse_grid_flag("3"), Err(GridFlagError::Range(3)));
        assert!(matches!(
            parse_grid_flag("abc"),
            Err(GridFlagError::NotANumber { .. })
        ));
        assert_eq!(
            GridFlagError::Range(3).to_string(),
            "--grid 3: a model's grid must be 4 to 2048 sites along its longest edge"
        );
    }

    #[test]
    fn placement_fills_the_interior_along_the_longest_edge() {
        let p = GridPlacement::fit([0.0, 0.0, 0.0], [9.0, 3.0, 0.0], 5).unwrap();
        assert_eq!(p.cell, 3.0);
        assert_eq!(p.dims, Dims::new(5, 3, 3).unwrap());
        // x: cells 1..=3 cover [0, 9]; y: the one interior cell is [0, 3]; z: centred on 0.
        assert_eq!(p.origin, [-3.0, -3.0, -4.5]);
        let b = p.bounds();
        assert_eq!(b.min, [-1.5, -1.5, -3.0]);
        assert_eq!(b.max, [10.5, 4.5, 3.0]);
        // Site spacing equals the cell edge.
        assert_eq!((b.max[0] - b.min[0]) / 4.0, 3.0);
        assert!(matches!(
            GridPlacement::fit([0.0; 3], [1.0; 3], 3),
            Err(VoxelizeError::BadGrid(3))
        ));
        assert!(matches!(
            GridPlacement::fit([0.0; 3], [0.0; 3], 8),
            Err(VoxelizeError::ZeroExtent(_))
        ));
    }

    #[test]
    fn equal_edges_get_equal_sites_despite_rounding() {
        for n in [4, 7, 33, 128, 129, 1000] {
            let p = GridPlacement::fit([0.1, -0.3, 0.7], [1.3, 0.9, 1.9], n).unwrap();
            assert_eq!(p.dims, Dims::cube(n).unwrap(), "n = {n}");
        }
    }

    #[test]
    fn strip_extent_of_a_triangle() {
        let tri = [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]];
        assert_eq!(strip_extent(&tri, 1.0, 2.0), Some((0.0, 3.0)));
        assert_eq!(strip_extent(&tri, 4.0, 5.0), Some((0.0, 0.0)));
        assert_eq!(strip_extent(&tri, 5.0, 6.0), None);
    }

    #[test]
    fn coverage_counts_with_wrap() {
        // 4×2, opaque only at texel (3, 1).
        let mut px = vec![[0u8; 4]; 8];
        px[7][3] = 255;
        let rep = TextureCoverage::new(&Texture::new(4, 2, px.clone(), Wrap::Repeat));
        let clamp = TextureCoverage::new(&Texture::new(4, 2, px, Wrap::Clamp));
        assert_eq!(rep.count(0, 3, 0, 1), (1, 8));
        // Unwrapped column -1 is column 3 when repeating, column 0 when clamped.
        assert_eq!(rep.count(-1, 0, 1, 1), (1, 2));
        assert_eq!(clamp.count(-1, 0, 1, 1), (0, 1));
        assert_eq!(clamp.count(3, 9, 1, 5), (1, 1));
        // A thin sliver through the opaque texel's interior, and one just past it.
        assert!(rep.polygon_is_opaque(&[[3.2, 1.5], [3.3, 1.5], [3.3, 1.6]]));
        assert!(!rep.polygon_is_opaque(&[[0.2, 0.5], [2.9, 1.9], [2.9, 1.95]]));
        // Its box reaches the opaque texel and its centroid misses it: the row scan decides.
        // The hypotenuse crosses v = 1 at u = 2.95, so row 1 is sampled only in column 2.
        assert!(!rep.polygon_is_opaque(&[[2.0, 0.1], [3.9, 0.1], [2.0, 1.9]]));
        assert!(rep.polygon_is_opaque(&[[2.0, 0.1], [3.9, 0.1], [2.0, 2.1]]));
    }
}
