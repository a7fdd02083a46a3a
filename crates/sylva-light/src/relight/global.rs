//! The coarse global grid (004 §3.2, 000 §3, SPEC §1 "two-level grid"): one LB grid over the
//! whole forest, so that a tree in its neighbours' shade gets less indirect light than the
//! same model standing alone.
//!
//! **Density.** Each coarse site's cell (edge `H`, world-aligned) takes its density from the
//! fine density grids of the instances that overlap it, resampled to world space: fine
//! densities are collision probabilities per fine cell (edge `h` in the world, the model's
//! cell times the instance's scale), so each sample becomes an extinction per unit length
//! `κ = -ln(1 - ρ) / h` (ρ capped at 0.999); overlapping instances add, the cell's mean `κ̄`
//! becomes the coarse collision probability `1 - exp(-κ̄ H)`, and the wood fraction is the
//! wood's share of `κ̄`. Luminance only: one colour whose σ_a, σ_s and g are the Rec. 709
//! luminance-weighted means of the medium's three.
//!
//! **What scales an instance.** A fine grid was solved assuming free-space light on its
//! boundary. The coarse grid says what actually arrives there: for each lattice direction
//! `k`, the mean of `f_k` (the density arriving along `c_k`) over the coarse sites just
//! outside the faces of the instance's box that `c_k` enters (the upwind shell), each face
//! weighted by the flux through it (`|n_k · normal| × area`). Summed over `k`, that is the
//! light entering the box relative to free space. Under base solution `C_j` it is exactly 1
//! (j ≥ 1) or 18 (`C_0`) for a tree with nothing around it: the sampled sites lie outside
//! the box, whose cells hold none of the tree, and what arrives there along `c_k` streamed
//! through empty sites from the boundary — the tree's own shadow and back-scatter travel
//! outwards and never enter this measure. A neighbour upwind absorbs part of it; light it
//! scatters towards the box adds. The numbers are linear in the coarse boundary, so they are
//! kept per coarse base solution (`inflow[i][j]`, 19 per instance) and relit with the
//! world-frame sun weights `W`: the sun scale of instance `i` is
//! `Σ_{j≥1} W_j inflow[i][j] / Σ_{j≥1} W_j`, the ambient scale `inflow[i][0] / 18`. They
//! multiply the instance's sun and ambient weights ([`InstanceScale::apply`]), so every
//! fragment's fine indirect light is scaled at no cost per lookup.
//!
//! The other option (the ratio of the forest's coarse solution to a coarse solution of the
//! instance alone, per fragment) needs a coarse solve per instance or model, and divides two
//! small numbers deep in a crown; this one is exactly 1 for a lone tree by construction.
//! What it does not see: a neighbour's foliage *inside* the instance's box (in a dense canopy
//! boxes overlap) and how the shade varies over one instance (the scale is per instance).
//!
//! The coarse solves (18 bases, `C_0` summed) run on the CPU solver (the grid is small, and
//! the shell inflows need the directional densities, which only the CPU lattice exposes) with
//! the papers' schedule; the result is cached per scene.

use std::path::Path;

use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use sylva_core::cache::CacheKey;
use sylva_core::container::{read_container, write_container, ByteReader, ByteWriter};
use sylva_geom::Aabb;
use sylva_lb::lattice::{unit, C, Q};
use sylva_lb::relight::{BasisWeights, RelightError, BASES};
use sylva_lb::solver::{Lattice, SolveOptions};
use sylva_lb::{Boundary, Bounds, ColourParams, DensityGrid, Dims, MediumParams};

use crate::lighting::LightingError;

/// Coarse cells between the forest's box and the grid's shell on every side.
pub(crate) const MARGIN: usize = 3;
/// Largest fine density used for the extinction (−ln(1 − ρ) is infinite at 1).
const RHO_CAP: f32 = 0.999;
/// Samples per coarse cell and axis at most, per instance.
const MAX_SAMPLES: usize = 4;
/// Extension, magic and version of cache entries.
pub const GLOBAL_EXTENSION: &str = "sglobal";
const MAGIC: &[u8; 8] = b"SYLVAGLB";
const VERSION: u32 = 1;

/// How the coarse grid is laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GlobalGridOptions {
    /// Sites along the forest box's longest edge, margins included (16 to 512).
    pub sites: usize,
}

impl Default for GlobalGridOptions {
    fn default() -> Self {
        GlobalGridOptions { sites: 64 }
    }
}

/// A coarse grid whose solves cost more than this many times the default grid's is announced
/// before it starts (the default takes seconds; 512 sites, about 4000 times as long).
pub const COSTLY_OVER_DEFAULT: f64 = 20.0;

impl GlobalGridOptions {
    pub fn validate(&self) -> Result<(), String> {
        if !(16..=512).contains(&self.sites) {
            return Err(format!(
                "global grid of {} sites along the longest edge: 16 to 512",
                self.sites
            ));
        }
        Ok(())
    }

    /// The coarse grid over a forest whose instances span `extent` (the size of their world
    /// box, metres).
    pub fn dims_over(&self, extent: Vec3) -> Result<Dims, String> {
        self.validate()?;
        let forest = Aabb {
            min: Vec3::ZERO,
            max: extent.max(Vec3::ZERO),
        };
        layout(&[forest], self).map(|(dims, _, _)| dims)
    }

    /// Site updates of one LB solve of that grid: its sites × its steps (the papers' run
    /// length, twice the longest edge). Every solve of the grid (3 colours for the forest
    /// grid, 18 base solutions for relighting's) costs this much.
    pub fn solve_updates(&self, extent: Vec3) -> Result<u64, String> {
        let dims = self.dims_over(extent)?;
        Ok(dims.sites() as u64 * SolveOptions::papers(dims).max_steps as u64)
    }

    /// How many times the default grid's solves these cost over the same forest.
    pub fn cost_over_default(&self, extent: Vec3) -> Result<f64, String> {
        let default = GlobalGridOptions::default().solve_updates(extent)?;
        Ok(self.solve_updates(extent)? as f64 / default.max(1) as f64)
    }

    /// A line to show before a grid that costs more than [`COSTLY_OVER_DEFAULT`] times the
    /// default's starts (`None` below that): its size and cost.
    pub fn cost_warning(&self, extent: Vec3, solves: usize) -> Result<Option<String>, String> {
        let ratio = self.cost_over_default(extent)?;
        if ratio <= COSTLY_OVER_DEFAULT {
            return Ok(None);
        }
        let dims = self.dims_over(extent)?;
        let updates = self.solve_updates(extent)? as f64 * solves as f64;
        Ok(Some(format!(
            "--global-grid {}: the coarse grid ({dims}, {} solves of {} steps, {:.1} G site \
             updates) costs about {ratio:.0}× the default's ({} sites): expect it to take \
             {ratio:.0} times as long (Ctrl-C stops it)",
            self.sites,
            solves,
            SolveOptions::papers(dims).max_steps,
            updates / 1e9,
            GlobalGridOptions::default().sites,
        )))
    }
}

/// What the coarse grid does to one instance's weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceScale {
    /// Factor of the sun's base solutions `B_1..B_18`.
    pub sun: f32,
    /// Factor of the ambient `B_0`.
    pub ambient: f32,
}

impl InstanceScale {
    pub const ONE: InstanceScale = InstanceScale {
        sun: 1.0,
        ambient: 1.0,
    };

    /// `w` with `w_1..w_18` scaled by `sun` and `w_0` by `ambient`.
    pub fn apply(&self, w: &BasisWeights) -> Result<BasisWeights, RelightError> {
        let mut v = w.0;
        v[0] *= self.ambient as f64;
        for x in &mut v[1..] {
            *x *= self.sun as f64;
        }
        BasisWeights::new(v)
    }
}

/// The coarse grid's answer for every instance of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalLight {
    pub dims: Dims,
    /// World position of site (0, 0, 0).
    pub origin: [f32; 3],
    /// Edge of a coarse cell in the world.
    pub cell: f32,
    /// Per instance and coarse base solution `j`: the light entering the instance's box,
    /// `Σ_k` of the flux-weighted mean `f_k` over its upwind shell (free space: 1, and 18
    /// for `C_0`). Instances without a fine grid hold the free-space values.
    inflow: Vec<[f32; BASES]>,
}

/// An instance as the coarse grid sees it.
#[derive(Debug, Clone, Copy)]
pub struct GlobalInstance<'a> {
    /// Its model's fine density grid (`None`: the instance is not in the coarse medium and
    /// keeps scale 1).
    pub density: Option<&'a DensityGrid>,
    /// Model → world.
    pub to_world: Affine3A,
}

/// A fine grid placed in the world.
pub(crate) struct Placed<'a> {
    grid: &'a DensityGrid,
    to_model: Affine3A,
    /// World box of the fine cells (the model grid's box, half a cell beyond the sites).
    pub(crate) world: Aabb,
    /// Fine cell edge in model space, and in the world.
    pub(crate) cell_model: f32,
    pub(crate) cell_world: f32,
}

pub(crate) fn placed<'a>(i: &GlobalInstance<'a>) -> Option<Placed<'a>> {
    let grid = i.density?;
    let b = grid.bounds;
    let cell_model = (b.max[0] - b.min[0]) / (grid.dims.nx - 1) as f32;
    let scale = i.to_world.matrix3.x_axis.length();
    if !(cell_model > 0.0 && cell_model.is_finite() && scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let half = Vec3::splat(0.5 * cell_model);
    let model_box = Aabb {
        min: Vec3::from_array(b.min) - half,
        max: Vec3::from_array(b.max) + half,
    };
    let mut world = Aabb::EMPTY;
    for c in model_box.corners() {
        world.grow(i.to_world.transform_point3(c));
    }
    Some(Placed {
        grid,
        to_model: i.to_world.inverse(),
        world,
        cell_model,
        cell_world: cell_model * scale,
    })
}

/// The single luminance colour: each parameter the Rec. 709 luminance-weighted mean.
pub fn luminance_medium(medium: &MediumParams) -> MediumParams {
    const Y: [f64; 3] = [0.2126, 0.7152, 0.0722];
    let mean = |f: fn(&ColourParams) -> f64| (0..3).map(|c| Y[c] * f(&medium.colours[c])).sum();
    let p = ColourParams {
        sigma_a: mean(|p| p.sigma_a),
        sigma_s: mean(|p| p.sigma_s),
        g: mean(|p| p.g),
    };
    MediumParams {
        colours: [p; 3],
        ..medium.clone()
    }
}

/// One face of an instance's upwind shell: coarse sites on a plane just outside the box.
#[derive(Debug, Clone)]
pub(crate) struct ShellFace {
    pub(crate) axis: usize,
    /// The face at the box's high side (entered by directions with `c[axis] < 0`).
    pub(crate) high: bool,
    pub(crate) area: f32,
    pub(crate) sites: Vec<[usize; 3]>,
}

/// The coarse layout over the instances' boxes: dims, origin, cell.
fn layout(boxes: &[Aabb], opts: &GlobalGridOptions) -> Result<(Dims, Vec3, f32), String> {
    let mut all = Aabb::EMPTY;
    for b in boxes {
        all = all.union(b);
    }
    let ext = all.max - all.min;
    let inner = opts.sites - 1 - 2 * MARGIN;
    let cell = (ext.max_element() / inner as f32).max(1e-3);
    let n = |e: f32| (e / cell).ceil() as usize + 1 + 2 * MARGIN;
    let dims = Dims::new(n(ext.x), n(ext.y), n(ext.z)).map_err(|e| e.to_string())?;
    Ok((dims, all.min - Vec3::splat(MARGIN as f32 * cell), cell))
}

/// The coarse density grid: each site's cell resampled from the fine grids overlapping it.
pub(crate) fn coarse_density(
    dims: Dims,
    origin: Vec3,
    cell: f32,
    fine: &[Option<Placed>],
) -> Result<DensityGrid, LightingError> {
    sylva_core::check_memory(
        &format!("the coarse global grid ({dims})"),
        dims.sites() as u64 * 8,
    )?;
    let (ny, nz) = (dims.ny, dims.nz);
    let slabs: Vec<(Vec<f32>, Vec<f32>)> = (0..dims.nx)
        .into_par_iter()
        .map(|x| {
            let x0 = origin.x + (x as f32 - 0.5) * cell;
            let near: Vec<&Placed> = fine
                .iter()
                .flatten()
                .filter(|p| p.world.max.x >= x0 && p.world.min.x <= x0 + cell)
                .collect();
            let mut density = vec![0.0f32; ny * nz];
            let mut wood = vec![0.0f32; ny * nz];
            for y in 0..ny {
                for z in 0..nz {
                    let c = origin + Vec3::new(x as f32, y as f32, z as f32) * cell;
                    let lo = c - Vec3::splat(0.5 * cell);
                    let hi = c + Vec3::splat(0.5 * cell);
                    let (mut kappa, mut kappa_wood) = (0.0f64, 0.0f64);
                    for p in &near {
                        if p.world.max.cmplt(lo).any() || p.world.min.cmpgt(hi).any() {
                            continue;
                        }
                        let (k, kw) = cell_extinction(p, lo, cell);
                        kappa += k;
                        kappa_wood += kw;
                    }
                    if kappa > 0.0 {
                        let i = y * nz + z;
                        density[i] = (1.0 - (-kappa * cell as f64).exp()) as f32;
                        wood[i] = (kappa_wood / kappa).clamp(0.0, 1.0) as f32;
                    }
                }
            }
            (density, wood)
        })
        .collect();
    let mut density = Vec::with_capacity(dims.sites());
    let mut wood = Vec::with_capacity(dims.sites());
    for (d, w) in slabs {
        density.extend(d);
        wood.extend(w);
    }
    let far = origin
        + Vec3::new(
            (dims.nx - 1) as f32,
            (dims.ny - 1) as f32,
            (dims.nz - 1) as f32,
        ) * cell;
    Ok(DensityGrid {
        dims,
        bounds: Bounds {
            min: origin.to_array(),
            max: far.to_array(),
        },
        density,
        wood,
    })
}

/// One instance's own extinction on the coarse sites whose cells overlap its box: a block of
/// sites from `lo` with `n` per axis, `κ` and its wood part per site (x, then y, then z).
pub(crate) struct ExtinctionBlock {
    pub(crate) lo: [usize; 3],
    pub(crate) n: [usize; 3],
    pub(crate) kappa: Vec<f32>,
    pub(crate) kappa_wood: Vec<f32>,
}

impl ExtinctionBlock {
    /// `(κ, κ_wood)` at coarse site `s`; zero outside the block.
    pub(crate) fn at(&self, s: [usize; 3]) -> (f32, f32) {
        let mut r = [0usize; 3];
        for a in 0..3 {
            if s[a] < self.lo[a] || s[a] >= self.lo[a] + self.n[a] {
                return (0.0, 0.0);
            }
            r[a] = s[a] - self.lo[a];
        }
        let i = (r[0] * self.n[1] + r[1]) * self.n[2] + r[2];
        (self.kappa[i], self.kappa_wood[i])
    }
}

/// `p`'s extinction on the coarse grid (`dims`, `origin`, `cell`), as [`coarse_density`]
/// resamples it, over the sites whose cells overlap its box.
pub(crate) fn instance_extinction(
    p: &Placed,
    dims: Dims,
    origin: Vec3,
    cell: f32,
) -> ExtinctionBlock {
    let n = [dims.nx, dims.ny, dims.nz];
    let mut lo = [0usize; 3];
    let mut count = [0usize; 3];
    for a in 0..3 {
        let first = ((p.world.min[a] - origin[a]) / cell - 0.5).ceil().max(0.0) as usize;
        let last =
            (((p.world.max[a] - origin[a]) / cell + 0.5).floor().max(0.0) as usize).min(n[a] - 1);
        lo[a] = first.min(n[a] - 1);
        count[a] = (last + 1).saturating_sub(lo[a]);
    }
    let sites = count[0] * count[1] * count[2];
    let mut kappa = vec![0.0f32; sites];
    let mut kappa_wood = vec![0.0f32; sites];
    let mut i = 0;
    for x in 0..count[0] {
        for y in 0..count[1] {
            for z in 0..count[2] {
                let s = Vec3::new((lo[0] + x) as f32, (lo[1] + y) as f32, (lo[2] + z) as f32);
                let corner = origin + (s - Vec3::splat(0.5)) * cell;
                let (k, kw) = cell_extinction(p, corner, cell);
                kappa[i] = k as f32;
                kappa_wood[i] = kw as f32;
                i += 1;
            }
        }
    }
    ExtinctionBlock {
        lo,
        n: count,
        kappa,
        kappa_wood,
    }
}

/// Mean extinction per unit length of one fine grid over the coarse cell at `lo` (edge
/// `cell`), and its wood part, from a few samples per axis (nearest fine site).
fn cell_extinction(p: &Placed, lo: Vec3, cell: f32) -> (f64, f64) {
    let q = ((cell / p.cell_world).ceil() as usize).clamp(1, MAX_SAMPLES);
    let g = p.grid;
    let (min, inv) = (Vec3::from_array(g.bounds.min), 1.0 / p.cell_model);
    let last = [g.dims.nx - 1, g.dims.ny - 1, g.dims.nz - 1];
    let (mut k, mut kw) = (0.0f64, 0.0f64);
    for a in 0..q {
        for b in 0..q {
            for c in 0..q {
                let f = Vec3::new(a as f32 + 0.5, b as f32 + 0.5, c as f32 + 0.5) / q as f32;
                let pm = p.to_model.transform_point3(lo + f * cell);
                let s = (pm - min) * inv;
                let r = s.round();
                if r.cmplt(Vec3::ZERO).any()
                    || r.x > last[0] as f32
                    || r.y > last[1] as f32
                    || r.z > last[2] as f32
                    || !r.is_finite()
                {
                    continue;
                }
                let i = g.dims.index(r.x as usize, r.y as usize, r.z as usize);
                let rho = g.density[i].min(RHO_CAP);
                if rho > 0.0 {
                    let e = -(1.0 - rho as f64).ln() / p.cell_world as f64;
                    k += e;
                    kw += e * g.wood[i] as f64;
                }
            }
        }
    }
    let n = (q * q * q) as f64;
    (k / n, kw / n)
}

/// The upwind shell faces of a world box: the coarse planes just outside each of its six
/// faces (their cells do not reach into the box), over the face's extent.
pub(crate) fn shell_faces(b: &Aabb, dims: Dims, origin: Vec3, cell: f32) -> Vec<ShellFace> {
    let n = [dims.nx, dims.ny, dims.nz];
    let coord = |a: usize, v: f32| (v - origin[a]) / cell;
    let clamp = |a: usize, i: f32| (i.max(1.0) as usize).min(n[a] - 2);
    let ext = b.max - b.min;
    let mut faces = Vec::with_capacity(6);
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let span = |a: usize| {
            let lo = clamp(a, coord(a, b.min[a]).round());
            let hi = clamp(a, coord(a, b.max[a]).round()).max(lo);
            lo..=hi
        };
        for high in [false, true] {
            // A site's cell reaches half a cell from it: below the low face, above the high.
            let plane = if high {
                clamp(axis, (coord(axis, b.max[axis]) + 0.5).ceil())
            } else {
                clamp(axis, (coord(axis, b.min[axis]) - 0.5).floor())
            };
            let mut sites = Vec::new();
            for i in span(u) {
                for j in span(v) {
                    let mut s = [0usize; 3];
                    s[axis] = plane;
                    s[u] = i;
                    s[v] = j;
                    sites.push(s);
                }
            }
            faces.push(ShellFace {
                axis,
                high,
                area: (ext[u] * ext[v]).max(cell * cell),
                sites,
            });
        }
    }
    faces
}

/// `Σ_k` of the flux-weighted mean `f_k` over the faces `c_k` enters.
fn shell_inflow(lattice: &Lattice, faces: &[ShellFace]) -> f32 {
    let mut total = 0.0f64;
    for (k, c) in C.iter().enumerate().take(Q).skip(1) {
        let n = unit(k);
        let (mut sum, mut weight) = (0.0f64, 0.0f64);
        for f in faces {
            let entering = if f.high { c[f.axis] < 0 } else { c[f.axis] > 0 };
            if !entering || f.sites.is_empty() {
                continue;
            }
            let w = n[f.axis].abs() * f.area as f64;
            let mean = f
                .sites
                .iter()
                .map(|s| lattice.f(s[0], s[1], s[2], k) as f64)
                .sum::<f64>()
                / f.sites.len() as f64;
            sum += w * mean;
            weight += w;
        }
        if weight > 0.0 {
            total += sum / weight;
        }
    }
    total as f32
}

impl GlobalLight {
    /// Lays the coarse grid over `instances`, resamples their fine grids into it, solves its
    /// 18 base solutions (luminance, CPU) and measures each instance's inflow under each.
    /// `progress(done, total)` after every LB step of its 18 solves.
    // Base solutions index the inflow table's columns while instances run over its rows.
    #[allow(clippy::needless_range_loop)]
    pub fn solve(
        instances: &[GlobalInstance],
        medium: &MediumParams,
        opts: &GlobalGridOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<GlobalLight, LightingError> {
        opts.validate().map_err(LightingError::Global)?;
        let fine: Vec<Option<Placed>> = instances.iter().map(placed).collect();
        let boxes: Vec<Aabb> = fine.iter().flatten().map(|p| p.world).collect();
        let mut free = [1.0f32; BASES];
        free[0] = (BASES - 1) as f32;
        if boxes.is_empty() {
            return Ok(GlobalLight {
                dims: Dims::new(3, 3, 3).expect("valid"),
                origin: [0.0; 3],
                cell: 1.0,
                inflow: vec![free; instances.len()],
            });
        }
        let (dims, origin, cell) = layout(&boxes, opts).map_err(LightingError::Global)?;
        let grid = coarse_density(dims, origin, cell, &fine)?;
        let coarse = luminance_medium(medium);
        let shells: Vec<Option<Vec<ShellFace>>> = fine
            .iter()
            .map(|p| {
                p.as_ref()
                    .map(|p| shell_faces(&p.world, dims, origin, cell))
            })
            .collect();
        let mut inflow = vec![free; instances.len()];
        let solve = SolveOptions::papers(dims);
        let mut lattice: Option<Lattice> = None;
        for j in 1..BASES {
            let boundary = Boundary::basis(j);
            let lat = match lattice.as_mut() {
                Some(l) => {
                    l.reset(boundary);
                    l
                }
                None => lattice.insert(
                    Lattice::new(&grid, &coarse, 0, boundary)
                        .map_err(|e| LightingError::Global(format!("coarse solve: {e}")))?,
                ),
            };
            let steps = solve.max_steps;
            let total = (BASES - 1) * steps;
            lat.run(&solve, &mut |step, _| {
                progress((j - 1) * steps + step.min(steps), total)
            })
            .map_err(|e| LightingError::Global(format!("coarse solve: {e}")))?;
            for (i, shell) in shells.iter().enumerate() {
                if let Some(faces) = shell {
                    inflow[i][j] = shell_inflow(lat, faces);
                }
            }
            progress(j * steps, total);
        }
        for (i, shell) in shells.iter().enumerate() {
            if shell.is_some() {
                inflow[i][0] = inflow[i][1..].iter().sum();
            }
        }
        Ok(GlobalLight {
            dims,
            origin: origin.to_array(),
            cell,
            inflow,
        })
    }

    /// Instances the grid was solved for.
    pub fn instances(&self) -> usize {
        self.inflow.len()
    }

    /// Instance `i`'s inflow under each coarse base solution.
    pub fn inflow(&self, i: usize) -> [f32; BASES] {
        self.inflow[i]
    }

    /// Per instance, its scales under world-frame weights `w` (see the module docs).
    pub fn scales(&self, w: &BasisWeights) -> Vec<InstanceScale> {
        let sun_total: f64 = w.0[1..].iter().sum();
        self.inflow
            .iter()
            .map(|f| {
                let sun = if sun_total > 0.0 {
                    (w.0[1..]
                        .iter()
                        .zip(&f[1..])
                        .map(|(w, v)| w * *v as f64)
                        .sum::<f64>()
                        / sun_total) as f32
                } else {
                    1.0
                };
                InstanceScale {
                    sun,
                    ambient: f[0] / (BASES - 1) as f32,
                }
            })
            .collect()
    }

    /// Writes the grid's answer as a cache entry (atomically; `key` in its metadata); `Err`
    /// says why it could not.
    pub fn write(&self, path: &Path, key: CacheKey) -> Result<(), String> {
        let meta = vec![
            key.metadata(),
            ("instances".to_string(), self.inflow.len().to_string()),
        ];
        write_container(path, MAGIC, VERSION, &meta, &self.to_bytes()).map_err(|e| e.to_string())
    }

    /// Reads a cache entry for `instances` instances under `key`; `Err` is why it is
    /// unusable, naming the file.
    pub fn read(path: &Path, key: CacheKey, instances: usize) -> Result<GlobalLight, String> {
        let c = read_container(path, MAGIC, VERSION, "global grid cache entry")
            .map_err(|e| e.to_string())?;
        let shown = path.display();
        key.check(path, c.metadata_value(crate::lighting::KEY_METADATA))?;
        GlobalLight::from_bytes(&c.payload, instances).map_err(|e| format!("{shown}: {e}"))
    }

    /// The grid's answer as bytes: a cache entry's payload, and what MPI ranks send.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        write_layout(&mut w, self.dims, self.origin, self.cell);
        w.f32s(self.inflow.as_flattened());
        w.bytes
    }

    /// The answer [`GlobalLight::to_bytes`] encoded, for `instances` instances; `Err` says
    /// what is wrong with the bytes.
    pub fn from_bytes(bytes: &[u8], instances: usize) -> Result<GlobalLight, String> {
        let mut r = ByteReader::new(bytes);
        let (dims, origin, cell) = read_layout(&mut r)?;
        let flat = r.f32s("inflow")?;
        r.finish()?;
        if flat.len() != instances * BASES {
            return Err(format!(
                "{} values, {instances} instances need {}",
                flat.len(),
                instances * BASES
            ));
        }
        if flat.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err("a value is not finite or negative".into());
        }
        Ok(GlobalLight {
            dims,
            origin,
            cell,
            inflow: flat
                .chunks_exact(BASES)
                .map(|c| c.try_into().expect("19 values"))
                .collect(),
        })
    }
}

/// Writes a coarse grid's layout (sites per axis, the world position of site 0, the cell):
/// the head of [`GlobalLight::to_bytes`] and of the forest grid's answers.
pub(crate) fn write_layout(w: &mut ByteWriter, dims: Dims, origin: [f32; 3], cell: f32) {
    for n in [dims.nx, dims.ny, dims.nz] {
        w.u32(n as u32);
    }
    for v in origin {
        w.f32(v);
    }
    w.f32(cell);
}

/// Reads what [`write_layout`] wrote; `Err` when it is no valid layout (a grid too small,
/// an origin or cell not finite, a cell not positive).
pub(crate) fn read_layout(r: &mut ByteReader) -> Result<(Dims, [f32; 3], f32), String> {
    let mut n = [0usize; 3];
    for v in &mut n {
        *v = r.u32("grid size")? as usize;
    }
    let dims = Dims::new(n[0], n[1], n[2]).map_err(|e| e.to_string())?;
    let mut origin = [0f32; 3];
    for v in &mut origin {
        *v = r.f32("origin")?;
    }
    let cell = r.f32("cell")?;
    if !(cell.is_finite() && cell > 0.0) || origin.iter().any(|v| !v.is_finite()) {
        return Err("the grid's origin or cell is not finite, or the cell not positive".into());
    }
    Ok((dims, origin, cell))
}

/// How long a global solve took and where its answer came from.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalReport {
    /// Which coarse grid: "global grid" (the paper light's), "forest grid" (the physical
    /// light's for one sun) or "forest grid parts" (its relit parts).
    pub what: &'static str,
    pub source: crate::lighting::LightingSource,
    pub seconds: f64,
    pub dims: Dims,
    pub path: Option<std::path::PathBuf>,
    /// Why the solved grid could not be cached (it is good, only not kept).
    pub cache_warning: Option<String>,
}

impl GlobalReport {
    /// A grid of `dims` solved now, not cached, `t0` when it began.
    pub(crate) fn computed(what: &'static str, dims: Dims, t0: std::time::Instant) -> GlobalReport {
        GlobalReport {
            what,
            source: crate::lighting::LightingSource::Computed,
            seconds: t0.elapsed().as_secs_f64(),
            dims,
            path: None,
            cache_warning: None,
        }
    }
}

#[cfg(test)]
mod cost_tests {
    use super::*;

    // Two trees side by side: 12 m by 8 m tall by 6 m.
    const FOREST: Vec3 = Vec3::new(12.0, 8.0, 6.0);

    #[test]
    fn the_default_costs_one_default_and_512_thousands() {
        let g = |sites| GlobalGridOptions { sites };
        assert_eq!(g(64).cost_over_default(FOREST).unwrap(), 1.0);
        // Sites grow with the cube of the edge and steps with the edge: about (512/64)⁴.
        let r = g(512).cost_over_default(FOREST).unwrap();
        assert!((2500.0..6000.0).contains(&r), "{r}");
        let r = g(32).cost_over_default(FOREST).unwrap();
        assert!(r < 0.1, "{r}");
        assert!(g(8).cost_over_default(FOREST).is_err(), "out of range");
    }

    #[test]
    fn only_a_grid_far_above_the_default_s_cost_warns() {
        let g = |sites| GlobalGridOptions { sites };
        assert_eq!(g(64).cost_warning(FOREST, 3).unwrap(), None);
        assert_eq!(g(96).cost_warning(FOREST, 3).unwrap(), None, "about 5×");
        let w = g(512).cost_warning(FOREST, 3).unwrap().expect("a warning");
        assert!(
            w.starts_with("--global-grid 512: the coarse grid (512×")
                && w.contains("× the default's (64 sites)")
                && w.contains("3 solves of 1024 steps"),
            "{w}"
        );
    }
}
