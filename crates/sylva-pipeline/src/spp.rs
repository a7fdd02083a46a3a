//! Frames under the SPP light (003 §5): the plane-parallel light of the prepared scene's
//! trees (deep opacity maps in 16 directions, 16³ instance grids, leaf albedo from the scene's
//! `[lb]` preset) under the paper's shading.

use std::time::Instant;

use sylva_light::{IndirectLight, NoDevice, Progress};
use sylva_render::render::{Frame, RenderSettings};
use sylva_spp::trees::system::{SppLight, SppSystem, SystemConfig};

use crate::{PipelineError, PreparedScene};

/// A frame under the SPP light.
pub struct SppFrame {
    pub frame: Frame,
    /// Seconds building the light (maps and grids).
    pub light_seconds: f64,
    /// Why the frame was shaded on the CPU though its rays were traced on a GPU (the GPU
    /// frame kernel reads only lights with a device side).
    pub cpu_shading: Option<NoDevice>,
}

impl PreparedScene {
    /// Builds the SPP light for this scene and renders a frame with it (in one process).
    pub fn render_spp(
        &self,
        settings: &RenderSettings,
        progress: &dyn Progress,
    ) -> Result<SppFrame, PipelineError> {
        let t = Instant::now();
        let system = SppSystem::for_scene(
            &self.scene,
            &self.tracer.cpu().accel,
            SystemConfig::default(),
        )
        .map_err(PipelineError::SppLight)?;
        let light = SppLight::with_preset(&system, &self.scene.lb.preset)?;
        let light_seconds = t.elapsed().as_secs_f64();
        let cpu_shading = match self.tracer.gpu() {
            Some(_) => light.device().err(),
            None => None,
        };
        Ok(SppFrame {
            frame: self.render_with(&light, settings, progress)?,
            light_seconds,
            cpu_shading,
        })
    }
}
