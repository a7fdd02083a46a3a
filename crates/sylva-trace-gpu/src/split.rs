//! Read-only arrays larger than one storage binding (lavapipe: 128 MiB): split into parts of
//! whole elements, one buffer and one binding each, read through a generated WGSL accessor
//! `fn NAME_at(i: u32) -> TYPE` that picks the part.

use sylva_wgpu::{wgpu, GpuContext, GpuError};

/// An array of `elem_bytes`-byte elements on the device, in one or more storage bindings.
pub struct SplitArray {
    name: &'static str,
    wgsl_type: &'static str,
    /// Elements per part (every part but the last is full).
    per_part: u64,
    elem_bytes: u64,
    len: u64,
    parts: Vec<wgpu::Buffer>,
}

impl SplitArray {
    /// Uploads `data` (whole elements of `elem_bytes`, a multiple of 4) as `name`, an
    /// `array<wgsl_type>` split so that no part exceeds `max_binding` bytes. An empty array
    /// gets one element of zeros (bindings cannot be empty).
    pub fn upload(
        ctx: &GpuContext,
        name: &'static str,
        wgsl_type: &'static str,
        elem_bytes: u64,
        data: &[u8],
        max_binding: u64,
    ) -> Result<SplitArray, GpuError> {
        assert!(elem_bytes.is_multiple_of(4) && (data.len() as u64).is_multiple_of(elem_bytes));
        let len = data.len() as u64 / elem_bytes;
        if len > u32::MAX as u64 {
            return Err(GpuError::TooLarge(format!(
                "{name}: {len} elements exceed 32-bit indices"
            )));
        }
        let per_part = (max_binding / elem_bytes).min(u32::MAX as u64);
        if per_part == 0 {
            return Err(GpuError::TooLarge(format!(
                "{name}: one {elem_bytes}-byte element exceeds the {max_binding}-byte binding limit"
            )));
        }
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let mut parts = Vec::new();
        if len == 0 {
            let b = ctx.buffer(name, elem_bytes, usage)?;
            ctx.queue
                .write_buffer(&b, 0, &vec![0u8; elem_bytes as usize]);
            parts.push(b);
        }
        for (k, chunk) in data.chunks((per_part * elem_bytes) as usize).enumerate() {
            let b = ctx.buffer(&format!("{name} part {k}"), chunk.len() as u64, usage)?;
            ctx.queue.write_buffer(&b, 0, chunk);
            // Bound the staging memory of large uploads.
            ctx.queue.submit([]);
            ctx.wait()?;
            parts.push(b);
        }
        ctx.check(&format!("uploading {name}"))?;
        Ok(SplitArray {
            name,
            wgsl_type,
            per_part,
            elem_bytes,
            len,
            parts,
        })
    }

    /// Overwrites the elements from `first` with `data` (whole elements) in place: the
    /// array keeps its length and bindings, so kernels built over it stay valid.
    pub fn write(&self, ctx: &GpuContext, first: u64, data: &[u8]) -> Result<(), GpuError> {
        let n = data.len() as u64 / self.elem_bytes;
        if !(data.len() as u64).is_multiple_of(self.elem_bytes) || first + n > self.len {
            return Err(GpuError::TooLarge(format!(
                "{}: {} bytes from element {first} do not fit its {} elements of {} bytes",
                self.name,
                data.len(),
                self.len,
                self.elem_bytes
            )));
        }
        let (mut at, mut rest) = (first, data);
        while !rest.is_empty() {
            let (part, within) = (at / self.per_part, at % self.per_part);
            let take = ((self.per_part - within) * self.elem_bytes).min(rest.len() as u64);
            let (chunk, tail) = rest.split_at(take as usize);
            ctx.queue
                .write_buffer(&self.parts[part as usize], within * self.elem_bytes, chunk);
            // Bound the staging memory of large writes.
            ctx.queue.submit([]);
            ctx.wait()?;
            at += take / self.elem_bytes;
            rest = tail;
        }
        ctx.check(&format!("writing {}", self.name))?;
        Ok(())
    }

    /// Storage bindings it takes.
    pub fn bindings(&self) -> u32 {
        self.parts.len() as u32
    }

    pub fn len(&self) -> u64 {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes on the device.
    pub fn bytes(&self) -> u64 {
        self.parts.iter().map(|b| b.size()).sum()
    }

    /// WGSL: the parts as bindings `first..` of `group` and the accessor `NAME_at`.
    pub fn declare(&self, group: u32, first: u32) -> String {
        let (n, t) = (self.name, self.wgsl_type);
        let mut s = String::new();
        for k in 0..self.parts.len() {
            s += &format!(
                "@group({group}) @binding({}) var<storage, read> {n}_{k}: array<{t}>;\n",
                first + k as u32
            );
        }
        s += &format!("fn {n}_at(i: u32) -> {t} {{\n");
        let last = self.parts.len() - 1;
        for k in 0..last {
            s += &format!(
                "    if (i < {}u) {{ return {n}_{k}[i - {}u]; }}\n",
                (k as u64 + 1) * self.per_part,
                k as u64 * self.per_part
            );
        }
        s += &format!(
            "    return {n}_{last}[i - {}u];\n}}\n",
            last as u64 * self.per_part
        );
        s
    }

    /// Layout entries for bindings `first..`.
    pub fn layout_entries(&self, first: u32) -> Vec<wgpu::BindGroupLayoutEntry> {
        (0..self.bindings())
            .map(|k| storage_entry(first + k, true))
            .collect()
    }

    /// Bind group entries for bindings `first..`.
    pub fn group_entries(&self, first: u32) -> Vec<wgpu::BindGroupEntry<'_>> {
        self.parts
            .iter()
            .enumerate()
            .map(|(k, b)| wgpu::BindGroupEntry {
                binding: first + k as u32,
                resource: b.as_entire_binding(),
            })
            .collect()
    }
}

/// A compute-stage storage buffer binding.
pub fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(binding, wgpu::BufferBindingType::Storage { read_only })
}

/// A compute-stage uniform buffer binding.
pub fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(binding, wgpu::BufferBindingType::Uniform)
}

fn buffer_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A float as a WGSL literal that parses back to the same f32 (Rust's shortest round-trip
/// form, with the `f` suffix).
pub fn f32_literal(x: f32) -> String {
    assert!(x.is_finite());
    let s = format!("{:?}", x.abs());
    let s = if s.contains('.') || s.contains('e') {
        s
    } else {
        format!("{s}.0")
    };
    if x.is_sign_negative() {
        format!("(-{s}f)")
    } else {
        format!("{s}f")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literals_round_trip() {
        for x in [1e-5f32, 1.0 + 1e-5, 0.1, 3.0, -2.5, 1e30, 7e-39] {
            let s = f32_literal(x);
            let body = s.trim_start_matches("(-").trim_end_matches(')');
            let v: f32 = body.trim_end_matches('f').parse().unwrap();
            let v = if s.starts_with("(-") { -v } else { v };
            assert_eq!(v.to_bits(), x.to_bits(), "{s}");
        }
    }
}
