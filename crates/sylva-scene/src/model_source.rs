//! Resolving a model named on the command line: a built-in species name, or a model file chosen
//! by its extension (`.xml`: an Arbaro species, grown by the generator; `.obj`, `.gltf`, `.glb`:
//! a mesh read by [`sylva_io::import`]); and picking one model of a scene.

use std::path::Path;

use crate::scene::{ModelDesc, ModelSource, SceneDesc};
use sylva_geom::Model;
use sylva_grow::arbaro::{self, ArbaroError};
use sylva_grow::species::{normalize_name, Species, BUILTIN_NAMES};
use sylva_grow::weber_penn::GenerateError;
use sylva_io::import::{self, ImportError, ImportOptions};

/// Model file extensions [`load_model`] reads, lower case.
pub const MODEL_FILE_EXTENSIONS: &[&str] = &["xml", "obj", "gltf", "glb"];

#[derive(Debug, thiserror::Error)]
pub enum ModelSourceError {
    #[error("'{spec}' is neither a built-in species ({species}) nor a model file (extensions: {extensions})", species = BUILTIN_NAMES.join(", "), extensions = extensions())]
    Unknown { spec: String },
    #[error("{path}: unsupported model file type '.{ext}' (supported: {extensions})", extensions = extensions())]
    UnsupportedFormat { path: String, ext: String },
    #[error(transparent)]
    Arbaro(#[from] ArbaroError),
    #[error(transparent)]
    Import(#[from] Box<ImportError>),
    #[error("{origin}: {source}")]
    Generate {
        origin: String,
        source: GenerateError,
    },
    #[error("{scene}: no model named '{name}' (models: {})", models.join(", "))]
    NoSuchSceneModel {
        scene: String,
        name: String,
        models: Vec<String>,
    },
    #[error("{scene} has {} models ({}): choose one", models.len(), models.join(", "))]
    AmbiguousSceneModel { scene: String, models: Vec<String> },
    #[error("{0} has no models")]
    EmptyScene(String),
}

fn extensions() -> String {
    MODEL_FILE_EXTENSIONS
        .iter()
        .map(|e| format!(".{e}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn grow(species: &Species, origin: &str) -> Result<Model, ModelSourceError> {
    species
        .build_model()
        .map_err(|source| ModelSourceError::Generate {
            origin: origin.to_string(),
            source,
        })
}

/// A model from `spec`: a path with a model file extension, or a built-in species name (any
/// case, spaces or dashes for underscores).
pub fn load_model(spec: &str) -> Result<Model, ModelSourceError> {
    let path = Path::new(spec);
    if let Some(ext) = path.extension() {
        let ext = ext.to_string_lossy().to_ascii_lowercase();
        return match ext.as_str() {
            "xml" => {
                let a = arbaro::load_file(path)?;
                let species = Species::from_params(
                    &normalize_name(&a.name),
                    a.params,
                    a.seed.unwrap_or(0),
                    path.display().to_string(),
                );
                grow(&species, spec)
            }
            "obj" | "gltf" | "glb" => {
                Ok(import::load_mesh_file(path, &ImportOptions::default()).map_err(Box::new)?)
            }
            _ => Err(ModelSourceError::UnsupportedFormat {
                path: spec.to_string(),
                ext,
            }),
        };
    }
    match Species::builtin(spec) {
        Some(s) => grow(&s, &format!("species '{}'", s.name)),
        None => Err(ModelSourceError::Unknown {
            spec: spec.to_string(),
        }),
    }
}

/// The description of model `name` of a scene (the only one when `name` is `None` and the
/// scene has one).
pub fn scene_model_desc<'a>(
    scene: &'a SceneDesc,
    name: Option<&str>,
) -> Result<&'a ModelDesc, ModelSourceError> {
    let names: Vec<String> = scene.models.iter().map(|m| m.name.clone()).collect();
    Ok(match name {
        Some(n) => scene.models.iter().find(|m| m.name == n).ok_or_else(|| {
            ModelSourceError::NoSuchSceneModel {
                scene: scene.origin.clone(),
                name: n.to_string(),
                models: names.clone(),
            }
        })?,
        None => match scene.models.as_slice() {
            [only] => only,
            [] => return Err(ModelSourceError::EmptyScene(scene.origin.clone())),
            _ => {
                return Err(ModelSourceError::AmbiguousSceneModel {
                    scene: scene.origin.clone(),
                    models: names,
                })
            }
        },
    })
}

/// The LB preset of model `name` of a scene: its own or the scene's.
pub fn scene_model_preset(
    scene: &SceneDesc,
    name: Option<&str>,
) -> Result<String, ModelSourceError> {
    let desc = scene_model_desc(scene, name)?;
    Ok(desc
        .preset
        .clone()
        .unwrap_or_else(|| scene.lb.preset.clone()))
}

/// Model `name` of a scene (the only one when `name` is `None` and the scene has one), built
/// and named as the scene names it.
pub fn load_scene_model(scene: &SceneDesc, name: Option<&str>) -> Result<Model, ModelSourceError> {
    let desc = scene_model_desc(scene, name)?;
    let origin = format!("{}: model '{}'", scene.origin, desc.name);
    let mut model = match &desc.source {
        ModelSource::Shape { shape, color } => shape.build(*color),
        ModelSource::Species(s) => grow(s, &origin)?,
        ModelSource::Mesh { path, options } => {
            import::load_mesh_file(path, options).map_err(Box::new)?
        }
        ModelSource::Stand { spec, unit } => sylva_grow::stand::unit_model(spec, *unit),
    };
    model.name = desc.name.clone();
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_specs_list_the_choices() {
        let e = load_model("no_such_tree").unwrap_err().to_string();
        assert!(e.contains("red_maple") && e.contains("dogrose"), "{e}");
        assert!(e.contains(".xml"), "{e}");
        let e = load_model("tree.stl").unwrap_err().to_string();
        assert!(e.contains("tree.stl") && e.contains("'.stl'"), "{e}");
        let e = load_model("missing.xml").unwrap_err().to_string();
        assert!(e.contains("missing.xml"), "{e}");
    }

    #[test]
    fn arbaro_file_and_species_name() {
        let s = Species::builtin("dogrose").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rose.XML");
        std::fs::write(&path, arbaro::to_xml("my rose", &s.params)).unwrap();
        let from_file = load_model(path.to_str().unwrap()).unwrap();
        assert_eq!(from_file.name, "my_rose");
        // Same parameters and seed 0: the same mesh as the species grown with seed 0.
        let mut seeded = s.clone();
        seeded.seed = 0;
        assert_eq!(
            from_file.mesh.geometry_hash(),
            seeded.generate_mesh().unwrap().geometry_hash()
        );
        let by_name = load_model("Dog Rose").unwrap();
        assert_eq!(by_name.name, "dogrose");
        assert_eq!(
            by_name.mesh.geometry_hash(),
            s.generate_mesh().unwrap().geometry_hash()
        );
    }

    #[test]
    fn scene_models_by_name() {
        let demo = SceneDesc::load("demo").unwrap();
        let rose = load_scene_model(&demo, Some("rose")).unwrap();
        assert_eq!(rose.name, "rose");
        let e = load_scene_model(&demo, None).unwrap_err().to_string();
        assert!(e.contains("maple, pine, rose"), "{e}");
        let e = load_scene_model(&demo, Some("oak"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("'oak'") && e.contains("maple"), "{e}");
    }
}
