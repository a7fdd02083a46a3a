//! Wavefront OBJ + MTL. `tobj` reads the geometry (triangulated, one index per vertex) and
//! the materials; a line-by-line check runs first because tobj's errors do not say where:
//! every syntax error, bad index or non-finite number is reported with its file and line.
//!
//! Per material: `Kd` (linear colour, multiplied into the texture), `map_Kd` (colour and
//! alpha), `map_d` (coverage: the image's alpha, or its luminance when it has none);
//! `-clamp on` on a map makes its texture clamp. Textures resolve against the MTL file's
//! directory. OBJ's v runs up the image, sylva's down: v is flipped.

use super::{
    decode_image_with_alpha, read_model_file, read_referenced, tint, to_texture, ImportError,
    RawMaterial, RawModel,
};
use glam::Vec3;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use sylva_geom::{Texture, Wrap};

/// Untextured colour of a material without `Kd`, and of faces without `usemtl`.
const DEFAULT_GREY: [f32; 3] = [0.8, 0.8, 0.8];

pub(super) fn load(path: &Path) -> Result<RawModel, ImportError> {
    let text = read_text(path, path, None)?;
    let scan = scan_obj(&text, path)?;
    let dir = path.parent().unwrap_or(Path::new(""));

    let mut libs = Vec::new();
    for (line, name) in &scan.mtllibs {
        let what = format!("line {line}: mtllib '{name}'");
        let p = resolve(dir, dir, name, path, &what)?;
        let text = read_text(&p, path, Some((*line, &format!("mtllib '{name}'"))))?;
        let materials = scan_mtl(&text, &p)?;
        libs.push(MtlLib {
            name: name.clone(),
            folder: dir.to_path_buf(),
            path: p,
            text,
            materials,
        });
    }
    for (line, name) in &scan.usemtl {
        if !libs
            .iter()
            .any(|l| l.materials.iter().any(|m| m.name == *name))
        {
            let known = if libs.is_empty() {
                "the file has no mtllib".to_string()
            } else {
                format!(
                    "{} define{} none of that name",
                    libs.iter()
                        .map(|l| l.path.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", "),
                    if libs.len() == 1 { "s" } else { "" }
                )
            };
            return Err(ImportError::at(
                path,
                format!("line {line}"),
                format!("usemtl '{name}': no such material ({known})"),
            ));
        }
    }

    let load_options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, materials) = tobj::load_obj_buf(
        &mut Cursor::new(text.as_bytes()),
        &load_options,
        |p: &Path| match libs.iter().find(|l| Path::new(&l.name) == p) {
            Some(l) => tobj::load_mtl_buf(&mut Cursor::new(l.text.as_bytes())),
            None => Err(tobj::LoadError::OpenFileFailed),
        },
    )
    .map_err(|e| ImportError::whole(path, format!("OBJ reader: {e}")))?;
    let materials = materials.map_err(|e| ImportError::whole(path, format!("MTL reader: {e}")))?;
    // tobj appends each mtllib's materials in order, as `libs` holds them.
    let scanned: Vec<(&MtlLib, &MtlInfo)> = libs
        .iter()
        .flat_map(|l| l.materials.iter().map(move |m| (l, m)))
        .collect();
    if scanned.len() != materials.len() {
        return Err(ImportError::whole(
            path,
            format!(
                "MTL reader found {} materials where the check found {}",
                materials.len(),
                scanned.len()
            ),
        ));
    }

    let mut raw = RawModel::default();
    // tobj material index → index in raw.materials, built on first use.
    let mut slot: Vec<Option<u32>> = vec![None; materials.len()];
    let mut default_slot: Option<u32> = None;
    for model in &models {
        let mesh = &model.mesh;
        let n = mesh.positions.len() / 3;
        if mesh.indices.is_empty() {
            continue;
        }
        let material = match mesh.material_id {
            Some(k) if k < materials.len() => match slot[k] {
                Some(s) => s,
                None => {
                    let (lib, info) = scanned[k];
                    let m = build_material(&materials[k], lib, info)?;
                    raw.materials.push(m);
                    let s = raw.materials.len() as u32 - 1;
                    slot[k] = Some(s);
                    s
                }
            },
            _ => *default_slot.get_or_insert_with(|| {
                raw.materials
                    .push(RawMaterial::plain("default", DEFAULT_GREY));
                raw.materials.len() as u32 - 1
            }),
        };
        let base = raw.positions.len() as u32;
        let has_normals = mesh.normals.len() == 3 * n;
        let has_uvs = mesh.texcoords.len() == 2 * n;
        for i in 0..n {
            raw.positions
                .push(Vec3::from_slice(&mesh.positions[3 * i..3 * i + 3]));
            raw.normals.push(if has_normals {
                Vec3::from_slice(&mesh.normals[3 * i..3 * i + 3])
            } else {
                Vec3::ZERO
            });
            raw.uvs.push(if has_uvs {
                [mesh.texcoords[2 * i], 1.0 - mesh.texcoords[2 * i + 1]]
            } else {
                [0.0, 0.0]
            });
        }
        for t in mesh.indices.chunks_exact(3) {
            raw.triangles.push([base + t[0], base + t[1], base + t[2]]);
            raw.material_of.push(material);
        }
    }
    Ok(raw)
}

/// Reads a text file; `referenced` is (line, what) of the reference in `file` that names it.
fn read_text(
    p: &Path,
    file: &Path,
    referenced: Option<(usize, &str)>,
) -> Result<String, ImportError> {
    let bytes = match referenced {
        None => read_model_file(p)?,
        Some((line, what)) => read_referenced(
            p,
            file,
            &format!("line {line}: {what}"),
            sylva_core::limits::TEXT_FILE_BYTES,
        )?,
    };
    String::from_utf8(bytes).map_err(|e| {
        ImportError::whole(
            p,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

/// `dir/name` (`name` as `file` wrote it, `what` the reference for errors), also trying `\`
/// as a separator (files written on Windows). Refused when it lies outside `folder`, the
/// model's folder (the OBJ's; `dir` is inside it): a model must not read /etc/passwd. The
/// same rule as glTF's ([`sylva_core::resolve_inside`]).
fn resolve(
    folder: &Path,
    dir: &Path,
    name: &str,
    file: &Path,
    what: &str,
) -> Result<PathBuf, ImportError> {
    let mut name = name.to_string();
    if !dir.join(&name).exists() && name.contains('\\') {
        let slashed = name.replace('\\', "/");
        if dir.join(&slashed).exists() {
            name = slashed;
        }
    }
    // Checked from the model's folder, so an MTL file in a subfolder may name `../tex.png`.
    let from_folder = dir.strip_prefix(folder).unwrap_or(dir).join(&name);
    match sylva_core::resolve_inside(folder, &from_folder.to_string_lossy(), file) {
        Ok(_) => Ok(dir.join(&name)),
        Err(sylva_core::InputError::OutsideFolder { dir: folder, .. }) => Err(ImportError::at(
            file,
            what,
            format!(
                "lies outside the model's folder {}: only files inside it are read",
                folder.display()
            ),
        )),
        Err(e) => Err(ImportError::at(file, what, e.problem())),
    }
}

// ---------- the line-by-line check ----------

#[derive(Debug, Default)]
struct ObjScan {
    mtllibs: Vec<(usize, String)>,
    usemtl: Vec<(usize, String)>,
}

/// The rest of `line` after its first word, trimmed (names may hold spaces).
fn rest(line: &str) -> &str {
    line.trim_start()
        .split_once(char::is_whitespace)
        .map(|(_, r)| r.trim())
        .unwrap_or("")
}

fn parse_f32(tok: &str, file: &Path, line: usize, what: &str) -> Result<f32, ImportError> {
    let v: f32 = tok.parse().map_err(|_| {
        ImportError::at(
            file,
            format!("line {line}"),
            format!("bad number '{tok}' in {what}"),
        )
    })?;
    if !v.is_finite() {
        return Err(ImportError::at(
            file,
            format!("line {line}"),
            format!("{what} has a non-finite number '{tok}'"),
        ));
    }
    Ok(v)
}

/// Checks every statement tobj will read; returns the material references. Allocation-free
/// per line: a model has millions of them.
fn scan_obj(text: &str, file: &Path) -> Result<ObjScan, ImportError> {
    // Absolute indices may point at vertices defined later: count them all first.
    let (mut nv, mut nvt, mut nvn) = (0usize, 0usize, 0usize);
    for line in text.lines() {
        match line.split_whitespace().next() {
            Some("v") => nv += 1,
            Some("vt") => nvt += 1,
            Some("vn") => nvn += 1,
            _ => {}
        }
    }
    let totals = [nv, nvt, nvn];
    let mut so_far = [0usize; 3];
    let mut scan = ObjScan::default();
    for (k, line) in text.lines().enumerate() {
        let l = k + 1;
        let at = |m: String| ImportError::at(file, format!("line {l}"), m);
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        match key {
            "v" => {
                // x y z, x y z w, or x y z r g b.
                let mut vals = [0f32; 7];
                let mut n = 0;
                for tok in words {
                    if n == vals.len() {
                        n += 1;
                        break;
                    }
                    vals[n] = parse_f32(tok, file, l, "vertex")?;
                    n += 1;
                }
                if !matches!(n, 3 | 4 | 6) {
                    return Err(at(format!(
                        "a vertex needs 3 coordinates (then a w or an r g b colour), got {n} values"
                    )));
                }
                if n == 4
                    && (vals[3] == 0.0 || !vals[..3].iter().all(|x| (x / vals[3]).is_finite()))
                {
                    return Err(at(format!(
                        "vertex weight w = {} makes x/w, y/w, z/w not finite",
                        vals[3]
                    )));
                }
                so_far[0] += 1;
            }
            "vt" | "vn" => {
                let (what, range) = if key == "vt" {
                    ("texture coordinate", 2..=3)
                } else {
                    ("normal", 3..=3)
                };
                let mut n = 0;
                for tok in words {
                    parse_f32(tok, file, l, what)?;
                    n += 1;
                }
                if !range.contains(&n) {
                    return Err(at(if key == "vt" {
                        format!("a texture coordinate needs u and v, got {n} values")
                    } else {
                        format!("a normal needs 3 numbers, got {n}")
                    }));
                }
                so_far[if key == "vt" { 1 } else { 2 }] += 1;
            }
            "f" => {
                let mut n = 0;
                let mut uses_vt = None;
                for tok in words {
                    n += 1;
                    let has_vt = check_face_vertex(tok, &totals, &so_far).map_err(at)?;
                    if *uses_vt.get_or_insert(has_vt) != has_vt {
                        return Err(at(
                            "face mixes vertices with and without texture coordinates".into(),
                        ));
                    }
                }
                if n < 3 {
                    return Err(at(format!("a face needs at least 3 vertices, got {n}")));
                }
            }
            "mtllib" | "usemtl" => {
                let name = rest(line);
                if name.is_empty() {
                    return Err(at(format!("{key} needs a name")));
                }
                let list = if key == "mtllib" {
                    &mut scan.mtllibs
                } else {
                    &mut scan.usemtl
                };
                list.push((l, name.to_string()));
            }
            // Points, lines, groups, smoothing and comments carry no surface or are free text.
            _ => {}
        }
    }
    Ok(scan)
}

/// Checks one face vertex (`v`, `v/vt`, `v//vn`, `v/vt/vn`) against the vertices, texture
/// coordinates and normals defined in the file (`totals`) and before this line (`so_far`,
/// for negative indices). Returns whether it has a texture coordinate.
fn check_face_vertex(tok: &str, totals: &[usize; 3], so_far: &[usize; 3]) -> Result<bool, String> {
    const WHAT: [[&str; 2]; 3] = [
        ["vertex", "vertices"],
        ["texture coordinate", "texture coordinates"],
        ["normal", "normals"],
    ];
    let mut has_vt = false;
    for (p, part) in tok.split('/').enumerate() {
        if p > 2 || (p == 0 && part.is_empty()) {
            return Err(format!(
                "bad face vertex '{tok}' (expected v, v/vt, v//vn or v/vt/vn)"
            ));
        }
        if part.is_empty() {
            continue;
        }
        has_vt |= p == 1;
        let i: i64 = part.parse().map_err(|_| {
            format!("bad face index '{part}' in '{tok}' (an integer ≠ 0 is expected)")
        })?;
        // Negative indices count back from the last one defined so far.
        let (resolved, defined) = if i < 0 {
            (so_far[p] as i64 + i + 1, so_far[p])
        } else {
            (i, totals[p])
        };
        if i == 0 || resolved < 1 || resolved > defined as i64 {
            return Err(format!(
                "face index {i} in '{tok}' is out of range: {defined} {} defined{}",
                if defined == 1 {
                    format!("{} is", WHAT[p][0])
                } else {
                    format!("{} are", WHAT[p][1])
                },
                if i < 0 { " before this line" } else { "" }
            ));
        }
    }
    Ok(has_vt)
}

#[derive(Debug)]
struct MtlLib {
    /// As the mtllib line wrote it.
    name: String,
    /// The model's folder (the OBJ's), where its textures must lie.
    folder: PathBuf,
    path: PathBuf,
    text: String,
    materials: Vec<MtlInfo>,
}

/// Where a material's statements are, for errors.
#[derive(Debug)]
struct MtlInfo {
    name: String,
    line: usize,
    map_kd_line: Option<usize>,
    map_d_line: Option<usize>,
}

/// Checks the statements tobj reads from an MTL file.
fn scan_mtl(text: &str, file: &Path) -> Result<Vec<MtlInfo>, ImportError> {
    let mut out: Vec<MtlInfo> = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let l = k + 1;
        let at = |m: String| ImportError::at(file, format!("line {l}"), m);
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let args: Vec<&str> = words.collect();
        let need_material = |out: &Vec<MtlInfo>| {
            if out.is_empty() {
                Err(at(format!("'{key}' before any newmtl")))
            } else {
                Ok(())
            }
        };
        match key {
            "newmtl" => {
                let name = rest(line);
                if name.is_empty() {
                    return Err(at("newmtl needs a name".into()));
                }
                out.push(MtlInfo {
                    name: name.to_string(),
                    line: l,
                    map_kd_line: None,
                    map_d_line: None,
                });
            }
            "Ka" | "Kd" | "Ks" | "Ke" => {
                need_material(&out)?;
                if args.len() != 3 {
                    return Err(at(format!(
                        "{key} needs 3 numbers (r g b), got {}",
                        args.len()
                    )));
                }
                for tok in &args {
                    let v = parse_f32(tok, file, l, key)?;
                    if v < 0.0 {
                        return Err(at(format!("{key} component {v} is negative")));
                    }
                }
            }
            "d" | "Ns" | "Ni" => {
                need_material(&out)?;
                match args.first() {
                    Some(tok) => {
                        parse_f32(tok, file, l, key)?;
                    }
                    None => return Err(at(format!("{key} needs a number"))),
                }
            }
            k if k.starts_with("map_") || k == "bump" || k == "disp" || k == "decal" => {
                need_material(&out)?;
                if rest(line).is_empty() {
                    return Err(at(format!("{key} needs a file name")));
                }
                let m = out.last_mut().expect("checked");
                if key == "map_Kd" {
                    m.map_kd_line = Some(l);
                } else if key == "map_d" {
                    m.map_d_line = Some(l);
                }
            }
            _ => {}
        }
    }
    Ok(out)
}

/// A texture statement's options and file name: `-clamp on -s 1 1 1 leaf.png`.
struct TextureRef {
    file: String,
    clamp: bool,
}

fn parse_texture_ref(arg: &str) -> TextureRef {
    let toks: Vec<&str> = arg.split_whitespace().collect();
    let mut i = 0;
    let mut clamp = false;
    while i < toks.len() && toks[i].starts_with('-') && toks[i].len() > 1 {
        let opt = toks[i];
        i += 1;
        match opt {
            "-o" | "-s" | "-t" => {
                // One to three numbers.
                let mut n = 0;
                while n < 3 && i < toks.len() && toks[i].parse::<f32>().is_ok() {
                    i += 1;
                    n += 1;
                }
            }
            "-mm" => i += 2,
            "-clamp" => {
                clamp = toks.get(i).is_some_and(|v| v.eq_ignore_ascii_case("on"));
                i += 1;
            }
            // -blendu -blendv -boost -bm -cc -imfchan -texres -type: one value each.
            _ => i += 1,
        }
    }
    TextureRef {
        file: toks.get(i..).unwrap_or_default().join(" "),
        clamp,
    }
}

fn build_material(
    m: &tobj::Material,
    lib: &MtlLib,
    info: &MtlInfo,
) -> Result<RawMaterial, ImportError> {
    let dir = lib.path.parent().unwrap_or(Path::new(""));
    let kd = m.diffuse;
    let mut raw = RawMaterial::plain(m.name.clone(), kd.unwrap_or(DEFAULT_GREY));

    // Loads a map; returns the texture, whether the image had alpha, and its element name.
    let load_map = |arg: &str, key: &str, line: Option<usize>| {
        let r = parse_texture_ref(arg);
        let what = format!("line {}: {key} '{}'", line.unwrap_or(info.line), r.file);
        if r.file.is_empty() {
            return Err(ImportError::at(&lib.path, what, "no file name"));
        }
        let p = resolve(&lib.folder, dir, &r.file, &lib.path, &what)?;
        let bytes = read_referenced(&p, &lib.path, &what, sylva_core::limits::MODEL_FILE_BYTES)?;
        let (img, has_alpha) = decode_image_with_alpha(&bytes, &lib.path, &what)?;
        let wrap = if r.clamp { Wrap::Clamp } else { Wrap::Repeat };
        Ok((to_texture(&img, wrap), has_alpha))
    };

    let diffuse = match &m.diffuse_texture {
        Some(arg) => Some(load_map(arg, "map_Kd", info.map_kd_line)?),
        None => None,
    };
    let coverage = match &m.dissolve_texture {
        Some(arg) => Some(load_map(arg, "map_d", info.map_d_line)?),
        None => None,
    };
    let mut texture: Option<Texture> = match (diffuse, &coverage) {
        (Some((mut t, has_alpha)), _) => {
            // MTL multiplies the map by Kd; a missing Kd leaves the map as it is.
            tint(&mut t.pixels, kd.unwrap_or([1.0; 3]));
            raw.alpha_mask = has_alpha && t.pixels.iter().any(|p| !sylva_geom::is_opaque(*p));
            Some(t)
        }
        (None, Some((d, _))) => {
            // Only a coverage map: the colour is Kd everywhere.
            let c = raw.color.map(sylva_core::colour::linear_to_srgb8);
            Some(Texture::new(
                d.width,
                d.height,
                vec![[c[0], c[1], c[2], 255]; d.pixels.len()],
                d.wrap,
            ))
        }
        (None, None) => None,
    };
    if let (Some(t), Some((d, d_has_alpha))) = (&mut texture, coverage) {
        // Coverage is the map's alpha, or its luminance when it has none; sampled at the
        // colour texture's texel centres (nearest) when the sizes differ.
        for y in 0..t.height {
            for x in 0..t.width {
                let dx = (x as u64 * d.width as u64 / t.width as u64) as u32;
                let dy = (y as u64 * d.height as u64 / t.height as u64) as u32;
                let p = d.texel(dx, dy);
                let a = if d_has_alpha {
                    p[3]
                } else {
                    let lum = 0.2126 * p[0] as f32 + 0.7152 * p[1] as f32 + 0.0722 * p[2] as f32;
                    lum.round().clamp(0.0, 255.0) as u8
                };
                t.pixels[(y * t.width + x) as usize][3] = a;
            }
        }
        raw.alpha_mask = true;
    }
    // With a texture, the material's base colour becomes the texture's mean (see `finish`).
    raw.texture = texture;
    Ok(raw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_options_are_skipped() {
        let r = parse_texture_ref("-clamp on -s 1 2 3 -bm 0.5 my leaf.png");
        assert_eq!(r.file, "my leaf.png");
        assert!(r.clamp);
        let r = parse_texture_ref("-o 0.5 bark.jpg");
        assert_eq!(r.file, "bark.jpg");
        assert!(!r.clamp);
        assert_eq!(parse_texture_ref("leaf.png").file, "leaf.png");
    }
}
