//! The CPU tracer's structures on the device, as they are: every model's kd-tree nodes and
//! leaf lists, triangle data, alpha data and opacity masks, the top-level tree, the
//! instances' transforms and world boxes, and the ground. Nothing is rebuilt.

use std::borrow::Cow;

use glam::Vec3;
use sylva_geom::Wrap;
use sylva_trace::kdtree::TERMINATION_SLACK;
use sylva_trace::ray::{BARY_EPS, ROUNDING};
use sylva_trace::{KdTree, SceneAccel};
use sylva_wgpu::{wgpu, GpuContext, GpuError};

use crate::split::{f32_literal, storage_entry, uniform_entry, SplitArray};
use crate::TraceGpuError;

/// The traversal's WGSL (after the generated prelude).
pub const TRACE_WGSL: &str = include_str!("trace.wgsl");

/// Bind group the scene takes in every pipeline that traces.
pub const SCENE_GROUP: u32 = 0;

/// Storage bindings left to the kernels that include the scene (their rays, answers and
/// shading data).
pub const OWN_BINDINGS: u32 = 12;

/// One tree's record (`ModelRec` in trace.wgsl): where its arrays start, its root box.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ModelRec {
    node_base: u32,
    prim_base: u32,
    tri_base: u32,
    alpha_base: u32,
    mask_base: u32,
    pad: [u32; 3],
    bmin: [f32; 4],
    bmax: [f32; 4],
}

/// Host copies of the arrays, before upload.
#[derive(Default)]
struct Arrays {
    nodes: Vec<[u32; 2]>,
    prims: Vec<u32>,
    tris: Vec<[f32; 4]>,
    alpha: Vec<[f32; 4]>,
    mask_words: Vec<u32>,
    masks: Vec<[u32; 4]>,
    models: Vec<ModelRec>,
    instances: Vec<[f32; 4]>,
    boxes: Vec<[f32; 4]>,
}

impl Arrays {
    fn tree(&mut self, tree: &KdTree) -> ModelRec {
        let rec = ModelRec {
            node_base: self.nodes.len() as u32,
            prim_base: self.prims.len() as u32,
            tri_base: 0,
            alpha_base: 0,
            mask_base: 0,
            pad: [0; 3],
            bmin: v4(tree.bounds().min, 0.0),
            bmax: v4(tree.bounds().max, 0.0),
        };
        self.nodes.extend(tree.nodes().iter().map(|n| n.raw()));
        self.prims.extend_from_slice(tree.leaf_indices());
        rec
    }

    fn build(accel: &SceneAccel) -> Arrays {
        let mut a = Arrays::default();
        for m in accel.models() {
            let mut rec = a.tree(m.tree());
            rec.tri_base = (a.tris.len() / 3) as u32;
            rec.alpha_base = (a.alpha.len() / 2) as u32;
            rec.mask_base = a.masks.len() as u32;
            for (d, alpha) in m.triangles() {
                a.tris.push(v4(d.v0, f32::from_bits(alpha)));
                a.tris.push(v4(d.e1, 0.0));
                a.tris.push(v4(d.e2, 0.0));
            }
            for (uv, mask) in m.alpha_triangles() {
                a.alpha.push([uv[0].x, uv[0].y, uv[1].x, uv[1].y]);
                a.alpha.push([uv[2].x, uv[2].y, f32::from_bits(mask), 0.0]);
            }
            for mask in m.alpha_masks() {
                let wrap = match mask.wrap() {
                    Wrap::Repeat => 0,
                    Wrap::Clamp => 1,
                };
                a.masks
                    .push([mask.width(), mask.height(), wrap, a.mask_words.len() as u32]);
                for &w in mask.bits() {
                    a.mask_words.push(w as u32);
                    a.mask_words.push((w >> 32) as u32);
                }
            }
            a.models.push(rec);
        }
        let top = a.tree(accel.top_tree());
        a.models.push(top);
        for inst in accel.instances() {
            let m = &inst.to_model;
            a.instances
                .push(v4(m.matrix3.x_axis.into(), f32::from_bits(inst.model)));
            a.instances.push(v4(m.matrix3.y_axis.into(), 0.0));
            a.instances.push(v4(m.matrix3.z_axis.into(), 0.0));
            a.instances.push(v4(m.translation.into(), 0.0));
            a.boxes.push(v4(inst.world_bounds.min, 0.0));
            a.boxes.push(v4(inst.world_bounds.max, 0.0));
        }
        a
    }

    fn bytes(&self) -> u64 {
        (self.nodes.len() * 8
            + self.prims.len() * 4
            + (self.tris.len() + self.alpha.len() + self.instances.len() + self.boxes.len()) * 16
            + self.mask_words.len() * 4
            + self.masks.len() * 16
            + self.models.len() * std::mem::size_of::<ModelRec>()) as u64
    }
}

fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// Device bytes the scene's arrays take (before splitting), for memory checks.
pub fn scene_device_bytes(accel: &SceneAccel) -> u64 {
    let mut bytes = 0u64;
    let tree = |t: &KdTree| (t.nodes().len() * 8 + t.leaf_indices().len() * 4) as u64;
    for m in accel.models() {
        bytes += tree(m.tree())
            + m.triangles().len() as u64 * 48
            + m.alpha_triangles().len() as u64 * 32
            + m.alpha_masks()
                .iter()
                .map(|k| k.bits().len() as u64 * 8 + 16)
                .sum::<u64>();
    }
    bytes + tree(accel.top_tree()) + accel.instances().len() as u64 * 96
}

/// The scene on the device: the arrays, their bind group and the WGSL that reads them.
pub struct GpuScene {
    // Held for the bind group's lifetime.
    _params: wgpu::Buffer,
    _models: wgpu::Buffer,
    _masks: wgpu::Buffer,
    arrays: Vec<SplitArray>,
    layout: wgpu::BindGroupLayout,
    group: wgpu::BindGroup,
    stack_size: usize,
    bytes: u64,
}

impl GpuScene {
    /// Uploads `accel` as it is; the traversal will use a short stack of `stack_size`
    /// entries. Arrays larger than the adapter's storage binding limit are split.
    pub fn new(
        ctx: &GpuContext,
        accel: &SceneAccel,
        stack_size: usize,
    ) -> Result<GpuScene, TraceGpuError> {
        sylva_core::check_memory(
            "the scene's kd-trees for the GPU (host staging)",
            scene_device_bytes(accel),
        )?;
        let a = Arrays::build(accel);
        let limits = ctx.limits();
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let arrays = [
            split(ctx, "node", "vec2<u32>", 8, &a.nodes, max_binding)?,
            split(ctx, "prim", "u32", 4, &a.prims, max_binding)?,
            split(ctx, "tri", "vec4<f32>", 16, &a.tris, max_binding)?,
            split(ctx, "alpha", "vec4<f32>", 16, &a.alpha, max_binding)?,
            split(ctx, "mask_word", "u32", 4, &a.mask_words, max_binding)?,
            split(ctx, "inst", "vec4<f32>", 16, &a.instances, max_binding)?,
            split(ctx, "box", "vec4<f32>", 16, &a.boxes, max_binding)?,
        ];
        let arrays = arrays.into_iter().collect::<Vec<_>>();
        let need = 2 + arrays.iter().map(SplitArray::bindings).sum::<u32>() + OWN_BINDINGS;
        let allowed = limits.max_storage_buffers_per_shader_stage;
        if need > allowed {
            return Err(TraceGpuError::TooLarge(format!(
                "the scene's {} of arrays split into {} storage bindings of at most {}, with \
                 the kernels' own {need} in all; the adapter allows {allowed} per shader stage",
                sylva_core::format_bytes(a.bytes()),
                need - OWN_BINDINGS,
                sylva_core::format_bytes(max_binding),
            )));
        }
        let whole = |label: &str, data: &[u8], usage: wgpu::BufferUsages| {
            let size = (data.len() as u64).max(16);
            if size > max_binding {
                return Err(GpuError::TooLarge(format!(
                    "{label}: {size} bytes exceed one binding ({max_binding})"
                )));
            }
            let b = ctx.buffer(label, size, usage | wgpu::BufferUsages::COPY_DST)?;
            ctx.queue.write_buffer(&b, 0, data);
            Ok(b)
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let models = whole("models", bytemuck::cast_slice(&a.models), storage)?;
        let masks = whole("masks", bytemuck::cast_slice(&a.masks), storage)?;
        let ground = accel.ground();
        let mut words = [0u32; 8];
        if let Some([hx, hz]) = ground {
            words[0] = 1f32.to_bits();
            words[1] = hx.to_bits();
            words[2] = hz.to_bits();
        }
        words[4] = accel.models().len() as u32;
        words[5] = accel.instances().len() as u32;
        let params = whole(
            "scene params",
            bytemuck::cast_slice(&words),
            wgpu::BufferUsages::UNIFORM,
        )?;

        let mut entries = vec![
            uniform_entry(0),
            storage_entry(1, true),
            storage_entry(2, true),
        ];
        let mut next = 3;
        for arr in &arrays {
            entries.extend(arr.layout_entries(next));
            next += arr.bindings();
        }
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("scene"),
                entries: &entries,
            });
        let mut group_entries = vec![
            wgpu::BindGroupEntry {
                binding: 0,
                resource: params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: models.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: masks.as_entire_binding(),
            },
        ];
        let mut next = 3;
        for arr in &arrays {
            group_entries.extend(arr.group_entries(next));
            next += arr.bindings();
        }
        let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &layout,
            entries: &group_entries,
        });
        ctx.check("uploading the scene")?;
        Ok(GpuScene {
            _params: params,
            _models: models,
            _masks: masks,
            bytes: a.bytes(),
            arrays,
            layout,
            group,
            stack_size: stack_size.clamp(1, sylva_trace::MAX_DEPTH),
        })
    }

    /// Storage bindings the scene takes (a pipeline adds its own).
    pub fn storage_bindings(&self) -> u32 {
        2 + self.arrays.iter().map(SplitArray::bindings).sum::<u32>()
    }

    /// Bytes on the device.
    pub fn device_bytes(&self) -> u64 {
        self.bytes
    }

    /// Parts the largest array is split into (1 when everything fits one binding).
    pub fn max_parts(&self) -> u32 {
        self.arrays
            .iter()
            .map(SplitArray::bindings)
            .max()
            .unwrap_or(1)
    }

    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    pub fn group(&self) -> &wgpu::BindGroup {
        &self.group
    }

    pub fn stack_size(&self) -> usize {
        self.stack_size
    }

    /// The WGSL that traces this scene: its bindings (group [`SCENE_GROUP`]), accessors and
    /// constants, then the traversal (`closest_hit`, `any_hit` and their helpers).
    pub fn wgsl(&self) -> String {
        let g = SCENE_GROUP;
        let mut s = format!(
            "// Generated for one scene (sylva-trace-gpu/src/scene.rs).\n\
             const STACK: u32 = {}u;\n\
             const BARY_EPS: f32 = {};\n\
             const ROUNDING: f32 = {};\n\
             const SLACK: f32 = {};\n\
             @group({g}) @binding(0) var<uniform> scene: SceneParams;\n\
             @group({g}) @binding(1) var<storage, read> models: array<ModelRec>;\n\
             @group({g}) @binding(2) var<storage, read> masks: array<vec4<u32>>;\n",
            self.stack_size,
            f32_literal(BARY_EPS),
            f32_literal(ROUNDING),
            f32_literal(TERMINATION_SLACK),
        );
        let mut next = 3;
        for arr in &self.arrays {
            s += &arr.declare(g, next);
            next += arr.bindings();
        }
        s += TRACE_WGSL;
        s
    }

    /// A shader module from WGSL that includes [`GpuScene::wgsl`].
    pub fn module(&self, ctx: &GpuContext, label: &str, src: String) -> wgpu::ShaderModule {
        ctx.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(Cow::Owned(src)),
            })
    }
}

fn split<T: bytemuck::Pod>(
    ctx: &GpuContext,
    name: &'static str,
    ty: &'static str,
    elem: u64,
    data: &[T],
    max_binding: u64,
) -> Result<SplitArray, GpuError> {
    SplitArray::upload(ctx, name, ty, elem, bytemuck::cast_slice(data), max_binding)
}
