//! A cumulus cloud grown in code: the density grid of paper 002 §3.2.1's cloud, which came from
//! a convective lattice-Boltzmann model (002 ref. [13]). This generator is a parcel model of
//! the same physics, cheap enough to run on every scene build:
//!
//! 1. **Thermals.** Buoyant bubbles leave the ground with a temperature excess ΔT₀ and a
//!    radius R. A parcel cools dry-adiabatically (9.8 K/km) in an environment that cools by
//!    [`CumulusParams::lapse_rate`]; it reaches saturation at the lifting condensation level
//!    (LCL), `125 m/K × (T − T_d)` (Espy): every thermal condenses at the same height, which
//!    makes the flat cloud base. Thermals whose buoyancy is gone before the LCL make no cloud.
//! 2. **Ascent.** Above the LCL the parcel cools moist-adiabatically (6 K/km), so it gains
//!    buoyancy against the environment, while it entrains environmental air (rate ε = 0.2/R:
//!    wide thermals entrain less), which pulls its excess back and, being dry, cools it further
//!    as cloud water evaporates into it: `db/dz = (Γ_env − Γ_moist) − ε (b + χ)` with χ
//!    [`CumulusParams::evaporative_cooling`]. Above the inversion the environment is stable and
//!    the parcel decelerates. Its top is where `b = 0` (the level of neutral buoyancy, overshoot
//!    ignored): narrow thermals die as small cumuli below the inversion, strong wide ones make
//!    the towers.
//! 3. **Water.** Condensed water grows at the adiabatic rate Γ_l ≈ 2 g/m³ per km above the
//!    base and is diluted by entrainment: `q_l = Γ_l Δz e^{−ε Δz}`. The density is
//!    `q_l / q_full` clamped to 1, where [`CumulusParams::lwc_full`] is the liquid water that
//!    gives the preset's extinction per cell (with the cloud preset's σ_t = 0.8 per 12 m cell,
//!    β = 0.067/m, the extinction of 0.44 g/m³ of 10 μm droplets: β = 3 q_l / (2 ρ_w r_e)).
//! 4. **Shape.** Each thermal is a tower of overlapping spherical bubbles along its (sheared)
//!    axis, widening as it entrains, ending in a dome at its top; the dome and the upper
//!    tower carry recursive sub-bubbles (the turbulent eddies of a rising thermal cap): the
//!    cauliflower. Bubbles add smooth kernels; the cloud edge is a threshold of their sum,
//!    ruffled by fractal noise (entrainment eddies) over a band a few cells wide.
//!
//! Deterministic: every random choice comes from the seed in a fixed order, and each site is
//! a pure function of the bubbles, so any thread count gives the same grid. Bubbles are
//! splatted row by row, so the cost follows the cloud's volume (well under a second for
//! 256×128×128 on two cores).

use rayon::prelude::*;
use thiserror::Error;

use crate::rng::Rng;

/// Dry-adiabatic lapse rate, K/km.
const DRY_LAPSE: f64 = 9.8;
/// Moist-adiabatic lapse rate near the surface at 15 °C, K/km.
const MOIST_LAPSE: f64 = 6.0;
/// Adiabatic liquid water gradient, g/m³ per km of ascent above the base.
const LIQUID_LAPSE: f64 = 2.0;
/// Espy's LCL estimate, metres per kelvin of dew-point spread.
const LCL_PER_KELVIN: f64 = 125.0;
/// Entrainment rate × radius (ε = this / R): wide thermals entrain less (Morton, Taylor &
/// Turner's ε ∝ 1/R).
const ENTRAINMENT_RADIUS: f64 = 0.2;
/// Empty sites kept inside the grid's shell on every side.
const MARGIN: f64 = 3.0;

#[derive(Debug, Error, PartialEq)]
pub enum CloudError {
    #[error("cumulus grid {0}×{1}×{2}: every edge must be 16 to 4096 sites")]
    Dims(usize, usize, usize),
    #[error("cumulus parameter {name} = {value}: {why}")]
    Param {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("no thermal reaches the condensation level at {lcl_m:.0} m: raise the thermals' temperature excess or lower the dew-point spread")]
    NoCloud { lcl_m: f64 },
    #[error("the condensation level at {lcl_m:.0} m (the cloud's base) is not below the grid's top margin at {top_m:.0} m: make the cells larger or the grid taller")]
    BaseAboveGrid { lcl_m: f64, top_m: f64 },
}

/// What the cumulus generator is given. Heights are in metres, grid sizes in sites.
#[derive(Debug, Clone, PartialEq)]
pub struct CumulusParams {
    /// Sites along x, y (up), z, shell included.
    pub dims: [usize; 3],
    pub seed: u64,
    /// Metres per cell.
    pub cell_m: f64,
    /// Surface temperature minus dew point, K: sets the LCL (the base).
    pub dew_point_spread: f64,
    /// Environmental lapse rate below the inversion, K/km (between moist and dry: the air is
    /// conditionally unstable).
    pub lapse_rate: f64,
    /// Height of the inversion that slows the towers, m.
    pub inversion_m: f64,
    /// Cooling of the parcel by evaporation into the air it entrains, K (the environment's
    /// saturation deficit in temperature units).
    pub evaporative_cooling: f64,
    /// Environmental lapse rate above the inversion, K/km (below the moist rate: stable).
    pub inversion_lapse_rate: f64,
    /// Thermals feeding the cloud.
    pub thermals: usize,
    /// Surface temperature excess of the thermals, K, drawn in this range.
    pub excess: [f64; 2],
    /// Radius of the thermals at the base, m, drawn in this range.
    pub radius_m: [f64; 2],
    /// Horizontal drift of the towers per metre of height (wind shear), along +x.
    pub shear: f64,
    /// Liquid water content that makes density 1, g/m³.
    pub lwc_full: f64,
}

impl Default for CumulusParams {
    fn default() -> Self {
        CumulusParams {
            dims: [256, 128, 128],
            seed: 1,
            cell_m: 12.0,
            dew_point_spread: 2.4,
            lapse_rate: 7.0,
            inversion_m: 1000.0,
            evaporative_cooling: 0.8,
            inversion_lapse_rate: 4.0,
            thermals: 7,
            excess: [0.9, 2.0],
            radius_m: [80.0, 190.0],
            shear: 0.12,
            lwc_full: 0.44,
        }
    }
}

impl CumulusParams {
    /// The defaults on another grid: physical sizes scale with the grid's width.
    pub fn for_grid(dims: [usize; 3], seed: u64) -> CumulusParams {
        let d = CumulusParams::default();
        CumulusParams {
            dims,
            seed,
            cell_m: d.cell_m * d.dims[0] as f64 / dims[0].max(1) as f64,
            ..d
        }
    }

    fn validate(&self) -> Result<(), CloudError> {
        let [nx, ny, nz] = self.dims;
        if [nx, ny, nz].iter().any(|&n| !(16..=4096).contains(&n)) {
            return Err(CloudError::Dims(nx, ny, nz));
        }
        if !(self.evaporative_cooling.is_finite() && self.evaporative_cooling >= 0.0) {
            return Err(CloudError::Param {
                name: "evaporative_cooling",
                value: self.evaporative_cooling,
                why: "must be a number ≥ 0",
            });
        }
        let positive = [
            ("cell_m", self.cell_m),
            ("dew_point_spread", self.dew_point_spread),
            ("inversion_m", self.inversion_m),
            ("lwc_full", self.lwc_full),
            ("excess min", self.excess[0]),
            ("radius_m min", self.radius_m[0]),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(CloudError::Param {
                    name,
                    value,
                    why: "must be a positive number",
                });
            }
        }
        for (name, lo, hi) in [
            ("excess", self.excess[0], self.excess[1]),
            ("radius_m", self.radius_m[0], self.radius_m[1]),
        ] {
            if !(hi.is_finite() && hi >= lo) {
                return Err(CloudError::Param {
                    name,
                    value: hi,
                    why: "the range's upper end must be finite and at least its lower end",
                });
            }
        }
        if !(self.lapse_rate.is_finite()
            && self.lapse_rate > MOIST_LAPSE
            && self.lapse_rate < DRY_LAPSE)
        {
            return Err(CloudError::Param {
                name: "lapse_rate",
                value: self.lapse_rate,
                why: "must lie between the moist (6) and dry (9.8) adiabatic rates, K/km",
            });
        }
        if !(self.inversion_lapse_rate.is_finite() && self.inversion_lapse_rate < MOIST_LAPSE) {
            return Err(CloudError::Param {
                name: "inversion_lapse_rate",
                value: self.inversion_lapse_rate,
                why: "must be below the moist adiabatic rate (6 K/km), or the towers never stop",
            });
        }
        if !self.shear.is_finite() || self.shear.abs() > 2.0 {
            return Err(CloudError::Param {
                name: "shear",
                value: self.shear,
                why: "must be a number in [-2, 2]",
            });
        }
        if self.thermals == 0 || self.thermals > 256 {
            return Err(CloudError::Param {
                name: "thermals",
                value: self.thermals as f64,
                why: "must be 1 to 256",
            });
        }
        Ok(())
    }
}

/// One thermal's ascent, in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermal {
    /// Ground position (x, z) of its axis at the base, m from the grid's corner.
    pub x: f64,
    pub z: f64,
    pub radius: f64,
    /// Entrainment rate, 1/km.
    pub entrainment: f64,
    /// Buoyancy (temperature excess) at the base, K.
    pub base_excess: f64,
    /// Cloud top (level of neutral buoyancy), m; clipped to the grid.
    pub top: f64,
}

/// The generator's result: the density grid and what it was made of.
#[derive(Debug, Clone)]
pub struct Cumulus {
    pub dims: [usize; 3],
    /// Density per site, index `(x · ny + y) · nz + z`; zero on the shell.
    pub density: Vec<f32>,
    /// The base (LCL) in sites above the grid's bottom.
    pub base: f64,
    /// The thermals that reached the LCL.
    pub thermals: Vec<Thermal>,
    pub cell_m: f64,
}

/// A saturated parcel's ascent through a layer: entrainment rate `eps` (1/km), environmental
/// lapse rate `env` (K/km), evaporative cooling `chi` (K).
#[derive(Debug, Clone, Copy)]
struct Layer {
    eps: f64,
    env: f64,
    chi: f64,
}

impl Layer {
    /// The buoyancy the parcel tends to: `db/dz = 0`.
    fn limit(&self) -> f64 {
        (self.env - MOIST_LAPSE) / self.eps - self.chi
    }

    /// Buoyancy (K) `dz` km above a point where it was `b0`: the solution of
    /// `db/dz = (env − Γ_moist) − ε (b + χ)`.
    fn buoyancy(&self, b0: f64, dz: f64) -> f64 {
        let b_inf = self.limit();
        b_inf + (b0 - b_inf) * (-self.eps * dz).exp()
    }

    /// Height (km) above a point of buoyancy `b0 > 0` where the buoyancy reaches zero; `None`
    /// where it never does (`limit ≥ 0`).
    fn stop_height(&self, b0: f64) -> Option<f64> {
        let b_inf = self.limit();
        (b_inf < 0.0).then(|| ((b0 - b_inf) / (-b_inf)).ln() / self.eps)
    }
}

/// A kernel of the field: centre and radius in cells, and its thermal's entrainment.
#[derive(Debug, Clone, Copy)]
struct Bubble {
    c: [f32; 3],
    r: f32,
    eps: f32,
}

/// Grows the cloud.
pub fn cumulus(p: &CumulusParams) -> Result<Cumulus, CloudError> {
    p.validate()?;
    let [nx, ny, nz] = p.dims;
    let h = p.cell_m;
    let lcl_m = LCL_PER_KELVIN * p.dew_point_spread;
    let base = lcl_m / h;
    let top_limit = (ny as f64 - 1.0 - MARGIN) * h;
    if lcl_m + 2.0 * h >= top_limit {
        return Err(CloudError::BaseAboveGrid {
            lcl_m,
            top_m: top_limit,
        });
    }
    let mut rng = Rng::new(p.seed);

    // Thermals: the strongest near the middle of the field, others around it; placed with
    // some spacing so the towers stay distinct.
    let centre = [0.5 * nx as f64 * h, 0.5 * nz as f64 * h];
    let spread = [0.24 * nx as f64 * h, 0.17 * nz as f64 * h];
    let mut thermals: Vec<Thermal> = Vec::new();
    let mut tries = 0;
    while thermals.len() < p.thermals && tries < 64 * p.thermals {
        tries += 1;
        let k = thermals.len();
        // The first thermal is the strongest and sits near the centre.
        let (fx, fz) = if k == 0 {
            (rng.var(0.15), rng.var(0.15))
        } else {
            (rng.var(1.0), rng.var(1.0))
        };
        let x = centre[0] + fx * spread[0];
        let z = centre[1] + fz * spread[1];
        let strength = if k == 0 { 1.0 } else { rng.range(0.0, 1.0) };
        let radius = p.radius_m[0] + (p.radius_m[1] - p.radius_m[0]) * strength.sqrt();
        let excess = p.excess[0] + (p.excess[1] - p.excess[0]) * strength;
        let too_close = thermals
            .iter()
            .any(|t| ((t.x - x).powi(2) + (t.z - z).powi(2)).sqrt() < 0.6 * (t.radius + radius));
        if too_close {
            continue;
        }
        // Dry ascent to the LCL.
        let base_excess = excess - (DRY_LAPSE - p.lapse_rate) * lcl_m / 1000.0;
        let eps = ENTRAINMENT_RADIUS / (radius / 1000.0);
        let mut t = Thermal {
            x,
            z,
            radius,
            entrainment: eps,
            base_excess,
            top: lcl_m,
        };
        if base_excess > 0.0 {
            // Moist ascent to the inversion (if it gets there), then the stable layer.
            let lower = Layer {
                eps,
                env: p.lapse_rate,
                chi: p.evaporative_cooling,
            };
            let upper = Layer {
                env: p.inversion_lapse_rate,
                ..lower
            };
            let to_inv = (p.inversion_m - lcl_m).max(0.0) / 1000.0;
            let top = match lower.stop_height(base_excess) {
                Some(dz) if dz <= to_inv => lcl_m + 1000.0 * dz,
                _ => {
                    let b_inv = lower.buoyancy(base_excess, to_inv);
                    let dz = upper
                        .stop_height(b_inv)
                        .expect("the stable layer stops every parcel");
                    lcl_m.max(p.inversion_m) + 1000.0 * dz
                }
            };
            t.top = top.min(top_limit);
        }
        thermals.push(t);
    }
    thermals.retain(|t| t.base_excess > 0.0 && t.top > lcl_m + 2.0 * h);
    if thermals.is_empty() {
        return Err(CloudError::NoCloud { lcl_m });
    }

    let bubbles = bubbles(&thermals, base, h, p, &mut rng);
    let density = splat(&bubbles, p.dims, base, h, p);
    Ok(Cumulus {
        dims: p.dims,
        density,
        base,
        thermals,
        cell_m: h,
    })
}

/// The bubbles of every thermal's tower and cauliflower, in cells.
fn bubbles(
    thermals: &[Thermal],
    base: f64,
    h: f64,
    p: &CumulusParams,
    rng: &mut Rng,
) -> Vec<Bubble> {
    let mut out = Vec::new();
    for t in thermals {
        let eps = t.entrainment as f32;
        let r0 = t.radius / h;
        let top = t.top / h;
        // The tower widens slowly as it entrains.
        let radius_at = |y: f64| r0 * (1.0 + 0.1 * (y - base).max(0.0) / r0.max(1.0)).min(1.3);
        let axis = |y: f64| [t.x / h + p.shear * (y - base), y, t.z / h];
        // Stack from below the base (cut flat there) up to the dome, whose visible top
        // (about half a kernel radius above its centre) is the parcel's top.
        let mut y = base - 0.4 * r0;
        let mut tower = Vec::new();
        loop {
            let r = radius_at(y).min((top - y).max(0.25 * r0));
            let jitter = 1.0 + rng.var(0.12);
            let c = axis(y);
            let b = Bubble {
                c: [
                    (c[0] + rng.var(0.15) * r) as f32,
                    c[1] as f32,
                    (c[2] + rng.var(0.15) * r) as f32,
                ],
                r: (1.7 * r * jitter) as f32,
                eps,
            };
            tower.push(b);
            if y + r >= top - 0.5 {
                break;
            }
            y = (y + 0.55 * r).min(top - r);
        }
        // Sub-bubbles: the dome gets three generations, the upper half of the tower one or two.
        let n = tower.len();
        for (k, b) in tower.iter().enumerate() {
            let height = (k + 1) as f64 / n as f64;
            let levels = if k + 1 == n {
                3
            } else if height > 0.5 {
                2
            } else {
                1
            };
            cauliflower(*b, levels, k + 1 == n, [base, top], rng, &mut out);
        }
        out.extend(tower);
    }
    out
}

/// Adds the children of `parent`, `levels` generations deep: on the upper hemisphere for a
/// cap, around the sides otherwise; never below the base nor (by more than a cell) above the
/// parcel's top, `[base, top]` in cells.
fn cauliflower(
    parent: Bubble,
    levels: u32,
    cap: bool,
    [base, top]: [f64; 2],
    rng: &mut Rng,
    out: &mut Vec<Bubble>,
) {
    if levels == 0 {
        return;
    }
    let count = if cap { 6 } else { 4 };
    for _ in 0..count {
        // A direction: uniform azimuth, elevation biased upwards on caps.
        let phi = rng.range(0.0, std::f64::consts::TAU);
        let up = if cap {
            rng.range(0.35, 1.0)
        } else {
            rng.range(-0.1, 0.5)
        };
        let flat = (1.0 - up * up).max(0.0).sqrt();
        let d = [flat * phi.cos(), up, flat * phi.sin()];
        let r = parent.r as f64 * rng.range(0.38, 0.55);
        let dist = parent.r as f64 * rng.range(0.5, 0.68);
        let c = [
            parent.c[0] as f64 + d[0] * dist,
            parent.c[1] as f64 + d[1] * dist,
            parent.c[2] as f64 + d[2] * dist,
        ];
        // The visible part of a kernel reaches about half its radius from the centre.
        if c[1] - 0.3 * r < base || c[1] + 0.5 * r > top + 1.0 {
            continue;
        }
        let child = Bubble {
            c: c.map(|v| v as f32),
            r: r as f32,
            eps: parent.eps,
        };
        out.push(child);
        cauliflower(child, levels - 1, cap, [base, top], rng, out);
    }
}

/// Hash of an integer lattice point and a seed → [0, 1).
fn hash3(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f)
        ^ seed.wrapping_mul(0x1656_67b1);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Smooth 3-D value noise in [0, 1) with unit lattice spacing.
fn value_noise(p: [f32; 3], seed: u32) -> f32 {
    let f = p.map(f32::floor);
    let t = [0, 1, 2].map(|a| {
        let t = p[a] - f[a];
        t * t * (3.0 - 2.0 * t)
    });
    let i = f.map(|v| v as i32);
    let mut acc = 0.0;
    for corner in 0..8 {
        let o = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let w = (0..3)
            .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
            .product::<f32>();
        acc += w * hash3(i[0] + o[0], i[1] + o[1], i[2] + o[2], seed);
    }
    acc
}

/// Three octaves of value noise, wavelengths 12, 6 and 3 cells, in [0, 1).
fn eddies(p: [f32; 3], seed: u32) -> f32 {
    let mut sum = 0.0;
    let mut amp = 0.5;
    let mut wavelength = 12.0;
    for octave in 0..3u32 {
        sum += amp * value_noise(p.map(|v| v / wavelength), seed.wrapping_add(octave));
        amp *= 0.5;
        wavelength *= 0.5;
    }
    sum / 0.875
}

fn smoothstep(lo: f32, hi: f32, x: f32) -> f32 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Evaluates the field over the grid, x-plane by x-plane in parallel (each site a pure
/// function of the bubbles), and turns it into density.
fn splat(bubbles: &[Bubble], dims: [usize; 3], base: f64, h: f64, p: &CumulusParams) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let seed = (p.seed ^ (p.seed >> 32)) as u32;
    let mut density = vec![0.0f32; nx * ny * nz];
    let base = base as f32;
    let dz_km = h as f32 / 1000.0;
    let (q_rate, q_full) = (LIQUID_LAPSE as f32, p.lwc_full as f32);
    // Fade to zero over the last cells inside the margin: the shell holds the LB boundary.
    let taper = |i: usize, n: usize| {
        let d = i.min(n - 1 - i) as f32;
        smoothstep(1.0, MARGIN as f32, d)
    };
    density
        .par_chunks_mut(ny * nz)
        .enumerate()
        .for_each(|(x, plane)| {
            let xf = x as f32;
            let in_plane: Vec<&Bubble> = bubbles
                .iter()
                .filter(|b| (b.c[0] - xf).abs() < b.r)
                .collect();
            if in_plane.is_empty() {
                return;
            }
            let mut field = vec![0.0f32; nz];
            let mut eps = vec![0.0f32; nz];
            for y in 1..ny - 1 {
                let yf = y as f32;
                if yf < base - 1.0 {
                    continue;
                }
                field.fill(0.0);
                eps.fill(0.0);
                let mut any = false;
                for b in &in_plane {
                    let (dx, dy) = (xf - b.c[0], yf - b.c[1]);
                    let rr = b.r * b.r - dx * dx - dy * dy;
                    if rr <= 0.0 {
                        continue;
                    }
                    any = true;
                    let half = rr.sqrt();
                    let z0 = (b.c[2] - half).ceil().max(1.0);
                    let z1 = (b.c[2] + half).floor().min((nz - 2) as f32);
                    if z1 < z0 {
                        continue;
                    }
                    let inv = 1.0 / (b.r * b.r);
                    for z in z0 as usize..=z1 as usize {
                        let dz = z as f32 - b.c[2];
                        let s = 1.0 - (dx * dx + dy * dy + dz * dz) * inv;
                        if s > 0.0 {
                            let k = s * s * s;
                            field[z] += k;
                            eps[z] += k * b.eps;
                        }
                    }
                }
                if !any {
                    continue;
                }
                let height = yf - base;
                // Flat base: the condensation level, anti-aliased over one cell.
                let below = smoothstep(-0.5, 1.0, height);
                if below == 0.0 {
                    continue;
                }
                let ty = taper(y, ny) * taper(x, nx);
                let row = &mut plane[y * nz..(y + 1) * nz];
                for z in 1..nz - 1 {
                    let f = field[z];
                    if f <= 0.0 {
                        continue;
                    }
                    let n = eddies([xf, yf, z as f32], seed);
                    let inside = smoothstep(0.32, 0.62, f * (0.55 + 0.9 * n));
                    if inside == 0.0 {
                        continue;
                    }
                    // Adiabatic liquid water, diluted by the field-weighted entrainment.
                    let e = eps[z] / f;
                    let dz = height.max(0.0) * dz_km;
                    let q = q_rate * dz * (-e * dz).exp();
                    // The lowest cell of the base holds at least a trace of liquid water.
                    let q = q.max(0.05 * q_full * below);
                    let rho = (q / q_full).min(1.0) * inside * below * ty * taper(z, nz);
                    row[z] = rho;
                }
            }
        });
    density
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buoyancy_solves_its_equation() {
        // db/dz = (env − Γ_m) − ε (b + χ), checked by a central difference.
        let layer = Layer {
            eps: 1.3,
            env: 7.2,
            chi: 0.6,
        };
        let b0 = 0.8;
        for dz in [0.1, 0.2, 0.7] {
            let d = 1e-6;
            let slope = (layer.buoyancy(b0, dz + d) - layer.buoyancy(b0, dz - d)) / (2.0 * d);
            let want = (layer.env - MOIST_LAPSE) - layer.eps * (layer.buoyancy(b0, dz) + layer.chi);
            assert!((slope - want).abs() < 1e-4, "{slope} {want}");
        }
        assert_eq!(layer.buoyancy(b0, 0.0), b0);
        // Where the limit is negative the buoyancy reaches zero at the stop height.
        let stable = Layer { env: 3.0, ..layer };
        let s = stable.stop_height(1.1).unwrap();
        assert!(stable.buoyancy(1.1, s).abs() < 1e-12);
        assert!(Layer { chi: 0.0, ..layer }.stop_height(1.1).is_none());
    }

    #[test]
    fn noise_is_smooth_and_in_range() {
        let mut prev = value_noise([0.0, 0.3, 0.7], 5);
        for k in 1..200 {
            let v = value_noise([k as f32 * 0.01, 0.3, 0.7], 5);
            assert!((0.0..1.0).contains(&v));
            assert!((v - prev).abs() < 0.05, "continuous");
            prev = v;
        }
        // Lattice points take the hash value.
        assert_eq!(value_noise([2.0, 3.0, 4.0], 9), hash3(2, 3, 4, 9));
    }
}
