//! The lattice-Boltzmann budget of a cyclic plot (issue 29 item 5b): the stand's leaf area
//! binned into cubic cells, the light's first flights traced through the explicit leaves,
//! and the rest carried by the LB solver over a cyclic plot on a reflecting soil
//! (`sylva_lb::plot`), the same lattice as a scene's physical light (docs/budget.md).
//!
//! * **Cells.** Whole cells tile the plot (its sides must be multiples of the cell), from the
//!   soil up to above the highest leaf. Each leaf triangle's one-sided area goes to the cell
//!   of its centroid, wrapped around the plot, as 2⁻³² cell² fixed-point integers (the same
//!   for any thread count); a cell's LB density is the collision probability of that area
//!   ([`sylva_grid::density::collision_probability`], G = 1/2).
//! * **First flights, traced** on the photons' kd-trees across the cyclic sides, because the
//!   lattice's 18 directions draw them poorly (its upward ones reach 45° from the zenith at
//!   most, its horizontal ones never leave their row): the sun's beam to the first leaf or
//!   the soil ([`direct_beam`]); the light those leaves scatter once, to the next leaf, the
//!   sky or the soil, and the soil's light, to the first leaf or the sky ([`Flights`]).
//!   Where a flight meets a leaf, the leaf absorbs 1 − (r + t) and scatters the rest into
//!   the lattice in its cell, along the lattice directions about the ray's.
//! * **The LB** carries the light scattered twice and more until nothing changes, the soil
//!   reflecting what lands on it each step, and tallies what the leaves absorb, what leaves
//!   through the top and what lands on the soil.

use crate::photons::{PlotBox, SunAngles, MAX_EVENTS};
use crate::stand::Stand;
use crate::{Band, BudgetError, CanopySpec, StandError};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use sylva_lb::lattice::{weight, Q};
use sylva_lb::light::{medium_for, PlantOptics};
use sylva_lb::plot::{solve_cyclic_plot, FirstFlight, PlotLight, PlotOptions, SoilLight};
use sylva_lb::{Bounds, DensityGrid, Dims};
use sylva_trace::{Ray, SceneAccel, TraceStats, TraversalConfig};

/// Fixed-point scale of binned leaf area (cell² units).
const AREA_SCALE: f64 = 4_294_967_296.0;

/// How the lattice budget is made.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LbConfig {
    /// Cell edge, m (rounded so that whole cells tile the plot). The default 1 m agreed best
    /// with the photons over the 54 cases (docs/budget.md): finer cells made more
    /// nearly empty rows, along which the lattice's horizontal directions carry light round
    /// the plot that a real photon would have climbed out of.
    pub cell: f64,
    /// Direct-beam rays per column side (`rays²` per column).
    pub rays: usize,
    /// The LB stops once the flows through its faces change by at most this share of a
    /// step's input from step to step (and input and output agree to 10⁻³).
    pub tolerance: f64,
    pub max_steps: usize,
}

impl Default for LbConfig {
    fn default() -> LbConfig {
        LbConfig {
            cell: 1.0,
            rays: 4,
            tolerance: 1e-6,
            max_steps: 50_000,
        }
    }
}

impl LbConfig {
    pub fn validate(&self) -> Result<(), BudgetError> {
        if !(self.cell.is_finite() && self.cell > 0.0) {
            return Err(BudgetError::invalid(
                "--lb-cell",
                self.cell,
                "must be a positive number of metres",
            ));
        }
        if !(1..=64).contains(&self.rays) {
            return Err(BudgetError::invalid(
                "--lb-rays",
                self.rays,
                "must be 1 to 64 rays per column side",
            ));
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(BudgetError::invalid(
                "--lb-tolerance",
                self.tolerance,
                "must be in (0, 1)",
            ));
        }
        Ok(())
    }
}

/// The stand's leaves as LB cells.
#[derive(Debug, Clone)]
pub struct PlotGrid {
    /// The LB grid: interior sites are the cells, plus the shell.
    pub grid: DensityGrid,
    /// Cell edge, m.
    pub cell: f64,
    /// One-sided leaf area binned, m² (the stand's, to rounding).
    pub leaf_area: f64,
}

impl PlotGrid {
    /// Bins the leaves of `stand` (grown from `spec`) into cells of about `cell` metres,
    /// once it is sure the lattice and the flights of `rays²` rays a column will fit.
    pub fn build(
        spec: &CanopySpec,
        stand: &Stand,
        cell: f64,
        rays: usize,
    ) -> Result<PlotGrid, BudgetError> {
        if !spec.plot.cyclic {
            return Err(StandError::invalid(
                format!("{}: [plot] cyclic", spec.name),
                false,
                "the lattice budget needs a cyclic plot (light leaving a side re-enters on \
                 the opposite one); use the Monte Carlo budget for an isolated plot",
            )
            .into());
        }
        let [sx, sz] = spec.plot.size;
        let asked = cell;
        let nx = (sx / cell).round().max(1.0) as usize;
        let cell = sx / nx as f64;
        let nz = (sz / cell).round().max(1.0) as usize;
        if (nz as f64 * cell - sz).abs() > 1e-6 * sz || nx < 2 || nz < 2 {
            return Err(BudgetError::invalid(
                "--lb-cell",
                asked,
                format!(
                    "whole cells must tile the {sx} m × {sz} m plot, at least 2 along each side: \
                     choose a cell that divides both sides"
                ),
            ));
        }
        let ny = (stand.top / cell).ceil().max(1.0) as usize;
        let dims = Dims::new(nx + 2, ny + 2, nz + 2)
            .map_err(|e| BudgetError::invalid("--lb-cell", cell, format!("the LB grid: {e}")))?;
        // Per site: the binned area, the density and wood, the beam's counts and shares. Per
        // ray of a column: its beam hit and, for the soil and the once-scattered light, up to
        // three sorted entries a ray that meets a leaf (24 B each, 4 scattered rays a hit).
        let rays_per_column = (rays * rays) as u64;
        let flights = (nx * nz) as u64 * rays_per_column * (32 + 3 * 24 * (1 + 4));
        sylva_core::check_memory(
            &format!("the lattice budget on a {dims} grid"),
            sylva_lb::solver::memory_needed(dims)
                + dims.sites() as u64 * (8 + 8 + 8 + 4 + 4)
                + flights,
        )?;
        let area: Vec<AtomicU64> = (0..dims.sites()).map(|_| AtomicU64::new(0)).collect();
        let half = stand.half;
        let per_cell = AREA_SCALE / (cell * cell);
        stand.instances[..stand.placed].par_iter().for_each(|inst| {
            let t = inst.transform();
            let mesh = &stand.models[inst.model as usize].mesh;
            for tri in &mesh.indices {
                let [a, b, c] = tri.map(|i| t.transform_point3(mesh.positions[i as usize].into()));
                let a_m2 = 0.5 * (b - a).cross(c - a).length() as f64;
                let g = (a + b + c) / 3.0;
                let ix = ((g.x as f64 + half[0]) / cell)
                    .floor()
                    .rem_euclid(nx as f64) as usize;
                let iz = ((g.z as f64 + half[1]) / cell)
                    .floor()
                    .rem_euclid(nz as f64) as usize;
                let iy = ((g.y as f64 / cell).floor().max(0.0) as usize).min(ny - 1);
                let i = dims.index(ix.min(nx - 1) + 1, iy + 1, iz.min(nz - 1) + 1);
                area[i].fetch_add((a_m2 * per_cell).round() as u64, Ordering::Relaxed);
            }
        });
        let cell_area: Vec<f64> = area
            .into_iter()
            .map(|a| a.into_inner() as f64 / AREA_SCALE)
            .collect();
        let density: Vec<f32> = cell_area
            .iter()
            .map(|&a| sylva_grid::density::collision_probability(a, 0.0, 1.0).0 as f32)
            .collect();
        let leaf_area = cell_area.iter().sum::<f64>() * cell * cell;
        let h = 0.5 * cell as f32;
        let bounds = Bounds {
            min: [-half[0] as f32 - h, -h, -half[1] as f32 - h],
            max: [
                half[0] as f32 + h,
                (ny as f64 + 0.5) as f32 * cell as f32,
                half[1] as f32 + h,
            ],
        };
        let grid = DensityGrid::new(dims, bounds, density, vec![0.0; dims.sites()])
            .map_err(|e| BudgetError::invalid("the lattice budget's grid", dims, e.to_string()))?;
        Ok(PlotGrid {
            grid,
            cell,
            leaf_area,
        })
    }
}

/// Where a leaf first met a ray of the sun: the point, the leaf's normal facing the sun,
/// and the ray's share of the sunlight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamHit {
    pub point: Vec3,
    pub facing: Vec3,
    pub share: f64,
}

/// The sun's direct beam: per site the share of the sunlight whose first leaf is in that
/// cell, per interior column the share that reaches the soil without meeting one, and
/// where each ray met its leaf.
#[derive(Debug, Clone)]
pub struct DirectBeam {
    pub intercepted: Vec<f64>,
    pub ground: Vec<f64>,
    pub hits: Vec<BeamHit>,
}

/// The cell (site index) of point `p` of the plot, wrapped around the sides.
fn site_of(plot: &PlotGrid, half: [f64; 2], p: Vec3) -> usize {
    let dims = plot.grid.dims;
    let (nx, ny, nz) = (dims.nx - 2, dims.ny - 2, dims.nz - 2);
    let (x, z) = column_of(plot, half, p);
    let y = ((p.y as f64 / plot.cell).floor().max(0.0) as usize).min(ny - 1);
    debug_assert!(x < nx && z < nz);
    dims.index(x + 1, y + 1, z + 1)
}

/// The interior column (x, z) of point `p`, wrapped around the sides.
fn column_of(plot: &PlotGrid, half: [f64; 2], p: Vec3) -> (usize, usize) {
    let dims = plot.grid.dims;
    let (nx, nz) = (dims.nx - 2, dims.nz - 2);
    let x = ((p.x as f64 + half[0]) / plot.cell).floor() as i64;
    let z = ((p.z as f64 + half[1]) / plot.cell).floor() as i64;
    (
        x.rem_euclid(nx as i64) as usize,
        z.rem_euclid(nz as i64) as usize,
    )
}

/// Where a ray from `o` along `d` ends in the cyclic plot.
enum RayEnd {
    /// A leaf at this point, with its normal facing the ray's origin.
    Leaf(Vec3, Vec3),
    Sky,
    Soil(Vec3),
}

fn follow(
    bx: &PlotBox,
    accel: &SceneAccel,
    stats: &mut TraceStats,
    mut o: Vec3,
    d: Vec3,
) -> RayEnd {
    for _ in 0..MAX_EVENTS {
        let e = bx.exits(o, d);
        let ray = Ray::segment(o, d, 0.0, e.end);
        if let Some(hit) = accel.closest_hit(&ray, TraversalConfig::default(), stats) {
            let ng = accel.geometric_normal(&hit);
            let facing = if ng.dot(d) < 0.0 { ng } else { -ng };
            return RayEnd::Leaf(ray.at(hit.t), facing);
        }
        if e.end == e.soil {
            return RayEnd::Soil(o + d * e.soil);
        }
        if e.end == e.top {
            return RayEnd::Sky;
        }
        o = bx.wrapped(o, d, &e);
    }
    // A ray that keeps crossing the sides without meeting anything: it runs parallel to
    // the soil, which cosine-distributed and sun rays do not.
    RayEnd::Sky
}

/// Traces `rays²` parallel rays per column of `plot` along `travel` (unit, downwards) from
/// the stand's top through its explicit leaves (`accel`, built from the stand's models and
/// instances), crossing the cyclic sides, to the first leaf or the soil.
pub fn direct_beam(
    stand: &Stand,
    accel: &SceneAccel,
    plot: &PlotGrid,
    travel: Vec3,
    rays: usize,
) -> DirectBeam {
    let dims = plot.grid.dims;
    let (nx, nz) = (dims.nx - 2, dims.nz - 2);
    let ray_share = 1.0 / (nx * nz * rays * rays) as f64;
    let bx = PlotBox::of(stand);
    let cell = plot.cell;
    // Per column: the sites met, the columns landed on, the hits.
    type Column = (Vec<usize>, Vec<usize>, Vec<BeamHit>);
    let columns: Vec<Column> = (0..nx * nz)
        .into_par_iter()
        .map(|column| {
            let (cx, cz) = (column / nz, column % nz);
            let mut stats = TraceStats::default();
            let (mut met, mut landed, mut hits) = (Vec::new(), Vec::new(), Vec::new());
            for a in 0..rays {
                for b in 0..rays {
                    let o = Vec3::new(
                        ((cx as f64 + (a as f64 + 0.5) / rays as f64) * cell - stand.half[0])
                            as f32,
                        bx.top,
                        ((cz as f64 + (b as f64 + 0.5) / rays as f64) * cell - stand.half[1])
                            as f32,
                    );
                    match follow(&bx, accel, &mut stats, o, travel) {
                        RayEnd::Leaf(p, facing) => {
                            met.push(site_of(plot, stand.half, p));
                            hits.push(BeamHit {
                                point: p,
                                facing,
                                share: ray_share,
                            });
                        }
                        RayEnd::Soil(p) => {
                            let (x, z) = column_of(plot, stand.half, p);
                            landed.push(x * nz + z);
                        }
                        // Downwards rays end on a leaf or the soil.
                        RayEnd::Sky => {}
                    }
                }
            }
            (met, landed, hits)
        })
        .collect();
    // Every ray carries the same share: count them, so the sums are exact whatever the order.
    let mut intercepted = vec![0u32; dims.sites()];
    let mut ground = vec![0u32; nx * nz];
    let mut hits = Vec::new();
    for (met, landed, h) in columns {
        for i in met {
            intercepted[i] += 1;
        }
        for c in landed {
            ground[c] += 1;
        }
        hits.extend(h);
    }
    let share = |n: u32| n as f64 * ray_share;
    DirectBeam {
        intercepted: intercepted.into_iter().map(share).collect(),
        ground: ground.into_iter().map(share).collect(),
        hits,
    }
}

/// Light on its first flight from known sources, traced once through the explicit leaves:
/// for each leaf met, its cell and the lattice directions around the ray's direction (the
/// polyhedron face it crosses, as the sun's first collision), so that the lattice scatters
/// it as the leaf would; and per source what escapes to the sky or lands on the soil.
/// Scaled by the sources' strengths each time it is used ([`Flights::flight`]).
#[derive(Debug, Clone)]
pub struct Flights {
    /// Sites met, in site order, and where each one's entries start in `entries` (one more
    /// than the sites: the end).
    sites: Vec<usize>,
    starts: Vec<usize>,
    /// (incident lattice direction, source, share of the source's light).
    entries: Vec<(u8, u32, f32)>,
    /// Per source, the share of its light that escapes to the sky.
    escape: Vec<f64>,
    /// (source, column, share) of the rays that land on the soil.
    floor: Vec<(u32, u32, f64)>,
    columns: usize,
}

/// Traces the rays of a unit of work, telling the callback each one's source, share and end.
type SourceRays<'a> = dyn Fn(usize, &mut dyn FnMut(usize, f64, Traced)) + Sync + 'a;

/// What one ray of a source did.
enum Traced {
    Met(usize, Vec3),
    Sky,
    Soil(usize),
}

impl Flights {
    /// `rays(unit, emit)` traces the rays of each of `units` (in parallel), calling
    /// `emit(source, share, end)` for each; `sources` strengths scale them later.
    fn build(units: usize, sources: usize, columns: usize, rays: &SourceRays) -> Flights {
        type PerUnit = (
            Vec<(usize, u8, u32, f32)>,
            Vec<(u32, f64)>,
            Vec<(u32, u32, f64)>,
        );
        let per_unit: Vec<PerUnit> = (0..units)
            .into_par_iter()
            .map(|unit| {
                let (mut met, mut escape, mut floor) = (Vec::new(), Vec::new(), Vec::new());
                rays(unit, &mut |source, share, end| match end {
                    Traced::Met(site, d) => {
                        let travel = [d.x as f64, d.y as f64, d.z as f64];
                        if let Ok(h) = sylva_lb::relight::polyhedron::face_hit(travel) {
                            for (&j, &k) in h.vertices.iter().zip(&h.weights) {
                                if k > 0.0 {
                                    met.push((site, j as u8, source as u32, (share * k) as f32));
                                }
                            }
                        }
                    }
                    Traced::Sky => escape.push((source as u32, share)),
                    Traced::Soil(column) => floor.push((source as u32, column as u32, share)),
                });
                (met, escape, floor)
            })
            .collect();
        // Summed in the units' order: the same for any thread count.
        let mut escape = vec![0.0; sources];
        let mut floor = Vec::new();
        for (_, e, f) in &per_unit {
            for &(source, share) in e {
                escape[source as usize] += share;
            }
            floor.extend_from_slice(f);
        }
        let mut all: Vec<(usize, u8, u32, f32)> =
            per_unit.into_iter().flat_map(|(m, _, _)| m).collect();
        // Stable: entries of one (site, direction, source) keep the rays' order, so the sums
        // are the same for any thread count.
        all.par_sort_by_key(|&(site, j, source, _)| (site, j, source));
        let mut sites = Vec::new();
        let mut starts = Vec::new();
        for (i, e) in all.iter().enumerate() {
            if sites.last() != Some(&e.0) {
                sites.push(e.0);
                starts.push(i);
            }
        }
        starts.push(all.len());
        Flights {
            sites,
            starts,
            entries: all.into_iter().map(|(_, j, c, w)| (j, c, w)).collect(),
            escape,
            floor,
            columns,
        }
    }

    /// The soil's first flights: from every column, `rays²` rays leave the soil
    /// cosine-distributed (stratified, jittered from a fixed seed) up to the first leaf or
    /// the sky. Source = column.
    pub fn soil(stand: &Stand, accel: &SceneAccel, plot: &PlotGrid, rays: usize) -> Flights {
        let dims = plot.grid.dims;
        let (nx, nz) = (dims.nx - 2, dims.nz - 2);
        let bx = PlotBox::of(stand);
        let w = 1.0 / (rays * rays) as f64;
        Flights::build(nx * nz, nx * nz, nx * nz, &|column, emit| {
            let (cx, cz) = (column / nz, column % nz);
            let mut rng = sylva_core::SplitMix64::for_chunk(SOIL_SEED, column as u64);
            let mut stats = TraceStats::default();
            for a in 0..rays {
                for b in 0..rays {
                    let u1 = (a as f64 + rng.next_f64()) / rays as f64;
                    let u2 = (b as f64 + rng.next_f64()) / rays as f64;
                    let d = cosine(Vec3::Y, u1, u2);
                    let o = Vec3::new(
                        ((cx as f64 + rng.next_f64()) * plot.cell - stand.half[0]) as f32,
                        0.0,
                        ((cz as f64 + rng.next_f64()) * plot.cell - stand.half[1]) as f32,
                    );
                    let end = match follow(&bx, accel, &mut stats, o, d) {
                        RayEnd::Leaf(p, _) => Traced::Met(site_of(plot, stand.half, p), d),
                        _ => Traced::Sky,
                    };
                    emit(column, w, end);
                }
            }
        })
    }

    /// The sun's light once scattered, on its flight from the leaf the beam met: per hit,
    /// `rays` rays cosine-distributed about the side facing the sun (reflected: source 0) and
    /// as many about the other side (transmitted: source 1), to the next leaf, the sky or the
    /// soil.
    pub fn once_scattered(
        stand: &Stand,
        accel: &SceneAccel,
        plot: &PlotGrid,
        hits: &[BeamHit],
        rays: usize,
    ) -> Flights {
        let dims = plot.grid.dims;
        let nz = dims.nz - 2;
        let bx = PlotBox::of(stand);
        // Units of work: each side (source 0: reflected, 1: transmitted) of a chunk of hits.
        const CHUNK: usize = 1024;
        let units = 2 * hits.len().div_ceil(CHUNK);
        Flights::build(units, 2, (dims.nx - 2) * nz, &|k, emit| {
            let (side, chunk) = (k % 2, k / 2);
            let mut rng = sylva_core::SplitMix64::for_chunk(SCATTER_SEED, k as u64);
            let mut stats = TraceStats::default();
            for h in hits.iter().skip(chunk * CHUNK).take(CHUNK) {
                let n = if side == 0 { h.facing } else { -h.facing };
                let eps = 1e-4 * h.point.abs().max_element().max(1.0);
                for a in 0..rays {
                    let u1 = (a as f64 + rng.next_f64()) / rays as f64;
                    let d = cosine(n, u1, rng.next_f64());
                    let end = match follow(&bx, accel, &mut stats, h.point + n * eps, d) {
                        RayEnd::Leaf(p, _) => Traced::Met(site_of(plot, stand.half, p), d),
                        RayEnd::Sky => Traced::Sky,
                        RayEnd::Soil(p) => {
                            let (x, z) = column_of(plot, stand.half, p);
                            Traced::Soil(x * nz + z)
                        }
                    };
                    emit(side, h.share / rays as f64, end);
                }
            }
        })
    }

    /// The flight of light `strength` per source, met by leaves that scatter as `leaf`.
    pub fn flight(&self, strength: &[f64], leaf: &LeafScatter) -> FirstFlight {
        if strength.iter().all(|&v| v == 0.0) {
            // A black soil sends nothing: no work per step.
            return FirstFlight::default();
        }
        let groups: Vec<((usize, [f32; Q]), f64)> = (0..self.sites.len())
            .into_par_iter()
            .map(|g| {
                let mut incident = [0.0f64; Q];
                for &(j, c, w) in &self.entries[self.starts[g]..self.starts[g + 1]] {
                    incident[j as usize] += strength[c as usize] * w as f64;
                }
                let mut out = [0.0f32; Q];
                for (j, &v) in incident.iter().enumerate() {
                    if v != 0.0 {
                        for (o, &share) in out.iter_mut().zip(&leaf.into[j]) {
                            *o += (v * share) as f32;
                        }
                    }
                }
                let met: f64 = incident.iter().sum();
                ((self.sites[g], out), (1.0 - leaf.albedo) * met)
            })
            .collect();
        let mut floor = Vec::new();
        if !self.floor.is_empty() {
            floor = vec![0.0; self.columns];
            for &(source, column, share) in &self.floor {
                floor[column as usize] += strength[source as usize] * share;
            }
        }
        FirstFlight {
            scattered: groups.iter().map(|(s, _)| *s).collect(),
            absorbed: groups.iter().map(|(_, a)| a).sum(),
            escaped: self.escape.iter().zip(strength).map(|(e, l)| e * l).sum(),
            floor,
        }
    }
}

/// How a leaf scatters light arriving along lattice direction `j`: `into[j][m]`, the share
/// sent along `m`, is the albedo times `w_m pn(m ← j)` (the lattice's leaf phase function),
/// computed once per band for the flights' every step.
#[derive(Debug, Clone, PartialEq)]
pub struct LeafScatter {
    pub albedo: f64,
    pub into: [[f64; Q]; Q],
}

impl LeafScatter {
    pub fn new(medium: &sylva_lb::MediumParams) -> LeafScatter {
        let leaf = &medium.colours[0];
        let albedo = leaf.sigma_s / leaf.sigma_t();
        let pn = sylva_lb::collision::normalised_phase(leaf.g);
        LeafScatter {
            albedo,
            into: std::array::from_fn(|j| {
                std::array::from_fn(|m| {
                    if m == 0 {
                        0.0
                    } else {
                        albedo * weight(m) * pn[m][j]
                    }
                })
            }),
        }
    }
}

/// A unit direction cosine-distributed about unit `n` from `u1`, `u2` in [0, 1).
fn cosine(n: Vec3, u1: f64, u2: f64) -> Vec3 {
    let a = if n.x.abs() > 0.9 { Vec3::Y } else { Vec3::X };
    let u = n.cross(a).normalize();
    let v = n.cross(u);
    let (r, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
    (u * (r * phi.cos()) as f32
        + v * (r * phi.sin()) as f32
        + n * (1.0 - u1).max(0.0).sqrt() as f32)
        .normalize()
}

/// Seeds of the soil's and the once-scattered rays' jitter.
const SOIL_SEED: u64 = 0x736f_696c;
const SCATTER_SEED: u64 = 0x7363_6174;

/// One band's lattice budget: fractions of the sunlight entering the plot's top.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LbBand {
    pub band: String,
    pub canopy_absorbed: f64,
    pub reflected: f64,
    pub ground_arrived: f64,
    pub ground_direct: f64,
    pub soil_absorbed: f64,
    /// 1 − canopy absorbed − reflected − soil absorbed, each tallied on its own: 0 in an
    /// exact steady state.
    pub balance: f64,
    /// LB steps to the steady state.
    pub steps: usize,
    pub converged: bool,
    pub seconds: f64,
}

/// What the lattice budget was made on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LbRun {
    pub cell_m: f64,
    pub grid: [usize; 3],
    pub rays_per_column: usize,
    /// Leaf area over the plot's area as binned (the stand's LAI, to rounding).
    pub lai: f64,
    pub build_seconds: f64,
    pub bands: Vec<LbBand>,
}

/// The lattice budget of every band of `spec` under `sun`. `progress(band, step, residual)`
/// hears every LB step.
pub fn lb_budget(
    spec: &CanopySpec,
    stand: &Stand,
    accel: &SceneAccel,
    sun: SunAngles,
    cfg: &LbConfig,
    progress: &(dyn Fn(&str, usize, f64) + Sync),
) -> Result<LbRun, BudgetError> {
    cfg.validate()?;
    sun.validate_sun()?;
    let t0 = std::time::Instant::now();
    let plot = PlotGrid::build(spec, stand, cfg.cell, cfg.rays)?;
    let beam = direct_beam(stand, accel, &plot, sun.travel(), cfg.rays);
    let soil = Flights::soil(stand, accel, &plot, cfg.rays);
    let scattered_once =
        Flights::once_scattered(stand, accel, &plot, &beam.hits, (cfg.rays / 2).max(1));
    let build_seconds = t0.elapsed().as_secs_f64();
    let intercepted: f64 = beam.intercepted.iter().sum();
    let direct: f64 = beam.ground.iter().sum();
    let bands = spec
        .bands
        .iter()
        .map(|band: &Band| {
            let t = std::time::Instant::now();
            let (r, tr) = (band.leaf_reflectance, band.leaf_transmittance);
            let medium = medium_for(&PlantOptics {
                leaf_reflectance: [r; 3],
                leaf_transmittance: [tr; 3],
                bark_reflectance: [0.0; 3],
            })
            .map_err(|e| {
                BudgetError::invalid(format!("band {}", band.name), r + tr, e.to_string())
            })?;
            let leaf = LeafScatter::new(&medium);
            let steady = scattered_once.flight(&[r, tr], &leaf);
            let soil_flight = |radiance: &[f64]| soil.flight(radiance, &leaf);
            let solution = solve_cyclic_plot(
                &plot.grid,
                &medium,
                0,
                PlotLight {
                    source: None,
                    soil_albedo: band.soil_albedo,
                    ground_direct: &beam.ground,
                    soil: SoilLight::Traced {
                        soil: &soil_flight,
                        steady: &steady,
                    },
                },
                PlotOptions {
                    tolerance: cfg.tolerance,
                    max_steps: cfg.max_steps,
                    ..PlotOptions::default()
                },
                &mut |step, residual| progress(&band.name, step, residual),
            )
            .map_err(|e| {
                BudgetError::invalid(format!("band {}", band.name), "LB", e.to_string())
            })?;
            let canopy = (1.0 - (r + tr)) * intercepted + solution.absorbed;
            let arrived = direct + solution.floor_total();
            let soil = (1.0 - band.soil_albedo) * arrived;
            Ok(LbBand {
                band: band.name.clone(),
                canopy_absorbed: canopy,
                reflected: solution.top,
                ground_arrived: arrived,
                ground_direct: direct,
                soil_absorbed: soil,
                balance: 1.0 - canopy - solution.top - soil,
                steps: solution.steps,
                converged: solution.converged,
                seconds: t.elapsed().as_secs_f64(),
            })
        })
        .collect::<Result<Vec<_>, BudgetError>>()?;
    let dims = plot.grid.dims;
    Ok(LbRun {
        cell_m: plot.cell,
        grid: [dims.nx - 2, dims.ny - 2, dims.nz - 2],
        rays_per_column: cfg.rays,
        lai: plot.leaf_area / (spec.plot.size[0] * spec.plot.size[1]),
        build_seconds,
        bands,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photons::Angles;

    fn layer(lai: f64, soil: f64, r: f64, t: f64) -> CanopySpec {
        let mut spec = CanopySpec::builtin("layer").unwrap();
        spec.layer.as_mut().unwrap().lai = lai;
        for b in &mut spec.bands {
            b.soil_albedo = soil;
            b.leaf_reflectance = r;
            b.leaf_transmittance = t;
        }
        spec
    }

    fn accel(stand: &Stand) -> SceneAccel {
        SceneAccel::from_parts(&stand.models, &stand.instances, None).unwrap()
    }

    #[test]
    fn the_direct_beam_follows_beers_law_and_conserves() {
        // Black leaves in a homogeneous layer: what reaches the soil uncollided is
        // exp(−G LAI / cos θ), what the cells intercept the rest.
        let spec = layer(3.0, 0.0, 0.0, 0.0);
        let stand = Stand::build(&spec).unwrap();
        let accel = accel(&stand);
        let plot = PlotGrid::build(&spec, &stand, 0.5, 4).unwrap();
        assert!(
            (plot.leaf_area / 100.0 - 3.0).abs() < 1e-3,
            "LAI {}",
            plot.leaf_area / 100.0
        );
        for zenith in [0.0, 30.0, 60.0] {
            let sun = Angles {
                zenith_deg: zenith,
                azimuth_deg: 20.0,
            };
            let beam = direct_beam(&stand, &accel, &plot, sun.travel(), 8);
            let ground: f64 = beam.ground.iter().sum();
            let intercepted: f64 = beam.intercepted.iter().sum();
            assert!((ground + intercepted - 1.0).abs() < 1e-12, "{zenith}°");
            let beer = (-0.5 * 3.0 / zenith.to_radians().cos()).exp();
            assert!(
                (ground - beer).abs() < 0.005,
                "{zenith}°: {ground} against {beer}"
            );
            // Leaves are intercepted where they are: the layer's cells only.
            let dims = plot.grid.dims;
            for (i, &v) in beam.intercepted.iter().enumerate() {
                if v > 0.0 {
                    assert!(plot.grid.density[i] > 0.0, "site {:?}", dims.coords(i));
                }
            }
        }
    }

    #[test]
    fn black_leaves_over_a_black_soil_absorb_all_they_intercept() {
        let spec = layer(2.0, 0.0, 0.0, 0.0);
        let stand = Stand::build(&spec).unwrap();
        let sun = Angles {
            zenith_deg: 40.0,
            azimuth_deg: 0.0,
        };
        let cfg = LbConfig {
            cell: 0.5,
            ..LbConfig::default()
        };
        let run = lb_budget(&spec, &stand, &accel(&stand), sun, &cfg, &|_, _, _| {}).unwrap();
        for b in &run.bands {
            assert_eq!(b.reflected, 0.0);
            assert!((b.canopy_absorbed + b.ground_direct - 1.0).abs() < 1e-9);
            assert!(b.balance.abs() < 1e-9);
        }
    }

    #[test]
    fn a_white_soil_under_a_bare_plot_sends_everything_back() {
        // No leaves to speak of (LAI 1e-3): the sunlight reaches the soil and a white soil
        // sends it all back to the sky through the lattice.
        let spec = layer(1e-3, 1.0, 0.07, 0.06);
        let stand = Stand::build(&spec).unwrap();
        let sun = Angles {
            zenith_deg: 30.0,
            azimuth_deg: 0.0,
        };
        let run = lb_budget(
            &spec,
            &stand,
            &accel(&stand),
            sun,
            &LbConfig::default(),
            &|_, _, _| {},
        )
        .unwrap();
        for b in &run.bands {
            assert!(b.converged);
            assert!(
                (b.reflected - 1.0).abs() < 0.002,
                "{}: {}",
                b.band,
                b.reflected
            );
            assert!(b.balance.abs() < 1e-4, "{}", b.balance);
        }
    }

    /// The lattice's fractions against the Monte Carlo's on the same leaves.
    fn against_monte_carlo(spec: &CanopySpec, zenith: f64, cell: f64) -> f64 {
        let stand = Stand::build(spec).unwrap();
        let accel = accel(&stand);
        let sun = Angles {
            zenith_deg: zenith,
            azimuth_deg: 30.0,
        };
        let cfg = crate::BudgetConfig {
            photons: 200_000,
            seed: 3,
            sun,
            views: Vec::new(),
            image: None,
        };
        let mc = crate::trace_budget(&stand, &accel, &spec.bands, true, &cfg, &|_| {}).unwrap();
        let lb = lb_budget(
            spec,
            &stand,
            &accel,
            sun,
            &LbConfig {
                cell,
                ..LbConfig::default()
            },
            &|_, _, _| {},
        )
        .unwrap();
        let mut worst = 0.0f64;
        for (m, l) in mc.iter().zip(&lb.bands) {
            assert!(
                l.converged && l.balance.abs() < 0.005,
                "{}: balance {}",
                l.band,
                l.balance
            );
            // The direct transmission is traced on the same leaves: it agrees to the
            // photons' noise.
            assert!(
                (l.ground_direct - m.ground_direct.value).abs()
                    < 4.0 * m.ground_direct.std_error + 0.003
            );
            for (a, b) in [
                (l.canopy_absorbed, m.canopy_absorbed.value),
                (l.reflected, m.reflected.value),
                (l.ground_arrived, m.ground_arrived.value),
                (l.soil_absorbed, m.soil_absorbed.value),
            ] {
                worst = worst.max((a - b).abs());
            }
        }
        worst
    }

    #[test]
    fn the_lattice_agrees_with_the_photons_in_a_layer() {
        // Red and near-infrared leaves in a layer of LAI 3 over a bright soil.
        let mut spec = layer(3.0, 0.5, 0.07, 0.06);
        spec.bands[1].soil_albedo = 0.5;
        let worst = against_monte_carlo(&spec, 40.0, 0.5);
        assert!(worst < 0.02, "largest difference {worst}");
    }

    #[test]
    fn the_lattice_agrees_with_the_photons_among_crowns() {
        // Spheres of crown LAI 5 at cover 0.3 over a white soil, the hardest soil:
        // most light leaves the soil many times.
        let mut spec = CanopySpec::builtin("crowns").unwrap();
        spec.plot.size = [30.0, 30.0];
        for b in &mut spec.bands {
            b.soil_albedo = 0.96;
        }
        let worst = against_monte_carlo(&spec, 60.0, 1.0);
        assert!(worst < 0.02, "largest difference {worst}");
    }

    #[test]
    fn the_lattice_budget_is_the_same_on_one_thread() {
        let mut spec = CanopySpec::builtin("crowns").unwrap();
        spec.plot.size = [20.0, 20.0];
        let stand = Stand::build(&spec).unwrap();
        let accel = accel(&stand);
        let sun = Angles {
            zenith_deg: 50.0,
            azimuth_deg: 10.0,
        };
        let cfg = LbConfig {
            cell: 1.0,
            ..LbConfig::default()
        };
        let run = || {
            lb_budget(&spec, &stand, &accel, sun, &cfg, &|_, _, _| {})
                .unwrap()
                .bands
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(run);
        let many = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(run);
        for (a, b) in one.iter().zip(&many) {
            assert_eq!(
                (a.canopy_absorbed, a.reflected, a.ground_arrived, a.steps),
                (b.canopy_absorbed, b.reflected, b.ground_arrived, b.steps)
            );
        }
    }

    #[test]
    fn a_lattice_that_cannot_fit_is_refused_before_it_is_made() {
        // A 1 km plot in half-metre cells with 64² rays a column: petabytes of flights.
        let mut spec = layer(1e-4, 0.1, 0.07, 0.06);
        spec.plot.size = [1000.0, 1000.0];
        let stand = Stand::build(&spec).unwrap();
        let err = PlotGrid::build(&spec, &stand, 0.5, 64)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("lattice budget") && err.contains("needs"),
            "{err}"
        );
    }

    #[test]
    fn isolated_plots_and_untileable_cells_are_refused() {
        let mut spec = layer(3.0, 0.1, 0.07, 0.06);
        spec.plot.size = [10.0, 7.3];
        let stand = Stand::build(&spec).unwrap();
        let err = PlotGrid::build(&spec, &stand, 0.5, 4)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--lb-cell"), "{err}");
        spec.plot.cyclic = false;
        let err = PlotGrid::build(&spec, &stand, 0.5, 4)
            .unwrap_err()
            .to_string();
        assert!(err.contains("cyclic"), "{err}");
    }
}
