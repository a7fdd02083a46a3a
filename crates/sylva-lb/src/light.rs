//! The physical light of docs/light.md as linear operators on LB boundaries and media.
//!
//! Units: an LB value is a fluence (radiance integrated over all directions) divided by the
//! irradiance `E0 = π` of a sun of intensity 1, so a unit sun's unobstructed beam is 1 and an
//! isotropic field of radiance `L` (sylva's radiance unit: a white Lambertian surface facing
//! the unit sun has radiance 1) is `4 L`. A lattice direction `i` of an isotropic field holds
//! `4 L w_i` (`w_i` the lattice weights, `Σ w_i = 1`).
//!
//! * Boundaries ([`sun_boundaries`], [`sky_boundaries`], [`ground_boundaries`],
//!   [`Environment`]): per colour, the shell's 19 inflow values for the sun (its irradiance
//!   split over the lattice directions as `max(0, n_i · d) / Σ_j max(0, n_j · d)`), a uniform
//!   sky over the downward half of the directions and the ground's light over the upward half
//!   (horizontal directions take half of each). Each is linear in its radiance, so any of them
//!   is a fixed weighted sum of the relighting bases `B_j` (docs/relight.md).
//! * The uncollided part ([`uncollided`]): light that has not met a leaf yet. The LB is linear
//!   in its boundary and each step keeps `1 - ρ σ_t` of every moving direction at a site
//!   before it scatters anything, so the uncollided field along direction `m` is `b_m` times
//!   the product of `1 - ρ_k σ_t` over the upstream sites: one sweep per direction, no
//!   iteration, exactly the steady state of an LB solve whose medium scatters nothing.
//!   The scattered light of a solve is its total minus that ([`subtract`]), still linear.
//! * The medium ([`medium_for`], [`collision_probability`]): per site the probability that
//!   light crossing it meets a leaf or bark (`ρ`, with `σ_t = 1`), from the leaf and bark
//!   area in the cell; the single-scattering albedo and asymmetry from the surfaces'
//!   reflectance and transmittance.

// Colour and direction indices address several arrays at once.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use crate::grid::{DensityGrid, Dims, LightingGrid};
use crate::lattice::{unit, weight, C, Q};
use crate::params::{ColourParams, MediumParams, ParamError};
use crate::solver::{Boundary, Floor, VolumeSource};

pub use sylva_grid::density::{
    collision_probability, step_optical_depth_factor, BARK_PROJECTION, LEAF_PROJECTION,
};

/// Mean cosine of the light a randomly oriented Lambertian sheet scatters, per unit of
/// `(T - R) / (T + R)`: a Lambertian lobe about the normal has mean cosine 2/3 with the
/// normal, and the normal's cosine with the incident direction, weighted by the projected
/// area `|cos|`, averages 2/3 too.
pub const LAMBERTIAN_SHEET_ASYMMETRY: f64 = 4.0 / 9.0;

/// Radiance leaving a Lambertian sheet of albedo 1 (reflected plus transmitted) in an
/// isotropic field of LB value `u`: each side receives the irradiance `π u / 4` (in units
/// of `E0 = π`: `u / 4`), so a sheet with reflectance `R` and transmittance `T` sends
/// `(R + T) u / 4` towards either side.
pub const SHEET_RADIANCE_PER_FLUENCE: f32 = 0.25;

/// Mean reflectance and transmittance of a model's leaves and reflectance of its bark, per
/// colour (linear R, G, B).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantOptics {
    pub leaf_reflectance: [f64; 3],
    pub leaf_transmittance: [f64; 3],
    pub bark_reflectance: [f64; 3],
}

/// The LB medium of a plant: every collision is with a leaf (green sites) or bark (brown
/// sites, wood fraction above 1/2), `σ_t = 1` so that `ρ` is the collision probability;
/// leaves scatter `σ_s = R + T` with asymmetry `g = 4/9 · (T - R)/(T + R)`
/// ([`LAMBERTIAN_SHEET_ASYMMETRY`]), bark `σ_s = R_bark` with `g = -4/9`; absorbed light is
/// lost (`f_0` zeroed on both). Errors when a surface scatters more than it receives.
pub fn medium_for(optics: &PlantOptics) -> Result<MediumParams, ParamError> {
    let colour = |albedo: f64, g: f64, what: &str| -> Result<ColourParams, ParamError> {
        if !albedo.is_finite() {
            return Err(ParamError::NotFinite {
                name: format!("{what} albedo"),
                value: albedo,
            });
        }
        if !(0.0..=1.0).contains(&albedo) {
            return Err(ParamError::OutOfRange {
                name: format!("{what} albedo (reflectance + transmittance)"),
                value: albedo,
                lo: 0.0,
                hi: 1.0,
            });
        }
        ColourParams::new(1.0 - albedo, albedo, g)
    };
    let mut leaf = [ColourParams {
        sigma_a: 1.0,
        sigma_s: 0.0,
        g: 0.0,
    }; 3];
    let mut bark = leaf;
    for c in 0..3 {
        let (r, t) = (optics.leaf_reflectance[c], optics.leaf_transmittance[c]);
        let g = if r + t > 0.0 {
            LAMBERTIAN_SHEET_ASYMMETRY * (t - r) / (t + r)
        } else {
            0.0
        };
        let name = crate::params::COLOUR_NAMES[c];
        leaf[c] = colour(r + t, g, &format!("{name} leaf"))?;
        bark[c] = colour(
            optics.bark_reflectance[c],
            -LAMBERTIAN_SHEET_ASYMMETRY,
            &format!("{name} bark"),
        )?;
    }
    Ok(MediumParams {
        colours: leaf,
        zero_f0_on_green: true,
        zero_f0_on_brown: true,
        brown_threshold: 0.5,
        brown: Some(bark),
    })
}

/// `Σ_i max(0, n_i · d)`: what a free-space site holds under a sun of boundary
/// `f_i = max(0, n_i · d)`; `None` for a zero or non-finite `travel`.
pub fn sun_total(travel: [f64; 3]) -> Option<f64> {
    let len = (travel[0] * travel[0] + travel[1] * travel[1] + travel[2] * travel[2]).sqrt();
    if !(len.is_finite() && len > 0.0) {
        return None;
    }
    let d = travel.map(|v| v / len);
    Some(
        (1..Q)
            .map(|i| {
                let n = unit(i);
                (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]).max(0.0)
            })
            .sum(),
    )
}

/// The sun's boundary per colour: light travelling along `travel` with irradiance
/// `irradiance[c]` (units of `E0`) on a surface facing it, carried by the three lattice
/// directions `j` whose face of the 32-face polyhedron the sun's direction crosses, in
/// proportion to its barycentric weights `w_j` there (004 §3.1,
/// [`crate::relight::polyhedron::face_hit`]). (000's `max(0, n_i · d)` spreads the sun over
/// about ten directions up to 80° from it, which lights the crown's shadowed side.)
///
/// Scaled so that the beam's energy flux along the sun is `E_c`: a lattice value `f_j`
/// moves `f_j c_j` per step (a diagonal link is `√2` cells long; the lattice weights make an
/// isotropic field's flux exact this way: `Σ_{c_y < 0} 4 L w_i |c_i,y| = L`), so `f_j = E_c
/// w_j / Σ_k w_k c_k · d`. The sun's light is then intercepted at the rate a surface facing
/// it receives. All zero for a zero or non-finite `travel`.
pub fn sun_boundaries(travel: [f64; 3], irradiance: [f64; 3]) -> [Boundary; 3] {
    let Ok(hit) = crate::relight::polyhedron::face_hit(travel) else {
        return [Boundary { values: [0.0; Q] }; 3];
    };
    let d = travel.map(|v| v / len3(travel));
    let flux: f64 = hit
        .vertices
        .iter()
        .zip(&hit.weights)
        .map(|(&j, &w)| w * (0..3).map(|a| C[j][a] as f64 * d[a]).sum::<f64>())
        .sum();
    irradiance.map(|e| {
        let mut values = [0.0f32; Q];
        for (&j, &w) in hit.vertices.iter().zip(&hit.weights) {
            values[j] = (e * w / flux) as f32;
        }
        Boundary { values }
    })
}

fn len3(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Share of lattice direction `i`'s cone that lies below the horizon (travelling down):
/// 1 for `n_y < 0`, 1/2 for horizontal directions, 0 for upward ones.
fn downward_share(i: usize) -> f64 {
    match C[i][1] {
        y if y < 0 => 1.0,
        0 => 0.5,
        _ => 0.0,
    }
}

/// A uniform sky of radiance `radiance[c]` over the upper hemisphere: the light it sends
/// travels down, `f_i = 4 L w_i` on downward directions, half that on horizontal ones.
pub fn sky_boundaries(radiance: [f64; 3]) -> [Boundary; 3] {
    hemisphere(radiance, downward_share)
}

/// A uniform Lambertian ground of radiance `radiance[c]` below: its light travels up, `f_i =
/// 4 L w_i` on upward directions, half that on horizontal ones.
pub fn ground_boundaries(radiance: [f64; 3]) -> [Boundary; 3] {
    hemisphere(radiance, |i| 1.0 - downward_share(i))
}

fn hemisphere(radiance: [f64; 3], share: impl Fn(usize) -> f64) -> [Boundary; 3] {
    radiance.map(|l| {
        let mut values = [0.0f32; Q];
        for (i, v) in values.iter_mut().enumerate().skip(1) {
            *v = (4.0 * l * weight(i) * share(i)) as f32;
        }
        Boundary { values }
    })
}

/// `a + b` per colour and direction.
pub fn add(a: &[Boundary; 3], b: &[Boundary; 3]) -> [Boundary; 3] {
    std::array::from_fn(|c| Boundary {
        values: std::array::from_fn(|i| a[c].values[i] + b[c].values[i]),
    })
}

/// The light around a plant: the sun, a uniform sky and an open Lambertian ground, per
/// colour in linear RGB.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Environment {
    /// The direction sunlight travels (away from the sun); need not be unit length.
    pub sun_travel: [f64; 3],
    /// The sun's irradiance on a surface facing it, units of `E0` (sylva's sun: its colour
    /// times its intensity).
    pub sun_irradiance: [f64; 3],
    /// The sky's radiance.
    pub sky_radiance: [f64; 3],
    /// The ground's albedo; `None`: no ground, the sky all round.
    pub ground_albedo: Option<[f64; 3]>,
}

impl Environment {
    /// The open ground's radiance, lit by the sun and the sky: `ρ (E cos θ + L_sky)` (the
    /// sky's irradiance on it is `π L_sky`, i.e. `L_sky` in units of `E0`); the sky's where
    /// there is no ground.
    pub fn ground_radiance(&self) -> [f64; 3] {
        let Some(albedo) = self.ground_albedo else {
            return self.sky_radiance;
        };
        let len = len3(self.sun_travel);
        let cos = if len > 0.0 && len.is_finite() {
            (-self.sun_travel[1] / len).max(0.0)
        } else {
            0.0
        };
        std::array::from_fn(|c| albedo[c] * (self.sun_irradiance[c] * cos + self.sky_radiance[c]))
    }

    /// The sun's part of the boundary.
    pub fn sun_boundaries(&self) -> [Boundary; 3] {
        sun_boundaries(self.sun_travel, self.sun_irradiance)
    }

    /// The diffuse part: sky above, ground below.
    pub fn diffuse_boundaries(&self) -> [Boundary; 3] {
        add(
            &sky_boundaries(self.sky_radiance),
            &ground_boundaries(self.ground_radiance()),
        )
    }

    /// Sun, sky and ground.
    pub fn boundaries(&self) -> [Boundary; 3] {
        add(&self.sun_boundaries(), &self.diffuse_boundaries())
    }

    /// The ground under a plant (`grid`, medium `medium`) as the LB's floor: per `(x, z)`,
    /// the open ground's radiance with the sun's and the sky's share scaled by how much of
    /// each reaches the ground there uncollided (the plant's shadow on the ground, from
    /// [`floor_irradiance`] over its free-space value). `None` without a ground.
    pub fn floor(
        &self,
        grid: &DensityGrid,
        medium: &MediumParams,
    ) -> Result<Option<Floor>, crate::SolveError> {
        let Some(albedo) = self.ground_albedo else {
            return Ok(None);
        };
        let len = len3(self.sun_travel);
        let cos = if len > 0.0 && len.is_finite() {
            (-self.sun_travel[1] / len).max(0.0)
        } else {
            0.0
        };
        let sky = sky_boundaries(self.sky_radiance);
        let sky_irr = floor_irradiance(grid, medium, &sky)?;
        let dims = grid.dims;
        let radiance = std::array::from_fn(|c| {
            let open = open_floor_irradiance(&sky[c]);
            let k_sky = if open > 0.0 { 1.0 / open } else { 0.0 };
            // The sun's share: exactly along its direction (the lattice's three directions
            // around it would see past the crown's edge and light the ground under it).
            let sun = if cos > 0.0 {
                floor_sun_transmittance(grid, medium, c, self.sun_travel)
            } else {
                vec![0.0; dims.nx * dims.nz]
            };
            (0..dims.nx * dims.nz)
                .map(|k| {
                    (albedo[c]
                        * (self.sun_irradiance[c] * cos * sun[k]
                            + self.sky_radiance[c] * sky_irr[c][k] * k_sky))
                        as f32
                })
                .collect()
        });
        Ok(Some(Floor {
            nx: dims.nx,
            nz: dims.nz,
            radiance,
        }))
    }

    /// Checks that every value is finite and ≥ 0, naming the one that is not.
    pub fn validate(&self) -> Result<(), String> {
        let named = [
            ("sun direction", self.sun_travel, false),
            ("sun irradiance", self.sun_irradiance, true),
            ("sky radiance", self.sky_radiance, true),
            (
                "ground albedo",
                self.ground_albedo.unwrap_or([0.0; 3]),
                true,
            ),
        ];
        for (what, v, non_negative) in named {
            if !v
                .iter()
                .all(|x| x.is_finite() && (!non_negative || *x >= 0.0))
            {
                return Err(format!(
                    "{what} {v:?} must be finite{}",
                    if non_negative { " and ≥ 0" } else { "" }
                ));
            }
        }
        Ok(())
    }
}

/// The sun's transmittance from the ground (the plane between the bottom shell row and the
/// first interior row, `y = 1/2` in site units) at each `(x, z)` site to the edge of the
/// grid, straight along the sun (`-travel`): `exp(-Σ κ Δs)` in steps of a quarter cell, with
/// each interior site's extinction per cell `κ = -ln(1 - ρ σ_t) / k` (the LB medium's own
/// optical depth, [`step_optical_depth_factor`] `k`) over the cube around it.
pub fn floor_sun_transmittance(
    grid: &DensityGrid,
    medium: &MediumParams,
    colour: usize,
    travel: [f64; 3],
) -> Vec<f64> {
    let dims = grid.dims;
    let len = len3(travel);
    let to_sun = travel.map(|v| -v / len);
    let kappa = extinction(grid, medium, colour);
    (0..dims.nx * dims.nz)
        .into_par_iter()
        .map(|i| {
            let p = [(i / dims.nz) as f64, 0.5, (i % dims.nz) as f64];
            (-optical_depth_to_sun(dims, &kappa, p, to_sun)).exp()
        })
        .collect()
}

/// Extinction per cell edge of each site for colour `colour`: `κ = -ln(1 - ρ σ_t) / k`, the
/// medium's optical depth per unit length ([`step_optical_depth_factor`] `k`; brown sites
/// with their own `σ_t`).
pub fn extinction(grid: &DensityGrid, medium: &MediumParams, colour: usize) -> Vec<f64> {
    let k = step_optical_depth_factor();
    let (green, brown) = (
        medium.colours[colour].sigma_t(),
        medium.brown_colour(colour).sigma_t(),
    );
    grid.density
        .par_iter()
        .zip(grid.wood.par_iter())
        .map(|(&rho, &wood)| {
            let rho = rho as f64;
            if rho <= 0.0 {
                return 0.0;
            }
            let sigma_t = if wood as f64 > medium.brown_threshold {
                brown
            } else {
                green
            };
            -(1.0 - (rho * sigma_t).min(1.0 - 1e-9)).ln() / k
        })
        .collect()
}

/// `v.round() as usize` for `0 ≤ v < 2⁵²` without a library call (x86-64's baseline has no
/// rounding instruction; this march makes three per step): the fraction `v - trunc(v)` is
/// exact there, so halves round up exactly as `round` does.
#[inline(always)]
fn round_positive(v: f64) -> usize {
    let t = v as usize;
    t + (v - t as f64 >= 0.5) as usize
}

/// Optical depth from site-unit point `p` to the edge of the interior, straight towards
/// `to_sun` (unit), in steps of a quarter cell through the nearest sites' extinction
/// (`kappa` per site, as [`extinction`] gives it).
pub fn optical_depth_to_sun(dims: Dims, kappa: &[f64], mut p: [f64; 3], to_sun: [f64; 3]) -> f64 {
    const STEP: f64 = 0.25;
    // Interior sites cover [1/2, n - 3/2] along each axis.
    let last = [dims.nx - 2, dims.ny - 2, dims.nz - 2].map(|v| v as f64 + 0.5);
    let mut tau = 0.0;
    loop {
        for a in 0..3 {
            p[a] += to_sun[a] * STEP;
        }
        if (0..3).any(|a| p[a] < 0.5 || p[a] > last[a]) {
            return tau;
        }
        let q = p.map(round_positive);
        tau += kappa[dims.index(q[0], q[1], q[2])] * STEP;
    }
}

/// The sunlight scattered at its first collision, as a [`VolumeSource`]: the sun's beam
/// (irradiance `irradiance[c]` in units of `E0`, travelling along `travel`) is attenuated
/// straight along its own direction through the medium (each site's extinction per cell
/// `κ = -ln(1 - ρ σ_t) / k`), not along lattice directions; site `i` intercepts
/// `E T_i (1 - e^{-κ_i})` per step (`T_i` the transmittance up to its cell) and scatters
/// `σ_s / σ_t` of it into direction `m` in proportion to `w_m pn(m ← sun)` (the phase
/// function of the lattice directions around the sun, weighted as in [`sun_boundaries`]).
/// Linear in `irradiance`. The LB then carries this light through all further scattering;
/// the renderer traces the uncollided sun itself.
pub fn first_collision_source(
    grid: &DensityGrid,
    medium: &MediumParams,
    travel: [f64; 3],
    irradiance: [f64; 3],
) -> Result<VolumeSource, crate::SolveError> {
    medium.validate()?;
    let dims = grid.dims;
    sylva_core::check_memory(
        &format!("the sun's first-collision source on a {dims} grid"),
        dims.sites() as u64 * (8 + 8 + 3 * 4),
    )?;
    let zero = || VolumeSource {
        strength: std::array::from_fn(|_| vec![0.0; dims.sites()]),
        green: [[0.0; Q]; 3],
        brown: [[0.0; Q]; 3],
    };
    let Ok(hit) = crate::relight::polyhedron::face_hit(travel) else {
        return Ok(zero());
    };
    let len = len3(travel);
    let to_sun = travel.map(|v| -v / len);
    // Half a cell's chord: where the ray leaves a site's own cube.
    let exit = (0..3)
        .map(|a| 0.5 / to_sun[a].abs().max(1e-12))
        .fold(f64::INFINITY, f64::min);
    let mut source = zero();
    let mut unit_strengths: Vec<((f64, f64), Vec<f32>)> = Vec::new();
    for c in 0..3 {
        let profile = |p: &ColourParams| scatter_profile(p, &hit);
        source.green[c] = profile(&medium.colours[c]);
        source.brown[c] = profile(&medium.brown_colour(c));
        // Colours with the same extinction share the transmittance.
        let sigma = (
            medium.colours[c].sigma_t(),
            medium.brown_colour(c).sigma_t(),
        );
        let unit = match unit_strengths.iter().position(|(s, _)| *s == sigma) {
            Some(k) => k,
            None => {
                let kappa = extinction(grid, medium, c);
                unit_strengths.push((sigma, first_collision_strength(dims, &kappa, to_sun, exit)));
                unit_strengths.len() - 1
            }
        };
        let e = irradiance[c];
        source.strength[c] = unit_strengths[unit]
            .1
            .iter()
            .map(|&v| (v as f64 * e) as f32)
            .collect();
    }
    Ok(source)
}

/// What a site's first collision with the sun's beam scatters into each lattice direction,
/// per unit of intercepted light: `σ_s / σ_t` times `w_m pn(m ← sun)`, the phase function of
/// the lattice directions around the sun (`hit`: the polyhedron face its direction crosses).
/// The directions' shares sum to the single-scattering albedo.
fn scatter_profile(p: &ColourParams, hit: &crate::relight::polyhedron::FaceHit) -> [f32; Q] {
    let pn = crate::collision::normalised_phase(p.g);
    let albedo = if p.sigma_t() > 0.0 {
        p.sigma_s / p.sigma_t()
    } else {
        0.0
    };
    std::array::from_fn(|m| {
        if m == 0 {
            return 0.0;
        }
        let share: f64 = hit
            .vertices
            .iter()
            .zip(&hit.weights)
            .map(|(&j, &w)| w * weight(m) * pn[m][j])
            .sum();
        (albedo * share) as f32
    })
}

/// `T_i (1 - e^{-κ_i})` per site for a unit sun (0 on the shell and where nothing is): the
/// transmittance from the sun up to where the ray leaves the site's cell (`exit` cells
/// from its centre) times the cell's interception.
fn first_collision_strength(dims: Dims, kappa: &[f64], to_sun: [f64; 3], exit: f64) -> Vec<f32> {
    (0..dims.sites())
        .into_par_iter()
        .map(|i| {
            let (x, y, z) = dims.coords(i);
            if kappa[i] <= 0.0 || dims.on_shell(x, y, z) {
                return 0.0;
            }
            let centre = [x as f64, y as f64, z as f64];
            let start = [0, 1, 2].map(|a| centre[a] + to_sun[a] * (exit - 0.125));
            let tau = optical_depth_to_sun(dims, kappa, start, to_sun);
            ((-tau).exp() * -(-kappa[i]).exp_m1()) as f32
        })
        .collect()
}

/// Bytes [`uncollided`] holds over `dims`: one direction's field, the per-site attenuation
/// and the f64 totals, plus the three-colour result.
pub fn uncollided_memory_needed(dims: Dims) -> u64 {
    dims.sites() as u64 * (4 + 4 + 8 + 3 * 4)
}

/// The uncollided light of `grid` under `boundaries` (one per colour): the steady state of
/// the LB update with the medium's scattering turned off (`σ_s = 0`, `σ_t` kept), i.e. per
/// site the sum over directions `m` of `b_m Π_k (1 - ρ_k σ_t,k)` over the interior sites
/// `k` upstream along `-c_m` up to the shell; shell sites hold the boundary. Site codes and
/// `σ_t` follow the solver exactly (brown sites where the wood fraction exceeds the
/// threshold). Deterministic for any thread count.
pub fn uncollided(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
) -> Result<LightingGrid, crate::SolveError> {
    let dims = grid.dims;
    let mut total = vec![0.0f64; dims.sites()];
    let mut colours: [Vec<f32>; 3] = Default::default();
    for (c, out) in colours.iter_mut().enumerate() {
        total.fill(0.0);
        // The rest direction never streams: the shell holds b_0, interior sites none.
        let b0 = boundaries[c].values[0] as f64;
        total.par_iter_mut().enumerate().for_each(|(i, t)| {
            let (x, y, z) = dims.coords(i);
            if dims.on_shell(x, y, z) {
                *t = b0;
            }
        });
        each_direction(grid, medium, c, &boundaries[c], |_, field, _| {
            total
                .par_iter_mut()
                .zip(field.par_iter())
                .for_each(|(t, &f)| *t += f as f64);
        })?;
        *out = total.par_iter().map(|&t| t as f32).collect();
    }
    Ok(LightingGrid {
        dims,
        bounds: grid.bounds,
        colours,
    })
}

/// The uncollided flux that reaches the ground under `grid` (the bottom of its interior,
/// `y = 1/2` in site units) per colour and `(x, z)` site, in the lattice's own measure: the
/// sum of the downward values (`c_y = -1`) that stream onto the floor sites.
pub fn floor_irradiance(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
) -> Result<[Vec<f64>; 3], crate::SolveError> {
    let dims = grid.dims;
    let (nx, nz) = (dims.nx, dims.nz);
    let mut out: [Vec<f64>; 3] = Default::default();
    for (c, irr) in out.iter_mut().enumerate() {
        *irr = vec![0.0f64; nx * nz];
        let b = &boundaries[c];
        each_direction(grid, medium, c, b, |m, field, atten| {
            let cm = C[m];
            if cm[1] != -1 {
                return;
            }
            irr.par_iter_mut().enumerate().for_each(|(k, e)| {
                let (x, z) = (k / nz, k % nz);
                // The site this direction streams onto floor site (x, 0, z) from.
                let (px, pz) = (x as i64 - cm[0] as i64, z as i64 - cm[2] as i64);
                let inside = |v: i64, n: usize| v >= 0 && v < n as i64;
                if !(inside(px, nx) && inside(pz, nz)) {
                    // Beyond the grid's edge: free space, lit by the boundary.
                    *e += b.values[m] as f64;
                    return;
                }
                let (px, pz) = (px as usize, pz as usize);
                let v = if dims.on_shell(px, 1, pz) {
                    b.values[m] as f64
                } else {
                    let i = dims.index(px, 1, pz);
                    field[i] as f64 * atten[i] as f64
                };
                *e += v;
            });
        })?;
    }
    Ok(out)
}

/// `Σ_{c_y = -1} b_m`: the floor flux of [`floor_irradiance`] in free space.
pub fn open_floor_irradiance(b: &Boundary) -> f64 {
    (1..Q)
        .filter(|&m| C[m][1] == -1)
        .map(|m| b.values[m] as f64)
        .sum()
}

/// The light of `grid` under `boundaries` scattered exactly once (the LB's second term after
/// [`uncollided`]): every site scatters what its collision takes from the uncollided field,
/// as the LB's collision does, and that light travels on uncollided. Per site the sum over
/// directions; shell sites hold none.
pub fn single_scattered(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
) -> Result<LightingGrid, crate::SolveError> {
    use crate::collision::Omega;
    let dims = grid.dims;
    let n = dims.sites();
    sylva_core::check_memory(
        &format!("the single-scattered light on a {dims} grid"),
        (Q as u64 + 4) * n as u64 * 4,
    )?;
    let mut colours: [Vec<f32>; 3] = Default::default();
    for (c, out) in colours.iter_mut().enumerate() {
        // Scattering from direction j into m: Ω_mj off the diagonal, Ω_mm + σ_t on it.
        let scatter = |p: &crate::ColourParams| {
            let o = Omega::new(p);
            let mut a = [[0.0f64; Q]; Q];
            for m in 1..Q {
                for j in 1..Q {
                    a[m][j] = o.0[m][j] + if m == j { p.sigma_t() } else { 0.0 };
                }
            }
            a
        };
        let (green, brown) = (
            scatter(&medium.colours[c]),
            scatter(&medium.brown_colour(c)),
        );
        let is_brown: Vec<bool> = (0..n)
            .map(|i| grid.density[i] > 0.0 && grid.wood[i] as f64 > medium.brown_threshold)
            .collect();
        // Sources q_m per site: ρ Σ_j A_mj U_j.
        let mut q = vec![0.0f32; Q * n];
        let mut atten_copy = Vec::new();
        each_direction(grid, medium, c, &boundaries[c], |j, field, atten| {
            if atten_copy.is_empty() {
                atten_copy = atten.to_vec();
            }
            q.par_chunks_mut(Q).enumerate().for_each(|(i, qi)| {
                let rho = grid.density[i] as f64;
                if rho == 0.0 || dims.on_shell_index(i) {
                    return;
                }
                let a = if is_brown[i] { &brown } else { &green };
                let u = field[i] as f64 * rho;
                for m in 1..Q {
                    qi[m] += (a[m][j] * u) as f32;
                }
            });
        })?;
        let mut total = vec![0.0f64; n];
        let mut src = vec![0.0f32; n];
        let mut s1 = vec![0.0f32; n];
        for m in 1..Q {
            src.par_iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = q[i * Q + m]);
            sweep_source(dims, &atten_copy, &src, C[m], &mut s1);
            total
                .par_iter_mut()
                .zip(s1.par_iter())
                .for_each(|(t, &v)| *t += v as f64);
        }
        *out = total.iter().map(|&t| t as f32).collect();
    }
    Ok(LightingGrid {
        dims,
        bounds: grid.bounds,
        colours,
    })
}

/// Experiment: single scattering from the sun's exact-direction uncollided beam.
pub fn single_scattered_exact(
    grid: &DensityGrid,
    medium: &MediumParams,
    travel: [f64; 3],
    irradiance: [f64; 3],
) -> Result<LightingGrid, crate::SolveError> {
    use crate::collision::normalised_phase;
    let dims = grid.dims;
    let n = dims.sites();
    let k = step_optical_depth_factor();
    let d = travel.map(|v| v / len3(travel));
    // κ per cell length at each site.
    let kappa: Vec<f32> = grid
        .density
        .iter()
        .map(|&p| (-(1.0 - p.min(0.999_999) as f64).ln() / k) as f32)
        .collect();
    // Exact transmittance along d from outside to each site, marched in half-cell steps
    // towards the sun with nearest-site κ.
    let trans: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (x, y, z) = dims.coords(i);
            let mut p = [x as f64, y as f64, z as f64];
            let mut tau = 0.0f64;
            let step = 0.5;
            loop {
                for a in 0..3 {
                    p[a] -= d[a] * step;
                }
                let q = [p[0].round(), p[1].round(), p[2].round()];
                if q[0] < 1.0
                    || q[1] < 1.0
                    || q[2] < 1.0
                    || q[0] > (dims.nx - 2) as f64
                    || q[1] > (dims.ny - 2) as f64
                    || q[2] > (dims.nz - 2) as f64
                {
                    break;
                }
                tau += kappa[dims.index(q[0] as usize, q[1] as usize, q[2] as usize)] as f64 * step;
            }
            (-tau).exp() as f32
        })
        .collect();
    let hit = crate::relight::polyhedron::face_hit(travel).expect("sun");
    let mut colours: [Vec<f32>; 3] = Default::default();
    let mut atten = vec![0.0f32; n];
    for c in 0..3 {
        let p = medium.colours[c];
        let pn = normalised_phase(p.g);
        atten
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, a)| *a = (1.0 - grid.density[i] as f64 * p.sigma_t()) as f32);
        let mut total = vec![0.0f64; n];
        let mut src = vec![0.0f32; n];
        let mut s1 = vec![0.0f32; n];
        for m in 1..Q {
            // Intercepted flux × albedo × share into m (the sun's face directions' phase).
            let share: f64 = hit
                .vertices
                .iter()
                .zip(&hit.weights)
                .map(|(&j, &w)| w * weight(m) * pn[m][j])
                .sum();
            src.par_iter_mut().enumerate().for_each(|(i, v)| {
                *v = if dims.on_shell_index(i) {
                    0.0
                } else {
                    (irradiance[c] * trans[i] as f64 * kappa[i] as f64 * k * p.sigma_s * share)
                        as f32
                };
            });
            sweep_source(dims, &atten, &src, C[m], &mut s1);
            total
                .par_iter_mut()
                .zip(s1.par_iter())
                .for_each(|(t, &v)| *t += v as f64);
        }
        colours[c] = total.iter().map(|&t| t as f32).collect();
    }
    Ok(LightingGrid {
        dims,
        bounds: grid.bounds,
        colours,
    })
}

/// `out_m(x) = out_m(x - c) · a(x - c) + src(x - c)` along direction `c`, zero from the
/// shell (sequential; an experiment's helper).
fn sweep_source(dims: Dims, atten: &[f32], src: &[f32], c: [i32; 3], out: &mut [f32]) {
    let order = |n: usize, step: i32| -> Vec<usize> {
        if step < 0 {
            (0..n).rev().collect()
        } else {
            (0..n).collect()
        }
    };
    for x in order(dims.nx, c[0]) {
        for y in order(dims.ny, c[1]) {
            for z in order(dims.nz, c[2]) {
                let i = dims.index(x, y, z);
                if dims.on_shell(x, y, z) {
                    out[i] = 0.0;
                    continue;
                }
                let (px, py, pz) = (
                    (x as i64 - c[0] as i64) as usize,
                    (y as i64 - c[1] as i64) as usize,
                    (z as i64 - c[2] as i64) as usize,
                );
                out[i] = if dims.on_shell(px, py, pz) {
                    0.0
                } else {
                    let j = dims.index(px, py, pz);
                    out[j] * atten[j] + src[j]
                };
            }
        }
    }
}

/// Calls `visit(m, field, attenuation)` with the steady uncollided field of every moving
/// direction `m` of colour `c` under `boundary`, and the per-site attenuation `1 - ρ σ_t`.
fn each_direction(
    grid: &DensityGrid,
    medium: &MediumParams,
    c: usize,
    boundary: &Boundary,
    mut visit: impl FnMut(usize, &[f32], &[f32]),
) -> Result<(), crate::SolveError> {
    medium.validate()?;
    let dims = grid.dims;
    sylva_core::check_memory(
        &format!("the uncollided light on a {dims} grid"),
        uncollided_memory_needed(dims),
    )?;
    let (green, brown) = (
        medium.colours[c].sigma_t(),
        medium.brown_colour(c).sigma_t(),
    );
    let atten: Vec<f32> = (0..dims.sites())
        .into_par_iter()
        .map(|i| {
            let rho = grid.density[i] as f64;
            let sigma_t = if rho > 0.0 && grid.wood[i] as f64 > medium.brown_threshold {
                brown
            } else {
                green
            };
            (1.0 - rho * sigma_t) as f32
        })
        .collect();
    let mut field = vec![0.0f32; dims.sites()];
    for m in 1..Q {
        sweep(dims, &atten, boundary.values[m], C[m], &mut field);
        visit(m, &field, &atten);
    }
    Ok(())
}

/// The steady uncollided field of one direction `c` entering with `b` from the shell.
fn sweep(dims: Dims, atten: &[f32], b: f32, c: [i32; 3], out: &mut [f32]) {
    let (nx, ny, nz) = (dims.nx, dims.ny, dims.nz);
    let plane = ny * nz;
    // Sites in an order in which every upstream site (x - c) comes first.
    let order = |n: usize, step: i32| -> Vec<usize> {
        if step < 0 {
            (0..n).rev().collect()
        } else {
            (0..n).collect()
        }
    };
    let (ys, zs) = (order(ny, c[1]), order(nz, c[2]));
    let back = |v: usize, s: i32| (v as i64 - s as i64) as usize;
    if c[0] == 0 {
        // Upstream sites lie in the same x-plane: planes are independent.
        out.par_chunks_mut(plane).enumerate().for_each(|(x, p)| {
            for &y in &ys {
                for &z in &zs {
                    let i = y * nz + z;
                    p[i] = if dims.on_shell(x, y, z) {
                        b
                    } else {
                        let (py, pz) = (back(y, c[1]), back(z, c[2]));
                        let j = py * nz + pz;
                        if dims.on_shell(x, py, pz) {
                            b
                        } else {
                            p[j] * atten[x * plane + j]
                        }
                    };
                }
            }
        });
        return;
    }
    // Upstream sites lie in the previous x-plane: planes in order, rows in parallel.
    for x in order(nx, c[0]) {
        if x == 0 || x == nx - 1 {
            out[x * plane..(x + 1) * plane].fill(b);
            continue;
        }
        let px = back(x, c[0]);
        let (cur, prev) = if px < x {
            let (lo, hi) = out.split_at_mut(x * plane);
            (&mut hi[..plane], &lo[px * plane..(px + 1) * plane])
        } else {
            let (lo, hi) = out.split_at_mut(px * plane);
            (&mut lo[x * plane..(x + 1) * plane], &hi[..plane])
        };
        let prev_atten = &atten[px * plane..(px + 1) * plane];
        cur.par_chunks_mut(nz).enumerate().for_each(|(y, row)| {
            for (z, v) in row.iter_mut().enumerate() {
                *v = if dims.on_shell(x, y, z) {
                    b
                } else {
                    let (py, pz) = (back(y, c[1]), back(z, c[2]));
                    let j = py * nz + pz;
                    if dims.on_shell(px, py, pz) {
                        b
                    } else {
                        prev[j] * prev_atten[j]
                    }
                };
            }
        });
    }
}

/// `total - part` per site and colour, clamped at 0 (float rounding where the two agree):
/// the scattered light of a solve, given its uncollided part.
pub fn subtract(total: &LightingGrid, part: &LightingGrid) -> LightingGrid {
    assert_eq!(total.dims, part.dims, "grids of one solve");
    LightingGrid {
        dims: total.dims,
        bounds: total.bounds,
        colours: std::array::from_fn(|c| {
            total.colours[c]
                .par_iter()
                .zip(part.colours[c].par_iter())
                .map(|(&t, &u)| (t - u).max(0.0))
                .collect()
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_positive_rounds_as_round_does() {
        let mut values = vec![0.0, 0.25, 0.5, 1.5, 2.5, 127.5, 4503599627370495.5];
        // Just below and above every half, where `(v + 0.5) as usize` would go wrong.
        for half in [0.5f64, 1.5, 2.5, 63.5, 1000.5] {
            values.push(f64::from_bits(half.to_bits() - 1));
            values.push(f64::from_bits(half.to_bits() + 1));
        }
        let mut rng = sylva_core::SplitMix64::new(3);
        values.extend((0..10_000).map(|_| rng.next_f64() * 300.0));
        for v in values {
            assert_eq!(round_positive(v), v.round() as usize, "{v:e}");
        }
        // The shortcut this replaced misses just below a half.
        let below = f64::from_bits(0.5f64.to_bits() - 1);
        assert_ne!((below + 0.5) as usize, below.round() as usize);
    }

    #[test]
    fn step_factor_is_the_weighted_inverse_length() {
        let k = step_optical_depth_factor();
        let want = 1.0 / (6.0 / 12.0 + 12.0 / 24.0 / 2f64.sqrt());
        assert!((k - want).abs() < 1e-12 && (k - 1.1716).abs() < 1e-4, "{k}");
    }

    #[test]
    fn boundaries_hold_the_right_fluence() {
        // A sun in any direction: three directions around it, carrying the flux E along it
        // (on the lattice a value f moves f c per step).
        for d in [
            [0.0, -1.0, 0.0],
            [0.3, -0.8, 0.5],
            [1.0, 0.0, 0.0],
            [-0.557, -0.766, -0.321],
        ] {
            let b = sun_boundaries(d, [1.0, 2.0, 0.5]);
            let len = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            for (c, e) in [1.0, 2.0, 0.5].into_iter().enumerate() {
                let flux: f64 = (1..Q)
                    .map(|m| {
                        b[c].values[m] as f64 * (0..3).map(|a| C[m][a] as f64 * d[a]).sum::<f64>()
                            / len.sqrt()
                    })
                    .sum();
                assert!((flux - e).abs() < 1e-5, "{d:?}: {flux} vs {e}");
                let lit = b[c].values.iter().filter(|&&v| v > 0.0).count();
                assert!((1..=3).contains(&lit), "{d:?}: {lit} directions");
            }
        }
        // Sky and ground of radiance L: 2 L each, 4 L together (an isotropic field).
        let sky = sky_boundaries([1.0, 0.5, 0.0]);
        let ground = ground_boundaries([1.0, 0.5, 0.0]);
        for (c, l) in [1.0f64, 0.5, 0.0].iter().enumerate() {
            let s: f64 = sky[c].values.iter().map(|&v| v as f64).sum();
            let g: f64 = ground[c].values.iter().map(|&v| v as f64).sum();
            assert!((s - 2.0 * l).abs() < 1e-6 && (g - 2.0 * l).abs() < 1e-6);
            for i in 1..Q {
                let both = sky[c].values[i] + ground[c].values[i];
                assert!((both as f64 - 4.0 * l * weight(i)).abs() < 1e-6);
            }
        }
        // The sky sends nothing up, the ground nothing down.
        for i in 1..Q {
            if C[i][1] > 0 {
                assert_eq!(sky[0].values[i], 0.0);
            }
            if C[i][1] < 0 {
                assert_eq!(ground[0].values[i], 0.0);
            }
        }
    }

    #[test]
    fn ground_radiance_is_lit_by_sun_and_sky() {
        let env = Environment {
            sun_travel: [0.0, -0.5, 0.5 * 3f64.sqrt()],
            sun_irradiance: [1.0, 1.0, 2.0],
            sky_radiance: [0.2, 0.3, 0.4],
            ground_albedo: Some([0.5, 0.1, 0.0]),
        };
        let l = env.ground_radiance();
        // cos θ = 0.5.
        assert!((l[0] - 0.5 * (0.5 + 0.2)).abs() < 1e-12);
        assert!((l[1] - 0.1 * (0.5 + 0.3)).abs() < 1e-12);
        assert_eq!(l[2], 0.0);
        let open = Environment {
            ground_albedo: None,
            ..env
        };
        assert_eq!(open.ground_radiance(), open.sky_radiance);
        assert!(env.validate().is_ok());
        let bad = Environment {
            sky_radiance: [0.1, f64::NAN, 0.1],
            ..env
        };
        assert!(bad.validate().unwrap_err().contains("sky"));
    }

    #[test]
    fn medium_from_optics() {
        let optics = PlantOptics {
            leaf_reflectance: [0.1, 0.2, 0.05],
            leaf_transmittance: [0.08, 0.24, 0.025],
            bark_reflectance: [0.2, 0.15, 0.1],
        };
        let m = medium_for(&optics).unwrap();
        for c in 0..3 {
            let (r, t) = (optics.leaf_reflectance[c], optics.leaf_transmittance[c]);
            assert!((m.colours[c].sigma_s - (r + t)).abs() < 1e-12);
            assert!((m.colours[c].sigma_t() - 1.0).abs() < 1e-12);
            assert!((m.colours[c].g - 4.0 / 9.0 * (t - r) / (t + r)).abs() < 1e-12);
            let b = m.brown_colour(c);
            assert!((b.sigma_s - optics.bark_reflectance[c]).abs() < 1e-12);
            assert!((b.g + 4.0 / 9.0).abs() < 1e-12);
        }
        // Green multiple scattering: the green albedo is the largest.
        assert!(m.colours[1].sigma_s > m.colours[0].sigma_s);
        let bright = PlantOptics {
            leaf_reflectance: [0.6; 3],
            leaf_transmittance: [0.6; 3],
            ..optics
        };
        let e = medium_for(&bright).unwrap_err().to_string();
        assert!(e.contains("red leaf albedo"), "{e}");
    }
}
