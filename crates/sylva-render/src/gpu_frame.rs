//! Frames on a GPU: primary rays, shadow rays and shading in one compute kernel per band of
//! image rows (`shade.wgsl`, which mirrors the CPU's `Renderer::sample_geometry`,
//! `Renderer::shade`, `shade::local_light`, `ModelLighting::sample` and
//! `ModelGridLight::ground_sky` function by function), over the scene the [`GpuTracer`] put
//! on the device.
//!
//! The kernel makes the camera rays as the CPU renderer's `sample_ray` does (the same
//! arithmetic; jittered sub-pixel offsets, drawn from a 64-bit generator, come from the
//! host), and the host uploads the shading data once: per model its mesh indices, vertex
//! normals and texture coordinates, material ids, materials with their linear textures; the
//! instances' world transforms; then the LB light as the light packs itself (its records per
//! model, the ground index: [`DeviceLight`], which names no light type here), and the light's
//! per-sun words in a buffer of their own, rewritten when the sun moves
//! ([`GpuFrame::relight`]).
//! A pixel whose rays the kernel hands back (a ray lying in a kd-tree split plane) is
//! rendered by the CPU renderer, so every pixel is what the CPU would make of it.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use sylva_geom::{Scene, Wrap};
use sylva_trace::{PinholeCamera, TraceStats};
use sylva_trace_gpu::split::{storage_entry, uniform_entry, SplitArray};
use sylva_trace_gpu::{GpuTracer, TraceGpuError, SCENE_GROUP};
use sylva_wgpu::{wgpu, GpuContext, GpuError, PassTimer};

use crate::render::{sample_offset, Frame, FrameTimings, RenderError, RenderSettings, Renderer};
use crate::shade::{Radiance, ShadeMaterial};
use sylva_lb::light::SHEET_RADIANCE_PER_FLUENCE;
use sylva_light::device::{DeviceLight, NONE};
use sylva_light::lighting::Light;

/// The kernel and the shading functions it calls (after the scene's WGSL).
const SHADE_WGSL: &str = include_str!("shade.wgsl");
/// Samples in flight at once, as the CPU renderer's bands.
const BAND_SAMPLES: usize = 1 << 21;
/// Bytes per uploaded sample offset (jittered sampling only), per pixel's radiance (four
/// RGB parts) and per pixel on the device in all (radiance and a flag word).
const OFFSET_BYTES: u64 = 8;
const RADIANCE_BYTES: u64 = 48;
const PIXEL_BYTES: u64 = RADIANCE_BYTES + 4;
/// A pixel's flag word: the CPU must render it (a ray lay in a split plane); below this bit,
/// the shadow rays it traced.
const TO_CPU: u32 = 1 << 31;

/// `FrameParams` in shade.wgsl: the band and the camera the kernel makes its rays with
/// (`PinholeCamera::ray` of `sample_ray`).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameParams {
    /// Band width and rows, samples per pixel, 1 / samples as f32 bits.
    size: [u32; 4],
    /// The band's first pixel (x0, y0) in the image; the image's width and height.
    origin: [u32; 4],
    position: [f32; 4],
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    /// tan(fov / 2), width / height.
    lens: [f32; 4],
}

impl FrameParams {
    fn new(c: &PinholeCamera, x0: u32, y0: u32, w: u32, rows: u32, n: u32, inv_n: f32) -> Self {
        let v4 = |v: Vec3| [v.x, v.y, v.z, 0.0];
        FrameParams {
            size: [w, rows, n, inv_n.to_bits()],
            origin: [x0, y0, c.width, c.height],
            position: v4(c.position),
            forward: v4(c.forward),
            right: v4(c.right),
            up: v4(c.up),
            lens: [c.tan_half(), c.aspect(), 0.0, 0.0],
        }
    }
}

/// `ShadeParams` in shade.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct ShadeParams {
    sun: [f32; 4],
    to_sun: [f32; 4],
    ground_colour: [f32; 4],
    sky: [f32; 4],
    leaf_transmission: [f32; 4],
    k: [f32; 4],
    k2: [f32; 4],
    tables: [u32; 4],
    ground: [u32; 4],
    ground_box: [f32; 4],
    ground_cell: [f32; 4],
    /// The final gather: rays per plant sample (0: none), the seed's low and high 32 bits,
    /// and one in how many of its rays traces the sun at its hit.
    gather: [u32; 4],
}

/// The shading data as one array of words, and where its tables start.
#[derive(Default)]
struct Pool {
    words: Vec<u32>,
    params: ShadeParams,
    /// Where the models' records start, and the light's words (the pool's last).
    models: u32,
    light_at: u32,
    ground: Option<sylva_light::device::DeviceGround>,
}

/// Words of a material record (shade.wgsl: MATERIAL_WORDS).
const MATERIAL_WORDS: usize = 16;

impl Pool {
    fn at(&self) -> u32 {
        self.words.len() as u32
    }

    fn f(&mut self, v: f32) {
        self.words.push(v.to_bits());
    }

    fn v3(&mut self, v: Vec3) {
        self.f(v.x);
        self.f(v.y);
        self.f(v.z);
    }

    /// Per model its record (8 words: indices, normals, uvs, material ids, materials,
    /// material count, LB light, 0) and data; the instances' world transforms; the LB light
    /// as `light` packs it (its records, the ground index).
    fn build(scene: &Scene, materials: &[Vec<ShadeMaterial>], light: &dyn DeviceLight) -> Pool {
        let mut p = Pool::default();
        let models = p.at();
        p.words.resize(p.words.len() + 8 * scene.models.len(), 0);
        let instances = p.at();
        for inst in &scene.instances {
            let t = inst.transform();
            p.v3(t.matrix3.x_axis.into());
            p.v3(t.matrix3.y_axis.into());
            p.v3(t.matrix3.z_axis.into());
            p.v3(t.translation.into());
        }
        for (m, model) in scene.models.iter().enumerate() {
            let mesh = &model.mesh;
            let mut rec = [NONE; 8];
            rec[0] = p.at();
            p.words.extend(mesh.indices.iter().flatten());
            if mesh.normals.len() == mesh.positions.len() {
                rec[1] = p.at();
                p.words
                    .extend(mesh.normals.iter().flatten().map(|v| v.to_bits()));
            }
            if mesh.uvs.len() == mesh.positions.len() {
                rec[2] = p.at();
                p.words
                    .extend(mesh.uvs.iter().flatten().map(|v| v.to_bits()));
            }
            if !mesh.material_ids.is_empty() {
                rec[3] = p.at();
                // Four ids per word; triangles past the list have material 0, as on the CPU.
                for four in mesh.material_ids.chunks(4) {
                    let w = four
                        .iter()
                        .enumerate()
                        .fold(0u32, |w, (k, &id)| w | (id as u32) << (8 * k));
                    p.words.push(w);
                }
            }
            // Material records, then their textures.
            let mats = &materials[m];
            rec[4] = p.at();
            rec[5] = mats.len() as u32;
            p.words
                .resize(p.words.len() + MATERIAL_WORDS * mats.len(), 0);
            for (k, mat) in mats.iter().enumerate() {
                let r = rec[4] as usize + MATERIAL_WORDS * k;
                p.words[r] = mat.leaf as u32;
                p.words[r + 1..r + 4].copy_from_slice(&mat.base.to_array().map(f32::to_bits));
                p.words[r + 4] = NONE;
                p.words[r + 8..r + 11].copy_from_slice(&mat.optics.reflect.map(f32::to_bits));
                p.words[r + 11..r + 14].copy_from_slice(&mat.optics.transmit.map(f32::to_bits));
                if let Some(tex) = &mat.texture {
                    let (w, h, wrap, texels) = tex.raw();
                    let at = p.at();
                    for &t in texels {
                        p.v3(t);
                    }
                    let wrap = match wrap {
                        Wrap::Repeat => 0,
                        Wrap::Clamp => 1,
                    };
                    p.words[r + 4..r + 8].copy_from_slice(&[at, w, h, wrap]);
                }
            }
            rec[7] = 0;
            let at = (models + 8 * m as u32) as usize;
            p.words[at..at + 8].copy_from_slice(&rec);
        }
        // The LB light after the meshes; each model's record says where its part starts.
        p.models = models;
        p.light_at = p.at();
        let packed = light.pack(&mut p.words);
        p.ground = packed.ground;
        for m in 0..scene.models.len() {
            let at = models as usize + 8 * m + 6;
            p.words[at] = packed.records.get(m).copied().unwrap_or(NONE);
        }
        p.params.tables = [models, instances, 0, light.kind().code()];
        if let Some(g) = packed.ground {
            p.params.ground = [g.starts, g.lists, g.nx, g.nz];
            p.params.ground_box = g.bounds;
            p.params.ground_cell = [g.inv_cell, 0.0, 0.0, 0.0];
        }
        p
    }
}

/// Device bytes of a scene's shading data (for memory checks and reports).
pub fn shading_bytes(scene: &Scene, light: &dyn DeviceLight) -> u64 {
    let mut words = 8 * scene.models.len() as u64 + 24 * scene.instances.len() as u64;
    for m in &scene.models {
        let mesh = &m.mesh;
        words += 3 * mesh.indices.len() as u64
            + 5 * mesh.positions.len() as u64
            + mesh.material_ids.len() as u64 / 4
            + MATERIAL_WORDS as u64 * m.materials.len() as u64;
        for mat in &m.materials {
            if let Some(t) = &mat.texture {
                words += 3 * t.pixels.len() as u64;
            }
        }
    }
    words += light.pool_words() + light.sun_capacity() as u64;
    words * 4
}

/// The shading data on the device and the frame kernel.
pub struct GpuFrame {
    ctx: GpuContext,
    /// The light's per-sun words (the relit light's per-instance combinations; a
    /// placeholder word for per-sun grids) and their capacity in words.
    relit: wgpu::Buffer,
    relit_capacity: usize,
    /// The light's free-space luminance as f32 bits (the relit light's ambient may change).
    free_space: AtomicU32,
    pool: SplitArray,
    /// Models, where their records start, and where the light's words start in the pool
    /// and its ground index (for [`GpuFrame::repack`]).
    models: usize,
    models_at: u32,
    light_at: u32,
    ground: Option<sylva_light::device::DeviceGround>,
    params: wgpu::Buffer,
    base: ShadeParams,
    shade_group: wgpu::BindGroup,
    frame_layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    max_binding: u64,
    /// Invocations per workgroup along x and y: 8, or 1 on a software adapter, where
    /// lavapipe lost iterations of the final gather's loop when the invocations of one SIMD
    /// batch left it at different times (each invocation alone gave the CPU's pixel).
    tile: u32,
    cpu_pixels: AtomicU64,
    /// The last frame's ray, pixel and read-back buffers, reused while they are large enough
    /// (creating and zeroing them each frame cost more than the kernel on small frames).
    buffers: Mutex<Option<FrameBuffers>>,
    /// The kernel's time on the GPU's clock, where the device has timestamps.
    timer: Option<PassTimer>,
}

/// A band's buffers on the device.
struct FrameBuffers {
    /// Sub-pixel offsets of jittered samples (one entry when the kernel makes its own).
    offsets_buf: wgpu::Buffer,
    /// Radiance per pixel, 12 floats.
    pixels: wgpu::Buffer,
    /// A flag word per pixel ([`TO_CPU`], shadow rays).
    flags: wgpu::Buffer,
    /// The radiance, then (at `flags_at`) the flags, for the host.
    staging: wgpu::Buffer,
    flags_at: u64,
    params: wgpu::Buffer,
    group: wgpu::BindGroup,
    /// Offsets and pixels they hold.
    offsets: usize,
    pixel_count: usize,
}

impl GpuFrame {
    /// Uploads the shading data of `scene` (traced by `tracer`, materials decoded, LB light:
    /// the device side of the scene's indirect light, [`sylva_light::IndirectLight::device`])
    /// and builds the kernel.
    pub fn new(
        tracer: &GpuTracer,
        scene: &Scene,
        materials: &[Vec<ShadeMaterial>],
        light: &dyn DeviceLight,
    ) -> Result<GpuFrame, TraceGpuError> {
        let ctx = tracer.context().clone();
        let tile: u32 = if ctx.is_software() { 1 } else { 8 };
        sylva_core::check_memory(
            "the scene's shading data for the GPU (host staging)",
            shading_bytes(scene, light),
        )?;
        let pool = Pool::build(scene, materials, light);
        let (models_at, light_at, ground) = (pool.models, pool.light_at, pool.ground);
        if pool.words.len() > u32::MAX as usize {
            return Err(TraceGpuError::TooLarge(format!(
                "the scene's shading data ({}) exceed the kernel's 32-bit word offsets",
                sylva_core::format_bytes(4 * pool.words.len() as u64)
            )));
        }
        let limits = ctx.limits();
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let words = SplitArray::upload(
            &ctx,
            "shade_word",
            "u32",
            4,
            bytemuck::cast_slice(&pool.words),
            max_binding,
        )?;
        drop(pool.words);
        // The light's per-sun words, rewritten when the sun moves (a binding holds a word
        // at least).
        let relit_words = light.sun_capacity().max(1);
        let relit = ctx.buffer(
            "relit words",
            4 * relit_words as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        )?;
        if relit_words as u64 * 4 > max_binding {
            return Err(TraceGpuError::TooLarge(format!(
                "the relit light's combinations ({}) exceed one storage binding ({})",
                sylva_core::format_bytes(relit_words as u64 * 4),
                sylva_core::format_bytes(max_binding)
            )));
        }
        // The scene's bindings, the pool's, the relit words and the frame's own three.
        let need = tracer.scene().storage_bindings() + words.bindings() + 4;
        let allowed = limits.max_storage_buffers_per_shader_stage;
        if need > allowed {
            return Err(TraceGpuError::TooLarge(format!(
                "the scene and its shading data take {need} storage bindings; the adapter allows {allowed} per shader stage"
            )));
        }
        let params = ctx.buffer(
            "shading params",
            std::mem::size_of::<ShadeParams>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        let relit_binding = 1 + words.bindings();
        let mut entries = vec![uniform_entry(0)];
        entries.extend(words.layout_entries(1));
        entries.push(storage_entry(relit_binding, true));
        let shade_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("shading"),
                entries: &entries,
            });
        let mut group_entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: params.as_entire_binding(),
        }];
        group_entries.extend(words.group_entries(1));
        group_entries.push(wgpu::BindGroupEntry {
            binding: relit_binding,
            resource: relit.as_entire_binding(),
        });
        let shade_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shading"),
            layout: &shade_layout,
            entries: &group_entries,
        });
        let frame_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("frame"),
                entries: &[
                    uniform_entry(0),
                    storage_entry(1, true),
                    storage_entry(2, false),
                    storage_entry(3, false),
                ],
            });
        let src = format!(
            "{}\n// Shading data (sylva-render/src/gpu_frame.rs).\n\
             @group(1) @binding(0) var<uniform> shading: ShadeParams;\n{}\n\
             @group(1) @binding({relit_binding}) var<storage, read> relit_words: array<u32>;\n\
             fn relit_word_at(i: u32) -> u32 {{ return relit_words[i]; }}\n{}",
            tracer.scene().wgsl(),
            words.declare(1, 1),
            SHADE_WGSL.replace(
                "@workgroup_size(8, 8)",
                &format!("@workgroup_size({tile}, {tile})")
            )
        );
        debug_assert_eq!(SCENE_GROUP, 0);
        let module = tracer.scene().module(&ctx, "frame", src);
        let layout = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("frame"),
                bind_group_layouts: &[
                    Some(tracer.scene().layout()),
                    Some(&shade_layout),
                    Some(&frame_layout),
                ],
                immediate_size: 0,
            });
        let pipeline = ctx
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("frame"),
                layout: Some(&layout),
                module: &module,
                entry_point: Some("render_frame"),
                compilation_options: Default::default(),
                cache: None,
            });
        ctx.check("building the GPU frame kernel")?;
        let timer = PassTimer::new(&ctx, 1)?;
        let frame = GpuFrame {
            ctx,
            relit,
            relit_capacity: relit_words,
            free_space: AtomicU32::new(1f32.to_bits()),
            pool: words,
            models: scene.models.len(),
            models_at,
            light_at,
            ground,
            params,
            base: pool.params,
            shade_group,
            frame_layout,
            pipeline,
            max_binding,
            tile,
            cpu_pixels: AtomicU64::new(0),
            buffers: Mutex::new(None),
            timer,
        };
        frame.relight(light)?;
        Ok(frame)
    }

    /// Uploads the light's per-sun words for its current sun (after its own update, e.g.
    /// `RelitLight::relight`); what the light packed into the pool stays.
    pub fn relight(&self, light: &dyn DeviceLight) -> Result<(), GpuError> {
        let sun = light.sun_words();
        if sun.words.len() > self.relit_capacity {
            return Err(GpuError::TooLarge(format!(
                "{} words of the light's per-sun data for a buffer of {}",
                sun.words.len(),
                self.relit_capacity
            )));
        }
        if !sun.words.is_empty() {
            self.ctx
                .queue
                .write_buffer(&self.relit, 0, bytemuck::cast_slice(&sun.words));
        }
        self.free_space
            .store(sun.free_space.to_bits(), Ordering::Relaxed);
        Ok(())
    }

    /// Packs `light` again for its current sun over its words in the pool as uploaded (a
    /// light decoded per sun, [`DeviceLight::pool_per_sun`]), then its sun words: the kernel
    /// and the rest of the pool stay. `Ok(false)`, nothing written: its words no longer have
    /// the uploaded size (other grids for this sun); the frame must be made again.
    pub fn repack(&self, light: &dyn DeviceLight) -> Result<bool, GpuError> {
        let at = self.light_at as usize;
        let mut words = vec![0u32; at];
        let packed = light.pack(&mut words);
        if words.len() as u64 != self.pool.len()
            || packed.ground != self.ground
            || light.sun_capacity() > self.relit_capacity
        {
            return Ok(false);
        }
        // Each model's record says where its light starts.
        for m in 0..self.models {
            let r = packed.records.get(m).copied().unwrap_or(NONE);
            let word = self.models_at as u64 + 8 * m as u64 + 6;
            self.pool.write(&self.ctx, word, bytemuck::bytes_of(&r))?;
        }
        self.pool
            .write(&self.ctx, at as u64, bytemuck::cast_slice(&words[at..]))?;
        self.relight(light)?;
        Ok(true)
    }

    /// Bytes of shading data on the device.
    pub fn device_bytes(&self) -> u64 {
        self.pool.bytes()
    }

    /// Pixels the CPU rendered for the kernel so far (their rays lay in a split plane).
    pub fn cpu_pixels(&self) -> u64 {
        self.cpu_pixels.load(Ordering::Relaxed)
    }

    /// Renders `settings.region` of `settings.camera`'s image on the GPU; `cpu` (the CPU
    /// renderer over the same scene, lights and tracer) renders the pixels the kernel hands
    /// back. `progress(n)` counts tiles × 3 as the CPU renderer does.
    pub fn render(
        &self,
        tracer: &GpuTracer,
        cpu: &Renderer,
        settings: &RenderSettings,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<Frame, FrameError> {
        let t0 = Instant::now();
        let camera = PinholeCamera::new(&settings.camera).map_err(RenderError::from)?;
        let region = settings.region;
        if !region.fits(camera.width, camera.height) {
            return Err(RenderError::Region {
                region,
                width: camera.width,
                height: camera.height,
            }
            .into());
        }
        let n = settings.rays_per_pixel.max(1);
        let w = region.width as usize;
        // Samples whose sub-pixel offsets the kernel cannot make itself (n other than 1 and
        // 4: jittered from the seed's 64-bit generator) are uploaded, 8 bytes each.
        let jittered = n != 1 && n != 4;
        let row_samples = w * n as usize;
        let row_offset_bytes = if jittered {
            row_samples as u64 * OFFSET_BYTES
        } else {
            0
        };
        if row_offset_bytes > self.max_binding || w as u64 * PIXEL_BYTES > self.max_binding {
            return Err(GpuError::TooLarge(format!(
                "one image row of {w} pixels × {n} samples exceeds the adapter's {} per storage binding",
                sylva_core::format_bytes(self.max_binding)
            ))
            .into());
        }
        let band_rows = (BAND_SAMPLES / row_samples)
            .min((self.max_binding / row_offset_bytes.max(1)) as usize)
            .min((self.max_binding / (w as u64 * PIXEL_BYTES)) as usize)
            .clamp(1, region.height as usize);
        self.write_params(cpu, settings);
        let ctx = &self.ctx;
        let mut held = self.buffers.lock().expect("frame buffers");
        let (need_offsets, need_pixels) = (
            if jittered { band_rows * row_samples } else { 1 },
            band_rows * w,
        );
        let fits = held
            .as_ref()
            .is_some_and(|b| b.offsets >= need_offsets && b.pixel_count >= need_pixels);
        if !fits {
            *held = None;
            *held = Some(self.buffers(need_offsets, need_pixels)?);
        }
        let bufs = held.as_ref().expect("frame buffers made");
        let mut kernel_seconds = 0.0;
        // Filled band by band from the read-back, in parallel (a frame's 10-20 MB written
        // once: no zeroing pass whose page faults cost more than the kernel).
        let mut pixels: Vec<Radiance> = Vec::with_capacity(region.pixels() as usize);
        let mut stats = TraceStats::default();
        let mut shadow_rays = 0u64;
        let tiles = 3 * crate::render::tile_count(region);
        let mut reported = 0u64;
        let mut offsets = Vec::new();
        let inv_n = 1.0 / n as f32;
        let mut row = 0usize;
        // SYLVA_GPU_PROFILE=1: each frame's host phases on stderr (docs/gpu.md).
        let profile = std::env::var_os("SYLVA_GPU_PROFILE").is_some();
        let mut phases = [0.0f64; 4];
        let mut lap = Instant::now();
        let mut mark = |k: usize, phases: &mut [f64; 4]| {
            if profile {
                phases[k] += lap.elapsed().as_secs_f64();
                lap = Instant::now();
            }
        };
        while row < region.height as usize {
            let rows = band_rows.min(region.height as usize - row);
            let y0 = region.y0 + row as u32;
            if jittered {
                offsets.clear();
                offsets.resize(rows * row_samples, [0f32; 2]);
                offsets
                    .par_chunks_mut(row_samples)
                    .enumerate()
                    .for_each(|(r, out)| {
                        let y = y0 + r as u32;
                        for (k, o) in out.iter_mut().enumerate() {
                            let x = region.x0 + (k / n as usize) as u32;
                            let s = (k % n as usize) as u32;
                            let pixel = y as u64 * camera.width as u64 + x as u64;
                            *o = sample_offset(n, s, pixel, settings.seed).to_array();
                        }
                    });
                ctx.queue
                    .write_buffer(&bufs.offsets_buf, 0, bytemuck::cast_slice(&offsets));
            }
            let params = FrameParams::new(&camera, region.x0, y0, w as u32, rows as u32, n, inv_n);
            ctx.queue
                .write_buffer(&bufs.params, 0, bytemuck::bytes_of(&params));
            mark(0, &mut phases);
            let mut enc = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("frame"),
                    timestamp_writes: self.timer.as_ref().map(|t| t.writes(0)),
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, tracer.scene().group(), &[]);
                pass.set_bind_group(1, &self.shade_group, &[]);
                pass.set_bind_group(2, &bufs.group, &[]);
                let tile = self.tile as usize;
                pass.dispatch_workgroups(w.div_ceil(tile) as u32, rows.div_ceil(tile) as u32, 1);
            }
            let band_pixels = rows * w;
            let (radiance_bytes, flag_bytes) =
                (band_pixels as u64 * RADIANCE_BYTES, band_pixels as u64 * 4);
            enc.copy_buffer_to_buffer(&bufs.pixels, 0, &bufs.staging, 0, radiance_bytes);
            enc.copy_buffer_to_buffer(&bufs.flags, 0, &bufs.staging, bufs.flags_at, flag_bytes);
            if let Some(t) = &self.timer {
                t.resolve(&mut enc, 1);
            }
            ctx.queue.submit([enc.finish()]);
            mark(1, &mut phases);
            let flags_at = bufs.flags_at as usize;
            let pixels_ref = &mut pixels;
            let (handed_back, traced) =
                ctx.map_read_with(&bufs.staging, bufs.flags_at + flag_bytes, |data| {
                    let values: &[f32] = bytemuck::cast_slice(&data[..radiance_bytes as usize]);
                    let flags: &[u32] =
                        bytemuck::cast_slice(&data[flags_at..flags_at + flag_bytes as usize]);
                    // Radiance per pixel as the kernel packs it: local, indirect, albedo, sky.
                    pixels_ref.par_extend(values.par_chunks_exact(12).map(|v| Radiance {
                        local: Vec3::new(v[0], v[1], v[2]),
                        indirect: Vec3::new(v[3], v[4], v[5]),
                        albedo: Vec3::new(v[6], v[7], v[8]),
                        sky: Vec3::new(v[9], v[10], v[11]),
                    }));
                    let mut back = Vec::new();
                    let mut traced = 0u64;
                    for (k, &f) in flags.iter().enumerate() {
                        if f & TO_CPU != 0 {
                            back.push(k);
                        } else {
                            traced += f as u64;
                        }
                    }
                    (back, traced)
                })?;
            mark(2, &mut phases);
            shadow_rays += traced;
            if let Some(t) = &self.timer {
                kernel_seconds += t.seconds(ctx, 1)?.iter().sum::<f64>();
            }
            for k in handed_back {
                let (x, y) = (region.x0 + (k % w) as u32, y0 + (k / w) as u32);
                let (r, s) = cpu.pixel(&camera, x, y, settings, &mut stats);
                pixels[row * w + k] = r;
                shadow_rays += s;
                self.cpu_pixels.fetch_add(1, Ordering::Relaxed);
            }
            mark(3, &mut phases);
            row += rows;
            let done = tiles * row as u64 / region.height as u64;
            progress(done - reported);
            reported = done;
        }
        if profile {
            let ms = phases.map(|s| s * 1e3);
            eprintln!(
                "GPU frame {}x{} at {n} rays/pixel: host set-up {:.2} ms, submit {:.2} ms, kernel + read-back + unpacking {:.2} ms (kernel {:.2} ms), CPU pixels {:.2} ms",
                region.width, region.height, ms[0], ms[1], ms[2], kernel_seconds * 1e3, ms[3]
            );
        }
        let primary_rays = region.pixels() * n as u64;
        // The CPU's single-ray counts for handed-back pixels are in `stats` already.
        stats.rays = primary_rays + shadow_rays;
        Ok(Frame {
            region,
            width: region.width,
            height: region.height,
            pixels,
            timings: FrameTimings {
                fused_seconds: t0.elapsed().as_secs_f64(),
                gpu_kernel_seconds: kernel_seconds,
                primary_rays,
                shadow_rays,
                ..FrameTimings::default()
            },
            stats,
        })
    }

    /// Buffers for bands of up to `offsets` uploaded sample offsets and `pixel_count` pixels.
    fn buffers(&self, offsets: usize, pixel_count: usize) -> Result<FrameBuffers, GpuError> {
        let ctx = &self.ctx;
        let offsets_buf = ctx.buffer(
            "frame sample offsets",
            offsets.max(1) as u64 * OFFSET_BYTES,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        )?;
        let radiance_bytes = pixel_count as u64 * RADIANCE_BYTES;
        let pixels = ctx.buffer(
            "frame pixels",
            radiance_bytes,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let flags = ctx.buffer(
            "frame pixel flags",
            pixel_count as u64 * 4,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )?;
        // Copies into the staging buffer start at multiples of 4 bytes (radiance_bytes is).
        let flags_at = radiance_bytes;
        let staging = ctx.buffer(
            "frame readback",
            flags_at + pixel_count as u64 * 4,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let params = ctx.buffer(
            "frame params",
            std::mem::size_of::<FrameParams>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry {
                binding,
                resource: buffer.as_entire_binding(),
            }
        }
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &self.frame_layout,
            entries: &[
                entry(0, &params),
                entry(1, &offsets_buf),
                entry(2, &pixels),
                entry(3, &flags),
            ],
        });
        Ok(FrameBuffers {
            offsets_buf,
            pixels,
            flags,
            staging,
            flags_at,
            params,
            group,
            offsets: offsets.max(1),
            pixel_count,
        })
    }

    /// The lights of `cpu` and the shading constants of `settings` into the uniform.
    fn write_params(&self, cpu: &Renderer, settings: &RenderSettings) {
        let [to_sun, sun, ground, sky] = cpu.lights();
        let s = &settings.shading;
        let v4 = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
        let p = ShadeParams {
            sun: v4(sun, f32::INFINITY),
            to_sun: v4(to_sun, 0.0),
            ground_colour: v4(ground, 0.0),
            sky: v4(sky, 0.0),
            // The final gather's rays per plant sample, the seed its directions come from and
            // one in how many of its rays traces the sun at its hit.
            gather: [
                cpu.gather_count(s),
                settings.seed as u32,
                (settings.seed >> 32) as u32,
                crate::gather::SUN_SHADOW_EVERY,
            ],
            leaf_transmission: v4(Vec3::from_array(s.leaf_transmission), 0.0),
            k: [
                s.indirect,
                s.sky_ambient,
                s.leaf_specular.0,
                s.leaf_specular.1,
            ],
            k2: [
                s.wood_specular.0,
                s.wood_specular.1,
                SHEET_RADIANCE_PER_FLUENCE,
                f32::from_bits(self.free_space.load(Ordering::Relaxed)),
            ],
            tables: [
                self.base.tables[0],
                self.base.tables[1],
                (s.light == Light::Physical) as u32,
                self.base.tables[3],
            ],
            ..self.base
        };
        self.ctx
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
    }
}

/// Why a GPU frame failed.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
}
