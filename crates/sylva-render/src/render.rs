//! The frame: primary rays, shadow rays and shading over 8×8 tiles on rayon, in bands of image
//! rows so memory stays bounded, and the comparison modes of paper 000 Fig. 2.
//!
//! The renderer asks its questions through two seams: a [`RayQuery`] (the CPU kd-tree tracer
//! today) answers batches of closest-hit and shadow rays, and an [`IndirectLight`] (today's
//! per-model LB grids) gives the light scattered in the canopy. Participating media
//! ([`Media`], clouds) are integrated along each primary ray up to its hit, in front of what
//! it hits, and shade the sun on surfaces. What it renders is a [`RenderSettings`]: any
//! camera, and any rectangle of that camera's image.
//!
//! Every pixel's samples depend only on the pixel (its place in the whole image), the sample
//! index and the seed, so a frame is bit-identical for any thread count, and a region's
//! pixels are those of the full image.

use std::time::Instant;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sylva_core::colour::luminance;
use sylva_core::SplitMix64;
use sylva_geom::{Camera, Scene};
use sylva_trace::{Hit, PinholeCamera, Ray, RayQuery, ShadowRay, TraceError, TraceStats, PACKET};

use crate::shade::{
    indirect_light, local_light, needs_shadow_ray, Radiance, ShadeMaterial, ShadingParams,
    SurfacePoint,
};
use sylva_light::indirect::IndirectLight;
use sylva_light::lighting::Light;
use sylva_light::media::Media;

/// Tile edge in pixels.
pub const TILE: u32 = 8;
/// Mixed into the seed of the media's step jitter, so it is independent of the pixel jitter.
const MEDIA_JITTER: u64 = 0x6d65_6469_615f_6a74;
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

    /// One mode by name, or `all`: the four ([`Mode::ALL`]).
    pub fn parse_set(s: &str) -> Option<Vec<Mode>> {
        match s {
            "all" => Some(Mode::ALL.to_vec()),
            m => Mode::parse(m).map(|m| vec![m]),
        }
    }

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

/// A rectangle of an image: pixels `x0 .. x0 + width` × `y0 .. y0 + height`, row 0 at the top.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

impl Region {
    /// The whole of a `width × height` image.
    pub fn full(width: u32, height: u32) -> Region {
        Region {
            x0: 0,
            y0: 0,
            width,
            height,
        }
    }

    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Whether the region is non-empty and lies inside a `width × height` image.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        self.width > 0
            && self.height > 0
            && self.x0 as u64 + self.width as u64 <= width as u64
            && self.y0 as u64 + self.height as u64 <= height as u64
    }
}

/// What a frame is rendered with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// The view; its `width × height` is the whole image (its `rays_per_pixel` is not used).
    pub camera: Camera,
    /// The part of the camera's image to render.
    pub region: Region,
    /// Samples per pixel, averaged (box filter) before tone mapping. 1: the pixel centre;
    /// 4: a 2×2 grid; a square k²: jittered k×k strata; otherwise jittered random positions.
    pub rays_per_pixel: u32,
    /// Seed of the jitter.
    pub seed: u64,
    pub shading: ShadingParams,
}

impl RenderSettings {
    /// The whole image of `camera` at `rays_per_pixel`.
    pub fn full(
        camera: Camera,
        rays_per_pixel: u32,
        seed: u64,
        shading: ShadingParams,
    ) -> RenderSettings {
        RenderSettings {
            camera,
            region: Region::full(camera.width, camera.height),
            rays_per_pixel,
            seed,
            shading,
        }
    }
}

/// Why a frame cannot be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Camera(#[from] TraceError),
    #[error("image region {}x{} at ({}, {}) does not lie inside the {width}x{height} image", .region.width, .region.height, .region.x0, .region.y0)]
    Region {
        region: Region,
        width: u32,
        height: u32,
    },
}

/// Wall time and ray counts of a frame's passes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameTimings {
    pub primary_seconds: f64,
    pub shadow_seconds: f64,
    pub shading_seconds: f64,
    /// A GPU frame's single pass (primary rays, shadow rays and shading in one kernel, with
    /// the rays' upload and the pixels' read-back); 0 on the CPU.
    pub fused_seconds: f64,
    /// Of `fused_seconds`, the kernel's own time on the GPU's clock (0 where the device has
    /// no timestamps, and on the CPU).
    pub gpu_kernel_seconds: f64,
    pub primary_rays: u64,
    pub shadow_rays: u64,
}

impl FrameTimings {
    /// Seconds spent tracing (a fused GPU pass counts whole: its shading is a small part).
    pub fn trace_seconds(&self) -> f64 {
        self.primary_seconds + self.shadow_seconds + self.fused_seconds
    }

    pub fn frame_seconds(&self) -> f64 {
        self.primary_seconds + self.shadow_seconds + self.shading_seconds + self.fused_seconds
    }

    /// Primary and shadow rays per second of tracing, in millions.
    pub fn mrays_per_second(&self) -> f64 {
        (self.primary_rays + self.shadow_rays) as f64 / self.trace_seconds().max(1e-12) * 1e-6
    }
}

/// A rendered frame: per pixel the parts the modes combine, averaged over the samples.
/// `width × height` pixels, row by row: those of `region`.
#[derive(Debug, Clone)]
pub struct Frame {
    pub region: Region,
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

/// Sub-pixel position of sample `s` of `n` in pixel `pixel`: the centre for one sample, a
/// 2 × 2 grid for four, and otherwise a jittered grid of `rows × cols` cells, `rows` the
/// largest divisor of `n` not above its square root (4 × 8 for 32; strips for a prime).
/// Independent jitter over the whole pixel would clump: at 32 samples it left the catalpa's
/// plant error at 12.8 % where 16 on a grid reach 12.1 % (docs/PERFORMANCE.md, "Camera
/// samples and gather rays"). The jitter is random, not a sequence like the gather's R2
/// points, which share the sample's index and would tie each sample's position to its
/// gather directions.
pub(crate) fn sample_offset(n: u32, s: u32, pixel: u64, seed: u64) -> Vec2 {
    if n == 1 {
        return Vec2::splat(0.5);
    }
    if n == 4 {
        return Vec2::new(0.25 + 0.5 * (s % 2) as f32, 0.25 + 0.5 * (s / 2) as f32);
    }
    let rows = (1..=(n as f64).sqrt() as u32)
        .rev()
        .find(|r| n.is_multiple_of(*r))
        .unwrap_or(1);
    let cols = n / rows;
    let mut rng = SplitMix64::for_chunk(seed, pixel * n as u64 + s as u64);
    let j = Vec2::new(rng.next_f64() as f32, rng.next_f64() as f32);
    let cell = Vec2::new((s % cols) as f32, (s / cols) as f32);
    ((cell + j) / Vec2::new(cols as f32, rows as f32)).min(Vec2::splat(ONE_BELOW))
}

/// The largest f32 below 1: an offset rounded up to 1.0 would leave its pixel.
const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

/// Sample `s` of `n` of pixel `(x, y)` of the whole image: the primary ray.
pub(crate) fn sample_ray(camera: &PinholeCamera, x: u32, y: u32, s: u32, n: u32, seed: u64) -> Ray {
    let pixel = y as u64 * camera.width as u64 + x as u64;
    let o = sample_offset(n, s, pixel, seed);
    camera.ray(x as f32 + o.x, y as f32 + o.y)
}

/// Per pixel of `settings.region` (row-major), the share of its samples whose primary ray
/// hits a plant (not the ground, not the sky): the rays a frame of `settings` traces, so
/// errors can be measured on plants alone (a pixel whose every sample hit a plant is a plant
/// pixel). Media in front are not looked at.
pub fn plant_coverage(
    query: &dyn RayQuery,
    settings: &RenderSettings,
) -> Result<Vec<f32>, RenderError> {
    let camera = PinholeCamera::new(&settings.camera)?;
    let region = settings.region;
    if !region.fits(camera.width, camera.height) {
        return Err(RenderError::Region {
            region,
            width: camera.width,
            height: camera.height,
        });
    }
    let n = settings.rays_per_pixel.max(1);
    let rows: Vec<Vec<f32>> = (region.y0..region.y0 + region.height)
        .into_par_iter()
        .map(|y| {
            let rays: Vec<Ray> = (region.x0..region.x0 + region.width)
                .flat_map(|x| (0..n).map(move |s| (x, s)))
                .map(|(x, s)| sample_ray(&camera, x, y, s, n, settings.seed))
                .collect();
            let mut hits = vec![None; rays.len()];
            query.closest_hits(&rays, &mut hits, &mut TraceStats::default());
            hits.chunks(n as usize)
                .map(|h| {
                    let plant = h.iter().flatten().filter(|h| !h.is_ground()).count();
                    plant as f32 / n as f32
                })
                .collect()
        })
        .collect();
    Ok(rows.concat())
}

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
        /// The mean radiance the front's and the back's gather rays brought back
        /// ([`crate::gather`]; zero when nothing is gathered).
        gather: [Vec3; 2],
        /// The gather rays cast on each side (front, back).
        gather_rays: (u32, u32),
        /// The geometric normal on the viewer's side and whether the surface transmits
        /// (where gather rays start and which sides they take).
        ng: Vec3,
        transmits: bool,
    },
}

impl SampleGeom {
    fn set_lit(&mut self, sunlit: bool) {
        match self {
            SampleGeom::Sky => {}
            SampleGeom::Ground { lit, .. } | SampleGeom::Plant { lit, .. } => *lit = sunlit,
        }
    }

    /// One of side `side`'s gather rays brought back `radiance`.
    fn add_gathered(&mut self, side: usize, radiance: Vec3) {
        if let SampleGeom::Plant {
            gather,
            gather_rays,
            transmits,
            ..
        } = self
        {
            let count = if side == 0 {
                gather_rays.0
            } else {
                gather_rays.1
            };
            let weight = crate::gather::side_weight(gather_rays.0 + gather_rays.1, *transmits);
            gather[side] += radiance * weight / count as f32;
        }
    }
}

/// A tile's primary samples, pixel by pixel and sample by sample: ray and hit.
type TileSamples = Vec<(Ray, Option<Hit>)>;

/// One work unit's traced tiles: per tile its primary samples and their shading inputs; the
/// unit's primary and shadow counters and busy seconds.
struct TracedUnit {
    tiles: Vec<(TileSamples, Vec<SampleGeom>)>,
    primary: TraceStats,
    shadow: TraceStats,
    busy: [f64; 2],
}

/// Buffers a worker reuses from one work unit to the next: the batch in packet order and
/// where each ray came from, `(tile, sample)`.
#[derive(Default)]
struct Scratch {
    order: Vec<(usize, usize)>,
    rays: Vec<Ray>,
    hits: Vec<Option<Hit>>,
    shadow_rays: Vec<ShadowRay>,
    waiting: Vec<(usize, usize)>,
    blocked: Vec<bool>,
    /// Gather rays, whose they are, `(tile, sample, side)`, their hits and the geometry
    /// of those.
    gather_rays: Vec<Ray>,
    /// Per gather ray: its sample's tile and index, its side, and whether it traces the
    /// sun's shadow ray from its hit ([`crate::gather::traces_sun`]).
    gather_owner: Vec<(usize, usize, usize, bool)>,
    gather_hits: Vec<Option<Hit>>,
    gather_geoms: Vec<SampleGeom>,
}

/// A scene, something that answers its ray queries and its indirect light, ready to render
/// frames of any view.
pub struct Renderer<'a> {
    scene: &'a Scene,
    query: &'a dyn RayQuery,
    light: &'a dyn IndirectLight,
    materials: &'a [Vec<ShadeMaterial>],
    media: Option<&'a Media>,
    to_sun: Vec3,
    /// Sun colour × irradiance.
    sun: Vec3,
    ground_colour: Vec3,
    sky: Vec3,
}

impl<'a> Renderer<'a> {
    /// `query` traces `scene` (its instances in the scene's order); `light` gives the
    /// indirect light; `materials` are the scene's, decoded ([`crate::shade::shade_materials`]); `to_sun`
    /// the unit vector towards the sun; `sun_colour` its linear RGB (luminance 1 for 6500 K).
    pub fn new(
        scene: &'a Scene,
        query: &'a dyn RayQuery,
        light: &'a dyn IndirectLight,
        materials: &'a [Vec<ShadeMaterial>],
        to_sun: Vec3,
        sun_colour: Vec3,
        sun_irradiance: f32,
    ) -> Renderer<'a> {
        assert_eq!(materials.len(), scene.models.len(), "materials per model");
        Renderer {
            scene,
            query,
            light,
            materials,
            media: None,
            to_sun: to_sun.normalize(),
            sun: sun_colour * sun_irradiance,
            ground_colour: Vec3::from_array(scene.ground.color),
            sky: Vec3::from_array(scene.sky_color),
        }
    }

    /// Towards the sun (unit), the sun's colour × irradiance, the ground's colour and the
    /// sky's: the lights of [`Renderer::shade`], for the GPU frame.
    pub(crate) fn lights(&self) -> [Vec3; 4] {
        [self.to_sun, self.sun, self.ground_colour, self.sky]
    }

    /// Draws `media` (clouds) in front of whatever each primary ray hits, and lets them
    /// shade the sun on surfaces.
    pub fn with_media(mut self, media: &'a Media) -> Renderer<'a> {
        self.media = (!media.is_empty()).then_some(media);
        self
    }

    /// Renders `settings.region` of `settings.camera`'s image. `progress(n)` is called from
    /// worker threads as tiles finish each of the three passes (3 × tiles units in all).
    pub fn render(
        &self,
        settings: &RenderSettings,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<Frame, RenderError> {
        let camera = PinholeCamera::new(&settings.camera)?;
        let region = settings.region;
        if !region.fits(camera.width, camera.height) {
            return Err(RenderError::Region {
                region,
                width: camera.width,
                height: camera.height,
            });
        }
        let n = settings.rays_per_pixel.max(1);
        let mut pixels = vec![Radiance::default(); region.pixels() as usize];
        let mut timings = FrameTimings::default();
        let mut stats = TraceStats::default();
        // Bands of whole tile rows; tiles sit on the whole image's 8-pixel grid.
        let (first_row, end_row) = tile_rows(region);
        let row_samples = (region.width as usize * TILE as usize * n as usize).max(1);
        let band_rows =
            (BAND_SAMPLES / row_samples).clamp(1, (end_row - first_row) as usize) as u32;
        let mut row = first_row;
        while row < end_row {
            let rows = band_rows.min(end_row - row);
            let tiles = band_tiles(region, row, rows);
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
            region,
            width: region.width,
            height: region.height,
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
        // Work units of whole tiles, about the tracer's preferred batch each: on the CPU one
        // tile. A unit's primary rays, then its shadow rays at once: a shadow ray starts where
        // its primary ray ended, so its walk down to that point in the model's tree finds the
        // nodes and triangles the primary ray just loaded still in cache. Each unit times its
        // two halves; the pass's wall time is split in their proportion.
        let per_tile = (TILE * TILE * n) as usize;
        let unit_tiles = (self.query.preferred_batch() / per_tile).max(1);
        let t0 = Instant::now();
        let traced: Vec<TracedUnit> = tiles
            .par_chunks(unit_tiles)
            .map_init(Scratch::default, |scratch, unit| {
                self.trace_unit(scratch, camera, unit, settings, n, progress)
            })
            .collect();
        let wall = t0.elapsed().as_secs_f64();
        let mut busy = [0f64; 2];
        let mut primary = Vec::with_capacity(tiles.len());
        let mut geoms = Vec::with_capacity(tiles.len());
        for unit in traced {
            *stats += unit.primary;
            *stats += unit.shadow;
            timings.shadow_rays += unit.shadow.rays;
            busy[0] += unit.busy[0];
            busy[1] += unit.busy[1];
            for (samples, g) in unit.tiles {
                timings.primary_rays += samples.len() as u64;
                primary.push(samples);
                geoms.push(g);
            }
        }
        let share = busy[0] / (busy[0] + busy[1]).max(1e-12);
        timings.primary_seconds += wall * share;
        timings.shadow_seconds += wall * (1.0 - share);
        // Shading.
        let t2 = Instant::now();
        let inv_n = 1.0 / n as f32;
        let width = camera.width as u64;
        let shaded: Vec<Vec<Radiance>> = tiles
            .par_iter()
            .zip(primary.par_iter().zip(geoms.par_iter()))
            .map(|(tile, (samples, g))| {
                let mut out = Vec::with_capacity(tile.pixels());
                for (k, (x, y)) in tile.iter().enumerate() {
                    let mut acc = Radiance::default();
                    for s in 0..n as usize {
                        let i = k * n as usize + s;
                        let (ray, hit) = &samples[i];
                        let mut r = self.shade(ray, hit.as_ref(), &g[i], &settings.shading);
                        if let Some(media) = self.media {
                            let pixel = y as u64 * width + x as u64;
                            r = self.through_media(media, ray, hit.as_ref(), r, pixel, s, settings);
                        }
                        acc += r;
                    }
                    out.push(acc * inv_n);
                }
                progress(1);
                out
            })
            .collect();
        let r = settings.region;
        for (tile, values) in tiles.iter().zip(shaded) {
            for ((x, y), v) in tile.iter().zip(values) {
                pixels[(y - r.y0) as usize * r.width as usize + (x - r.x0) as usize] = v;
            }
        }
        timings.shading_seconds += t2.elapsed().as_secs_f64();
    }

    /// Primary rays of a unit's tiles (in packet order: neighbours together), then the
    /// shading inputs of every sample and the shadow rays they need.
    fn trace_unit(
        &self,
        scratch: &mut Scratch,
        camera: &PinholeCamera,
        unit: &[Tile],
        settings: &RenderSettings,
        n: u32,
        progress: &(dyn Fn(u64) + Sync),
    ) -> TracedUnit {
        let start = Instant::now();
        let mut primary = TraceStats::default();
        let mut tiles: Vec<(TileSamples, Vec<SampleGeom>)> = Vec::with_capacity(unit.len());
        scratch.order.clear();
        for (t, tile) in unit.iter().enumerate() {
            let mut out = Vec::with_capacity(tile.pixels() * n as usize);
            for (x, y) in tile.iter() {
                for s in 0..n {
                    out.push((sample_ray(camera, x, y, s, n, settings.seed), None));
                }
            }
            for group in tile.packets(n) {
                let used = group.iter().filter(|&&i| i != usize::MAX);
                scratch.order.extend(used.map(|&i| (t, i)));
            }
            tiles.push((out, Vec::new()));
        }
        scratch.rays.clear();
        scratch
            .rays
            .extend(scratch.order.iter().map(|&(t, i)| tiles[t].0[i].0));
        scratch.hits.clear();
        scratch.hits.resize(scratch.rays.len(), None);
        self.query
            .closest_hits(&scratch.rays, &mut scratch.hits, &mut primary);
        for (&(t, i), hit) in scratch.order.iter().zip(&scratch.hits) {
            tiles[t].0[i].1 = *hit;
        }
        progress(unit.len() as u64);
        let mid = Instant::now();
        let mut shadow = TraceStats::default();
        scratch.shadow_rays.clear();
        scratch.waiting.clear();
        for (t, (samples, geoms)) in tiles.iter_mut().enumerate() {
            geoms.reserve_exact(samples.len());
            for (i, (ray, hit)) in samples.iter().enumerate() {
                let (geom, shadow_ray) = self.sample_geometry(ray, hit.as_ref());
                if let Some(s) = shadow_ray {
                    scratch.shadow_rays.push(s);
                    scratch.waiting.push((t, i));
                }
                geoms.push(geom);
            }
        }
        scratch.blocked.clear();
        scratch.blocked.resize(scratch.shadow_rays.len(), false);
        self.query
            .any_hits(&scratch.shadow_rays, &mut scratch.blocked, &mut shadow);
        for (&(t, i), &blocked) in scratch.waiting.iter().zip(&scratch.blocked) {
            tiles[t].1[i].set_lit(!blocked);
        }
        if self.gathers(&settings.shading) {
            // The final gather: rays from every plant sample, the geometry they hit, the
            // sun's shadow rays of those points, then what each brings back.
            scratch.gather_rays.clear();
            scratch.gather_owner.clear();
            for (t, tile) in unit.iter().enumerate() {
                let tw = (tile.x1 - tile.x0) as usize;
                for (i, g) in tiles[t].1.iter_mut().enumerate() {
                    let k = i / n as usize;
                    let (x, y) = (tile.x0 + (k % tw) as u32, tile.y0 + (k / tw) as u32);
                    let pixel = crate::gather::pixel_key(x, y, camera.width);
                    let s = (i % n as usize) as u32;
                    self.gather_rays(g, pixel, s, settings, &mut |ray, side, sun| {
                        scratch.gather_rays.push(ray);
                        scratch.gather_owner.push((t, i, side, sun));
                    });
                }
            }
            scratch.gather_hits.clear();
            scratch.gather_hits.resize(scratch.gather_rays.len(), None);
            self.query
                .closest_hits(&scratch.gather_rays, &mut scratch.gather_hits, &mut shadow);
            scratch.gather_geoms.clear();
            scratch.shadow_rays.clear();
            scratch.waiting.clear();
            for (j, (ray, hit)) in scratch
                .gather_rays
                .iter()
                .zip(&scratch.gather_hits)
                .enumerate()
            {
                let (geom, shadow_ray) = self.sample_geometry(ray, hit.as_ref());
                if let (Some(s), true) = (shadow_ray, scratch.gather_owner[j].3) {
                    scratch.shadow_rays.push(s);
                    scratch.waiting.push((j, 0));
                }
                scratch.gather_geoms.push(geom);
            }
            scratch.blocked.clear();
            scratch.blocked.resize(scratch.shadow_rays.len(), false);
            self.query
                .any_hits(&scratch.shadow_rays, &mut scratch.blocked, &mut shadow);
            for (&(j, _), &blocked) in scratch.waiting.iter().zip(&scratch.blocked) {
                scratch.gather_geoms[j].set_lit(!blocked);
            }
            for (j, &(t, i, side, _)) in scratch.gather_owner.iter().enumerate() {
                let l = self.gathered(
                    &scratch.gather_rays[j],
                    scratch.gather_hits[j].as_ref(),
                    &scratch.gather_geoms[j],
                    &settings.shading,
                );
                tiles[t].1[i].add_gathered(side, l);
            }
        }
        progress(unit.len() as u64);
        let end = Instant::now();
        TracedUnit {
            tiles,
            primary,
            shadow,
            busy: [(mid - start).as_secs_f64(), (end - mid).as_secs_f64()],
        }
    }

    /// Pixel `(x, y)` of the whole image of `settings.camera` traced and shaded on its own,
    /// sample by sample: the value a frame holds for it, and the secondary rays (shadow and gather) it traced.
    pub fn pixel(
        &self,
        camera: &PinholeCamera,
        x: u32,
        y: u32,
        settings: &RenderSettings,
        stats: &mut TraceStats,
    ) -> (Radiance, u64) {
        let n = settings.rays_per_pixel.max(1);
        let mut acc = Radiance::default();
        let mut shadow_rays = 0;
        for s in 0..n {
            let ray = sample_ray(camera, x, y, s, n, settings.seed);
            let (hit, mut geom) = self.trace_one(&ray, true, stats, &mut shadow_rays);
            if self.gathers(&settings.shading) {
                let pixel = crate::gather::pixel_key(x, y, camera.width);
                let mut rays = Vec::new();
                self.gather_rays(&mut geom, pixel, s, settings, &mut |r, side, sun| {
                    rays.push((r, side, sun))
                });
                for (r, side, sun) in rays {
                    shadow_rays += 1;
                    let (h, g) = self.trace_one(&r, sun, stats, &mut shadow_rays);
                    geom.add_gathered(side, self.gathered(&r, h.as_ref(), &g, &settings.shading));
                }
            }
            acc += self.shade(&ray, hit.as_ref(), &geom, &settings.shading);
        }
        (acc * (1.0 / n as f32), shadow_rays)
    }

    /// One ray's closest hit and its shading inputs, lit by its shadow ray when it needs one
    /// and `sun` allows it (counted in `shadow_rays`), each traced alone.
    fn trace_one(
        &self,
        ray: &Ray,
        sun: bool,
        stats: &mut TraceStats,
        shadow_rays: &mut u64,
    ) -> (Option<Hit>, SampleGeom) {
        let mut hit = [None];
        self.query
            .closest_hits(std::slice::from_ref(ray), &mut hit, stats);
        let (mut geom, shadow) = self.sample_geometry(ray, hit[0].as_ref());
        if let (Some(shadow), true) = (shadow, sun) {
            let mut blocked = [false];
            self.query.any_hits(&[shadow], &mut blocked, stats);
            geom.set_lit(!blocked[0]);
            *shadow_rays += 1;
        }
        (hit[0], geom)
    }

    /// The hit point and viewer-facing normal (not yet lit), and the shadow ray that decides
    /// whether the sun reaches it, when one is needed.
    fn sample_geometry(&self, ray: &Ray, hit: Option<&Hit>) -> (SampleGeom, Option<ShadowRay>) {
        let Some(hit) = hit else {
            return (SampleGeom::Sky, None);
        };
        let point = ray.at(hit.t);
        let view = -ray.dir;
        if hit.is_ground() {
            let shadow = (self.to_sun.y > 0.0).then(|| self.shadow_ray(point, Vec3::Y, None));
            return (SampleGeom::Ground { point, lit: false }, shadow);
        }
        let ng = self.query.geometric_normal(hit);
        let inst = &self.query.instances()[hit.instance as usize];
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
        let material = self.material(inst.model, hit.triangle);
        let leaf = material.is_some_and(|m| m.leaf);
        let transmits =
            leaf && material.is_some_and(|m| m.optics.transmit.iter().any(|&t| t > 0.0));
        let probe = SurfacePoint {
            normal,
            view,
            colour: Vec3::ONE,
            leaf,
            optics: sylva_geom::Optics::OPAQUE,
        };
        let shadow = needs_shadow_ray(&probe, self.to_sun)
            .then(|| self.shadow_ray(point, ng, Some(hit.instance)));
        (
            SampleGeom::Plant {
                point,
                normal,
                lit: false,
                gather: [Vec3::ZERO; 2],
                gather_rays: (0, 0),
                ng: ng_view,
                transmits,
            },
            shadow,
        )
    }

    /// The material of `triangle` of `model` (material 0 past the id list, as on the GPU).
    fn material(&self, model: u32, triangle: u32) -> Option<&ShadeMaterial> {
        let mesh = &self.scene.models[model as usize].mesh;
        let m = mesh
            .material_ids
            .get(triangle as usize)
            .copied()
            .unwrap_or(0) as usize;
        self.materials[model as usize].get(m)
    }

    /// The final gather's rays per plant sample, 0 when it does not gather (for the GPU
    /// frame).
    pub(crate) fn gather_count(&self, p: &ShadingParams) -> u32 {
        if self.gathers(p) {
            p.gather_rays
        } else {
            0
        }
    }

    /// Whether plants' indirect light is gathered ([`crate::gather`]): the physical light and
    /// an indirect light that has it ([`IndirectLight::gatherable`]).
    fn gathers(&self, p: &ShadingParams) -> bool {
        p.light == Light::Physical && p.gather_rays > 0 && self.light.gatherable()
    }

    /// A plant sample's gather rays ([`crate::gather`]): `settings.shading.gather_rays` split
    /// between its front and (leaves that transmit) back, cosine-distributed about the
    /// shading normal and its opposite, each handed to `cast` with its side and whether it
    /// traces its hit's shadow ray ([`crate::gather::traces_sun`]). Sets the sample's ray
    /// counts.
    fn gather_rays(
        &self,
        g: &mut SampleGeom,
        pixel: u32,
        sample: u32,
        settings: &RenderSettings,
        cast: &mut dyn FnMut(Ray, usize, bool),
    ) {
        let SampleGeom::Plant {
            point,
            normal,
            gather_rays,
            ng,
            transmits,
            ..
        } = g
        else {
            return;
        };
        *gather_rays = crate::gather::split(
            settings.shading.gather_rays,
            *transmits,
            settings.seed,
            pixel,
            sample,
        );
        let eps = 1e-4 * point.abs().max_element().max(1.0);
        for (side, count, n) in [(0, gather_rays.0, *normal), (1, gather_rays.1, -*normal)] {
            for j in 0..count {
                let index = sample.wrapping_mul(count).wrapping_add(j);
                let u = crate::gather::sample_point(settings.seed, pixel, side as u32, index);
                let dir = crate::gather::cosine_direction(n, u);
                // Off the surface on the ray's side of the triangle (as Renderer::shadow_ray).
                let off = if dir.dot(*ng) >= 0.0 { eps } else { -eps };
                let sun = crate::gather::traces_sun(settings.seed, pixel, side as u32, index);
                cast(Ray::new(*point + *ng * off, dir), side, sun);
            }
        }
    }

    /// The radiance a gather ray brings back: what the surface it hits sends back along it,
    /// its direct sunlight and its LB light ([`Renderer::shade`] of that point, `g` lit by
    /// its own shadow ray), or the sky where it hits nothing (in any direction, as a camera
    /// ray past the ground's edge sees it). One gather ray in
    /// [`crate::gather::SUN_SHADOW_EVERY`] traces the sun at its hit, so its direct sunlight
    /// counts that many times (the others' `g` is unlit).
    fn gathered(&self, ray: &Ray, hit: Option<&Hit>, g: &SampleGeom, p: &ShadingParams) -> Vec3 {
        let r = self.shade(ray, hit, g, p);
        r.local * crate::gather::SUN_SHADOW_EVERY as f32 + r.indirect + r.sky
    }

    /// The ray towards the sun from `point` (on instance `from`, if any), starting a little
    /// off the surface on the sun's side of the geometric normal `ng`.
    fn shadow_ray(&self, point: Vec3, ng: Vec3, from: Option<u32>) -> ShadowRay {
        let side = if ng.dot(self.to_sun) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let eps = 1e-4 * point.abs().max_element().max(1.0);
        ShadowRay {
            ray: Ray::new(point + ng * (side * eps), self.to_sun),
            from,
        }
    }

    /// `r`, the light from what the primary ray hit, seen through the media in front of it,
    /// plus what they scatter towards the viewer. Surfaces lit by the sun get the media's
    /// shadow. The step jitter depends on the pixel, the sample and the seed only.
    #[allow(clippy::too_many_arguments)]
    fn through_media(
        &self,
        media: &Media,
        ray: &Ray,
        hit: Option<&Hit>,
        mut r: Radiance,
        pixel: u64,
        sample: usize,
        settings: &RenderSettings,
    ) -> Radiance {
        let t_max = hit.map_or(f32::INFINITY, |h| h.t);
        if r.local != Vec3::ZERO {
            r.local *= media.sun_transmittance(ray.at(t_max));
        }
        let n = settings.rays_per_pixel.max(1) as u64;
        let jitter = SplitMix64::for_chunk(settings.seed ^ MEDIA_JITTER, pixel * n + sample as u64)
            .next_f64() as f32;
        let seg = media.integrate(ray.origin, ray.dir, t_max, jitter);
        let t = seg.transmittance;
        Radiance {
            local: seg.local + t * r.local,
            indirect: seg.indirect + t * r.indirect,
            albedo: seg.albedo + t * r.albedo,
            sky: t * r.sky,
        }
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
                let local = if lit { c * cos } else { Vec3::ZERO };
                match p.light {
                    // The open ground takes π L_sky from the sky: L_sky in units of E0.
                    Light::Physical => Radiance {
                        local,
                        indirect: self.ground_colour * self.sky * self.light.ground_sky(point),
                        albedo: self.ground_colour,
                        sky: Vec3::ZERO,
                    },
                    Light::Paper => Radiance {
                        local,
                        indirect: c * (p.sky_ambient * self.light.ground_sky(point).x),
                        albedo: c,
                        sky: Vec3::ZERO,
                    },
                }
            }
            SampleGeom::Plant {
                point,
                normal,
                lit,
                gather,
                gather_rays,
                ..
            } => {
                let hit = hit.expect("plant geometry comes from a hit");
                let inst = &self.query.instances()[hit.instance as usize];
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
                    optics: material.optics,
                };
                let albedo = match p.light {
                    Light::Physical => s.albedo(Light::Physical),
                    Light::Paper => colour * self.sun,
                };
                let indirect = if gather_rays != (0, 0) {
                    // Gathered: R of the light in front, T of the light behind.
                    (s.reflectance() * gather[0] + s.transmittance() * gather[1]) * p.indirect
                } else {
                    match self.light.plant(hit.instance, inst, point) {
                        Some(l) => indirect_light(&s, l, self.sun, p),
                        None => Vec3::ZERO,
                    }
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

/// The tile rows of the whole image's 8-pixel grid that `r` covers: `first..end`.
fn tile_rows(r: Region) -> (u32, u32) {
    (r.y0 / TILE, (r.y0 + r.height).div_ceil(TILE))
}

/// The tile columns of the whole image's grid that `r` covers: `first..end`.
fn tile_columns(r: Region) -> (u32, u32) {
    (r.x0 / TILE, (r.x0 + r.width).div_ceil(TILE))
}

/// The tiles of tile rows `row..row + rows` clipped to `r`.
fn band_tiles(r: Region, row: u32, rows: u32) -> Vec<Tile> {
    let (x_end, y_end) = (r.x0 + r.width, r.y0 + r.height);
    let (first, end) = tile_columns(r);
    let mut out = Vec::new();
    for ty in row..row + rows {
        for tx in first..end {
            out.push(Tile {
                x0: (tx * TILE).max(r.x0),
                y0: (ty * TILE).max(r.y0),
                x1: ((tx + 1) * TILE).min(x_end),
                y1: ((ty + 1) * TILE).min(y_end),
            });
        }
    }
    // Z order: a thread's consecutive tiles cluster in both directions, so the trees seen
    // in one tile are still in cache for the tiles above and below it, not only beside it.
    // Each tile's results depend on that tile alone, so the order changes no pixel.
    out.sort_by_key(|t| morton(t.x0 / TILE - first, t.y0 / TILE - row));
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

/// Bytes a frame of `w × h` pixels (a whole image or a region) at `rays_per_pixel` holds at
/// its peak: the per-pixel parts, the composed and tone-mapped images the caller makes from
/// them, and one band of samples.
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

/// Bytes the images made from a `w × h` frame hold at their peak: per image the composed
/// linear image and its tone-mapped 8-bit copy (15 B/pixel), and the encoding of one image
/// at a time (the EXR's pixel copy and file, 24 B/pixel). Measured peaks of `sylva render`
/// grow by 95 B/pixel with one image and HDR, 145 with `--mode all --hdr`; this and
/// [`memory_needed`] give 114 and 159.
pub fn output_memory_needed(w: u32, h: u32, images: usize) -> u64 {
    w as u64 * h as u64 * (15 * images.max(1) as u64 + 24)
}

/// Number of tiles a frame of region `r` is rendered in.
pub fn tile_count(r: Region) -> u64 {
    let ((r0, r1), (c0, c1)) = (tile_rows(r), tile_columns(r));
    (r1 - r0) as u64 * (c1 - c0) as u64
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
    fn counts_off_a_square_take_one_cell_each_of_a_grid() {
        // A pixel's samples fill a rows × cols grid, one per cell (32: 4 × 8; a prime: strips
        // across), where independent jitter would leave cells empty in most pixels.
        for (n, rows) in [(2u32, 1u32), (8, 2), (32, 4), (48, 6), (7, 1)] {
            let cols = n / rows;
            for pixel in 0..16u64 {
                let mut seen = vec![false; n as usize];
                for s in 0..n {
                    let o = sample_offset(n, s, pixel, 11);
                    assert_eq!(o, sample_offset(n, s, pixel, 11));
                    assert!(
                        (0.0..1.0).contains(&o.x) && (0.0..1.0).contains(&o.y),
                        "{o}"
                    );
                    let cell = (o.y * rows as f32) as u32 * cols + (o.x * cols as f32) as u32;
                    seen[cell as usize] = true;
                }
                assert!(
                    seen.iter().all(|&b| b),
                    "n {n} pixel {pixel}: a cell left empty"
                );
            }
        }
    }

    #[test]
    fn tiles_cover_the_image_once() {
        let (w, h) = (21u32, 13u32);
        let mut count = vec![0; (w * h) as usize];
        let tiles = band_tiles(Region::full(w, h), 0, h.div_ceil(TILE));
        assert_eq!(tiles.len() as u64, tile_count(Region::full(w, h)));
        for t in &tiles {
            for (x, y) in t.iter() {
                count[(y * w + x) as usize] += 1;
            }
        }
        assert!(count.iter().all(|&c| c == 1));
        // A region's tiles cover it once, on the whole image's grid.
        let r = Region {
            x0: 5,
            y0: 3,
            width: 13,
            height: 9,
        };
        let (first, end) = tile_rows(r);
        assert_eq!((first, end), (0, 2));
        let tiles = band_tiles(r, first, end - first);
        assert_eq!(tiles.len() as u64, tile_count(r));
        let mut count = vec![0; (w * h) as usize];
        for t in &tiles {
            assert!(t.x0 % TILE == 0 || t.x0 == r.x0);
            assert!(t.y0 % TILE == 0 || t.y0 == r.y0);
            for (x, y) in t.iter() {
                count[(y * w + x) as usize] += 1;
            }
        }
        for y in 0..h {
            for x in 0..w {
                let inside = (5..18).contains(&x) && (3..12).contains(&y);
                assert_eq!(count[(y * w + x) as usize], inside as i32, "({x}, {y})");
            }
        }
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
        let order: Vec<(u32, u32)> = band_tiles(Region::full(w, h), 2, 3)
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
