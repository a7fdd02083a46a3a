//! Frames on a GPU: primary rays, shadow rays and shading in one compute kernel per band of
//! image rows (`shade.wgsl`, which mirrors the CPU's `Renderer::sample_geometry`,
//! `Renderer::shade`, `shade::local_light`, `ModelLighting::sample` and
//! `ModelGridLight::ground_sky` function by function), over the scene the [`GpuTracer`] put
//! on the device.
//!
//! The host makes the camera rays (the CPU renderer's `sample_ray`, so both devices trace the
//! same rays) and uploads them with the shading data: per model its mesh indices, vertex
//! normals and texture coordinates, material ids, materials with their linear textures, its
//! LB grid (today's [`ModelGridLight`]); the instances' world transforms; the ground index.
//! A pixel whose rays the kernel hands back (a ray lying in a kd-tree split plane) is
//! rendered by the CPU renderer, so every pixel is what the CPU would make of it.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use sylva_geom::{Scene, Wrap};
use sylva_trace::{PinholeCamera, TraceStats};
use sylva_trace_gpu::split::{storage_entry, uniform_entry, SplitArray};
use sylva_trace_gpu::{GpuTracer, TraceGpuError, SCENE_GROUP};
use sylva_wgpu::{wgpu, GpuContext, GpuError};

use crate::indirect::{IndirectLight, ModelGridLight};
use crate::render::{sample_ray, Frame, FrameTimings, RenderError, RenderSettings, Renderer};
use crate::shade::{Radiance, ShadeMaterial};

/// The kernel and the shading functions it calls (after the scene's WGSL).
const SHADE_WGSL: &str = include_str!("shade.wgsl");
/// "No such entry" in the pool's records.
const NONE: u32 = u32::MAX;
/// Samples in flight at once, as the CPU renderer's bands.
const BAND_SAMPLES: usize = 1 << 21;
/// Bytes per sample's ray and per pixel's result on the device.
const RAY_BYTES: u64 = 32;
const PIXEL_BYTES: u64 = 64;

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
}

/// The shading data as one array of words, and where its tables start.
#[derive(Default)]
struct Pool {
    words: Vec<u32>,
    params: ShadeParams,
}

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
    /// material count, LB grid, 0) and data; the instances' world transforms; the ground
    /// index.
    fn build(scene: &Scene, materials: &[Vec<ShadeMaterial>], light: &ModelGridLight) -> Pool {
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
            p.words.resize(p.words.len() + 8 * mats.len(), 0);
            for (k, mat) in mats.iter().enumerate() {
                let r = (rec[4] + 8 * k as u32) as usize;
                p.words[r] = mat.leaf as u32;
                p.words[r + 1..r + 4].copy_from_slice(&mat.base.to_array().map(f32::to_bits));
                p.words[r + 4] = NONE;
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
            if let Some(l) = light.model(m) {
                let (dims, origin, inv_cell, last, values) = l.raw();
                rec[6] = p.at();
                let values_at = rec[6] + 19;
                p.words
                    .extend([dims.nx as u32, dims.ny as u32, dims.nz as u32, values_at]);
                p.v3(origin);
                p.v3(inv_cell);
                p.v3(last);
                let b = light.model_bounds(m);
                p.v3(b.min);
                p.v3(b.max);
                p.words.extend(values.iter().flatten().map(|v| v.to_bits()));
            }
            rec[7] = 0;
            let at = (models + 8 * m as u32) as usize;
            p.words[at..at + 8].copy_from_slice(&rec);
        }
        p.params.tables = [models, instances, 0, 0];
        if let Some(g) = light.ground_index() {
            let cells = &g.cells;
            let starts = p.at();
            let lists = starts + cells.len() as u32 + 1;
            let mut first = 0u32;
            for c in cells {
                p.words.push(first);
                first += c.len() as u32;
            }
            p.words.push(first);
            for c in cells {
                p.words.extend_from_slice(c);
            }
            p.params.ground = [starts, lists, g.nx as u32, g.nz as u32];
            p.params.ground_box = [g.origin.x, g.origin.y, g.end.x, g.end.y];
            p.params.ground_cell = [g.inv_cell, 0.0, 0.0, 0.0];
        }
        p
    }
}

/// Device bytes of a scene's shading data (for memory checks and reports).
pub fn shading_bytes(scene: &Scene, light: &ModelGridLight) -> u64 {
    let mut words = 8 * scene.models.len() as u64 + 12 * scene.instances.len() as u64;
    for m in &scene.models {
        let mesh = &m.mesh;
        words += 3 * mesh.indices.len() as u64
            + 5 * mesh.positions.len() as u64
            + mesh.material_ids.len() as u64 / 4
            + 8 * m.materials.len() as u64;
        for mat in &m.materials {
            if let Some(t) = &mat.texture {
                words += 3 * t.pixels.len() as u64;
            }
        }
    }
    words * 4 + light.memory_bytes()
}

/// The shading data on the device and the frame kernel.
pub struct GpuFrame {
    ctx: GpuContext,
    pool: SplitArray,
    params: wgpu::Buffer,
    base: ShadeParams,
    shade_group: wgpu::BindGroup,
    frame_layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    max_binding: u64,
    cpu_pixels: AtomicU64,
}

impl GpuFrame {
    /// Uploads the shading data of `scene` (traced by `tracer`, materials decoded, LB light)
    /// and builds the kernel.
    pub fn new(
        tracer: &GpuTracer,
        scene: &Scene,
        materials: &[Vec<ShadeMaterial>],
        light: &ModelGridLight,
    ) -> Result<GpuFrame, TraceGpuError> {
        let ctx = tracer.context().clone();
        sylva_core::check_memory(
            "the scene's shading data for the GPU (host staging)",
            shading_bytes(scene, light),
        )?;
        let pool = Pool::build(scene, materials, light);
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
        // The scene's bindings, the pool's and the frame's own two.
        let need = tracer.scene().storage_bindings() + words.bindings() + 2;
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
        let mut entries = vec![uniform_entry(0)];
        entries.extend(words.layout_entries(1));
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
                ],
            });
        let src = format!(
            "{}\n// Shading data (sylva-render/src/gpu_frame.rs).\n\
             @group(1) @binding(0) var<uniform> shading: ShadeParams;\n{}\n{}",
            tracer.scene().wgsl(),
            words.declare(1, 1),
            SHADE_WGSL
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
        Ok(GpuFrame {
            ctx,
            pool: words,
            params,
            base: pool.params,
            shade_group,
            frame_layout,
            pipeline,
            max_binding,
            cpu_pixels: AtomicU64::new(0),
        })
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
    pub(crate) fn render(
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
        let row_samples = w * n as usize;
        if row_samples as u64 * RAY_BYTES > self.max_binding {
            return Err(GpuError::TooLarge(format!(
                "one image row of {row_samples} samples ({} of rays) exceeds the adapter's {} per storage binding",
                sylva_core::format_bytes(row_samples as u64 * RAY_BYTES),
                sylva_core::format_bytes(self.max_binding)
            ))
            .into());
        }
        let band_rows = (BAND_SAMPLES / row_samples)
            .min((self.max_binding / (row_samples as u64 * RAY_BYTES)) as usize)
            .min((self.max_binding / (w as u64 * PIXEL_BYTES)) as usize)
            .clamp(1, region.height as usize);
        self.write_params(cpu, settings);
        let ctx = &self.ctx;
        let rays_buf = ctx.buffer(
            "frame rays",
            (band_rows * row_samples) as u64 * RAY_BYTES,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        )?;
        let pixel_bytes = (band_rows * w) as u64 * PIXEL_BYTES;
        let pixels_buf = ctx.buffer(
            "frame pixels",
            pixel_bytes,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let staging = ctx.buffer(
            "frame readback",
            pixel_bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let frame_params = ctx.buffer(
            "frame params",
            16,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout: &self.frame_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: frame_params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: rays_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: pixels_buf.as_entire_binding(),
                },
            ],
        });

        let mut pixels = vec![Radiance::default(); region.pixels() as usize];
        let mut stats = TraceStats::default();
        let mut shadow_rays = 0u64;
        let tiles = 3 * crate::render::tile_count(region);
        let mut reported = 0u64;
        let mut rays = vec![[0f32; 8]; band_rows * row_samples];
        let inv_n = 1.0 / n as f32;
        let mut row = 0usize;
        while row < region.height as usize {
            let rows = band_rows.min(region.height as usize - row);
            let y0 = region.y0 + row as u32;
            rays[..rows * row_samples]
                .par_chunks_mut(row_samples)
                .enumerate()
                .for_each(|(r, out)| {
                    for (k, ray) in out.iter_mut().enumerate() {
                        let (x, s) = ((k / n as usize) as u32, (k % n as usize) as u32);
                        let ray_ =
                            sample_ray(&camera, region.x0 + x, y0 + r as u32, s, n, settings.seed);
                        let (o, d) = (ray_.origin, ray_.dir);
                        *ray = [o.x, o.y, o.z, ray_.t_min, d.x, d.y, d.z, ray_.t_max];
                    }
                });
            ctx.queue.write_buffer(
                &rays_buf,
                0,
                bytemuck::cast_slice(&rays[..rows * row_samples]),
            );
            ctx.queue.write_buffer(
                &frame_params,
                0,
                bytemuck::cast_slice(&[w as u32, rows as u32, n, inv_n.to_bits()]),
            );
            let mut enc = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("frame"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, tracer.scene().group(), &[]);
                pass.set_bind_group(1, &self.shade_group, &[]);
                pass.set_bind_group(2, &group, &[]);
                pass.dispatch_workgroups(w.div_ceil(8) as u32, rows.div_ceil(8) as u32, 1);
            }
            let bytes = (rows * w) as u64 * PIXEL_BYTES;
            enc.copy_buffer_to_buffer(&pixels_buf, 0, &staging, 0, bytes);
            ctx.queue.submit([enc.finish()]);
            let data = ctx.map_read(&staging, bytes)?;
            let out: &[[f32; 16]] = bytemuck::cast_slice(&data);
            let dst = &mut pixels[row * w..(row + rows) * w];
            for (k, (p, v)) in dst.iter_mut().zip(out).enumerate() {
                if v[3] != 0.0 {
                    let (x, y) = (region.x0 + (k % w) as u32, y0 + (k / w) as u32);
                    let (r, s) = cpu.pixel(&camera, x, y, settings, &mut stats);
                    *p = r;
                    shadow_rays += s;
                    self.cpu_pixels.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                *p = Radiance {
                    local: Vec3::new(v[0], v[1], v[2]),
                    indirect: Vec3::new(v[4], v[5], v[6]),
                    albedo: Vec3::new(v[8], v[9], v[10]),
                    sky: Vec3::new(v[12], v[13], v[14]),
                };
                shadow_rays += v[7].to_bits() as u64;
            }
            row += rows;
            let done = tiles * row as u64 / region.height as u64;
            progress(done - reported);
            reported = done;
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
                primary_rays,
                shadow_rays,
                ..FrameTimings::default()
            },
            stats,
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
            leaf_transmission: v4(Vec3::from_array(s.leaf_transmission), 0.0),
            k: [
                s.indirect,
                s.sky_ambient,
                s.leaf_specular.0,
                s.leaf_specular.1,
            ],
            k2: [s.wood_specular.0, s.wood_specular.1, 0.0, 0.0],
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
