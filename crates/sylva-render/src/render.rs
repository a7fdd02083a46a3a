//! The frame: primary rays, shadow rays and shading over 8×8 tiles on rayon, in bands of image
//! rows so memory stays bounded, and the comparison modes of paper 000 Fig. 2.
//!
//! Every pixel's samples depend only on the pixel, the sample index and the seed, so a frame is
//! bit-identical for any thread count.

use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sylva_core::colour::luminance;
use sylva_core::SplitMix64;
use sylva_geom::Scene;
use sylva_trace::{
    Hit, OccluderCache, PinholeCamera, Ray, SceneAccel, TraceError, TraceStats, TraversalConfig,
    PACKET,
};

use crate::lighting::ModelLighting;
use crate::shade::{
    local_light, needs_shadow_ray, shade_materials, Radiance, ShadeMaterial, ShadingParams,
    SurfacePoint,
};

/// Tile edge in pixels.
pub const TILE: u32 = 8;
/// Samples held at once (hits and shading inputs): about 100 MB.
const BAND_SAMPLES: usize = 1 << 21;

/// The four images of paper 000 Fig. 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Local sunlight plus LB indirect light.
    Full,
    /// Local sunlight only.
    Local,
    /// Local sunlight plus a constant ambient whose image mean luminance equals the full one.
    Ambient,
    /// The LB indirect light alone (texture-modulated); escaped rays are black.
    Lb,
}

impl Mode {
    pub const ALL: [Mode; 4] = [Mode::Full, Mode::Local, Mode::Ambient, Mode::Lb];

    pub fn parse(s: &str) -> Option<Mode> {
        Some(match s {
            "full" => Mode::Full,
            "local" => Mode::Local,
            "ambient" => Mode::Ambient,
            "lb" => Mode::Lb,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Mode::Full => "full",
            Mode::Local => "local",
            Mode::Ambient => "ambient",
            Mode::Lb => "lb",
        }
    }

    /// Whether the mode needs the LB lighting grids.
    pub fn needs_lb(self) -> bool {
        self != Mode::Local
    }
}

/// What a frame is rendered with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel, averaged (box filter) before tone mapping. 1: the pixel centre;
    /// 4: a 2×2 grid; a square k²: jittered k×k strata; otherwise jittered random positions.
    pub rays_per_pixel: u32,
    /// Seed of the jitter.
    pub seed: u64,
    pub traversal: TraversalConfig,
    pub shading: ShadingParams,
}

/// Wall time and ray counts of a frame's passes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameTimings {
    pub primary_seconds: f64,
    pub shadow_seconds: f64,
    pub shading_seconds: f64,
    pub primary_rays: u64,
    pub shadow_rays: u64,
}

impl FrameTimings {
    pub fn trace_seconds(&self) -> f64 {
        self.primary_seconds + self.shadow_seconds
    }

    pub fn frame_seconds(&self) -> f64 {
        self.primary_seconds + self.shadow_seconds + self.shading_seconds
    }

    /// Primary and shadow rays per second of tracing, in millions.
    pub fn mrays_per_second(&self) -> f64 {
        (self.primary_rays + self.shadow_rays) as f64 / self.trace_seconds().max(1e-12) * 1e-6
    }
}

/// A rendered frame: per pixel the parts the modes combine, averaged over the samples.
#[derive(Debug, Clone)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Radiance>,
    pub timings: FrameTimings,
    pub stats: TraceStats,
}

/// Mean luminance of linear pixels (f64 sum in pixel order: deterministic).
pub fn mean_luminance(pixels: &[[f32; 3]]) -> f64 {
    if pixels.is_empty() {
        return 0.0;
    }
    pixels.iter().map(|p| luminance(*p) as f64).sum::<f64>() / pixels.len() as f64
}

impl Frame {
    /// The constant ambient of [`Mode::Ambient`]: `c` with `mean L(local + sky + c · albedo) =
    /// mean L(full)`. Luminance is linear, so `c = mean L(indirect) / mean L(albedo)`.
    pub fn matched_ambient(&self) -> f32 {
        let sum = |f: fn(&Radiance) -> Vec3| {
            self.pixels
                .iter()
                .map(|r| luminance(f(r).to_array()) as f64)
                .sum::<f64>()
        };
        let albedo = sum(|r| r.albedo);
        if albedo > 0.0 {
            (sum(|r| r.indirect) / albedo) as f32
        } else {
            0.0
        }
    }

    /// The linear HDR image of `mode`.
    pub fn compose(&self, mode: Mode) -> Vec<[f32; 3]> {
        let ambient = if mode == Mode::Ambient {
            self.matched_ambient()
        } else {
            0.0
        };
        self.pixels
            .iter()
            .map(|r| {
                let c = match mode {
                    Mode::Full => r.local + r.indirect + r.sky,
                    Mode::Local => r.local + r.sky,
                    Mode::Ambient => r.local + r.sky + r.albedo * ambient,
                    Mode::Lb => r.indirect,
                };
                c.to_array()
            })
            .collect()
    }
}

/// Sub-pixel position of sample `s` of `n` in pixel `pixel`.
fn sample_offset(n: u32, s: u32, pixel: u64, seed: u64) -> Vec2 {
    if n == 1 {
        return Vec2::splat(0.5);
    }
    if n == 4 {
        return Vec2::new(0.25 + 0.5 * (s % 2) as f32, 0.25 + 0.5 * (s / 2) as f32);
    }
    let mut rng = SplitMix64::for_chunk(seed, pixel * n as u64 + s as u64);
    let j = Vec2::new(rng.next_f64() as f32, rng.next_f64() as f32);
    let k = (n as f64).sqrt().round() as u32;
    if k * k == n {
        (Vec2::new((s % k) as f32, (s / k) as f32) + j) / k as f32
    } else {
        j
    }
}

/// One tile's primary rays and hits (pixel by pixel, sample by sample) and their counters.
type TileHits = (Vec<(Ray, Option<Hit>)>, TraceStats);

/// The inputs of shading one sample, found by the shadow pass.
#[derive(Debug, Clone, Copy)]
enum SampleGeom {
    Sky,
    Ground {
        point: Vec3,
        lit: bool,
    },
    Plant {
        point: Vec3,
        normal: Vec3,
        lit: bool,
    },
}

/// The scene, its acceleration structure and lighting, ready to render frames.
pub struct Renderer<'a> {
    scene: &'a Scene,
    accel: &'a SceneAccel,
    lighting: &'a [Option<ModelLighting>],
    materials: Vec<Vec<ShadeMaterial>>,
    to_sun: Vec3,
    /// Sun colour × irradiance.
    sun: Vec3,
    ground_colour: Vec3,
    sky: Vec3,
    /// Instances over each ground cell, for the LB light under trees.
    ground_index: GroundIndex,
}

impl<'a> Renderer<'a> {
    /// `lighting[m]` is model `m`'s LB light (`None`: no indirect light on it); `to_sun` the
    /// unit vector towards the sun; `sun_colour` its linear RGB (luminance 1 for 6500 K).
    pub fn new(
        scene: &'a Scene,
        accel: &'a SceneAccel,
        lighting: &'a [Option<ModelLighting>],
        to_sun: Vec3,
        sun_colour: Vec3,
        sun_irradiance: f32,
    ) -> Renderer<'a> {
        assert_eq!(lighting.len(), scene.models.len(), "one lighting per model");
        Renderer {
            scene,
            accel,
            lighting,
            materials: shade_materials(&scene.models),
            to_sun: to_sun.normalize(),
            sun: sun_colour * sun_irradiance,
            ground_colour: Vec3::from_array(scene.ground.color),
            sky: Vec3::from_array(scene.sky_color),
            ground_index: if lighting.iter().any(Option::is_some) {
                GroundIndex::new(accel)
            } else {
                GroundIndex::default()
            },
        }
    }

    /// How much of the sky light reaches the ground at `point`: the product, over the trees
    /// whose LB grid covers it, of their LB luminance there (1 in free space, less in a crown's
    /// shade), clamped to [0, 1]. 1 away from trees.
    fn ground_lb_factor(&self, point: Vec3) -> f32 {
        let mut f = 1.0f32;
        for &i in self.ground_index.at(point) {
            let inst = &self.accel.instances()[i as usize];
            let Some(l) = &self.lighting[inst.model as usize] else {
                continue;
            };
            let b = &self.scene.models[inst.model as usize].bounds;
            let pm = inst.to_model.transform_point3(point);
            // Trees stand on the ground; a model floating above it has no LB light down here.
            let margin = 0.05 * (b.max.y - b.min.y) + 1e-3;
            if pm.x >= b.min.x
                && pm.x <= b.max.x
                && pm.z >= b.min.z
                && pm.z <= b.max.z
                && pm.y >= b.min.y - margin
            {
                // The grid ends at the model's box while its shade on the ground would go on:
                // fade to open sky over the box's outer 20 % so no edge shows.
                let edge = (pm.x - b.min.x)
                    .min(b.max.x - pm.x)
                    .min(pm.z - b.min.z)
                    .min(b.max.z - pm.z);
                let width = 0.2 * (b.max.x - b.min.x).min(b.max.z - b.min.z);
                let w = if width > 0.0 {
                    (edge / width).clamp(0.0, 1.0)
                } else {
                    1.0
                };
                let lb = luminance(l.sample(pm).to_array()).clamp(0.0, 1.0);
                f *= 1.0 - w * (1.0 - lb);
            }
        }
        f
    }

    /// Renders the scene's camera view at `settings`' resolution. `progress(n)` is called from
    /// worker threads as tiles finish each of the three passes (3 × tiles units in all).
    pub fn render(
        &self,
        settings: &RenderSettings,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<Frame, TraceError> {
        let mut cam = self.scene.camera;
        cam.width = settings.width;
        cam.height = settings.height;
        let camera = PinholeCamera::new(&cam)?;
        let (w, h, n) = (
            settings.width,
            settings.height,
            settings.rays_per_pixel.max(1),
        );
        let mut pixels = vec![Radiance::default(); w as usize * h as usize];
        let mut timings = FrameTimings::default();
        let mut stats = TraceStats::default();
        // Bands of whole tile rows.
        let tile_rows = h.div_ceil(TILE);
        let row_samples = (w as usize * TILE as usize * n as usize).max(1);
        let band_rows = (BAND_SAMPLES / row_samples).clamp(1, tile_rows as usize) as u32;
        let mut row = 0;
        while row < tile_rows {
            let rows = band_rows.min(tile_rows - row);
            let tiles = band_tiles(w, h, row * TILE, rows);
            self.render_band(
                &camera,
                &tiles,
                settings,
                n,
                &mut pixels,
                &mut timings,
                &mut stats,
                progress,
            );
            row += rows;
        }
        Ok(Frame {
            width: w,
            height: h,
            pixels,
            timings,
            stats,
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn render_band(
        &self,
        camera: &PinholeCamera,
        tiles: &[Tile],
        settings: &RenderSettings,
        n: u32,
        pixels: &mut [Radiance],
        timings: &mut FrameTimings,
        stats: &mut TraceStats,
        progress: &(dyn Fn(u64) + Sync),
    ) {
        let cfg = settings.traversal;
        let w = camera.width;
        // Primary rays, then the shadow rays of the same tile at once: a shadow ray starts
        // where its primary ray ended, so its walk down to that point in the model's tree
        // finds the nodes and triangles the primary ray just loaded still in cache. Each
        // tile times its two halves; the pass's wall time is split in their proportion.
        let t0 = Instant::now();
        let traced: Vec<(TileHits, Vec<SampleGeom>, TraceStats, [f64; 2])> = tiles
            .par_iter()
            .map(|tile| {
                let start = Instant::now();
                let mut st = TraceStats::default();
                let mut out = Vec::with_capacity(tile.pixels() * n as usize);
                for (x, y) in tile.iter() {
                    let pixel = y as u64 * w as u64 + x as u64;
                    for s in 0..n {
                        let o = sample_offset(n, s, pixel, settings.seed);
                        out.push((camera.ray(x as f32 + o.x, y as f32 + o.y), None));
                    }
                }
                // Packets of neighbouring rays share their way through the trees; each
                // ray's hit is the one it would find alone.
                for group in tile.packets(n) {
                    let mut rays = [out[group[0]].0; PACKET];
                    let mut mask = 0u32;
                    for (l, &i) in group.iter().enumerate() {
                        if i != usize::MAX {
                            rays[l] = out[i].0;
                            mask |= 1 << l;
                        }
                    }
                    let hits = self.accel.closest_hit_packet(&rays, mask, cfg, &mut st);
                    for (l, &i) in group.iter().enumerate() {
                        if i != usize::MAX {
                            out[i].1 = hits[l];
                        }
                    }
                }
                progress(1);
                let mid = Instant::now();
                let mut sst = TraceStats::default();
                // One occluder cache per tile: the result never depends on it, and per tile
                // even the work counters do not depend on the thread count.
                let mut cache = OccluderCache::new();
                let g = out
                    .iter()
                    .map(|(ray, hit)| {
                        self.sample_geometry(ray, hit.as_ref(), cfg, &mut sst, &mut cache)
                    })
                    .collect();
                progress(1);
                let end = Instant::now();
                let halves = [(mid - start).as_secs_f64(), (end - mid).as_secs_f64()];
                ((out, st), g, sst, halves)
            })
            .collect();
        let wall = t0.elapsed().as_secs_f64();
        let mut busy = [0f64; 2];
        let mut primary = Vec::with_capacity(traced.len());
        let mut geoms = Vec::with_capacity(traced.len());
        for ((samples, st), g, sst, halves) in traced {
            timings.primary_rays += samples.len() as u64;
            timings.shadow_rays += sst.rays;
            *stats += st;
            *stats += sst;
            busy[0] += halves[0];
            busy[1] += halves[1];
            primary.push(samples);
            geoms.push(g);
        }
        let share = busy[0] / (busy[0] + busy[1]).max(1e-12);
        timings.primary_seconds += wall * share;
        timings.shadow_seconds += wall * (1.0 - share);
        // Shading.
        let t2 = Instant::now();
        let inv_n = 1.0 / n as f32;
        let shaded: Vec<Vec<Radiance>> = tiles
            .par_iter()
            .zip(primary.par_iter().zip(geoms.par_iter()))
            .map(|(tile, (samples, g))| {
                let mut out = Vec::with_capacity(tile.pixels());
                for (k, _) in tile.iter().enumerate() {
                    let mut acc = Radiance::default();
                    for s in 0..n as usize {
                        let i = k * n as usize + s;
                        let (ray, hit) = &samples[i];
                        acc += self.shade(ray, hit.as_ref(), &g[i], &settings.shading);
                    }
                    out.push(acc * inv_n);
                }
                progress(1);
                out
            })
            .collect();
        for (tile, values) in tiles.iter().zip(shaded) {
            for ((x, y), v) in tile.iter().zip(values) {
                pixels[y as usize * w as usize + x as usize] = v;
            }
        }
        timings.shading_seconds += t2.elapsed().as_secs_f64();
    }

    /// The hit point, viewer-facing normal, and whether the sun reaches it (shadow ray).
    fn sample_geometry(
        &self,
        ray: &Ray,
        hit: Option<&Hit>,
        cfg: TraversalConfig,
        st: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> SampleGeom {
        let Some(hit) = hit else {
            return SampleGeom::Sky;
        };
        let point = ray.at(hit.t);
        let view = -ray.dir;
        if hit.is_ground() {
            let lit = self.to_sun.y > 0.0 && !self.shadowed(point, Vec3::Y, None, cfg, st, cache);
            return SampleGeom::Ground { point, lit };
        }
        let ng = self.accel.geometric_normal(hit);
        let inst = &self.accel.instances()[hit.instance as usize];
        let mesh = &self.scene.models[inst.model as usize].mesh;
        let tri = mesh.indices[hit.triangle as usize];
        let (u, v) = (hit.u, hit.v);
        let ns = if mesh.normals.len() == mesh.positions.len() {
            let n = |k: u32| Vec3::from_array(mesh.normals[k as usize]);
            let m = n(tri[0]) * (1.0 - u - v) + n(tri[1]) * u + n(tri[2]) * v;
            inst.to_world.transform_vector3(m).normalize_or_zero()
        } else {
            Vec3::ZERO
        };
        let mut normal = if ns == Vec3::ZERO || !ns.is_finite() {
            ng
        } else if ns.dot(ng) < 0.0 {
            -ns
        } else {
            ns
        };
        // Two-sided: the side the viewer sees.
        let ng_view = if ng.dot(view) < 0.0 { -ng } else { ng };
        if normal.dot(ng_view) < 0.0 {
            normal = -normal;
        }
        let leaf = self.is_leaf(inst.model, hit.triangle);
        let probe = SurfacePoint {
            normal,
            view,
            colour: Vec3::ONE,
            leaf,
        };
        let lit = needs_shadow_ray(&probe, self.to_sun)
            && !self.shadowed(point, ng, Some(hit.instance), cfg, st, cache);
        SampleGeom::Plant { point, normal, lit }
    }

    fn is_leaf(&self, model: u32, triangle: u32) -> bool {
        let mesh = &self.scene.models[model as usize].mesh;
        let m = mesh
            .material_ids
            .get(triangle as usize)
            .copied()
            .unwrap_or(0) as usize;
        self.materials[model as usize]
            .get(m)
            .is_some_and(|m| m.leaf)
    }

    /// Whether something opaque lies between `point` (on instance `from`, if any) and the
    /// sun. The ray starts a little off the surface on the sun's side of the geometric
    /// normal `ng`.
    fn shadowed(
        &self,
        point: Vec3,
        ng: Vec3,
        from: Option<u32>,
        cfg: TraversalConfig,
        st: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> bool {
        let side = if ng.dot(self.to_sun) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let eps = 1e-4 * point.abs().max_element().max(1.0);
        let ray = Ray::new(point + ng * (side * eps), self.to_sun);
        self.accel.any_hit_from(&ray, from, cfg, st, cache)
    }

    fn shade(&self, ray: &Ray, hit: Option<&Hit>, g: &SampleGeom, p: &ShadingParams) -> Radiance {
        match *g {
            SampleGeom::Sky => Radiance {
                sky: self.sky,
                ..Default::default()
            },
            SampleGeom::Ground { point, lit } => {
                let c = self.ground_colour * self.sun;
                let cos = self.to_sun.y.max(0.0);
                Radiance {
                    local: if lit { c * cos } else { Vec3::ZERO },
                    indirect: c * (p.sky_ambient * self.ground_lb_factor(point)),
                    albedo: c,
                    sky: Vec3::ZERO,
                }
            }
            SampleGeom::Plant { point, normal, lit } => {
                let hit = hit.expect("plant geometry comes from a hit");
                let inst = &self.accel.instances()[hit.instance as usize];
                let mi = inst.model as usize;
                let mesh = &self.scene.models[mi].mesh;
                let tri = mesh.indices[hit.triangle as usize];
                let mat = mesh
                    .material_ids
                    .get(hit.triangle as usize)
                    .copied()
                    .unwrap_or(0);
                let material = &self.materials[mi][mat as usize];
                let colour = if material.texture.is_some() && mesh.uvs.len() == mesh.positions.len()
                {
                    let uv = |k: u32| Vec2::from_array(mesh.uvs[k as usize]);
                    let (u, v) = (hit.u, hit.v);
                    material.colour(uv(tri[0]) * (1.0 - u - v) + uv(tri[1]) * u + uv(tri[2]) * v)
                } else {
                    material.base
                };
                let s = SurfacePoint {
                    normal,
                    view: -ray.dir,
                    colour,
                    leaf: material.leaf,
                };
                let albedo = colour * self.sun;
                let indirect = match &self.lighting[mi] {
                    Some(l) => {
                        l.sample(inst.to_model.transform_point3(point)) * albedo * p.indirect
                    }
                    None => Vec3::ZERO,
                };
                Radiance {
                    local: local_light(&s, self.to_sun, lit, p) * self.sun,
                    indirect,
                    albedo,
                    sky: Vec3::ZERO,
                }
            }
        }
    }
}

/// A uniform grid over the ground (x, z) listing the instances whose world box covers each
/// cell: the ground's LB lookup visits a handful of trees, not all of them.
#[derive(Debug, Default)]
struct GroundIndex {
    origin: Vec2,
    end: Vec2,
    inv_cell: f32,
    nx: usize,
    nz: usize,
    cells: Vec<Vec<u32>>,
}

impl GroundIndex {
    /// At most this many cells a side.
    const MAX_CELLS: usize = 256;

    fn new(accel: &SceneAccel) -> GroundIndex {
        let boxes: Vec<_> = accel.instances().iter().map(|i| i.world_bounds).collect();
        if boxes.is_empty() {
            return GroundIndex::default();
        }
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        let mut footprint = 0.0f64;
        for b in &boxes {
            lo = lo.min(Vec2::new(b.min.x, b.min.z));
            hi = hi.max(Vec2::new(b.max.x, b.max.z));
            footprint += (b.max.x - b.min.x).max(b.max.z - b.min.z) as f64;
        }
        let extent = (hi - lo).max_element().max(1e-3);
        // Cells about a tree's width, but not more than MAX_CELLS a side.
        let cell = ((footprint / boxes.len() as f64) as f32).max(extent / Self::MAX_CELLS as f32);
        if !(cell.is_finite() && cell > 0.0) {
            return GroundIndex::default();
        }
        let nx = (((hi.x - lo.x) / cell).floor() as usize + 1).min(Self::MAX_CELLS);
        let nz = (((hi.y - lo.y) / cell).floor() as usize + 1).min(Self::MAX_CELLS);
        let mut index = GroundIndex {
            origin: lo,
            end: hi,
            inv_cell: 1.0 / cell,
            nx,
            nz,
            cells: vec![Vec::new(); nx * nz],
        };
        for (i, b) in boxes.iter().enumerate() {
            let (x0, z0) = index.cell_of(b.min.x, b.min.z);
            let (x1, z1) = index.cell_of(b.max.x, b.max.z);
            for z in z0..=z1 {
                for x in x0..=x1 {
                    index.cells[z * nx + x].push(i as u32);
                }
            }
        }
        index
    }

    fn cell_of(&self, x: f32, z: f32) -> (usize, usize) {
        let c = |v: f32, o: f32, n: usize| {
            (((v - o) * self.inv_cell).floor().max(0.0) as usize).min(n - 1)
        };
        (c(x, self.origin.x, self.nx), c(z, self.origin.y, self.nz))
    }

    /// Instances whose box may cover ground point `p` (a superset).
    fn at(&self, p: Vec3) -> &[u32] {
        if self.cells.is_empty() {
            return &[];
        }
        let q = Vec2::new(p.x, p.z);
        // Also false for NaN.
        let inside = q.cmpge(self.origin).all() && q.cmple(self.end).all();
        if !inside {
            return &[];
        }
        let (x, z) = self.cell_of(q.x, q.y);
        &self.cells[z * self.nx + x]
    }
}

/// An image tile `[x0, x1) × [y0, y1)`.
#[derive(Debug, Clone, Copy)]
struct Tile {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
}

impl Tile {
    fn pixels(&self) -> usize {
        ((self.x1 - self.x0) * (self.y1 - self.y0)) as usize
    }

    /// Pixels row by row.
    fn iter(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        (self.y0..self.y1).flat_map(move |y| (self.x0..self.x1).map(move |x| (x, y)))
    }

    /// The tile's samples (`n` per pixel, indexed in [`Tile::iter`] order, sample by sample)
    /// in packets of [`PACKET`] neighbours: 2×2 pixels at one sample per pixel, else runs
    /// of a pixel's samples. `usize::MAX` marks an unused lane at a ragged edge.
    fn packets(&self, n: u32) -> Vec<[usize; PACKET]> {
        let (tw, th) = ((self.x1 - self.x0) as usize, (self.y1 - self.y0) as usize);
        let total = tw * th * n as usize;
        let mut out = Vec::with_capacity(total.div_ceil(PACKET));
        if n == 1 {
            for by in (0..th).step_by(2) {
                for bx in (0..tw).step_by(2) {
                    let mut g = [usize::MAX; PACKET];
                    for (l, (dx, dy)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
                        let (x, y) = (bx + dx, by + dy);
                        if x < tw && y < th {
                            g[l] = y * tw + x;
                        }
                    }
                    out.push(g);
                }
            }
        } else {
            for start in (0..total).step_by(PACKET) {
                out.push(std::array::from_fn(|l| {
                    if start + l < total {
                        start + l
                    } else {
                        usize::MAX
                    }
                }));
            }
        }
        out
    }
}

/// The tiles of `rows` tile rows starting at pixel row `y0`.
fn band_tiles(w: u32, h: u32, y0: u32, rows: u32) -> Vec<Tile> {
    let mut out = Vec::new();
    for r in 0..rows {
        let ty = y0 + r * TILE;
        for tx in (0..w).step_by(TILE as usize) {
            out.push(Tile {
                x0: tx,
                y0: ty,
                x1: (tx + TILE).min(w),
                y1: (ty + TILE).min(h),
            });
        }
    }
    // Z order: a thread's consecutive tiles cluster in both directions, so the trees seen
    // in one tile are still in cache for the tiles above and below it, not only beside it.
    // Each tile's results depend on that tile alone, so the order changes no pixel.
    out.sort_by_key(|t| morton(t.x0 / TILE, (t.y0 - y0) / TILE));
    out
}

/// Interleaves the bits of `x` and `y` (Z-order curve index).
fn morton(x: u32, y: u32) -> u64 {
    let spread = |v: u32| {
        let mut v = v as u64 & 0xffff_ffff;
        v = (v | v << 16) & 0x0000_ffff_0000_ffff;
        v = (v | v << 8) & 0x00ff_00ff_00ff_00ff;
        v = (v | v << 4) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | v << 2) & 0x3333_3333_3333_3333;
        (v | v << 1) & 0x5555_5555_5555_5555
    };
    spread(x) | spread(y) << 1
}

/// Bytes a `w × h` frame at `rays_per_pixel` holds at its peak: the per-pixel parts, the
/// composed and tone-mapped images the caller makes from them, and one band of samples.
pub fn memory_needed(w: u32, h: u32, rays_per_pixel: u32) -> u64 {
    let pixels = w as u64 * h as u64;
    let per_pixel = std::mem::size_of::<Radiance>() as u64 + 2 * 12 + 3;
    let band = (pixels * rays_per_pixel.max(1) as u64).min(BAND_SAMPLES as u64 + 64 * w as u64);
    // Per sample: ray and hit, geometry, shaded value.
    let per_sample = (std::mem::size_of::<(Ray, Option<Hit>)>()
        + std::mem::size_of::<SampleGeom>()
        + std::mem::size_of::<Radiance>()) as u64;
    pixels * per_pixel + band * per_sample
}

/// Number of tiles of a `w × h` image.
pub fn tile_count(w: u32, h: u32) -> u64 {
    w.div_ceil(TILE) as u64 * h.div_ceil(TILE) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_positions_are_stratified_and_deterministic() {
        assert_eq!(sample_offset(1, 0, 7, 1), Vec2::splat(0.5));
        let four: Vec<Vec2> = (0..4).map(|s| sample_offset(4, s, 7, 1)).collect();
        assert_eq!(four[3], Vec2::new(0.75, 0.75));
        for n in [9u32, 16] {
            let k = (n as f32).sqrt() as u32;
            let mut seen = vec![false; n as usize];
            for s in 0..n {
                let o = sample_offset(n, s, 123, 9);
                assert_eq!(o, sample_offset(n, s, 123, 9));
                let cell = (o.y * k as f32) as u32 * k + (o.x * k as f32) as u32;
                seen[cell as usize] = true;
            }
            assert!(seen.iter().all(|&b| b), "one sample per stratum");
        }
        for s in 0..5 {
            let o = sample_offset(5, s, 3, 2);
            assert!((0.0..1.0).contains(&o.x) && (0.0..1.0).contains(&o.y));
        }
    }

    #[test]
    fn tiles_cover_the_image_once() {
        let (w, h) = (21u32, 13u32);
        let mut count = vec![0; (w * h) as usize];
        let tiles = band_tiles(w, h, 0, h.div_ceil(TILE));
        assert_eq!(tiles.len() as u64, tile_count(w, h));
        for t in &tiles {
            for (x, y) in t.iter() {
                count[(y * w + x) as usize] += 1;
            }
        }
        assert!(count.iter().all(|&c| c == 1));
    }

    #[test]
    fn tiles_follow_the_z_order_curve() {
        // Bits interleaved, x in the even positions.
        assert_eq!(morton(0, 0), 0);
        assert_eq!(morton(1, 0), 1);
        assert_eq!(morton(0, 1), 2);
        assert_eq!(morton(3, 1), 0b0111);
        assert_eq!(morton(0xffff, 0), 0x5555_5555);
        assert_eq!(morton(0, 0xffff), 0xaaaa_aaaa);
        // A band of 4 × 3 tiles starting below the first tile row: 2×2 blocks first, each
        // in Z order, rows counted from the band's top.
        let (w, h) = (4 * TILE, 5 * TILE);
        let order: Vec<(u32, u32)> = band_tiles(w, h, 2 * TILE, 3)
            .iter()
            .map(|t| (t.x0 / TILE, t.y0 / TILE - 2))
            .collect();
        let want = [
            (0, 0),
            (1, 0),
            (0, 1),
            (1, 1),
            (2, 0),
            (3, 0),
            (2, 1),
            (3, 1),
            (0, 2),
            (1, 2),
            (2, 2),
            (3, 2),
        ];
        assert_eq!(order, want);
    }

    #[test]
    fn modes_parse_and_name() {
        for m in Mode::ALL {
            assert_eq!(Mode::parse(m.name()), Some(m));
        }
        assert_eq!(Mode::parse("fancy"), None);
        assert!(!Mode::Local.needs_lb() && Mode::Ambient.needs_lb());
    }
}
