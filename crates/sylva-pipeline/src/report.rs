//! What a front end shows of a prepared scene and its frames, built from the pipeline's
//! values (nothing here prints): the scene's line ([`scene_line`]), the tracer and the light
//! ([`PreparedScene::describe`]), how a frame was split across processes
//! ([`SplitFrame::summary`]), an image written ([`written_line`]) and a render's per-stage
//! times ([`RenderSummary`]).

use std::fmt;

use sylva_geom::Scene;
use sylva_render::render::{mean_luminance, Frame, Mode};
use sylva_render::shade::ShadingParams;
use sylva_render::stages::{stage, StageClock};

use sylva_lb::Schedule;
use sylva_light::lighting::{Light, LightingError};
use sylva_light::relight::physical::PARTS;
use sylva_light::relight::BasisPlan;

use crate::{ModeImage, PhysicalRelighting, PreparedScene, Relighting, SplitFrame, WrittenImage};

/// ` (K gather rays/sample)` where the physical light gathers, else nothing: the final
/// gather's rays per sample follow the rays per pixel unless given, so a summary says how
/// many a frame took.
pub fn gather_note(shading: &ShadingParams) -> String {
    match shading.gather_rays {
        k if shading.light == Light::Physical && k > 0 => {
            format!(" ({k} gather ray{}/sample)", if k == 1 { "" } else { "s" })
        }
        _ => String::new(),
    }
}

/// The scene as it will be rendered at `width`×`height`: models, instances, triangles,
/// media and the sun.
pub fn scene_line(scene: &Scene, width: u32, height: u32) -> String {
    format!(
        "scene {}: {} models, {} instances, {} instanced triangles, {} media; {width}x{height}; sun elevation {:.1}° azimuth {:.1}°",
        scene.name,
        scene.models.len(),
        scene.instances.len(),
        scene.instanced_triangles(),
        scene.media.len(),
        scene.sun.elevation_deg(),
        scene.sun.azimuth_deg()
    )
}

impl PreparedScene {
    /// Lines on what was prepared: the ray tracer and where frames are shaded, the LB light
    /// when it is relit from base solutions, and the forest grid's weights (per instance
    /// too with `per_instance`).
    pub fn describe(&self, per_instance: bool) -> Vec<String> {
        let mut lines = vec![format!(
            "ray tracer: {}{}",
            self.tracer.describe(),
            match (&self.gpu_frame, self.tracer.gpu()) {
                (Some(f), _) => format!(
                    "; shading on the GPU ({} of shading data)",
                    sylva_core::format_bytes(f.device_bytes())
                ),
                (None, Some(_)) => match self.gpu_shading_note() {
                    Some(why) => format!("; shading on the CPU: {why}"),
                    None => "; shading on the CPU".into(),
                },
                _ => String::new(),
            }
        )];
        if let Some(p) = &self.physical {
            lines.push(format!(
                "LB light: the physical light relit from its base solutions ({} sun parts and 3 \
                 diffuse parts per model, forest grid {}), shadows {}",
                sylva_light::relight::physical::SUN_PARTS,
                if p.has_forest() { "relit" } else { "off" },
                self.shadows().name()
            ));
        }
        if let Some(r) = &self.relit {
            let ill = r.illumination();
            lines.push(format!(
                "LB light: relit from base solutions ({} weights, ambient {}, global grid {}), shadows {}",
                ill.sun.name(),
                ill.ambient,
                r.global()
                    .map(|g| g.dims.to_string())
                    .unwrap_or_else(|| "off".into()),
                self.shadows().name()
            ));
        }
        if let Some(f) = &self.forest {
            lines.push(f.summary(per_instance));
        }
        lines
    }
}

impl SplitFrame {
    /// One line on how the frame was split across processes.
    pub fn summary(&self) -> String {
        let ranks: Vec<String> = self
            .ranks
            .iter()
            .enumerate()
            .map(|(r, w)| format!("rank {r}: {} units {:.3} s", w.units, w.seconds))
            .collect();
        format!(
            "MPI: {} ranks, {} units of {}x{} tiles, frame {:.3} s wall; {}; imbalance {:.1} %",
            self.ranks.len(),
            self.layout.units(),
            self.layout.edge,
            self.layout.edge,
            self.wall_seconds,
            ranks.join(", "),
            100.0 * self.imbalance()
        )
    }
}

/// The scene whose base solutions `sylva basis` precomputes, on `grid` sites per model.
pub fn basis_scene_line(scene: &Scene, grid: usize) -> String {
    format!(
        "scene {}: {} models, {} instances; LB grid {grid}, preset {}",
        scene.name,
        scene.models.len(),
        scene.instances.len(),
        scene.lb.preset
    )
}

/// The independent solve jobs of `scene`'s base solutions, a tab-separated line each after a
/// header, to `line`: per model the physical light's parts, or (`physical` false) the paper
/// light's (model, base solution, colour) with models on `grid` sites: the work list a
/// distributed precompute hands out.
pub fn basis_jobs(
    scene: &Scene,
    physical: bool,
    grid: usize,
    line: &mut dyn FnMut(String),
) -> Result<(), LightingError> {
    if physical {
        line("model\tpart".into());
        for m in 0..scene.models.len() {
            for part in 0..PARTS {
                line(format!("{m}\t{part}"));
            }
        }
        return Ok(());
    }
    line("model\tbasis\tcolour".into());
    for (m, model) in scene.models.iter().enumerate() {
        // The jobs are the same on any schedule.
        let (_, jobs) = BasisPlan::jobs_of(model, grid, scene.model_preset(m), Schedule::Papers)?;
        for job in jobs {
            line(format!("{m}\t{}\t{}", job.basis, job.colour));
        }
    }
    Ok(())
}

impl PhysicalRelighting {
    /// One line on the precomputed parts of `models` models, stored as `codec` says
    /// ("uncompressed" or the codecs' names), `seconds` in all.
    pub fn summary(&self, models: usize, codec: &str, seconds: f64) -> String {
        let bytes: u64 = self.bases.iter().flatten().map(|b| b.bytes()).sum();
        format!(
            "{} of {models} models from the cache; physical bases {} in all ({PARTS} parts per \
             model, {codec}; {} uncompressed){}; {seconds:.1} s",
            self.cached,
            sylva_core::format_bytes(bytes),
            sylva_core::format_bytes(self.raw_bytes),
            if self.forest.is_some() {
                ", forest grid parts solved"
            } else {
                ""
            },
        )
    }
}

impl Relighting {
    /// One line on the compressed base solutions (`codec`) of `models` models, `seconds` in
    /// all.
    pub fn summary(&self, models: usize, codec: &str, seconds: f64) -> String {
        let bytes: u64 = self.compressed.iter().flatten().map(|b| b.bytes()).sum();
        format!(
            "{} of {models} models from the cache; compressed bases {} in all ({codec}); \
             {seconds:.1} s",
            self.cached,
            sylva_core::format_bytes(bytes),
        )
    }
}

/// The line on one mode's image of `frame`, written as `files`.
pub fn written_line(image: &ModeImage, files: &WrittenImage, frame: &Frame) -> String {
    let mut wrote = files.png.display().to_string();
    if let Some(exr) = &files.exr {
        wrote = format!("{wrote} and {}", exr.display());
    }
    format!(
        "wrote {wrote} ({} mode, mean luminance {:.4}{})",
        image.mode.name(),
        mean_luminance(&image.hdr),
        if image.mode == Mode::Ambient {
            format!(", ambient {:.4}", frame.matched_ambient())
        } else {
            String::new()
        }
    )
}

/// A render's stages timed (scene build to image output, from the spans `clock` heard and
/// the frame's own pass timings), its frame and its memory: `sylva render`'s summary.
pub struct RenderSummary<'a> {
    pub prepared: &'a PreparedScene,
    pub frame: &'a Frame,
    pub rays_per_pixel: u32,
    pub clock: &'a StageClock,
    /// Seconds building the SPP light, when the frame used it.
    pub spp_seconds: Option<f64>,
    pub total_seconds: f64,
    /// [`SplitFrame::summary`] when the frame was split across processes.
    pub split: Option<String>,
}

impl fmt::Display for RenderSummary<'_> {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (frame, clock) = (self.frame, self.clock);
        let t = &frame.timings;
        writeln!(o, "stage                 seconds")?;
        for (name, s) in [
            ("scene build", clock.seconds(stage::SCENE_BUILD)),
            ("LB precompute", clock.seconds(stage::LB_PRECOMPUTE)),
            ("SPP maps and grids", self.spp_seconds.unwrap_or(0.0)),
            ("acceleration build", clock.seconds(stage::ACCEL_BUILD)),
            ("primary rays", t.primary_seconds),
            ("shadow rays", t.shadow_seconds),
            ("shading", t.shading_seconds),
            ("GPU frame", t.fused_seconds),
            ("tone mapping", clock.seconds(stage::TONE_MAPPING)),
            ("image output", clock.seconds(stage::IMAGE_OUTPUT)),
        ] {
            // A GPU frame is one pass (rays and shading); the CPU's passes are separate.
            let pass = ["primary rays", "shadow rays", "shading"].contains(&name);
            let gpu = t.fused_seconds > 0.0;
            if (name == "GPU frame" && !gpu) || (pass && gpu) {
                continue;
            }
            writeln!(o, "  {name:<20}{s:>8.3}")?;
        }
        writeln!(o, "  {:<20}{:>8.3}", "total", self.total_seconds)?;
        if let Some(split) = &self.split {
            writeln!(o, "{split}")?;
        }
        let gather = gather_note(&self.prepared.shading);
        writeln!(
            o,
            "{}x{} at {} rays/pixel{gather}: {} primary + {} shadow rays, {:.2} Mrays/s; frame {:.3} s; {} kd-restarts; kd-trees {}, LB grids {}",
            frame.width,
            frame.height,
            self.rays_per_pixel,
            t.primary_rays,
            t.shadow_rays,
            t.mrays_per_second(),
            t.frame_seconds(),
            frame.stats.restarts,
            sylva_core::format_bytes(self.prepared.tracer.cpu().accel.memory().total()),
            sylva_core::format_bytes(self.prepared.lighting_bytes()),
        )?;
        if let Some(b) = self.prepared.bake_summary() {
            writeln!(
                o,
                "relit light decoded for this sun: {} of {} instances in {} grids, {} in {:.3} s",
                b.instances,
                b.of,
                b.grids,
                sylva_core::format_bytes(b.bytes),
                b.seconds
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gather_note_names_the_rays_a_sample_took() {
        let with = |light, gather_rays| {
            gather_note(&ShadingParams {
                light,
                gather_rays,
                ..ShadingParams::default()
            })
        };
        assert_eq!(with(Light::Physical, 2), " (2 gather rays/sample)");
        assert_eq!(with(Light::Physical, 1), " (1 gather ray/sample)");
        // No gather: the LB light at the leaf, or a light that does not gather.
        assert_eq!(with(Light::Physical, 0), "");
        assert_eq!(with(Light::Paper, 8), "");
    }
}
