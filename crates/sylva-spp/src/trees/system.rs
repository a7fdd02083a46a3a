//! The rendering system of 003 §5: prototypes with deep opacity maps in a few sample
//! directions, instances with coarse grids of depths and G-factors, depths through a forest
//! by eq. 31, and the SPP light on a plant (eq. 19 with eq. 28's compensation).
//!
//! Steps of 003 Fig. 9, as here:
//!
//! * **Step 2** ([`SppSystem::build`]): per prototype (a model under one rotation), a deep
//!   opacity map in each of `N` sample directions (a spherical Fibonacci set; the paper uses
//!   16, and 22 for its Table 4).
//! * **Step 3** (also in `build`): per instance, a grid of `n³` points over its box (`n` = 16 in
//!   the paper), each storing the depth in every sample direction by eq. 31: the sum over the
//!   instances whose maps cover the line of each one's map at the point (in its model space).
//! * **Step 5** ([`SppSystem::set_light`]): per prototype, the maps along the light (one at
//!   the sample maps' resolution, one finer for shading); per grid point, the depth and
//!   thickness along the light (eq. 31, coarse map) and, from them and the stored sample
//!   depths, the G-factor (eqs. 26-27, A.3). The paper lists G with the static steps,
//!   but A.3 depends on the light (through `z0`, `w` and each direction's angle to it), so it
//!   is recomputed here with the light.
//! * **Step 4** ([`SppSystem::update_sky`]): per grid point, the sky's light getting through:
//!   the mean over the downward sample directions of `e^{−d(x, s_j)}`.
//! * **Step 6** ([`SppLight`]): at a surface point, the depth and thickness along the light
//!   from the light maps (eq. 31, full resolution), the SPP field there (eq. 19), and the
//!   instance grid's G (trilinear).
//!
//! Sums over instances run in instance order through a per-direction [`PlaneIndex`], so every
//! value depends on the scene only, not on the thread count.

use super::gfactor::{g_factor, sample_directions};
use super::meshes::SceneMeshes;
use super::opacity_map::{prototypes_of, DeepOpacityMap, MapResolution, Prototype};
use super::shading::TreeSpp;
use super::TreeError;
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use std::time::Instant;
use sylva_geom::{Aabb, Model};
use sylva_trace::{SceneAccel, TraceInstance};

/// Sizes of the system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SystemConfig {
    /// Sample directions of the deep opacity maps (003: 16, Table 4: 22).
    pub directions: usize,
    /// Resolution of the maps in the sample directions (and of the light's map that the grid
    /// points' G uses). A texel should be about a grid cell: G is a coarse quantity, and the
    /// count along a single line is noisy (Poisson, for leaves placed at random).
    pub map: MapResolution,
    /// Resolution of the maps along the light used for shading (003 §5.3: the prototype's
    /// map, at full resolution).
    pub light_map: MapResolution,
    /// Points along each edge of an instance's grid (003: about 16).
    pub grid: usize,
}

impl Default for SystemConfig {
    fn default() -> Self {
        SystemConfig {
            directions: 16,
            map: MapResolution {
                texels: 32,
                layers: 64,
                samples: 4,
            },
            light_map: MapResolution {
                texels: 256,
                layers: 128,
                samples: 2,
            },
            grid: 16,
        }
    }
}

impl SystemConfig {
    pub fn validate(&self) -> Result<(), TreeError> {
        if !(1..=256).contains(&self.directions) {
            return Err(TreeError::invalid(
                "sample directions",
                self.directions.to_string(),
                "must be 1 to 256 (003 uses 16 to 22)",
            ));
        }
        if !(2..=128).contains(&self.grid) {
            return Err(TreeError::invalid(
                "instance grid",
                self.grid.to_string(),
                "must be 2 to 128 points per edge (003 uses about 16)",
            ));
        }
        self.map.validate()?;
        self.light_map.validate()
    }
}

/// Instances whose box, seen along one direction, covers a point: a uniform grid of buckets
/// over the plane perpendicular to the direction.
#[derive(Debug, Clone)]
pub struct PlaneIndex {
    u_axis: Vec3,
    v_axis: Vec3,
    min: [f32; 2],
    cell: f32,
    nu: usize,
    nv: usize,
    /// Instance ids per bucket, ascending.
    buckets: Vec<Vec<u32>>,
}

impl PlaneIndex {
    /// Buckets `boxes` seen along unit `dir`.
    pub fn new(dir: Vec3, boxes: &[Aabb]) -> PlaneIndex {
        let (u_axis, v_axis) = super::beam::frame(dir);
        let rects: Vec<[f32; 4]> = boxes
            .iter()
            .map(|b| {
                let mut r = [
                    f32::INFINITY,
                    f32::INFINITY,
                    f32::NEG_INFINITY,
                    f32::NEG_INFINITY,
                ];
                for c in b.corners() {
                    let (u, v) = (c.dot(u_axis), c.dot(v_axis));
                    r = [r[0].min(u), r[1].min(v), r[2].max(u), r[3].max(v)];
                }
                r
            })
            .collect();
        let mut lo = [f32::INFINITY; 2];
        let mut hi = [f32::NEG_INFINITY; 2];
        let mut mean_size = 0.0f64;
        for r in &rects {
            lo = [lo[0].min(r[0]), lo[1].min(r[1])];
            hi = [hi[0].max(r[2]), hi[1].max(r[3])];
            mean_size += ((r[2] - r[0]).max(r[3] - r[1])) as f64;
        }
        if rects.is_empty() || !(lo[0].is_finite() && hi[0].is_finite()) {
            return PlaneIndex {
                u_axis,
                v_axis,
                min: [0.0; 2],
                cell: 1.0,
                nu: 1,
                nv: 1,
                buckets: vec![Vec::new()],
            };
        }
        mean_size /= rects.len() as f64;
        let ext = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-6);
        // Buckets about half an instance wide, at most 512 along a side.
        let cell = ((0.5 * mean_size) as f32).max(ext / 512.0).max(1e-6);
        let nu = (((hi[0] - lo[0]) / cell).ceil() as usize).clamp(1, 512);
        let nv = (((hi[1] - lo[1]) / cell).ceil() as usize).clamp(1, 512);
        let mut buckets = vec![Vec::new(); nu * nv];
        for (id, r) in rects.iter().enumerate() {
            let i0 = (((r[0] - lo[0]) / cell).floor() as usize).min(nu - 1);
            let i1 = (((r[2] - lo[0]) / cell).floor() as usize).min(nu - 1);
            let j0 = (((r[1] - lo[1]) / cell).floor() as usize).min(nv - 1);
            let j1 = (((r[3] - lo[1]) / cell).floor() as usize).min(nv - 1);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    buckets[j * nu + i].push(id as u32);
                }
            }
        }
        PlaneIndex {
            u_axis,
            v_axis,
            min: lo,
            cell,
            nu,
            nv,
            buckets,
        }
    }

    /// Instances whose box may cover the line through `p`, ascending.
    #[inline]
    pub fn at(&self, p: Vec3) -> &[u32] {
        let u = (p.dot(self.u_axis) - self.min[0]) / self.cell;
        let v = (p.dot(self.v_axis) - self.min[1]) / self.cell;
        if !(u >= 0.0 && v >= 0.0 && u < self.nu as f32 + 1e-3 && v < self.nv as f32 + 1e-3) {
            return &[];
        }
        let i = (u as usize).min(self.nu - 1);
        let j = (v as usize).min(self.nv - 1);
        &self.buckets[j * self.nu + i]
    }
}

/// One instance's coarse grid (003 §5.1 "instance model").
#[derive(Debug, Clone)]
pub struct InstanceGrid {
    /// World position of point (0, 0, 0).
    min: Vec3,
    /// World spacing of the points along each axis.
    cell: Vec3,
    n: usize,
    /// Depth in every sample direction at every point: `depths[p * N + j]`.
    depths: Vec<f32>,
    /// G-factor at every point (1 until a light is set).
    g: Vec<f32>,
    /// Depth and thickness along the light at every point.
    light: Vec<[f32; 2]>,
    /// Fraction of the sky's light reaching every point.
    sky: Vec<f32>,
}

impl InstanceGrid {
    fn point(&self, p: usize) -> Vec3 {
        let n = self.n;
        let (i, j, k) = (p / (n * n), (p / n) % n, p % n);
        self.min + self.cell * Vec3::new(i as f32, j as f32, k as f32)
    }

    /// Trilinear interpolation of `values` at world point `x` (clamped to the grid).
    fn sample(&self, values: &[f32], x: Vec3) -> f32 {
        let n = self.n;
        let last = (n - 1) as f32;
        let f = Vec3::select(
            self.cell.cmpgt(Vec3::ZERO),
            (x - self.min) / self.cell,
            Vec3::ZERO,
        )
        .max(Vec3::ZERO)
        .min(Vec3::splat(last));
        let i = f.floor().min(Vec3::splat(last - 1.0)).max(Vec3::ZERO);
        let t = f - i;
        let (i, j, k) = (i.x as usize, i.y as usize, i.z as usize);
        let at = |a: usize, b: usize, c: usize| values[(a * n + b) * n + c];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let (i1, j1, k1) = ((i + 1).min(n - 1), (j + 1).min(n - 1), (k + 1).min(n - 1));
        let x00 = lerp(at(i, j, k), at(i1, j, k), t.x);
        let x01 = lerp(at(i, j, k1), at(i1, j, k1), t.x);
        let x10 = lerp(at(i, j1, k), at(i1, j1, k), t.x);
        let x11 = lerp(at(i, j1, k1), at(i1, j1, k1), t.x);
        lerp(lerp(x00, x10, t.y), lerp(x01, x11, t.y), t.z)
    }

    /// Points in the grid.
    pub fn points(&self) -> usize {
        self.n * self.n * self.n
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        ((self.depths.capacity() + self.g.capacity() + self.sky.capacity()) * 4
            + self.light.capacity() * 8) as u64
    }
}

/// Seconds spent in each step.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SystemTimings {
    /// Step 2: the maps in the sample directions.
    pub sample_maps: f64,
    /// Step 3: the instance grids' depths in the sample directions (eq. 31).
    pub grid_depths: f64,
    /// Step 5: the maps along the light.
    pub light_maps: f64,
    /// Step 5: depth, thickness and G at the grid points.
    pub light_grid: f64,
    /// Step 4: the sky's light at the grid points.
    pub sky: f64,
}

/// The §5 system over one scene.
#[derive(Debug, Clone)]
pub struct SppSystem {
    config: SystemConfig,
    /// Sample directions, world space, unit (the direction light travels in).
    directions: Vec<Vec3>,
    prototypes: Vec<Prototype>,
    /// Per instance: its prototype and world → model transform.
    instance_proto: Vec<u32>,
    to_model: Vec<Affine3A>,
    boxes: Vec<Aabb>,
    /// Per sample direction, the instances covering each line.
    index: Vec<PlaneIndex>,
    /// The instances over each ground point.
    vertical: PlaneIndex,
    grids: Vec<InstanceGrid>,
    /// The light's direction of travel and its index, once set.
    light: Option<(Vec3, PlaneIndex)>,
    pub timings: SystemTimings,
}

impl SppSystem {
    /// Steps 2 and 3: maps in the sample directions for every prototype and the depth grids
    /// of every instance. `instances` are `accel`'s (same order); `meshes` group its models.
    pub fn build(
        models: &[Model],
        instances: &[sylva_geom::Instance],
        accel: &SceneAccel,
        meshes: &SceneMeshes,
        config: SystemConfig,
    ) -> Result<SppSystem, TreeError> {
        config.validate()?;
        if instances.len() != accel.instances().len() {
            return Err(TreeError::invalid(
                "instances",
                instances.len().to_string(),
                "must be the traced scene's instances",
            ));
        }
        let directions = sample_directions(config.directions);
        let (mut prototypes, instance_proto) = prototypes_of(instances);
        let n_dirs = directions.len();
        let cells = config.grid.pow(3);
        sylva_core::check_memory(
            "the instance grids of the plane-parallel system",
            instances.len() as u64 * cells as u64 * (n_dirs as u64 + 4) * 4,
        )?;

        let t0 = Instant::now();
        let jobs: Vec<(usize, usize)> = (0..prototypes.len())
            .flat_map(|p| (0..n_dirs).map(move |j| (p, j)))
            .collect();
        let maps: Vec<DeepOpacityMap> = jobs
            .iter()
            .map(|&(p, j)| {
                let proto = &prototypes[p];
                let m = proto.model as usize;
                DeepOpacityMap::build(
                    &models[m],
                    &accel.models()[m],
                    &meshes.models[m],
                    proto.world_to_model * directions[j],
                    config.map,
                )
            })
            .collect::<Result<_, _>>()?;
        let mut maps = maps.into_iter();
        for proto in prototypes.iter_mut() {
            proto.maps = maps.by_ref().take(n_dirs).collect();
        }
        let sample_maps = t0.elapsed().as_secs_f64();

        let t1 = Instant::now();
        let traced: &[TraceInstance] = accel.instances();
        let to_model: Vec<Affine3A> = traced.iter().map(|i| i.to_model).collect();
        let boxes: Vec<Aabb> = traced.iter().map(|i| i.world_bounds).collect();
        let boxes_copy = boxes.clone();
        let index: Vec<PlaneIndex> = directions
            .iter()
            .map(|&d| PlaneIndex::new(d, &boxes))
            .collect();
        let mut system = SppSystem {
            config,
            directions,
            prototypes,
            instance_proto,
            to_model,
            boxes,
            index,
            vertical: PlaneIndex::new(Vec3::NEG_Y, &boxes_copy),
            grids: Vec::new(),
            light: None,
            timings: SystemTimings {
                sample_maps,
                ..SystemTimings::default()
            },
        };
        let n = config.grid;
        let grids: Vec<InstanceGrid> = system
            .boxes
            .par_iter()
            .map(|b| {
                let ext = b.max - b.min;
                let mut grid = InstanceGrid {
                    min: b.min,
                    cell: ext / (n - 1) as f32,
                    n,
                    depths: vec![0.0; cells * n_dirs],
                    g: vec![1.0; cells],
                    light: vec![[0.0; 2]; cells],
                    sky: vec![1.0; cells],
                };
                for p in 0..cells {
                    let x = grid.point(p);
                    for j in 0..n_dirs {
                        grid.depths[p * n_dirs + j] = system.depth(x, j).0;
                    }
                }
                grid
            })
            .collect();
        system.grids = grids;
        system.timings.grid_depths = t1.elapsed().as_secs_f64();
        Ok(system)
    }

    /// Steps 2 to 5 for `scene` as `accel` traces it (its instances in order), lit by the
    /// scene's sun: what a renderer needs for [`SppLight`].
    pub fn for_scene(
        scene: &sylva_geom::Scene,
        accel: &SceneAccel,
        config: SystemConfig,
    ) -> Result<SppSystem, TreeError> {
        let meshes = SceneMeshes::new(&scene.models, accel);
        let mut system = SppSystem::build(&scene.models, &scene.instances, accel, &meshes, config)?;
        let t = scene.sun.travel();
        system.set_light(
            &scene.models,
            accel,
            &meshes,
            Vec3::new(t.x as f32, t.y as f32, t.z as f32),
        )?;
        system.update_sky();
        Ok(system)
    }

    /// Step 5: maps along the light `dir` (the direction light travels in) for every
    /// prototype, then depth, thickness and G at every grid point.
    pub fn set_light(
        &mut self,
        models: &[Model],
        accel: &SceneAccel,
        meshes: &SceneMeshes,
        dir: Vec3,
    ) -> Result<(), TreeError> {
        let len = dir.length();
        if !(len.is_finite() && len > 0.0) {
            return Err(TreeError::invalid(
                "light direction",
                format!("{dir}"),
                "must be a finite, non-zero vector",
            ));
        }
        let dir = dir / len;
        let t0 = Instant::now();
        for proto in self.prototypes.iter_mut() {
            let m = proto.model as usize;
            let build = |res| {
                DeepOpacityMap::build(
                    &models[m],
                    &accel.models()[m],
                    &meshes.models[m],
                    proto.world_to_model * dir,
                    res,
                )
            };
            proto.light_maps = Some([build(self.config.map)?, build(self.config.light_map)?]);
        }
        self.light = Some((dir, PlaneIndex::new(dir, &self.boxes)));
        self.timings.light_maps = t0.elapsed().as_secs_f64();

        let t1 = Instant::now();
        let mus: Vec<f64> = self.directions.iter().map(|s| s.dot(dir) as f64).collect();
        let n_dirs = self.directions.len();
        let this = &*self;
        let updated: Vec<(Vec<f32>, Vec<[f32; 2]>)> = self
            .grids
            .par_iter()
            .map(|grid| {
                let cells = grid.points();
                let mut g = vec![1.0f32; cells];
                let mut light = vec![[0.0f32; 2]; cells];
                for p in 0..cells {
                    let x = grid.point(p);
                    let (z0, w) = this.light_depth_at(x, 0);
                    light[p] = [z0, w];
                    let depths = &grid.depths[p * n_dirs..(p + 1) * n_dirs];
                    g[p] = g_factor(
                        z0 as f64,
                        w as f64,
                        mus.iter().zip(depths).map(|(&mu, &tau)| (mu, tau as f64)),
                    ) as f32;
                }
                (g, light)
            })
            .collect();
        for (grid, (g, light)) in self.grids.iter_mut().zip(updated) {
            grid.g = g;
            grid.light = light;
        }
        self.timings.light_grid = t1.elapsed().as_secs_f64();
        Ok(())
    }

    /// Step 4: the fraction of a uniform sky's light reaching every grid point, the mean of
    /// `e^{−d}` over the sample directions that travel downwards.
    pub fn update_sky(&mut self) {
        let t0 = Instant::now();
        let down: Vec<usize> = (0..self.directions.len())
            .filter(|&j| self.directions[j].y < 0.0)
            .collect();
        let n_dirs = self.directions.len();
        self.grids.par_iter_mut().for_each(|grid| {
            for p in 0..grid.points() {
                let d = &grid.depths[p * n_dirs..(p + 1) * n_dirs];
                grid.sky[p] = if down.is_empty() {
                    1.0
                } else {
                    down.iter().map(|&j| (-d[j]).exp()).sum::<f32>() / down.len() as f32
                };
            }
        });
        self.timings.sky = t0.elapsed().as_secs_f64();
    }

    /// Eq. 31 in sample direction `j`: the surfaces crossed before world point `x` along the
    /// direction, summed over the instances (each prototype's map at `x` in its model space),
    /// and along the whole line: `(depth, thickness)`.
    pub fn depth(&self, x: Vec3, j: usize) -> (f32, f32) {
        let (mut d, mut w) = (0.0, 0.0);
        for &i in self.index[j].at(x) {
            let proto = &self.prototypes[self.instance_proto[i as usize] as usize];
            let (a, b) =
                proto.maps[j].depth_and_total(self.to_model[i as usize].transform_point3(x));
            d += a;
            w += b;
        }
        (d, w)
    }

    /// Eq. 31 along the light at full resolution: `(depth, thickness)` at world point `x` (0
    /// before a light is set).
    pub fn light_depth(&self, x: Vec3) -> (f32, f32) {
        self.light_depth_at(x, 1)
    }

    /// Eq. 31 along the light with the coarse (`0`) or the full-resolution (`1`) maps.
    fn light_depth_at(&self, x: Vec3, which: usize) -> (f32, f32) {
        let Some((_, index)) = &self.light else {
            return (0.0, 0.0);
        };
        let (mut d, mut w) = (0.0, 0.0);
        for &i in index.at(x) {
            let proto = &self.prototypes[self.instance_proto[i as usize] as usize];
            if let Some(maps) = &proto.light_maps {
                let p = self.to_model[i as usize].transform_point3(x);
                let (a, b) = maps[which].depth_and_total(p);
                d += a;
                w += b;
            }
        }
        (d, w)
    }

    /// The G-factor at world point `x` on instance `instance` (trilinear in its grid).
    pub fn g(&self, instance: usize, x: Vec3) -> f32 {
        let grid = &self.grids[instance];
        grid.sample(&grid.g, x)
    }

    /// The sky's light reaching world point `x` on (or under) instance `instance`.
    pub fn sky(&self, instance: usize, x: Vec3) -> f32 {
        let grid = &self.grids[instance];
        grid.sample(&grid.sky, x)
    }

    /// The sky's light reaching a ground point `p`: the lowest value of the grids of the
    /// instances standing over it (1 in the open). A grid ends at its instance's box while
    /// the shade goes on, so, as the LB light does, the value fades to 1 over the outer 20 %
    /// of the box's footprint and no edge shows.
    pub fn ground_sky(&self, p: Vec3) -> f32 {
        let mut f = 1.0f32;
        for &i in self.vertical.at(p) {
            let b = &self.boxes[i as usize];
            if p.x >= b.min.x && p.x <= b.max.x && p.z >= b.min.z && p.z <= b.max.z {
                let sky = self.sky(i as usize, Vec3::new(p.x, b.min.y.max(p.y), p.z));
                let edge = (p.x - b.min.x)
                    .min(b.max.x - p.x)
                    .min(p.z - b.min.z)
                    .min(b.max.z - p.z);
                let width = 0.2 * (b.max.x - b.min.x).min(b.max.z - b.min.z);
                let w = if width > 0.0 {
                    (edge / width).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                f = f.min(1.0 + (sky - 1.0) * w);
            }
        }
        f
    }

    /// The light's direction of travel, once set.
    pub fn light_dir(&self) -> Option<Vec3> {
        self.light.as_ref().map(|(d, _)| *d)
    }

    pub fn directions(&self) -> &[Vec3] {
        &self.directions
    }

    pub fn prototypes(&self) -> &[Prototype] {
        &self.prototypes
    }

    pub fn config(&self) -> SystemConfig {
        self.config
    }

    /// Grid points over all instances (003 Table 4's "cells").
    pub fn cells(&self) -> usize {
        self.grids.iter().map(InstanceGrid::points).sum()
    }

    /// Bytes of the maps and grids.
    pub fn memory_bytes(&self) -> u64 {
        let maps: u64 = self
            .prototypes
            .iter()
            .flat_map(|p| p.maps.iter().chain(p.light_maps.iter().flatten()))
            .map(DeepOpacityMap::memory_bytes)
            .sum();
        maps + self
            .grids
            .iter()
            .map(InstanceGrid::memory_bytes)
            .sum::<u64>()
    }
}

/// The SPP light of a plant as sylva's renderer takes it ([`sylva_light::IndirectLight`]):
/// the compensated diffuse field at the point, per colour, as a fluence in the units of the
/// LB light (unobstructed sunlight is 1). The diffuse fluxes `E±` of a field isotropic within
/// each hemisphere make the fluence `2(E+ + E−)`, and the renderer's `--indirect` 0.5 turns a
/// fluence into a leaf's irradiance, `G (E+ + E−)` ([`super::shading`]). The direct sunlight
/// is the renderer's own (exact shadows), so eq. 28's `G I_pp + (1 − G) I0 = I0 + G · diffuse`
/// is what the image gets.
pub struct SppLight<'a> {
    pub system: &'a SppSystem,
    /// One model per colour (the leaves' albedo per colour).
    pub colours: [TreeSpp; 3],
}

impl<'a> SppLight<'a> {
    /// The light of `system` for leaves of albedo `σs/σt` per colour of the LB preset
    /// `preset` (the scene's `[lb] preset`), so that it compares with the LB light.
    pub fn with_preset(system: &'a SppSystem, preset: &str) -> Result<SppLight<'a>, TreeError> {
        let params = sylva_lb::Preset::parse(preset)?.params();
        let mut colours = [TreeSpp::new(0.0)?; 3];
        for (c, p) in colours.iter_mut().zip(&params.colours) {
            *c = TreeSpp::new(p.sigma_s / p.sigma_t())?;
        }
        Ok(SppLight { system, colours })
    }
}

impl sylva_light::IndirectLight for SppLight<'_> {
    fn plant(&self, instance: u32, _: &TraceInstance, world: Vec3) -> Option<Vec3> {
        let (d, w) = self.system.light_depth(world);
        let g = self.system.g(instance as usize, world).clamp(0.0, 1.0);
        let mut out = [0.0f32; 3];
        for (o, spp) in out.iter_mut().zip(&self.colours) {
            let (ep, em) = spp.diffuse(d as f64, w as f64).ok()?;
            *o = 2.0 * g * (ep + em) as f32;
        }
        Some(Vec3::from_array(out))
    }

    fn ground_sky(&self, p: Vec3) -> Vec3 {
        Vec3::splat(self.system.ground_sky(p))
    }

    fn memory_bytes(&self) -> u64 {
        self.system.memory_bytes()
    }

    fn device(&self) -> Result<&dyn sylva_light::DeviceLight, sylva_light::NoDevice> {
        Err(sylva_light::NoDevice(
            "the plane-parallel light (deep opacity maps, eq. 28's diffuse fluxes) has no GPU \
             kernel; the CPU shades it, the GPU traces the rays",
        ))
    }
}
