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
//! **Neighbours inside the box.** Where boxes overlap, the neighbours' foliage inside a
//! model's boxes (the coarse extinction less the instance's own, averaged over the model's
//! instances) is added to the density its sun part is solved on ([`neighbour_shade`]): the
//! beam and its first collisions then pass the neighbours' crowns, not only the model's own.
//!
//! What it does not see: how the shade varies over one instance (the weights are per
//! instance, the neighbours' foliage a mean over the model's instances), the neighbours
//! inside the box for the diffuse parts, and detail below the coarse cell.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use glam::{Affine3A, Vec3};
use serde::Serialize;
use sylva_core::cache::{Cache, CacheKey, CacheKind};
use sylva_core::container::{read_container, write_container, ByteReader, ByteWriter};
use sylva_geom::Aabb;
use sylva_lb::lattice::{C, Q};
use sylva_lb::light::{self, Environment};
use sylva_lb::relight::Footprint;
use sylva_lb::solver::{Lattice, SolveOptions};
use sylva_lb::{ColourParams, CpuSolver, DensityGrid, Dims, LbSolver, MediumParams};

use crate::lighting::{LightingError, MediumKey, PartWeights, ShadedDensity, KEY_METADATA};
use crate::relight::global::{
    coarse_density, instance_extinction, placed, read_layout, shell_faces, write_layout,
    ExtinctionBlock, GlobalGridOptions, GlobalInstance, GlobalReport, Placed, ShellFace, MARGIN,
};

/// Largest fine density used for the optical-depth weights of the coarse medium.
const RHO_CAP: f64 = 0.999;
/// Points per axis on each sunward face for the sun's transmittance.
const SUN_SAMPLES: usize = 8;
/// Points per axis (at most) at which a model's neighbour foliage is measured; the fine
/// sites interpolate between them (the foliage comes from the coarse grid: smooth).
const SHADE_SAMPLES: usize = 33;
/// Largest optical depth a fine cell may gain from the neighbours below which the model
/// keeps its own density (and its cache keys).
const SHADE_MIN: f64 = 1e-4;

/// A forest grid's answer in the cache ([`ForestLight::solve_cached`],
/// [`ForestBases::solve_cached`]): keyed by everything its coarse solves read.
pub const FOREST_GRID: CacheKind = CacheKind {
    name: "forest grid",
    version: crate::lighting::CACHE_VERSION,
};
/// Extension of forest grid cache entries.
pub const FOREST_EXTENSION: &str = "sforest";
const FOREST_MAGIC: &[u8; 8] = b"SYLVAFOR";
const FOREST_FILE_VERSION: u32 = 1;

/// Everything a coarse forest solve reads ([`Coarse`]): the coarse medium as resampled from
/// the instances' fine grids (so the key follows what the solve sees, not how the scene was
/// written), the instances' boxes (their shells and the sun's transmittance), the schedule,
/// the kernel, and the light.
#[derive(Debug, Clone, PartialEq, Serialize)]
struct CoarseKey<'a> {
    solver: String,
    dims: [usize; 3],
    origin: [f32; 3],
    cell: f32,
    ground_y: f32,
    density: &'a [f32],
    wood: &'a [f32],
    medium: MediumKey,
    boxes: Vec<Option<[[f32; 3]; 2]>>,
    steps: usize,
    step_optical_depth_factor: f64,
    sun_samples: usize,
    light: CoarseLight,
}

/// What a forest grid is solved under.
#[derive(Debug, Clone, PartialEq, Serialize)]
enum CoarseLight {
    /// One environment ([`ForestLight`]).
    Environment {
        sun_travel: [f64; 3],
        sun_irradiance: [f64; 3],
        sky_radiance: [f64; 3],
        ground_albedo: Option<[f64; 3]>,
    },
    /// The relit parts: a unit sun along each direction, a unit sky, a unit ground
    /// ([`ForestBases`]).
    Parts {
        suns: Vec<[f64; 3]>,
        ground_albedo: Option<[f64; 3]>,
    },
}

impl CoarseLight {
    fn environment(env: &Environment) -> CoarseLight {
        CoarseLight::Environment {
            sun_travel: env.sun_travel,
            sun_irradiance: env.sun_irradiance,
            sky_radiance: env.sky_radiance,
            ground_albedo: env.ground_albedo,
        }
    }
}

/// Where a forest's answers are cached: the cache and the scene's file stem.
#[derive(Debug, Clone)]
pub struct ForestCache {
    cache: Cache,
    stem: String,
}

impl ForestCache {
    /// The cache in `dir` for the forest of the scene named `scene`.
    pub fn new(dir: &Path, scene: &str) -> ForestCache {
        ForestCache {
            cache: Cache::new(dir),
            stem: sylva_core::file_stem(scene, "scene"),
        }
    }

    /// The entry `<stem>-<name>-<key>.<extension>`.
    fn entry(&self, name: &str, key: CacheKey, extension: &str) -> std::path::PathBuf {
        self.cache
            .entry(&format!("{}-{name}", self.stem), key, extension)
    }
}

/// A forest grid's answers in the cache: (what reports call it, its entries' name).
const LIGHT_ENTRY: (&str, &str) = ("forest grid", "forest");
const PARTS_ENTRY: (&str, &str) = ("forest grid parts", "forest-parts");

/// `solve`d, or read from `cache` under `key` when it holds a valid entry (a bad one is
/// solved again and replaced), with the report of what happened.
#[allow(clippy::too_many_arguments)]
fn cached_or_solved<T>(
    (what, name): (&'static str, &str),
    cache: Option<&ForestCache>,
    key: CacheKey,
    dims: Dims,
    t0: Instant,
    read: impl FnOnce(&Path) -> Result<T, String>,
    solve: impl FnOnce() -> Result<T, LightingError>,
    write: impl FnOnce(&T, &Path) -> Result<(), String>,
) -> Result<(T, GlobalReport), LightingError> {
    let Some(at) = cache else {
        let value = solve()?;
        return Ok((value, GlobalReport::computed(what, dims, t0)));
    };
    let path = at.entry(name, key, FOREST_EXTENSION);
    let got = at.cache.get_or_compute(&path, read, solve, write)?;
    let report = GlobalReport {
        what,
        source: got.outcome.into(),
        seconds: t0.elapsed().as_secs_f64(),
        dims,
        path: Some(path),
        cache_warning: got.write_warning,
    };
    Ok((got.value, report))
}

/// Reads a forest grid cache entry's payload under `key`; `Err` is why it is unusable,
/// naming the file.
fn read_forest_entry(path: &Path, key: CacheKey) -> Result<Vec<u8>, String> {
    let c = read_container(
        path,
        FOREST_MAGIC,
        FOREST_FILE_VERSION,
        "forest grid cache entry",
    )
    .map_err(|e| e.to_string())?;
    key.check(path, c.metadata_value(KEY_METADATA))?;
    Ok(c.payload)
}

fn write_forest_entry(path: &Path, key: CacheKey, payload: &[u8]) -> Result<(), String> {
    write_container(
        path,
        FOREST_MAGIC,
        FOREST_FILE_VERSION,
        &[key.metadata()],
        payload,
    )
    .map_err(|e| e.to_string())
}

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
/// How far past a bound rounding may push a weighted mean of valid parameters: far above the
/// error of summing millions of shares (about 1e-16 each), far below any real excess.
const MIX_ROUNDING: f64 = 1e-9;

/// The colour of a weighted mean of valid media. Mathematically its σ_a, σ_s lie in [0, 1], its
/// g in [-1, 1] and its σ_t in (0, 1], as every input's do; a sum over a dense forest's 100 000
/// shares rounds past 1 by about 1e-12, which the lattice's stability check would refuse.
/// Such excess (up to [`MIX_ROUNDING`]) is pulled back; a larger one is left for the check to
/// report, since it cannot come from rounding.
fn mean_colour(sigma_s: f64, sigma_a: f64, g: f64) -> ColourParams {
    let pull = |v: f64, lo: f64, hi: f64| {
        if v < lo && v >= lo - MIX_ROUNDING {
            lo
        } else if v > hi && v <= hi + MIX_ROUNDING {
            hi
        } else {
            v
        }
    };
    let (mut sigma_s, mut sigma_a) = (pull(sigma_s, 0.0, 1.0), pull(sigma_a, 0.0, 1.0));
    let t = sigma_s + sigma_a;
    if t > 1.0 && t <= 1.0 + MIX_ROUNDING {
        sigma_s /= t;
        // σ_a from σ_s, not divided too: the sum is then 1 within an ulp, not two.
        sigma_a = (1.0 - sigma_s).min(sigma_a / t);
    }
    ColourParams {
        sigma_s,
        sigma_a,
        g: g.clamp(-1.0, 1.0),
    }
}

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
        std::array::from_fn(|c| {
            let [s, a, g] = sums[k][c];
            mean_colour(s / w[k], a / w[k], g / w[k])
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

/// The added foliage of a [`ShadedDensity`] (its fingerprint, part of the sun part's key).
pub const NEIGHBOUR_SHADE: CacheKind = CacheKind {
    name: "neighbour shade",
    version: crate::lighting::CACHE_VERSION,
};

/// What the added foliage is made of: the sample lattice's size and, per sample point, the
/// neighbours' optical depth of leaves and of wood per fine cell (f32).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct ShadeKey {
    samples: [usize; 3],
    depths: Vec<[f32; 2]>,
}

/// Per model, its density with the foliage of its instances' neighbours that reaches into
/// their boxes added (`None`: none does, the model keeps its own density). The model's sun
/// part is solved on it (docs/light.md, "Neighbours inside the box").
///
/// A fine grid is solved with only its own model inside; in a dense stand the boxes overlap
/// and the neighbours' crowns fill part of every box (in the canopy 4 to 18 times the
/// model's own optical depth), so the sun's beam reached the inside of a crown through
/// foliage the solve did not see, and its first collisions there scattered light into
/// leaves the neighbours shade (the canopy's shadowed leaves were 1.4× the path-traced
/// light, docs/reference.md). The forest grid's `τ` says what reaches the box's faces; this
/// says what stands between the faces and the model's own leaves. Per instance the
/// neighbours' extinction is the coarse forest extinction less the instance's own share, on
/// the coarse sites (as [`ForestLight`]'s coarse grid resamples the fine grids),
/// interpolated at the model's fine sites through the instance's transform; the model's
/// instances are averaged (one fine grid serves them all) and the optical depths added site
/// by site, the wood share carried along. Exactly nothing is added where no neighbour's box
/// reaches.
///
/// The diffuse parts (sky, ground) keep the model's own density: the added foliage is the
/// coarse grid's mean, without the gaps between leaves and crowns through which diffuse
/// light reaches deep, and solved on it the canopy went 0.66× the reference (measured,
/// docs/reference.md); the beam's transmittance through the coarse medium is not biased
/// (checked against shadow rays through the geometry).
pub fn neighbour_shade(
    models: &[&DensityGrid],
    instances: &[(usize, Affine3A)],
    ground_y: f32,
    opts: &GlobalGridOptions,
) -> Result<Vec<Option<ShadedDensity>>, LightingError> {
    opts.validate().map_err(LightingError::Global)?;
    let none = || (0..models.len()).map(|_| None).collect();
    let global: Vec<GlobalInstance> = instances
        .iter()
        .map(|&(m, to_world)| GlobalInstance {
            density: models.get(m).copied(),
            to_world,
        })
        .collect();
    let fine: Vec<Option<Placed>> = global.iter().map(placed).collect();
    let boxes: Vec<Aabb> = fine.iter().flatten().map(|p| p.world).collect();
    if boxes.len() < 2 {
        return Ok(none());
    }
    let (dims, origin, cell) = layout(&boxes, ground_y, opts).map_err(LightingError::Global)?;
    sylva_core::check_memory(
        &format!("the forest's extinction ({dims})"),
        dims.sites() as u64 * 16,
    )?;
    let blocks: Vec<Option<ExtinctionBlock>> = fine
        .par_iter()
        .map(|p| {
            p.as_ref()
                .map(|p| instance_extinction(p, dims, origin, cell))
        })
        .collect();
    // The forest's extinction, summed in instance order (the same for any thread count).
    let mut total = vec![[0.0f64; 2]; dims.sites()];
    for b in blocks.iter().flatten() {
        let mut i = 0;
        for x in 0..b.n[0] {
            for y in 0..b.n[1] {
                for z in 0..b.n[2] {
                    let t = &mut total[dims.index(b.lo[0] + x, b.lo[1] + y, b.lo[2] + z)];
                    t[0] += b.kappa[i] as f64;
                    t[1] += b.kappa_wood[i] as f64;
                    i += 1;
                }
            }
        }
    }
    // Instance `i`'s neighbours' (κ, κ_wood) at world point `w`, trilinear between sites.
    let neighbours = |i: usize, w: Vec3| -> (f64, f64) {
        let Some(own) = &blocks[i] else {
            return (0.0, 0.0);
        };
        let fp = Footprint::at(dims, ((w - origin) / cell).to_array());
        let (mut k, mut kw) = (0.0f64, 0.0f64);
        for (corner, (site, wgt)) in fp.sites(dims).into_iter().zip(fp.weights()).enumerate() {
            if wgt == 0.0 {
                continue;
            }
            let wgt = wgt as f64;
            let [x, y, z] = fp.corner;
            let s = [x + (corner >> 2), y + (corner >> 1 & 1), z + (corner & 1)];
            let tot = total[site];
            let (ok, okw) = own.at(s);
            // The instance's own share is one of the summands: what remains is the others'.
            let rest = tot[0] - ok as f64;
            if rest > 1e-9 * tot[0].max(1e-30) {
                k += wgt * rest;
                kw += wgt * (tot[1] - okw as f64).clamp(0.0, rest);
            }
        }
        (k, kw)
    };
    let mut out = Vec::with_capacity(models.len());
    for (m, grid) in models.iter().enumerate() {
        let mine: Vec<usize> = (0..instances.len())
            .filter(|&i| instances[i].0 == m && fine[i].is_some())
            .collect();
        if mine.is_empty() {
            out.push(None);
            continue;
        }
        let d = grid.dims;
        let nf = [d.nx, d.ny, d.nz];
        // The sample lattice: fine grids have at least 3 sites per axis, so it has too.
        let ns = Dims::new(
            d.nx.min(SHADE_SAMPLES),
            d.ny.min(SHADE_SAMPLES),
            d.nz.min(SHADE_SAMPLES),
        )
        .expect("at least 3 sites per axis");
        let n_s = [ns.nx, ns.ny, ns.nz];
        let min = Vec3::from_array(grid.bounds.min);
        let cell_model = fine[mine[0]].as_ref().expect("filtered").cell_model;
        // Sample point j of axis a sits at fine coordinate j (n_f - 1) / (n_s - 1).
        let at = |a: usize, j: usize| j as f32 * (nf[a] - 1) as f32 / (n_s[a] - 1) as f32;
        let samples: Vec<[f64; 2]> = (0..ns.sites())
            .into_par_iter()
            .map(|j| {
                let (x, y, z) = ns.coords(j);
                let p = min + Vec3::new(at(0, x), at(1, y), at(2, z)) * cell_model;
                let mut sum = [0.0f64; 2];
                for &i in &mine {
                    let placed = fine[i].as_ref().expect("filtered");
                    let w = instances[i].1.transform_point3(p);
                    let (k, kw) = neighbours(i, w);
                    // Optical depth over one fine cell of this instance.
                    sum[0] += k * placed.cell_world as f64;
                    sum[1] += kw * placed.cell_world as f64;
                }
                sum.map(|v| v / mine.len() as f64)
            })
            .collect();
        let peak = samples.iter().map(|s| s[0]).fold(0.0f64, f64::max);
        if peak.is_nan() || peak < SHADE_MIN {
            out.push(None);
            continue;
        }
        let key = CacheKey::new(
            NEIGHBOUR_SHADE,
            &ShadeKey {
                samples: n_s,
                depths: samples.iter().map(|s| s.map(|v| v as f32)).collect(),
            },
        );
        // A fine site between sample points.
        let sample = |f: [usize; 3]| -> [f64; 2] {
            let g: [f32; 3] =
                std::array::from_fn(|a| f[a] as f32 * (n_s[a] - 1) as f32 / (nf[a] - 1) as f32);
            let fp = Footprint::at(ns, g);
            let mut v = [0.0f64; 2];
            for (site, wgt) in fp.sites(ns).into_iter().zip(fp.weights()) {
                v[0] += wgt as f64 * samples[site][0];
                v[1] += wgt as f64 * samples[site][1];
            }
            v
        };
        let mut density = (*grid).clone();
        let (mut own_depth, mut added_depth) = (0.0f64, 0.0f64);
        for i in 0..d.sites() {
            let (x, y, z) = d.coords(i);
            if d.on_shell(x, y, z) {
                continue;
            }
            let rho = (grid.density[i] as f64).min(RHO_CAP);
            let own = -(1.0 - rho).ln();
            let [add, add_wood] = sample([x, y, z]);
            let tau = own + add;
            own_depth += own;
            added_depth += add;
            if tau > 0.0 {
                density.density[i] = (1.0 - (-tau).exp()) as f32;
                density.wood[i] =
                    ((own * grid.wood[i] as f64 + add_wood) / tau).clamp(0.0, 1.0) as f32;
            }
        }
        out.push(Some(ShadedDensity {
            density,
            key,
            own_depth,
            added_depth,
        }));
    }
    Ok(out)
}

/// The neighbours' foliage of a forest in the cache ([`neighbour_shade_cached`]).
pub const NEIGHBOUR_SHADES: CacheKind = CacheKind {
    name: "neighbour shades",
    version: crate::lighting::CACHE_VERSION,
};
/// Extension of neighbour-shade cache entries.
pub const SHADE_EXTENSION: &str = "sshade";
const SHADE_MAGIC: &[u8; 8] = b"SYLVASHD";
const SHADE_FILE_VERSION: u32 = 1;

/// What [`neighbour_shade`] reads: every model's density (by its key: what it was voxelized
/// from), every instance's model and placement, the ground and the coarse layout, and the
/// measure's own constants.
#[derive(Debug, Clone, PartialEq, Serialize)]
struct ShadesKey {
    densities: Vec<u64>,
    instances: Vec<(usize, [f32; 12])>,
    ground_y: f32,
    sites: usize,
    samples: usize,
    min: f64,
}

/// [`neighbour_shade`], read from `cache` when an entry holds it for the same densities
/// (`density_keys`, one per model: what each was voxelized from), placements, ground and
/// layout; else measured and stored. Also the warning to show when an entry could not be
/// used (measured again) or kept, naming the file. In a large forest the measure is most of
/// a warm run's LB stage (the woodland's 3,900 instances: 2.9 s of 3.3 s).
pub fn neighbour_shade_cached(
    models: &[&DensityGrid],
    density_keys: &[CacheKey],
    instances: &[(usize, Affine3A)],
    ground_y: f32,
    opts: &GlobalGridOptions,
    cache: Option<&ForestCache>,
) -> Result<(Vec<Option<ShadedDensity>>, Option<String>), LightingError> {
    let Some(at) = cache else {
        return Ok((neighbour_shade(models, instances, ground_y, opts)?, None));
    };
    if density_keys.len() != models.len() {
        return Err(LightingError::Global(format!(
            "{} density keys for {} models",
            density_keys.len(),
            models.len()
        )));
    }
    let key = CacheKey::new(
        NEIGHBOUR_SHADES,
        &ShadesKey {
            densities: density_keys.iter().map(|k| k.value()).collect(),
            instances: instances
                .iter()
                .map(|(m, t)| (*m, t.to_cols_array()))
                .collect(),
            ground_y,
            sites: opts.sites,
            samples: SHADE_SAMPLES,
            min: SHADE_MIN,
        },
    );
    let path = at.entry("shade", key, SHADE_EXTENSION);
    let read = |p: &Path| {
        let c = read_container(
            p,
            SHADE_MAGIC,
            SHADE_FILE_VERSION,
            "neighbour shade cache entry",
        )
        .map_err(|e| e.to_string())?;
        key.check(p, c.metadata_value(KEY_METADATA))?;
        shades_from_bytes(&c.payload, models).map_err(|e| format!("{}: {e}", p.display()))
    };
    let got = at.cache.get_or_compute(
        &path,
        read,
        || neighbour_shade(models, instances, ground_y, opts),
        |shades, p| {
            write_container(
                p,
                SHADE_MAGIC,
                SHADE_FILE_VERSION,
                &[key.metadata()],
                &shades_to_bytes(shades),
            )
            .map_err(|e| e.to_string())
        },
    )?;
    let warning = got.warning("measured again");
    Ok((got.value, warning))
}

/// The shades as bytes: per model whether it has one, then its key, depths, density and
/// wood.
fn shades_to_bytes(shades: &[Option<ShadedDensity>]) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.u32(shades.len() as u32);
    for shade in shades {
        match shade {
            None => w.u8(0),
            Some(s) => {
                w.u8(1);
                w.u64(s.key.value());
                w.f64s(&[s.own_depth, s.added_depth]);
                w.f32s(&s.density.density);
                w.f32s(&s.density.wood);
            }
        }
    }
    w.bytes
}

/// [`shades_to_bytes`]'s shades of `models` (each shaded grid on its model's grid); `Err`
/// says what is wrong.
fn shades_from_bytes(
    bytes: &[u8],
    models: &[&DensityGrid],
) -> Result<Vec<Option<ShadedDensity>>, String> {
    let mut r = ByteReader::new(bytes);
    let n = r.u32("model count")? as usize;
    if n != models.len() {
        return Err(format!("{n} models, the forest has {}", models.len()));
    }
    let mut out = Vec::with_capacity(n);
    for (k, own) in models.iter().enumerate() {
        if r.u8("whether a model is shaded")? == 0 {
            out.push(None);
            continue;
        }
        let key = CacheKey::from_value(r.u64("shade key")?);
        let depths = r.f64s("optical depths")?;
        let density = r.f32s("shaded density")?;
        let wood = r.f32s("shaded wood")?;
        let sites = own.dims.sites();
        if depths.len() != 2 || density.len() != sites || wood.len() != sites {
            return Err(format!(
                "model {k}: {} and {} values for a {} grid",
                density.len(),
                wood.len(),
                own.dims
            ));
        }
        let unit = |v: &f32| (0.0..=1.0).contains(v);
        if !density.iter().all(unit)
            || !wood.iter().all(unit)
            || !depths.iter().all(|d| d.is_finite())
        {
            return Err(format!("model {k}: a value out of range"));
        }
        out.push(Some(ShadedDensity {
            density: DensityGrid {
                dims: own.dims,
                bounds: own.bounds,
                density,
                wood,
            },
            key,
            own_depth: depths[0],
            added_depth: depths[1],
        }));
    }
    r.finish()?;
    Ok(out)
}

/// Per instance and colour, what the forest grid measures of one coarse solve: the side
/// faces' class inflows ([`class_inflow`]) and the top face's downward inflow. Linear in the
/// coarse light, so the measures of a sum of solves are the sums of their measures.
type Inflow = [([f64; 3], f64); 3];

/// The coarse grid over a forest, ready to solve: its layout and medium, each instance's
/// fine placement and shell faces.
struct Coarse {
    dims: Dims,
    origin: Vec3,
    cell: f32,
    grid: DensityGrid,
    medium: MediumParams,
    /// Per instance in the coarse medium, the world box of its fine cells.
    boxes: Vec<Option<Aabb>>,
    shells: Vec<Option<Vec<ShellFace>>>,
    /// Per instance, the side faces' lattice directions measured (the same in every solve).
    measured: Vec<[bool; Q]>,
    /// The coarse medium's extinction per colour, which the sun's transmittance marches.
    kappa: [Vec<f64>; 3],
}

fn solve_err(e: sylva_lb::SolveError) -> LightingError {
    LightingError::Global(format!("coarse solve: {e}"))
}

impl Coarse {
    /// The coarse grid over `instances` (ground at `ground_y`); `None` when no instance is in
    /// the coarse medium (every instance keeps the free weights).
    fn new(
        instances: &[ForestInstance],
        ground_y: f32,
        opts: &GlobalGridOptions,
    ) -> Result<Option<Coarse>, LightingError> {
        opts.validate().map_err(LightingError::Global)?;
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
            return Ok(None);
        };
        medium
            .validate()
            .map_err(|e| LightingError::Global(format!("the forest's medium: {e}")))?;
        let (dims, origin, cell) = layout(&boxes, ground_y, opts).map_err(LightingError::Global)?;
        let grid = coarse_density(dims, origin, cell, &fine)?;
        let shells: Vec<Option<Vec<ShellFace>>> = fine
            .iter()
            .map(|p| {
                p.as_ref()
                    .map(|p| shell_faces(&p.world, dims, origin, cell))
            })
            .collect();
        let measured = shells
            .iter()
            .map(|shell| match shell {
                Some(faces) => {
                    let sides: Vec<&ShellFace> = faces.iter().filter(|f| f.axis != 1).collect();
                    class_inflow(&|_, _| 0.0, &sides).1
                }
                None => [false; Q],
            })
            .collect();
        Ok(Some(Coarse {
            dims,
            origin,
            cell,
            boxes: fine.iter().map(|p| p.as_ref().map(|p| p.world)).collect(),
            shells,
            measured,
            kappa: std::array::from_fn(|c| light::extinction(&grid, &medium, c)),
            grid,
            medium,
        }))
    }

    /// The cache key of this grid's answer under `light` (the ground at `ground_y`).
    fn key(&self, ground_y: f32, light: CoarseLight) -> CacheKey {
        CacheKey::new(
            FOREST_GRID,
            &CoarseKey {
                solver: CpuSolver.cache_tag(),
                dims: [self.dims.nx, self.dims.ny, self.dims.nz],
                origin: self.origin.to_array(),
                cell: self.cell,
                ground_y,
                density: &self.grid.density,
                wood: &self.grid.wood,
                medium: MediumKey::new(&self.medium),
                boxes: self
                    .boxes
                    .iter()
                    .map(|b| b.map(|b| [b.min.to_array(), b.max.to_array()]))
                    .collect(),
                steps: self.steps(),
                step_optical_depth_factor: light::step_optical_depth_factor(),
                sun_samples: SUN_SAMPLES,
                light,
            },
        )
    }

    /// The forest's light under `env`: one solve per colour, each instance's weights.
    fn light(
        &self,
        env: &Environment,
        free: PartWeights,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<ForestLight, LightingError> {
        let total = 3 * self.steps();
        let inflow = self.solve(env, env.diffuse_boundaries(), true, true, &mut |done| {
            progress(done, total)
        })?;
        Ok(ForestLight {
            dims: self.dims,
            origin: self.origin.to_array(),
            cell: self.cell,
            weights: self.weights(&inflow, env, free),
            free,
        })
    }

    /// Solves colour `c` under `boundary`, `floor` and `source` and measures every instance's
    /// inflows.
    fn solve_colour(
        &self,
        c: usize,
        boundary: sylva_lb::Boundary,
        floor: Option<&sylva_lb::solver::Floor>,
        source: Option<&sylva_lb::solver::VolumeSource>,
        out: &mut [Inflow],
        step: &mut dyn FnMut(usize),
    ) -> Result<(), LightingError> {
        let sopts = SolveOptions::papers(self.dims);
        let mut lat = Lattice::new(&self.grid, &self.medium, c, boundary).map_err(solve_err)?;
        lat.set_floor(floor.map(|f| f.radiance[c].clone()));
        lat.set_source(source.map(|s| s.colour(c)));
        lat.reset(boundary);
        let steps = sopts.max_steps;
        lat.run(&sopts, &mut |s, _| step(s.min(steps)))
            .map_err(solve_err)?;
        let f = |s: [usize; 3], k: usize| lat.f(s[0], s[1], s[2], k);
        for (i, shell) in self.shells.iter().enumerate() {
            if let Some(faces) = shell {
                let sides: Vec<&ShellFace> = faces.iter().filter(|f| f.axis != 1).collect();
                let top: Vec<&ShellFace> = faces.iter().filter(|f| f.axis == 1 && f.high).collect();
                let (m, _) = class_inflow(&f, &sides);
                let (t, _) = class_inflow(&f, &top);
                out[i][c] = (m, t[0]);
            }
        }
        Ok(())
    }

    /// LB steps of one coarse solve of one colour.
    fn steps(&self) -> usize {
        SolveOptions::papers(self.dims).max_steps
    }

    /// Solves all three colours of one coarse light (`env`'s floor with `floor`, its sun's
    /// first collisions with `sun`, `boundaries` on the shell); the inflows per instance.
    /// `progress(done)` after every LB step, counting this light's steps (3 × [`Coarse::steps`]).
    fn solve(
        &self,
        env: &Environment,
        boundaries: [sylva_lb::Boundary; 3],
        floor: bool,
        sun: bool,
        progress: &mut dyn FnMut(usize),
    ) -> Result<Vec<Inflow>, LightingError> {
        // Without `floor` a ground is dark (the ground part's floor), not left out: with no
        // floor at all the bottom shell would hold the boundary's open ground.
        let floor = match (floor, env.ground_albedo) {
            (true, _) => env.floor(&self.grid, &self.medium).map_err(solve_err)?,
            (false, Some(_)) => Some(sylva_lb::solver::Floor {
                nx: self.dims.nx,
                nz: self.dims.nz,
                radiance: std::array::from_fn(|_| vec![0.0; self.dims.nx * self.dims.nz]),
            }),
            (false, None) => None,
        };
        let source = match sun {
            true => Some(
                light::first_collision_source(
                    &self.grid,
                    &self.medium,
                    env.sun_travel,
                    env.sun_irradiance,
                )
                .map_err(solve_err)?,
            ),
            false => None,
        };
        let mut inflow = vec![[([0.0f64; 3], 0.0f64); 3]; self.shells.len()];
        let steps = self.steps();
        for (c, &boundary) in boundaries.iter().enumerate() {
            self.solve_colour(
                c,
                boundary,
                floor.as_ref(),
                source.as_ref(),
                &mut inflow,
                &mut |s| progress(c * steps + s),
            )?;
            progress((c + 1) * steps);
        }
        Ok(inflow)
    }

    /// Each instance's part weights from its inflows under the whole light of `env` (the
    /// sun's transmittance marched towards `env`'s sun through the coarse extinction).
    fn weights(&self, inflow: &[Inflow], env: &Environment, free: PartWeights) -> Vec<PartWeights> {
        let to_sun = Vec3::from_array(env.sun_travel.map(|v| -v as f32)).normalize_or_zero();
        let unit_sky = light::sky_boundaries([1.0; 3])[0];
        let top_unit: f64 = (1..Q)
            .filter(|&k| class(k) == 0)
            .map(|k| unit_sky.values[k] as f64)
            .sum();
        self.boxes
            .iter()
            .zip(inflow)
            .zip(&self.measured)
            .map(|((world, m), measured)| {
                let Some(world) = world else {
                    return free;
                };
                let fits: [(f64, f64); 3] =
                    std::array::from_fn(|c| fit_sky_ground(m[c].0, measured));
                // Through the top only downward directions enter: a unit sky's sum there.
                let top: [f32; 3] = std::array::from_fn(|c| (m[c].1 / top_unit) as f32);
                let sun = if to_sun.y > 0.0 {
                    sun_transmittance(
                        world,
                        self.dims,
                        self.origin,
                        self.cell,
                        &self.kappa,
                        to_sun,
                    )
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
            .collect()
    }
}

impl ForestLight {
    /// Lays the coarse grid over `instances` (ground at `ground_y`), resamples their fine
    /// grids into it, solves it per colour under `env` (sky and open ground on the shell, the
    /// forest-shadowed ground as its floor, the sun's first collisions as its source) and
    /// measures each instance's weights. `progress(done, total)` after every LB step (three
    /// colours of `SolveOptions::papers` steps each).
    pub fn solve(
        instances: &[ForestInstance],
        env: &Environment,
        ground_y: f32,
        opts: &GlobalGridOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<ForestLight, LightingError> {
        env.validate().map_err(LightingError::Illumination)?;
        let free = free_weights(env);
        let Some(coarse) = Coarse::new(instances, ground_y, opts)? else {
            return Ok(ForestLight::alone(instances.len(), free));
        };
        coarse.light(env, free, progress)
    }

    /// [`ForestLight::solve`], its answer read from `cache` when an entry holds it for the
    /// same coarse medium, boxes and light, else solved and cached; and what happened.
    pub fn solve_cached(
        instances: &[ForestInstance],
        env: &Environment,
        ground_y: f32,
        opts: &GlobalGridOptions,
        cache: Option<&ForestCache>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(ForestLight, GlobalReport), LightingError> {
        let t0 = Instant::now();
        env.validate().map_err(LightingError::Illumination)?;
        let free = free_weights(env);
        let Some(coarse) = Coarse::new(instances, ground_y, opts)? else {
            let alone = ForestLight::alone(instances.len(), free);
            let report = GlobalReport::computed(LIGHT_ENTRY.0, alone.dims, t0);
            return Ok((alone, report));
        };
        let key = coarse.key(ground_y, CoarseLight::environment(env));
        let n = instances.len();
        cached_or_solved(
            LIGHT_ENTRY,
            cache,
            key,
            coarse.dims,
            t0,
            |p| {
                ForestLight::from_bytes(&read_forest_entry(p, key)?, n)
                    .map_err(|e| format!("{}: {e}", p.display()))
            },
            || coarse.light(env, free, progress),
            |f, p| write_forest_entry(p, key, &f.to_bytes()),
        )
    }

    /// The answer as bytes: a cache entry's payload, and what MPI processes send.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        write_layout(&mut w, self.dims, self.origin, self.cell);
        let flat = |p: &PartWeights| [p.sun, p.sky_top, p.sky, p.ground].map(|v| v.to_array());
        w.f32s(flat(&self.free).as_flattened());
        let weights: Vec<[[f32; 3]; 4]> = self.weights.iter().map(flat).collect();
        w.f32s(weights.as_flattened().as_flattened());
        w.bytes
    }

    /// The answer [`ForestLight::to_bytes`] encoded, for `instances` instances; `Err` says
    /// what is wrong with the bytes.
    pub fn from_bytes(bytes: &[u8], instances: usize) -> Result<ForestLight, String> {
        let mut r = ByteReader::new(bytes);
        let (dims, origin, cell) = read_layout(&mut r)?;
        let free = r.f32s("free weights")?;
        let flat = r.f32s("weights")?;
        r.finish()?;
        if free.len() != 12 || flat.len() != 12 * instances {
            return Err(format!(
                "{} weights, {instances} instances need {}",
                flat.len(),
                12 * instances
            ));
        }
        if flat
            .iter()
            .chain(&free)
            .any(|v| !(v.is_finite() && *v >= 0.0))
        {
            return Err("a value is not finite or negative".into());
        }
        let weights = |c: &[f32]| {
            let v = |i: usize| Vec3::new(c[3 * i], c[3 * i + 1], c[3 * i + 2]);
            PartWeights {
                sun: v(0),
                sky_top: v(1),
                sky: v(2),
                ground: v(3),
            }
        };
        Ok(ForestLight {
            dims,
            origin,
            cell,
            weights: flat.chunks_exact(12).map(weights).collect(),
            free: weights(&free),
        })
    }

    /// No coarse grid: every instance keeps the free weights.
    fn alone(instances: usize, free: PartWeights) -> ForestLight {
        ForestLight {
            dims: Dims::new(3, 3, 3).expect("valid"),
            origin: [0.0; 3],
            cell: 1.0,
            weights: vec![free; instances],
            free,
        }
    }
}

/// The forest grid relit (issue 27, docs/relight.md): the coarse grid solved once per linear
/// part of its light, a unit sun along each of the models' sun-part directions
/// ([`crate::relight::sun_parts::sun_directions`]), a unit sky and a unit ground, and each
/// instance's measures of every part kept. [`ForestBases::light`] combines them for any sun,
/// sky and ground (the sun's parts by the barycentric weights of the hull face its direction
/// crosses, [`crate::relight::sun_parts`]) and marches the sun's transmittance: a
/// [`ForestLight`] without an LB solve. At a part's direction it is [`ForestLight::solve`]'s
/// up to rounding
/// (the coarse LB is linear; tested); between them the sun's parts are interpolated.
pub struct ForestBases {
    coarse: Option<Coarse>,
    instances: usize,
    /// Per part (the sun's directions, then sky and ground), per instance, its inflows.
    parts: Vec<Vec<Inflow>>,
    /// The ground's albedo the parts were solved with (their floors).
    ground_albedo: Option<[f64; 3]>,
}

/// The parts' measures (per part, per instance, per colour: three class inflows and the
/// top's) as bytes.
fn parts_to_bytes(parts: &[Vec<Inflow>], instances: usize) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.u32(parts.len() as u32);
    w.u32(instances as u32);
    let flat: Vec<f64> = parts
        .iter()
        .flatten()
        .flat_map(|inflow| inflow.iter().flat_map(|(m, t)| [m[0], m[1], m[2], *t]))
        .collect();
    w.f64s(&flat);
    w.bytes
}

/// [`parts_to_bytes`]'s parts for `instances` instances; `Err` says what is wrong.
fn parts_from_bytes(bytes: &[u8], instances: usize) -> Result<Vec<Vec<Inflow>>, String> {
    let mut r = ByteReader::new(bytes);
    let parts = r.u32("part count")? as usize;
    let stored = r.u32("instance count")? as usize;
    let flat = r.f64s("inflows")?;
    r.finish()?;
    let want = crate::relight::sun_parts::SUN_PARTS + 2;
    if parts != want && parts != 0 {
        return Err(format!("{parts} parts, not {want}"));
    }
    if stored != instances {
        return Err(format!("{stored} instances, the forest has {instances}"));
    }
    if flat.len() != parts * instances * 12 {
        return Err(format!(
            "{} values, {parts} parts of {instances} instances need {}",
            flat.len(),
            parts * instances * 12
        ));
    }
    if flat.iter().any(|v| !v.is_finite()) {
        return Err("a value is not finite".into());
    }
    let inflow = |c: &[f64]| -> Inflow {
        std::array::from_fn(|k| ([c[4 * k], c[4 * k + 1], c[4 * k + 2]], c[4 * k + 3]))
    };
    Ok(flat
        .chunks_exact(12 * instances.max(1))
        .map(|part| part.chunks_exact(12).map(inflow).collect())
        .collect())
}

impl ForestBases {
    /// Coarse solves: one per sun direction and colour, a unit sky's and a unit ground's.
    pub const SOLVES: usize = 3 * (crate::relight::sun_parts::SUN_PARTS + 2);

    /// Solves the parts over `instances` with the ground's albedo `ground_albedo` (`None`:
    /// no ground). `progress(done, total)` after every LB step.
    pub fn solve(
        instances: &[ForestInstance],
        ground_albedo: Option<[f64; 3]>,
        ground_y: f32,
        opts: &GlobalGridOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<ForestBases, LightingError> {
        let coarse = Coarse::new(instances, ground_y, opts)?;
        let parts = match &coarse {
            Some(coarse) => Self::solve_parts(coarse, ground_albedo, progress)?,
            None => Vec::new(),
        };
        Ok(ForestBases {
            coarse,
            instances: instances.len(),
            parts,
            ground_albedo,
        })
    }

    /// The coarse solves of every part over `coarse`: per part, per instance, its inflows.
    fn solve_parts(
        coarse: &Coarse,
        ground_albedo: Option<[f64; 3]>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<Vec<Inflow>>, LightingError> {
        let zero = [sylva_lb::Boundary { values: [0.0; Q] }; 3];
        let sky = Environment {
            sun_travel: [0.0, -1.0, 0.0],
            sun_irradiance: [0.0; 3],
            sky_radiance: [1.0; 3],
            ground_albedo,
        };
        // The lights: a unit sun along each direction, a unit sky, a unit ground.
        let mut lights: Vec<(Environment, [sylva_lb::Boundary; 3], bool, bool)> =
            crate::relight::sun_parts::sun_directions()
                .iter()
                .map(|&d| {
                    let env = Environment {
                        sun_travel: d,
                        sun_irradiance: [1.0; 3],
                        sky_radiance: [0.0; 3],
                        ground_albedo,
                    };
                    (env, zero, true, true)
                })
                .collect();
        lights.push((sky, light::sky_boundaries([1.0; 3]), true, false));
        lights.push((sky, light::ground_boundaries([1.0; 3]), false, false));
        // Progress after every LB step over all of them.
        let per_light = 3 * coarse.steps();
        let total = lights.len() * per_light;
        let mut parts = Vec::with_capacity(lights.len());
        for (k, (env, boundaries, floor, sun)) in lights.into_iter().enumerate() {
            parts.push(coarse.solve(&env, boundaries, floor, sun, &mut |done| {
                progress(k * per_light + done, total)
            })?);
        }
        Ok(parts)
    }

    /// [`ForestBases::solve`], the parts read from `cache` when an entry holds them for the
    /// same coarse medium, boxes, directions and ground, else solved and cached; and what
    /// happened.
    pub fn solve_cached(
        instances: &[ForestInstance],
        ground_albedo: Option<[f64; 3]>,
        ground_y: f32,
        opts: &GlobalGridOptions,
        cache: Option<&ForestCache>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(ForestBases, GlobalReport), LightingError> {
        let t0 = Instant::now();
        let Some(coarse) = Coarse::new(instances, ground_y, opts)? else {
            let none = Dims::new(3, 3, 3).expect("valid");
            let report = GlobalReport::computed(PARTS_ENTRY.0, none, t0);
            return Ok((
                ForestBases::without_grid(instances.len(), ground_albedo),
                report,
            ));
        };
        let key = coarse.key(
            ground_y,
            CoarseLight::Parts {
                suns: crate::relight::sun_parts::sun_directions().to_vec(),
                ground_albedo,
            },
        );
        let n = instances.len();
        let (parts, report) = cached_or_solved(
            PARTS_ENTRY,
            cache,
            key,
            coarse.dims,
            t0,
            |p| {
                parts_from_bytes(&read_forest_entry(p, key)?, n)
                    .map_err(|e| format!("{}: {e}", p.display()))
            },
            || Self::solve_parts(&coarse, ground_albedo, progress),
            |parts, p| write_forest_entry(p, key, &parts_to_bytes(parts, n)),
        )?;
        Ok((
            ForestBases {
                coarse: Some(coarse),
                instances: n,
                parts,
                ground_albedo,
            },
            report,
        ))
    }

    /// No coarse grid: every instance keeps the free weights.
    fn without_grid(instances: usize, ground_albedo: Option<[f64; 3]>) -> ForestBases {
        ForestBases {
            coarse: None,
            instances,
            parts: Vec::new(),
            ground_albedo,
        }
    }

    /// The parts' measures as bytes: what MPI processes send ([`ForestBases::with_parts`]).
    pub fn parts_bytes(&self) -> Vec<u8> {
        parts_to_bytes(&self.parts, self.instances)
    }

    /// The parts over `instances` (as [`ForestBases::solve`] was given them) from
    /// [`ForestBases::parts_bytes`]: the coarse grid laid out again, its solves not run.
    pub fn with_parts(
        instances: &[ForestInstance],
        ground_albedo: Option<[f64; 3]>,
        ground_y: f32,
        opts: &GlobalGridOptions,
        bytes: &[u8],
    ) -> Result<ForestBases, LightingError> {
        let coarse = Coarse::new(instances, ground_y, opts)?;
        let parts = parts_from_bytes(bytes, instances.len())
            .map_err(|e| LightingError::Global(format!("the forest grid's parts: {e}")))?;
        if coarse.is_some() == parts.is_empty() {
            return Err(LightingError::Global(
                "the forest grid's parts do not match its instances".into(),
            ));
        }
        Ok(ForestBases {
            coarse,
            instances: instances.len(),
            parts,
            ground_albedo,
        })
    }

    /// The forest's light under `env` (its ground albedo must be the one solved with): each
    /// instance's weights, no LB solve. The sun's parts are weighted by the barycentric
    /// weights of the hull face its direction crosses; a sun below the horizon lights
    /// nothing.
    pub fn light(&self, env: &Environment) -> Result<ForestLight, LightingError> {
        env.validate().map_err(LightingError::Illumination)?;
        if env.ground_albedo != self.ground_albedo {
            return Err(LightingError::Global(format!(
                "the forest's parts were solved over a ground of albedo {:?}, not {:?}",
                self.ground_albedo, env.ground_albedo
            )));
        }
        let free = free_weights(env);
        let Some(coarse) = &self.coarse else {
            return Ok(ForestLight::alone(self.instances, free));
        };
        let sun = crate::relight::sun_parts::sun_part_weights(env.sun_travel)?;
        let (sky, ground) = (env.sky_radiance, env.ground_radiance());
        let n = crate::relight::sun_parts::SUN_PARTS;
        let inflow: Vec<Inflow> = (0..self.instances)
            .map(|i| {
                std::array::from_fn(|c| {
                    let mut m = [0.0f64; 3];
                    let mut t = 0.0f64;
                    let mut add = |part: &Inflow, w: f64| {
                        for (m, v) in m.iter_mut().zip(part[c].0) {
                            *m += w * v;
                        }
                        t += w * part[c].1;
                    };
                    for &(k, w) in &sun {
                        add(&self.parts[k][i], w * env.sun_irradiance[c]);
                    }
                    add(&self.parts[n][i], sky[c]);
                    add(&self.parts[n + 1][i], ground[c]);
                    (m, t)
                })
            })
            .collect();
        Ok(ForestLight {
            dims: coarse.dims,
            origin: coarse.origin.to_array(),
            cell: coarse.cell,
            weights: coarse.weights(&inflow, env, free),
            free,
        })
    }
}

impl ForestLight {
    /// What the forest grid did, for a front end to show: per part (sun, sky through the
    /// top, through the sides, ground) the range over the instances of its weight's
    /// luminance over its value in the open; with `per_instance`, a line per instance too.
    pub fn summary(&self, per_instance: bool) -> String {
        let y = |v: Vec3| sylva_core::colour::luminance(v.to_array());
        let range = |part: fn(&PartWeights) -> Vec3| {
            let free = y(part(&self.free));
            let (lo, hi) = self
                .weights
                .iter()
                .map(|w| if free > 0.0 { y(part(w)) / free } else { 1.0 })
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
                    (a.min(v), b.max(v))
                });
            format!("{lo:.2}–{hi:.2}")
        };
        let mut lines = vec![format!(
            "forest grid {}: per instance, of the open's: sun {}, sky through the top {}, \
             through the sides {}, ground {}",
            self.dims,
            range(|w| w.sun),
            range(|w| w.sky_top),
            range(|w| w.sky),
            range(|w| w.ground)
        )];
        if per_instance {
            let free = &self.free;
            for (i, w) in self.weights.iter().enumerate() {
                lines.push(format!(
                    "  instance {i}: sun {:.3} sky top {:.3} sides {:.3} ground {:.3}",
                    y(w.sun),
                    y(w.sky_top) / y(free.sky_top).max(f32::MIN_POSITIVE),
                    y(w.sky) / y(free.sky).max(f32::MIN_POSITIVE),
                    y(w.ground) / y(free.ground).max(f32::MIN_POSITIVE)
                ));
            }
        }
        lines.join("\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_core::cache::assert_each_field_changes_the_key;

    #[test]
    fn shade_key_changes_with_every_field() {
        let base = ShadeKey {
            samples: [3, 4, 5],
            depths: vec![[0.5, 0.25]; 60],
        };
        let mut leaves = base.clone();
        leaves.depths[59][0] = 0.5001;
        let mut wood = base.clone();
        wood.depths[0][1] = 0.0;
        assert_each_field_changes_the_key(
            NEIGHBOUR_SHADE,
            &base,
            &[
                (
                    "samples",
                    ShadeKey {
                        samples: [3, 5, 4],
                        ..base.clone()
                    },
                ),
                ("depths: leaves", leaves),
                ("depths: wood", wood),
                (
                    "depths: count",
                    ShadeKey {
                        depths: vec![[0.5, 0.25]; 59],
                        ..base.clone()
                    },
                ),
            ],
        );
    }
    use sylva_lb::Bounds;

    /// Issue 31 item 3: a mix whose σ_t rounding put at 1 + 1.1e-12 (what a dense forest of
    /// 100 000 dogroses gave) is a valid medium; an excess rounding cannot make is not hidden.
    #[test]
    fn mixed_media_are_valid_within_rounding() {
        let (s, a): (f64, f64) = (0.897_000_000_001_1, 0.103);
        assert!((s + a - 1.0 - 1.1e-12).abs() < 1e-15);
        assert!(
            ColourParams::new(a, s, 0.0).is_err(),
            "the raw mean is refused"
        );
        let c = mean_colour(s, a, 0.5);
        c.validate("").unwrap();
        assert!(c.sigma_t() <= 1.0 + f64::EPSILON, "{}", c.sigma_t());
        assert!((c.sigma_s - s).abs() < 1e-11 && (c.sigma_a - a).abs() < 1e-11);
        // A g or σ just past its bound by rounding.
        let c = mean_colour(1.0 + 1e-13, -1e-13, -1.0 - 1e-13);
        assert_eq!((c.sigma_s, c.sigma_a, c.g), (1.0, 0.0, -1.0));
        c.validate("").unwrap();
        // Valid means pass through unchanged.
        assert_eq!(
            mean_colour(0.7, 0.2, 0.3),
            ColourParams {
                sigma_s: 0.7,
                sigma_a: 0.2,
                g: 0.3
            }
        );
        // Not rounding: left for the check to refuse.
        assert!(mean_colour(0.9, 0.2, 0.0).validate("").is_err());
    }

    /// A cube of uniform density `rho` over `[-1, 1]³` (shell empty), `n` sites per axis.
    fn cube(n: usize, rho: f32) -> DensityGrid {
        let dims = Dims::new(n, n, n).unwrap();
        let density = (0..dims.sites())
            .map(|i| {
                let (x, y, z) = dims.coords(i);
                if dims.on_shell(x, y, z) {
                    0.0
                } else {
                    rho
                }
            })
            .collect();
        DensityGrid {
            dims,
            bounds: Bounds {
                min: [-1.0; 3],
                max: [1.0; 3],
            },
            density,
            wood: vec![0.0; dims.sites()],
        }
    }

    fn depth(rho: f32) -> f64 {
        -(1.0 - rho as f64).ln()
    }

    #[test]
    fn neighbour_shade_adds_the_overlapping_crown_and_nothing_elsewhere() {
        let (a, b) = (cube(24, 0.2), cube(24, 0.2));
        let opts = GlobalGridOptions { sites: 40 };
        let at = |x: f32| Affine3A::from_translation(Vec3::new(x, 1.0, 0.0));
        // B overlaps A's +x half.
        let shades = neighbour_shade(&[&a, &b], &[(0, at(0.0)), (1, at(1.0))], 0.0, &opts).unwrap();
        let s = shades[0].as_ref().expect("A's box holds B's foliage");
        let d = a.dims;
        let site = |x: usize| d.index(x, 12, 12);
        // Model x = -1 + 2 i / 23: site 17 is at 0.48 (0.5 inside B's box, which starts at
        // -0.04), site 3 at -0.74 (0.7 outside it, several coarse cells).
        let added = |i: usize| depth(s.density.density[i]) - depth(a.density[i]);
        let inside = added(site(17));
        assert!(
            (inside / depth(0.2) - 1.0).abs() < 0.1,
            "inside B: added {inside}, B's own {}",
            depth(0.2)
        );
        assert_eq!(s.density.density[site(3)], a.density[site(3)], "far from B");
        assert!(s.added_depth > 0.2 * s.own_depth && s.added_depth < 0.8 * s.own_depth);
        // B gets A's the same way (mirror image).
        let t = shades[1].as_ref().unwrap();
        assert_eq!(
            t.density.density[d.index(23 - 17, 12, 12)],
            s.density.density[site(17)]
        );
        assert!(s.density.wood.iter().all(|&w| w == 0.0));
        // Deterministic, and its key follows the added foliage.
        let again = neighbour_shade(&[&a, &b], &[(0, at(0.0)), (1, at(1.0))], 0.0, &opts).unwrap();
        assert_eq!(again[0].as_ref().unwrap().key, s.key);
        let nearer = neighbour_shade(&[&a, &b], &[(0, at(0.0)), (1, at(0.8))], 0.0, &opts).unwrap();
        assert_ne!(nearer[0].as_ref().unwrap().key, s.key);
    }

    /// The neighbours' foliage is cached: read back as measured, keyed by the densities'
    /// keys and the placements, and a damaged entry is measured again with a warning naming
    /// the file.
    #[test]
    fn the_neighbours_foliage_is_cached_as_measured() {
        let (a, b) = (cube(24, 0.2), cube(24, 0.2));
        let opts = GlobalGridOptions { sites: 40 };
        let at = |x: f32| Affine3A::from_translation(Vec3::new(x, 1.0, 0.0));
        let placed = [(0, at(0.0)), (1, at(1.0))];
        let keys = [CacheKey::from_value(1), CacheKey::from_value(2)];
        let dir = tempfile::tempdir().unwrap();
        let at_cache = ForestCache::new(dir.path(), "pair");
        let want = neighbour_shade(&[&a, &b], &placed, 0.0, &opts).unwrap();
        let same = |got: &[Option<ShadedDensity>]| {
            got.len() == want.len()
                && got.iter().zip(&want).all(|(g, w)| match (g, w) {
                    (Some(g), Some(w)) => {
                        g.density == w.density
                            && g.key == w.key
                            && (g.own_depth, g.added_depth) == (w.own_depth, w.added_depth)
                    }
                    (None, None) => true,
                    _ => false,
                })
        };
        let cached = |keys: &[CacheKey]| {
            neighbour_shade_cached(&[&a, &b], keys, &placed, 0.0, &opts, Some(&at_cache)).unwrap()
        };
        let entries = || std::fs::read_dir(dir.path()).unwrap().count();
        for _ in 0..2 {
            let (got, warning) = cached(&keys);
            assert!(same(&got) && warning.is_none(), "{warning:?}");
            assert_eq!(entries(), 1);
        }
        // Another density (its key): another entry.
        let (got, _) = cached(&[keys[0], CacheKey::from_value(3)]);
        assert!(same(&got));
        assert_eq!(entries(), 2);
        // A damaged entry (the only one in its cache): measured again, named, replaced.
        let dir = tempfile::tempdir().unwrap();
        let one = ForestCache::new(dir.path(), "pair");
        let measure =
            || neighbour_shade_cached(&[&a, &b], &keys, &placed, 0.0, &opts, Some(&one)).unwrap();
        assert!(measure().1.is_none());
        let path = std::fs::read_dir(dir.path())
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path();
        let good = std::fs::read(&path).unwrap();
        for bad in [&good[..good.len() - 9], &b"garbage"[..]] {
            std::fs::write(&path, bad).unwrap();
            let (got, warning) = measure();
            let w = warning.expect("a warning");
            assert!(
                w.contains(&path.display().to_string()) && w.ends_with("measured again"),
                "{w}"
            );
            assert!(same(&got));
            assert_eq!(std::fs::read(&path).unwrap(), good, "replaced");
        }
    }

    #[test]
    fn apart_or_alone_no_shade_is_added() {
        let (a, b) = (cube(16, 0.3), cube(16, 0.3));
        let opts = GlobalGridOptions { sites: 32 };
        let at = |x: f32| Affine3A::from_translation(Vec3::new(x, 1.0, 0.0));
        let apart = neighbour_shade(&[&a, &b], &[(0, at(0.0)), (1, at(3.0))], 0.0, &opts).unwrap();
        assert!(apart.iter().all(Option::is_none));
        let alone = neighbour_shade(&[&a], &[(0, at(0.0))], 0.0, &opts).unwrap();
        assert!(alone[0].is_none());
        // A model without instances, and one whose instances stand apart.
        let unused = neighbour_shade(&[&a, &b], &[(0, at(0.0)), (0, at(5.0))], 0.0, &opts).unwrap();
        assert!(unused.iter().all(Option::is_none));
    }

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
