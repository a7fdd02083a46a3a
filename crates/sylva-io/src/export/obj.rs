//! Wavefront OBJ export of the flattened scene: `scene.obj`, `scene.mtl` and `textures/*.png`.
//!
//! Every instance becomes an object (`o maple_3`) whose vertices are its model's transformed to
//! world space (normals by the inverse transpose), followed by its faces grouped by material
//! (`usemtl maple_leaf`). Vertices, texture coordinates and normals share one index per
//! vertex (`f 7/7/7 8/8/8 9/9/9`). The ground is the first object, a quad with its colour.
//!
//! Texture coordinates follow the OBJ convention (v = 0 at the image's bottom row), so `vt` is
//! `(u, 1 - v)` of sylva's (v = 0 at the top row). Leaf materials carry `map_Kd` (RGBA, the
//! leaf outline in alpha) and `map_d` (the alpha channel alone as a grey image, what the MTL
//! format reads for dissolve).
//!
//! The text is produced instance by instance, a few instances at a time in parallel (in order,
//! so the file is the same for any thread count), and streamed into the atomic writer; the
//! whole scene's text is never in memory. [`estimate_size`] predicts the file size before a
//! long write.

use super::{
    file_stems, has_transparency, material_stems, triangles_by_material, validate_models,
    write_file, write_png, ExportError, Exported, PngChannels, TextureFiles,
};
use glam::{Affine3A, Mat3A, Vec3};
use rayon::prelude::*;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use sylva_geom::{Model, Scene};

/// The OBJ file in the output directory.
pub const OBJ_FILE: &str = "scene.obj";
/// The material library beside it.
pub const MTL_FILE: &str = "scene.mtl";
/// Where the textures go, relative to the output directory.
pub const TEXTURE_DIR: &str = "textures";

/// Scenes with more instanced triangles than this get a size warning before the write
/// (`beech`, 270 M triangles, makes a file of tens of GB).
pub const LARGE_SCENE_TRIANGLES: u64 = 50_000_000;

/// Whether a scene of `triangles` instanced triangles deserves the size warning.
pub fn is_large(triangles: u64) -> bool {
    triangles > LARGE_SCENE_TRIANGLES
}

/// The warning to print before writing a scene of `triangles` instanced triangles whose OBJ is
/// estimated at `estimated_bytes`; `None` for scenes at or under [`LARGE_SCENE_TRIANGLES`].
pub fn size_warning(triangles: u64, estimated_bytes: u64) -> Option<String> {
    is_large(triangles).then(|| {
        format!(
            "the scene has {:.1} M instanced triangles (over {} M): the OBJ will be about {} \
             and take a while to write; the Mitsuba export (--format mitsuba) keeps the \
             instancing and stays small",
            triangles as f64 / 1e6,
            LARGE_SCENE_TRIANGLES / 1_000_000,
            sylva_core::format_bytes(estimated_bytes)
        )
    })
}

/// Per-model data shared by all its instances.
struct Prepared {
    /// Triangle indices grouped by material.
    by_material: Vec<Vec<u32>>,
    /// MTL material names, by material index.
    mtl_names: Vec<String>,
    /// Object-name stem of the model's instances.
    stem: String,
}

fn prepare(scene: &Scene) -> Vec<Prepared> {
    let mat_stems = material_stems(&scene.models);
    let model_stems = file_stems(&scene.models.iter().map(|m| &m.name).collect::<Vec<_>>());
    scene
        .models
        .iter()
        .zip(mat_stems)
        .zip(model_stems)
        .map(|((m, mtl_names), stem)| Prepared {
            by_material: triangles_by_material(m),
            mtl_names,
            stem,
        })
        .collect()
}

/// Writes one instance's object. `stride` > 1 writes only every `stride`-th vertex and
/// triangle (for the size estimate). `base` is the number of vertices written before it.
fn format_instance(
    out: &mut impl Write,
    name: &str,
    model: &Model,
    prep: &Prepared,
    to_world: Affine3A,
    base: u64,
    stride: usize,
) -> io::Result<()> {
    let mesh = &model.mesh;
    let normal_matrix: Mat3A = to_world.matrix3.inverse().transpose();
    writeln!(out, "o {name}")?;
    for p in mesh.positions.iter().step_by(stride) {
        let w = to_world.transform_point3(Vec3::from_array(*p));
        writeln!(out, "v {} {} {}", w.x, w.y, w.z)?;
    }
    for uv in mesh.uvs.iter().step_by(stride) {
        writeln!(out, "vt {} {}", uv[0], 1.0 - uv[1])?;
    }
    for n in mesh.normals.iter().step_by(stride) {
        let w = (normal_matrix * Vec3::from_array(*n)).normalize_or_zero();
        writeln!(out, "vn {} {} {}", w.x, w.y, w.z)?;
    }
    for (tris, mtl) in prep.by_material.iter().zip(&prep.mtl_names) {
        if tris.is_empty() {
            continue;
        }
        writeln!(out, "usemtl {mtl}")?;
        for &t in tris.iter().step_by(stride) {
            let [a, b, c] = mesh.indices[t as usize].map(|i| base + i as u64 + 1);
            writeln!(out, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}")?;
        }
    }
    Ok(())
}

/// Counts bytes without storing them.
struct Counter(u64);

impl Write for Counter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.0 += buf.len() as u64;
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Vertices (each a `v`, `vt` and `vn` line) in the whole OBJ, the ground included.
fn total_vertices(scene: &Scene) -> u64 {
    let ground = if super::ground_quad(scene).is_some() {
        4
    } else {
        0
    };
    ground
        + scene
            .instances
            .iter()
            .map(|i| scene.models[i.model as usize].mesh.vertex_count() as u64)
            .sum::<u64>()
}

/// Text bytes of one instance of `model`, estimated from about 4096 of its vertices and
/// triangles at a typical index offset.
fn estimate_instance(
    model: &Model,
    prep: &Prepared,
    to_world: Affine3A,
    base: u64,
) -> io::Result<u64> {
    let n = model.mesh.vertex_count().max(model.mesh.triangle_count());
    let stride = (n / 4096).max(1);
    let mut c = Counter(0);
    format_instance(&mut c, &prep.stem, model, prep, to_world, base, stride)?;
    // Scale the per-element lines up; the name and `usemtl` lines are counted once.
    Ok(c.0 * stride as u64)
}

/// Predicted size of `scene.obj` in bytes (within a few per cent): each model's text sampled
/// at the transform of its first instance, times its instance count.
pub fn estimate_size(scene: &Scene) -> u64 {
    let prep = prepare(scene);
    let base = total_vertices(scene) / 2;
    let mut total = 1024u64; // header and ground
    for (k, (model, p)) in scene.models.iter().zip(&prep).enumerate() {
        let mut insts = scene.instances.iter().filter(|i| i.model as usize == k);
        let Some(first) = insts.next() else { continue };
        let count = 1 + insts.count() as u64;
        let per = estimate_instance(model, p, first.transform(), base).unwrap_or(0);
        total += per * count;
    }
    total
}

/// The files [`write`] writes for `scene`, relative to its directory, in the order written:
/// the textures, the MTL file, the OBJ file.
pub fn files(scene: &Scene) -> Vec<PathBuf> {
    let textures = TextureFiles::new(&scene.models, &material_stems(&scene.models));
    let mut files = Vec::new();
    for (t, stem) in textures.unique(&scene.models) {
        files.push(PathBuf::from(TEXTURE_DIR).join(format!("{stem}.png")));
        if has_transparency(t) {
            files.push(PathBuf::from(TEXTURE_DIR).join(format!("{stem}_alpha.png")));
        }
    }
    files.extend([PathBuf::from(MTL_FILE), PathBuf::from(OBJ_FILE)]);
    files
}

/// Writes `scene.obj`, `scene.mtl` and the textures into `dir` (created if needed), after
/// checking that the disk has room for the estimated size and that every file can be
/// written; the files replace the old ones together at the end, or none does. `progress(n)` is called with the
/// number of instances written so far; returning `false` cancels the export
/// ([`ExportError::Cancelled`]) and leaves no partial `scene.obj` behind.
pub fn write(
    scene: &Scene,
    dir: &Path,
    progress: &mut dyn FnMut(u64) -> bool,
) -> Result<Exported, ExportError> {
    validate_models(&scene.models)?;
    super::prepare_dir(dir)?;
    super::check_disk_space(dir, estimate_size(scene), super::available_disk_bytes(dir))?;
    let prep = prepare(scene);
    let mat_stems = material_stems(&scene.models);
    let textures = TextureFiles::new(&scene.models, &mat_stems);
    let mut set = Exported::plan(dir, &files(scene))?;

    // Textures: RGBA for map_Kd; the alpha alone for map_d where the texture cuts a shape.
    for (t, stem) in textures.unique(&scene.models) {
        let rel = PathBuf::from(TEXTURE_DIR).join(format!("{stem}.png"));
        write_png(&mut set, &dir.join(&rel), t, PngChannels::Rgba)?;
        if has_transparency(t) {
            let rel = PathBuf::from(TEXTURE_DIR).join(format!("{stem}_alpha.png"));
            write_png(&mut set, &dir.join(&rel), t, PngChannels::Alpha)?;
        }
    }

    // Material library.
    let mtl_path = dir.join(MTL_FILE);
    write_file(&mut set, &mtl_path, |w| {
        writeln!(w, "# sylva materials of scene '{}'", scene.name)?;
        writeln!(w, "# Kd is linear RGB; texture maps are sRGB PNGs.")?;
        if super::ground_quad(scene).is_some() {
            let [r, g, b] = scene.ground.color;
            writeln!(
                w,
                "\nnewmtl ground\nKa 0 0 0\nKd {r} {g} {b}\nKs 0 0 0\nd 1\nillum 1"
            )?;
        }
        for (model, p) in scene.models.iter().zip(&prep) {
            for (mat, name) in model.materials.iter().zip(&p.mtl_names) {
                writeln!(w, "\nnewmtl {name}")?;
                let [r, g, b] = mat.base_color;
                writeln!(
                    w,
                    "# {} ({}, {}-sided), mean colour {r} {g} {b}",
                    mat.name,
                    mat.kind.name(),
                    if mat.two_sided { "two" } else { "one" }
                )?;
                writeln!(w, "Ka 0 0 0\nKs 0 0 0\nillum 1")?;
                match &mat.texture {
                    Some(t) => {
                        // The map is multiplied by Kd: keep Kd white so the colour is the map's.
                        let stem = textures.stem(t);
                        writeln!(w, "Kd 1 1 1\nd 1\nmap_Kd {TEXTURE_DIR}/{stem}.png")?;
                        if has_transparency(t) {
                            writeln!(w, "map_d {TEXTURE_DIR}/{stem}_alpha.png")?;
                        }
                    }
                    None => writeln!(w, "Kd {r} {g} {b}\nd 1")?,
                }
            }
        }
        Ok(())
    })?;

    // Geometry.
    let threads = rayon::current_num_threads().max(1);
    let base = total_vertices(scene) / 2;
    let largest = scene
        .models
        .iter()
        .zip(&prep)
        .map(|(m, p)| estimate_instance(m, p, Affine3A::IDENTITY, base).unwrap_or(0))
        .max()
        .unwrap_or(0);
    sylva_core::check_memory(
        &format!("OBJ text of {threads} instances at a time"),
        largest * threads as u64 * 2,
    )?;
    let obj_path = dir.join(OBJ_FILE);
    let mut cancelled = false;
    let result = write_file(&mut set, &obj_path, |w| {
        writeln!(
            w,
            "# sylva scene '{}' ({}), flattened: {} instances, {} triangles plus the ground",
            scene.name,
            scene.origin,
            scene.instances.len(),
            scene.instanced_triangles()
        )?;
        writeln!(
            w,
            "# World frame: right-handed, +y up, metres; ground at y = 0.\nmtllib {MTL_FILE}"
        )?;
        let mut written: u64 = 0;
        if let Some(quad) = super::ground_quad(scene) {
            writeln!(w, "o ground")?;
            for (p, _) in &quad {
                writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
            }
            for (_, uv) in &quad {
                writeln!(w, "vt {} {}", uv[0], uv[1])?;
            }
            for _ in &quad {
                writeln!(w, "vn 0 1 0")?;
            }
            writeln!(w, "usemtl ground\nf 1/1/1 2/2/2 3/3/3\nf 1/1/1 3/3/3 4/4/4")?;
            written = 4;
        }
        let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); threads];
        let mut done = 0u64;
        for (c, chunk) in scene.instances.chunks(threads).enumerate() {
            let mut bases = Vec::with_capacity(chunk.len());
            for inst in chunk {
                bases.push(written);
                written += scene.models[inst.model as usize].mesh.vertex_count() as u64;
            }
            bufs[..chunk.len()]
                .par_iter_mut()
                .zip(chunk.par_iter().zip(bases.par_iter()))
                .enumerate()
                .try_for_each(|(j, (buf, (inst, &b)))| {
                    buf.clear();
                    let m = inst.model as usize;
                    let name = format!("{}_{}", prep[m].stem, c * threads + j);
                    format_instance(
                        buf,
                        &name,
                        &scene.models[m],
                        &prep[m],
                        inst.transform(),
                        b,
                        1,
                    )
                })?;
            for buf in &bufs[..chunk.len()] {
                w.write_all(buf)?;
            }
            done += chunk.len() as u64;
            if !progress(done) {
                cancelled = true;
                return Err(io::Error::other("cancelled"));
            }
        }
        Ok(())
    });
    if cancelled {
        return Err(ExportError::Cancelled);
    }
    result?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warning_threshold() {
        assert!(!is_large(LARGE_SCENE_TRIANGLES));
        assert!(is_large(LARGE_SCENE_TRIANGLES + 1));
        assert!(size_warning(50_000_000, 1 << 30).is_none());
        assert!(size_warning(1_000, 1 << 40).is_none());
        let w = size_warning(270_000_000, 30 << 30).unwrap();
        assert!(w.contains("270.0 M") && w.contains("30.0 GiB"), "{w}");
    }
}
