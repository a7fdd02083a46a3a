//! The built scene as plain data: unique models, instances that reference them, media
//! (clouds), and the ground, sun, sky, camera and LB settings. How it is described and built (scene files,
//! growing, import) is `sylva-scene`'s business; everything downstream reads this.

use crate::medium::Medium;
use crate::mesh::{Aabb, Model};
use glam::{Affine3A, Quat, Vec3};
use std::path::PathBuf;
use sylva_core::Sun;

/// The ground plane y = 0: a `size[0]` × `size[1]` rectangle centred on the origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ground {
    pub enabled: bool,
    /// Extent along x and z in metres; `None` in a description means "cover the instances".
    pub size: Option<[f32; 2]>,
    /// Linear RGB.
    pub color: [f32; 3],
}

/// Pinhole camera; +y is up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    pub look_at: Vec3,
    /// Vertical field of view in degrees.
    pub fov_deg: f32,
    pub width: u32,
    pub height: u32,
    pub rays_per_pixel: u32,
}

/// What the LB lighting of a scene uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LbSettings {
    /// Cells along each model's longest edge.
    pub grid: u32,
    /// An LB preset name ([`crate::Preset`]).
    pub preset: String,
}

impl Default for LbSettings {
    fn default() -> Self {
        LbSettings {
            grid: 128,
            preset: "leaf".into(),
        }
    }
}

/// One placed plant: a model reference and a transform (rotation about +y, uniform scale,
/// translation). Geometry is never copied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Instance {
    /// Index into [`Scene::models`].
    pub model: u32,
    pub position: Vec3,
    pub rotation_deg: f32,
    pub scale: f32,
}

impl Instance {
    /// Model space → world space.
    pub fn transform(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(
            Vec3::splat(self.scale),
            Quat::from_rotation_y(self.rotation_deg.to_radians()),
            self.position,
        )
    }

    /// World bounds of `model` under this instance's transform.
    pub fn world_bounds(&self, model: &Model) -> Aabb {
        let t = self.transform();
        let mut b = Aabb::EMPTY;
        for c in model.bounds.corners() {
            b.grow(t.transform_point3(c));
        }
        b
    }
}

/// Where a model of a built scene came from, for reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModelOrigin {
    /// Grown from the species of this name (built-in or an Arbaro file).
    Species(String),
    /// Read from this mesh file.
    MeshFile(PathBuf),
    /// Made in code: the built-in shape of this name (`teapot`).
    Shape(String),
}

/// A built scene: unique models, instances referencing them, and the lighting and view.
#[derive(Debug, Clone)]
pub struct Scene {
    pub name: String,
    /// The file path, or `built-in scene 'NAME'`.
    pub origin: String,
    pub models: Vec<Model>,
    /// Where each model came from, index for index.
    pub model_origins: Vec<ModelOrigin>,
    /// The LB preset of each model, index for index: its own (`[[models]] preset`) or the
    /// scene's `[lb] preset`.
    pub model_presets: Vec<String>,
    pub instances: Vec<Instance>,
    /// Participating media (clouds), drawn by the volume tracer.
    pub media: Vec<Medium>,
    pub ground: Ground,
    pub sun: Sun,
    /// Linear RGB radiance of the sky.
    pub sky_color: [f32; 3],
    /// The sun's colour (irradiance per channel, before `--sun-irradiance` scales it);
    /// `None`: a 6500 K black body of luminance 1. Bands set it ([`Scene::apply_band_group`]).
    pub sun_color: Option<[f32; 3]>,
    pub camera: Camera,
    pub lb: LbSettings,
    /// Spectral bands in place of RGB (`[bands]`), rendered three at a time.
    pub bands: Option<crate::bands::Bands>,
}

impl Scene {
    /// Forms every material's optics for `mode` from its measured values
    /// ([`crate::Material::set_leaf_optics`]; imported materials keep their own). Every
    /// command that lights, renders or exports a scene calls this once after loading it, so
    /// the renderer, the LB and the export read the same factors.
    pub fn set_leaf_optics(&mut self, mode: crate::LeafOptics) -> Result<(), String> {
        for model in &mut self.models {
            for m in &mut model.materials {
                m.set_leaf_optics(mode)
                    .map_err(|e| format!("model '{}': {e}", model.name))?;
            }
        }
        Ok(())
    }

    /// The sun's colour: [`Scene::sun_color`], or a 6500 K black body of luminance 1.
    pub fn sun_rgb(&self) -> [f32; 3] {
        self.sun_color
            .unwrap_or_else(|| sylva_core::blackbody_rgb(sylva_core::SUN_TEMPERATURE_K))
    }

    /// World bounds of all instances (the ground excluded).
    pub fn instance_bounds(&self) -> Aabb {
        self.instances.iter().fold(Aabb::EMPTY, |b, i| {
            b.union(&i.world_bounds(&self.models[i.model as usize]))
        })
    }

    /// Iterates (instance, its model).
    pub fn instances_with_models(&self) -> impl Iterator<Item = (&Instance, &Model)> {
        self.instances
            .iter()
            .map(|i| (i, &self.models[i.model as usize]))
    }

    pub fn unique_triangles(&self) -> usize {
        self.models.iter().map(Model::triangle_count).sum()
    }

    pub fn instanced_triangles(&self) -> u64 {
        self.instances
            .iter()
            .map(|i| self.models[i.model as usize].triangle_count() as u64)
            .sum()
    }

    /// The LB preset of model `k`: its own, or the scene's `[lb] preset`.
    pub fn model_preset(&self, k: usize) -> &str {
        self.model_presets
            .get(k)
            .map_or(self.lb.preset.as_str(), String::as_str)
    }

    /// Model geometry and textures, instance records and media grids.
    pub fn memory_bytes(&self) -> u64 {
        self.models.iter().map(Model::memory_bytes).sum::<u64>()
            + (self.instances.capacity() * std::mem::size_of::<Instance>()) as u64
            + self.media.iter().map(Medium::memory_bytes).sum::<u64>()
    }

    /// Half extents (x, z) of the ground rectangle on y = 0, when there is one.
    pub fn ground_half_extents(&self) -> Option<[f32; 2]> {
        self.ground
            .enabled
            .then(|| self.ground.size.map(|s| [0.5 * s[0], 0.5 * s[1]]))
            .flatten()
    }
}

impl Scene {
    /// The scene's bands of group `g` ([`Bands::group`]) in its three channels: every leaf
    /// gets the bands' measured reflectance and transmittance (its factors are formed by the
    /// next [`Scene::set_leaf_optics`]), bark the bands' albedo as its mean (its texture
    /// keeps the pattern), the ground, the sun and the sky the bands' values. Solid
    /// materials (built-in shapes) keep theirs. No bands: unchanged.
    pub fn apply_band_group(&mut self, g: usize) -> Result<(), String> {
        let Some(bands) = self.bands.clone() else {
            return Ok(());
        };
        if g >= bands.groups() {
            return Err(format!(
                "band group {g}: the scene's {} bands make {} groups",
                bands.len(),
                bands.groups()
            ));
        }
        let measured = crate::Measured {
            reflectance: bands.channels(g, &bands.leaf_reflectance),
            transmittance: bands.channels(g, &bands.leaf_transmittance),
        };
        let bark = bands.channels(g, &bands.bark);
        for model in &mut self.models {
            for m in &mut model.materials {
                match m.kind {
                    crate::MaterialKind::Leaf => m.optics.measured = Some(measured),
                    crate::MaterialKind::Wood => {
                        let mean = m.mean_colour();
                        for c in 0..3 {
                            if mean[c] <= 0.0 && bark[c] > 0.0 {
                                return Err(format!(
                                    "model '{}', material '{}': its colour is black in a \
                                     channel, so it cannot carry band '{}''s bark albedo {}",
                                    model.name,
                                    m.name,
                                    bands.names[bands.group(g)[c]],
                                    bark[c]
                                ));
                            }
                            m.optics.reflect[c] = if mean[c] > 0.0 {
                                bark[c] / mean[c]
                            } else {
                                0.0
                            };
                            m.optics.transmit[c] = 0.0;
                        }
                    }
                    crate::MaterialKind::Solid => {}
                }
            }
        }
        self.ground.color = bands.channels(g, &bands.soil);
        self.sky_color = bands.channels(g, &bands.sky);
        self.sun_color = Some(bands.channels(g, &bands.sun));
        Ok(())
    }
}
