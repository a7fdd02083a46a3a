//! Adapter choice and the device: which GPU runs the work, with which limits.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use crate::GpuError;

/// Which adapters may be chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterChoice {
    /// Hardware GPUs only (discrete, integrated or virtual); software rasterisers such as
    /// lavapipe are skipped.
    Hardware,
    /// The best adapter there is, a software one (lavapipe) included.
    Any,
}

/// How to open the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ContextOptions {
    pub choice: AdapterChoice,
    /// Request at most this many bytes per storage binding (below the adapter's limit), so
    /// that a small grid must split its state as a large one would. `None`: the adapter's
    /// full limit.
    pub max_binding_bytes: Option<u64>,
    /// Backends to search; `None`: `WGPU_BACKEND` from the environment, else Vulkan, Metal
    /// and DX12.
    pub backends: Option<wgpu::Backends>,
}

impl ContextOptions {
    pub fn new(choice: AdapterChoice) -> ContextOptions {
        ContextOptions {
            choice,
            max_binding_bytes: None,
            backends: None,
        }
    }
}

/// An opened GPU: adapter description, device, queue and the limits it was granted. Clones
/// share the device (wgpu's handles are reference counted), so the LB solver and the ray
/// tracer of one render run on one device.
#[derive(Clone)]
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    f16: bool,
    /// The device was opened with `TIMESTAMP_QUERY` (kernel times from the GPU's clock).
    timestamps: bool,
    /// Validation and out-of-memory errors no scope caught, reported at the next check.
    errors: Arc<Mutex<Vec<String>>>,
}

/// Preference among adapters: lower is better.
fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

impl GpuContext {
    /// Opens the best adapter `opts` allows, requesting its full limits (storage binding size
    /// capped by `opts.max_binding_bytes`) and `SHADER_F16` where it has it.
    /// [`GpuError::NoAdapter`] when none qualifies.
    pub fn new(opts: &ContextOptions) -> Result<GpuContext, GpuError> {
        let backends = opts.backends.unwrap_or_else(|| {
            wgpu::Backends::from_env()
                .unwrap_or(wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12)
        });
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(backends));
        let seen: Vec<String> = adapters
            .iter()
            .map(|a| {
                let i = a.get_info();
                format!("{} ({:?})", i.name, i.device_type)
            })
            .collect();
        let best = adapters
            .into_iter()
            .filter(|a| {
                let t = a.get_info().device_type;
                opts.choice == AdapterChoice::Any || t != wgpu::DeviceType::Cpu
            })
            .min_by_key(|a| rank(a.get_info().device_type));
        let Some(adapter) = best else {
            return Err(GpuError::NoAdapter {
                hardware_only: opts.choice == AdapterChoice::Hardware,
                seen: if seen.is_empty() {
                    "none".into()
                } else {
                    seen.join(", ")
                },
            });
        };
        let info = adapter.get_info();
        let mut limits = adapter.limits();
        if let Some(cap) = opts.max_binding_bytes {
            // Binding sizes stay multiples of 4 (whole f32 values).
            limits.max_storage_buffer_binding_size = limits
                .max_storage_buffer_binding_size
                .min(cap.max(4) / 4 * 4);
        }
        let f16 = adapter.features().contains(wgpu::Features::SHADER_F16);
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut features = wgpu::Features::empty();
        if f16 {
            features |= wgpu::Features::SHADER_F16;
        }
        if timestamps {
            features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("sylva"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            sink.lock().expect("error list").push(e.to_string());
        }));
        let limits = device.limits();
        Ok(GpuContext {
            device,
            queue,
            info,
            limits,
            f16,
            timestamps,
            errors,
        })
    }

    /// The adapter's name, e.g. "NVIDIA H100 80GB HBM3" or "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub fn adapter_name(&self) -> &str {
        &self.info.name
    }

    /// Name, type and backend in one line, for reports.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?}{})",
            self.info.name,
            self.info.device_type,
            self.info.backend,
            if self.info.driver.is_empty() {
                String::new()
            } else {
                format!(", {} {}", self.info.driver, self.info.driver_info)
            }
        )
    }

    /// A software rasteriser (lavapipe/llvmpipe, WARP): correct but CPU-speed.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The device can store the state as f16 (`SHADER_F16`).
    pub fn supports_f16(&self) -> bool {
        self.f16
    }

    /// The device records compute passes' start and end on the GPU's clock
    /// ([`crate::PassTimer`]).
    pub fn timestamps(&self) -> bool {
        self.timestamps
    }

    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Fails with the first error the device reported since the last check.
    pub fn check(&self, what: &str) -> Result<(), GpuError> {
        let mut errors = self.errors.lock().expect("error list");
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(GpuError::Wgpu {
            what: what.to_string(),
            message,
        })
    }

    /// Blocks until the queue is idle.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait {
                submission_index: None,
                timeout: None,
            })
            .map_err(|e| GpuError::Wgpu {
                what: "waiting for the GPU".into(),
                message: e.to_string(),
            })?;
        Ok(())
    }

    /// Creates a buffer, turning an out-of-memory or validation failure into an error.
    pub fn buffer(
        &self,
        label: &str,
        size: u64,
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer, GpuError> {
        if size > self.limits.max_buffer_size {
            return Err(GpuError::TooLarge(format!(
                "buffer '{label}' of {} exceeds the adapter's max_buffer_size {}",
                sylva_core::format_bytes(size),
                sylva_core::format_bytes(self.limits.max_buffer_size)
            )));
        }
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(oom.pop()) {
            return Err(GpuError::OutOfMemory {
                what: format!("buffer '{label}' ({})", sylva_core::format_bytes(size)),
                message: e.to_string(),
            });
        }
        Ok(buffer)
    }

    /// Copies `src[..bytes]` back to the host.
    pub fn read_back(&self, src: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let staging = self.buffer(
            "readback",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(src, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        self.map_read(&staging, bytes)
    }

    /// Maps a MAP_READ buffer after the submissions that fill it and copies it out.
    pub fn map_read(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        self.map_read_with(staging, bytes, |data| data.to_vec())
    }

    /// Maps a MAP_READ buffer after the submissions that fill it and hands its first `bytes`
    /// to `read` (no intermediate copy), then unmaps it.
    pub fn map_read_with<T>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| GpuError::Wgpu {
                what: "reading back".into(),
                message: "the map callback never ran".into(),
            })?
            .map_err(|e| GpuError::Wgpu {
                what: "reading back".into(),
                message: e.to_string(),
            })?;
        let data = {
            let view = staging
                .get_mapped_range(0..bytes)
                .map_err(|e| GpuError::Wgpu {
                    what: "reading back".into(),
                    message: e.to_string(),
                })?;
            read(&view)
        };
        staging.unmap();
        self.check("reading back")?;
        Ok(data)
    }

    /// GPU copy bandwidth in GB/s (10⁹ bytes/s, read + write counted, as the solver's
    /// effective bandwidth) between two device buffers of `bytes` (capped by the adapter's
    /// limits): the better of the copy command (`copy_buffer_to_buffer`) and a compute
    /// kernel copying 16 bytes per invocation, each the median of `repeats` timed batches.
    /// On some drivers the copy command runs well below what kernels reach (measured on an
    /// H200: 0.8 against 3.4 TB/s), so the kernel copy is the honest ceiling for a kernel.
    pub fn copy_bandwidth_gbs(&self, bytes: u64, repeats: usize) -> Result<f64, GpuError> {
        let bytes = bytes
            .min(self.limits.max_buffer_size)
            .min(self.limits.max_storage_buffer_binding_size)
            / 256
            * 256;
        let usage = wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::STORAGE;
        let a = self.buffer("copy-a", bytes, usage)?;
        let b = self.buffer("copy-b", bytes, usage)?;
        let copies = 8;
        let kernel = CopyKernel::new(self, &a, &b, bytes);
        let batch = |shader: bool| -> Result<f64, GpuError> {
            let mut enc = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            for i in 0..copies {
                match &kernel {
                    Some(k) if shader => k.encode(&mut enc, i % 2 == 1),
                    _ => {
                        let (s, d) = if i % 2 == 0 { (&a, &b) } else { (&b, &a) };
                        enc.copy_buffer_to_buffer(s, 0, d, 0, bytes);
                    }
                }
            }
            let t = Instant::now();
            self.queue.submit([enc.finish()]);
            self.wait()?;
            let s = t.elapsed().as_secs_f64();
            Ok(2.0 * bytes as f64 * copies as f64 / s / 1e9)
        };
        let mut best = 0.0f64;
        for shader in [false, true] {
            if shader && kernel.is_none() {
                continue;
            }
            // Warm-up: first use of the buffers pays for their allocation.
            batch(shader)?;
            let mut runs = Vec::with_capacity(repeats.max(1));
            for _ in 0..repeats.max(1) {
                runs.push(batch(shader)?);
            }
            runs.sort_by(f64::total_cmp);
            best = best.max(runs[runs.len() / 2]);
        }
        self.check("measuring copy bandwidth")?;
        Ok(best)
    }
}

/// A compute kernel copying one buffer into another, 16 bytes per invocation (both ways).
struct CopyKernel {
    pipeline: wgpu::ComputePipeline,
    groups: [wgpu::BindGroup; 2],
    dispatch: (u32, u32),
}

impl CopyKernel {
    const WORKGROUP: u64 = 256;
    const ROW: u64 = 32768;

    fn new(ctx: &GpuContext, a: &wgpu::Buffer, b: &wgpu::Buffer, bytes: u64) -> Option<CopyKernel> {
        let n = bytes / 16;
        let groups = n.div_ceil(Self::WORKGROUP);
        let (x, y) = (groups.min(Self::ROW), groups.div_ceil(Self::ROW));
        if n == 0 || y > ctx.limits.max_compute_workgroups_per_dimension as u64 {
            return None;
        }
        let src = format!(
            "@group(0) @binding(0) var<storage, read> src: array<vec4<u32>>;\n\
             @group(0) @binding(1) var<storage, read_write> dst: array<vec4<u32>>;\n\
             @compute @workgroup_size({wg})\n\
             fn copy(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
                 let i = id.y * {row}u + id.x;\n\
                 if (i < {n}u) {{ dst[i] = src[i]; }}\n\
             }}\n",
            wg = Self::WORKGROUP,
            row = Self::ROW * Self::WORKGROUP,
            n = n
        );
        let module = ctx
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("copy"),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            });
        let pipeline = ctx
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("copy"),
                layout: None,
                module: &module,
                entry_point: Some("copy"),
                compilation_options: Default::default(),
                cache: None,
            });
        let layout = pipeline.get_bind_group_layout(0);
        let group = |s: &wgpu::Buffer, d: &wgpu::Buffer| {
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("copy"),
                layout: &layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: s.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: d.as_entire_binding(),
                    },
                ],
            })
        };
        Some(CopyKernel {
            groups: [group(a, b), group(b, a)],
            pipeline,
            dispatch: (x as u32, y as u32),
        })
    }

    fn encode(&self, enc: &mut wgpu::CommandEncoder, back: bool) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("copy"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.groups[back as usize], &[]);
        pass.dispatch_workgroups(self.dispatch.0, self.dispatch.1, 1);
    }
}
