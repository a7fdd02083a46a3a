//! The physical light's coarse forest grid (docs/light.md, "Forests"): one LB grid over the
//! whole forest, lit by the scene's sun, sky and ground as each model's own grid is, so that
//! the light models exchange (a neighbour's shade, the light it scatters, the forest's
//! shadow on the ground between the trees) reaches each instance's fine light.
//!
//! **Parts.** Each model's fine physical light is solved as four linear parts
//! ([`crate::lighting::LightParts`]): `S`, the sun's (its first-collision source and the
//! sunlit floor); `D_top`, the response to a unit sky entering through the grid's top face;
//! `D_side`, to a unit sky entering through its sides (radiance 1 on the downward
//! directions, half on horizontal ones, with the floor's sky part); and `G`, to a unit ground
//! on the side faces (upward directions, half on horizontal ones). The model alone is
//! `S + L_sky (D_top + D_side) + L_g G` with `L_g` the open ground's radiance. An instance in
//! the forest gets `τ S + a_top D_top + a D_side + b G` per colour ([`PartWeights`]):
//!
//! - `τ`, the sun's transmittance from the sun to the instance's box through the forest:
//!   the coarse medium's extinction (as the fine first-collision source's, `κ = -ln(1 - ρ) /
//!   k`) marched straight towards the sun from points just outside the box's sunward faces,
//!   each face weighted by its area times the sun's cosine on it.
//! - `a_top`: the downward light arriving at the box's top face (per direction the mean `f_k`
//!   over the coarse sites just above it, the upwind shell as the paper light's global grid
//!   measures it, [`crate::relight::global`]) over a unit sky's.
//! - `a`, `b`: the light that arrives through the side faces. For every lattice direction
//!   `k`, the flux-weighted mean of `f_k` over the coarse sites just outside the side faces
//!   `c_k` enters, summed per class (downward, horizontal, upward directions), matched by
//!   least squares to `a` × a unit sky's values on the same directions plus `b` × a unit
//!   ground's. The bottom face is not measured: the ground under the tree is the fine grid's
//!   own floor. In the open every weight is exact: `τ = 1`, `a_top = a = L_sky`, `b = L_g`.
//!   Light a neighbour scatters towards the box counts, as sky-like or ground-like light by
//!   its direction; a neighbour's shade lowers them.
//!
//! The coarse solve is linear in the sun's irradiance and the sky's radiance (its boundary,
//! floor and source are), so `a_top`, `a` and `b` are too (but where a fit is clamped at 0),
//! and `τ` depends on neither: the instance's light stays linear in them (tested). Luminance
//! is not collapsed: the coarse grid is solved per colour with the forest's mean medium (each
//! model's leaf and bark parameters weighted by their optical depth over the instances).
//!
//! What it does not see: how the shade varies over one instance (the weights are per
//! instance), foliage of a neighbour inside the instance's box (overlapping boxes), and
//! detail below the coarse cell.

use std::collections::HashMap;

use glam::{Affine3A, Vec3};
use sylva_geom::Aabb;
use sylva_lb::lattice::{C, Q};
use sylva_lb::light::{self, Environment};
use sylva_lb::solver::{Lattice, SolveOptions};
use sylva_lb::{ColourParams, DensityGrid, Dims, MediumParams};

use crate::lighting::{LightingError, PartWeights};
use crate::relight::global::{
    coarse_density, placed, shell_faces, GlobalGridOptions, GlobalInstance, Placed, ShellFace,
    MARGIN,
};

/// Largest fine density used for the optical-depth weights of the coarse medium.
const RHO_CAP: f64 = 0.999;
/// Points per axis on each sunward face for the sun's transmittance.
const SUN_SAMPLES: usize = 8;

/// An instance as the forest grid sees it.
#[derive(Debug, Clone, Copy)]
pub struct ForestInstance<'a> {
    /// Its model's fine density grid and physical medium (`None`: not in the coarse medium,
    /// and it keeps the free weights).
    pub model: Option<(&'a DensityGrid, &'a MediumParams)>,
    /// Model → world.
    pub to_world: Affine3A,
}

/// The forest grid's answer: per instance, the weights of its model's light parts.
#[derive(Debug, Clone, PartialEq)]
pub struct ForestLight {
    pub dims: Dims,
    /// World position of site (0, 0, 0).
    pub origin: [f32; 3],
    /// Edge of a coarse cell in the world.
    pub cell: f32,
    /// Per instance.
    pub weights: Vec<PartWeights>,
    /// The weights of a model standing alone (sun 1, the sky's and open ground's radiance).
    pub free: PartWeights,
}

/// The free weights under `env`: sun 1, sky `L_sky`, ground `L_g`.
pub fn free_weights(env: &Environment) -> PartWeights {
    let f = |v: [f64; 3]| Vec3::from_array(v.map(|x| x as f32));
    PartWeights {
        sun: Vec3::ONE,
        sky_top: f(env.sky_radiance),
        sky: f(env.sky_radiance),
        ground: f(env.ground_radiance()),
    }
}

/// Per lattice direction, its class: 0 downward (`c_y < 0`), 1 horizontal, 2 upward.
fn class(k: usize) -> usize {
    match C[k][1] {
        y if y < 0 => 0,
        0 => 1,
        _ => 2,
    }
}

/// The coarse layout: the forest's boxes with [`MARGIN`] cells around them in x and z and
/// above, and the ground (`y = ground_y`) between the bottom shell row and the first interior
/// row, as in the models' own grids.
fn layout(
    boxes: &[Aabb],
    ground_y: f32,
    opts: &GlobalGridOptions,
) -> Result<(Dims, Vec3, f32), String> {
    let mut all = Aabb::EMPTY;
    for b in boxes {
        all = all.union(b);
    }
    let bottom = ground_y.min(all.min.y);
    let ext = Vec3::new(
        all.max.x - all.min.x,
        all.max.y - bottom,
        all.max.z - all.min.z,
    );
    let inner = opts.sites - 1 - 2 * MARGIN;
    let cell = (ext.max_element() / inner as f32).max(1e-3);
    let n = |e: f32| (e / cell).ceil() as usize + 1 + 2 * MARGIN;
    let ny = (ext.y / cell).ceil() as usize + 2 + MARGIN;
    let dims = Dims::new(n(ext.x), ny, n(ext.z)).map_err(|e| e.to_string())?;
    let origin = Vec3::new(
        all.min.x - MARGIN as f32 * cell,
        bottom - 0.5 * cell,
        all.min.z - MARGIN as f32 * cell,
    );
    Ok((dims, origin, cell))
}

/// The forest's mean medium per colour: each model's leaf and bark parameters weighted by
/// their optical depth (`Σ -ln(1 - ρ) h²` over its sites, green and wood shares apart) times
/// its instances' scale².
fn forest_medium(instances: &[ForestInstance], fine: &[Option<Placed>]) -> Option<MediumParams> {
    // Per distinct fine grid: its green and wood optical depth (model units).
    let mut depth: HashMap<usize, (f64, f64)> = HashMap::new();
    let mut w = [0.0f64; 2];
    // (σ_s, σ_a, g) per colour, green then brown.
    let mut sums = [[[0.0f64; 3]; 3]; 2];
    for (inst, p) in instances.iter().zip(fine) {
        let (Some((grid, medium)), Some(p)) = (inst.model, p) else {
            continue;
        };
        let (g, b) = *depth
            .entry(grid as *const DensityGrid as usize)
            .or_insert_with(|| {
                let (mut g, mut b) = (0.0f64, 0.0f64);
                for (&rho, &wood) in grid.density.iter().zip(&grid.wood) {
                    if rho > 0.0 {
                        let tau = -(1.0 - (rho as f64).min(RHO_CAP)).ln();
                        g += tau * (1.0 - wood as f64);
                        b += tau * wood as f64;
                    }
                }
                let h2 = (p.cell_model as f64).powi(2);
                (g * h2, b * h2)
            });
        let s2 = (p.cell_world as f64 / p.cell_model as f64).powi(2);
        for (k, (share, params)) in [
            (g * s2, medium.colours),
            (b * s2, std::array::from_fn(|c| medium.brown_colour(c))),
        ]
        .into_iter()
        .enumerate()
        {
            w[k] += share;
            for (c, cp) in params.iter().enumerate() {
                sums[k][c][0] += share * cp.sigma_s;
                sums[k][c][1] += share * cp.sigma_a;
                sums[k][c][2] += share * cp.g;
            }
        }
    }
    if w[0] + w[1] <= 0.0 {
        return None;
    }
    let mean = |k: usize| -> [ColourParams; 3] {
        // A kind that is absent takes the other's parameters (no site uses it).
        let k = if w[k] > 0.0 { k } else { 1 - k };
        std::array::from_fn(|c| ColourParams {
            sigma_s: sums[k][c][0] / w[k],
            sigma_a: sums[k][c][1] / w[k],
            g: (sums[k][c][2] / w[k]).clamp(-1.0, 1.0),
        })
    };
    Some(MediumParams {
        colours: mean(0),
        zero_f0_on_green: true,
        zero_f0_on_brown: true,
        brown_threshold: 0.5,
        brown: Some(mean(1)),
    })
}

/// Per class (downward, horizontal, upward), `Σ_k` of the flux-weighted mean `f_k` over the
/// faces `c_k` enters among `faces` (the side faces, or the top face), and the directions
/// measured.
fn class_inflow(
    f: &impl Fn([usize; 3], usize) -> f32,
    faces: &[&ShellFace],
) -> ([f64; 3], [bool; Q]) {
    let mut out = [0.0f64; 3];
    let mut measured = [false; Q];
    for (k, c) in C.iter().enumerate().skip(1) {
        let n = sylva_lb::lattice::unit(k);
        let (mut sum, mut weight) = (0.0f64, 0.0f64);
        for face in faces {
            let entering = if face.high {
                c[face.axis] < 0
            } else {
                c[face.axis] > 0
            };
            if !entering || face.sites.is_empty() {
                continue;
            }
            let w = n[face.axis].abs() * face.area as f64;
            let mean =
                face.sites.iter().map(|&s| f(s, k) as f64).sum::<f64>() / face.sites.len() as f64;
            sum += w * mean;
            weight += w;
        }
        if weight > 0.0 {
            out[class(k)] += sum / weight;
            measured[k] = true;
        }
    }
    (out, measured)
}

/// `(a, b)` minimising `Σ_class (a s_class + b g_class - m_class)²`, where `s` and `g` are a
/// unit sky's and a unit ground's class sums over the `measured` directions.
fn fit_sky_ground(m: [f64; 3], measured: &[bool; Q]) -> (f64, f64) {
    let sky = light::sky_boundaries([1.0; 3])[0];
    let ground = light::ground_boundaries([1.0; 3])[0];
    let (mut s, mut g) = ([0.0f64; 3], [0.0f64; 3]);
    for k in 1..Q {
        if measured[k] {
            s[class(k)] += sky.values[k] as f64;
            g[class(k)] += ground.values[k] as f64;
        }
    }
    let dot = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|i| a[i] * b[i]).sum::<f64>();
    let (ss, sg, gg) = (dot(&s, &s), dot(&s, &g), dot(&g, &g));
    let (sm, gm) = (dot(&s, &m), dot(&g, &m));
    let det = ss * gg - sg * sg;
    if det.abs() < 1e-12 {
        return (0.0, 0.0);
    }
    ((sm * gg - gm * sg) / det, (gm * ss - sm * sg) / det)
}

/// The sun's transmittance from the sun to box `b` per colour: the mean over points just
/// outside its sunward faces (not the bottom) of `exp(-τ)`, `τ` marched through `kappa`
/// towards the sun; faces weighted by area × cosine.
fn sun_transmittance(
    b: &Aabb,
    dims: Dims,
    origin: Vec3,
    cell: f32,
    kappa: &[Vec<f64>; 3],
    to_sun: Vec3,
) -> Vec3 {
    let mut sum = [0.0f64; 3];
    let mut weight = 0.0f64;
    let ext = b.max - b.min;
    for axis in 0..3 {
        let cos = to_sun[axis];
        if cos.abs() < 1e-6 || (axis == 1 && cos < 0.0) {
            continue;
        }
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let area = (ext[u] * ext[v]) as f64;
        if area <= 0.0 {
            continue;
        }
        let w = cos.abs() as f64 * area / (SUN_SAMPLES * SUN_SAMPLES) as f64;
        for i in 0..SUN_SAMPLES {
            for j in 0..SUN_SAMPLES {
                let mut p = Vec3::ZERO;
                p[axis] = if cos > 0.0 {
                    b.max[axis] + 0.5 * cell
                } else {
                    b.min[axis] - 0.5 * cell
                };
                p[u] = b.min[u] + ext[u] * (i as f32 + 0.5) / SUN_SAMPLES as f32;
                p[v] = b.min[v] + ext[v] * (j as f32 + 0.5) / SUN_SAMPLES as f32;
                let s = ((p - origin) / cell).as_dvec3().to_array();
                for (c, k) in kappa.iter().enumerate() {
                    let tau = light::optical_depth_to_sun(dims, k, s, to_sun.as_dvec3().to_array());
                    sum[c] += w * (-tau).exp();
                }
                weight += w;
            }
        }
    }
    if weight <= 0.0 {
        return Vec3::ONE;
    }
    Vec3::from_array(sum.map(|s| (s / weight) as f32))
}

impl ForestLight {
    /// Lays the coarse grid over `instances` (ground at `ground_y`), resamples their fine
    /// grids into it, solves it per colour under `env` (sky and open ground on the shell, the
    /// forest-shadowed ground as its floor, the sun's first collisions as its source) and
    /// measures each instance's weights. `progress(done, 3)` after each colour.
    pub fn solve(
        instances: &[ForestInstance],
        env: &Environment,
        ground_y: f32,
        opts: &GlobalGridOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<ForestLight, LightingError> {
        opts.validate().map_err(LightingError::Global)?;
        env.validate().map_err(LightingError::Illumination)?;
        let free = free_weights(env);
        let global: Vec<GlobalInstance> = instances
            .iter()
            .map(|i| GlobalInstance {
                density: i.model.map(|m| m.0),
                to_world: i.to_world,
            })
            .collect();
        let fine: Vec<Option<Placed>> = global.iter().map(placed).collect();
        let boxes: Vec<Aabb> = fine.iter().flatten().map(|p| p.world).collect();
        let medium = forest_medium(instances, &fine);
        let (Some(medium), false) = (medium, boxes.is_empty()) else {
            return Ok(ForestLight {
                dims: Dims::new(3, 3, 3).expect("valid"),
                origin: [0.0; 3],
                cell: 1.0,
                weights: vec![free; instances.len()],
                free,
            });
        };
        medium
            .validate()
            .map_err(|e| LightingError::Global(format!("the forest's medium: {e}")))?;
        let (dims, origin, cell) = layout(&boxes, ground_y, opts).map_err(LightingError::Global)?;
        let grid = coarse_density(dims, origin, cell, &fine)?;
        let solve_err =
            |e: sylva_lb::SolveError| LightingError::Global(format!("coarse solve: {e}"));
        let boundaries = env.diffuse_boundaries();
        let floor = env.floor(&grid, &medium).map_err(solve_err)?;
        let source =
            light::first_collision_source(&grid, &medium, env.sun_travel, env.sun_irradiance)
                .map_err(solve_err)?;
        let shells: Vec<Option<Vec<ShellFace>>> = fine
            .iter()
            .map(|p| {
                p.as_ref()
                    .map(|p| shell_faces(&p.world, dims, origin, cell))
            })
            .collect();
        let sopts = SolveOptions::papers(dims);
        // Per instance and colour: the side faces' class inflows and the directions
        // measured, and the top face's downward inflow.
        let mut inflow = vec![[([0.0f64; 3], [false; Q], 0.0f64); 3]; instances.len()];
        for c in 0..3 {
            let mut lat = Lattice::new(&grid, &medium, c, boundaries[c]).map_err(solve_err)?;
            lat.set_floor(floor.as_ref().map(|f| f.radiance[c].clone()));
            lat.set_source(Some(source.colour(c)));
            lat.reset(boundaries[c]);
            lat.run(&sopts, &mut |_, _| {}).map_err(solve_err)?;
            let f = |s: [usize; 3], k: usize| lat.f(s[0], s[1], s[2], k);
            for (i, shell) in shells.iter().enumerate() {
                if let Some(faces) = shell {
                    let sides: Vec<&ShellFace> = faces.iter().filter(|f| f.axis != 1).collect();
                    let top: Vec<&ShellFace> =
                        faces.iter().filter(|f| f.axis == 1 && f.high).collect();
                    let (m, measured) = class_inflow(&f, &sides);
                    let (t, _) = class_inflow(&f, &top);
                    inflow[i][c] = (m, measured, t[0]);
                }
            }
            progress(c + 1, 3);
        }
        let to_sun = Vec3::from_array(env.sun_travel.map(|v| -v as f32)).normalize_or_zero();
        let kappa: [Vec<f64>; 3] = std::array::from_fn(|c| light::extinction(&grid, &medium, c));
        let unit_sky = light::sky_boundaries([1.0; 3])[0];
        let top_unit: f64 = (1..Q)
            .filter(|&k| class(k) == 0)
            .map(|k| unit_sky.values[k] as f64)
            .sum();
        let weights = fine
            .iter()
            .zip(&inflow)
            .map(|(p, m)| {
                let Some(p) = p else {
                    return free;
                };
                let fits: [(f64, f64); 3] =
                    std::array::from_fn(|c| fit_sky_ground(m[c].0, &m[c].1));
                // Through the top only downward directions enter: a unit sky's sum there.
                let top: [f32; 3] = std::array::from_fn(|c| (m[c].2 / top_unit) as f32);
                let sun = if to_sun.y > 0.0 {
                    sun_transmittance(&p.world, dims, origin, cell, &kappa, to_sun)
                } else {
                    Vec3::ZERO
                };
                PartWeights {
                    sun,
                    sky_top: Vec3::from_array(top),
                    sky: Vec3::from_array(fits.map(|f| f.0.max(0.0) as f32)),
                    ground: Vec3::from_array(fits.map(|f| f.1.max(0.0) as f32)),
                }
            })
            .collect();
        Ok(ForestLight {
            dims,
            origin: origin.to_array(),
            cell,
            weights,
            free,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_is_exact_in_the_open() {
        // Every direction measured, and only the side faces' upward ones.
        let sky = light::sky_boundaries([1.0; 3])[0];
        let ground = light::ground_boundaries([1.0; 3])[0];
        for measured in [
            [true; Q],
            std::array::from_fn(|k| k != 0 && C[k] != [0, 1, 0]),
        ] {
            for (l, lg) in [(0.7, 0.12), (0.0, 0.3), (1.5, 0.0)] {
                let mut m = [0.0f64; 3];
                for k in 1..Q {
                    if measured[k] {
                        m[class(k)] += l * sky.values[k] as f64 + lg * ground.values[k] as f64;
                    }
                }
                let (a, b) = fit_sky_ground(m, &measured);
                assert!((a - l).abs() < 1e-6 && (b - lg).abs() < 1e-6, "{a} {b}");
            }
        }
    }
}
