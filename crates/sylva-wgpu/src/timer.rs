//! Kernel times from the GPU's own clock: compute passes write a timestamp at their start
//! and end ([`wgpu::Features::TIMESTAMP_QUERY`]), so a frame's kernel time is measured apart
//! from the host's work (ray generation, uploads, read-back, synchronisation).

use crate::{GpuContext, GpuError};

/// Start and end timestamps of up to `capacity` compute passes.
pub struct PassTimer {
    set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    staging: wgpu::Buffer,
    capacity: u32,
    period_ns: f64,
}

impl PassTimer {
    /// `None` where the device has no timestamp queries.
    pub fn new(ctx: &GpuContext, capacity: u32) -> Result<Option<PassTimer>, GpuError> {
        if !ctx.timestamps() || capacity == 0 {
            return Ok(None);
        }
        let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("pass timer"),
            ty: wgpu::QueryType::Timestamp,
            count: 2 * capacity,
        });
        let bytes = 16 * capacity as u64;
        let resolved = ctx.buffer(
            "pass timer resolve",
            bytes,
            wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        )?;
        let staging = ctx.buffer(
            "pass timer read-back",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        Ok(Some(PassTimer {
            set,
            resolved,
            staging,
            capacity,
            period_ns: ctx.queue.get_timestamp_period() as f64,
        }))
    }

    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// The timestamp writes of pass `k` (< capacity).
    pub fn writes(&self, k: u32) -> wgpu::ComputePassTimestampWrites<'_> {
        assert!(
            k < self.capacity,
            "pass {k} past the timer's {}",
            self.capacity
        );
        wgpu::ComputePassTimestampWrites {
            query_set: &self.set,
            beginning_of_pass_write_index: Some(2 * k),
            end_of_pass_write_index: Some(2 * k + 1),
        }
    }

    /// Copies the first `passes` passes' timestamps towards the host (after the passes, in
    /// the same encoder).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder, passes: u32) {
        let passes = passes.min(self.capacity);
        if passes == 0 {
            return;
        }
        enc.resolve_query_set(&self.set, 0..2 * passes, &self.resolved, 0);
        enc.copy_buffer_to_buffer(&self.resolved, 0, &self.staging, 0, 16 * passes as u64);
    }

    /// Seconds of each of the first `passes` passes (after the encoder of
    /// [`PassTimer::resolve`] was submitted).
    pub fn seconds(&self, ctx: &GpuContext, passes: u32) -> Result<Vec<f64>, GpuError> {
        let passes = passes.min(self.capacity);
        if passes == 0 {
            return Ok(Vec::new());
        }
        let data = ctx.map_read(&self.staging, 16 * passes as u64)?;
        let ticks: Vec<u64> = data
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        Ok(ticks
            .chunks_exact(2)
            .map(|t| t[1].saturating_sub(t[0]) as f64 * self.period_ns * 1e-9)
            .collect())
    }
}
