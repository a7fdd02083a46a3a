//! Per-model LB lighting (000 §4.2-4.3, SPEC §2, docs/light.md): voxelize a model, light it
//! with the lattice-Boltzmann solver, and look the result up trilinearly in model space.
//!
//! Two light models ([`Light`]):
//!
//! * **Physical** (the default, docs/light.md). The medium comes from the model itself: per
//!   site the probability that light crossing it meets a leaf or bark (from their area,
//!   [`sylva_voxel::plant_area`]), and per colour the leaves' and bark's albedo and asymmetry
//!   from their [`sylva_geom::Optics`] ([`plant_medium`]). The boundary holds the sun, the sky
//!   and the open ground's light ([`sylva_lb::light::Environment`]), and the sun's uncollided
//!   part ([`sylva_lb::light::uncollided`]) is subtracted: the renderer traces direct sunlight
//!   exactly, so the grid holds what it cannot trace, the scattered sunlight plus the sky's and
//!   ground's light, as an LB value (fluence in units of the unit sun's irradiance `E0 = π`).
//!   Everything is linear in the sun, sky and ground. A model with a solid material (a
//!   scattering object such as the PMMA teapot) takes its medium from its LB preset instead,
//!   on the sub-cell occupancy.
//! * **Paper** (000). The scene's LB preset, sub-cell occupancy, a sun-only boundary, and the
//!   total divided by the free-space total `Σ_i max(0, n_i·d)`, so unobstructed sunlight is 1.
//!
//! * **Placement.** Site `(i, j, k)` sits at `bounds.min + (i, j, k) · cell` with
//!   `cell = (bounds.max - bounds.min) / (dims - 1)` per axis ([`sylva_lb::Bounds`] is the span
//!   of site centres). Points outside the grid clamp to the nearest site.
//! * **Cache.** With a cache directory, the grid is stored as `<model>-<key>.sgrid` (a
//!   lighting [`GridFile`], f32, CRC-checked, `sylva lb info` reads it): the physical light as
//!   it is used, the paper's raw solver result. The key ([`sylva_core::cache::CacheKey`]) is
//!   derived from one struct of everything the result depends on (see [`cache_key`]) and is
//!   stored in the file's metadata too. An entry that cannot be read, or whose key, dimensions
//!   or bounds are not the expected ones, is recomputed and replaced atomically;
//!   [`LightingSource::Recomputed`] says why. An entry that cannot be written is a warning
//!   ([`LightingReport::cache_warning`]), not an error: the light was solved and is good.
//! * **Sun.** The direction is rounded to 1e-5 per component (then renormalised) before it is
//!   hashed *and* before it is solved with, so a cache entry is a function of its key alone.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
pub use glam::Vec3;
use serde::Serialize;
use sylva_core::cache::{Cache, CacheKey, CacheKind, CacheOutcome, Lookup};
use sylva_core::colour::luminance;
use sylva_geom::{is_opaque, Aabb, LbSettings, MaterialKind, Model, Scene, Wrap, OPAQUE_ALPHA};
use sylva_lb::light::{self, Environment, PlantOptics};
use sylva_lb::relight::{Footprint, Placement};
use sylva_lb::solver::{memory_needed, Boundary, Floor, SolveOptions, VolumeSource};
use sylva_lb::{
    Bounds, DensityGrid, Dims, Element, GridFile, GridKind, LightingGrid, MediumParams, ParamError,
    Preset,
};
use sylva_lb::{LbSolver, LbSolverError};
use sylva_voxel::{
    placement_for, voxelize, GridPlacement, Occupancy, VoxelizeError, VoxelizeOptions,
    DEFAULT_GRID, SUB,
};
use thiserror::Error;

use crate::device::{Packer, LIGHT_OPEN, LIGHT_PARTS, NONE};

/// Bump whenever the solver, the voxelizer or this module changes what a cache entry holds.
/// 2: the solver backend's [`LbSolver::cache_tag`] is part of the key.
/// 3: the physical light (docs/light.md): plant medium, sky and ground, uncollided sun removed.
/// 4: keys derived from serialized key structs ([`sylva_core::cache`]); grid files in the
/// checked container.
pub const CACHE_VERSION: u32 = 4;
/// Extension of cache entries.
pub const CACHE_EXTENSION: &str = "sgrid";
pub use sylva_core::cache::KEY_METADATA;
/// A model's lighting grid ([`cache_key`]).
pub const MODEL_LIGHTING: CacheKind = CacheKind {
    name: "model lighting",
    version: CACHE_VERSION,
};
/// One part of a model's physical light ([`PartsPlan`]).
pub const LIGHT_PART: CacheKind = CacheKind {
    name: "physical light part",
    version: CACHE_VERSION,
};
/// A model's voxelized density ([`LightingPlan::density`]): keyed by what the medium key
/// holds of the mesh, its leaves' opacity, the occupancy rule and the grid.
pub const MODEL_DENSITY: CacheKind = CacheKind {
    name: "model density",
    version: CACHE_VERSION,
};
/// Sun direction components are rounded to multiples of this.
pub const SUN_QUANTUM: f64 = 1e-5;

#[derive(Debug, Error)]
pub enum LightingError {
    #[error("LB preset: {0}")]
    Params(#[from] ParamError),
    #[error("model '{model}': its materials give no valid LB medium: {source}")]
    Medium { model: String, source: ParamError },
    #[error("sun direction ({}, {}, {}) must be a finite, non-zero vector", .0[0], .0[1], .0[2])]
    Sun([f32; 3]),
    #[error("light around the plants: {0}")]
    Illumination(String),
    #[error(transparent)]
    Voxelize(#[from] VoxelizeError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("LB lighting of model '{model}': {source}")]
    Solve {
        model: String,
        source: LbSolverError,
    },
    #[error("LB lighting of medium '{medium}': {source}")]
    SolveMedium {
        medium: String,
        source: LbSolverError,
    },
    /// A participating medium (cloud) whose grid cannot be lit (its dimensions).
    #[error("{0}")]
    MediumGrid(String),
    #[error(transparent)]
    Relight(#[from] sylva_lb::relight::RelightError),
    #[error("global grid: {0}")]
    Global(String),
}

/// Which light model plants are lit with (docs/light.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Light {
    /// One physical material model for the renderer, the LB and the export: exact direct
    /// sun plus the LB's scattered, sky and ground light, no scale factor.
    #[default]
    Physical,
    /// Paper 000's: the preset's medium lit by the sun alone, its total light (sunlight not
    /// yet scattered included) scaled by `--indirect` (0.5 in the papers' images here).
    Paper,
}

impl Light {
    pub const ALL: [Light; 2] = [Light::Physical, Light::Paper];

    pub fn name(self) -> &'static str {
        match self {
            Light::Physical => "physical",
            Light::Paper => "paper",
        }
    }

    pub fn parse(s: &str) -> Option<Light> {
        Light::ALL
            .into_iter()
            .find(|l| l.name().eq_ignore_ascii_case(s.trim()))
    }
}

/// How models are lit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LightingOptions {
    /// Sites along each model's longest edge, shell included (scene `[lb] grid`).
    pub grid: usize,
    /// The light model.
    pub light: Light,
    /// LB preset name (scene `[lb] preset`): the paper model's medium.
    pub preset: String,
    /// Where lighting grids are cached; `None`: always compute, write nothing.
    pub cache_dir: Option<PathBuf>,
}

impl Default for LightingOptions {
    fn default() -> Self {
        LightingOptions {
            grid: DEFAULT_GRID,
            light: Light::Physical,
            preset: "leaf".into(),
            cache_dir: None,
        }
    }
}

impl LightingOptions {
    /// The options a scene's `[lb]` table asks for.
    pub fn from_scene(lb: &LbSettings, light: Light, cache_dir: Option<PathBuf>) -> Self {
        LightingOptions {
            grid: lb.grid as usize,
            light,
            preset: lb.preset.clone(),
            cache_dir,
        }
    }

    /// These options for model `k` of `scene`: its own LB preset ([`Scene::model_preset`]).
    pub fn for_model(&self, scene: &Scene, k: usize) -> LightingOptions {
        LightingOptions {
            preset: scene.model_preset(k).to_string(),
            ..self.clone()
        }
    }
}

/// The light around a model, in its own frame: the sun, the sky and the ground (linear RGB).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Illumination {
    /// Towards the sun; need not be unit length.
    pub sun_to: Vec3,
    /// The sun's irradiance on a surface facing it, per colour, in units of `E0` (its
    /// colour times its intensity).
    pub sun: Vec3,
    /// The sky's radiance.
    pub sky: Vec3,
    /// The ground's albedo; `None`: no ground (the sky all round).
    pub ground: Option<Vec3>,
}

impl Illumination {
    /// A white unit sun towards `sun_to`, no sky, a black ground: all the paper model uses.
    pub fn sun_only(sun_to: Vec3) -> Illumination {
        Illumination {
            sun_to,
            sun: Vec3::ONE,
            sky: Vec3::ZERO,
            ground: Some(Vec3::ZERO),
        }
    }

    /// As [`Environment`], with the sun towards the unit vector `sun_to`.
    fn environment(&self, sun_to: DVec3) -> Environment {
        let d = |v: Vec3| v.as_dvec3().to_array();
        Environment {
            sun_travel: (-sun_to).to_array(),
            sun_irradiance: d(self.sun),
            sky_radiance: d(self.sky),
            ground_albedo: self.ground.map(d),
        }
    }
}

/// The physical light's free-field values per colour, what the ground lookup measures
/// against: the LB value of the open sky's light (`2 L_sky`), and what the bottom shell
/// holds besides its floor's emission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct OpenField {
    pub(crate) sky: Vec3,
    pub(crate) bottom: Vec3,
}

/// The free field of the physical light under `env`: the LB value of the open sky's light,
/// and the bottom shell's on its directions other than upward (the diffuse boundary).
pub(crate) fn open_field(env: &Environment) -> OpenField {
    let total = |b: &[Boundary; 3], keep: &dyn Fn(usize) -> bool| {
        Vec3::from_array(std::array::from_fn(|c| {
            (1..sylva_lb::lattice::Q)
                .filter(|&m| keep(m))
                .map(|m| b[c].values[m] as f64)
                .sum::<f64>() as f32
        }))
    };
    let up = |m: usize| sylva_lb::lattice::C[m][1] == 1;
    OpenField {
        sky: total(&light::sky_boundaries(env.sky_radiance), &|_| true),
        bottom: total(&env.diffuse_boundaries(), &|m| !up(m)),
    }
}

/// [`ModelLighting::ground_sky`] of the physical light from its values at the floor and at
/// the lowest interior layer above a ground point.
pub(crate) fn physical_ground_sky(floor: Vec3, lowest: Vec3, open: &OpenField) -> Vec3 {
    let ground = (floor - open.bottom).max(Vec3::ZERO);
    let sky = open.sky * 0.5;
    Vec3::select(
        sky.cmpgt(Vec3::ZERO),
        ((lowest - 2.0 * ground) * 0.5 / sky.max(Vec3::splat(f32::MIN_POSITIVE)))
            .clamp(Vec3::ZERO, Vec3::ONE),
        Vec3::ONE,
    )
}

/// One model's LB light with its placement in model space: the physical light's scattered,
/// sky and ground light in LB units (fluence / `E0`), or the paper's light normalised so that
/// unobstructed sunlight (free space) is 1.0 per colour. The placement is the relighting
/// bases' [`Placement`] and [`Footprint`]: one definition of where a grid sits and which
/// sites a lookup reads.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelLighting {
    dims: Dims,
    placement: Placement,
    /// RGB per site, site order `(x * ny + y) * nz + z`.
    values: Vec<[f32; 3]>,
    /// The physical light's free field; `None` for the paper's.
    open: Option<OpenField>,
    /// The physical light split into its parts ([`LightParts`]), when it was solved so.
    parts: Option<LightParts>,
}

/// Weights of a physical grid's four parts ([`LightParts`]), per colour: the sun part's
/// factor (1 for the sun it was solved for), and the radiance of the sky-like light arriving
/// through the grid's top face and through its sides (both the sky's `L_sky` in the open),
/// and of the ground-like light arriving through its sides (the open ground's `L_g`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PartWeights {
    pub sun: Vec3,
    pub sky_top: Vec3,
    pub sky: Vec3,
    pub ground: Vec3,
}

/// A physical grid as four linear parts (docs/light.md, "Forests"), per site and colour:
/// the sun's (its first-collision source and the sunlit floor, for the sun solved for), the
/// response to a unit sky entering through the top face, to a unit sky entering through the
/// side faces (with the floor's sky part), and to a unit ground (the side faces' upward
/// directions, radiance 1; the floor dark). Under [`LightParts::free`] they sum to the
/// model's physical light in the open.
#[derive(Debug, Clone, PartialEq)]
pub struct LightParts {
    /// Per site: sun, unit sky through the top, unit sky through the sides, unit ground;
    /// RGB each.
    values: Vec<[[f32; 3]; 4]>,
    /// The weights that give the light of the model standing alone: sun 1, the scene's sky
    /// radiance and its open ground's.
    pub free: PartWeights,
}

impl LightParts {
    /// `w.sun ⊙ S + w.sky_top ⊙ D_top + w.sky ⊙ D_side + w.ground ⊙ G` of one site's parts.
    #[inline]
    pub fn combine(v: &[[f32; 3]; 4], w: &PartWeights) -> Vec3 {
        Vec3::from_array(v[0]) * w.sun
            + Vec3::from_array(v[1]) * w.sky_top
            + Vec3::from_array(v[2]) * w.sky
            + Vec3::from_array(v[3]) * w.ground
    }
}

impl ModelLighting {
    /// Normalises a paper-model solver result lit by a sun in direction `sun_to` (towards the
    /// sun; it is normalised here). A zero or non-finite `sun_to` leaves the values as they
    /// are.
    pub fn from_grid(grid: &LightingGrid, sun_to: Vec3) -> ModelLighting {
        let scale = free_space_total(sun_to.as_dvec3())
            .filter(|&t| t > 0.0)
            .map_or(1.0, |t| 1.0 / t);
        Self::scaled(grid, scale)
    }

    /// A paper-light grid whose values are already normalised (a relit combination).
    pub fn from_normalised(grid: &LightingGrid) -> ModelLighting {
        Self::scaled(grid, 1.0)
    }

    fn scaled(grid: &LightingGrid, scale: f64) -> ModelLighting {
        let [r, g, b] = &grid.colours;
        let values = r
            .iter()
            .zip(g)
            .zip(b)
            .map(|((&r, &g), &b)| [r, g, b].map(|v| (v as f64 * scale) as f32))
            .collect();
        ModelLighting {
            dims: grid.dims,
            placement: Placement::new(grid.dims, grid.bounds),
            values,
            open: None,
            parts: None,
        }
    }

    /// A physical grid from its four parts ([`LightParts`]: sun, unit sky through the top,
    /// unit sky through the sides, unit ground), lit by `env`: the values are the parts under
    /// the free weights.
    pub(crate) fn physical_parts(parts: [&LightingGrid; 4], env: &Environment) -> ModelLighting {
        let f = |v: [f64; 3]| Vec3::from_array(v.map(|x| x as f32));
        let free = PartWeights {
            sun: Vec3::ONE,
            sky_top: f(env.sky_radiance),
            sky: f(env.sky_radiance),
            ground: f(env.ground_radiance()),
        };
        let values: Vec<[[f32; 3]; 4]> = (0..parts[0].dims.sites())
            .map(|i| std::array::from_fn(|k| std::array::from_fn(|c| parts[k].colours[c][i])))
            .collect();
        let total = LightingGrid {
            dims: parts[0].dims,
            bounds: parts[0].bounds,
            colours: std::array::from_fn(|c| {
                values
                    .iter()
                    .map(|v| LightParts::combine(v, &free)[c])
                    .collect()
            }),
        };
        ModelLighting {
            parts: Some(LightParts { values, free }),
            ..Self::physical(&total, env)
        }
    }

    /// The four parts when the grid was solved so ([`model_lighting_parts`]).
    pub fn parts(&self) -> Option<&LightParts> {
        self.parts.as_ref()
    }

    /// The light at model-space point `p` under part weights `w` (trilinear, as
    /// [`ModelLighting::sample`]); the plain sample when the grid has no parts.
    #[inline]
    pub fn sample_weighted(&self, p: Vec3, w: &PartWeights) -> Vec3 {
        let Some(parts) = &self.parts else {
            return self.sample(p);
        };
        let fp = Footprint::at(self.dims, self.placement.grid_coords(p.to_array()));
        let (sites, wt) = (fp.sites(self.dims), fp.weights());
        let mut out = Vec3::ZERO;
        for k in 0..8 {
            out += LightParts::combine(&parts.values[sites[k]], w) * wt[k];
        }
        out
    }

    /// A physical-light grid as stored (LB units), lit by `env`.
    fn physical(grid: &LightingGrid, env: &Environment) -> ModelLighting {
        ModelLighting {
            open: Some(open_field(env)),
            ..Self::scaled(grid, 1.0)
        }
    }

    /// Whether this is the physical light (LB units, direct sun removed).
    pub fn is_physical(&self) -> bool {
        self.open.is_some()
    }

    /// The fraction of the open sky's light that reaches the ground at model-space point `p`
    /// (its `y` taken as the ground's), per colour in [0, 1].
    ///
    /// Physical light: the bottom shell's value is the floor's emission `L_g` (the ground's
    /// radiance there) plus a constant; at the lowest interior sites the ground's light is
    /// about `2 L_g` (from below, and its share of the horizontal directions), so the rest,
    /// `u - 2 L_g`, is the light from above (sky, scattered sunlight), whose half is the
    /// ground's irradiance in units of `E0`; divided by the open sky's (`L_sky`). Paper
    /// light: the luminance of the normalised light (1 in the open, less in a crown's shade).
    pub fn ground_sky(&self, p: Vec3) -> Vec3 {
        match &self.open {
            None => Vec3::splat(luminance(self.sample(p).to_array()).clamp(0.0, 1.0)),
            Some(open) => {
                let origin = Vec3::from_array(self.placement.origin());
                let floor = self.sample(Vec3::new(p.x, origin.y, p.z));
                let lowest = self.sample(Vec3::new(p.x, origin.y + self.cell().y, p.z));
                physical_ground_sky(floor, lowest, open)
            }
        }
    }

    /// Cell edge per axis (0 along a degenerate axis).
    fn cell(&self) -> Vec3 {
        let inv_cell = Vec3::from_array(self.placement.inv_cell());
        Vec3::select(inv_cell.cmpgt(Vec3::ZERO), inv_cell.recip(), Vec3::ZERO)
    }

    /// Trilinear interpolation of the RGB light at model-space point `p`; points
    /// outside the grid clamp to the nearest site.
    #[inline]
    pub fn sample(&self, p: Vec3) -> Vec3 {
        let fp = Footprint::at(self.dims, self.placement.grid_coords(p.to_array()));
        let (sites, w) = (fp.sites(self.dims), fp.weights());
        let mut out = Vec3::ZERO;
        for k in 0..8 {
            out += Vec3::from_array(self.values[sites[k]]) * w[k];
        }
        out
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    /// Bytes held (the values and the struct).
    pub fn memory_bytes(&self) -> u64 {
        let parts = self.parts.as_ref().map_or(0, |p| {
            p.values.capacity() * std::mem::size_of::<[[f32; 3]; 4]>()
        });
        (self.values.capacity() * std::mem::size_of::<[f32; 3]>()
            + parts
            + std::mem::size_of::<Self>()) as u64
    }

    /// Appends this grid's record as shade.wgsl reads it ([`crate::device`]): the header
    /// (its free field when physical), the RGB values per site (site order
    /// `(x * ny + y) * nz + z`), then, when the forest grid weighs the instances' parts
    /// (`weights_at`: where their weights are, [`NONE`]: not weighed), the four parts' RGB per
    /// site (shade.wgsl: `parts_sample`). `bounds`: the model's. Returns where it starts.
    pub(crate) fn pack(&self, p: &mut Packer, bounds: Aabb, weights_at: u32) -> u32 {
        // The header's last 9 words (from LIGHT_OPEN): the free field (1, open sky, open
        // bottom), then where the parts and the instances' weights are.
        let mut extra = [0u32; 9];
        if let Some(open) = self.open {
            extra[0] = 1;
            extra[1..4].copy_from_slice(&open.sky.to_array().map(f32::to_bits));
            extra[4..7].copy_from_slice(&open.bottom.to_array().map(f32::to_bits));
        }
        extra[LIGHT_PARTS - LIGHT_OPEN] = NONE;
        let start = p.light_header(
            self.dims,
            (
                Vec3::from_array(self.placement.origin()),
                Vec3::from_array(self.placement.inv_cell()),
            ),
            bounds,
            extra,
        );
        p.words
            .extend(self.values.iter().flatten().map(|v| v.to_bits()));
        if let (Some(parts), true) = (&self.parts, weights_at != NONE) {
            let at = p.at();
            p.set(start + LIGHT_PARTS as u32, at);
            p.set(start + LIGHT_PARTS as u32 + 1, weights_at);
            p.words
                .extend(parts.values.iter().flatten().flatten().map(|v| v.to_bits()));
        }
        start
    }

    /// The light at site `(x, y, z)`.
    pub fn site(&self, x: usize, y: usize, z: usize) -> [f32; 3] {
        self.values[self.dims.index(x, y, z)]
    }

    /// Model-space centre of site `(x, y, z)`.
    pub fn site_position(&self, x: usize, y: usize, z: usize) -> Vec3 {
        Vec3::from_array(self.placement.model_point([x as f32, y as f32, z as f32]))
    }
}

/// Where a model's lighting came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LightingSource {
    /// Read from a valid cache entry.
    Cached,
    /// Solved (no cache, or no entry yet).
    Computed,
    /// The cache entry was bad (`reason` names the file and the problem) and was replaced.
    Recomputed { reason: String },
}

impl LightingSource {
    /// What several entries read or solved together report: a bad entry's reason first,
    /// else computed if any was, else cached.
    pub fn merge(self, other: LightingSource) -> LightingSource {
        match (self, other) {
            (r @ LightingSource::Recomputed { .. }, _) => r,
            (_, r @ LightingSource::Recomputed { .. }) => r,
            (LightingSource::Computed, _) | (_, LightingSource::Computed) => {
                LightingSource::Computed
            }
            _ => LightingSource::Cached,
        }
    }
}

/// What [`model_lighting`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct LightingReport {
    pub source: LightingSource,
    /// Wall-clock seconds of the whole call.
    pub seconds: f64,
    /// The cache entry (read or written); `None` without a cache.
    pub path: Option<PathBuf>,
    pub dims: Dims,
    /// Why the solved grid could not be cached (a read-only cache directory, a full disk):
    /// the light is good, only not kept.
    pub cache_warning: Option<String>,
}

impl From<CacheOutcome> for LightingSource {
    fn from(o: CacheOutcome) -> LightingSource {
        match o {
            CacheOutcome::Hit => LightingSource::Cached,
            CacheOutcome::Miss => LightingSource::Computed,
            CacheOutcome::BadEntry(reason) => LightingSource::Recomputed { reason },
        }
    }
}

/// The physical light's [`Environment`] of `illum`, its sun direction quantised as the
/// models' grids are solved with it.
pub fn physical_environment(illum: &Illumination) -> Result<Environment, LightingError> {
    let (_, sun) = quantise_sun(illum.sun_to)?;
    let env = illum.environment(sun);
    env.validate().map_err(LightingError::Illumination)?;
    Ok(env)
}

/// The sun direction rounded to [`SUN_QUANTUM`]: the integer components (hashed) and the unit
/// vector solved with.
pub(crate) fn quantise_sun(sun_to: Vec3) -> Result<([i64; 3], DVec3), LightingError> {
    let v = sun_to.as_dvec3();
    let len = v.length();
    if !(len.is_finite() && len > 0.0) {
        return Err(LightingError::Sun(sun_to.to_array()));
    }
    let q = (v / len)
        .to_array()
        .map(|c| (c / SUN_QUANTUM).round() as i64);
    let d = DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64) * SUN_QUANTUM;
    Ok((q, d.normalize()))
}

/// `Σ_i max(0, n_i · d)` for light travelling along `d = -sun_to`: the total a free-space
/// site holds under a unit-intensity sun, summed from the boundary values the solver uses.
pub(crate) fn free_space_total(sun_to: DVec3) -> Option<f64> {
    light::sun_total((-sun_to).to_array())
}

pub fn preset_medium(preset: &str) -> Result<MediumParams, LightingError> {
    let m = Preset::parse(preset)?.params();
    m.validate()?;
    Ok(m)
}

/// The mean optics of `model`'s leaves and bark: reflectance and transmittance per colour,
/// each material weighted by its surface area (leaves by their opaque part: the area times
/// the texture's opaque fraction).
pub fn plant_optics(model: &Model) -> PlantOptics {
    let mut area = vec![0.0f64; model.materials.len()];
    let mesh = &model.mesh;
    for (t, &m) in mesh.indices.iter().zip(&mesh.material_ids) {
        let p = t.map(|i| Vec3::from_array(mesh.positions[i as usize]).as_dvec3());
        let a = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
        if a.is_finite() {
            if let Some(slot) = area.get_mut(m as usize) {
                *slot += a;
            }
        }
    }
    let mut sums = [[0.0f64; 3]; 3];
    let mut weights = [0.0f64; 2];
    for (mat, a) in model.materials.iter().zip(area) {
        let (r, t) = (mat.mean_reflectance(), mat.mean_transmittance());
        if mat.is_leaf() {
            let w = a * mat.texture.as_ref().map_or(1.0, |t| t.opaque_fraction());
            weights[0] += w;
            for c in 0..3 {
                sums[0][c] += w * r[c] as f64;
                sums[1][c] += w * t[c] as f64;
            }
        } else {
            weights[1] += a;
            for c in 0..3 {
                sums[2][c] += a * r[c] as f64;
            }
        }
    }
    let mean = |s: [f64; 3], w: f64| if w > 0.0 { s.map(|v| v / w) } else { [0.0; 3] };
    PlantOptics {
        leaf_reflectance: mean(sums[0], weights[0]),
        leaf_transmittance: mean(sums[1], weights[0]),
        bark_reflectance: mean(sums[2], weights[1]),
    }
}

/// The physical LB medium of `model` ([`light::medium_for`] of [`plant_optics`]).
pub fn plant_medium(model: &Model) -> Result<MediumParams, LightingError> {
    for m in &model.materials {
        m.optics
            .validate(&format!("material '{}'", m.name))
            .map_err(|e| LightingError::Illumination(format!("model '{}': {e}", model.name)))?;
    }
    light::medium_for(&plant_optics(model)).map_err(|source| LightingError::Medium {
        model: model.name.clone(),
        source,
    })
}

/// How the paper light (and its relighting bases) voxelizes: sub-cell occupancy.
pub const PAPER_OCCUPANCY: Occupancy = Occupancy::SubCells;

/// The medium, occupancy and boundaries (per colour) of a solve, and (physical light) the
/// environment whose sun enters as a first-collision source and whose ground is the floor.
struct SolvePlan {
    medium: MediumParams,
    occupancy: Occupancy,
    boundaries: [Boundary; 3],
    environment: Option<Environment>,
}

fn solve_plan(
    model: &Model,
    illum: &Illumination,
    sun: DVec3,
    opts: &LightingOptions,
) -> Result<SolvePlan, LightingError> {
    Ok(match opts.light {
        Light::Paper => SolvePlan {
            medium: preset_medium(&opts.preset)?,
            occupancy: PAPER_OCCUPANCY,
            boundaries: [Boundary::sun((-sun).to_array(), 1.0); 3],
            environment: None,
        },
        Light::Physical => {
            let env = illum.environment(sun);
            env.validate().map_err(LightingError::Illumination)?;
            // A solid (the PMMA teapot, docs/media.md) is a scattering material, not leaves
            // and bark: its medium is its preset's, on the paper's sub-cell occupancy.
            let solid = model
                .materials
                .iter()
                .any(|m| m.kind == MaterialKind::Solid);
            SolvePlan {
                medium: if solid {
                    preset_medium(&opts.preset)?
                } else {
                    plant_medium(model)?
                },
                occupancy: if solid {
                    Occupancy::SubCells
                } else {
                    Occupancy::Area
                },
                boundaries: env.diffuse_boundaries(),
                environment: Some(env),
            }
        }
    })
}

/// How long `solver` runs over `dims`: its backend's [`LbSolver::schedule`].
pub(crate) fn solve_options(dims: Dims, solver: &dyn LbSolver) -> SolveOptions {
    solver.schedule().options(dims)
}

/// The stable 64-bit key of a model's lighting: [`CACHE_VERSION`] and the grid file version,
/// the light model, the mesh's geometry hash, per material its kind and (for leaves, whose
/// textures are alpha-tested) the texture's size, wrap and opaque texels, the voxelizer's
/// occupancy rule and opacity threshold, the grid size, the medium's parameters (bit
/// patterns; the physical medium's come from the materials' colours and optics), the
/// boundaries per colour (the sun direction rounded to 1e-5, and in the physical light the
/// sun's, sky's and ground's colours), whether the uncollided sunlight is removed, the solve
/// schedule, and the solver backend's [`LbSolver::cache_tag`] (CPU and GPU results differ
/// in the last bits).
pub fn cache_key(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
) -> Result<CacheKey, LightingError> {
    let (sun_q, sun) = quantise_sun(illum.sun_to)?;
    let plan = solve_plan(model, illum, sun, opts)?;
    Ok(CacheKey::new(
        MODEL_LIGHTING,
        &ModelLightingKey::new(
            ModelMediumKey::new(model, opts.grid, &plan.medium, plan.occupancy),
            sun_q,
            opts,
            &plan,
            solver,
        ),
    ))
}

/// Everything a model's lighting grid depends on ([`cache_key`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct ModelLightingKey {
    light: &'static str,
    /// The solver backend's [`LbSolver::cache_tag`].
    solver: String,
    model: ModelMediumKey,
    /// The sun direction rounded to [`SUN_QUANTUM`].
    sun: [i64; 3],
    /// Per colour (paper: the unit sun; physical: the sky and ground colours).
    boundaries: Vec<[f32; sylva_lb::lattice::Q]>,
    /// The physical light's first-collision sun source and floor.
    physical: Option<PhysicalKey>,
    /// The solve schedule ([`sylva_lb::Schedule::name`]).
    schedule: &'static str,
}

/// The physical light's sources: the sun straight along its direction, the sky's and the
/// ground's light (the floor is the ground shadowed by the plant).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct PhysicalKey {
    sun_travel: [f64; 3],
    sun_irradiance: [f64; 3],
    sky_radiance: [f64; 3],
    ground_albedo: Option<[f64; 3]>,
    step_optical_depth_factor: f64,
}

impl ModelLightingKey {
    fn new(
        model: ModelMediumKey,
        sun: [i64; 3],
        opts: &LightingOptions,
        plan: &SolvePlan,
        solver: &dyn LbSolver,
    ) -> ModelLightingKey {
        ModelLightingKey {
            light: opts.light.name(),
            solver: solver.cache_tag(),
            model,
            sun,
            boundaries: plan.boundaries.iter().map(|b| b.values).collect(),
            physical: plan.environment.as_ref().map(|env| PhysicalKey {
                sun_travel: env.sun_travel,
                sun_irradiance: env.sun_irradiance,
                sky_radiance: env.sky_radiance,
                ground_albedo: env.ground_albedo,
                step_optical_depth_factor: light::step_optical_depth_factor(),
            }),
            schedule: solver.schedule().name(),
        }
    }
}

/// What an LB result of a model depends on besides the boundary: the grid file version, the
/// mesh's geometry, the voxelizer's occupancy rule, sub-cells and opacity rule, per material
/// its kind and (for leaves) the texture's size, wrap and opaque texels, the grid size and
/// the medium's parameters (brown sites' included). Part of the per-sun lighting key, the
/// basis key and the global grid's key.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelMediumKey {
    grid_file_version: u32,
    geometry: u64,
    occupancy: &'static str,
    sub_cells: usize,
    opaque_alpha: u8,
    alpha_test: bool,
    materials: Vec<MaterialKey>,
    grid: usize,
    medium: MediumKey,
}

/// What the voxelizer reads of a material.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) enum MaterialKey {
    Wood,
    Leaf { texture: Option<TextureKey> },
    Solid,
}

/// A leaf texture as the voxelizer sees it: only opacity matters, one bit per texel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct TextureKey {
    width: u32,
    height: u32,
    wrap: &'static str,
    opaque: Vec<u8>,
}

/// A medium's parameters, brown sites' resolved.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MediumKey {
    /// Per colour: green `(σ_a, σ_s, g)`, brown `(σ_a, σ_s, g)`.
    colours: [[[f64; 3]; 2]; 3],
    zero_f0_on_green: bool,
    zero_f0_on_brown: bool,
    brown_threshold: f64,
}

impl MediumKey {
    pub fn new(m: &MediumParams) -> MediumKey {
        let p = |c: sylva_lb::ColourParams| [c.sigma_a, c.sigma_s, c.g];
        MediumKey {
            colours: std::array::from_fn(|c| [p(m.colours[c]), p(m.brown_colour(c))]),
            zero_f0_on_green: m.zero_f0_on_green,
            zero_f0_on_brown: m.zero_f0_on_brown,
            brown_threshold: m.brown_threshold,
        }
    }
}

impl ModelMediumKey {
    pub fn new(
        model: &Model,
        grid: usize,
        m: &MediumParams,
        occupancy: Occupancy,
    ) -> ModelMediumKey {
        let materials = model
            .materials
            .iter()
            .map(|mat| match mat.kind {
                MaterialKind::Wood => MaterialKey::Wood,
                MaterialKind::Solid => MaterialKey::Solid,
                MaterialKind::Leaf => MaterialKey::Leaf {
                    texture: mat.texture.as_ref().map(|t| TextureKey {
                        width: t.width,
                        height: t.height,
                        wrap: match t.wrap {
                            Wrap::Repeat => "repeat",
                            Wrap::Clamp => "clamp",
                        },
                        opaque: t
                            .pixels
                            .chunks(8)
                            .map(|c| c.iter().fold(0u8, |b, p| (b << 1) | is_opaque(*p) as u8))
                            .collect(),
                    }),
                },
            })
            .collect();
        ModelMediumKey {
            grid_file_version: sylva_lb::grid_file::VERSION,
            geometry: model.mesh.geometry_hash(),
            occupancy: occupancy.name(),
            sub_cells: SUB,
            opaque_alpha: OPAQUE_ALPHA,
            alpha_test: true,
            materials,
            grid,
            medium: MediumKey::new(m),
        }
    }
}

/// A model's medium key and the grid, medium and occupancy it was made for.
type MediumKeyFor = ((usize, MediumParams, Occupancy), ModelMediumKey);

/// The cache entry of `model` under `key` in `cache`.
pub fn cache_path(cache: &Cache, model: &Model, key: CacheKey) -> PathBuf {
    cache.entry(
        &sylva_core::file_stem(&model.name, "model"),
        key,
        CACHE_EXTENSION,
    )
}

/// Lights `grid` as `plan` says on `solver`, forwarding progress: the solver's result, less
/// the uncollided part where the plan removes it.
fn solve_density(
    grid: &DensityGrid,
    plan: &SolvePlan,
    solver: &dyn LbSolver,
    progress: &mut dyn FnMut(usize, usize, usize),
) -> Result<LightingGrid, LbSolverError> {
    let opts = solve_options(grid.dims, solver);
    let max = opts.max_steps;
    // Physical light: the ground under the plant, shadowed by it, and the sunlight
    // scattered at its first collision.
    let (floor, source) = match &plan.environment {
        Some(env) => {
            let (floor, source) = physical_sources(grid, plan, env)?;
            (floor, Some(source))
        }
        None => (None, None),
    };
    let (lighting, _) = solver.solve_lighting_rgb(
        grid,
        &plan.medium,
        &plan.boundaries,
        floor.as_ref(),
        source.as_ref(),
        &opts,
        &mut |c, s, _| progress(c, s, max),
    )?;
    Ok(lighting)
}

/// Lights a medium's `grid` with one `boundary` on `solver` (its schedule), forwarding
/// progress: the total light, as the media's volume tracer reads it (docs/media.md).
pub(crate) fn solve_medium(
    grid: &DensityGrid,
    medium: &MediumParams,
    boundary: Boundary,
    solver: &dyn LbSolver,
    progress: &mut dyn FnMut(usize, usize, usize),
) -> Result<LightingGrid, LbSolverError> {
    let opts = solve_options(grid.dims, solver);
    let max = opts.max_steps;
    let (lighting, _) = solver.solve_lighting(grid, medium, boundary, &opts, &mut |c, s, _| {
        progress(c, s, max)
    })?;
    Ok(lighting)
}

/// The physical light's floor and first-collision source of `grid` under `plan`.
fn physical_sources(
    grid: &DensityGrid,
    plan: &SolvePlan,
    env: &Environment,
) -> Result<(Option<Floor>, VolumeSource), LbSolverError> {
    Ok((
        env.floor(grid, &plan.medium)?,
        light::first_collision_source(grid, &plan.medium, env.sun_travel, env.sun_irradiance)?,
    ))
}

/// Colour `colour` of a physical-light plan in all three slots (medium, boundary, floor and
/// source), so a three-colour solve solves it once and gives that colour of the full solve.
fn physical_colour(
    grid: &DensityGrid,
    plan: &SolvePlan,
    colour: usize,
) -> Result<(MediumParams, [Boundary; 3], Option<Floor>, VolumeSource), LbSolverError> {
    let env = plan
        .environment
        .as_ref()
        .expect("physical_colour is for the physical light");
    let (floor, source) = physical_sources(grid, plan, env)?;
    let m = &plan.medium;
    let medium = MediumParams {
        colours: [m.colours[colour]; 3],
        brown: Some([m.brown_colour(colour); 3]),
        ..m.clone()
    };
    let floor = floor.map(|f| Floor {
        radiance: std::array::from_fn(|_| f.radiance[colour].clone()),
        ..f
    });
    let source = VolumeSource {
        strength: std::array::from_fn(|_| source.strength[colour].clone()),
        green: [source.green[colour]; 3],
        brown: [source.brown[colour]; 3],
    };
    Ok((medium, [plan.boundaries[colour]; 3], floor, source))
}

/// The stored grid as the renderer uses it.
fn to_model_lighting(grid: &LightingGrid, plan: &SolvePlan, sun_to: DVec3) -> ModelLighting {
    match &plan.environment {
        Some(env) => ModelLighting::physical(grid, env),
        None => {
            let total = free_space_total(sun_to).expect("a unit sun direction");
            ModelLighting::scaled(grid, 1.0 / total)
        }
    }
}

/// Reads a cached grid file and checks what every entry must match: its kind, its key, the
/// model's grid and box; `Err` is the reason it is unusable, naming the file.
fn read_checked(
    path: &Path,
    kind: GridKind,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
) -> Result<GridFile, String> {
    let file = GridFile::read(path).map_err(|e| e.to_string())?;
    let shown = path.display();
    if file.kind != kind {
        return Err(format!(
            "{shown} holds a {} grid, not a {} grid",
            file.kind.name(),
            kind.name()
        ));
    }
    key.check(path, file.metadata_value(KEY_METADATA))?;
    if file.dims != dims {
        return Err(format!(
            "{shown} holds a {} grid, the model needs {}",
            file.dims, dims
        ));
    }
    if file.bounds != bounds {
        return Err(format!(
            "{shown} covers {:?}..{:?}, the model's grid covers {:?}..{:?}",
            file.bounds.min, file.bounds.max, bounds.min, bounds.max
        ));
    }
    Ok(file)
}

/// Reads and checks a cache entry; `Err` is the reason it is unusable, naming the file.
fn read_entry(
    path: &Path,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
) -> Result<LightingGrid, String> {
    let shown = path.display();
    let file = read_checked(path, GridKind::Lighting, key, dims, bounds)?;
    let grid = file.into_lighting(path).map_err(|e| e.to_string())?;
    for (c, ch) in grid.colours.iter().enumerate() {
        if let Some(i) = ch.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            let (x, y, z) = grid.dims.coords(i);
            return Err(format!(
                "{shown}: {} light at site ({x}, {y}, {z}) is {}",
                sylva_lb::params::COLOUR_NAMES[c],
                ch[i]
            ));
        }
    }
    Ok(grid)
}

/// What a model's cache entry holds: a valid entry's grid, no entry (or no cache), or the
/// reason an entry cannot be used, naming the file.
pub type CacheLookup = Lookup<LightingGrid>;

/// The density grid cached at `path` under `key` for a `dims` grid over `bounds`; `Err` is
/// why it is unusable, naming the file.
fn read_density_entry(
    path: &Path,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
) -> Result<DensityGrid, String> {
    read_checked(path, GridKind::Density, key, dims, bounds)?
        .into_density(path)
        .map_err(|e| e.to_string())
}

/// Writes `grid` as a cache entry at `path` with `metadata` (the key first).
fn write_entry(
    grid: &LightingGrid,
    path: &Path,
    key: CacheKey,
    mut metadata: Vec<(String, String)>,
) -> Result<(), String> {
    metadata.insert(0, key.metadata());
    GridFile::from_lighting(grid, Element::F32, metadata)
        .write(path)
        .map_err(|e| e.to_string())
}

/// One model's LB lighting as separate steps, for whoever schedules the solves: the cache
/// entry, the density grid, each colour's solve, the cache write and the conversion to a
/// [`ModelLighting`]. [`model_lighting`] runs them in order in one process; `sylva-mpi`
/// solves the colours of many models in different processes and assembles them with
/// [`LightingPlan::assemble`]. A colour solved alone is bit for bit that colour of the
/// three-colour solve, so both give the same grids and cache entries.
pub struct LightingPlan<'a> {
    pub model: &'a Model,
    /// The cache key ([`cache_key`]).
    pub key: CacheKey,
    placement: GridPlacement,
    solve: SolvePlan,
    /// The quantised unit sun direction.
    sun: DVec3,
    opts: LightingOptions,
    /// The model's part of the key (also the key of its cached density).
    medium_key: ModelMediumKey,
    /// The cache and the entry; `None` without a cache.
    entry: Option<(Cache, PathBuf)>,
}

impl<'a> LightingPlan<'a> {
    /// The plan of lighting `model` under `illum` with `opts` on `solver` (its
    /// [`LbSolver::cache_tag`] is part of the key).
    pub fn new(
        model: &'a Model,
        illum: &Illumination,
        opts: &LightingOptions,
        solver: &dyn LbSolver,
    ) -> Result<LightingPlan<'a>, LightingError> {
        Self::new_reusing(model, illum, opts, solver, &mut None)
    }

    /// [`LightingPlan::new`], taking the model's medium key from `medium` when it was made
    /// for the same grid, medium and occupancy (else making it and leaving it there): the
    /// key hashes the whole mesh and every leaf texture's opacity, the same for every sun.
    fn new_reusing(
        model: &'a Model,
        illum: &Illumination,
        opts: &LightingOptions,
        solver: &dyn LbSolver,
        medium: &mut Option<MediumKeyFor>,
    ) -> Result<LightingPlan<'a>, LightingError> {
        let (sun_q, sun) = quantise_sun(illum.sun_to)?;
        let solve = solve_plan(model, illum, sun, opts)?;
        let inputs = (opts.grid, solve.medium.clone(), solve.occupancy);
        let model_key = match medium {
            Some((made_for, key)) if *made_for == inputs => key.clone(),
            _ => {
                let key = ModelMediumKey::new(model, opts.grid, &solve.medium, solve.occupancy);
                *medium = Some((inputs, key.clone()));
                key
            }
        };
        let lighting_key = ModelLightingKey::new(model_key, sun_q, opts, &solve, solver);
        let key = CacheKey::new(MODEL_LIGHTING, &lighting_key);
        let medium_key = lighting_key.model;
        let placement = placement_for(model, opts.grid)?;
        let entry = opts.cache_dir.as_ref().map(|dir| {
            let cache = Cache::new(dir);
            let path = cache_path(&cache, model, key);
            (cache, path)
        });
        Ok(LightingPlan {
            model,
            key,
            placement,
            solve,
            sun,
            opts: opts.clone(),
            medium_key,
            entry,
        })
    }

    /// The lighting grid's size.
    pub fn dims(&self) -> Dims {
        self.placement.dims
    }

    /// The cache entry (read or to be written); `None` without a cache.
    pub fn cache_path(&self) -> Option<&Path> {
        self.entry.as_ref().map(|(_, p)| p.as_path())
    }

    /// The cache entry, if there is a usable one.
    pub fn lookup(&self) -> CacheLookup {
        let Some((cache, path)) = &self.entry else {
            return Lookup::Miss;
        };
        cache.lookup(path, |p| {
            read_entry(p, self.key, self.placement.dims, self.placement.bounds())
        })
    }

    /// The colours a solve computes, each with the colour whose result it takes: a colour
    /// with the same parameters and boundary as an earlier one takes that one's (as
    /// [`sylva_lb::solver::solve_colours`] does; the physical light's colours are all
    /// solved, their sources differ).
    pub fn colour_sources(&self) -> [usize; 3] {
        if self.solve.environment.is_some() {
            return [0, 1, 2];
        }
        let c = &self.solve.medium.colours;
        let b = &self.solve.boundaries;
        std::array::from_fn(|i| (0..i).find(|&p| c[p] == c[i] && b[p] == b[i]).unwrap_or(i))
    }

    /// The model's density grid, its memory (with the solve's) checked first.
    pub fn density(&self) -> Result<DensityGrid, LightingError> {
        self.check_density_memory()?;
        self.voxelized()
    }

    fn check_density_memory(&self) -> Result<(), LightingError> {
        let dims = self.dims();
        sylva_core::check_memory(
            &format!(
                "the LB lighting of model '{}' on a {dims} grid",
                self.model.name
            ),
            memory_needed(dims)
                + sylva_voxel::memory_needed(dims)
                + light::uncollided_memory_needed(dims),
        )?;
        Ok(())
    }

    fn voxelized(&self) -> Result<DensityGrid, LightingError> {
        Ok(voxelize(
            self.model,
            &VoxelizeOptions {
                grid: self.opts.grid,
                alpha_test: true,
                occupancy: self.solve.occupancy,
            },
        )?)
    }

    /// [`LightingPlan::density`], kept in the plan's cache (`<model>-density-<key>.sgrid`):
    /// a forest voxelizes every model on each run to key its light (the neighbours' foliage
    /// is an input). Every process of a run asks for it alike, so the cache holds the same
    /// entries under MPI as in one process. The medium's optics are in the key though they
    /// do not change the density.
    /// With the density, the warning to show: a damaged entry voxelized again (naming the
    /// file and why), or an entry that could not be written.
    pub fn density_cached(&self) -> Result<(DensityGrid, Option<String>), LightingError> {
        self.check_density_memory()?;
        let dims = self.dims();
        let Some((cache, _)) = &self.entry else {
            return Ok((self.voxelized()?, None));
        };
        let key = self.density_key();
        let path = cache.entry(
            &format!(
                "{}-density",
                sylva_core::file_stem(&self.model.name, "model")
            ),
            key,
            CACHE_EXTENSION,
        );
        let bounds = self.placement.bounds();
        let got = cache.get_or_compute(
            &path,
            |p| read_density_entry(p, key, dims, bounds),
            || self.voxelized(),
            |grid, p| {
                let metadata = vec![
                    key.metadata(),
                    ("source".to_string(), self.model.name.clone()),
                    ("grid".to_string(), self.opts.grid.to_string()),
                ];
                GridFile::from_density(grid, metadata)
                    .write(p)
                    .map_err(|e| e.to_string())
            },
        )?;
        let warning = got.warning("voxelized again");
        debug_assert_eq!(got.value.dims, dims);
        debug_assert_eq!(got.value.bounds, bounds);
        Ok((got.value, warning))
    }

    /// The key of the model's voxelized density: the mesh, materials, voxelizer, grid and
    /// medium it is made from (its medium key), whether or not it is cached.
    pub fn density_key(&self) -> CacheKey {
        CacheKey::new(MODEL_DENSITY, &self.medium_key)
    }

    fn solve_error(&self, source: LbSolverError) -> LightingError {
        LightingError::Solve {
            model: self.model.name.clone(),
            source,
        }
    }

    /// All three colours on `solver`; `progress(colour, step, max_steps)`.
    pub fn solve(
        &self,
        density: &DensityGrid,
        solver: &dyn LbSolver,
        progress: &mut dyn FnMut(usize, usize, usize),
    ) -> Result<LightingGrid, LightingError> {
        solve_density(density, &self.solve, solver, progress).map_err(|e| self.solve_error(e))
    }

    /// Colour `colour` alone on `solver`: its site totals. `progress(step, max_steps)`.
    pub fn solve_colour(
        &self,
        density: &DensityGrid,
        colour: usize,
        solver: &dyn LbSolver,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<f32>, LightingError> {
        let opts = solve_options(density.dims, solver);
        let max = opts.max_steps;
        if self.solve.environment.is_none() {
            let (totals, _) = solver
                .solve_colour(
                    density,
                    &self.solve.medium,
                    colour,
                    self.solve.boundaries[colour],
                    &opts,
                    &mut |s, _| progress(s, max),
                )
                .map_err(|e| self.solve_error(e))?;
            return Ok(totals);
        }
        // The physical light: this colour's medium, boundary, floor and source in all three
        // slots, which the solver solves once.
        let (medium, boundaries, floor, source) =
            physical_colour(density, &self.solve, colour).map_err(|e| self.solve_error(e))?;
        let (lighting, _) = solver
            .solve_lighting_rgb(
                density,
                &medium,
                &boundaries,
                floor.as_ref(),
                Some(&source),
                &opts,
                &mut |_, s, _| progress(s, max),
            )
            .map_err(|e| self.solve_error(e))?;
        let [totals, _, _] = lighting.colours;
        Ok(totals)
    }

    /// The lighting grid of three colours' site totals, placed in model space.
    pub fn assemble(&self, colours: [Vec<f32>; 3]) -> LightingGrid {
        LightingGrid {
            dims: self.placement.dims,
            bounds: self.placement.bounds(),
            colours,
        }
    }

    /// Writes `grid` (solved on `solver`) as the cache entry, atomically; nothing without a
    /// cache. Returns a warning, naming the file, when the entry could not be written.
    pub fn store(&self, grid: &LightingGrid, solver: &dyn LbSolver) -> Option<String> {
        let (cache, path) = self.entry.as_ref()?;
        let sun = self.sun;
        let metadata = vec![
            ("source".to_string(), self.model.name.clone()),
            ("light".to_string(), self.opts.light.name().to_string()),
            (
                "medium".to_string(),
                match self.opts.light {
                    Light::Paper => format!("preset {}", self.opts.preset),
                    Light::Physical => "plant optics".to_string(),
                },
            ),
            ("grid".to_string(), self.opts.grid.to_string()),
            (
                "sun_to".to_string(),
                format!("{:.6},{:.6},{:.6}", sun.x, sun.y, sun.z),
            ),
            (
                "steps".to_string(),
                solve_options(self.dims(), solver).max_steps.to_string(),
            ),
            ("solver".to_string(), solver.describe()),
        ];
        cache.store(path, |p| write_entry(grid, p, self.key, metadata))
    }

    /// The stored grid as the renderer uses it (the paper light normalised so unobstructed
    /// sunlight is 1; the physical light as it is).
    pub fn lighting(&self, grid: &LightingGrid) -> ModelLighting {
        to_model_lighting(grid, &self.solve, self.sun)
    }
}

/// A lighting grid from [`cached_solve`].
#[derive(Debug)]
pub struct CachedGrid {
    pub grid: LightingGrid,
    pub source: LightingSource,
    /// The cache entry (read or written); `None` without a cache.
    pub path: Option<PathBuf>,
    /// Why the solved grid could not be stored.
    pub cache_warning: Option<String>,
}

/// One raw LB solve through the cache: `<stem>-<key>.sgrid` in `cache_dir` when a valid entry
/// holds it (key, dimensions and bounds checked), otherwise `solve()`d and, with a cache,
/// stored atomically with `metadata` and the key.
pub(crate) fn cached_solve(
    cache_dir: Option<&Path>,
    stem: &str,
    key: CacheKey,
    dims: Dims,
    bounds: Bounds,
    metadata: Vec<(String, String)>,
    solve: impl FnOnce() -> Result<LightingGrid, LightingError>,
) -> Result<CachedGrid, LightingError> {
    let Some(cache) = cache_dir.map(Cache::new) else {
        return Ok(CachedGrid {
            grid: solve()?,
            source: LightingSource::Computed,
            path: None,
            cache_warning: None,
        });
    };
    let path = cache.entry(stem, key, CACHE_EXTENSION);
    let got = cache.get_or_compute(
        &path,
        |p| read_entry(p, key, dims, bounds),
        solve,
        |grid, p| write_entry(grid, p, key, metadata),
    )?;
    Ok(CachedGrid {
        grid: got.value,
        source: got.outcome.into(),
        path: Some(path),
        cache_warning: got.write_warning,
    })
}

/// One model's LB lighting under `illum` (model frame): from the cache when it holds a valid
/// entry, otherwise voxelized, solved on `solver` and (with a cache) stored.
/// `progress(colour, step, max_steps)` follows the solve.
pub fn model_lighting(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
    progress: &mut dyn FnMut(usize, usize, usize),
) -> Result<(ModelLighting, LightingReport), LightingError> {
    let t0 = Instant::now();
    let plan = LightingPlan::new(model, illum, opts, solver)?;
    let report = |source, cache_warning| LightingReport {
        source,
        seconds: t0.elapsed().as_secs_f64(),
        path: plan.cache_path().map(Path::to_path_buf),
        dims: plan.dims(),
        cache_warning,
    };
    let source = match plan.lookup() {
        Lookup::Hit(grid) => {
            return Ok((plan.lighting(&grid), report(LightingSource::Cached, None)));
        }
        Lookup::Miss => LightingSource::Computed,
        Lookup::Bad(reason) => LightingSource::Recomputed { reason },
    };
    let density = plan.density()?;
    let grid = plan.solve(&density, solver, progress)?;
    drop(density);
    let warning = plan.store(&grid, solver);
    Ok((plan.lighting(&grid), report(source, warning)))
}

/// A model's physical light solved as its four parts ([`LightParts`]: the sun's, a unit sky's
/// through the top face and through the sides, a unit ground's; four solves, the top one on
/// the model mirrored in y with its floor as the top face), each cached on its own, for the forest grid
/// to weigh per instance (the `forest` module). Also returns the density grid and medium the
/// parts were solved with (the forest grid resamples them). Under the free weights the
/// parts sum to [`model_lighting`]'s grid (the LB is linear; tested).
pub fn model_lighting_parts(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
    progress: &mut dyn FnMut(usize, usize, usize),
) -> Result<(ModelLighting, LightingReport, DensityGrid, MediumParams), LightingError> {
    let (density, _) = model_density(model, illum, opts, solver)?;
    model_lighting_parts_on(model, illum, opts, solver, density, None, progress)
}

/// A model's density grid (voxelized as its LB solve sees it) and the medium of `opts`'s
/// light, for whoever prepares the solve's density first (the forest's neighbour shade).
pub fn model_density(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
) -> Result<(DensityGrid, MediumParams), LightingError> {
    let plan = LightingPlan::new(model, illum, opts, solver)?;
    Ok((plan.density()?, plan.solve.medium.clone()))
}

/// [`model_density`]'s density kept in the cache, and the warning to show
/// ([`LightingPlan::density_cached`]).
/// Also the density's key (what it was voxelized from: [`LightingPlan::density_key`]).
pub fn model_density_cached(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
) -> Result<(DensityGrid, CacheKey, Option<String>), LightingError> {
    let plan = LightingPlan::new(model, illum, opts, solver)?;
    let (density, warning) = plan.density_cached()?;
    Ok((density, plan.density_key(), warning))
}

/// [`model_lighting_parts`] on the model's `own` density ([`model_density`]), its sun part
/// solved on `shade`'s density when given (its neighbours' foliage added,
/// `forest::neighbour_shade`; its hash joins that part's cache key). Returns `own`.
pub fn model_lighting_parts_on(
    model: &Model,
    illum: &Illumination,
    opts: &LightingOptions,
    solver: &dyn LbSolver,
    own: DensityGrid,
    shade: Option<&ShadedDensity>,
    progress: &mut dyn FnMut(usize, usize, usize),
) -> Result<(ModelLighting, LightingReport, DensityGrid, MediumParams), LightingError> {
    let t0 = Instant::now();
    let plan = PartsPlan::new(model, illum, opts, solver, own, shade)?;
    let parts = plan.cached_parts(solver, &mut |k| plan.solve(k, solver, progress))?;
    let dims = plan.dims();
    let (lighting, own, medium) = plan.assemble(&parts.grids);
    let report = LightingReport {
        source: parts.source,
        seconds: t0.elapsed().as_secs_f64(),
        path: parts.path,
        dims,
        cache_warning: parts.cache_warning,
    };
    Ok((lighting, report, own, medium))
}

/// A model's four light parts ([`PARTS`] order) gathered through the cache
/// ([`PartsPlan::cached_parts`]), with what its report says of them.
#[derive(Debug)]
pub struct CachedParts {
    pub grids: Vec<LightingGrid>,
    /// A bad entry's reason first, else computed if any part was, else cached.
    pub source: LightingSource,
    /// The first part's cache entry; `None` without a cache.
    pub path: Option<PathBuf>,
    /// Why a solved part could not be stored.
    pub cache_warning: Option<String>,
}

/// A model's density with its neighbours' foliage inside its instances' boxes added
/// (`forest::neighbour_shade`), for its sun part's solve.
#[derive(Debug, Clone)]
pub struct ShadedDensity {
    /// The density the model's light parts are solved on.
    pub density: DensityGrid,
    /// A fingerprint of the added foliage, for the parts' cache keys.
    pub key: CacheKey,
    /// Optical depth (`Σ -ln(1 - ρ)` over the interior sites) of the model's own foliage and
    /// of the neighbours' that was added.
    pub own_depth: f64,
    pub added_depth: f64,
}

/// A model's light parts as [`PartsPlan::layout`] finds them before its density is made.
#[derive(Debug, Clone)]
pub struct PartsLayout {
    /// Each part's cache key, in [`PARTS`] order.
    pub keys: [CacheKey; 4],
    /// The parts' grid and its box (model space).
    pub dims: Dims,
    pub bounds: sylva_lb::Bounds,
    /// The medium the parts are solved with.
    pub medium: MediumParams,
}

/// Where part `k` ([`PARTS`]) of `model`'s physical light keyed `key` is cached in `dir`.
pub fn part_path(dir: &Path, model: &Model, k: usize, key: CacheKey) -> PathBuf {
    let stem = sylva_core::file_stem(&model.name, "model");
    Cache::new(dir).entry(&format!("{stem}-{}", PARTS[k]), key, CACHE_EXTENSION)
}

/// The physical light's parts as solved and cached, in order: the sun's, a unit sky's
/// (through every face, with the floor's sky part), a unit ground's, a unit sky's through the
/// top face (solved on the model mirrored in y).
pub const PARTS: [&str; 4] = ["sun", "sky", "ground", "skytop"];

/// One model's physical light parts as separate solves, for whoever schedules them:
/// [`model_lighting_parts_on`] runs them in order; `sylva-pipeline`'s forest hands them to
/// a job runner (other processes, under MPI) and caches them at the root. A part solved alone is bit for bit the part of the
/// one-process solve.
pub struct PartsPlan<'a> {
    model: &'a Model,
    plan: LightingPlan<'a>,
    env: Environment,
    medium: MediumParams,
    own: DensityGrid,
    /// The density the sun part is solved on, when the neighbours' foliage is added.
    shaded: Option<DensityGrid>,
    keys: [CacheKey; 4],
}

/// Everything one part of a model's physical light depends on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct LightPartKey {
    /// The model's lighting key ([`cache_key`]): the model, medium, sun, sky, ground, solver.
    model: u64,
    part: &'static str,
    /// The added foliage's fingerprint ([`crate::forest::ShadedDensity::key`]), the sun
    /// part's alone.
    shade: Option<u64>,
}

impl<'a> PartsPlan<'a> {
    /// The plan for `model` on its `own` density ([`model_density`]) and, for the sun part,
    /// `shade`'s.
    pub fn new(
        model: &'a Model,
        illum: &Illumination,
        opts: &LightingOptions,
        solver: &dyn LbSolver,
        own: DensityGrid,
        shade: Option<&ShadedDensity>,
    ) -> Result<PartsPlan<'a>, LightingError> {
        if opts.light != Light::Physical {
            return Err(LightingError::Illumination(
                "the light's parts are the physical light's".into(),
            ));
        }
        let plan = LightingPlan::new(model, illum, opts, solver)?;
        let env = plan
            .solve
            .environment
            .expect("the physical light has an environment");
        let medium = plan.solve.medium.clone();
        let dims = plan.dims();
        if own.dims != dims {
            return Err(LightingError::Illumination(format!(
                "model '{}': a {} density for a {dims} grid",
                model.name, own.dims
            )));
        }
        if let Some(s) = shade {
            if s.density.dims != dims {
                return Err(LightingError::Illumination(format!(
                    "model '{}': a {} shaded density for a {dims} grid",
                    model.name, s.density.dims
                )));
            }
        }
        let keys = Self::keys_of(&plan, shade.map(|s| s.key));
        Ok(PartsPlan {
            model,
            plan,
            env,
            medium,
            own,
            shaded: shade.map(|s| s.density.clone()),
            keys,
        })
    }

    /// What [`PartsPlan::new`]'s plan of `model` under `illum` with `opts` on `solver` keys
    /// and solves its parts by (`shade`: the added foliage's key for the sun part), found
    /// without its density, so the cache can be asked before any model is voxelized (the
    /// parts' files: [`part_path`]).
    pub fn layout(
        model: &Model,
        illum: &Illumination,
        opts: &LightingOptions,
        solver: &dyn LbSolver,
        shade: Option<CacheKey>,
    ) -> Result<PartsLayout, LightingError> {
        Ok(Self::layouts(model, std::slice::from_ref(illum), opts, solver, shade)?.remove(0))
    }

    /// [`PartsPlan::layout`] for each of `illums` in turn, the model's medium key made once.
    pub fn layouts(
        model: &Model,
        illums: &[Illumination],
        opts: &LightingOptions,
        solver: &dyn LbSolver,
        shade: Option<CacheKey>,
    ) -> Result<Vec<PartsLayout>, LightingError> {
        let mut medium = None;
        illums
            .iter()
            .map(|illum| {
                let plan = LightingPlan::new_reusing(model, illum, opts, solver, &mut medium)?;
                Ok(PartsLayout {
                    keys: Self::keys_of(&plan, shade),
                    dims: plan.dims(),
                    bounds: plan.placement.bounds(),
                    medium: plan.solve.medium.clone(),
                })
            })
            .collect()
    }

    /// Part `k`'s cache key: the model's lighting key, the part, and for the sun part the
    /// added foliage's key.
    fn keys_of(plan: &LightingPlan, shade: Option<CacheKey>) -> [CacheKey; 4] {
        std::array::from_fn(|k| {
            let key = LightPartKey {
                model: plan.key.value(),
                part: PARTS[k],
                shade: shade.filter(|_| k == 0).map(|s| s.value()),
            };
            CacheKey::new(LIGHT_PART, &key)
        })
    }

    /// The parts' grid size.
    pub fn dims(&self) -> Dims {
        self.plan.dims()
    }

    /// The parts' grid's box (model space).
    pub fn bounds(&self) -> sylva_lb::Bounds {
        self.plan.placement.bounds()
    }

    /// The medium the parts are solved with.
    pub fn medium(&self) -> &MediumParams {
        &self.medium
    }

    /// Part `k`'s name in reports: [`PARTS`]`[k]`, the sun's with its direction.
    pub fn part_name(&self, k: usize) -> String {
        match k {
            0 => {
                let t = self.env.sun_travel;
                format!("sun along ({:.2}, {:.2}, {:.2})", t[0], t[1], t[2])
            }
            _ => PARTS.get(k).copied().unwrap_or("unknown").to_string(),
        }
    }

    /// Part `k`'s cache key.
    pub fn key(&self, k: usize) -> CacheKey {
        self.keys[k]
    }

    /// Solves part `k` (no cache). `progress(colour, step, max_steps)`.
    pub fn solve(
        &self,
        k: usize,
        solver: &dyn LbSolver,
        progress: &mut dyn FnMut(usize, usize, usize),
    ) -> Result<LightingGrid, LightingError> {
        let (env, medium, dims) = (&self.env, &self.medium, self.dims());
        let density = &self.own;
        let sun_density = self.shaded.as_ref().unwrap_or(&self.own);
        let err = |source| LightingError::Solve {
            model: self.model.name.clone(),
            source,
        };
        let zero = [Boundary {
            values: [0.0; sylva_lb::lattice::Q],
        }; 3];
        let floor_of = |v: f32| Floor {
            nx: dims.nx,
            nz: dims.nz,
            radiance: std::array::from_fn(|_| vec![v; dims.nx * dims.nz]),
        };
        let (boundaries, floor, source) = match k {
            0 => {
                let sun_only = Environment {
                    sky_radiance: [0.0; 3],
                    ..*env
                };
                let floor = sun_only
                    .floor(sun_density, medium)
                    .map_err(|e| err(e.into()))?;
                let source = light::first_collision_source(
                    sun_density,
                    medium,
                    env.sun_travel,
                    env.sun_irradiance,
                )
                .map_err(|e| err(e.into()))?;
                (zero, floor, Some(source))
            }
            1 => {
                let unit_sky = Environment {
                    sun_irradiance: [0.0; 3],
                    sky_radiance: [1.0; 3],
                    ..*env
                };
                let floor = unit_sky.floor(density, medium).map_err(|e| err(e.into()))?;
                (light::sky_boundaries([1.0; 3]), floor, None)
            }
            2 => (
                light::ground_boundaries([1.0; 3]),
                env.ground_albedo.map(|_| floor_of(0.0)),
                None,
            ),
            // The plant upside down: its floor is the top face, lit by a unit sky there.
            3 => (zero, Some(floor_of(1.0)), None),
            _ => {
                return Err(LightingError::Illumination(format!(
                    "no light part {k} (of {})",
                    PARTS.len()
                )))
            }
        };
        let flipped;
        let grid = match k {
            0 => sun_density,
            3 => {
                flipped = flip_y(density);
                &flipped
            }
            _ => density,
        };
        let sopts = solve_options(dims, solver);
        let max = sopts.max_steps;
        let (grid, _) = solver
            .solve_lighting_rgb(
                grid,
                medium,
                &boundaries,
                floor.as_ref(),
                source.as_ref(),
                &sopts,
                &mut |c, s, _| progress(c, s, max),
            )
            .map_err(err)?;
        Ok(if k == 3 { flip_lighting(&grid) } else { grid })
    }

    /// Part `k` from the cache, else `solve()`d and (with a cache) stored.
    pub fn cached(
        &self,
        k: usize,
        solver: &dyn LbSolver,
        solve: impl FnOnce() -> Result<LightingGrid, LightingError>,
    ) -> Result<CachedGrid, LightingError> {
        let metadata = vec![
            ("source".to_string(), self.model.name.clone()),
            ("light".to_string(), format!("physical, {} part", PARTS[k])),
            ("grid".to_string(), self.plan.opts.grid.to_string()),
            ("solver".to_string(), solver.describe()),
        ];
        let stem = sylva_core::file_stem(&self.model.name, "model");
        cached_solve(
            self.plan.opts.cache_dir.as_deref(),
            &format!("{stem}-{}", PARTS[k]),
            self.keys[k],
            self.dims(),
            self.plan.placement.bounds(),
            metadata,
            solve,
        )
    }

    /// Every part from the cache, else `solve(k)`d and (with a cache) stored: the one-process
    /// solves, or the results of jobs run elsewhere.
    pub fn cached_parts(
        &self,
        solver: &dyn LbSolver,
        solve: &mut dyn FnMut(usize) -> Result<LightingGrid, LightingError>,
    ) -> Result<CachedParts, LightingError> {
        self.cached_some(&[0, 1, 2, 3], solver, solve)
    }

    /// [`PartsPlan::cached_parts`] of the parts `wanted` alone (their grids in that order).
    pub fn cached_some(
        &self,
        wanted: &[usize],
        solver: &dyn LbSolver,
        solve: &mut dyn FnMut(usize) -> Result<LightingGrid, LightingError>,
    ) -> Result<CachedParts, LightingError> {
        let mut parts = CachedParts {
            grids: Vec::with_capacity(wanted.len()),
            source: LightingSource::Cached,
            path: None,
            cache_warning: None,
        };
        for &k in wanted {
            let CachedGrid {
                grid,
                source,
                path,
                cache_warning,
            } = self.cached(k, solver, || solve(k))?;
            parts.cache_warning = parts.cache_warning.or(cache_warning);
            parts.source = parts.source.merge(source);
            parts.path = parts.path.or(path);
            parts.grids.push(grid);
        }
        Ok(parts)
    }

    /// Whether the cache holds a valid entry of part `k`.
    pub fn is_cached(&self, k: usize) -> bool {
        let Some(dir) = self.plan.opts.cache_dir.as_deref() else {
            return false;
        };
        let path = part_path(dir, self.model, k, self.keys[k]);
        read_entry(
            &path,
            self.keys[k],
            self.dims(),
            self.plan.placement.bounds(),
        )
        .is_ok()
    }

    /// The grid of part `k` from its values (colour-major, one per site each), checked.
    pub fn grid_from(&self, values: Vec<f32>) -> Result<LightingGrid, LightingError> {
        let dims = self.dims();
        let n = dims.sites();
        if values.len() != 3 * n {
            return Err(LightingError::Illumination(format!(
                "model '{}': a light part of {} values for a {dims} grid",
                self.model.name,
                values.len()
            )));
        }
        let mut c = values.chunks_exact(n).map(<[f32]>::to_vec);
        Ok(LightingGrid {
            dims,
            bounds: self.plan.placement.bounds(),
            colours: std::array::from_fn(|_| c.next().expect("three colours")),
        })
    }

    /// The model's light from its four parts (in [`PARTS`] order), with its own density and
    /// medium.
    pub fn assemble(self, grids: &[LightingGrid]) -> (ModelLighting, DensityGrid, MediumParams) {
        // The sky through the sides (and the floor's sky part): the whole sky's less the top's.
        let side = light::subtract(&grids[1], &grids[3]);
        let lighting =
            ModelLighting::physical_parts([&grids[0], &grids[3], &side, &grids[2]], &self.env);
        (lighting, self.own, self.medium)
    }
}

/// `grid` mirrored in y (site `(x, y, z)` ↔ `(x, ny − 1 − y, z)`); the D3Q19 lattice and the
/// media's phase functions are symmetric under it, so a solve of the mirror is the mirror of
/// a solve.
fn flip_y(grid: &DensityGrid) -> DensityGrid {
    let d = grid.dims;
    let at = |v: &[f32], i: usize| {
        let (x, y, z) = d.coords(i);
        v[d.index(x, d.ny - 1 - y, z)]
    };
    DensityGrid {
        dims: d,
        bounds: grid.bounds,
        density: (0..d.sites()).map(|i| at(&grid.density, i)).collect(),
        wood: (0..d.sites()).map(|i| at(&grid.wood, i)).collect(),
    }
}

/// A lighting grid of the mirrored density ([`flip_y`]) back in the model's frame.
fn flip_lighting(grid: &LightingGrid) -> LightingGrid {
    let d = grid.dims;
    LightingGrid {
        dims: d,
        bounds: grid.bounds,
        colours: std::array::from_fn(|c| {
            (0..d.sites())
                .map(|i| {
                    let (x, y, z) = d.coords(i);
                    grid.colours[c][d.index(x, d.ny - 1 - y, z)]
                })
                .collect()
        }),
    }
}

/// A model and medium key with a textured leaf, wood and a solid, for the key tests (of this
/// crate's keys and of keys that hold one, feature `test-fixtures`).
#[cfg(any(test, feature = "test-fixtures"))]
pub fn sample_model_medium_key() -> ModelMediumKey {
    ModelMediumKey {
        grid_file_version: sylva_lb::grid_file::VERSION,
        geometry: 0x1234,
        occupancy: Occupancy::Area.name(),
        sub_cells: SUB,
        opaque_alpha: OPAQUE_ALPHA,
        alpha_test: true,
        materials: vec![
            MaterialKey::Leaf {
                texture: Some(TextureKey {
                    width: 4,
                    height: 2,
                    wrap: "clamp",
                    opaque: vec![0b1010_0101],
                }),
            },
            MaterialKey::Wood,
        ],
        grid: 16,
        medium: MediumKey {
            colours: [[[0.1, 0.2, 0.3], [0.4, 0.5, -1.0]]; 3],
            zero_f0_on_green: true,
            zero_f0_on_brown: true,
            brown_threshold: 0.5,
        },
    }
}

/// Every field of [`sample_model_medium_key`] changed in turn, each sub-field of the
/// materials and the medium included.
#[cfg(any(test, feature = "test-fixtures"))]
pub fn model_medium_variants() -> Vec<(String, ModelMediumKey)> {
    let base = sample_model_medium_key;
    let with = |f: &dyn Fn(&mut ModelMediumKey)| {
        let mut k = base();
        f(&mut k);
        k
    };
    let texture = |f: &dyn Fn(&mut TextureKey)| {
        with(&|k| {
            if let MaterialKey::Leaf { texture: Some(t) } = &mut k.materials[0] {
                f(t)
            }
        })
    };
    let mut v: Vec<(String, ModelMediumKey)> = vec![
        (
            "grid_file_version".into(),
            with(&|k| k.grid_file_version += 1),
        ),
        ("geometry".into(), with(&|k| k.geometry += 1)),
        (
            "occupancy".into(),
            with(&|k| k.occupancy = Occupancy::SubCells.name()),
        ),
        ("sub_cells".into(), with(&|k| k.sub_cells += 1)),
        ("opaque_alpha".into(), with(&|k| k.opaque_alpha += 1)),
        ("alpha_test".into(), with(&|k| k.alpha_test = false)),
        (
            "material kind".into(),
            with(&|k| k.materials[1] = MaterialKey::Solid),
        ),
        ("material count".into(), with(&|k| k.materials.truncate(1))),
        (
            "leaf texture".into(),
            with(&|k| k.materials[0] = MaterialKey::Leaf { texture: None }),
        ),
        ("texture width".into(), texture(&|t| t.width += 1)),
        ("texture height".into(), texture(&|t| t.height += 1)),
        ("texture wrap".into(), texture(&|t| t.wrap = "repeat")),
        ("texture opacity".into(), texture(&|t| t.opaque[0] ^= 1)),
        ("grid".into(), with(&|k| k.grid += 1)),
        (
            "zero_f0_on_green".into(),
            with(&|k| k.medium.zero_f0_on_green = false),
        ),
        (
            "zero_f0_on_brown".into(),
            with(&|k| k.medium.zero_f0_on_brown = false),
        ),
        (
            "brown_threshold".into(),
            with(&|k| k.medium.brown_threshold = 0.6),
        ),
    ];
    for c in 0..3 {
        for (s, site) in ["green", "brown"].into_iter().enumerate() {
            for (p, param) in ["sigma_a", "sigma_s", "g"].into_iter().enumerate() {
                v.push((
                    format!("medium colour {c} {site} {param}"),
                    with(&|k| k.medium.colours[c][s][p] += 0.01),
                ));
            }
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_core::cache::assert_each_field_changes_the_key;
    use sylva_geom::LeafOptics;
    use sylva_geom::{Material, Mesh};
    use sylva_lb::Bounds;
    use sylva_lb::CpuSolver;

    const N: usize = 16;

    fn quad(mesh: &mut Mesh, c: [Vec3; 4], material: u8) {
        let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize();
        let uv = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let i: Vec<u32> = (0..4).map(|k| mesh.push_vertex(c[k], n, uv[k])).collect();
        mesh.push_triangle(i[0], i[1], i[2], material);
        mesh.push_triangle(i[0], i[2], i[3], material);
    }

    /// A leafy plate at y = 1 over x, z ∈ [0, 2] on a wooden post from y = 0.
    fn model(plate_y: f32) -> Model {
        let mut mesh = Mesh::default();
        quad(
            &mut mesh,
            [
                Vec3::new(0.0, plate_y, 0.0),
                Vec3::new(0.0, plate_y, 2.0),
                Vec3::new(2.0, plate_y, 2.0),
                Vec3::new(2.0, plate_y, 0.0),
            ],
            0,
        );
        quad(
            &mut mesh,
            [
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(1.1, 0.0, 1.0),
                Vec3::new(1.1, plate_y, 1.0),
                Vec3::new(1.0, plate_y, 1.0),
            ],
            1,
        );
        let mat = |name: &str, kind| Material {
            name: name.into(),
            kind,
            // A leaf reflects its colour and transmits up to 1.2 times it: R + T ≤ 1.
            base_color: [0.2, 0.4, 0.1],
            texture: None,
            two_sided: true,
            optics: if kind == MaterialKind::Leaf {
                sylva_geom::Optics::FOREST_LEAF
            } else {
                sylva_geom::Optics::OPAQUE
            },
        };
        Model::new(
            "test plate/1",
            mesh,
            vec![
                mat("leaf", MaterialKind::Leaf),
                mat("bark", MaterialKind::Wood),
            ],
        )
    }

    fn opts(dir: Option<&Path>) -> LightingOptions {
        LightingOptions {
            grid: N,
            light: Light::Physical,
            preset: "leaf".into(),
            cache_dir: dir.map(Path::to_path_buf),
        }
    }

    /// A slightly coloured sun towards `sun_to`, a blue sky and a dark ground.
    fn illum(sun_to: Vec3) -> Illumination {
        Illumination {
            sun_to,
            sun: Vec3::new(1.04, 0.98, 1.03),
            sky: Vec3::new(0.55, 0.7, 0.95),
            ground: Some(Vec3::new(0.16, 0.14, 0.08)),
        }
    }

    fn sun() -> Vec3 {
        Vec3::new(0.3, 0.8, 0.2).normalize()
    }

    fn no_progress() -> impl FnMut(usize, usize, usize) {
        |_, _, _| {}
    }

    /// Samples at a fixed set of points in and around the model's box.
    fn probe(l: &ModelLighting) -> Vec<[u32; 3]> {
        let mut out = Vec::new();
        for i in 0..7 {
            for j in 0..5 {
                for k in 0..7 {
                    let p = Vec3::new(
                        i as f32 * 0.37 - 0.2,
                        j as f32 * 0.29 - 0.1,
                        k as f32 * 0.33,
                    );
                    out.push(l.sample(p).to_array().map(f32::to_bits));
                }
            }
        }
        out
    }

    #[test]
    fn computed_then_cached_bit_identical() {
        let dir = tempfile::tempdir().unwrap();
        let m = model(1.0);
        let o = opts(Some(dir.path()));
        let mut calls = 0usize;
        let mut last = (0, 0, 0);
        let (a, ra) = model_lighting(&m, &illum(sun()), &o, &CpuSolver, &mut |c, s, max| {
            calls += 1;
            last = (c, s, max);
        })
        .unwrap();
        assert_eq!(ra.source, LightingSource::Computed);
        let path = ra.path.clone().unwrap();
        assert!(path.is_file());
        let key = cache_key(&m, &illum(sun()), &o, &CpuSolver).unwrap();
        assert_eq!(
            path.file_name().unwrap().to_str().unwrap(),
            format!("test_plate_1-{key}.sgrid")
        );
        assert_eq!(ra.dims, a.dims());
        assert!(calls > 0);
        assert_eq!(last.1, last.2, "progress reaches max steps");
        assert_eq!(
            last.2,
            SolveOptions::coarse_started(a.dims()).max_steps,
            "the CPU's coarse-started schedule"
        );

        let mut calls2 = 0usize;
        let (b, rb) = model_lighting(&m, &illum(sun()), &o, &CpuSolver, &mut |_, _, _| {
            calls2 += 1
        })
        .unwrap();
        assert_eq!(rb.source, LightingSource::Cached);
        assert_eq!(rb.path.as_deref(), Some(path.as_path()));
        assert_eq!(calls2, 0, "no solve on a cache hit");
        assert_eq!(a, b);
        assert_eq!(probe(&a), probe(&b));

        // Without a cache: computed, same values, nothing written.
        let (c, rc) = model_lighting(
            &m,
            &illum(sun()),
            &opts(None),
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap();
        assert_eq!(rc.source, LightingSource::Computed);
        assert_eq!(rc.path, None);
        assert_eq!(probe(&a), probe(&c));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    fn assert_recomputed(m: &Model, o: &LightingOptions, want: &ModelLighting, path: &Path) {
        let (l, r) = model_lighting(m, &illum(sun()), o, &CpuSolver, &mut no_progress()).unwrap();
        match &r.source {
            LightingSource::Recomputed { reason } => {
                assert!(
                    reason.contains(&path.display().to_string()),
                    "reason names the file: {reason}"
                );
            }
            s => panic!("expected Recomputed, got {s:?}"),
        }
        assert_eq!(probe(&l), probe(want));
        // The entry was replaced by a valid one.
        let (_, r2) = model_lighting(m, &illum(sun()), o, &CpuSolver, &mut no_progress()).unwrap();
        assert_eq!(r2.source, LightingSource::Cached);
        GridFile::read(path).unwrap();
    }

    #[test]
    fn corrupt_entries_are_recomputed() {
        let dir = tempfile::tempdir().unwrap();
        let m = model(1.0);
        let o = opts(Some(dir.path()));
        let (orig, r) =
            model_lighting(&m, &illum(sun()), &o, &CpuSolver, &mut no_progress()).unwrap();
        let path = r.path.unwrap();
        let good = std::fs::read(&path).unwrap();

        // A flipped byte in the middle of the payload: checksum mismatch.
        let mut bad = good.clone();
        let mid = bad.len() / 2;
        bad[mid] ^= 0x5a;
        std::fs::write(&path, &bad).unwrap();
        assert_recomputed(&m, &o, &orig, &path);

        // Truncated.
        std::fs::write(&path, &good[..good.len() / 3]).unwrap();
        assert_recomputed(&m, &o, &orig, &path);

        // Empty.
        std::fs::write(&path, b"").unwrap();
        assert_recomputed(&m, &o, &orig, &path);

        // A valid grid file with another key (renamed or from an older version): stale.
        let mut file = GridFile::read(&path).unwrap();
        for (k, v) in &mut file.metadata {
            if k == KEY_METADATA {
                *v = "0123456789abcdef".into();
            }
        }
        file.write(&path).unwrap();
        assert_recomputed(&m, &o, &orig, &path);

        // Right key, wrong dimensions.
        let mut file = GridFile::read(&path).unwrap();
        let d = file.dims;
        let small = Dims::new(d.nx, d.ny, d.nz - 1).unwrap();
        file.dims = small;
        for ch in &mut file.channels {
            ch.truncate(small.sites());
        }
        file.write(&path).unwrap();
        assert_recomputed(&m, &o, &orig, &path);
    }

    #[test]
    fn key_changes_with_the_leaf_optics() {
        // A light solved with the texture's colour as the leaves' reflectance must not be
        // reused for measured leaves, nor the other way round; either mode again is a hit.
        let measured = |mode| {
            let mut m = model(1.0);
            m.materials[0].optics = sylva_geom::Optics::measured_leaf(
                sylva_geom::KNAPP_CARTER_LEAF,
                mode,
                m.materials[0].mean_colour(),
            )
            .unwrap();
            m
        };
        let o = opts(None);
        let key = |m: &Model| cache_key(m, &illum(sun()), &o, &CpuSolver).unwrap();
        let (k_measured, k_texture) = (
            key(&measured(LeafOptics::Measured)),
            key(&measured(LeafOptics::Texture)),
        );
        assert_ne!(k_measured, k_texture);
        assert_eq!(k_measured, key(&measured(LeafOptics::Measured)));
        // The texture mode is the colour look of before: the same key as a leaf that had
        // those factors without measured values.
        assert_eq!(k_texture, key(&model(1.0)));
        // Through a scene, as every command sets them.
        let mut scene_model = measured(LeafOptics::Measured);
        let mut m = scene_model.materials[0].clone();
        m.set_leaf_optics(LeafOptics::Texture).unwrap();
        scene_model.materials[0] = m;
        assert_eq!(key(&scene_model), k_texture);
    }

    #[test]
    fn key_tracks_inputs() {
        let m = model(1.0);
        let o = opts(None);
        let k = cache_key(&m, &illum(sun()), &o, &CpuSolver).unwrap();
        assert_eq!(
            k,
            cache_key(&model(1.0), &illum(sun()), &o, &CpuSolver).unwrap(),
            "stable"
        );
        assert_eq!(
            k,
            cache_key(&m, &illum(sun() * 3.0), &o, &CpuSolver).unwrap(),
            "length of sun_to"
        );
        assert_eq!(
            k,
            cache_key(&m, &illum(sun() + Vec3::splat(1e-7)), &o, &CpuSolver).unwrap(),
            "below the rounding"
        );
        let other_sun = Vec3::new(0.3, 0.8, 0.25).normalize();
        assert_ne!(
            k,
            cache_key(&m, &illum(other_sun), &o, &CpuSolver).unwrap(),
            "sun"
        );
        let grid = LightingOptions {
            grid: N + 1,
            ..o.clone()
        };
        assert_ne!(
            k,
            cache_key(&m, &illum(sun()), &grid, &CpuSolver).unwrap(),
            "grid"
        );
        // The preset is the paper light's medium; the physical light's comes from the
        // materials.
        let paper = LightingOptions {
            light: Light::Paper,
            ..o.clone()
        };
        let paper_key = cache_key(&m, &illum(sun()), &paper, &CpuSolver).unwrap();
        assert_ne!(k, paper_key, "light model");
        let preset = LightingOptions {
            preset: "dogrose".into(),
            ..paper.clone()
        };
        assert_ne!(
            paper_key,
            cache_key(&m, &illum(sun()), &preset, &CpuSolver).unwrap(),
            "preset"
        );
        assert_eq!(
            k,
            cache_key(
                &m,
                &illum(sun()),
                &LightingOptions {
                    preset: "dogrose".into(),
                    ..o.clone()
                },
                &CpuSolver
            )
            .unwrap(),
            "the physical light ignores the preset"
        );
        // ... except for a solid (the PMMA teapot): its medium is its preset under either light.
        let mut solid = model(1.0);
        for mat in &mut solid.materials {
            mat.kind = MaterialKind::Solid;
        }
        let solid_key = |preset: &str| {
            let opts = LightingOptions {
                preset: preset.into(),
                ..o.clone()
            };
            cache_key(&solid, &illum(sun()), &opts, &CpuSolver).unwrap()
        };
        assert_ne!(solid_key("pmma"), solid_key("dogrose"), "a solid's preset");
        assert_ne!(
            k,
            cache_key(&model(1.01), &illum(sun()), &o, &CpuSolver).unwrap(),
            "geometry"
        );
        // Material kind and leaf opacity.
        let mut wood = m.clone();
        wood.materials[0].kind = MaterialKind::Wood;
        assert_ne!(
            k,
            cache_key(&wood, &illum(sun()), &o, &CpuSolver).unwrap(),
            "material kind"
        );
        let mut tex = m.clone();
        let mut t = sylva_geom::Texture::new(2, 2, vec![[10, 150, 10, 255]; 4], Wrap::Clamp);
        tex.materials[0].texture = Some(std::sync::Arc::new(t.clone()));
        let kt = cache_key(&tex, &illum(sun()), &o, &CpuSolver).unwrap();
        assert_ne!(k, kt, "texture");
        t.pixels[3][3] = 0;
        tex.materials[0].texture = Some(std::sync::Arc::new(t.clone()));
        assert_ne!(
            kt,
            cache_key(&tex, &illum(sun()), &o, &CpuSolver).unwrap(),
            "texture alpha"
        );
        // The cache directory and the model's name are not part of the key.
        let elsewhere = LightingOptions {
            cache_dir: Some("/somewhere".into()),
            ..o.clone()
        };
        assert_eq!(
            k,
            cache_key(&m, &illum(sun()), &elsewhere, &CpuSolver).unwrap()
        );
        let mut renamed = m.clone();
        renamed.name = "other".into();
        assert_eq!(
            k,
            cache_key(&renamed, &illum(sun()), &o, &CpuSolver).unwrap()
        );

        assert!(matches!(
            cache_key(&m, &illum(Vec3::ZERO), &o, &CpuSolver),
            Err(LightingError::Sun(_))
        ));
        assert!(matches!(
            cache_key(&m, &illum(Vec3::new(f32::NAN, 1.0, 0.0)), &o, &CpuSolver),
            Err(LightingError::Sun(_))
        ));
        let bad = LightingOptions {
            preset: "granite".into(),
            ..paper
        };
        let e = cache_key(&m, &illum(sun()), &bad, &CpuSolver).unwrap_err();
        assert!(e.to_string().contains("granite"), "{e}");
    }

    #[test]
    fn model_medium_key_changes_with_every_field() {
        let variants = model_medium_variants();
        let named: Vec<(&str, ModelMediumKey)> = variants
            .iter()
            .map(|(n, k)| (n.as_str(), k.clone()))
            .collect();
        assert_each_field_changes_the_key(MODEL_LIGHTING, &sample_model_medium_key(), &named);
    }

    #[test]
    fn model_lighting_key_changes_with_every_field() {
        let physical = PhysicalKey {
            sun_travel: [0.0, -1.0, 0.0],
            sun_irradiance: [1.0; 3],
            sky_radiance: [0.2; 3],
            ground_albedo: Some([0.1; 3]),
            step_optical_depth_factor: 1.0,
        };
        let base = ModelLightingKey {
            light: Light::Physical.name(),
            solver: "cpu".into(),
            model: sample_model_medium_key(),
            sun: [0, 100_000, 0],
            boundaries: vec![[0.5; sylva_lb::lattice::Q]; 3],
            physical: Some(physical.clone()),
            schedule: sylva_lb::Schedule::Papers.name(),
        };
        let with_physical = |f: &dyn Fn(&mut PhysicalKey)| {
            let mut p = physical.clone();
            f(&mut p);
            ModelLightingKey {
                physical: Some(p),
                ..base.clone()
            }
        };
        let mut boundary = base.boundaries.clone();
        boundary[2][18] = 0.0;
        let mut variants: Vec<(String, ModelLightingKey)> = vec![
            (
                "light".into(),
                ModelLightingKey {
                    light: Light::Paper.name(),
                    ..base.clone()
                },
            ),
            (
                "solver".into(),
                ModelLightingKey {
                    solver: "gpu-f32".into(),
                    ..base.clone()
                },
            ),
            (
                "sun".into(),
                ModelLightingKey {
                    sun: [1, 100_000, 0],
                    ..base.clone()
                },
            ),
            (
                "boundaries".into(),
                ModelLightingKey {
                    boundaries: boundary,
                    ..base.clone()
                },
            ),
            (
                "physical".into(),
                ModelLightingKey {
                    physical: None,
                    ..base.clone()
                },
            ),
            (
                "schedule".into(),
                ModelLightingKey {
                    schedule: sylva_lb::Schedule::Extrapolated.name(),
                    ..base.clone()
                },
            ),
            (
                "sun_travel".into(),
                with_physical(&|p| p.sun_travel[0] = 0.1),
            ),
            (
                "sun_irradiance".into(),
                with_physical(&|p| p.sun_irradiance[1] = 0.9),
            ),
            (
                "sky_radiance".into(),
                with_physical(&|p| p.sky_radiance[2] = 0.3),
            ),
            (
                "ground_albedo".into(),
                with_physical(&|p| p.ground_albedo = None),
            ),
            (
                "ground_albedo value".into(),
                with_physical(&|p| p.ground_albedo = Some([0.2; 3])),
            ),
            (
                "step_optical_depth_factor".into(),
                with_physical(&|p| p.step_optical_depth_factor = 0.5),
            ),
        ];
        for (name, m) in model_medium_variants() {
            variants.push((
                format!("model: {name}"),
                ModelLightingKey {
                    model: m,
                    ..base.clone()
                },
            ));
        }
        let named: Vec<(&str, ModelLightingKey)> = variants
            .iter()
            .map(|(n, k)| (n.as_str(), k.clone()))
            .collect();
        assert_each_field_changes_the_key(MODEL_LIGHTING, &base, &named);
    }

    #[test]
    fn light_part_key_changes_with_every_field() {
        let base = LightPartKey {
            model: 7,
            part: PARTS[0],
            shade: Some(3),
        };
        assert_each_field_changes_the_key(
            LIGHT_PART,
            &base,
            &[
                (
                    "model",
                    LightPartKey {
                        model: 8,
                        ..base.clone()
                    },
                ),
                (
                    "part",
                    LightPartKey {
                        part: PARTS[1],
                        ..base.clone()
                    },
                ),
                (
                    "shade",
                    LightPartKey {
                        shade: None,
                        ..base.clone()
                    },
                ),
                (
                    "shade value",
                    LightPartKey {
                        shade: Some(4),
                        ..base.clone()
                    },
                ),
            ],
        );
        // The same inputs under another kind are another key.
        assert_ne!(
            CacheKey::new(LIGHT_PART, &base),
            CacheKey::new(MODEL_LIGHTING, &base)
        );
    }

    #[test]
    fn parts_keys_follow_the_model_key_and_the_shade() {
        let m = model(1.0);
        let o = opts(None);
        let own = model_density(&m, &illum(sun()), &o, &CpuSolver).unwrap().0;
        let plan = PartsPlan::new(&m, &illum(sun()), &o, &CpuSolver, own.clone(), None).unwrap();
        let keys: Vec<CacheKey> = (0..PARTS.len()).map(|k| plan.key(k)).collect();
        for (i, a) in keys.iter().enumerate() {
            assert!(keys[..i].iter().all(|b| b != a), "parts {i} shares a key");
        }
        let other_sun = illum(Vec3::new(0.3, 0.8, 0.25));
        let moved = PartsPlan::new(&m, &other_sun, &o, &CpuSolver, own.clone(), None).unwrap();
        assert!((0..PARTS.len()).all(|k| moved.key(k) != keys[k]));
        let shade = ShadedDensity {
            density: own.clone(),
            key: CacheKey::new(crate::forest::NEIGHBOUR_SHADE, &1u8),
            own_depth: 1.0,
            added_depth: 0.5,
        };
        let shaded = PartsPlan::new(&m, &illum(sun()), &o, &CpuSolver, own, Some(&shade)).unwrap();
        assert_ne!(shaded.key(0), keys[0], "the shade is the sun part's input");
        assert!((1..PARTS.len()).all(|k| shaded.key(k) == keys[k]));
        // The layout found without a density keys, sizes and solves the parts as the plan
        // does: the cache is asked with it before any model is voxelized.
        for (il, shade_key, p) in [
            (illum(sun()), None, &plan),
            (other_sun, None, &moved),
            (illum(sun()), Some(shade.key), &shaded),
        ] {
            let layout = PartsPlan::layout(&m, &il, &o, &CpuSolver, shade_key).unwrap();
            assert_eq!(
                layout.keys.to_vec(),
                (0..PARTS.len()).map(|k| p.key(k)).collect::<Vec<_>>()
            );
            assert_eq!((layout.dims, layout.bounds), (p.dims(), p.bounds()));
            assert_eq!(&layout.medium, p.medium());
        }
        // Several suns at once (the medium key made once) key each as alone.
        let suns = [
            illum(sun()),
            illum(Vec3::new(0.3, 0.8, 0.25)),
            illum(Vec3::Y),
        ];
        let many = PartsPlan::layouts(&m, &suns, &o, &CpuSolver, None).unwrap();
        for (il, l) in suns.iter().zip(&many) {
            let alone = PartsPlan::layout(&m, il, &o, &CpuSolver, None).unwrap();
            assert_eq!(l.keys, alone.keys);
            assert_eq!(l.keys[0], cache_key_part(&m, il, &o));
        }
        assert_ne!(many[0].keys, many[1].keys);
    }

    #[test]
    fn the_density_is_voxelized_once_and_a_damaged_entry_is_made_again() {
        let dir = tempfile::tempdir().unwrap();
        let m = model(1.0);
        let plan =
            LightingPlan::new(&m, &illum(sun()), &opts(Some(dir.path())), &CpuSolver).unwrap();
        let bare = LightingPlan::new(&m, &illum(sun()), &opts(None), &CpuSolver).unwrap();
        let voxelized = bare.density().unwrap();
        let entries = || {
            std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.to_string_lossy().contains("-density-"))
                .collect::<Vec<_>>()
        };
        assert_eq!(plan.density_cached().unwrap(), (voxelized.clone(), None));
        let [entry] = &entries()[..] else {
            panic!("one density entry: {:?}", entries())
        };
        // Read back (the same grid); another sun's plan shares it.
        let other = LightingPlan::new(
            &m,
            &illum(Vec3::new(0.3, 0.8, 0.25)),
            &opts(Some(dir.path())),
            &CpuSolver,
        )
        .unwrap();
        assert_eq!(other.density_cached().unwrap(), (voxelized.clone(), None));
        assert_eq!(entries().len(), 1);
        // Truncated: voxelized again and rewritten whole.
        let bytes = std::fs::read(entry).unwrap();
        std::fs::write(entry, &bytes[..bytes.len() / 2]).unwrap();
        let (again, warning) = plan.density_cached().unwrap();
        assert_eq!(again, voxelized);
        let warning = warning.expect("a damaged entry is reported");
        assert!(warning.contains(&entry.display().to_string()), "{warning}");
        assert_eq!(std::fs::read(entry).unwrap(), bytes);
        // A denser model is another entry.
        let denser = model(2.0);
        let p2 =
            LightingPlan::new(&denser, &illum(sun()), &opts(Some(dir.path())), &CpuSolver).unwrap();
        assert_ne!(p2.density_cached().unwrap().0, voxelized);
        assert_eq!(entries().len(), 2);
    }

    /// Part 0's key as a plan made from scratch gives it.
    fn cache_key_part(m: &Model, il: &Illumination, o: &LightingOptions) -> CacheKey {
        let own = model_density(m, il, o, &CpuSolver).unwrap().0;
        PartsPlan::new(m, il, o, &CpuSolver, own, None)
            .unwrap()
            .key(0)
    }

    #[test]
    fn free_space_holds_the_sky_and_ground_light_alone() {
        // Physical light in free space: the sun's light is all uncollided and removed; what
        // stays is the open sky's and ground's light, 2 L_sky + 2 L_ground per colour.
        let dims = Dims::new(11, 12, 9).unwrap();
        let empty = DensityGrid::empty(dims);
        let m = model(1.0);
        for to_sun in [Vec3::Y, sun(), Vec3::new(-0.7, 0.2, 0.6)] {
            let (_, s) = quantise_sun(to_sun).unwrap();
            let il = illum(to_sun);
            let plan = solve_plan(&m, &il, s, &opts(None)).unwrap();
            let grid = solve_density(&empty, &plan, &CpuSolver, &mut no_progress()).unwrap();
            let l = to_model_lighting(&grid, &plan, s);
            assert!(l.is_physical());
            let env = il.environment(s);
            let lg = Vec3::from_array(env.ground_radiance().map(|v| v as f32));
            let want = 2.0 * il.sky + 2.0 * lg;
            for i in 0..dims.sites() {
                let (x, y, z) = dims.coords(i);
                let v = Vec3::from_array(l.site(x, y, z));
                assert!(
                    (v - want).abs().max_element() < 1e-5,
                    "{to_sun}: ({x}, {y}, {z}) {v} vs {want}"
                );
            }
            // The ground under no tree sees the whole sky.
            let g = l.ground_sky(Vec3::new(0.5, 0.0, 0.5));
            assert!((g - Vec3::ONE).abs().max_element() < 1e-5, "{g}");
        }
    }

    #[test]
    fn free_space_is_one() {
        let dims = Dims::new(12, 10, 9).unwrap();
        let bounds = Bounds {
            min: [-1.0, 0.0, 2.0],
            max: [3.0, 2.0, 4.0],
        };
        let empty = DensityGrid {
            bounds,
            ..DensityGrid::empty(dims)
        };
        for to_sun in [
            Vec3::Y,
            sun(),
            Vec3::new(-0.7, 0.2, 0.6),
            Vec3::new(0.0, -1.0, 0.0),
        ] {
            let (_, s) = quantise_sun(to_sun).unwrap();
            let paper = LightingOptions {
                light: Light::Paper,
                ..opts(None)
            };
            let plan = solve_plan(&model(1.0), &illum(to_sun), s, &paper).unwrap();
            let grid = solve_density(&empty, &plan, &CpuSolver, &mut no_progress()).unwrap();
            let l = to_model_lighting(&grid, &plan, s);
            assert!(!l.is_physical());
            for x in 0..dims.nx {
                for y in 0..dims.ny {
                    for z in 0..dims.nz {
                        for v in l.site(x, y, z) {
                            assert!((v - 1.0).abs() < 1e-5, "{to_sun}: ({x},{y},{z}) {v}");
                        }
                    }
                }
            }
            for p in [Vec3::new(0.3, 1.1, 2.9), Vec3::new(-5.0, 9.0, 3.0)] {
                let v = l.sample(p);
                assert!((v - Vec3::ONE).abs().max_element() < 1e-5, "{v}");
            }
            // from_grid normalises the same way.
            let f = ModelLighting::from_grid(&grid, s.as_vec3());
            assert!(
                (f.sample(Vec3::new(1.0, 1.0, 3.0)) - Vec3::ONE)
                    .abs()
                    .max_element()
                    < 1e-5
            );
        }
    }

    #[test]
    fn shadow_under_the_plate() {
        let m = model(1.0);
        let (l, _) = model_lighting(
            &m,
            &illum(Vec3::Y),
            &opts(None),
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap();
        let under = l.sample(Vec3::new(0.6, 0.5, 0.6));
        let above = l.sample(Vec3::new(0.6, 1.05 + 1.0 / N as f32 * 2.0, 0.6));
        // The plate hides the sky from below (green leaks through it most): less light under
        // it than above in every colour.
        assert!(
            (under - above).max_element() < 0.0
                && luminance(under.to_array()) < 0.95 * luminance(above.to_array()),
            "under {under}, above {above}"
        );
    }

    /// A lighting grid holding `f(position)` with unit normalisation.
    fn linear_grid(dims: Dims, bounds: Bounds, f: impl Fn(Vec3) -> Vec3) -> LightingGrid {
        let n = [dims.nx, dims.ny, dims.nz];
        let min = Vec3::from_array(bounds.min);
        let cell = Vec3::from_array(std::array::from_fn(|a| {
            (bounds.max[a] - bounds.min[a]) / (n[a] - 1) as f32
        }));
        let mut colours: [Vec<f32>; 3] = Default::default();
        for i in 0..dims.sites() {
            let (x, y, z) = dims.coords(i);
            let p = min + Vec3::new(x as f32, y as f32, z as f32) * cell;
            let v = f(p);
            for c in 0..3 {
                colours[c].push(v[c]);
            }
        }
        LightingGrid {
            dims,
            bounds,
            colours,
        }
    }

    #[test]
    fn trilinear_exact_on_linear_fields_and_clamps() {
        let dims = Dims::new(5, 4, 7).unwrap();
        let bounds = Bounds {
            min: [-1.0, 0.5, 2.0],
            max: [3.0, 2.0, 5.0],
        };
        let f = |p: Vec3| {
            Vec3::new(
                1.0 + 0.5 * p.x - 0.25 * p.y + 0.125 * p.z,
                2.0 - p.x + 0.75 * p.z,
                3.0 + 0.3 * p.y,
            )
        };
        let grid = linear_grid(dims, bounds, f);
        // Scale so that the normalisation is undone: from_grid divides by the free-space total.
        let total = free_space_total(Vec3::Y.as_dvec3()).unwrap();
        let l = ModelLighting::scaled(&grid, 1.0);
        let l2 = ModelLighting::from_grid(&grid, Vec3::Y);
        let min = Vec3::from_array(bounds.min);
        let max = Vec3::from_array(bounds.max);
        let mut rng = 0x1234_5678u32;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            rng as f32 / u32::MAX as f32
        };
        for _ in 0..2000 {
            let t = Vec3::new(next(), next(), next());
            let p = min + (max - min) * t;
            let want = f(p);
            let got = l.sample(p);
            assert!(
                (got - want).abs().max_element() < 1e-5 * want.abs().max_element().max(1.0),
                "{p}: {got} vs {want}"
            );
            let got2 = l2.sample(p) * total as f32;
            assert!((got2 - want).abs().max_element() < 1e-4, "{got2} vs {want}");
        }
        // Sites exactly.
        for (x, y, z) in [(0, 0, 0), (4, 3, 6), (2, 1, 3)] {
            let p = l.site_position(x, y, z);
            assert_eq!(l.sample(p).to_array(), l.site(x, y, z));
        }
        // Clamping: outside points take the value at the nearest point of the box.
        let outside = [
            Vec3::new(-10.0, 1.0, 3.0),
            Vec3::new(10.0, 100.0, -3.0),
            Vec3::new(0.0, -5.0, 9.0),
            Vec3::new(1e30, -1e30, f32::INFINITY),
        ];
        for p in outside {
            let q = p.clamp(min, max);
            let (got, want) = (l.sample(p), f(q));
            assert!(
                (got - want).abs().max_element() < 1e-5 * 10.0,
                "{p}: {got} vs {want}"
            );
        }
        // NaN does not panic.
        let _ = l.sample(Vec3::NAN);
        assert!(l.memory_bytes() >= (dims.sites() * 12) as u64);
        assert_eq!(l.dims(), dims);
    }

    #[test]
    fn unwritable_cache_dir_is_a_warning_naming_it() {
        // Issue 31: a cache that cannot be written must not fail a render after the solve.
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("not-a-dir");
        std::fs::write(&file, b"x").unwrap();
        let cache = file.join("cache");
        let (l, r) = model_lighting(
            &model(1.0),
            &illum(sun()),
            &opts(Some(&cache)),
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap();
        let warning = r.cache_warning.expect("a warning");
        assert!(warning.contains(&cache.display().to_string()), "{warning}");
        let (free, _) = model_lighting(
            &model(1.0),
            &illum(sun()),
            &opts(None),
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap();
        assert_eq!(probe(&l), probe(&free), "the light is the uncached one");
    }

    #[test]
    fn model_errors_pass_through() {
        let empty = Model::new("nothing", Mesh::default(), vec![]);
        let e = model_lighting(
            &empty,
            &illum(sun()),
            &opts(None),
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("nothing"), "{e}");
        let e = model_lighting(
            &model(1.0),
            &illum(sun()),
            &LightingOptions {
                grid: 2,
                ..opts(None)
            },
            &CpuSolver,
            &mut no_progress(),
        )
        .unwrap_err();
        assert!(
            matches!(e, LightingError::Voxelize(VoxelizeError::BadGrid(2))),
            "{e:?}"
        );
    }

    #[test]
    fn placement_matches_voxelize() {
        let m = model(1.0);
        for n in [4, 9, 16, 23] {
            let p = placement_for(&m, n).unwrap();
            let g = voxelize(
                &m,
                &VoxelizeOptions {
                    grid: n,
                    alpha_test: true,
                    occupancy: Occupancy::Area,
                },
            )
            .unwrap();
            assert_eq!(p.dims, g.dims);
            assert_eq!(p.bounds(), g.bounds);
        }
    }
}
