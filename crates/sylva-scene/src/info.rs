//! What `sylva scene info` reports: a built scene's statistics ([`SceneStats`]) with its sun,
//! camera, LB settings, ground and sky, as text ([`SceneInfo`]'s `Display`) or JSON (its
//! `Serialize`).

use std::fmt;

use serde::Serialize;
use sylva_core::{format_bytes, thousands};
use sylva_geom::Scene;

use crate::scene::SceneStats;

/// A built scene as `sylva scene info` describes it.
#[derive(Debug, Clone, Serialize)]
pub struct SceneInfo {
    #[serde(flatten)]
    pub stats: SceneStats,
    /// The file path, or `built-in scene 'NAME'`.
    pub origin: String,
    pub sun: SunInfo,
    pub camera: CameraInfo,
    pub lb: LbInfo,
    pub ground: GroundInfo,
    /// Linear RGB radiance of the sky.
    pub sky_color: [f32; 3],
    /// `[bands]`, when the scene has them: what `sylva render` draws in place of RGB.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bands: Option<BandsInfo>,
}

/// A scene's spectral bands, one entry per band in each list.
#[derive(Debug, Clone, Serialize)]
pub struct BandsInfo {
    pub names: Vec<String>,
    pub leaf_reflectance: Vec<f32>,
    pub leaf_transmittance: Vec<f32>,
    pub bark: Vec<f32>,
    pub soil: Vec<f32>,
    pub sun: Vec<f32>,
    pub sky: Vec<f32>,
    /// The bands shown as red, green and blue.
    pub false_colour: [String; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct SunInfo {
    pub elevation_deg: f64,
    pub azimuth_deg: f64,
    /// Unit vector towards the sun (+y up).
    pub direction: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct CameraInfo {
    pub position: [f32; 3],
    pub look_at: [f32; 3],
    pub fov_deg: f32,
    pub resolution: [u32; 2],
    pub rays_per_pixel: u32,
}

#[derive(Debug, Clone, Serialize)]
pub struct LbInfo {
    pub grid: u32,
    pub preset: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct GroundInfo {
    pub enabled: bool,
    pub size: Option<[f32; 2]>,
    pub color: [f32; 3],
}

impl SceneInfo {
    pub fn of(scene: &Scene) -> SceneInfo {
        let c = &scene.camera;
        let g = &scene.ground;
        SceneInfo {
            stats: SceneStats::of(scene),
            origin: scene.origin.clone(),
            sun: SunInfo {
                elevation_deg: scene.sun.elevation_deg(),
                azimuth_deg: scene.sun.azimuth_deg(),
                direction: scene.sun.to_sun().to_array(),
            },
            camera: CameraInfo {
                position: c.position.to_array(),
                look_at: c.look_at.to_array(),
                fov_deg: c.fov_deg,
                resolution: [c.width, c.height],
                rays_per_pixel: c.rays_per_pixel,
            },
            lb: LbInfo {
                grid: scene.lb.grid,
                preset: scene.lb.preset.clone(),
            },
            ground: GroundInfo {
                enabled: g.enabled,
                size: g.size,
                color: g.color,
            },
            sky_color: scene.sky_color,
            bands: scene.bands.as_ref().map(|b| BandsInfo {
                names: b.names.clone(),
                leaf_reflectance: b.leaf_reflectance.clone(),
                leaf_transmittance: b.leaf_transmittance.clone(),
                bark: b.bark.clone(),
                soil: b.soil.clone(),
                sun: b.sun.clone(),
                sky: b.sky.clone(),
                false_colour: b.false_colour.map(|k| b.names[k].clone()),
            }),
        }
    }
}

impl fmt::Display for SceneInfo {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        let stats = &self.stats;
        writeln!(o, "scene {} ({})", stats.name, self.origin)?;
        writeln!(
            o,
            "  instances            {}",
            thousands(stats.instances as u64)
        )?;
        writeln!(
            o,
            "  unique triangles     {} in {} models",
            thousands(stats.unique_triangles as u64),
            stats.models.len()
        )?;
        writeln!(
            o,
            "  instanced triangles  {}",
            thousands(stats.instanced_triangles)
        )?;
        let [a, b, c] = stats.bounds_min;
        let [d, e, f] = stats.bounds_max;
        writeln!(
            o,
            "  bounds               ({a:.1}, {b:.1}, {c:.1}) .. ({d:.1}, {e:.1}, {f:.1}) m"
        )?;
        writeln!(
            o,
            "  memory               {} (models and textures, instance records, media)",
            format_bytes(stats.memory_bytes)
        )?;
        writeln!(
            o,
            "  sun                  elevation {:.1}°, azimuth {:.1}°",
            self.sun.elevation_deg, self.sun.azimuth_deg
        )?;
        let cam = &self.camera;
        writeln!(
            o,
            "  camera               {}×{}, {} ray(s)/pixel, fov {}°, at {:?} looking at {:?}",
            cam.resolution[0],
            cam.resolution[1],
            cam.rays_per_pixel,
            cam.fov_deg,
            cam.position,
            cam.look_at
        )?;
        writeln!(
            o,
            "  lb                   grid {}, preset {}",
            self.lb.grid, self.lb.preset
        )?;
        if let Some(b) = &self.bands {
            writeln!(
                o,
                "  bands                {} in place of RGB (false colour: R = {}, G = {}, B = {})",
                b.names.len(),
                b.false_colour[0],
                b.false_colour[1],
                b.false_colour[2]
            )?;
            writeln!(
                o,
                "    {:<12} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}",
                "band", "leaf R", "leaf T", "bark", "soil", "sun", "sky"
            )?;
            for (k, n) in b.names.iter().enumerate() {
                writeln!(
                    o,
                    "    {:<12} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3}",
                    n,
                    b.leaf_reflectance[k],
                    b.leaf_transmittance[k],
                    b.bark[k],
                    b.soil[k],
                    b.sun[k],
                    b.sky[k]
                )?;
            }
        }
        if !stats.models.is_empty() {
            writeln!(o)?;
            writeln!(
                o,
                "  {:<18} {:<18} {:>9} {:>11} {:>11} {:>11}  preset",
                "model", "species", "instances", "triangles", "leaf", "wood"
            )?;
        }
        for m in &stats.models {
            writeln!(
                o,
                "  {:<18} {:<18} {:>9} {:>11} {:>11} {:>11}  {}",
                m.name,
                m.species,
                m.instances,
                thousands(m.triangles as u64),
                thousands(m.leaf_triangles as u64),
                thousands(m.wood_triangles as u64),
                m.preset
            )?;
        }
        if !stats.media.is_empty() {
            writeln!(o)?;
            writeln!(
                o,
                "  {:<18} {:<8} {:<13} {:>8} {:>11} {:>6}  box (m)",
                "medium", "preset", "grid", "cell (m)", "occupied", "mean ρ"
            )?;
        }
        for m in &stats.media {
            let [a, b, c] = m.bounds_min;
            let [d, e, f] = m.bounds_max;
            writeln!(
                o,
                "  {:<18} {:<8} {:<13} {:>8.2} {:>11} {:>6.3}  ({a:.0}, {b:.0}, {c:.0}) .. ({d:.0}, {e:.0}, {f:.0})",
                m.name,
                m.preset,
                format!("{}×{}×{}", m.grid[0], m.grid[1], m.grid[2]),
                m.cell,
                thousands(m.occupied as u64),
                m.mean_density
            )?;
        }
        Ok(())
    }
}
