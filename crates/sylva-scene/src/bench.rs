//! `sylva bench scene`: generating each built-in species and building a scene, timed.

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::format_bytes;
use sylva_core::measure::{median, peak_rss_bytes};
use sylva_grow::weber_penn::GenerateError;
use sylva_grow::Species;

use crate::{SceneError, SceneStats};

/// One species' generation.
#[derive(Debug, Clone, Serialize)]
pub struct SpeciesTime {
    pub name: String,
    pub triangles: usize,
    pub median_s: f64,
}

/// The scene's build.
#[derive(Debug, Clone, Serialize)]
pub struct SceneTime {
    pub name: String,
    pub build_median_s: f64,
    pub instances: usize,
    pub unique_triangles: usize,
    pub instanced_triangles: u64,
    pub memory_bytes: u64,
}

/// What [`scene_build`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct SceneBench {
    pub threads: usize,
    pub runs: u32,
    pub species: Vec<SpeciesTime>,
    pub scene: SceneTime,
    pub peak_rss_bytes: Option<u64>,
}

/// Why [`scene_build`] failed.
#[derive(Debug, thiserror::Error)]
pub enum SceneBenchError {
    #[error("species {species}")]
    Species {
        species: String,
        #[source]
        source: GenerateError,
    },
    #[error(transparent)]
    Scene(#[from] SceneError),
}

/// `runs` (at least one) generations of every built-in species and builds of `scene` (a
/// file or a built-in scene): the medians.
pub fn scene_build(scene: &str, runs: u32) -> Result<SceneBench, SceneBenchError> {
    let runs = runs.max(1);
    let mut species = Vec::new();
    for s in Species::all_builtin() {
        let mut times = Vec::new();
        let mut triangles = 0;
        for _ in 0..runs {
            let t = Instant::now();
            let m = s.build_model().map_err(|source| SceneBenchError::Species {
                species: s.name.clone(),
                source,
            })?;
            times.push(t.elapsed().as_secs_f64());
            triangles = m.triangle_count();
        }
        species.push(SpeciesTime {
            name: s.name.clone(),
            triangles,
            median_s: median(times),
        });
    }
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let t = Instant::now();
        let built = crate::load(scene)?;
        times.push(t.elapsed().as_secs_f64());
        last = Some(built);
    }
    let stats = SceneStats::of(&last.expect("runs ≥ 1"));
    Ok(SceneBench {
        threads: rayon::current_num_threads(),
        runs,
        species,
        scene: SceneTime {
            name: stats.name,
            build_median_s: median(times),
            instances: stats.instances,
            unique_triangles: stats.unique_triangles,
            instanced_triangles: stats.instanced_triangles,
            memory_bytes: stats.memory_bytes,
        },
        peak_rss_bytes: peak_rss_bytes(),
    })
}

impl fmt::Display for SceneBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "species generation (median of {} runs, {} threads):",
            self.runs, self.threads
        )?;
        for s in &self.species {
            writeln!(
                f,
                "  {:<18} {:>9} triangles  {:>8.1} ms",
                s.name,
                s.triangles,
                s.median_s * 1e3
            )?;
        }
        let s = &self.scene;
        writeln!(
            f,
            "scene {}: built in {:.3} s (median), {} instances, {} unique / {} instanced triangles, {} in models",
            s.name,
            s.build_median_s,
            s.instances,
            s.unique_triangles,
            s.instanced_triangles,
            format_bytes(s.memory_bytes)
        )?;
        if let Some(p) = self.peak_rss_bytes {
            writeln!(f, "peak resident memory {}", format_bytes(p))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_every_species_and_the_scene_and_names_an_unknown_scene() {
        let b = scene_build("catalpa", 1).unwrap();
        assert_eq!(b.species.len(), Species::all_builtin().len());
        assert!(b
            .species
            .iter()
            .all(|s| s.triangles > 0 && s.median_s > 0.0));
        assert!(b.scene.instances > 0 && b.scene.build_median_s > 0.0);
        let e = scene_build("no_such_scene", 1).unwrap_err();
        assert!(e.to_string().contains("no_such_scene"), "{e}");
    }
}
