//! Mitsuba 3 export: `scene.xml`, `meshes/*.ply`, `textures/*.png`.
//!
//! The scene keeps sylva's instancing. Each unique model is written once, one binary PLY per
//! material (a Mitsuba shape carries one BSDF), grouped in a `shapegroup`; each plant is an
//! `instance` of it with its `to_world` matrix. The mapping (see `docs/export.md`):
//!
//! | sylva | Mitsuba 3 |
//! | --- | --- |
//! | leaf material (alpha-textured quad) | `mask` (opacity = the alpha channel, nearest texel) around an even `blendbsdf` of a `twosided` `diffuse` of reflectance `2R` and a `principledthin` of `diff_trans` 2 (a pure Lambertian transmitter) of colour `2T`: exactly `R` reflected and `T` transmitted per colour, both Lambertian, as sylva shades them ([`sylva_geom::Optics`]); `2R`, `2T` as linear float EXR textures |
//! | wood material | `diffuse` with the bark texture (an EXR of `R` where the material scales its colour); wrapped in `twosided` when the material is two-sided |
//! | sun | `directional`, `direction` = the direction light travels, `irradiance` = [`MitsubaOptions::sun_irradiance`] × the 6500 K black-body colour |
//! | sky colour | `constant` emitter of that radiance |
//! | ground | `rectangle` on y = 0 with a `diffuse` of the ground colour |
//! | camera | `perspective`, `lookat` with up = +y, `fov_axis` = `y` (sylva's fov is vertical), the same width, height |
//! | rays per pixel | `independent` sampler's `sample_count` (the `spp` default, `-Dspp=N` overrides) |
//! | — | `volpath` integrator: unlike `path`, its shadow rays pass through a mask's transparent texels (null transmission), so leaves cast leaf-shaped shadows rather than quad-shaped ones |
//! | medium (cloud) | a `cube` with a `null` BSDF around a `heterogeneous` interior medium: `sigma_t` a `gridvolume` of the density (`media/<name>.vol`, trilinear), `scale` = the preset's σ_t per lattice step / the cell length (per world unit), `albedo` = σ_s / σ_t per colour, `hg` phase with the preset's g (its luminance-weighted mean where the colours differ) |
//!
//! PLY texture coordinates are sylva's as they are: Mitsuba's PLY loader and bitmap texture
//! both put v = 0 at the image's first (top) row, as sylva does.

use super::{
    file_stems, has_transparency, material_stems, triangles_by_material, validate_models,
    write_file, write_png, write_scaled_exr, ExportError, Exported, PngChannels, TextureFiles,
};
use glam::{Mat4, Vec3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use sylva_geom::{Material, Medium, Model, Scene, Wrap};

/// The scene file in the output directory.
pub const XML_FILE: &str = "scene.xml";
/// PLY meshes, relative to the output directory.
pub const MESH_DIR: &str = "meshes";
/// Textures, relative to the output directory.
pub const TEXTURE_DIR: &str = "textures";
/// Media density grids (`.vol`), relative to the output directory.
pub const MEDIA_DIR: &str = "media";

/// Choices the scene file does not fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MitsubaOptions {
    /// Samples per pixel, the XML's `spp` default (render with `-Dspp=N` to change it).
    pub spp: u32,
    /// The `volpath` integrator's `max_depth`: scattering events (passes through transparent
    /// texels do not count); -1 is unbounded, ended by Russian roulette. The XML's
    /// `max_depth` default.
    pub max_depth: i32,
    /// Irradiance of the sun on a surface facing it, as luminance; its colour is a 6500 K
    /// black body. π makes a white Lambertian surface facing the sun as bright as sylva's
    /// local shading `R (N·L)` with a sun of intensity 1.
    pub sun_irradiance: f32,
}

impl MitsubaOptions {
    /// The scene's samples per pixel, unbounded paths (an unbiased reference), a sun of
    /// irradiance π.
    pub fn for_scene(scene: &Scene) -> MitsubaOptions {
        MitsubaOptions {
            spp: scene.camera.rays_per_pixel,
            max_depth: -1,
            sun_irradiance: std::f32::consts::PI,
        }
    }

    pub fn validate(&self) -> Result<(), ExportError> {
        let bad = |m: String| Err(ExportError::Option(m));
        if self.spp == 0 {
            return bad("samples per pixel must be at least 1".into());
        }
        if self.max_depth < -1 || self.max_depth == 0 {
            return bad(format!(
                "max_depth {} must be -1 (unbounded) or at least 1",
                self.max_depth
            ));
        }
        if !(self.sun_irradiance.is_finite() && self.sun_irradiance >= 0.0) {
            return bad(format!(
                "sun irradiance {} must be finite and ≥ 0",
                self.sun_irradiance
            ));
        }
        Ok(())
    }
}

/// `"x, y, z"`.
fn v3(v: impl Into<[f32; 3]>) -> String {
    let [x, y, z] = v.into();
    format!("{x}, {y}, {z}")
}

/// Text safe inside an XML comment or attribute.
fn xml_text(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace("--", "- -")
}

/// Row-major "m00 m01 ... m33" of `m`.
fn matrix_value(m: Mat4) -> String {
    let rows: Vec<String> = (0..4)
        .map(|r| {
            let row = m.row(r);
            format!("{} {} {} {}", row.x, row.y, row.z, row.w)
        })
        .collect();
    rows.join("  ")
}

fn bitmap(out: &mut String, indent: &str, name: &str, file: &str, wrap: Wrap, alpha: bool) {
    let wrap = match wrap {
        Wrap::Repeat => "repeat",
        Wrap::Clamp => "clamp",
    };
    let _ = writeln!(out, "{indent}<texture type=\"bitmap\" name=\"{name}\">");
    let _ = writeln!(
        out,
        "{indent}    <string name=\"filename\" value=\"{file}\"/>"
    );
    let _ = writeln!(
        out,
        "{indent}    <string name=\"wrap_mode\" value=\"{wrap}\"/>"
    );
    if alpha {
        // Coverage is linear, and sylva's alpha test reads the nearest texel.
        let _ = writeln!(out, "{indent}    <boolean name=\"raw\" value=\"true\"/>");
        let _ = writeln!(
            out,
            "{indent}    <string name=\"filter_type\" value=\"nearest\"/>"
        );
    }
    let _ = writeln!(out, "{indent}</texture>");
}

/// Opens `<bsdf type="TY" [id="ID"]>` and indents further.
fn open_bsdf(out: &mut String, indent: &mut String, ty: &str, id: Option<&str>) {
    match id {
        Some(id) => {
            let _ = writeln!(out, "{indent}<bsdf type=\"{ty}\" id=\"{id}\">");
        }
        None => {
            let _ = writeln!(out, "{indent}<bsdf type=\"{ty}\">");
        }
    }
    indent.push_str("    ");
}

/// Where a material's textures went: the colour PNG (shared by materials of one texture)
/// and, per material, the linear EXRs of its scaled colours.
struct MaterialFiles {
    /// `textures/<texture>.png`, the colour as stored (sRGB).
    colour: Option<String>,
    /// Leaves: `2R`; wood whose reflectance is not its colour: `R`.
    reflect: Option<String>,
    /// Leaves: `2T`.
    transmit: Option<String>,
}

/// `<rgb name="NAME" value="..."/>` or a bitmap of `file`.
fn colour_param(
    out: &mut String,
    indent: &str,
    name: &str,
    file: Option<&str>,
    rgb: [f32; 3],
    wrap: Wrap,
) {
    match file {
        Some(f) => bitmap(out, indent, name, f, wrap, false),
        None => {
            let _ = writeln!(out, "{indent}<rgb name=\"{name}\" value=\"{}\"/>", v3(rgb));
        }
    }
}

/// `v ⊙ factor · k`.
fn scaled(v: [f32; 3], factor: [f32; 3], k: f32) -> [f32; 3] {
    [0, 1, 2].map(|c| v[c] * factor[c] * k)
}

/// The BSDF element of `mat` with id `id`.
fn bsdf(out: &mut String, id: &str, mat: &Material, files: &MaterialFiles, alpha: Option<&str>) {
    let tex = mat.texture.as_ref();
    let masked = tex.is_some_and(|t| has_transparency(t));
    let o = &mat.optics;
    let _ = writeln!(
        out,
        "    <!-- {} ({}): reflectance {} × colour, transmittance {} × colour -->",
        xml_text(&mat.name),
        mat.kind.name(),
        v3(o.reflect),
        v3(if mat.is_leaf() { o.transmit } else { [0.0; 3] }),
    );
    let mut indent = "    ".to_string();
    let mut closes = 0;
    let mut id = Some(id);
    if masked {
        open_bsdf(out, &mut indent, "mask", id.take());
        closes += 1;
        bitmap(
            out,
            &indent,
            "opacity",
            alpha.unwrap_or_default(),
            Wrap::Clamp,
            true,
        );
    }
    let wrap = tex.map(|t| t.wrap).unwrap_or(Wrap::Repeat);
    if mat.is_leaf() {
        // A thin two-sided sheet: half a two-sided Lambertian reflector of 2R, half a
        // Lambertian transmitter of 2T (principledthin at diff_trans = 2 transmits its
        // base colour and reflects nothing; at spec_trans = 0 it has no specular lobe).
        open_bsdf(out, &mut indent, "blendbsdf", id.take());
        closes += 1;
        let _ = writeln!(out, "{indent}<float name=\"weight\" value=\"0.5\"/>");
        open_bsdf(out, &mut indent, "twosided", None);
        open_bsdf(out, &mut indent, "diffuse", None);
        colour_param(
            out,
            &indent,
            "reflectance",
            files.reflect.as_deref(),
            scaled(mat.base_color, o.reflect, 2.0),
            wrap,
        );
        for _ in 0..2 {
            indent.truncate(indent.len() - 4);
            let _ = writeln!(out, "{indent}</bsdf>");
        }
        open_bsdf(out, &mut indent, "principledthin", None);
        colour_param(
            out,
            &indent,
            "base_color",
            files.transmit.as_deref(),
            scaled(mat.base_color, o.transmit, 2.0),
            wrap,
        );
        let _ = writeln!(out, "{indent}<float name=\"diff_trans\" value=\"2\"/>");
        indent.truncate(indent.len() - 4);
        let _ = writeln!(out, "{indent}</bsdf>");
    } else {
        if mat.two_sided {
            open_bsdf(out, &mut indent, "twosided", id.take());
            closes += 1;
        }
        open_bsdf(out, &mut indent, "diffuse", id.take());
        closes += 1;
        colour_param(
            out,
            &indent,
            "reflectance",
            files.reflect.as_deref().or(files.colour.as_deref()),
            scaled(mat.base_color, o.reflect, 1.0),
            wrap,
        );
    }
    for _ in 0..closes {
        indent.truncate(indent.len() - 4);
        let _ = writeln!(out, "{indent}</bsdf>");
    }
}

/// Writes the triangles `tris` of `model` as a binary little-endian PLY (x y z nx ny nz u v,
/// faces as `vertex_indices`), with only the vertices they use.
fn write_ply(
    set: &mut sylva_core::OutputSet,
    path: &Path,
    model: &Model,
    tris: &[u32],
    comment: &str,
) -> Result<(), ExportError> {
    let mesh = &model.mesh;
    let mut remap = vec![u32::MAX; mesh.vertex_count()];
    let mut used: Vec<u32> = Vec::new();
    for &t in tris {
        for i in mesh.indices[t as usize] {
            if remap[i as usize] == u32::MAX {
                remap[i as usize] = used.len() as u32;
                used.push(i);
            }
        }
    }
    write_file(set, path, |w| {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n\
             property float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             property float u\nproperty float v\n\
             element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
            used.len(),
            tris.len()
        )?;
        let mut rec = [0u8; 32];
        for &i in &used {
            let i = i as usize;
            let vals = [
                mesh.positions[i][0],
                mesh.positions[i][1],
                mesh.positions[i][2],
                mesh.normals[i][0],
                mesh.normals[i][1],
                mesh.normals[i][2],
                mesh.uvs[i][0],
                mesh.uvs[i][1],
            ];
            for (k, v) in vals.iter().enumerate() {
                rec[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
            }
            w.write_all(&rec)?;
        }
        let mut face = [0u8; 13];
        face[0] = 3;
        for &t in tris {
            for (k, i) in mesh.indices[t as usize].iter().enumerate() {
                face[1 + 4 * k..5 + 4 * k].copy_from_slice(&remap[*i as usize].to_le_bytes());
            }
            w.write_all(&face)?;
        }
        Ok(())
    })
}

/// The far clipping distance: twice the farthest point of the scene from the camera, at least
/// Mitsuba's default 10 km.
fn far_clip(scene: &Scene) -> f32 {
    let mut b = scene.instance_bounds();
    if let Some(q) = super::ground_quad(scene) {
        for (p, _) in q {
            b.grow(Vec3::from_array(p));
        }
    }
    if b.is_empty() {
        return 1e4;
    }
    let far = b
        .corners()
        .iter()
        .map(|c| c.distance(scene.camera.position))
        .fold(0.0f32, f32::max);
    (2.0 * far).max(1e4)
}

/// Bytes of the PLY files of the models in `written` (exact: header aside, 32 bytes a vertex
/// and 13 a face).
fn ply_bytes(scene: &Scene, written: &[bool]) -> u64 {
    scene
        .models
        .iter()
        .zip(written)
        .filter(|(_, w)| **w)
        .map(|(m, _)| 32 * m.mesh.vertex_count() as u64 + 13 * m.triangle_count() as u64 + 4096)
        .sum()
}

/// Writes `m`'s density as Mitsuba's binary grid volume (`VOL` version 3: float32, one
/// channel, x fastest, then the bounding box, which Mitsuba 3 ignores in favour of the
/// volume's `to_world`).
fn write_vol(set: &mut sylva_core::OutputSet, path: &Path, m: &Medium) -> Result<(), ExportError> {
    let [nx, ny, nz] = m.dims;
    write_file(set, path, |w| {
        let mut head = Vec::with_capacity(48);
        head.extend_from_slice(b"VOL");
        head.push(3);
        for v in [1i32, nx as i32, ny as i32, nz as i32, 1] {
            head.extend_from_slice(&v.to_le_bytes());
        }
        let (lo, hi) = cell_box(m);
        for v in lo.to_array().into_iter().chain(hi.to_array()) {
            head.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&head)?;
        let mut row = Vec::with_capacity(nx * 4);
        for z in 0..nz {
            for y in 0..ny {
                row.clear();
                for x in 0..nx {
                    row.extend_from_slice(&m.density[m.index(x, y, z)].to_le_bytes());
                }
                w.write_all(&row)?;
            }
        }
        Ok(())
    })
}

/// The box Mitsuba's grid covers: its values sit at cell centres, so sylva's site-centre box
/// grows by half a cell on every side.
fn cell_box(m: &Medium) -> (Vec3, Vec3) {
    let half = Vec3::splat(0.5 * m.cell());
    (m.bounds.min - half, m.bounds.max + half)
}

/// The optical parameters of `m` in world units: σ_t per unit length at density 1 (the
/// same for every colour in sylva's presets), albedo per colour, and one g.
fn medium_optics(m: &Medium) -> Result<(f32, [f32; 3], f32, bool), ExportError> {
    let params = sylva_geom::Preset::parse(&m.preset)
        .map_err(|e| ExportError::Option(format!("medium '{}': {e}", m.name)))?
        .params();
    let c = params.colours;
    let sigma_t = c[0].sigma_t();
    if c.iter().any(|p| (p.sigma_t() - sigma_t).abs() > 1e-9) {
        return Err(ExportError::Option(format!(
            "medium '{}': preset '{}' has a different σ_t per colour, which one Mitsuba density grid cannot hold",
            m.name, m.preset
        )));
    }
    let albedo = c.map(|p| (p.sigma_s / p.sigma_t()) as f32);
    let w = [0.2126, 0.7152, 0.0722];
    let g: f64 = c.iter().zip(w).map(|(p, w)| p.g * w).sum();
    let grey_g = c.iter().all(|p| p.g == c[0].g);
    Ok(((sigma_t / m.cell() as f64) as f32, albedo, g as f32, grey_g))
}

/// Which models are written: those placed and with geometry.
fn written_models(scene: &Scene) -> Vec<bool> {
    (0..scene.models.len())
        .map(|k| {
            scene.models[k].triangle_count() > 0
                && scene.instances.iter().any(|i| i.model as usize == k)
        })
        .collect()
}

/// The distinct textures of the written models, with their stems.
fn needed_textures<'a>(
    scene: &'a Scene,
    textures: &TextureFiles,
    written: &[bool],
) -> Vec<(&'a std::sync::Arc<sylva_geom::Texture>, String)> {
    let needed: std::collections::HashSet<&str> = scene
        .models
        .iter()
        .zip(written)
        .filter(|(_, w)| **w)
        .flat_map(|(m, _)| m.materials.iter().filter_map(|mat| mat.texture.as_ref()))
        .map(|t| textures.stem(t))
        .collect();
    textures
        .unique(&scene.models)
        .into_iter()
        .filter(|(_, stem)| needed.contains(stem.as_str()))
        .collect()
}

/// The EXR textures of a textured material, by suffix, with the factor on its colour: a leaf's
/// `2R` and `2T`; wood's `R` where it scales its texture.
fn scaled_textures(mat: &Material) -> Vec<(&'static str, [f32; 3])> {
    let o = &mat.optics;
    if mat.is_leaf() {
        vec![
            ("reflect", o.reflect.map(|f| 2.0 * f)),
            ("transmit", o.transmit.map(|f| 2.0 * f)),
        ]
    } else if o.reflect != [1.0; 3] {
        vec![("reflect", o.reflect)]
    } else {
        Vec::new()
    }
}

/// The files [`write`] writes for `scene`, relative to its directory, in the order written:
/// textures, EXR textures, media, meshes, `scene.xml`.
pub fn files(scene: &Scene) -> Vec<PathBuf> {
    let mat_stems = material_stems(&scene.models);
    let textures = TextureFiles::new(&scene.models, &mat_stems);
    let written = written_models(scene);
    let mut files = Vec::new();
    for (t, stem) in needed_textures(scene, &textures, &written) {
        files.push(PathBuf::from(TEXTURE_DIR).join(format!("{stem}.png")));
        if has_transparency(t) {
            files.push(PathBuf::from(TEXTURE_DIR).join(format!("{stem}_alpha.png")));
        }
    }
    for (k, model) in scene.models.iter().enumerate() {
        if !written[k] {
            continue;
        }
        for (j, mat) in model.materials.iter().enumerate() {
            if mat.texture.is_some() {
                for (suffix, _) in scaled_textures(mat) {
                    files.push(PathBuf::from(format!(
                        "{TEXTURE_DIR}/{}_{suffix}.exr",
                        mat_stems[k][j]
                    )));
                }
            }
        }
    }
    let media_stems = file_stems(&scene.media.iter().map(|m| &m.name).collect::<Vec<_>>());
    for stem in media_stems {
        files.push(PathBuf::from(MEDIA_DIR).join(format!("{stem}.vol")));
    }
    for (k, model) in scene.models.iter().enumerate() {
        if !written[k] {
            continue;
        }
        for (j, tris) in triangles_by_material(model).iter().enumerate() {
            if !tris.is_empty() {
                files.push(PathBuf::from(format!("{MESH_DIR}/{}.ply", mat_stems[k][j])));
            }
        }
    }
    files.push(PathBuf::from(XML_FILE));
    files
}

/// Writes `scene.xml`, the PLY meshes and the textures into `dir` (created if needed), after
/// checking that the disk has room and that every file can be written; the files replace the
/// old ones together at the end, or none does. `progress(n)` is called with the number of models written
/// so far; returning `false` cancels the export ([`ExportError::Cancelled`]) before
/// `scene.xml` is written.
pub fn write(
    scene: &Scene,
    dir: &Path,
    opts: &MitsubaOptions,
    progress: &mut dyn FnMut(u64) -> bool,
) -> Result<Exported, ExportError> {
    opts.validate()?;
    validate_models(&scene.models)?;
    super::prepare_dir(dir)?;
    let model_stems = file_stems(&scene.models.iter().map(|m| &m.name).collect::<Vec<_>>());
    let mat_stems = material_stems(&scene.models);
    let textures = TextureFiles::new(&scene.models, &mat_stems);
    let written = written_models(scene);
    let media_bytes: u64 = scene.media.iter().map(|m| m.memory_bytes() + 48).sum();
    super::check_disk_space(
        dir,
        ply_bytes(scene, &written) + 200 * scene.instances.len() as u64 + media_bytes,
        super::available_disk_bytes(dir),
    )?;
    let optics = scene
        .media
        .iter()
        .map(medium_optics)
        .collect::<Result<Vec<_>, _>>()?;
    let mut set = Exported::plan(dir, &files(scene))?;

    for (t, stem) in needed_textures(scene, &textures, &written) {
        let rel = PathBuf::from(TEXTURE_DIR).join(format!("{stem}.png"));
        write_png(&mut set, &dir.join(&rel), t, PngChannels::Rgb)?;
        if has_transparency(t) {
            let rel = PathBuf::from(TEXTURE_DIR).join(format!("{stem}_alpha.png"));
            write_png(&mut set, &dir.join(&rel), t, PngChannels::Alpha)?;
        }
    }

    let cam = scene.camera;
    let mut x = String::new();
    let _ = writeln!(x, "<?xml version=\"1.0\" encoding=\"utf-8\"?>");
    let _ = writeln!(
        x,
        "<!-- sylva scene '{}' ({}): {} instances of {} models, {} triangles plus the ground, {} media.\n     \
         World frame: right-handed, +y up, metres. Render with Mitsuba 3 (RGB variant), e.g.\n     \
         mitsuba -m scalar_rgb -Dspp=256 -o render.exr {XML_FILE}  (see docs/export.md) -->",
        xml_text(&scene.name),
        xml_text(&scene.origin),
        scene.instances.len(),
        scene.models.len(),
        scene.instanced_triangles(),
        scene.media.len()
    );
    let _ = writeln!(x, "<scene version=\"3.0.0\">");
    let _ = writeln!(x, "    <default name=\"spp\" value=\"{}\"/>", opts.spp);
    let _ = writeln!(
        x,
        "    <default name=\"max_depth\" value=\"{}\"/>\n",
        opts.max_depth
    );
    let _ = writeln!(
        x,
        "    <!-- volpath, not path: its shadow rays see through the leaves' transparent texels. -->\n    <integrator type=\"volpath\">\n        <integer name=\"max_depth\" value=\"$max_depth\"/>\n    </integrator>\n"
    );

    // Camera: sylva's fov is vertical; lookat with +y up.
    let fwd = (cam.look_at - cam.position).normalize_or_zero();
    let up = if fwd.cross(Vec3::Y).length() < 1e-6 {
        // Looking straight up or down: +y cannot be "up" on the image; take +z.
        Vec3::Z
    } else {
        Vec3::Y
    };
    let _ = writeln!(x, "    <sensor type=\"perspective\">");
    let _ = writeln!(x, "        <string name=\"fov_axis\" value=\"y\"/>");
    let _ = writeln!(x, "        <float name=\"fov\" value=\"{}\"/>", cam.fov_deg);
    let _ = writeln!(x, "        <float name=\"near_clip\" value=\"0.01\"/>");
    let _ = writeln!(
        x,
        "        <float name=\"far_clip\" value=\"{}\"/>",
        far_clip(scene)
    );
    let _ = writeln!(
        x,
        "        <transform name=\"to_world\">\n            <lookat origin=\"{}\" target=\"{}\" up=\"{}\"/>\n        </transform>",
        v3(cam.position),
        v3(cam.look_at),
        v3(up)
    );
    let _ = writeln!(
        x,
        "        <sampler type=\"independent\">\n            <integer name=\"sample_count\" value=\"$spp\"/>\n        </sampler>"
    );
    let _ = writeln!(
        x,
        "        <film type=\"hdrfilm\">\n            <integer name=\"width\" value=\"{}\"/>\n            <integer name=\"height\" value=\"{}\"/>\n            <string name=\"pixel_format\" value=\"rgb\"/>\n            <rfilter type=\"box\"/>\n        </film>",
        cam.width, cam.height
    );
    let _ = writeln!(x, "    </sensor>\n");

    // Lights.
    let sun = scene.sun_rgb().map(|c| c * opts.sun_irradiance);
    let _ = writeln!(
        x,
        "    <!-- The sun: elevation {:.2}°, azimuth {:.2}°; its colour {:?} (a 6500 K black body unless bands set it). -->",
        scene.sun.elevation_deg(),
        scene.sun.azimuth_deg(),
        scene.sun_rgb()
    );
    let _ = writeln!(
        x,
        "    <emitter type=\"directional\">\n        <vector name=\"direction\" value=\"{}\"/>\n        <rgb name=\"irradiance\" value=\"{}\"/>\n    </emitter>",
        v3(scene.sun.travel().as_vec3()),
        v3(sun)
    );
    let _ = writeln!(
        x,
        "    <emitter type=\"constant\">\n        <rgb name=\"radiance\" value=\"{}\"/>\n    </emitter>\n",
        v3(scene.sky_color)
    );

    // Materials, with the EXR textures of their scaled colours.
    for (k, model) in scene.models.iter().enumerate() {
        if !written[k] {
            continue;
        }
        for (j, mat) in model.materials.iter().enumerate() {
            let stem = mat.texture.as_ref().map(|t| textures.stem(t));
            let mut files = MaterialFiles {
                colour: stem.map(|s| format!("{TEXTURE_DIR}/{s}.png")),
                reflect: None,
                transmit: None,
            };
            if let Some(t) = &mat.texture {
                for (suffix, factor) in scaled_textures(mat) {
                    let rel = format!("{TEXTURE_DIR}/{}_{suffix}.exr", mat_stems[k][j]);
                    write_scaled_exr(&mut set, &dir.join(&rel), t, factor)?;
                    match suffix {
                        "reflect" => files.reflect = Some(rel),
                        _ => files.transmit = Some(rel),
                    }
                }
            }
            let alpha = stem.map(|s| format!("{TEXTURE_DIR}/{s}_alpha.png"));
            bsdf(
                &mut x,
                &format!("bsdf-{}", mat_stems[k][j]),
                mat,
                &files,
                alpha.as_deref(),
            );
        }
    }
    x.push('\n');

    // Ground.
    if let Some(q) = super::ground_quad(scene) {
        let (hx, hz) = (q[2].0[0], q[2].0[2]);
        // The rectangle spans [-1, 1]² in x-y with normal +z: map x → x, y → -z, z → +y.
        let m = Mat4::from_cols_array_2d(&[
            [hx, 0.0, 0.0, 0.0],
            [0.0, 0.0, -hz, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]);
        let _ = writeln!(
            x,
            "    <shape type=\"rectangle\" id=\"ground\">\n        <transform name=\"to_world\">\n            <matrix value=\"{}\"/>\n        </transform>\n        <bsdf type=\"diffuse\">\n            <rgb name=\"reflectance\" value=\"{}\"/>\n        </bsdf>\n    </shape>\n",
            matrix_value(m),
            v3(scene.ground.color)
        );
    }

    // Media: a null-surfaced cube around a heterogeneous interior.
    let media_stems = file_stems(&scene.media.iter().map(|m| &m.name).collect::<Vec<_>>());
    for ((m, stem), (sigma_t, albedo, g, grey_g)) in
        scene.media.iter().zip(&media_stems).zip(optics)
    {
        let rel = PathBuf::from(MEDIA_DIR).join(format!("{stem}.vol"));
        write_vol(&mut set, &dir.join(&rel), m)?;
        let (lo, hi) = cell_box(m);
        let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        let _ = writeln!(
            x,
            "    <!-- Medium '{}': {}×{}×{} sites of {} m, preset {} (σ per lattice step / cell length = per metre){} -->",
            xml_text(&m.name),
            m.dims[0],
            m.dims[1],
            m.dims[2],
            m.cell(),
            xml_text(&m.preset),
            if grey_g {
                ""
            } else {
                "; g differs per colour: Mitsuba's hg takes one, the luminance-weighted mean"
            }
        );
        let _ = writeln!(
            x,
            "    <shape type=\"cube\">\n        <transform name=\"to_world\">\n            <scale value=\"{}\"/>\n            <translate value=\"{}\"/>\n        </transform>\n        <bsdf type=\"null\"/>\n        <medium type=\"heterogeneous\" name=\"interior\">\n            <rgb name=\"albedo\" value=\"{}\"/>\n            <float name=\"scale\" value=\"{}\"/>\n            <volume type=\"gridvolume\" name=\"sigma_t\">\n                <string name=\"filename\" value=\"{MEDIA_DIR}/{stem}.vol\"/>\n                <transform name=\"to_world\">\n                    <scale value=\"{}\"/>\n                    <translate value=\"{}\"/>\n                </transform>\n            </volume>\n            <phase type=\"hg\">\n                <float name=\"g\" value=\"{}\"/>\n            </phase>\n        </medium>\n    </shape>\n",
            v3(half),
            v3(centre),
            v3(albedo),
            sigma_t,
            v3(hi - lo),
            v3(lo),
            g
        );
    }

    // Models: one PLY per material, grouped.
    let mut done = 0u64;
    for (k, model) in scene.models.iter().enumerate() {
        if !written[k] {
            done += 1;
            if !progress(done) {
                return Err(ExportError::Cancelled);
            }
            continue;
        }
        let _ = writeln!(
            x,
            "    <shape type=\"shapegroup\" id=\"model-{}\">",
            model_stems[k]
        );
        for (j, tris) in triangles_by_material(model).iter().enumerate() {
            if tris.is_empty() {
                continue;
            }
            // Forward slashes: the XML is read on any system.
            let name = format!("{MESH_DIR}/{}.ply", mat_stems[k][j]);
            let rel = PathBuf::from(&name);
            write_ply(
                &mut set,
                &dir.join(&rel),
                model,
                tris,
                &format!("sylva model {} material {}", model_stems[k], j),
            )?;
            let _ = writeln!(
                x,
                "        <shape type=\"ply\">\n            <string name=\"filename\" value=\"{}\"/>\n            <ref id=\"bsdf-{}\"/>\n        </shape>",
                name,
                mat_stems[k][j]
            );
        }
        let _ = writeln!(x, "    </shape>");
        done += 1;
        if !progress(done) {
            return Err(ExportError::Cancelled);
        }
    }
    x.push('\n');

    // Instances.
    for inst in &scene.instances {
        let k = inst.model as usize;
        if !written[k] {
            continue;
        }
        let _ = writeln!(
            x,
            "    <shape type=\"instance\">\n        <ref id=\"model-{}\"/>\n        <transform name=\"to_world\">\n            <matrix value=\"{}\"/>\n        </transform>\n    </shape>",
            model_stems[k],
            matrix_value(Mat4::from(inst.transform()))
        );
    }
    let _ = writeln!(x, "</scene>");
    write_file(&mut set, &dir.join(XML_FILE), |w| w.write_all(x.as_bytes()))?;
    let mut out = Exported::default();
    out.commit(dir, set)?;
    out.triangles = scene.instanced_triangles()
        + if super::ground_quad(scene).is_some() {
            2
        } else {
            0
        };
    Ok(out)
}
