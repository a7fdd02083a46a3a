//! One colour's lattice on the GPU, and the three-colour driver.
//!
//! Correspondence with the CPU solver (`sylva_lb::Lattice`): the GPU keeps post-collision
//! values `P_j` and the CPU's state after `t ≥ 1` steps is `X_t = stream(P_{t-1})`. After a
//! reset the buffer holds `X_0` (interior zero, shell at the boundary), which is also `P_0`
//! because colliding a zero interior changes nothing. CPU step 1 therefore needs no launch
//! (its monitor total, of the zero interior, is 0), and every later CPU step s is one launch
//! that streams `X_{s-1}`, sums it for the monitor (exactly what CPU step s reports),
//! collides and writes `P_{s-1}`. The stop rules run on the host on these totals, so the GPU
//! stops after the same step as the CPU would, and the result `X_T` is one gather away.

use std::borrow::Cow;
use std::num::NonZeroU64;

use sylva_lb::collision::{Omega, ReducedOmega};
use sylva_lb::kernel::CubicOmega;
use sylva_lb::lattice::Q;
use sylva_lb::solver::ColourSource;
use sylva_lb::{
    Boundary, ColourParams, DensityGrid, Dims, Floor, LightingGrid, MediumParams, RunMonitor,
    SolveError, SolveOptions, SolveReport, VolumeSource,
};

use crate::shader::{self, Layout, REDUCE_THREADS};
use crate::LbGpuError;
use sylva_wgpu::{wgpu, GpuContext};

/// How the state is stored on the device. Arithmetic is f32 either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    F32,
    /// Half the memory traffic; needs `SHADER_F16`. Each stored value is rounded to 11
    /// significant bits (see docs/gpu.md for the measured error).
    F16,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F16 => "f16",
        }
    }

    pub fn parse(s: &str) -> Option<Precision> {
        match s.trim().to_ascii_lowercase().as_str() {
            "f32" => Some(Precision::F32),
            "f16" => Some(Precision::F16),
            _ => None,
        }
    }

    /// Bytes per stored value.
    pub fn bytes(self) -> u64 {
        match self {
            Precision::F32 => 4,
            Precision::F16 => 2,
        }
    }

    /// Bytes moved per site update: 19 values read and written, one f32 code read.
    pub fn bytes_per_update(self) -> u64 {
        2 * Q as u64 * self.bytes() + 4
    }
}

/// Bytes of the step's uniform: sizes and f_0 factors (8 words), green and brown Ω (20
/// each), the source's green and brown profiles (20 each).
const PARAMS_BYTES: u64 = 4 * (8 + 4 * 20);

/// Steps per submission when no tolerance asks for a check after every pair.
const BATCH: usize = 32;

/// Elements between directions in a state part: the site count rounded up so every
/// direction starts 256-byte aligned (and f16 uploads stay 4-byte aligned).
fn direction_stride(sites: u64) -> u64 {
    sites.div_ceil(128) * 128
}

/// Device bytes a solve over `dims` holds: two states, the codes, the site totals.
pub fn device_memory_needed(dims: Dims, precision: Precision) -> u64 {
    let stride = direction_stride(dims.sites() as u64);
    2 * Q as u64 * stride * precision.bytes() + 2 * dims.sites() as u64 * 4
}

/// One colour's lattice on the device.
pub struct GpuLattice<'c> {
    ctx: &'c GpuContext,
    dims: Dims,
    precision: Precision,
    layout: Layout,
    stride: u64,
    params: wgpu::Buffer,
    states: [Vec<wgpu::Buffer>; 2],
    out: wgpu::Buffer,
    sums: wgpu::Buffer,
    sums_staging: wgpu::Buffer,
    step_pipeline: wgpu::ComputePipeline,
    /// The step without the monitor's sum, for steps whose total nobody reads.
    quiet_pipeline: wgpu::ComputePipeline,
    /// Steps numbered below this run quiet (their totals are NaN): set by [`GpuLattice::run`].
    quiet_before: usize,
    /// Monitor every step even without a tolerance (each step's residual reported).
    monitor_every_step: bool,
    gather_pipeline: wgpu::ComputePipeline,
    reduce_pipeline: wgpu::ComputePipeline,
    /// `step_groups[i]` reads state i and writes state 1 - i.
    step_groups: [wgpu::BindGroup; 2],
    gather_groups: [wgpu::BindGroup; 2],
    reduce_group: wgpu::BindGroup,
    partial_stride: u64,
    max_batch: usize,
    groups: [u32; 3],
    current: usize,
    /// CPU-equivalent steps since the last reset.
    steps: usize,
    boundary: Boundary,
    /// This colour's floor radiance per `(x, z)` (`sylva_lb::Floor`), if any.
    floor: Option<Vec<f32>>,
    /// The volume source's strength per site on the device, which sites are brown (when the
    /// step has a source), and this colour's source.
    strength: wgpu::Buffer,
    brown_sites: Option<Vec<bool>>,
    source: Option<ColourSource>,
    /// The uniform's colour part (sizes, f_0 factors, Ω coefficients).
    colour_words: Vec<u32>,
    keep_f0: [f32; 2],
}

fn validate_boundary(b: &Boundary) -> Result<(), SolveError> {
    for (index, &value) in b.values.iter().enumerate() {
        if !(value.is_finite() && value >= 0.0) {
            return Err(SolveError::Boundary { index, value });
        }
    }
    Ok(())
}

fn validate_options(o: &SolveOptions) -> Result<(), SolveError> {
    if o.max_steps == 0 {
        return Err(SolveError::Steps);
    }
    if o.extrapolate || o.coarse_start {
        return Err(SolveError::ExtrapolateOnGpu);
    }
    if let Some(t) = o.tolerance {
        if !(t.is_finite() && t > 0.0) {
            return Err(SolveError::Tolerance(t));
        }
    }
    Ok(())
}

fn entry(binding: u32, ty: wgpu::BufferBindingType, dynamic: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: dynamic,
            min_binding_size: None,
        },
        count: None,
    }
}

fn storage(read_only: bool) -> wgpu::BufferBindingType {
    wgpu::BufferBindingType::Storage { read_only }
}

fn whole(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// The host-side (f32) constants of one colour: green and brown Ω in the cubic factorised
/// form, 19 coefficients each, padded to five vec4.
fn omega_coefficients(green: &ColourParams, brown: &ColourParams) -> [[f32; 20]; 2] {
    [green, brown].map(|c| {
        let k = CubicOmega::new(&ReducedOmega::new(&Omega::new(c))).coefficients();
        let mut out = [0.0f32; 20];
        out[..19].copy_from_slice(&k);
        out
    })
}

impl<'c> GpuLattice<'c> {
    /// Builds the lattice for `grid` with colour `colour` of `medium`, interior at zero and
    /// the shell at `boundary`; the state is split over as many storage bindings as the
    /// device's binding limit needs.
    pub fn new(
        ctx: &'c GpuContext,
        grid: &DensityGrid,
        medium: &MediumParams,
        colour: usize,
        boundary: Boundary,
        precision: Precision,
    ) -> Result<GpuLattice<'c>, LbGpuError> {
        Self::with_source(ctx, grid, medium, colour, boundary, precision, false)
    }

    /// [`GpuLattice::new`], with a step that adds a volume source when `source` (set per
    /// colour with [`GpuLattice::set_source`]; none until then).
    pub fn with_source(
        ctx: &'c GpuContext,
        grid: &DensityGrid,
        medium: &MediumParams,
        colour: usize,
        boundary: Boundary,
        precision: Precision,
        source: bool,
    ) -> Result<GpuLattice<'c>, LbGpuError> {
        medium.validate().map_err(SolveError::from)?;
        validate_boundary(&boundary)?;
        if precision == Precision::F16 && !ctx.supports_f16() {
            return Err(LbGpuError::F16Unsupported(ctx.adapter_name().to_string()));
        }
        let dims = grid.dims;
        let sites = dims.sites() as u64;
        let stride = direction_stride(sites);
        let limits = ctx.limits().clone();
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let direction_bytes = stride * precision.bytes();
        if direction_bytes > max_binding || sites * 4 > max_binding {
            return Err(LbGpuError::TooLarge(format!(
                "a {dims} grid needs {} per direction and {} for the densities, above the \
                 adapter's {} per storage binding",
                sylva_core::format_bytes(direction_bytes),
                sylva_core::format_bytes(sites * 4),
                sylva_core::format_bytes(max_binding)
            )));
        }
        if stride * Q as u64 > u32::MAX as u64 {
            return Err(LbGpuError::TooLarge(format!(
                "a {dims} grid has too many sites for 32-bit indices"
            )));
        }
        let per_part = ((max_binding / direction_bytes) as usize).clamp(1, Q);
        let (wg_z, wg_y) = shader::workgroup_shape(dims.nz);
        let layout = Layout {
            per_part,
            f16: precision == Precision::F16,
            wg_z,
            wg_y,
            source,
        };
        let parts = layout.parts();
        let needed_storage = 2 + 2 * parts as u32 + source as u32;
        if needed_storage > limits.max_storage_buffers_per_shader_stage {
            return Err(LbGpuError::TooLarge(format!(
                "a {dims} grid splits into {parts} state parts per copy, needing \
                 {needed_storage} storage buffers per shader stage; the adapter allows {}",
                limits.max_storage_buffers_per_shader_stage
            )));
        }
        let groups = [
            dims.nz.div_ceil(wg_z as usize) as u32,
            dims.ny.div_ceil(wg_y as usize) as u32,
            dims.nx as u32,
        ];
        if groups
            .iter()
            .any(|&g| g > limits.max_compute_workgroups_per_dimension)
        {
            return Err(LbGpuError::TooLarge(format!(
                "a {dims} grid needs {groups:?} workgroups, above the adapter's {} per dimension",
                limits.max_compute_workgroups_per_dimension
            )));
        }
        // Host memory for the upload of one direction and the three-colour result.
        sylva_core::check_memory(
            &format!("a GPU LB solve on a {dims} grid (host side)"),
            sites * 4 * 5,
        )?;

        let storage_usage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        let mut states: [Vec<wgpu::Buffer>; 2] = [Vec::new(), Vec::new()];
        for (i, set) in states.iter_mut().enumerate() {
            for p in 0..parts {
                let bytes = layout.directions_in(p) as u64 * direction_bytes;
                set.push(ctx.buffer(&format!("state {i} part {p}"), bytes, storage_usage)?);
            }
        }
        let codes = ctx.buffer("codes", sites * 4, storage_usage)?;
        let out = ctx.buffer("site totals", sites * 4, storage_usage)?;
        let params = ctx.buffer(
            "params",
            PARAMS_BYTES,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        // The source's strength per site (one zero word without a source).
        let strength = ctx.buffer(
            "source strength",
            if source { sites * 4 } else { 4 },
            storage_usage,
        )?;
        let partials_per_step = groups.iter().map(|&g| g as u64).product::<u64>();
        let align = limits.min_storage_buffer_offset_alignment.max(4) as u64;
        let partial_stride = (partials_per_step * 4).div_ceil(align) * align;
        let max_batch = (BATCH as u64)
            .min(max_binding / partial_stride)
            .min(max_binding / (REDUCE_THREADS as u64 * 4))
            .min(u32::MAX as u64 / partial_stride)
            .max(1) as usize;
        if partial_stride > max_binding {
            return Err(LbGpuError::TooLarge(format!(
                "{partials_per_step} monitor partials per step exceed one storage binding"
            )));
        }
        let partials = ctx.buffer(
            "monitor partials",
            partial_stride * max_batch as u64,
            wgpu::BufferUsages::STORAGE,
        )?;
        let sums_bytes = (max_batch as u64) * REDUCE_THREADS as u64 * 4;
        let sums = ctx.buffer(
            "monitor sums",
            sums_bytes,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let sums_staging = ctx.buffer(
            "monitor readback",
            sums_bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let reduce_params = ctx.buffer(
            "reduce params",
            16,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        ctx.queue.write_buffer(
            &reduce_params,
            0,
            bytemuck::cast_slice(&[partials_per_step as u32, (partial_stride / 4) as u32, 0, 0]),
        );

        // Pipelines.
        let device = &ctx.device;
        let module = |label: &str, src: String| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(Cow::Owned(src)),
            })
        };
        let pipeline = |label: &str, module: &wgpu::ShaderModule, bgl: &wgpu::BindGroupLayout| {
            let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(bgl)],
                immediate_size: 0,
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&pl),
                module,
                entry_point: Some(label),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let uniform = wgpu::BufferBindingType::Uniform;

        let mut step_entries = vec![
            entry(0, uniform, false),
            entry(1, storage(true), false),
            entry(2, storage(false), true),
        ];
        for p in 0..parts as u32 {
            step_entries.push(entry(3 + p, storage(true), false));
            step_entries.push(entry(3 + parts as u32 + p, storage(false), false));
        }
        if source {
            step_entries.push(entry(3 + 2 * parts as u32, storage(true), false));
        }
        let step_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("step"),
            entries: &step_entries,
        });
        let step_module = module("step", shader::step_shader(&layout));
        let step_pipeline = pipeline("step", &step_module, &step_bgl);
        let quiet_module = module("step", shader::step_shader_with(&layout, false));
        let quiet_pipeline = pipeline("step", &quiet_module, &step_bgl);
        let step_group = |from: usize| {
            let mut e = vec![
                whole(0, &params),
                whole(1, &codes),
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &partials,
                        offset: 0,
                        size: NonZeroU64::new(partials_per_step * 4),
                    }),
                },
            ];
            for (p, (src, dst)) in states[from].iter().zip(&states[1 - from]).enumerate() {
                e.push(whole(3 + p as u32, src));
                e.push(whole(3 + (parts + p) as u32, dst));
            }
            if source {
                e.push(whole(3 + 2 * parts as u32, &strength));
            }
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("step"),
                layout: &step_bgl,
                entries: &e,
            })
        };
        let step_groups = [step_group(0), step_group(1)];

        let mut gather_entries = vec![entry(0, uniform, false), entry(1, storage(false), false)];
        for p in 0..parts as u32 {
            gather_entries.push(entry(2 + p, storage(true), false));
        }
        let gather_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gather"),
            entries: &gather_entries,
        });
        let gather_module = module("gather", shader::gather_shader(&layout));
        let gather_pipeline = pipeline("gather", &gather_module, &gather_bgl);
        let gather_group = |from: usize| {
            let mut e = vec![whole(0, &params), whole(1, &out)];
            for (p, src) in states[from].iter().enumerate() {
                e.push(whole(2 + p as u32, src));
            }
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("gather"),
                layout: &gather_bgl,
                entries: &e,
            })
        };
        let gather_groups = [gather_group(0), gather_group(1)];

        let reduce_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("reduce"),
            entries: &[
                entry(0, uniform, false),
                entry(1, storage(true), false),
                entry(2, storage(false), false),
            ],
        });
        let reduce_module = module("reduce", shader::reduce_shader());
        let reduce_pipeline = pipeline("reduce", &reduce_module, &reduce_bgl);
        let reduce_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("reduce"),
            layout: &reduce_bgl,
            entries: &[
                whole(0, &reduce_params),
                whole(1, &partials),
                whole(2, &sums),
            ],
        });
        ctx.check("building the LB pipelines")?;

        // Site codes as on the CPU: ρ for green and plain sites, -ρ for brown, 0 on the shell.
        let code: Vec<f32> = (0..dims.sites())
            .map(|i| {
                let (x, y, z) = dims.coords(i);
                let rho = grid.density[i];
                if dims.on_shell(x, y, z) {
                    0.0
                } else if rho > 0.0 && grid.wood[i] as f64 > medium.brown_threshold {
                    -rho
                } else {
                    rho
                }
            })
            .collect();
        ctx.queue
            .write_buffer(&codes, 0, bytemuck::cast_slice(&code));
        // Which interior sites are brown (the source's profile there), for the first
        // post-collision state.
        let brown_sites = source.then(|| code.iter().map(|&c| c < 0.0).collect());
        drop(code);

        let mut lattice = GpuLattice {
            ctx,
            dims,
            precision,
            layout,
            stride,
            params,
            states,
            out,
            sums,
            sums_staging,
            step_pipeline,
            quiet_pipeline,
            quiet_before: 0,
            monitor_every_step: std::env::var_os("SYLVA_LB_MONITOR_EVERY_STEP").is_some(),
            gather_pipeline,
            reduce_pipeline,
            step_groups,
            gather_groups,
            reduce_group,
            partial_stride,
            max_batch,
            groups,
            current: 0,
            steps: 0,
            boundary,
            floor: None,
            strength,
            brown_sites,
            source: None,
            colour_words: Vec::new(),
            keep_f0: [
                if medium.zero_f0_on_green { 0.0 } else { 1.0 },
                if medium.zero_f0_on_brown { 0.0 } else { 1.0 },
            ],
        };
        lattice.set_colour(&medium.colours[colour], &medium.brown_colour(colour))?;
        lattice.reset(boundary)?;
        Ok(lattice)
    }

    /// Switches to another colour's scattering parameters of green and brown sites (the
    /// medium stays); call [`GpuLattice::reset`] before solving again.
    pub fn set_colour(
        &mut self,
        green: &ColourParams,
        brown: &ColourParams,
    ) -> Result<(), LbGpuError> {
        green.validate("").map_err(SolveError::from)?;
        brown.validate("brown ").map_err(SolveError::from)?;
        let d = self.dims;
        let mut words = vec![
            d.nx as u32,
            d.ny as u32,
            d.nz as u32,
            self.stride as u32,
            self.keep_f0[0].to_bits(),
            self.keep_f0[1].to_bits(),
            0,
            0,
        ];
        for set in omega_coefficients(green, brown) {
            words.extend(set.iter().map(|v| v.to_bits()));
        }
        self.colour_words = words;
        self.write_params();
        Ok(())
    }

    /// The uniform: the colour's constants and the source's profiles.
    fn write_params(&self) {
        let mut words = self.colour_words.clone();
        for profile in [
            self.source.as_ref().map(|s| s.green),
            self.source.as_ref().map(|s| s.brown),
        ] {
            let mut p = [0u32; 20];
            if let Some(v) = profile {
                for (w, v) in p.iter_mut().zip(v) {
                    *w = v.to_bits();
                }
            }
            words.extend(p);
        }
        debug_assert_eq!(words.len() as u64 * 4, PARAMS_BYTES);
        self.ctx
            .queue
            .write_buffer(&self.params, 0, bytemuck::cast_slice(&words));
    }

    /// Sets this colour's volume source (`None`: none); takes effect at the next
    /// [`GpuLattice::reset`]. A source needs a lattice made with one
    /// ([`GpuLattice::with_source`]).
    pub fn set_source(&mut self, source: Option<ColourSource>) -> Result<(), LbGpuError> {
        if let Some(s) = &source {
            if self.brown_sites.is_none() {
                return Err(LbGpuError::Solve(SolveError::Source(
                    "this GPU lattice was built without a source term".into(),
                )));
            }
            if s.strength.len() != self.dims.sites() {
                return Err(LbGpuError::Solve(SolveError::Source(format!(
                    "{} strengths for a {} grid",
                    s.strength.len(),
                    self.dims
                ))));
            }
            self.ctx
                .queue
                .write_buffer(&self.strength, 0, bytemuck::cast_slice(&s.strength));
        } else if self.brown_sites.is_some() {
            let zeros = vec![0f32; self.dims.sites()];
            self.ctx
                .queue
                .write_buffer(&self.strength, 0, bytemuck::cast_slice(&zeros));
        }
        self.source = source;
        self.write_params();
        Ok(())
    }

    /// Sets this colour's floor radiance per `(x, z)` (`None`: the bottom face emits the
    /// boundary); takes effect at the next [`GpuLattice::reset`].
    pub fn set_floor(&mut self, floor: Option<Vec<f32>>) {
        if let Some(f) = &floor {
            assert_eq!(f.len(), self.dims.nx * self.dims.nz, "one value per (x, z)");
        }
        self.floor = floor;
    }

    /// The value shell site `(x, y, z)` holds in direction `m`: the boundary's, or the
    /// floor's on the bottom face.
    fn shell_value(&self, x: usize, y: usize, z: usize, m: usize) -> f32 {
        match &self.floor {
            Some(f) if y == 0 => Floor::value(f[x * self.dims.nz + z], m, &self.boundary),
            _ => self.boundary.values[m],
        }
    }

    /// Interior back to zero (plus the source's first emission), shell to `boundary` and the
    /// floor (both states).
    pub fn reset(&mut self, boundary: Boundary) -> Result<(), LbGpuError> {
        validate_boundary(&boundary)?;
        self.boundary = boundary;
        let d = self.dims;
        let elem = self.precision.bytes();
        for m in 0..Q {
            // The interior of P_0 (the state after the CPU's first collision of a zero
            // interior): the source's share, or zero.
            let interior = |i: usize| match (&self.source, &self.brown_sites) {
                (Some(s), Some(brown)) => {
                    s.strength[i] * if brown[i] { s.brown[m] } else { s.green[m] }
                }
                _ => 0.0,
            };
            let values: Vec<f32> = (0..d.sites())
                .map(|i| {
                    let (x, y, z) = d.coords(i);
                    if d.on_shell(x, y, z) {
                        self.shell_value(x, y, z, m)
                    } else {
                        interior(i)
                    }
                })
                .collect();
            let bytes: Vec<u8> = match self.precision {
                Precision::F32 => bytemuck::cast_slice(&values).to_vec(),
                Precision::F16 => {
                    let h: Vec<half::f16> =
                        values.iter().map(|&v| half::f16::from_f32(v)).collect();
                    let mut b = bytemuck::cast_slice(&h).to_vec();
                    // Uploads are whole 4-byte words; the direction stride leaves room.
                    b.resize(b.len().next_multiple_of(4), 0);
                    b
                }
            };
            let (part, k) = self.layout.place(m);
            for set in &self.states {
                self.ctx
                    .queue
                    .write_buffer(&set[part], k as u64 * self.stride * elem, &bytes);
            }
            // Bound the staging memory of large uploads.
            self.ctx.queue.submit([]);
            self.ctx.wait()?;
        }
        self.current = 0;
        self.steps = 0;
        Ok(self.ctx.check("uploading the initial state")?)
    }

    pub fn dims(&self) -> Dims {
        self.dims
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Monitor every step's total even without a tolerance, so each step's residual is
    /// reported (the default monitors only the last two steps of such a run).
    pub fn set_monitor_every_step(&mut self, yes: bool) {
        self.monitor_every_step = yes;
    }

    /// Storage bindings each copy of the state is split over.
    pub fn parts(&self) -> usize {
        self.layout.parts()
    }

    /// Advances `n` CPU-equivalent steps in one submission; returns the monitor total (the
    /// interior total before each step) per step.
    fn advance(&mut self, n: usize) -> Result<Vec<f64>, LbGpuError> {
        assert!(n <= self.max_batch + 1);
        let mut totals = Vec::with_capacity(n);
        let mut launches = 0usize;
        let mut quiet = Vec::with_capacity(n);
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("steps"),
            });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("steps"),
                timestamp_writes: None,
            });
            let mut bound: Option<bool> = None;
            for _ in 0..n {
                if self.steps == 0 {
                    // X_0 → X_1 is streaming alone; X_0's interior total is zero.
                    self.steps = 1;
                    totals.push(0.0);
                    continue;
                }
                if launches == self.max_batch {
                    break;
                }
                let q = self.steps + 1 < self.quiet_before;
                if bound != Some(q) {
                    pass.set_pipeline(if q {
                        &self.quiet_pipeline
                    } else {
                        &self.step_pipeline
                    });
                    bound = Some(q);
                }
                quiet.push(q);
                let offset = (launches as u64 * self.partial_stride) as u32;
                pass.set_bind_group(0, &self.step_groups[self.current], &[offset]);
                pass.dispatch_workgroups(self.groups[0], self.groups[1], self.groups[2]);
                self.current ^= 1;
                self.steps += 1;
                launches += 1;
            }
        }
        if launches == 0 {
            return Ok(totals);
        }
        if quiet.iter().all(|&q| q) {
            // Nothing to read: submit without waiting (the next read waits for it).
            self.ctx.queue.submit([enc.finish()]);
            totals.extend(std::iter::repeat_n(f64::NAN, launches));
            return Ok(totals);
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("monitor"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.reduce_pipeline);
            pass.set_bind_group(0, &self.reduce_group, &[]);
            pass.dispatch_workgroups(launches as u32, 1, 1);
        }
        let bytes = (launches * REDUCE_THREADS as usize * 4) as u64;
        enc.copy_buffer_to_buffer(&self.sums, 0, &self.sums_staging, 0, bytes);
        self.ctx.queue.submit([enc.finish()]);
        let data = self.ctx.map_read(&self.sums_staging, bytes)?;
        let sums: &[f32] = bytemuck::cast_slice(&data);
        for (step, &q) in sums.chunks_exact(REDUCE_THREADS as usize).zip(&quiet) {
            totals.push(if q {
                f64::NAN
            } else {
                step.iter().map(|&v| v as f64).sum()
            });
        }
        Ok(totals)
    }

    /// Steps until `opts` says stop, with the CPU solver's rules: at most `max_steps`; with
    /// a tolerance, the check after every pair of steps (so the GPU syncs once per pair).
    /// `progress(step, residual)` is called after every step.
    pub fn run(
        &mut self,
        opts: &SolveOptions,
        progress: &mut dyn FnMut(usize, f64),
    ) -> Result<SolveReport, LbGpuError> {
        validate_options(opts)?;
        let mut monitor = RunMonitor::new(opts);
        // Without a tolerance only the last two totals matter (the report's residual): the
        // steps before them skip the monitor's sum and the host's wait for it. Their
        // progress reports carry no new residual.
        self.quiet_before = if opts.tolerance.is_none() && !self.monitor_every_step {
            (self.steps + opts.max_steps).saturating_sub(1)
        } else {
            0
        };
        while monitor.steps_left() > 0 {
            // With a tolerance, the CPU checks after each pair (or the last single step);
            // batches without one are checked never, so grouping does not matter.
            let n = if opts.tolerance.is_some() {
                monitor.steps_left().min(2)
            } else {
                monitor.steps_left().min(self.max_batch)
            };
            let totals = self.advance(n)?;
            monitor.record(&totals, progress);
        }
        Ok(monitor.report())
    }

    /// Σ_m f_m per site of the current state (the CPU's `site_totals`).
    pub fn site_totals(&self) -> Result<Vec<f32>, LbGpuError> {
        let d = self.dims;
        if self.steps == 0 {
            // X_0 itself: the boundary (and floor) on the shell, zero inside.
            return Ok((0..d.sites())
                .map(|i| {
                    let (x, y, z) = d.coords(i);
                    if d.on_shell(x, y, z) {
                        (0..Q).fold(0.0f32, |a, m| a + self.shell_value(x, y, z, m))
                    } else {
                        0.0
                    }
                })
                .collect());
        }
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("gather"),
            });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("gather"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.gather_pipeline);
            pass.set_bind_group(0, &self.gather_groups[self.current], &[]);
            pass.dispatch_workgroups(self.groups[0], self.groups[1], self.groups[2]);
        }
        self.ctx.queue.submit([enc.finish()]);
        let data = self.ctx.read_back(&self.out, d.sites() as u64 * 4)?;
        Ok(bytemuck::cast_slice(&data).to_vec())
    }
}

/// Lights `grid` in all three colours on the GPU, each under its own boundary, as
/// [`sylva_lb::solver::solve_lighting_rgb`] does on the CPU (colours with identical
/// parameters and boundaries are solved once). `progress(colour, step, residual)`.
#[allow(clippy::too_many_arguments)]
pub fn solve_lighting_gpu(
    ctx: &GpuContext,
    grid: &DensityGrid,
    medium: &MediumParams,
    boundaries: &[Boundary; 3],
    floor: Option<&Floor>,
    source: Option<&VolumeSource>,
    opts: &SolveOptions,
    precision: Precision,
    progress: &mut dyn FnMut(usize, usize, f64),
) -> Result<(LightingGrid, Vec<SolveReport>), LbGpuError> {
    medium.validate().map_err(SolveError::from)?;
    validate_options(opts)?;
    if let Some(f) = floor {
        f.validate(grid.dims)?;
    }
    if let Some(s) = source {
        s.validate(grid.dims)?;
    }
    sylva_lb::solver::solve_colours(
        grid,
        medium,
        boundaries,
        floor,
        source,
        |c, lattice: Option<GpuLattice>| {
            let boundary = boundaries[c];
            let mut lat = match lattice {
                Some(mut l) => {
                    l.set_colour(&medium.colours[c], &medium.brown_colour(c))?;
                    l
                }
                None => GpuLattice::with_source(
                    ctx,
                    grid,
                    medium,
                    c,
                    boundary,
                    precision,
                    source.is_some(),
                )?,
            };
            if floor.is_some() {
                lat.set_floor(floor.map(|f| f.radiance[c].clone()));
            }
            if let Some(s) = source {
                lat.set_source(Some(s.colour(c)))?;
            }
            lat.reset(boundary)?;
            let report = lat.run(opts, &mut |s, r| progress(c, s, r))?;
            let totals = lat.site_totals()?;
            Ok((lat, totals, report))
        },
    )
}
