//! Mesh import: users' own plant models from Wavefront OBJ (+ MTL) and glTF 2.0 (`.gltf`,
//! `.glb`) files, turned into a [`Model`] with leaf and wood materials like the built-in
//! species, so the voxelizer, the LB solver and the renderer treat them alike.
//!
//! This module owns what the formats have in common: [`ImportOptions`], [`ImportError`],
//! the leaf/wood decision (alpha mask or diffuse transmission → leaf, overridden by
//! material-name patterns), texture decoding and baking (colour factors multiplied in,
//! alpha remapped so that the cutoff falls on [`sylva_geom::is_opaque`]), normals where the
//! file has none, and the final checks. [`obj`] and [`gltf`] read their formats into the
//! shared intermediate form.

mod gltf;
mod obj;

use glam::Vec3;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use sylva_core::colour::{linear_to_srgb8, srgb_to_linear};
use sylva_geom::{Material, MaterialKind, Mesh, Model, Optics, Texture, Wrap, OPAQUE_ALPHA};

/// Sylva models hold at most this many materials (material ids are `u8`).
pub const MAX_MATERIALS: usize = 256;

/// The file extensions [`load_mesh_file`] reads.
pub const EXTENSIONS: &[&str] = &["obj", "gltf", "glb"];

/// Which axis of the file points up; sylva's world is +y up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum UpAxis {
    /// The file is +y up (glTF always is; most OBJ exporters too).
    #[default]
    Y,
    /// The file is +z up (3ds Max, some CAD and plant tools): (x, y, z) → (x, z, −y).
    Z,
}

/// How [`load_mesh_file`] reads a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    /// Material names that are leaves whatever their alpha: patterns with `*` (any run of
    /// characters) and `?` (one character), compared without regard to case (`*leaf*`).
    pub leaf_materials: Vec<String>,
    /// Material names that are wood whatever their alpha (same pattern syntax).
    pub wood_materials: Vec<String>,
    /// Uniform scale applied to positions (0.01 for a model in centimetres). Must be > 0.
    pub scale: f32,
    /// The file's up axis.
    pub up: UpAxis,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            leaf_materials: Vec::new(),
            wood_materials: Vec::new(),
            scale: 1.0,
            up: UpAxis::Y,
        }
    }
}

/// A file that cannot be imported: which file, where in it (`line 17`, `materials[2]`,
/// `meshes[0].primitives[1]`) and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {}{message}", file.display(), element.as_deref().map(|e| format!("{e}: ")).unwrap_or_default())]
pub struct ImportError {
    /// The file the problem is in (an MTL file for a bad material, not the OBJ).
    pub file: PathBuf,
    /// The line or element, where the problem has one.
    pub element: Option<String>,
    pub message: String,
}

impl ImportError {
    pub(crate) fn new(file: &Path, element: Option<String>, message: impl Into<String>) -> Self {
        ImportError {
            file: file.to_path_buf(),
            element,
            message: message.into(),
        }
    }

    pub(crate) fn at(file: &Path, element: impl Into<String>, message: impl Into<String>) -> Self {
        ImportError::new(file, Some(element.into()), message)
    }

    pub(crate) fn whole(file: &Path, message: impl Into<String>) -> Self {
        ImportError::new(file, None, message)
    }
}

/// Reads an OBJ, glTF or GLB file (by extension, any case) into a [`Model`] named after the
/// file. Materials with an alpha mask or diffuse transmission become two-sided leaves, the
/// others wood, unless `opts` names them; see `docs/scenes.md` ("Importing meshes").
pub fn load_mesh_file(path: &Path, opts: &ImportOptions) -> Result<Model, ImportError> {
    if !(opts.scale.is_finite() && opts.scale > 0.0) {
        return Err(ImportError::whole(
            path,
            format!("scale must be a positive number, got {}", opts.scale),
        ));
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let raw = match ext.as_str() {
        "obj" => obj::load(path)?,
        "gltf" | "glb" => gltf::load(path)?,
        _ => {
            return Err(ImportError::whole(
                path,
                format!(
                    "unknown mesh format '.{ext}' (readable: {})",
                    EXTENSIONS
                        .iter()
                        .map(|e| format!(".{e}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ))
        }
    };
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "mesh".into());
    raw.finish(path, name, opts)
}

/// True for the file names [`load_mesh_file`] reads.
pub fn is_mesh_file(path: &Path) -> bool {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .is_some_and(|e| EXTENSIONS.contains(&e.as_str()))
}

// ---------- the formats' common intermediate ----------

/// A material as a format reader found it, before the leaf/wood decision.
#[derive(Debug, Clone)]
pub(crate) struct RawMaterial {
    pub name: String,
    /// Colour without texture, linear RGB.
    pub color: [f32; 3],
    /// Already baked: factors multiplied in, alpha ≥ 128 where opaque.
    pub texture: Option<Texture>,
    /// The material cuts its shape out of the surface by alpha.
    pub alpha_mask: bool,
    /// The material lets light through diffusely (glTF diffuse transmission).
    pub translucent: bool,
    /// glTF `KHR_materials_diffuse_transmission`: its factor (the share of the diffuse light
    /// transmitted) and colour factor, where the file gives a factor above 0.
    pub diffuse_transmission: Option<(f32, [f32; 3])>,
    pub double_sided: bool,
}

impl RawMaterial {
    /// An untextured, opaque, one-sided material.
    pub fn plain(name: impl Into<String>, color: [f32; 3]) -> RawMaterial {
        RawMaterial {
            name: name.into(),
            color,
            texture: None,
            alpha_mask: false,
            translucent: false,
            diffuse_transmission: None,
            double_sided: false,
        }
    }
}

/// Triangles with per-triangle material indices into `materials` (which may hold more
/// than 256 entries or unused ones until [`RawModel::finish`]). A zero normal means "none
/// in the file": it is computed.
#[derive(Debug, Default)]
pub(crate) struct RawModel {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    pub material_of: Vec<u32>,
    pub materials: Vec<RawMaterial>,
}

impl RawModel {
    /// Leaf/wood decision, material compaction, orientation and scale, missing normals, and
    /// the final invariants.
    fn finish(self, file: &Path, name: String, opts: &ImportOptions) -> Result<Model, ImportError> {
        let RawModel {
            mut positions,
            mut normals,
            uvs,
            triangles,
            material_of,
            materials,
        } = self;
        if triangles.is_empty() {
            return Err(ImportError::whole(
                file,
                "the mesh is empty: it has no triangles",
            ));
        }
        debug_assert_eq!(positions.len(), normals.len());
        debug_assert_eq!(positions.len(), uvs.len());
        debug_assert_eq!(triangles.len(), material_of.len());

        // Materials in file order, only those some triangle uses.
        let mut used = vec![false; materials.len()];
        for &m in &material_of {
            used[m as usize] = true;
        }
        let used_count = used.iter().filter(|&&u| u).count();
        if used_count > MAX_MATERIALS {
            return Err(ImportError::whole(
                file,
                format!(
                    "{used_count} materials are used; a sylva model holds at most {MAX_MATERIALS}"
                ),
            ));
        }
        let mut remap = vec![u8::MAX; materials.len()];
        let mut out_materials = Vec::with_capacity(used_count);
        let mut leaf_hits = vec![false; opts.leaf_materials.len()];
        let mut wood_hits = vec![false; opts.wood_materials.len()];
        for (k, m) in materials.into_iter().enumerate() {
            if !used[k] {
                continue;
            }
            let leaf_pat = first_match(&opts.leaf_materials, &m.name);
            let wood_pat = first_match(&opts.wood_materials, &m.name);
            if let (Some(l), Some(w)) = (leaf_pat, wood_pat) {
                return Err(ImportError::whole(
                    file,
                    format!(
                        "material '{}' matches leaf pattern '{}' and wood pattern '{}'",
                        m.name, opts.leaf_materials[l], opts.wood_materials[w]
                    ),
                ));
            }
            if let Some(l) = leaf_pat {
                leaf_hits[l] = true;
            }
            if let Some(w) = wood_pat {
                wood_hits[w] = true;
            }
            let leaf = match (leaf_pat, wood_pat) {
                (Some(_), _) => true,
                (_, Some(_)) => false,
                _ => m.alpha_mask || m.translucent,
            };
            remap[k] = out_materials.len() as u8;
            out_materials.push(m.into_material(leaf));
        }
        let names = || {
            out_materials
                .iter()
                .map(|m: &Material| format!("'{}'", m.name))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for (list, hits, what) in [
            (&opts.leaf_materials, &leaf_hits, "leaf"),
            (&opts.wood_materials, &wood_hits, "wood"),
        ] {
            if let Some(k) = hits.iter().position(|h| !h) {
                return Err(ImportError::whole(
                    file,
                    format!(
                        "{what} material pattern '{}' matches no material (materials: {})",
                        list[k],
                        names()
                    ),
                ));
            }
        }

        // Orientation, then scale (uniform and positive, so normals only rotate).
        if opts.up == UpAxis::Z {
            let rot = |v: Vec3| Vec3::new(v.x, v.z, -v.y);
            positions.iter_mut().for_each(|p| *p = rot(*p));
            normals.iter_mut().for_each(|n| *n = rot(*n));
        }
        if opts.scale != 1.0 {
            positions.iter_mut().for_each(|p| *p *= opts.scale);
        }
        if let Some(k) = positions.iter().position(|p| !p.is_finite()) {
            return Err(ImportError::whole(
                file,
                format!("vertex {k} is not finite after transforms and scale"),
            ));
        }
        fill_missing_normals(&positions, &mut normals, &triangles);

        let mesh = Mesh {
            positions: positions.iter().map(|p| p.to_array()).collect(),
            normals: normals.iter().map(|n| n.to_array()).collect(),
            uvs,
            indices: triangles,
            material_ids: material_of.iter().map(|&m| remap[m as usize]).collect(),
        };
        mesh.validate(out_materials.len())
            .map_err(|e| ImportError::whole(file, format!("invalid mesh: {e}")))?;
        Ok(Model::new(name, mesh, out_materials))
    }
}

impl RawMaterial {
    fn into_material(self, leaf: bool) -> Material {
        let base_color = match &self.texture {
            Some(t) => t.mean_opaque_linear(),
            None => self.color,
        };
        Material {
            name: self.name,
            kind: if leaf {
                MaterialKind::Leaf
            } else {
                MaterialKind::Wood
            },
            base_color,
            texture: self.texture.map(Arc::new),
            // Leaves are thin sheets seen from both sides, whatever the file says.
            two_sided: leaf || self.double_sided,
            optics: optics(leaf, self.diffuse_transmission),
        }
    }
}

/// A material's reflectance and transmittance factors (docs/scenes.md, "Importing meshes"):
/// wood is opaque; a glTF leaf with diffuse transmission factor `f` and colour factor `t`
/// reflects `(1 - f)` of its colour and transmits `f · t` of it (the extension's mix of a
/// diffuse BRDF and BTDF, with the transmitted colour taken as the base colour tinted by
/// `t`); other leaves reflect their colour and transmit Knapp & Carter's forest-leaf ratios
/// of it ([`Optics::FOREST_LEAF`]).
fn optics(leaf: bool, diffuse_transmission: Option<(f32, [f32; 3])>) -> Optics {
    match (leaf, diffuse_transmission) {
        (false, _) => Optics::OPAQUE,
        (true, Some((f, t))) => Optics {
            reflect: [1.0 - f; 3],
            transmit: t.map(|t| f * t),
            measured: None,
        },
        (true, None) => Optics::FOREST_LEAF,
    }
}

/// Area-weighted vertex normals for vertices whose normal is zero or not finite (none in
/// the file); others are normalised. A vertex on degenerate triangles only gets +y.
fn fill_missing_normals(positions: &[Vec3], normals: &mut [Vec3], triangles: &[[u32; 3]]) {
    let missing = |n: &Vec3| !n.is_finite() || n.length_squared() < 1e-20;
    if !normals.iter().any(missing) {
        normals.iter_mut().for_each(|n| *n = n.normalize());
        return;
    }
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        // The cross product's length is twice the area: larger faces weigh more.
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    for (n, a) in normals.iter_mut().zip(acc) {
        *n = if missing(n) {
            a.try_normalize().unwrap_or(Vec3::Y)
        } else {
            n.normalize()
        };
    }
}

/// Index of the first pattern in `patterns` matching `name`.
fn first_match(patterns: &[String], name: &str) -> Option<usize> {
    patterns.iter().position(|p| glob_match(p, name))
}

/// `*` matches any run of characters, `?` one character; case-insensitive.
pub fn glob_match(pattern: &str, name: &str) -> bool {
    let p: Vec<char> = pattern.chars().flat_map(char::to_lowercase).collect();
    let s: Vec<char> = name.chars().flat_map(char::to_lowercase).collect();
    // Greedy matching with backtracking to the last star: linear in practice.
    let (mut pi, mut si) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while si < s.len() {
        if pi < p.len() && (p[pi] == '?' || p[pi] == s[si]) {
            pi += 1;
            si += 1;
        } else if pi < p.len() && p[pi] == '*' {
            star = Some((pi, si));
            pi += 1;
        } else if let Some((sp, ss)) = star {
            pi = sp + 1;
            si = ss + 1;
            star = Some((sp, ss + 1));
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

// ---------- textures ----------

/// Decodes an image (PNG, JPEG, GIF, EXR) to RGBA8, checking memory for its pixels first.
/// `what` names the image in errors (`line 4: map_Kd 'leaf.png'`, `images[0]`).
pub(crate) fn decode_image(
    bytes: &[u8],
    file: &Path,
    what: &str,
) -> Result<image::RgbaImage, ImportError> {
    let (img, _) = decode_image_with_alpha(bytes, file, what)?;
    Ok(img)
}

/// As [`decode_image`], also telling whether the image has an alpha channel.
pub(crate) fn decode_image_with_alpha(
    bytes: &[u8],
    file: &Path,
    what: &str,
) -> Result<(image::RgbaImage, bool), ImportError> {
    let bad = |e: &dyn std::fmt::Display| {
        ImportError::at(file, what, format!("cannot decode image: {e}"))
    };
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| bad(&e))
    };
    let (w, h) = reader()?.into_dimensions().map_err(|e| bad(&e))?;
    if w == 0 || h == 0 {
        return Err(ImportError::at(
            file,
            what,
            format!("image is empty ({w}×{h})"),
        ));
    }
    sylva_core::check_memory(
        &format!("texture {what} ({w}×{h})"),
        w as u64 * h as u64 * 8,
    )
    .map_err(|e| ImportError::at(file, what, e.to_string()))?;
    let img = reader()?.decode().map_err(|e| bad(&e))?;
    let has_alpha = img.color().has_alpha();
    Ok((img.to_rgba8(), has_alpha))
}

/// An RGBA8 image as a [`Texture`] (row 0 at v = 0).
pub(crate) fn to_texture(img: &image::RgbaImage, wrap: Wrap) -> Texture {
    let pixels = img.pixels().map(|p| p.0).collect();
    Texture::new(img.width(), img.height(), pixels, wrap)
}

/// Multiplies the texels' colour by a linear `factor` (a glTF `baseColorFactor`, an MTL
/// `Kd`), in linear space; a factor of one leaves the bytes as they are.
pub(crate) fn tint(pixels: &mut [[u8; 4]], factor: [f32; 3]) {
    if factor == [1.0; 3] {
        return;
    }
    let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
    for p in pixels {
        for c in 0..3 {
            p[c] = linear_to_srgb8(lut[p[c] as usize] * factor[c]);
        }
    }
}

/// Maps coverage `a` ∈ [0, 1] to a byte so that `a >= cutoff` ⇔ the byte is opaque
/// ([`sylva_geom::is_opaque`]: byte ≥ [`OPAQUE_ALPHA`]), keeping the ramp monotonic so
/// filtering still sees edges.
pub(crate) fn remap_alpha(a: f32, cutoff: f32) -> u8 {
    // The bytes above and below the rule's threshold: 127 steps each way.
    const ABOVE: f32 = (u8::MAX - OPAQUE_ALPHA) as f32;
    const BELOW: f32 = (OPAQUE_ALPHA - 1) as f32;
    let a = a.clamp(0.0, 1.0);
    if a >= cutoff {
        let t = if cutoff < 1.0 {
            (a - cutoff) / (1.0 - cutoff)
        } else {
            1.0
        };
        OPAQUE_ALPHA + (ABOVE * t).round().clamp(0.0, ABOVE) as u8
    } else {
        // a < cutoff implies cutoff > 0.
        (BELOW * a / cutoff).floor().clamp(0.0, BELOW) as u8
    }
}

/// Reads a file the model refers to (an MTL file, a texture, a glTF buffer) through the
/// bounded reader, at most `limit` bytes; `what` names the reference in errors.
pub(crate) fn read_referenced(
    path: &Path,
    file: &Path,
    what: &str,
    limit: u64,
) -> Result<Vec<u8>, ImportError> {
    sylva_core::read_file(path, limit, "referenced files").map_err(|e| {
        let message = match e {
            sylva_core::InputError::Io { path, source } => {
                format!("cannot read {}: {source}", path.display())
            }
            e => e.to_string(),
        };
        ImportError::at(file, what, message)
    })
}

/// Reads a model file itself (OBJ, glTF, GLB) through the bounded reader.
pub(crate) fn read_model_file(path: &Path) -> Result<Vec<u8>, ImportError> {
    sylva_core::read_file(path, sylva_core::limits::MODEL_FILE_BYTES, "model files")
        .map_err(|e| ImportError::whole(path, e.problem()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glob_patterns() {
        assert!(glob_match("*leaf*", "Oak_Leaf_01"));
        assert!(glob_match("*LEAF*", "leaf"));
        assert!(!glob_match("*leaf*", "bark"));
        assert!(glob_match("bark?", "Bark2"));
        assert!(!glob_match("bark?", "bark"));
        assert!(glob_match("*", ""));
        assert!(glob_match("a*b*c", "axxbyyc"));
        assert!(!glob_match("a*b*c", "axxbyy"));
        assert!(glob_match("twig", "TWIG"));
    }

    #[test]
    fn alpha_remap_keeps_the_cutoff_at_half() {
        for cutoff in [0.0f32, 0.1, 0.3, 0.5, 0.77, 1.0] {
            for byte in 0..=255u8 {
                let a = byte as f32 / 255.0;
                let out = remap_alpha(a, cutoff);
                assert_eq!(
                    sylva_geom::is_opaque([0, 0, 0, out]),
                    a >= cutoff,
                    "a {a} cutoff {cutoff} -> {out}"
                );
            }
            // Monotonic.
            let outs: Vec<u8> = (0..=255)
                .map(|b| remap_alpha(b as f32 / 255.0, cutoff))
                .collect();
            assert!(outs.windows(2).all(|w| w[0] <= w[1]), "cutoff {cutoff}");
        }
    }

    #[test]
    fn tint_multiplies_in_linear_space() {
        let mut px = vec![[200u8, 100, 50, 7]];
        tint(&mut px, [1.0, 1.0, 1.0]);
        assert_eq!(px[0], [200, 100, 50, 7]);
        tint(&mut px, [0.5, 1.0, 0.0]);
        let expect = linear_to_srgb8(srgb_to_linear(200.0 / 255.0) * 0.5);
        assert_eq!(px[0], [expect, 100, 0, 7]);
    }

    #[test]
    fn computed_normals_face_the_winding() {
        let positions = vec![Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::new(1.0, 0.0, 1.0)];
        // Two triangles of the unit square in y = 0, wound so the normal is -y... and a
        // given normal that must only be normalised.
        let mut normals = vec![Vec3::ZERO, Vec3::ZERO, Vec3::ZERO, Vec3::new(0.0, 3.0, 0.0)];
        fill_missing_normals(&positions, &mut normals, &[[0, 1, 2], [1, 3, 2]]);
        let expect = Vec3::X.cross(Vec3::Z).normalize();
        assert_eq!(expect, -Vec3::Y);
        for n in &normals[..3] {
            assert!((*n - expect).length() < 1e-6, "{n}");
        }
        assert_eq!(normals[3], Vec3::Y);
    }
}
