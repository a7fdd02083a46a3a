//! What `sylva budget` takes (docs/budget.md): an abstract stand, built in or from a canopy
//! file, or a rendered scene, found by name; and the sun a budget of it has by default.

use std::path::Path;

use sylva_budget::{BudgetError, CanopySpec, SunAngles};
use sylva_geom::Scene;

use crate::PipelineError;

/// An abstract stand or a rendered scene.
pub enum BudgetSubject {
    /// A built-in stand or a canopy file.
    Stand(CanopySpec),
    /// A built-in scene or a scene file, built.
    Scene(Box<Scene>),
}

impl BudgetSubject {
    /// A built-in stand, a canopy file (one with `[crowns]` or `[layer]`, read once), or
    /// else a scene file or built-in scene.
    pub fn find(name: &str) -> Result<BudgetSubject, PipelineError> {
        if let Some(spec) = CanopySpec::builtin(name) {
            return Ok(BudgetSubject::Stand(spec));
        }
        let path = Path::new(name);
        if path.is_file() {
            let text = sylva_core::read_text_file(path, 16 << 20, "canopy or scene file").map_err(
                |e| {
                    PipelineError::Budget(BudgetError::Scene {
                        scene: name.to_string(),
                        message: e.to_string(),
                    })
                },
            )?;
            if CanopySpec::is_canopy_text(&text) {
                let spec = CanopySpec::from_text(path, &text).map_err(BudgetError::from)?;
                return Ok(BudgetSubject::Stand(spec));
            }
        }
        match crate::load_scene(name, None) {
            Ok(scene) => Ok(BudgetSubject::Scene(Box::new(scene))),
            Err(PipelineError::Scene(sylva_scene::SceneError::NotFound(_))) => {
                Err(PipelineError::Budget(BudgetError::Scene {
                    scene: name.to_string(),
                    message: format!(
                        "no such canopy or scene file, and not a built-in stand ({}) or scene ({})",
                        CanopySpec::BUILTIN.join(", "),
                        sylva_scene::builtin_scenes::NAMES.join(", ")
                    ),
                }))
            }
            Err(e) => Err(e),
        }
    }

    /// The sun of a budget without `--sun-zenith` and `--sun-azimuth`: a scene's own (to a
    /// nanodegree: its angles come back from a direction vector), 30° from the zenith at
    /// azimuth 0 for a stand.
    pub fn default_sun(&self) -> SunAngles {
        let nano = |deg: f64| (deg * 1e9).round() / 1e9;
        match self {
            BudgetSubject::Scene(scene) => SunAngles {
                zenith_deg: nano(90.0 - scene.sun.elevation_deg()),
                azimuth_deg: nano(scene.sun.azimuth_deg().rem_euclid(360.0)),
            },
            BudgetSubject::Stand(_) => SunAngles {
                zenith_deg: 30.0,
                azimuth_deg: 0.0,
            },
        }
    }
}
