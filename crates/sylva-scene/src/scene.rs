//! Scene files (TOML) and building them into a [`sylva_geom::Scene`].
//!
//! A [`SceneDesc`] is a parsed and checked scene file (no geometry yet); [`SceneDesc::build`]
//! generates each unique model once and places the instances, which only reference models:
//! a forest of 962 trees holds 5 meshes.
//!
//! Every error names its origin (file path or built-in scene) and, where it has one, the line.

use crate::builtin_scenes;
use crate::layout::{self, Amount, Area, LayoutError, Occupancy, ScatterSpec};
use glam::Vec3;
use rayon::prelude::*;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use sylva_core::limits;
use sylva_core::Sun;
use sylva_geom::{
    Aabb, Bands, Camera, Ground, Instance, LbSettings, Measured, Medium, Model, ModelOrigin, Scene,
};
use sylva_grow::arbaro::{self, ArbaroError};
use sylva_grow::cloud::{cumulus, CloudError, CumulusParams};
use sylva_grow::species::{normalize_name, Species, BUILTIN_NAMES};
use sylva_grow::stand::CanopySpec;
use sylva_grow::teapot::teapot_model;
use sylva_grow::weber_penn::GenerateError;
use sylva_io::import::{self, ImportError, ImportOptions, UpAxis};
use toml::Spanned;

/// LB presets a scene may name (the LB crate defines their values).
pub const LB_PRESETS: &[&str] = &["leaf", "dogrose", "cloud", "pmma"];

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A scene file that cannot be read (missing, not a regular file, too large, not text).
    #[error(transparent)]
    Input(#[from] sylva_core::InputError),
    #[error("no scene file '{0}' and no built-in scene of that name (built-in scenes: {builtins})", builtins = builtin_scenes::NAMES.join(", "))]
    NotFound(String),
    #[error("'{0}' is no scene file, built-in scene or built-in species (scenes: {scenes}; species: {species})", scenes = builtin_scenes::NAMES.join(", "), species = BUILTIN_NAMES.join(", "))]
    NoSceneOrSpecies(String),
    /// A model file (OBJ, glTF) given where a scene is expected.
    #[error("{}: is a {kind} model, not a scene: scene files are TOML (docs/scenes.md); to use the model, name it in a scene: [[models]] mesh = \"{}\"", path.display(), path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default())]
    ModelNotScene { path: PathBuf, kind: &'static str },
    /// Syntax, unknown keys, wrong types and bad values.
    #[error("{origin}{}: {message}", line.map(|l| format!(": line {l}")).unwrap_or_default())]
    Invalid {
        origin: String,
        line: Option<usize>,
        message: String,
    },
    #[error("{origin}: line {line}: model '{model}': {source}")]
    Arbaro {
        origin: String,
        line: usize,
        model: String,
        source: Box<ArbaroError>,
    },
    #[error("{origin}: model '{model}': {source}")]
    Generate {
        origin: String,
        model: String,
        source: GenerateError,
    },
    /// An imported mesh file that cannot be read; `source` names the file and element.
    #[error("{origin}: line {line}: model '{model}': {source}")]
    Import {
        origin: String,
        line: usize,
        model: String,
        source: Box<ImportError>,
    },
    #[error("{origin}: line {line}: medium '{medium}': {source}")]
    Medium {
        origin: String,
        line: usize,
        medium: String,
        source: CloudError,
    },
    #[error("{origin}: line {line}: instances of '{model}': {source}")]
    Layout {
        origin: String,
        line: usize,
        model: String,
        source: LayoutError,
    },
}

// ---------- the file as written ----------

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: Option<String>,
    #[serde(default)]
    models: Vec<Spanned<RawModel>>,
    #[serde(default)]
    instances: Vec<Spanned<RawInstance>>,
    #[serde(default)]
    media: Vec<Spanned<RawMedium>>,
    ground: Option<Spanned<RawGround>>,
    sun: Option<Spanned<RawSun>>,
    sky: Option<Spanned<RawSky>>,
    camera: Option<Spanned<RawCamera>>,
    lb: Option<Spanned<RawLb>>,
    stand: Option<Spanned<RawStand>>,
    bands: Option<Spanned<RawBands>>,
}

/// `[bands]`: spectral bands in place of RGB, one value per band in each list.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBands {
    names: Vec<String>,
    leaf_reflectance: Vec<f32>,
    leaf_transmittance: Vec<f32>,
    bark: Vec<f32>,
    soil: Vec<f32>,
    /// Default: 1 in every band (a flat spectrum).
    sun: Option<Vec<f32>>,
    sky: Vec<f32>,
    /// Three band names shown as red, green and blue (default: the last three bands, the
    /// longest wavelength in red when names run from short to long).
    false_colour: Option<[String; 3]>,
}

/// `[stand]`: an abstract canopy's crowns (or layer) as models and instances.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStand {
    /// A built-in stand (`crowns`, `layer`) or a canopy file, relative to the scene file.
    canopy: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    name: String,
    species: Option<String>,
    arbaro: Option<String>,
    mesh: Option<String>,
    shape: Option<String>,
    seed: Option<u64>,
    /// The model's own LB preset (default: the scene's `[lb] preset`).
    preset: Option<String>,
    // Built-in shapes only.
    color: Option<[f32; 3]>,
    // Grown models only: measured leaf optics replacing the species' (both or neither).
    leaf_reflectance: Option<[f32; 3]>,
    leaf_transmittance: Option<[f32; 3]>,
    // Imported meshes only.
    leaf_materials: Option<Vec<String>>,
    wood_materials: Option<Vec<String>>,
    scale: Option<f32>,
    up: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawArea {
    min: [f32; 2],
    max: [f32; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInstance {
    model: String,
    // Explicit placement.
    position: Option<[f32; 3]>,
    rotation: Option<f32>,
    scale: Option<f32>,
    // Generator.
    count: Option<u32>,
    density: Option<f64>,
    area: Option<RawArea>,
    min_spacing: Option<f32>,
    random_rotation: Option<bool>,
    scale_jitter: Option<f32>,
    seed: Option<u64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMedium {
    name: String,
    generator: String,
    grid: Option<[usize; 3]>,
    seed: Option<u64>,
    thermals: Option<usize>,
    shear: Option<f64>,
    position: Option<[f32; 3]>,
    size: Option<f32>,
    preset: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGround {
    enabled: Option<bool>,
    size: Option<[f32; 2]>,
    color: Option<[f32; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSun {
    direction: Option<[f64; 3]>,
    elevation: Option<f64>,
    azimuth: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSky {
    color: [f32; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    position: Option<[f32; 3]>,
    look_at: Option<[f32; 3]>,
    fov: Option<f32>,
    resolution: Option<[u32; 2]>,
    rays_per_pixel: Option<u32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLb {
    grid: Option<u32>,
    preset: Option<String>,
}

// ---------- checked description ----------

/// Where a model's geometry comes from.
#[derive(Debug, Clone)]
pub enum ModelSource {
    /// A built-in species or one read from an Arbaro file: grown by the generator.
    Species(Box<Species>),
    /// A mesh file (OBJ, glTF, GLB) read by [`import::load_mesh_file`].
    Mesh {
        path: PathBuf,
        options: ImportOptions,
    },
    /// A shape made in code ([`SHAPES`]) in one solid material of linear colour `color`.
    Shape { shape: Shape, color: [f32; 3] },
    /// Model `unit` of an abstract canopy (`[stand]`: a crown variant, or the layer).
    Stand {
        spec: std::sync::Arc<CanopySpec>,
        unit: usize,
    },
}

/// Shapes a model can be made of (`shape = "teapot"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// The Newell teapot (paper 002 §3.2.3), 16 × 16 quads per patch.
    Teapot,
}

/// Names of the [`Shape`]s.
pub const SHAPES: &[&str] = &["teapot"];

impl Shape {
    pub fn parse(s: &str) -> Option<Shape> {
        match s {
            "teapot" => Some(Shape::Teapot),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Shape::Teapot => "teapot",
        }
    }

    /// The shape's default colour: clear PMMA, a little warm.
    pub const DEFAULT_COLOR: [f32; 3] = [0.80, 0.76, 0.70];

    pub fn build(self, color: [f32; 3]) -> Model {
        match self {
            Shape::Teapot => teapot_model(16, color),
        }
    }
}

#[derive(Debug, Clone)]
pub struct ModelDesc {
    /// The name instances use.
    pub name: String,
    pub source: ModelSource,
    /// Its own LB preset (`preset = "dogrose"`); `None`: the scene's.
    pub preset: Option<String>,
    pub line: usize,
}

/// How a medium's density is made.
#[derive(Debug, Clone, PartialEq)]
pub enum MediumGenerator {
    /// The cumulus parcel model of [`sylva_grow::cloud`].
    Cumulus(CumulusParams),
}

/// Generators a medium may name.
pub const MEDIUM_GENERATORS: &[&str] = &["cumulus"];

/// A `[[media]]` entry: a density grid made in code, placed in the world.
#[derive(Debug, Clone)]
pub struct MediumDesc {
    pub name: String,
    pub generator: MediumGenerator,
    /// World position of the centre of the grid's bottom face.
    pub position: Vec3,
    pub preset: String,
    pub line: usize,
}

impl MediumDesc {
    /// The same medium generated at `dims` sites (its generator's parameters for that grid,
    /// its seed kept).
    pub fn at_grid(&self, dims: [usize; 3]) -> MediumDesc {
        let MediumGenerator::Cumulus(p) = &self.generator;
        MediumDesc {
            generator: MediumGenerator::Cumulus(CumulusParams::for_grid(dims, p.seed)),
            ..self.clone()
        }
    }

    /// Generates the density and places it.
    pub fn build(&self, origin: &str) -> Result<Medium, SceneError> {
        let MediumGenerator::Cumulus(p) = &self.generator;
        let cloud = cumulus(p).map_err(|source| SceneError::Medium {
            origin: origin.to_string(),
            line: self.line,
            medium: self.name.clone(),
            source,
        })?;
        let [nx, ny, nz] = cloud.dims;
        let h = cloud.cell_m as f32;
        let extent = Vec3::new((nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32) * h;
        let min = self.position - Vec3::new(0.5 * extent.x, 0.0, 0.5 * extent.z);
        Medium::new(
            self.name.clone(),
            cloud.dims,
            Aabb {
                min,
                max: min + extent,
            },
            cloud.density,
            self.preset.clone(),
        )
        .map_err(|message| SceneError::Invalid {
            origin: origin.to_string(),
            line: Some(self.line),
            message,
        })
    }
}

#[derive(Debug, Clone)]
pub enum Placement {
    Explicit {
        position: Vec3,
        rotation_deg: f32,
        scale: f32,
    },
    Scatter(ScatterSpec),
}

#[derive(Debug, Clone)]
pub struct InstanceDesc {
    /// Index into [`SceneDesc::models`].
    pub model: usize,
    pub placement: Placement,
    pub line: usize,
}

/// A parsed, checked scene file; [`SceneDesc::build`] makes the geometry.
#[derive(Debug, Clone)]
pub struct SceneDesc {
    pub name: String,
    /// The file path, or `built-in scene 'NAME'`.
    pub origin: String,
    pub models: Vec<ModelDesc>,
    pub instances: Vec<InstanceDesc>,
    pub media: Vec<MediumDesc>,
    pub ground: Ground,
    pub sun: Sun,
    /// Linear RGB radiance of the sky.
    pub sky_color: [f32; 3],
    /// `None` position: frame the scene's bounds when it is built.
    pub camera: CameraDesc,
    pub lb: LbSettings,
    /// `[bands]`: spectral bands in place of RGB.
    pub bands: Option<Bands>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraDesc {
    pub position: Option<Vec3>,
    pub look_at: Option<Vec3>,
    pub fov_deg: f32,
    pub width: u32,
    pub height: u32,
    pub rays_per_pixel: u32,
}

/// Per-model line of [`SceneStats`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct ModelStats {
    pub name: String,
    /// The species name, or the file name of an imported mesh.
    pub species: String,
    pub instances: usize,
    pub triangles: usize,
    pub leaf_triangles: usize,
    pub wood_triangles: usize,
    pub memory_bytes: u64,
    /// Its LB preset.
    pub preset: String,
}

/// Per-medium line of [`SceneStats`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct MediumStats {
    pub name: String,
    pub preset: String,
    pub grid: [usize; 3],
    /// World length of a cell (one LB step), m.
    pub cell: f32,
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    /// Sites with density.
    pub occupied: usize,
    pub mean_density: f64,
    pub memory_bytes: u64,
}

/// What `sylva scene info` reports.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SceneStats {
    pub name: String,
    pub instances: usize,
    pub unique_triangles: usize,
    pub instanced_triangles: u64,
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    /// Bytes of model geometry and textures, instance records and media grids.
    pub memory_bytes: u64,
    pub models: Vec<ModelStats>,
    pub media: Vec<MediumStats>,
}

/// `Err` names the presets when `preset` is not one of them.
fn check_preset(preset: &str) -> Result<(), String> {
    if LB_PRESETS.contains(&preset) {
        Ok(())
    } else {
        Err(format!(
            "unknown lb preset '{preset}' (presets: {})",
            LB_PRESETS.join(", ")
        ))
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn finite3(v: [f32; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SceneDesc {
    /// A scene by file path, or a built-in scene by name when no such file exists.
    pub fn load(name_or_path: &str) -> Result<SceneDesc, SceneError> {
        let path = Path::new(name_or_path);
        // Not `exists()`: a link that loops or dangles is a file name the user gave, and the
        // reader says what is wrong with it.
        if path.symlink_metadata().is_ok() {
            return SceneDesc::load_file(path);
        }
        match builtin_scenes::source(name_or_path) {
            Some(text) => SceneDesc::parse(text, &format!("built-in scene '{name_or_path}'"), None),
            None => Err(SceneError::NotFound(name_or_path.to_string())),
        }
    }

    pub fn load_file(path: &Path) -> Result<SceneDesc, SceneError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        let kind = match ext.as_deref() {
            Some("gltf") | Some("glb") => Some("glTF"),
            Some("obj") => Some("Wavefront OBJ"),
            _ => None,
        };
        if let Some(kind) = kind {
            return Err(SceneError::ModelNotScene {
                path: path.to_path_buf(),
                kind,
            });
        }
        let text =
            sylva_core::read_text_file(path, sylva_core::limits::TEXT_FILE_BYTES, "scene files")?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        SceneDesc::parse(&text, &path.display().to_string(), Some(&dir))
    }

    /// Parses and checks scene TOML. Relative model files resolve against `base_dir`
    /// (the current directory when `None`).
    pub fn parse(
        text: &str,
        origin: &str,
        base_dir: Option<&Path>,
    ) -> Result<SceneDesc, SceneError> {
        let invalid = |line: Option<usize>, message: String| SceneError::Invalid {
            origin: origin.to_string(),
            line,
            message,
        };
        let raw: RawScene = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            invalid(line, e.message().trim().to_string())
        })?;
        let line = |s: std::ops::Range<usize>| line_of(text, s.start);
        // Models.
        let mut models: Vec<ModelDesc> = Vec::new();
        for m in &raw.models {
            let l = line(m.span());
            let m = m.get_ref();
            if models.iter().any(|o| o.name == m.name) {
                return Err(invalid(
                    Some(l),
                    format!("model '{}' is defined twice", m.name),
                ));
            }
            let sources = [
                m.species.is_some(),
                m.arbaro.is_some(),
                m.mesh.is_some(),
                m.shape.is_some(),
            ];
            if m.shape.is_none() && m.color.is_some() {
                return Err(invalid(
                    Some(l),
                    format!(
                        "model '{}': 'color' applies to built-in shapes ('shape = \"teapot\"') only",
                        m.name
                    ),
                ));
            }
            if let Some(preset) = &m.preset {
                check_preset(preset).map_err(|message| {
                    invalid(Some(l), format!("model '{}': {message}", m.name))
                })?;
            }
            // A grown model's measured leaf, checked here so a bad one names the line.
            let leaf = match (m.leaf_reflectance, m.leaf_transmittance) {
                (None, None) => None,
                (Some(reflectance), Some(transmittance)) => {
                    if m.species.is_none() && m.arbaro.is_none() {
                        return Err(invalid(
                            Some(l),
                            format!(
                                "model '{}': 'leaf_reflectance' and 'leaf_transmittance' apply \
                                 to grown models ('species' or 'arbaro') only; imported meshes \
                                 keep their own materials",
                                m.name
                            ),
                        ));
                    }
                    let leaf = Measured {
                        reflectance,
                        transmittance,
                    };
                    leaf.validate(&format!("model '{}': leaf", m.name))
                        .map_err(|e| invalid(Some(l), e))?;
                    Some(leaf)
                }
                _ => {
                    return Err(invalid(
                        Some(l),
                        format!(
                            "model '{}': give both 'leaf_reflectance' and 'leaf_transmittance' \
                             (measured, linear R, G, B) or neither",
                            m.name
                        ),
                    ))
                }
            };
            let with_leaf = |s: Species| match leaf {
                Some(leaf) => s.with_leaf(leaf, &format!("scene file {origin}")),
                None => s,
            };
            if m.mesh.is_none() {
                let import_keys = [
                    ("leaf_materials", m.leaf_materials.is_some()),
                    ("wood_materials", m.wood_materials.is_some()),
                    ("scale", m.scale.is_some()),
                    ("up", m.up.is_some()),
                ];
                if let Some((key, _)) = import_keys.iter().find(|(_, set)| *set) {
                    return Err(invalid(
                        Some(l),
                        format!("model '{}': '{key}' applies to imported meshes ('mesh = \"file\"') only", m.name),
                    ));
                }
            }
            if sources.iter().filter(|&&s| s).count() != 1 {
                return Err(invalid(
                    Some(l),
                    format!(
                        "model '{}' needs exactly one of 'species', 'arbaro', 'mesh' or 'shape'",
                        m.name
                    ),
                ));
            }
            let source = if let Some(name) = &m.shape {
                let shape = Shape::parse(name).ok_or_else(|| {
                    invalid(
                        Some(l),
                        format!(
                            "model '{}': unknown shape '{name}' (shapes: {})",
                            m.name,
                            SHAPES.join(", ")
                        ),
                    )
                })?;
                if m.seed.is_some() {
                    return Err(invalid(
                        Some(l),
                        format!(
                            "model '{}': 'seed' applies to grown models; a shape is fixed",
                            m.name
                        ),
                    ));
                }
                let color = m.color.unwrap_or(Shape::DEFAULT_COLOR);
                if !color
                    .iter()
                    .all(|c| c.is_finite() && (0.0..=1.0).contains(c))
                {
                    return Err(invalid(
                        Some(l),
                        format!("model '{}': color {color:?} must lie in [0, 1]", m.name),
                    ));
                }
                ModelSource::Shape { shape, color }
            } else if let Some(name) = &m.species {
                let mut s = Species::builtin(name).ok_or_else(|| {
                    invalid(
                        Some(l),
                        format!(
                            "model '{}': unknown species '{name}' (built-in species: {})",
                            m.name,
                            BUILTIN_NAMES.join(", ")
                        ),
                    )
                })?;
                if let Some(seed) = m.seed {
                    s.seed = seed;
                }
                ModelSource::Species(Box::new(with_leaf(s)))
            } else if let Some(file) = &m.arbaro {
                let p: PathBuf = match base_dir {
                    Some(d) => d.join(file),
                    None => PathBuf::from(file),
                };
                let a = arbaro::load_file(&p).map_err(|source| SceneError::Arbaro {
                    origin: origin.to_string(),
                    line: l,
                    model: m.name.clone(),
                    source: Box::new(source),
                })?;
                let seed = m.seed.or(a.seed).unwrap_or(0);
                ModelSource::Species(Box::new(with_leaf(Species::from_params(
                    &normalize_name(&a.name),
                    a.params,
                    seed,
                    p.display().to_string(),
                ))))
            } else {
                let file = m.mesh.as_deref().unwrap_or_default();
                let path: PathBuf = match base_dir {
                    Some(d) => d.join(file),
                    None => PathBuf::from(file),
                };
                let bad =
                    |message: String| invalid(Some(l), format!("model '{}': {message}", m.name));
                if m.seed.is_some() {
                    return Err(bad(
                        "'seed' applies to grown models; a mesh file is fixed".into()
                    ));
                }
                if !import::is_mesh_file(&path) {
                    return Err(bad(format!(
                        "mesh '{file}': unknown format (readable: .{})",
                        import::EXTENSIONS.join(", .")
                    )));
                }
                if !path.is_file() {
                    return Err(bad(format!(
                        "mesh '{file}': no such file ({})",
                        path.display()
                    )));
                }
                let scale = m.scale.unwrap_or(1.0);
                if !(scale.is_finite() && scale > 0.0) {
                    return Err(bad(format!("scale must be a positive number, got {scale}")));
                }
                let up = match m.up.as_deref().map(str::to_ascii_lowercase).as_deref() {
                    None | Some("y") => UpAxis::Y,
                    Some("z") => UpAxis::Z,
                    Some(other) => {
                        return Err(bad(format!("up = '{other}': expected \"y\" or \"z\"")))
                    }
                };
                ModelSource::Mesh {
                    path,
                    options: ImportOptions {
                        leaf_materials: m.leaf_materials.clone().unwrap_or_default(),
                        wood_materials: m.wood_materials.clone().unwrap_or_default(),
                        scale,
                        up,
                    },
                }
            };
            models.push(ModelDesc {
                name: m.name.clone(),
                source,
                preset: m.preset.clone(),
                line: l,
            });
        }

        // Instances.
        let mut instances = Vec::new();
        for (k, inst) in raw.instances.iter().enumerate() {
            let l = line(inst.span());
            let i = inst.get_ref();
            let model = models
                .iter()
                .position(|m| m.name == i.model)
                .ok_or_else(|| {
                    invalid(
                        Some(l),
                        format!(
                            "instance refers to model '{}', which no [[models]] entry defines",
                            i.model
                        ),
                    )
                })?;
            let scale = i.scale.unwrap_or(1.0);
            if !(scale.is_finite() && scale > 0.0) {
                return Err(invalid(
                    Some(l),
                    format!("scale must be a positive number, got {scale}"),
                ));
            }
            let placement = if let Some(position) = i.position {
                let generator_keys = [
                    ("count", i.count.is_some()),
                    ("density", i.density.is_some()),
                    ("area", i.area.is_some()),
                    ("min_spacing", i.min_spacing.is_some()),
                    ("random_rotation", i.random_rotation.is_some()),
                    ("scale_jitter", i.scale_jitter.is_some()),
                    ("seed", i.seed.is_some()),
                ];
                if let Some((key, _)) = generator_keys.iter().find(|(_, set)| *set) {
                    return Err(invalid(
                        Some(l),
                        format!("an instance with 'position' is placed explicitly; '{key}' belongs to a generator"),
                    ));
                }
                let rotation_deg = i.rotation.unwrap_or(0.0);
                if !finite3(position) || !rotation_deg.is_finite() {
                    return Err(invalid(
                        Some(l),
                        "position and rotation must be finite".into(),
                    ));
                }
                Placement::Explicit {
                    position: Vec3::from_array(position),
                    rotation_deg,
                    scale,
                }
            } else {
                if i.rotation.is_some() {
                    return Err(invalid(
                        Some(l),
                        "'rotation' needs 'position'; a generator uses 'random_rotation'".into(),
                    ));
                }
                let amount = match (i.count, i.density) {
                    (Some(c), None) => Amount::Count(c as usize),
                    (None, Some(d)) => Amount::PerSquareMetre(d),
                    _ => {
                        return Err(invalid(
                            Some(l),
                            "an instance needs 'position', or a generator with exactly one of 'count' or 'density'".into(),
                        ))
                    }
                };
                let area = i.area.as_ref().ok_or_else(|| {
                    invalid(
                        Some(l),
                        "a generator needs 'area = { min = [x, z], max = [x, z] }'".into(),
                    )
                })?;
                Placement::Scatter(ScatterSpec {
                    amount,
                    area: Area {
                        min: area.min,
                        max: area.max,
                    },
                    min_spacing: i.min_spacing.unwrap_or(0.0),
                    random_rotation: i.random_rotation.unwrap_or(true),
                    scale,
                    scale_jitter: i.scale_jitter.unwrap_or(0.0),
                    seed: i.seed.unwrap_or(k as u64 + 1),
                })
            };
            instances.push(InstanceDesc {
                model,
                placement,
                line: l,
            });
        }

        // Media.
        let mut media: Vec<MediumDesc> = Vec::new();
        for m in &raw.media {
            let l = line(m.span());
            let m = m.get_ref();
            let bad = |message: String| invalid(Some(l), format!("medium '{}': {message}", m.name));
            if media.iter().any(|o| o.name == m.name) {
                return Err(bad("is defined twice".into()));
            }
            if !MEDIUM_GENERATORS.contains(&m.generator.as_str()) {
                return Err(bad(format!(
                    "unknown generator '{}' (generators: {})",
                    m.generator,
                    MEDIUM_GENERATORS.join(", ")
                )));
            }
            let grid = m.grid.unwrap_or(CumulusParams::default().dims);
            if grid.iter().any(|n| !limits::MEDIUM_GRID.contains(n)) {
                return Err(bad(format!(
                    "grid {}×{}×{} must have {} sites per edge",
                    grid[0],
                    grid[1],
                    grid[2],
                    limits::describe(&limits::MEDIUM_GRID)
                )));
            }
            let mut params = CumulusParams::for_grid(grid, m.seed.unwrap_or(1));
            if let Some(size) = m.size {
                if !(size.is_finite() && size > 0.0) {
                    return Err(bad(format!(
                        "size {size} must be a positive length (metres along x)"
                    )));
                }
                params.cell_m = size as f64 / (grid[0] - 1) as f64;
            }
            if let Some(t) = m.thermals {
                params.thermals = t;
            }
            if let Some(shear) = m.shear {
                params.shear = shear;
            }
            let position = m.position.unwrap_or([0.0; 3]);
            if !finite3(position) {
                return Err(bad(format!("position {position:?} must be finite")));
            }
            let preset = m.preset.clone().unwrap_or_else(|| "cloud".into());
            check_preset(&preset).map_err(bad)?;
            media.push(MediumDesc {
                name: m.name.clone(),
                generator: MediumGenerator::Cumulus(params),
                position: Vec3::from_array(position),
                preset,
                line: l,
            });
        }

        // Ground.
        let ground = match &raw.ground {
            None => Ground {
                enabled: true,
                size: None,
                color: [0.20, 0.17, 0.12],
            },
            Some(g) => {
                let l = line(g.span());
                let g = g.get_ref();
                if let Some(s) = g.size {
                    if !s.iter().all(|v| v.is_finite() && *v > 0.0) {
                        return Err(invalid(
                            Some(l),
                            format!("ground size {s:?} must be positive"),
                        ));
                    }
                }
                let color = g.color.unwrap_or([0.20, 0.17, 0.12]);
                if !color.iter().all(|c| c.is_finite() && *c >= 0.0) {
                    return Err(invalid(
                        Some(l),
                        format!("ground color {color:?} must be ≥ 0"),
                    ));
                }
                Ground {
                    enabled: g.enabled.unwrap_or(true),
                    size: g.size,
                    color,
                }
            }
        };

        // Sun.
        let sun = match &raw.sun {
            None => Sun::default(),
            Some(s) => {
                let l = line(s.span());
                let s = s.get_ref();
                let r = match (s.direction, s.elevation, s.azimuth) {
                    (Some(d), None, None) => Sun::from_direction(d[0], d[1], d[2]),
                    (None, Some(e), Some(a)) => Sun::from_angles(e, a),
                    _ => {
                        return Err(invalid(
                            Some(l),
                            "sun needs either 'direction' or both 'elevation' and 'azimuth'".into(),
                        ))
                    }
                };
                r.map_err(|e| invalid(Some(l), e.to_string()))?
            }
        };

        let sky_color = match &raw.sky {
            None => [0.55, 0.70, 0.95],
            Some(s) => {
                let c = s.get_ref().color;
                if !c.iter().all(|v| v.is_finite() && *v >= 0.0) {
                    return Err(invalid(
                        Some(line(s.span())),
                        format!("sky color {c:?} must be ≥ 0"),
                    ));
                }
                c
            }
        };

        let camera = match &raw.camera {
            None => CameraDesc {
                position: None,
                look_at: None,
                fov_deg: 45.0,
                width: 640,
                height: 360,
                rays_per_pixel: 1,
            },
            Some(c) => {
                let l = line(c.span());
                let c = c.get_ref();
                let fov = c.fov.unwrap_or(45.0);
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(invalid(
                        Some(l),
                        format!("camera fov {fov} must be in (0, 180) degrees"),
                    ));
                }
                let [w, h] = c.resolution.unwrap_or([640, 360]);
                let edge = limits::IMAGE_EDGE;
                if !edge.contains(&w) || !edge.contains(&h) {
                    return Err(invalid(
                        Some(l),
                        format!(
                            "camera resolution {w}×{h} must be {} per side",
                            limits::describe(&edge)
                        ),
                    ));
                }
                let rpp = c.rays_per_pixel.unwrap_or(1);
                if !limits::RAYS_PER_PIXEL.contains(&rpp) {
                    return Err(invalid(
                        Some(l),
                        format!(
                            "rays_per_pixel {rpp} must be {}",
                            limits::describe(&limits::RAYS_PER_PIXEL)
                        ),
                    ));
                }
                if c.position.is_some() != c.look_at.is_some() {
                    return Err(invalid(
                        Some(l),
                        "camera needs both 'position' and 'look_at' (or neither)".into(),
                    ));
                }
                if let (Some(p), Some(t)) = (c.position, c.look_at) {
                    if !finite3(p) || !finite3(t) || p == t {
                        return Err(invalid(
                            Some(l),
                            "camera position and look_at must be finite and differ".into(),
                        ));
                    }
                }
                CameraDesc {
                    position: c.position.map(Vec3::from_array),
                    look_at: c.look_at.map(Vec3::from_array),
                    fov_deg: fov,
                    width: w,
                    height: h,
                    rays_per_pixel: rpp,
                }
            }
        };

        let bands = match &raw.bands {
            None => None,
            Some(b) => {
                let l = line(b.span());
                let b = b.get_ref();
                let n = b.names.len();
                let index = |name: &str| {
                    b.names.iter().position(|x| x == name).ok_or_else(|| {
                        invalid(
                            Some(l),
                            format!("bands: false_colour names '{name}', which is not in names"),
                        )
                    })
                };
                let false_colour = match &b.false_colour {
                    Some([r, g, bl]) => [index(r)?, index(g)?, index(bl)?],
                    // The last three, longest first; fewer bands repeat.
                    None => [0, 1, 2].map(|k| n.saturating_sub(1 + k)),
                };
                let bands = Bands {
                    names: b.names.clone(),
                    leaf_reflectance: b.leaf_reflectance.clone(),
                    leaf_transmittance: b.leaf_transmittance.clone(),
                    bark: b.bark.clone(),
                    soil: b.soil.clone(),
                    sun: b.sun.clone().unwrap_or_else(|| vec![1.0; n]),
                    sky: b.sky.clone(),
                    false_colour,
                };
                bands
                    .validate()
                    .map_err(|e| invalid(Some(l), format!("bands: {e}")))?;
                Some(bands)
            }
        };

        let lb = match &raw.lb {
            None => LbSettings::default(),
            Some(s) => {
                let l = line(s.span());
                let s = s.get_ref();
                let grid = s.grid.unwrap_or(128);
                if !limits::MODEL_GRID.contains(&(grid as usize)) {
                    return Err(invalid(
                        Some(l),
                        format!(
                            "lb grid {grid} must be {}",
                            limits::describe(&limits::MODEL_GRID)
                        ),
                    ));
                }
                let preset = s.preset.clone().unwrap_or_else(|| "leaf".into());
                check_preset(&preset).map_err(|m| invalid(Some(l), format!("lb: {m}")))?;
                LbSettings { grid, preset }
            }
        };

        // An abstract canopy's models and placed instances after the file's own.
        if let Some(st) = &raw.stand {
            let l = line(st.span());
            let name = &st.get_ref().canopy;
            let spec = CanopySpec::find(name, base_dir)
                .map_err(|e| invalid(Some(l), format!("stand: {e}")))?;
            let placed = sylva_grow::stand::placements(&spec)
                .map_err(|e| invalid(Some(l), format!("stand '{name}': {e}")))?;
            let first = models.len();
            let units = sylva_grow::stand::unit_count(&spec);
            let spec = std::sync::Arc::new(spec);
            for unit in 0..units {
                let model_name = if spec.crowns.is_some() {
                    format!("{}-crown-{unit}", spec.name)
                } else {
                    format!("{}-layer", spec.name)
                };
                if models.iter().any(|o| o.name == model_name) {
                    return Err(invalid(
                        Some(l),
                        format!("stand '{name}': model '{model_name}' is defined twice"),
                    ));
                }
                models.push(ModelDesc {
                    name: model_name,
                    source: ModelSource::Stand {
                        spec: spec.clone(),
                        unit,
                    },
                    preset: None,
                    line: l,
                });
            }
            instances.extend(placed.into_iter().map(|i| InstanceDesc {
                model: first + i.model as usize,
                placement: Placement::Explicit {
                    position: i.position,
                    rotation_deg: i.rotation_deg,
                    scale: i.scale,
                },
                line: l,
            }));
        }

        // An empty (or truncated-to-empty) file would render an empty scene without a word. A
        // scene of media alone (the cloud) has something to draw.
        if (models.is_empty() || instances.is_empty()) && media.is_empty() {
            return Err(invalid(
                None,
                format!(
                    "the scene has {} [[models]], {} [[instances]] and no [[media]]: a scene needs at least one model and instance, or a medium (is the file empty or truncated?)",
                    models.len(),
                    instances.len()
                ),
            ));
        }

        Ok(SceneDesc {
            name: raw.name.unwrap_or_else(|| {
                Path::new(origin)
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "scene".into())
            }),
            origin: origin.to_string(),
            models,
            instances,
            media,
            ground,
            sun,
            sky_color,
            bands,
            camera,
            lb,
        })
    }

    /// Grows or imports each unique model (in parallel, results in file order) and places
    /// the instances.
    pub fn build(&self) -> Result<Scene, SceneError> {
        let models: Vec<Model> = self
            .models
            .par_iter()
            .map(|d| {
                let mut model = match &d.source {
                    ModelSource::Shape { shape, color } => shape.build(*color),
                    ModelSource::Species(s) => {
                        s.build_model().map_err(|source| SceneError::Generate {
                            origin: self.origin.clone(),
                            model: d.name.clone(),
                            source,
                        })?
                    }
                    ModelSource::Mesh { path, options } => import::load_mesh_file(path, options)
                        .map_err(|source| SceneError::Import {
                            origin: self.origin.clone(),
                            line: d.line,
                            model: d.name.clone(),
                            source: Box::new(source),
                        })?,
                    ModelSource::Stand { spec, unit } => sylva_grow::stand::unit_model(spec, *unit),
                };
                model.name = d.name.clone();
                Ok(model)
            })
            .collect::<Result<_, SceneError>>()?;
        let media: Vec<Medium> = self
            .media
            .iter()
            .map(|m| m.build(&self.origin))
            .collect::<Result<_, SceneError>>()?;
        let instances = self.place_instances()?;
        let mut scene = Scene {
            name: self.name.clone(),
            origin: self.origin.clone(),
            models,
            model_origins: self
                .models
                .iter()
                .map(|m| match &m.source {
                    ModelSource::Species(s) => ModelOrigin::Species(s.name.clone()),
                    ModelSource::Mesh { path, .. } => ModelOrigin::MeshFile(path.clone()),
                    ModelSource::Shape { shape, .. } => ModelOrigin::Shape(shape.name().into()),
                    ModelSource::Stand { spec, .. } => {
                        ModelOrigin::Shape(format!("stand {}", spec.name))
                    }
                })
                .collect(),
            model_presets: self
                .models
                .iter()
                .map(|m| m.preset.clone().unwrap_or_else(|| self.lb.preset.clone()))
                .collect(),
            instances,
            media,
            ground: self.ground,
            sun: self.sun,
            sky_color: self.sky_color,
            sun_color: None,
            bands: self.bands.clone(),
            camera: Camera {
                position: Vec3::ZERO,
                look_at: Vec3::Z,
                fov_deg: self.camera.fov_deg,
                width: self.camera.width,
                height: self.camera.height,
                rays_per_pixel: self.camera.rays_per_pixel,
            },
            lb: self.lb.clone(),
        };
        let bounds = scene.instance_bounds();
        if scene.ground.size.is_none() {
            // Cover the instances with a margin, centred on the origin.
            let half = if bounds.is_empty() {
                Vec3::splat(10.0)
            } else {
                bounds.min.abs().max(bounds.max.abs())
            };
            scene.ground.size = Some([2.0 * half.x + 20.0, 2.0 * half.z + 20.0]);
        }
        match (self.camera.position, self.camera.look_at) {
            (Some(p), Some(t)) => {
                scene.camera.position = p;
                scene.camera.look_at = t;
            }
            _ => {
                let (p, t) = frame(&bounds, self.camera.fov_deg);
                scene.camera.position = p;
                scene.camera.look_at = t;
            }
        }
        Ok(scene)
    }

    /// Instance transforms only (no geometry); deterministic for the file's seeds.
    pub fn place_instances(&self) -> Result<Vec<Instance>, SceneError> {
        let cell = self
            .instances
            .iter()
            .filter_map(|i| match &i.placement {
                Placement::Scatter(s) => Some(s.min_spacing),
                _ => None,
            })
            .fold(1.0f32, f32::max);
        let mut occupied = Occupancy::new(cell);
        let mut out = Vec::new();
        for inst in &self.instances {
            match &inst.placement {
                Placement::Explicit {
                    position,
                    rotation_deg,
                    scale,
                } => {
                    occupied.insert(position.x, position.z);
                    out.push(Instance {
                        model: inst.model as u32,
                        position: *position,
                        rotation_deg: *rotation_deg,
                        scale: *scale,
                    });
                }
                Placement::Scatter(spec) => {
                    let placed = layout::scatter(spec, &mut occupied).map_err(|source| {
                        SceneError::Layout {
                            origin: self.origin.clone(),
                            line: inst.line,
                            model: self.models[inst.model].name.clone(),
                            source,
                        }
                    })?;
                    out.extend(placed.into_iter().map(|p| Instance {
                        model: inst.model as u32,
                        position: Vec3::new(p.x, 0.0, p.z),
                        rotation_deg: p.rotation_deg,
                        scale: p.scale,
                    }));
                }
            }
        }
        Ok(out)
    }
}

/// A camera looking at `bounds` from the -z side, slightly above, so it fits in `fov_deg`.
fn frame(bounds: &Aabb, fov_deg: f32) -> (Vec3, Vec3) {
    if bounds.is_empty() {
        return (Vec3::new(0.0, 2.0, -10.0), Vec3::new(0.0, 1.0, 0.0));
    }
    let center = (bounds.min + bounds.max) * 0.5;
    let radius = (bounds.size().length() * 0.5).max(0.5);
    let dist = radius / (0.5 * fov_deg.to_radians()).tan().max(1e-3);
    let dir = Vec3::new(0.0, 0.35, -1.0).normalize();
    (center + dir * dist, center)
}

/// A built-in scene or scene file by name, built.
pub fn load(name_or_path: &str) -> Result<Scene, SceneError> {
    SceneDesc::load(name_or_path)?.build()
}

impl SceneStats {
    /// What `sylva scene info` reports about a built scene.
    pub fn of(scene: &Scene) -> SceneStats {
        let b = scene.instance_bounds();
        let (min, max) = if b.is_empty() {
            ([0.0; 3], [0.0; 3])
        } else {
            (b.min.to_array(), b.max.to_array())
        };
        SceneStats {
            name: scene.name.clone(),
            instances: scene.instances.len(),
            unique_triangles: scene.unique_triangles(),
            instanced_triangles: scene.instanced_triangles(),
            bounds_min: min,
            bounds_max: max,
            memory_bytes: scene.memory_bytes(),
            models: scene
                .models
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    let leaf = m
                        .mesh
                        .material_ids
                        .iter()
                        .filter(|&&id| m.materials[id as usize].is_leaf())
                        .count();
                    let species = match scene.model_origins.get(k) {
                        Some(ModelOrigin::Species(name)) => name.clone(),
                        Some(ModelOrigin::MeshFile(p)) => p
                            .file_name()
                            .map(|f| f.to_string_lossy().into_owned())
                            .unwrap_or_default(),
                        Some(ModelOrigin::Shape(name)) => name.clone(),
                        None => String::new(),
                    };
                    ModelStats {
                        name: m.name.clone(),
                        species,
                        instances: scene
                            .instances
                            .iter()
                            .filter(|i| i.model as usize == k)
                            .count(),
                        triangles: m.triangle_count(),
                        leaf_triangles: leaf,
                        wood_triangles: m.triangle_count() - leaf,
                        memory_bytes: m.memory_bytes(),
                        preset: scene.model_preset(k).to_string(),
                    }
                })
                .collect(),
            media: scene
                .media
                .iter()
                .map(|m| {
                    let (mean_density, occupied) = m.occupancy();
                    MediumStats {
                        name: m.name.clone(),
                        preset: m.preset.clone(),
                        grid: m.dims,
                        cell: m.cell(),
                        bounds_min: m.bounds.min.to_array(),
                        bounds_max: m.bounds.max.to_array(),
                        occupied,
                        mean_density,
                        memory_bytes: m.memory_bytes(),
                    }
                })
                .collect(),
        }
    }
}
