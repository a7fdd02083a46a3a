//! Participating media (clouds) drawn by a path-integrating volume tracer (paper 002 §3.2.1):
//! along each camera ray through a medium's box, the density grid and its LB lighting are
//! sampled trilinearly; opacity comes from the density, in-scattered light from the sun (single
//! scattering with the preset's Henyey-Greenstein phase function) and from the LB solution
//! (multiple scattering and sky light, taken as isotropic).
//!
//! Units. The LB coefficients are per lattice step, so a site of density ρ has extinction
//! `σ_t ρ / h` per world unit, `h` the cell length. Radiance is sylva's: a white Lambertian
//! surface facing a sun of irradiance `E` (sun colour × `sun_irradiance`) has radiance `E`,
//! which makes the sun's physical irradiance `π E` (the Mitsuba export uses π). At a point x,
//! the in-scattered radiance towards the viewer per unit length is `σ_s ρ(x) / h` times
//!
//! * single-scattered sun: `π p_HG(g, cos θ) E T_sun(x)`, `θ` between the sun's travel and the
//!   view, `T_sun` the transmittance towards the sun (a precomputed shadow volume, [`sun_path`]);
//! * scattered sunlight: `φ_s(x) E / 4`, the LB's scattered fluence (free-space sunlight = 1)
//!   as isotropic radiance `π E φ_s / 4π`;
//! * sky light: `φ_sky(x) L_sky`, the LB solution under a uniform sky boundary (every `f_i = 1`)
//!   divided by its free-space value 18, times the sky's radiance.
//!
//! Counting the sun once. The LB total holds the direct beam too, so the scattered part is the
//! local subtraction `φ_s = max(0, φ_LB − T_sun)`: the total minus the uncollided sun the
//! single-scattering term already uses. The clamp catches the cells where the lattice's
//! direction-split beam and the exact exponential disagree (the lit edge).
//!
//! A medium casts a shadow: the sun reaching a surface point is multiplied by the medium's
//! transmittance along the sun ray, which is `T_sun` where that ray enters the box (one lookup).
//! Light the medium scatters onto surfaces is not added, and the models' LB grids do not see
//! the medium.

use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use sylva_geom::Medium;
use sylva_lb::{LbSolver, LightingGrid, MediumParams};

use crate::device::NoDevice;

/// Marching step in cells.
pub const STEP_CELLS: f32 = 0.5;
/// Edge of the empty-space blocks, in cells.
const BLOCK: usize = 4;
/// Transmittance below which a ray is taken as stopped.
const OPAQUE: f32 = 1e-4;
/// Free-space LB total under the uniform sky boundary (`f_i = 1` for the 18 moving directions).
pub const SKY_FREE_SPACE: f32 = 18.0;

/// Henyey-Greenstein phase function, normalised over the sphere (`1/4π` when `g = 0`);
/// `cos_theta` between the light's travel and the scattered direction.
pub fn henyey_greenstein(g: f32, cos_theta: f32) -> f32 {
    let g = g.clamp(-0.999, 0.999);
    let d = (1.0 + g * g - 2.0 * g * cos_theta).max(1e-12);
    (1.0 - g * g) / (4.0 * std::f32::consts::PI * d * d.sqrt())
}

/// Per site, the density path integral towards the sun, `∫ ρ ds` in cells: the sun's optical
/// depth at the site is `σ_t` times it. One sweep over the grid, plane by plane away from the
/// sun along the axis the sun direction is closest to: a site's value is that of the point one
/// plane nearer the sun (bilinear in that plane; zero outside the box) plus the trapezoid of
/// the density over the step. Deterministic for any thread count.
pub fn sun_path(m: &Medium, to_sun: Vec3) -> Vec<f32> {
    let n = m.dims;
    let s = to_sun.normalize_or_zero();
    let a = (0..3)
        .max_by(|&i, &j| s[i].abs().total_cmp(&s[j].abs()))
        .expect("three axes");
    let (u, v) = ((a + 1) % 3, (a + 2) % 3);
    let mut out = vec![0.0f32; m.sites()];
    if s[a] == 0.0 {
        return out;
    }
    let step = Vec3::new(s[u] / s[a].abs(), s[v] / s[a].abs(), 0.0);
    let length = 1.0 / s[a].abs();
    let towards = if s[a] > 0.0 { 1isize } else { -1 };
    let index = |ia: usize, iu: usize, iv: usize| {
        let mut c = [0usize; 3];
        c[a] = ia;
        c[u] = iu;
        c[v] = iv;
        m.index(c[0], c[1], c[2])
    };
    let first = if towards > 0 { n[a] - 1 } else { 0 };
    let rho = &m.density;
    let mut plane = vec![0.0f32; n[u] * n[v]];
    for k in 1..n[a] {
        let ia = (first as isize - towards * k as isize) as usize;
        let prev = (ia as isize + towards) as usize;
        // Bilinear in plane `prev` (nearer the sun), zero off the grid.
        let bilinear = |values: &[f32], fu: f32, fv: f32| -> f32 {
            if fu < 0.0 || fv < 0.0 || fu > (n[u] - 1) as f32 || fv > (n[v] - 1) as f32 {
                return 0.0;
            }
            let iu = (fu.floor() as usize).min(n[u] - 2);
            let iv = (fv.floor() as usize).min(n[v] - 2);
            let (tu, tv) = (fu - iu as f32, fv - iv as f32);
            let g = |du: usize, dv: usize| values[index(prev, iu + du, iv + dv)];
            let a0 = g(0, 0) + (g(1, 0) - g(0, 0)) * tu;
            let a1 = g(0, 1) + (g(1, 1) - g(0, 1)) * tu;
            a0 + (a1 - a0) * tv
        };
        let done: &[f32] = &out;
        plane
            .par_chunks_mut(n[v])
            .enumerate()
            .for_each(|(iu, row)| {
                for (iv, value) in row.iter_mut().enumerate() {
                    let (fu, fv) = (iu as f32 + step.x, iv as f32 + step.y);
                    let here = rho[index(ia, iu, iv)];
                    *value = bilinear(done, fu, fv) + 0.5 * (here + bilinear(rho, fu, fv)) * length;
                }
            });
        for iu in 0..n[u] {
            for iv in 0..n[v] {
                out[index(ia, iu, iv)] = plane[iu * n[v] + iv];
            }
        }
    }
    out
}

/// What a ray picks up crossing media: the transmittance to what lies behind and the
/// in-scattered radiance, split as the render modes split surface light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Transmittance per colour.
    pub transmittance: Vec3,
    /// Single-scattered sunlight (the "local" part).
    pub local: Vec3,
    /// LB light: scattered sunlight and sky light (the "indirect" part).
    pub indirect: Vec3,
    /// What a uniform ambient radiance of 1 × the sun colour would scatter towards the viewer
    /// (the "ambient" mode's response).
    pub albedo: Vec3,
}

impl Segment {
    /// Nothing in the way.
    pub const CLEAR: Segment = Segment {
        transmittance: Vec3::ONE,
        local: Vec3::ZERO,
        indirect: Vec3::ZERO,
        albedo: Vec3::ZERO,
    };

    /// `self` in front of `behind`.
    pub fn then(&self, behind: &Segment) -> Segment {
        Segment {
            transmittance: self.transmittance * behind.transmittance,
            local: self.local + self.transmittance * behind.local,
            indirect: self.indirect + self.transmittance * behind.indirect,
            albedo: self.albedo + self.transmittance * behind.albedo,
        }
    }
}

/// The LB solutions a medium is lit with: raw solver totals (not normalised).
pub struct MediumLb<'a> {
    /// Under the sun boundary (`f_i = max(0, n_i · d)`).
    pub sun: &'a LightingGrid,
    /// Under the uniform sky boundary (`f_i = 1`).
    pub sky: &'a LightingGrid,
    /// The sun boundary's free-space total `Σ_i max(0, n_i · d)`.
    pub sun_free_space: f32,
}

/// A medium ready to draw: per site its density, its transmittance towards the sun and its LB
/// in-scattering radiance (before `σ_s ρ`), interleaved so a trilinear lookup touches 8
/// neighbouring records; a coarse occupancy grid for skipping empty space.
#[derive(Debug, Clone)]
pub struct MediumVolume {
    pub name: String,
    dims: [usize; 3],
    /// World position of site (0, 0, 0) and the cell length.
    origin: Vec3,
    cell: f32,
    /// Per site: ρ, T_sun (RGB), LB radiance (RGB), padding.
    sites: Vec<[f32; 8]>,
    /// Extinction and scattering per world unit at density 1, and the HG g, per colour.
    sigma_t: Vec3,
    sigma_s: Vec3,
    g: Vec3,
    /// Blocks of [`BLOCK`]³ cells: whether any of their sites has density.
    blocks: Vec<bool>,
    block_dims: [usize; 3],
    to_sun: Vec3,
    /// Sun colour × irradiance.
    sun: Vec3,
}

/// Bytes a [`MediumVolume`] of `dims` holds.
pub fn volume_bytes(dims: [usize; 3]) -> u64 {
    (dims[0] * dims[1] * dims[2]) as u64 * (32 + 4)
}

impl MediumVolume {
    /// Prepares `medium` (coefficients `params`, per lattice step) under the sun towards
    /// `to_sun` with colour × irradiance `sun` and a sky of radiance `sky`. Without `lb` only
    /// the single-scattered sun lights it.
    pub fn new(
        medium: &Medium,
        params: &MediumParams,
        lb: Option<MediumLb>,
        to_sun: Vec3,
        sun: Vec3,
        sky: Vec3,
    ) -> MediumVolume {
        let dims = medium.dims;
        let h = medium.cell();
        let per = |f: fn(&sylva_lb::ColourParams) -> f64| {
            Vec3::from_array(params.colours.each_ref().map(|c| f(c) as f32))
        };
        let (sigma_t, sigma_s, g) = (per(|c| c.sigma_t()), per(|c| c.sigma_s), per(|c| c.g));
        let path = sun_path(medium, to_sun);
        let mut sites = vec![[0.0f32; 8]; medium.sites()];
        sites.par_iter_mut().enumerate().for_each(|(i, s)| {
            let t_sun = (-sigma_t * path[i]).exp();
            let lb_radiance = match &lb {
                Some(lb) => {
                    let at =
                        |g: &LightingGrid| Vec3::from_array(g.colours.each_ref().map(|c| c[i]));
                    let scattered = (at(lb.sun) / lb.sun_free_space - t_sun).max(Vec3::ZERO);
                    scattered * sun * 0.25 + at(lb.sky) / SKY_FREE_SPACE * sky
                }
                None => Vec3::ZERO,
            };
            *s = [
                medium.density[i],
                t_sun.x,
                t_sun.y,
                t_sun.z,
                lb_radiance.x,
                lb_radiance.y,
                lb_radiance.z,
                0.0,
            ];
        });
        let block_dims = dims.map(|n| (n - 1).div_ceil(BLOCK));
        let mut blocks = vec![false; block_dims.iter().product()];
        for (i, &rho) in medium.density.iter().enumerate() {
            if rho <= 0.0 {
                continue;
            }
            let c = medium.coords(i);
            let c = [c.0, c.1, c.2];
            // A site belongs to the blocks on both sides of a block face it lies on.
            let range = |a: usize| {
                let lo = c[a].saturating_sub(1) / BLOCK;
                let hi = (c[a] / BLOCK).min(block_dims[a] - 1);
                lo..=hi
            };
            for bx in range(0) {
                for by in range(1) {
                    for bz in range(2) {
                        blocks[(bx * block_dims[1] + by) * block_dims[2] + bz] = true;
                    }
                }
            }
        }
        MediumVolume {
            name: medium.name.clone(),
            dims,
            origin: medium.bounds.min,
            cell: h,
            sites,
            sigma_t: sigma_t / h,
            sigma_s: sigma_s / h,
            g,
            blocks,
            block_dims,
            to_sun: to_sun.normalize_or_zero(),
            sun,
        }
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        (self.sites.len() * 32 + self.blocks.len()) as u64
    }

    fn last(&self) -> Vec3 {
        Vec3::new(
            (self.dims[0] - 1) as f32,
            (self.dims[1] - 1) as f32,
            (self.dims[2] - 1) as f32,
        )
    }

    /// Trilinear record at grid coordinates `g` (clamped to the grid).
    #[inline]
    fn sample(&self, g: Vec3) -> [f32; 8] {
        let last = self.last();
        let f = g.max(Vec3::ZERO).min(last);
        let i = f.floor().min(last - Vec3::ONE);
        let t = f - i;
        let [_, ny, nz] = self.dims;
        let (sx, sy) = (ny * nz, nz);
        let base = i.x as usize * sx + i.y as usize * sy + i.z as usize;
        let mut out = [0.0f32; 8];
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            let w = if dx == 1 { t.x } else { 1.0 - t.x }
                * if dy == 1 { t.y } else { 1.0 - t.y }
                * if dz == 1 { t.z } else { 1.0 - t.z };
            if w == 0.0 {
                continue;
            }
            let r = &self.sites[base + dx * sx + dy * sy + dz];
            for k in 0..7 {
                out[k] += w * r[k];
            }
        }
        out
    }

    /// The ray's parameter range inside the grid's box (site centres), clipped to
    /// `[0, t_max]`; `None` when it misses.
    fn clip(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<(f32, f32)> {
        let lo = self.origin;
        let hi = self.origin + self.last() * self.cell;
        let inv = dir.recip();
        let (a, b) = ((lo - origin) * inv, (hi - origin) * inv);
        let (near, far) = (a.min(b), a.max(b));
        // NaN (a zero direction component with the origin on a face) counts as unbounded.
        let t0 = near.x.max(near.y).max(near.z).max(0.0);
        let t1 = far.x.min(far.y).min(far.z).min(t_max);
        (t0 < t1).then_some((t0, t1))
    }

    /// The medium's transmittance towards the sun from world point `p`: `T_sun` where the sun
    /// ray from `p` enters the box (at `p` itself inside it); 1 when the ray misses.
    pub fn sun_transmittance(&self, p: Vec3) -> Vec3 {
        if self.to_sun == Vec3::ZERO {
            return Vec3::ONE;
        }
        match self.clip(p, self.to_sun, f32::INFINITY) {
            Some((t0, _)) => {
                let r = self.sample((p + self.to_sun * t0 - self.origin) / self.cell);
                Vec3::new(r[1], r[2], r[3])
            }
            None => Vec3::ONE,
        }
    }

    /// Integrates the ray `origin + t · dir` over `t ∈ [0, t_max]` (`t_max`: the surface hit,
    /// or infinity). `jitter ∈ [0, 1)` offsets the samples within their steps (per pixel
    /// sample, so banding becomes noise that supersampling averages).
    pub fn integrate(&self, origin: Vec3, dir: Vec3, t_max: f32, jitter: f32) -> Segment {
        let mut seg = Segment::CLEAR;
        let speed = dir.length();
        if !(speed > 0.0 && speed.is_finite()) {
            return seg;
        }
        let Some((t0, t1)) = self.clip(origin, dir, t_max) else {
            return seg;
        };
        // Per ray: the sun's phase term π p(θ) E, with cos θ between the sun's travel and the
        // direction towards the viewer.
        let cos = (self.to_sun.dot(dir) / speed).clamp(-1.0, 1.0);
        let phase = Vec3::new(
            henyey_greenstein(self.g.x, cos),
            henyey_greenstein(self.g.y, cos),
            henyey_greenstein(self.g.z, cos),
        ) * std::f32::consts::PI
            * self.sun;
        // Walk the blocks in grid coordinates (3-D DDA), integrating occupied ones.
        let g0 = (origin - self.origin) / self.cell;
        let gd = dir / self.cell;
        let step_t = STEP_CELLS * self.cell / speed;
        let start = g0 + gd * t0;
        let bs = BLOCK as f32;
        let mut b = [0usize; 3];
        let mut next = [f32::INFINITY; 3];
        let mut delta = [f32::INFINITY; 3];
        let mut stride = [0isize; 3];
        for a in 0..3 {
            let pos = (start[a] / bs)
                .floor()
                .clamp(0.0, (self.block_dims[a] - 1) as f32);
            b[a] = pos as usize;
            if gd[a] > 0.0 {
                stride[a] = 1;
                delta[a] = bs / gd[a];
                next[a] = t0 + ((pos + 1.0) * bs - start[a]) / gd[a];
            } else if gd[a] < 0.0 {
                stride[a] = -1;
                delta[a] = -bs / gd[a];
                next[a] = t0 + (pos * bs - start[a]) / gd[a];
            }
        }
        let mut t = t0;
        let mut trans = Vec3A::ONE;
        let (mut local, mut indirect, mut albedo) = (Vec3A::ZERO, Vec3A::ZERO, Vec3A::ZERO);
        let (sig_t, sig_s) = (Vec3A::from(self.sigma_t), Vec3A::from(self.sigma_s));
        let (phase, sun) = (Vec3A::from(phase), Vec3A::from(self.sun));
        while t < t1 {
            let a = (0..3)
                .min_by(|&i, &j| next[i].total_cmp(&next[j]))
                .expect("three axes");
            let t_exit = next[a].min(t1).max(t);
            let block = (b[0] * self.block_dims[1] + b[1]) * self.block_dims[2] + b[2];
            if self.blocks[block] && t_exit > t {
                let steps = ((t_exit - t) / step_t).ceil().max(1.0);
                let dt = (t_exit - t) / steps;
                let len = dt * speed;
                for k in 0..steps as usize {
                    let tm = t + (k as f32 + jitter) * dt;
                    let r = self.sample(g0 + gd * tm);
                    let rho = r[0];
                    if rho <= 0.0 {
                        continue;
                    }
                    let ext = sig_t * rho;
                    let x = ext * len;
                    let seg_t = Vec3A::new((-x.x).exp(), (-x.y).exp(), (-x.z).exp());
                    let absorbed = -Vec3A::new((-x.x).exp_m1(), (-x.y).exp_m1(), (-x.z).exp_m1());
                    // ∫ over the step of T(s) ds, exact for constant extinction.
                    let weight = trans * absorbed / ext.max(Vec3A::splat(1e-30));
                    let scat = weight * sig_s * rho;
                    local += scat * phase * Vec3A::new(r[1], r[2], r[3]);
                    indirect += scat * Vec3A::new(r[4], r[5], r[6]);
                    albedo += scat * sun;
                    trans *= seg_t;
                    if trans.max_element() < OPAQUE {
                        break;
                    }
                }
                if trans.max_element() < OPAQUE {
                    break;
                }
            }
            t = t_exit;
            if next[a] >= t1 {
                break;
            }
            let nb = b[a] as isize + stride[a];
            if nb < 0 || nb >= self.block_dims[a] as isize {
                break;
            }
            b[a] = nb as usize;
            next[a] += delta[a];
        }
        seg.transmittance = trans.into();
        seg.local = local.into();
        seg.indirect = indirect.into();
        seg.albedo = albedo.into();
        seg
    }
}

/// Every medium of a scene, ready to draw.
#[derive(Debug, Clone, Default)]
pub struct Media {
    pub volumes: Vec<MediumVolume>,
}

impl Media {
    pub fn is_empty(&self) -> bool {
        self.volumes.is_empty()
    }

    /// Whether the GPU frame kernel can draw these media: only when there are none (the
    /// volume tracer, [`Media::integrate`], runs on the CPU; `shade.wgsl` has none).
    pub fn device(&self) -> Result<(), NoDevice> {
        if self.is_empty() {
            Ok(())
        } else {
            Err(NoDevice(
                "the scene has media (clouds), which the CPU's volume tracer draws; the GPU \
                 traces the rays",
            ))
        }
    }

    /// The media along the ray up to `t_max`, front to back (overlapping boxes are composited
    /// in the order the ray enters them: an approximation where they overlap).
    pub fn integrate(&self, origin: Vec3, dir: Vec3, t_max: f32, jitter: f32) -> Segment {
        match self.volumes.as_slice() {
            [] => Segment::CLEAR,
            [one] => one.integrate(origin, dir, t_max, jitter),
            many => {
                let mut hits: Vec<(f32, &MediumVolume)> = many
                    .iter()
                    .filter_map(|v| v.clip(origin, dir, t_max).map(|(t0, _)| (t0, v)))
                    .collect();
                hits.sort_by(|a, b| a.0.total_cmp(&b.0));
                hits.iter().fold(Segment::CLEAR, |acc, (_, v)| {
                    acc.then(&v.integrate(origin, dir, t_max, jitter))
                })
            }
        }
    }

    /// The product of the media's transmittances towards the sun from `p`.
    pub fn sun_transmittance(&self, p: Vec3) -> Vec3 {
        self.volumes
            .iter()
            .fold(Vec3::ONE, |acc, v| acc * v.sun_transmittance(p))
    }

    pub fn memory_bytes(&self) -> u64 {
        self.volumes.iter().map(MediumVolume::memory_bytes).sum()
    }
}

/// The LB light of a medium: which boundary a solve used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum MediumBoundary {
    /// The sun, towards the (quantised) direction.
    Sun([i64; 3]),
    /// A uniform sky: every moving direction enters at 1.
    Sky,
}

/// A medium's LB light ([`medium_cache_key`]).
pub const MEDIUM_LIGHTING: sylva_core::cache::CacheKind = sylva_core::cache::CacheKind {
    name: "medium lighting",
    version: crate::lighting::CACHE_VERSION,
};

/// Everything a medium's LB solve depends on: the solver, the density grid, the preset's
/// coefficients, the boundary and the schedule. A medium has no wood: brown sites' parameters
/// do not enter.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub(crate) struct MediumLightingKey {
    solver: String,
    grid_file_version: u32,
    /// [`Medium::density_hash`]: the grid's sizes and densities.
    density: u64,
    /// Per colour `(σ_a, σ_s, g)`.
    colours: [[f64; 3]; 3],
    zero_f0_on_green: bool,
    boundary: MediumBoundary,
    schedule: &'static str,
}

impl MediumLightingKey {
    fn new(
        medium: &Medium,
        params: &MediumParams,
        boundary: MediumBoundary,
        solver: &dyn LbSolver,
    ) -> MediumLightingKey {
        MediumLightingKey {
            solver: solver.cache_tag(),
            grid_file_version: sylva_lb::grid_file::VERSION,
            density: medium.density_hash(),
            colours: params.colours.map(|c| [c.sigma_a, c.sigma_s, c.g]),
            zero_f0_on_green: params.zero_f0_on_green,
            boundary,
            schedule: solver.schedule().name(),
        }
    }
}

/// The cache key of a medium's LB solve ([`MediumLightingKey`]; as
/// [`crate::lighting::cache_key`] for models).
pub fn medium_cache_key(
    medium: &Medium,
    params: &MediumParams,
    boundary: MediumBoundary,
    solver: &dyn LbSolver,
) -> sylva_core::cache::CacheKey {
    sylva_core::cache::CacheKey::new(
        MEDIUM_LIGHTING,
        &MediumLightingKey::new(medium, params, boundary, solver),
    )
}

/// Where a medium's LB solves run and are cached.
pub struct MediumSolve<'a> {
    pub solver: &'a dyn LbSolver,
    pub cache_dir: Option<&'a std::path::Path>,
}

/// A medium ready to draw, with its LB light under the sun towards `to_sun` and a uniform
/// sky (each solve from the cache when it holds it, else solved and stored) when `lb` is
/// given. `progress(solve, colour, step, max_steps)`: solve 0 is the sun's, 1 the sky's.
/// Returns the reports of the two solves.
#[allow(clippy::too_many_arguments)]
pub fn prepare_medium(
    medium: &Medium,
    to_sun: Vec3,
    sun: Vec3,
    sky: Vec3,
    lb: Option<MediumSolve>,
    progress: &mut dyn FnMut(usize, usize, usize, usize),
) -> Result<(MediumVolume, Vec<crate::lighting::LightingReport>), crate::lighting::LightingError> {
    use crate::lighting::{
        cached_solve, free_space_total, preset_medium as preset_params, quantise_sun, solve_medium,
        solve_options, LightingError, LightingReport,
    };
    use sylva_lb::{Bounds, DensityGrid, Dims};

    let params = preset_params(&medium.preset)?;
    let (sun_q, sun_dir) = quantise_sun(to_sun)?;
    let dims = Dims::new(medium.dims[0], medium.dims[1], medium.dims[2])
        .map_err(|e| LightingError::MediumGrid(format!("medium '{}': {e}", medium.name)))?;
    sylva_core::check_memory(
        &format!("drawing medium '{}' ({dims} sites)", medium.name),
        volume_bytes(medium.dims),
    )?;
    let bounds = Bounds {
        min: medium.bounds.min.to_array(),
        max: medium.bounds.max.to_array(),
    };
    let mut reports = Vec::new();
    let lit = match lb {
        None => None,
        Some(lb) => {
            let mut grids = Vec::with_capacity(2);
            for (k, boundary) in [MediumBoundary::Sun(sun_q), MediumBoundary::Sky]
                .into_iter()
                .enumerate()
            {
                let t0 = std::time::Instant::now();
                let key = medium_cache_key(medium, &params, boundary, lb.solver);
                let (which, values) = match boundary {
                    MediumBoundary::Sun(_) => {
                        ("sun", sylva_lb::Boundary::sun((-sun_dir).to_array(), 1.0))
                    }
                    MediumBoundary::Sky => ("sky", sylva_lb::Boundary::basis(0)),
                };
                let metadata = vec![
                    ("source".to_string(), format!("medium {}", medium.name)),
                    ("preset".to_string(), medium.preset.clone()),
                    ("boundary".to_string(), which.to_string()),
                    (
                        "sun_to".to_string(),
                        format!("{:.6},{:.6},{:.6}", sun_dir.x, sun_dir.y, sun_dir.z),
                    ),
                    (
                        "steps".to_string(),
                        solve_options(dims, lb.solver).max_steps.to_string(),
                    ),
                    ("solver".to_string(), lb.solver.describe()),
                ];
                let stem = format!("{}-{which}", sylva_core::file_stem(&medium.name, "medium"));
                let got = cached_solve(lb.cache_dir, &stem, key, dims, bounds, metadata, || {
                    sylva_core::check_memory(
                        &format!(
                            "the LB lighting of medium '{}' on a {dims} grid",
                            medium.name
                        ),
                        sylva_lb::solver::memory_needed(dims),
                    )?;
                    let density = DensityGrid {
                        dims,
                        bounds,
                        density: medium.density.to_vec(),
                        wood: vec![0.0; dims.sites()],
                    };
                    solve_medium(&density, &params, values, lb.solver, &mut |c, s, m| {
                        progress(k, c, s, m)
                    })
                    .map_err(|source| LightingError::SolveMedium {
                        medium: medium.name.clone(),
                        source,
                    })
                })?;
                reports.push(LightingReport {
                    source: got.source,
                    seconds: t0.elapsed().as_secs_f64(),
                    path: got.path,
                    dims,
                    cache_warning: got.cache_warning,
                });
                grids.push(got.grid);
            }
            Some(grids)
        }
    };
    let sun_free_space = free_space_total(sun_dir).expect("a unit sun direction") as f32;
    let volume = MediumVolume::new(
        medium,
        &params,
        lit.as_ref().map(|g| MediumLb {
            sun: &g[0],
            sky: &g[1],
            sun_free_space,
        }),
        to_sun,
        sun,
        sky,
    );
    Ok((volume, reports))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_core::cache::assert_each_field_changes_the_key;

    #[test]
    fn medium_lighting_key_changes_with_every_field() {
        let base = MediumLightingKey {
            solver: "cpu".into(),
            grid_file_version: sylva_lb::grid_file::VERSION,
            density: 0xabc,
            colours: [[0.01, 0.2, 0.8]; 3],
            zero_f0_on_green: true,
            boundary: MediumBoundary::Sun([0, 100_000, 0]),
            schedule: "papers:2N",
        };
        let mut variants: Vec<(String, MediumLightingKey)> = vec![
            (
                "solver".into(),
                MediumLightingKey {
                    solver: "gpu-f32".into(),
                    ..base.clone()
                },
            ),
            (
                "grid_file_version".into(),
                MediumLightingKey {
                    grid_file_version: 1,
                    ..base.clone()
                },
            ),
            (
                "density".into(),
                MediumLightingKey {
                    density: 0xabd,
                    ..base.clone()
                },
            ),
            (
                "zero_f0_on_green".into(),
                MediumLightingKey {
                    zero_f0_on_green: false,
                    ..base.clone()
                },
            ),
            (
                "boundary".into(),
                MediumLightingKey {
                    boundary: MediumBoundary::Sky,
                    ..base.clone()
                },
            ),
            (
                "boundary sun".into(),
                MediumLightingKey {
                    boundary: MediumBoundary::Sun([1, 100_000, 0]),
                    ..base.clone()
                },
            ),
            (
                "schedule".into(),
                MediumLightingKey {
                    schedule: sylva_lb::Schedule::Extrapolated.name(),
                    ..base.clone()
                },
            ),
        ];
        for c in 0..3 {
            for p in 0..3 {
                let mut k = base.clone();
                k.colours[c][p] += 0.01;
                variants.push((format!("colour {c} parameter {p}"), k));
            }
        }
        let named: Vec<(&str, MediumLightingKey)> = variants
            .iter()
            .map(|(n, k)| (n.as_str(), k.clone()))
            .collect();
        assert_each_field_changes_the_key(MEDIUM_LIGHTING, &base, &named);
    }
    use sylva_geom::Aabb;
    use sylva_lb::{Bounds, ColourParams, Dims, Preset};

    /// A `dims` medium of cell `h` at the origin with density `f(x, y, z)` (site coordinates)
    /// inside the shell.
    fn medium(dims: [usize; 3], h: f32, f: impl Fn(f32, f32, f32) -> f32) -> Medium {
        let mut rho = vec![0.0; dims[0] * dims[1] * dims[2]];
        for x in 1..dims[0] - 1 {
            for y in 1..dims[1] - 1 {
                for z in 1..dims[2] - 1 {
                    rho[(x * dims[1] + y) * dims[2] + z] = f(x as f32, y as f32, z as f32);
                }
            }
        }
        let size = Vec3::new(
            (dims[0] - 1) as f32,
            (dims[1] - 1) as f32,
            (dims[2] - 1) as f32,
        ) * h;
        Medium::new(
            "m",
            dims,
            Aabb {
                min: Vec3::ZERO,
                max: size,
            },
            rho,
            "cloud",
        )
        .unwrap()
    }

    fn grey(sigma_a: f64, sigma_s: f64, g: f64) -> MediumParams {
        MediumParams {
            colours: [ColourParams {
                sigma_a,
                sigma_s,
                g,
            }; 3],
            ..Preset::Cloud.params()
        }
    }

    fn lighting(m: &Medium, values: impl Fn(usize) -> f32) -> LightingGrid {
        let c: Vec<f32> = (0..m.sites()).map(values).collect();
        LightingGrid {
            dims: Dims::new(m.dims[0], m.dims[1], m.dims[2]).unwrap(),
            bounds: Bounds::UNIT,
            colours: [c.clone(), c.clone(), c],
        }
    }

    #[test]
    fn phase_function_is_normalised() {
        for g in [-0.88f32, 0.0, 0.5, 0.9] {
            // 2π ∫ p(μ) dμ over [-1, 1], midpoint rule.
            let n = 200_000;
            let sum: f64 = (0..n)
                .map(|k| {
                    let mu = -1.0 + (k as f64 + 0.5) * 2.0 / n as f64;
                    henyey_greenstein(g, mu as f32) as f64
                })
                .sum::<f64>()
                * 2.0
                / n as f64
                * std::f64::consts::TAU;
            assert!((sum - 1.0).abs() < 1e-3, "g {g}: {sum}");
        }
        assert!((henyey_greenstein(0.0, 0.3) - 1.0 / (4.0 * std::f32::consts::PI)).abs() < 1e-7);
    }

    #[test]
    fn sun_path_matches_a_direct_march() {
        // A smooth blob; the sweep's value at interior sites against a fine march of the
        // trilinear density towards the sun (axis-aligned: exact).
        let n = [40, 32, 36];
        let m = medium(n, 1.0, |x, y, z| {
            let d = ((x - 20.0).powi(2) + (y - 15.0).powi(2) * 1.5 + (z - 17.0).powi(2)) / 120.0;
            (1.0 - d).clamp(0.0, 1.0)
        });
        let rho = |p: Vec3| -> f32 {
            let last = Vec3::new(39.0, 31.0, 35.0);
            if p.cmplt(Vec3::ZERO).any() || p.cmpgt(last).any() {
                return 0.0;
            }
            let i = p.floor().min(last - Vec3::ONE);
            let t = p - i;
            let mut acc = 0.0;
            for c in 0..8 {
                let o = Vec3::new((c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32);
                let w = (o * t + (Vec3::ONE - o) * (Vec3::ONE - t)).element_product();
                let q = i + o;
                acc += w * m.density[m.index(q.x as usize, q.y as usize, q.z as usize)];
            }
            acc
        };
        for to_sun in [
            Vec3::Y,
            Vec3::new(0.5, 0.8, 0.3),
            Vec3::new(-0.7, 0.4, -0.6),
            Vec3::new(0.2, -0.3, 0.9),
        ] {
            let s = to_sun.normalize();
            let path = sun_path(&m, s);
            let mut worst = 0.0f32;
            for &(x, y, z) in &[(20, 15, 17), (14, 12, 20), (25, 18, 13), (20, 8, 17)] {
                let mut march = 0.0;
                let ds = 0.01;
                for k in 0..10_000 {
                    march +=
                        rho(Vec3::new(x as f32, y as f32, z as f32) + s * ((k as f32 + 0.5) * ds))
                            * ds;
                }
                let got = path[m.index(x, y, z)];
                // Within 3 %, plus 0.15 cells of density: the sweep's repeated bilinear
                // steps blur the blob's edge a little.
                worst = worst.max((got - march).abs() / (0.03 * march + 0.15));
            }
            assert!(worst < 1.0, "sun {to_sun}: error {worst} of the tolerance");
        }
    }

    #[test]
    fn transmittance_of_an_absorbing_block_is_exponential() {
        // σ_s = 0: only extinction. A ray along x through the constant interior.
        let n = [24, 12, 12];
        let h = 2.0;
        let m = medium(n, h, |_, _, _| 0.7);
        let params = grey(0.05, 0.0, 0.0);
        let v = MediumVolume::new(&m, &params, None, Vec3::Y, Vec3::ONE, Vec3::ONE);
        let origin = Vec3::new(2.0, 5.0, 6.0) * h;
        let length = 17.0 * h;
        let seg = v.integrate(origin, Vec3::X * 2.0, length / 2.0, 0.5);
        let want = (-0.05f32 * 0.7 / h * length).exp();
        assert!(
            (seg.transmittance.x - want).abs() < 1e-5,
            "{} {want}",
            seg.transmittance.x
        );
        assert_eq!(seg.local, Vec3::ZERO);
        // A ray that stops before the box, or misses it, sees nothing.
        assert_eq!(
            v.integrate(Vec3::new(-10.0, 5.0, 6.0), Vec3::X, 5.0, 0.5),
            Segment::CLEAR
        );
        assert_eq!(
            v.integrate(Vec3::new(-10.0, 50.0, 6.0), Vec3::X, 1e9, 0.5),
            Segment::CLEAR
        );
    }

    #[test]
    fn in_scattering_has_the_closed_form() {
        // Constant density 1 inside; sun straight down; a horizontal ray at a site plane
        // through the constant interior; the LB scattered fluence c and sky fluence k
        // everywhere. Then along the ray
        //   L_local = σ_s' π p(θ) E T_sun (1 − e^{−σ_t' L}) / σ_t'
        //   L_ind   = σ_s' (c E / 4 + k L_sky) (1 − e^{−σ_t' L}) / σ_t'
        // with σ' = σ / h and T_sun = e^{−σ_t (y_top − y + 1/2)} (the top ramp is half a cell).
        let n = [30, 14, 12];
        let h = 3.0;
        let m = medium(n, h, |_, _, _| 1.0);
        let (sa, ss, g) = (0.01, 0.3, 0.6);
        let params = grey(sa, ss, g);
        let st = (sa + ss) as f32;
        let to_sun = Vec3::Y;
        let (c, k) = (0.37f32, 0.61f32);
        let path = sun_path(&m, to_sun);
        let free = 5.0;
        let sun_grid = lighting(&m, |i| free * ((-st * path[i]).exp() + c));
        let sky_grid = lighting(&m, |_| SKY_FREE_SPACE * k);
        let (sun, sky) = (Vec3::new(1.0, 0.9, 0.8), Vec3::new(0.3, 0.5, 0.9));
        let lb = MediumLb {
            sun: &sun_grid,
            sky: &sky_grid,
            sun_free_space: free,
        };
        let v = MediumVolume::new(&m, &params, Some(lb), to_sun, sun, sky);
        let y = 6.0;
        let dir = Vec3::new(1.0, 0.0, 0.0);
        let origin = Vec3::new(2.0, y, 5.0) * h;
        let length = 24.0 * h;
        let seg = v.integrate(origin, dir, length, 0.3);
        let (sp, tp) = (ss as f32 / h, st / h);
        let fill = (1.0 - (-tp * length).exp()) / tp;
        let t_sun = (-st * ((n[1] - 2) as f32 - y + 0.5)).exp();
        let p = henyey_greenstein(g as f32, to_sun.dot(dir));
        let local = sun * (sp * std::f32::consts::PI * p * t_sun * fill);
        let indirect = (sun * (c / 4.0) + sky * k) * (sp * fill);
        assert!(
            (seg.local - local).abs().max_element() < 1e-4 * local.max_element(),
            "{} {local}",
            seg.local
        );
        assert!(
            (seg.indirect - indirect).abs().max_element() < 1e-4 * indirect.max_element(),
            "{} {indirect}",
            seg.indirect
        );
        assert!((seg.albedo - sun * (sp * fill)).abs().max_element() < 1e-4);
        assert!((seg.transmittance.x - (-tp * length).exp()).abs() < 1e-5);
        // Composition: two halves of the ray equal the whole.
        let a = v.integrate(origin, dir, length / 2.0, 0.3);
        let b = v.integrate(origin + dir * (length / 2.0), dir, length / 2.0, 0.3);
        let ab = a.then(&b);
        assert!((ab.local - seg.local).abs().max_element() < 1e-4 * local.max_element());
        assert!((ab.transmittance - seg.transmittance).abs().max_element() < 1e-6);
    }

    #[test]
    fn shadows_come_from_the_sun_volume() {
        // Under the box with the sun straight up: the whole column, (n_y − 2) cells of density
        // 1 (two half ramps at the shell); beside the box: no shadow.
        let n = [10, 8, 10];
        let m = medium(n, 1.0, |_, _, _| 1.0);
        let params = grey(0.1, 0.2, 0.0);
        let v = MediumVolume::new(&m, &params, None, Vec3::Y, Vec3::ONE, Vec3::ONE);
        let under = v.sun_transmittance(Vec3::new(4.5, -20.0, 4.5));
        assert!((under.x - (-0.3f32 * 6.0).exp()).abs() < 1e-5, "{under}");
        assert_eq!(v.sun_transmittance(Vec3::new(40.0, -20.0, 4.5)), Vec3::ONE);
        let media = Media {
            volumes: vec![v.clone(), v],
        };
        let both = media.sun_transmittance(Vec3::new(4.5, -20.0, 4.5));
        assert!((both.x - under.x * under.x).abs() < 1e-6);
    }

    #[test]
    fn empty_space_skipping_misses_nothing() {
        // Two small blobs far apart in a large grid, rays at many angles: the transmittance
        // (σ_s = 0) against a fine brute-force march of the trilinear density.
        let n = [48, 40, 44];
        let m = medium(n, 1.0, |x, y, z| {
            let b = |c: Vec3, r: f32| (1.0 - (Vec3::new(x, y, z) - c).length() / r).max(0.0);
            (b(Vec3::new(10.0, 12.0, 9.0), 4.0) + b(Vec3::new(36.0, 27.0, 33.0), 3.0)).min(1.0)
        });
        let params = grey(0.4, 0.0, 0.0);
        let v = MediumVolume::new(&m, &params, None, Vec3::Y, Vec3::ONE, Vec3::ONE);
        let mut rng = sylva_core::SplitMix64::new(7);
        let mut checked = 0;
        for _ in 0..300 {
            let mut r = || rng.next_f64() as f32;
            let a = Vec3::new(r() * 47.0, r() * 39.0, r() * 43.0);
            let target = if r() < 0.5 {
                Vec3::new(10.0, 12.0, 9.0)
            } else {
                Vec3::new(36.0, 27.0, 33.0)
            };
            let dir = (target - a).normalize() + Vec3::new(r(), r(), r()) * 0.05;
            let seg = v.integrate(a, dir, 200.0, 0.5);
            // Brute force: the density along the ray, fine midpoint steps.
            let (mut tau, ds) = (0.0f64, 0.005f32);
            let speed = dir.length();
            let mut t = 0.5 * ds;
            while t < 200.0 {
                let p = a + dir * t;
                if p.cmpge(Vec3::ZERO).all() && p.cmple(Vec3::new(47.0, 39.0, 43.0)).all() {
                    tau += v.sample(p)[0] as f64 * (ds * speed) as f64;
                }
                t += ds;
            }
            let want = (-0.4 * tau).exp() as f32;
            if tau > 0.05 {
                checked += 1;
            }
            assert!(
                (seg.transmittance.x - want).abs() < 0.02 * want.max(0.05),
                "{} {want}",
                seg.transmittance.x
            );
        }
        assert!(checked > 100, "{checked} rays crossed a blob");
    }
}
