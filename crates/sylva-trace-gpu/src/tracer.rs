//! [`GpuTracer`]: the [`RayQuery`] answered by compute shaders over the uploaded scene.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use glam::Vec3;
use sylva_trace::{Hit, KdTracer, Ray, RayQuery, ShadowRay, TraceInstance, TraceStats};
use sylva_wgpu::{wgpu, GpuContext, GpuError};

use crate::scene::GpuScene;
use crate::split::{storage_entry, uniform_entry};
use crate::TraceGpuError;

/// The kernels that answer batches (after the scene's WGSL).
const QUERY_WGSL: &str = include_str!("query.wgsl");

/// Invocations per workgroup (query.wgsl).
const WORKGROUP: u64 = 64;
/// Rays per dispatch at most; larger calls are answered in several.
const MAX_DISPATCH: usize = 1 << 20;
/// Bytes per ray uploaded: origin, t_min, direction, t_max.
const RAY_BYTES: u64 = 32;

/// Buffers for one batch in flight; a worker thread takes a set, fills it, waits for the
/// answers and gives it back.
struct BatchBuffers {
    capacity: usize,
    params: wgpu::Buffer,
    rays: wgpu::Buffer,
    from: wgpu::Buffer,
    answers: wgpu::Buffer,
    staging: wgpu::Buffer,
    group: wgpu::BindGroup,
}

/// Closest-hit and shadow queries on a GPU: the CPU tracer's scene uploaded as it is
/// ([`GpuScene`]) and traversed by the same rules, so every hit is the CPU's (see
/// docs/gpu.md for where last bits may differ on hardware GPUs). The CPU tracer stays: it
/// answers the rare rays the kernel hands back (a ray lying in a split plane, which the CPU
/// walks leaf by leaf), the instance list and normals, and any batch the GPU fails on.
pub struct GpuTracer {
    cpu: KdTracer,
    ctx: GpuContext,
    scene: GpuScene,
    batch_layout: wgpu::BindGroupLayout,
    closest: wgpu::ComputePipeline,
    shadow: wgpu::ComputePipeline,
    pool: Mutex<Vec<BatchBuffers>>,
    /// Rays per dispatch: [`MAX_DISPATCH`], or fewer where a binding cannot hold their
    /// answers.
    max_rays: usize,
    /// The first GPU failure, answered on the CPU meanwhile; the renderer reports it.
    error: Mutex<Option<String>>,
    cpu_rays: AtomicU64,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Closest,
    Shadow,
}

impl Kind {
    /// Bytes of answers per ray.
    fn answer_bytes(self) -> u64 {
        match self {
            Kind::Closest => 32,
            Kind::Shadow => 16,
        }
    }
}

impl GpuTracer {
    /// Uploads `cpu`'s scene to the device of `ctx` and builds the query kernels (short
    /// stack of `cpu.traversal.stack_size` entries).
    pub fn new(ctx: GpuContext, cpu: KdTracer) -> Result<GpuTracer, TraceGpuError> {
        let scene = GpuScene::new(&ctx, &cpu.accel, cpu.traversal.stack_size)?;
        let batch_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("ray batch"),
                entries: &[
                    uniform_entry(0),
                    storage_entry(1, true),
                    storage_entry(2, true),
                    storage_entry(3, false),
                ],
            });
        let module = scene.module(&ctx, "trace", format!("{}\n{}", scene.wgsl(), QUERY_WGSL));
        let layout = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("trace"),
                bind_group_layouts: &[Some(scene.layout()), Some(&batch_layout)],
                immediate_size: 0,
            });
        let pipeline = |entry: &str| {
            ctx.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: Some(&layout),
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
        };
        let closest = pipeline("closest");
        let shadow = pipeline("shadow");
        ctx.check("building the ray-tracing kernels")?;
        let max_binding = ctx
            .limits()
            .max_storage_buffer_binding_size
            .min(ctx.limits().max_buffer_size);
        let max_rays =
            (max_binding / Kind::Closest.answer_bytes()).min(MAX_DISPATCH as u64) as usize;
        Ok(GpuTracer {
            max_rays,
            cpu,
            ctx,
            scene,
            batch_layout,
            closest,
            shadow,
            pool: Mutex::new(Vec::new()),
            error: Mutex::new(None),
            cpu_rays: AtomicU64::new(0),
        })
    }

    /// The CPU tracer over the same scene.
    pub fn cpu(&self) -> &KdTracer {
        &self.cpu
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    pub fn scene(&self) -> &GpuScene {
        &self.scene
    }

    /// The first GPU failure since the last call (its batches were answered on the CPU).
    pub fn take_error(&self) -> Option<String> {
        self.error.lock().expect("error slot").take()
    }

    /// Rays the CPU answered for the kernels (rays lying in a split plane).
    pub fn cpu_answered(&self) -> u64 {
        self.cpu_rays.load(Ordering::Relaxed)
    }

    /// Takes a buffer set for `n` rays (or makes one).
    fn take(&self, n: usize) -> Result<BatchBuffers, GpuError> {
        let mut pool = self.pool.lock().expect("buffer pool");
        if let Some(k) = pool.iter().position(|b| b.capacity >= n) {
            return Ok(pool.swap_remove(k));
        }
        drop(pool);
        let capacity = n.max(self.preferred_batch()).min(self.max_rays) as u64;
        let ctx = &self.ctx;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let params = ctx.buffer(
            "batch params",
            16,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        let rays = ctx.buffer("rays", capacity * RAY_BYTES, storage)?;
        let from = ctx.buffer("shadow ray instances", capacity * 4, storage)?;
        let answers = ctx.buffer(
            "answers",
            capacity * Kind::Closest.answer_bytes(),
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let staging = ctx.buffer(
            "answers readback",
            capacity * Kind::Closest.answer_bytes(),
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ray batch"),
            layout: &self.batch_layout,
            entries: &[
                entry(0, &params),
                entry(1, &rays),
                entry(2, &from),
                entry(3, &answers),
            ],
        });
        Ok(BatchBuffers {
            capacity: capacity as usize,
            params,
            rays,
            from,
            answers,
            staging,
            group,
        })
    }

    /// Runs `kind` on up to `max_rays` rays (`from`: shadow rays' start instances) and
    /// returns the answers' bytes.
    fn dispatch(&self, kind: Kind, rays: &[Ray], from: &[u32]) -> Result<Vec<u8>, GpuError> {
        let n = rays.len();
        let buf = self.take(n)?;
        let data: Vec<[f32; 8]> = rays.iter().map(encode).collect();
        let groups = (n as u64).div_ceil(WORKGROUP) as u32;
        let max = self
            .ctx
            .limits()
            .max_compute_workgroups_per_dimension
            .max(1);
        let groups_x = groups.min(max);
        let groups_y = groups.div_ceil(groups_x);
        let q = &self.ctx.queue;
        q.write_buffer(
            &buf.params,
            0,
            bytemuck::cast_slice(&[n as u32, groups_x, 0, 0]),
        );
        q.write_buffer(&buf.rays, 0, bytemuck::cast_slice(&data));
        if kind == Kind::Shadow {
            q.write_buffer(&buf.from, 0, bytemuck::cast_slice(from));
        }
        let bytes = n as u64 * kind.answer_bytes();
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("rays"),
                timestamp_writes: None,
            });
            pass.set_pipeline(match kind {
                Kind::Closest => &self.closest,
                Kind::Shadow => &self.shadow,
            });
            pass.set_bind_group(0, self.scene.group(), &[]);
            pass.set_bind_group(1, &buf.group, &[]);
            pass.dispatch_workgroups(groups_x, groups_y, 1);
        }
        enc.copy_buffer_to_buffer(&buf.answers, 0, &buf.staging, 0, bytes);
        q.submit([enc.finish()]);
        let out = self.ctx.map_read(&buf.staging, bytes);
        self.pool.lock().expect("buffer pool").push(buf);
        out
    }

    fn record(&self, e: GpuError) {
        let mut slot = self.error.lock().expect("error slot");
        if slot.is_none() {
            *slot = Some(e.to_string());
        }
    }
}

fn entry(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: b.as_entire_binding(),
    }
}

/// A ray as the kernel reads it; an invalid ray (which hits nothing) as an empty segment.
fn encode(r: &Ray) -> [f32; 8] {
    if r.is_valid() {
        [
            r.origin.x, r.origin.y, r.origin.z, r.t_min, r.dir.x, r.dir.y, r.dir.z, r.t_max,
        ]
    } else {
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0]
    }
}

impl RayQuery for GpuTracer {
    /// Many tiles per call: a GPU needs tens of thousands of rays in flight.
    fn preferred_batch(&self) -> usize {
        1 << 17
    }

    fn closest_hits(&self, rays: &[Ray], hits: &mut [Option<Hit>], stats: &mut TraceStats) {
        assert_eq!(rays.len(), hits.len(), "one hit per ray");
        let m = self.max_rays;
        for (rays, hits) in rays.chunks(m).zip(hits.chunks_mut(m)) {
            let words = match self.dispatch(Kind::Closest, rays, &[]) {
                Ok(w) => w,
                Err(e) => {
                    self.record(e);
                    self.cpu.closest_hits(rays, hits, stats);
                    continue;
                }
            };
            stats.rays += rays.len() as u64;
            let words: &[[u32; 8]] = bytemuck::cast_slice(&words);
            let mut cpu = TraceStats::default();
            for ((ray, hit), w) in rays.iter().zip(hits.iter_mut()).zip(words) {
                *hit = if w[3] != 0 {
                    self.cpu_rays.fetch_add(1, Ordering::Relaxed);
                    self.cpu
                        .accel
                        .closest_hit(ray, self.cpu.traversal, &mut cpu)
                } else if w[2] == u32::MAX || !ray.is_valid() {
                    None
                } else {
                    Some(Hit {
                        t: f32::from_bits(w[0]),
                        instance: w[1],
                        triangle: w[2],
                        u: f32::from_bits(w[4]),
                        v: f32::from_bits(w[5]),
                    })
                };
            }
            cpu.rays = 0;
            *stats += cpu;
        }
    }

    fn any_hits(&self, rays: &[ShadowRay], blocked: &mut [bool], stats: &mut TraceStats) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        let m = self.max_rays;
        for (rays, blocked) in rays.chunks(m).zip(blocked.chunks_mut(m)) {
            let plain: Vec<Ray> = rays.iter().map(|r| r.ray).collect();
            let from: Vec<u32> = rays.iter().map(|r| r.from.unwrap_or(u32::MAX)).collect();
            let words = match self.dispatch(Kind::Shadow, &plain, &from) {
                Ok(w) => w,
                Err(e) => {
                    self.record(e);
                    self.cpu.any_hits(rays, blocked, stats);
                    continue;
                }
            };
            stats.rays += rays.len() as u64;
            let words: &[[u32; 4]] = bytemuck::cast_slice(&words);
            let mut cpu = TraceStats::default();
            for ((r, b), w) in rays.iter().zip(blocked.iter_mut()).zip(words) {
                *b = if w[1] != 0 {
                    self.cpu_rays.fetch_add(1, Ordering::Relaxed);
                    self.cpu.accel.any_hit_from(
                        &r.ray,
                        r.from,
                        self.cpu.traversal,
                        &mut cpu,
                        &mut Default::default(),
                    )
                } else {
                    w[0] != 0 && r.ray.is_valid()
                };
            }
            cpu.rays = 0;
            *stats += cpu;
        }
    }

    fn instances(&self) -> &[TraceInstance] {
        self.cpu.accel.instances()
    }

    fn geometric_normal(&self, hit: &Hit) -> Vec3 {
        self.cpu.accel.geometric_normal(hit)
    }
}
