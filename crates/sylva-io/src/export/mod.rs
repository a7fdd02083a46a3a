//! Scene export, so that sylva's images can be checked against an independent path tracer.
//!
//! * [`obj`]: the flattened scene (every instance transformed to world space) as one Wavefront
//!   OBJ with its MTL and PNG textures, plus the ground as a quad. Streamed: the text of the
//!   whole scene is never held in memory.
//! * [`mitsuba`]: a Mitsuba 3 scene (`scene.xml`) that keeps the instancing: each unique model
//!   once as binary PLY files (one per material, since a Mitsuba shape has one BSDF) inside a
//!   `shapegroup`, one `instance` per plant; sun, sky, ground, camera and integrator alike.
//!
//! An export's files form one [`sylva_core::OutputSet`]: all of them are checked (not an
//! input, not a directory, a writable directory) before any is written, and they replace the
//! old ones together at the end or not at all (an error or Ctrl-C leaves every file as it
//! was). File and XML names come from model names made safe by [`file_stems`].

pub mod mitsuba;
pub mod obj;

use std::collections::HashMap;
use std::fmt;
use std::io;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;
use sylva_geom::{Model, Texture};

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
    #[error("{}: exists and is not a directory", .0.display())]
    NotADirectory(PathBuf),
    #[error("{}: cannot encode the image: {message}", path.display())]
    Png { path: PathBuf, message: String },
    #[error("model '{model}': {message}")]
    InvalidModel { model: String, message: String },
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("unknown export format '{0}' (formats: obj, mitsuba)")]
    UnknownFormat(String),
    #[error("invalid export option: {0}")]
    Option(String),
    #[error(
        "{}: the export needs about {} but only {} is free there",
        dir.display(),
        sylva_core::format_bytes(*.needed),
        sylva_core::format_bytes(*.available)
    )]
    DiskSpace {
        dir: PathBuf,
        needed: u64,
        available: u64,
    },
    #[error("export cancelled")]
    Cancelled,
    #[error(transparent)]
    Output(#[from] sylva_core::OutputError),
}

impl ExportError {
    pub(crate) fn io(path: &Path, source: io::Error) -> ExportError {
        ExportError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// What `sylva export --format` takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Obj,
    Mitsuba,
}

impl Format {
    pub const ALL: [Format; 2] = [Format::Obj, Format::Mitsuba];

    pub fn name(self) -> &'static str {
        match self {
            Format::Obj => "obj",
            Format::Mitsuba => "mitsuba",
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Format {
    type Err = ExportError;
    fn from_str(s: &str) -> Result<Format, ExportError> {
        Format::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| ExportError::UnknownFormat(s.to_string()))
    }
}

/// What an export wrote.
#[derive(Debug, Clone, Default)]
pub struct Exported {
    /// Every file written, relative to the output directory, in the order written.
    pub files: Vec<PathBuf>,
    /// Their total size.
    pub bytes: u64,
    /// Triangles in the exported scene: instanced triangles plus the ground's two.
    pub triangles: u64,
}

impl Exported {
    /// What `sylva export` says of this export of `format` into `dir`, `seconds` long: the
    /// files, bytes and triangles, then the main file (with Mitsuba, how to render it).
    pub fn summary(&self, format: Format, dir: &Path, seconds: f64) -> String {
        let next = match format {
            Format::Obj => format!("  {}", dir.join(obj::OBJ_FILE).display()),
            Format::Mitsuba => format!(
                "  render: mitsuba -m scalar_rgb -o render.exr {}   (pip install mitsuba; see docs/export.md)",
                dir.join(mitsuba::XML_FILE).display()
            ),
        };
        format!(
            "wrote {} files, {}, {} triangles, to {} in {seconds:.1} s\n{next}",
            self.files.len(),
            sylva_core::format_bytes(self.bytes),
            sylva_core::thousands(self.triangles),
            dir.display(),
        )
    }

    /// Plans `files` (relative to `dir`) in a new output set: every one is checked before
    /// the first is written.
    fn plan(dir: &Path, files: &[PathBuf]) -> Result<sylva_core::OutputSet, ExportError> {
        let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
        set.plan(&files.iter().map(|f| dir.join(f)).collect::<Vec<_>>())?;
        Ok(set)
    }

    /// Renames the files of `set` into place and records them with their sizes.
    fn commit(&mut self, dir: &Path, set: sylva_core::OutputSet) -> Result<(), ExportError> {
        for path in set.commit()? {
            let len = std::fs::metadata(&path)
                .map_err(|e| ExportError::io(&path, e))?
                .len();
            self.bytes += len;
            self.files
                .push(path.strip_prefix(dir).unwrap_or(&path).to_path_buf());
        }
        Ok(())
    }
}

/// Creates `dir` (and its parents) or checks that it is a directory.
pub fn prepare_dir(dir: &Path) -> Result<(), ExportError> {
    if dir.exists() && !dir.is_dir() {
        return Err(ExportError::NotADirectory(dir.to_path_buf()));
    }
    std::fs::create_dir_all(dir).map_err(|e| ExportError::io(dir, e))
}

/// Bytes free to this user on the file system holding `dir`; `None` where unknown.
pub fn available_disk_bytes(dir: &Path) -> Option<u64> {
    fs4::available_space(dir).ok()
}

/// Refuses a write of about `needed` bytes into `dir` when the disk has less free (with a
/// 1 % margin); unknown free space lets it through.
pub fn check_disk_space(
    dir: &Path,
    needed: u64,
    available: Option<u64>,
) -> Result<(), ExportError> {
    match available {
        Some(available) if needed + needed / 100 > available => Err(ExportError::DiskSpace {
            dir: dir.to_path_buf(),
            needed,
            available,
        }),
        _ => Ok(()),
    }
}

/// Writes `path` into `set` (a temporary until the set is committed), streaming through
/// `fill`; errors name the file.
pub(crate) fn write_file<F>(
    set: &mut sylva_core::OutputSet,
    path: &Path,
    fill: F,
) -> Result<(), ExportError>
where
    F: FnOnce(&mut dyn io::Write) -> io::Result<()>,
{
    Ok(set.write(path, fill)?)
}

/// `name` made safe as a file name and an XML id: ASCII letters, digits, `_` and `-` are
/// kept, every other character becomes `_`; an empty result becomes `unnamed`.
pub fn safe_name(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "unnamed".into()
    } else {
        s
    }
}

/// Safe, pairwise distinct stems for `names` (a later duplicate gets `_2`, `_3`, ...).
pub fn file_stems<S: AsRef<str>>(names: &[S]) -> Vec<String> {
    let mut used = std::collections::HashSet::new();
    names
        .iter()
        .map(|n| {
            let base = safe_name(n.as_ref());
            let mut stem = base.clone();
            let mut k = 1;
            while used.contains(&stem) {
                k += 1;
                stem = format!("{base}_{k}");
            }
            used.insert(stem.clone());
            stem
        })
        .collect()
}

/// Stems of every material of every model: `{model}_{kind}` (`maple_leaf`, `maple_wood`),
/// distinct over the scene. Index `[model][material]`.
pub fn material_stems(models: &[Model]) -> Vec<Vec<String>> {
    let model_stems = file_stems(&models.iter().map(|m| &m.name).collect::<Vec<_>>());
    let flat: Vec<String> = models
        .iter()
        .zip(&model_stems)
        .flat_map(|(m, stem)| {
            m.materials.iter().map(move |mat| {
                let kind = mat.kind.name();
                format!("{stem}_{kind}")
            })
        })
        .collect();
    let mut stems = file_stems(&flat).into_iter();
    models
        .iter()
        .map(|m| m.materials.iter().map(|_| stems.next().unwrap()).collect())
        .collect()
}

/// Whether any texel of `t` is less than fully opaque: such a texture cuts its surface's shape.
pub fn has_transparency(t: &Texture) -> bool {
    t.pixels.iter().any(|p| p[3] < 255)
}

/// How a texture's pixels go into a PNG.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PngChannels {
    /// RGBA as stored (sRGB colour, linear alpha).
    Rgba,
    /// RGB only (sRGB).
    Rgb,
    /// The alpha channel alone, as 8-bit grey (linear coverage).
    Alpha,
}

/// Writes `t`'s colour decoded to linear RGB (the renderer's decoding,
/// [`sylva_core::colour::srgb_to_linear`]) times `factor` per colour, as a 32-bit float
/// OpenEXR (row 0 at the top): a texture whose values can exceed 1.
pub(crate) fn write_scaled_exr(
    set: &mut sylva_core::OutputSet,
    path: &Path,
    t: &Texture,
    factor: [f32; 3],
) -> Result<(), ExportError> {
    let lut: Vec<f32> = (0..256)
        .map(|i| sylva_core::colour::srgb_to_linear(i as f32 / 255.0))
        .collect();
    let values: Vec<f32> = t
        .pixels
        .iter()
        .flat_map(|p| [0, 1, 2].map(|c| lut[p[c] as usize] * factor[c]))
        .collect();
    let img =
        image::Rgb32FImage::from_raw(t.width, t.height, values).expect("width × height × 3 values");
    let mut bytes = io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::OpenExr)
        .map_err(|e| ExportError::Png {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    write_file(set, path, |w| w.write_all(bytes.get_ref()))
}

/// Writes `t` as a PNG (row 0 of the texture, v = 0, is the image's top row).
pub(crate) fn write_png(
    set: &mut sylva_core::OutputSet,
    path: &Path,
    t: &Texture,
    channels: PngChannels,
) -> Result<(), ExportError> {
    use image::ImageEncoder;
    let (bytes, colour): (Vec<u8>, image::ExtendedColorType) = match channels {
        PngChannels::Rgba => (
            t.pixels.iter().flatten().copied().collect(),
            image::ExtendedColorType::Rgba8,
        ),
        PngChannels::Rgb => (
            t.pixels.iter().flat_map(|p| [p[0], p[1], p[2]]).collect(),
            image::ExtendedColorType::Rgb8,
        ),
        PngChannels::Alpha => (
            t.pixels.iter().map(|p| p[3]).collect(),
            image::ExtendedColorType::L8,
        ),
    };
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&bytes, t.width, t.height, colour)
        .map_err(|e| ExportError::Png {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    write_file(set, path, |w| w.write_all(&png))
}

/// One file per distinct texture (by identity: materials sharing an `Arc` share the file).
pub(crate) struct TextureFiles {
    names: HashMap<*const Texture, String>,
}

impl TextureFiles {
    /// Names textures after the first material (in model order) that uses them.
    pub(crate) fn new(models: &[Model], stems: &[Vec<String>]) -> TextureFiles {
        let mut names = HashMap::new();
        for (m, model) in models.iter().enumerate() {
            for (k, mat) in model.materials.iter().enumerate() {
                if let Some(t) = &mat.texture {
                    names
                        .entry(Arc::as_ptr(t))
                        .or_insert_with(|| stems[m][k].clone());
                }
            }
        }
        TextureFiles { names }
    }

    /// The stem of texture `t`'s files.
    pub(crate) fn stem(&self, t: &Arc<Texture>) -> &str {
        &self.names[&Arc::as_ptr(t)]
    }

    /// Distinct textures with their stems, in model then material order.
    pub(crate) fn unique<'a>(&self, models: &'a [Model]) -> Vec<(&'a Arc<Texture>, String)> {
        let mut done = std::collections::HashSet::new();
        let mut out = Vec::new();
        for model in models {
            for mat in &model.materials {
                if let Some(t) = &mat.texture {
                    if done.insert(Arc::as_ptr(t)) {
                        out.push((t, self.stem(t).to_string()));
                    }
                }
            }
        }
        out
    }
}

/// Checks the mesh of every model before anything is written, so a defect is reported by
/// model name instead of surfacing as an index panic or a corrupt file.
pub(crate) fn validate_models(models: &[Model]) -> Result<(), ExportError> {
    for m in models {
        m.mesh
            .validate(m.materials.len())
            .map_err(|message| ExportError::InvalidModel {
                model: m.name.clone(),
                message,
            })?;
    }
    Ok(())
}

/// Triangle indices of `model` grouped by material: `[material] -> triangles`.
pub(crate) fn triangles_by_material(model: &Model) -> Vec<Vec<u32>> {
    let mut out = vec![Vec::new(); model.materials.len()];
    for (t, &m) in model.mesh.material_ids.iter().enumerate() {
        out[m as usize].push(t as u32);
    }
    out
}

/// The ground's four corners on y = 0, counter-clockwise seen from above (normal +y), with
/// their texture coordinates; `None` when the scene has no ground.
pub(crate) fn ground_quad(scene: &sylva_geom::Scene) -> Option<[([f32; 3], [f32; 2]); 4]> {
    if !scene.ground.enabled {
        return None;
    }
    let [sx, sz] = scene.ground.size?;
    let (hx, hz) = (0.5 * sx, 0.5 * sz);
    Some([
        ([-hx, 0.0, -hz], [0.0, 0.0]),
        ([-hx, 0.0, hz], [0.0, 1.0]),
        ([hx, 0.0, hz], [1.0, 1.0]),
        ([hx, 0.0, -hz], [1.0, 0.0]),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stems_are_safe_and_distinct() {
        assert_eq!(safe_name("Red Maple/1"), "Red_Maple_1");
        assert_eq!(safe_name(""), "unnamed");
        let s = file_stems(&["a b", "a_b", "a b", "c"]);
        assert_eq!(s, ["a_b", "a_b_2", "a_b_3", "c"]);
        let unique: std::collections::HashSet<_> = s.iter().collect();
        assert_eq!(unique.len(), s.len());
    }

    #[test]
    fn format_names_parse() {
        assert_eq!("OBJ".parse::<Format>().unwrap(), Format::Obj);
        assert_eq!("mitsuba".parse::<Format>().unwrap(), Format::Mitsuba);
        let e = "gltf".parse::<Format>().unwrap_err().to_string();
        assert!(e.contains("gltf") && e.contains("obj, mitsuba"), "{e}");
    }

    #[test]
    fn disk_space_check() {
        let d = Path::new("/out");
        assert!(check_disk_space(d, 1000, Some(2000)).is_ok());
        assert!(check_disk_space(d, 1000, None).is_ok());
        let e = check_disk_space(d, 3 << 30, Some(1 << 30))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/out") && e.contains("3.0 GiB") && e.contains("1.0 GiB"),
            "{e}"
        );
        // The margin: exactly the free space is not enough.
        assert!(check_disk_space(d, 1000, Some(1000)).is_err());
        let free = available_disk_bytes(&std::env::temp_dir());
        assert!(free.is_some_and(|b| b > 0) || cfg!(not(unix)));
    }

    #[test]
    fn a_file_is_not_an_output_directory() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f");
        std::fs::write(&file, b"x").unwrap();
        let e = prepare_dir(&file).unwrap_err();
        assert!(matches!(e, ExportError::NotADirectory(_)), "{e}");
        assert!(prepare_dir(&dir.path().join("a/b")).is_ok());
        assert!(dir.path().join("a/b").is_dir());
    }
}
