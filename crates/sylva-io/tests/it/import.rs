//! Mesh import: round trips through small OBJ, glTF and GLB files written here, and every
//! kind of bad input giving an error that names the file, the line or element, and the
//! problem.

use base64::Engine;
use glam::Vec3;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use sylva_geom::{MaterialKind, Model, ModelOrigin};
use sylva_io::import::{load_mesh_file, ImportOptions, UpAxis};
use sylva_scene::{SceneDesc, SceneStats};

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    if let Some(parent) = p.parent() {
        std::fs::create_dir_all(parent).unwrap();
    }
    std::fs::write(&p, bytes).unwrap();
    p
}

fn png(width: u32, height: u32, f: impl Fn(u32, u32) -> [u8; 4]) -> Vec<u8> {
    let img = image::RgbaImage::from_fn(width, height, |x, y| image::Rgba(f(x, y)));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn grey_png(width: u32, height: u32, f: impl Fn(u32, u32) -> u8) -> Vec<u8> {
    let img = image::GrayImage::from_fn(width, height, |x, y| image::Luma([f(x, y)]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn load(p: &Path) -> Model {
    load_mesh_file(p, &ImportOptions::default()).unwrap_or_else(|e| panic!("{e}"))
}

fn load_err(p: &Path, opts: &ImportOptions) -> String {
    match load_mesh_file(p, opts) {
        Ok(m) => panic!("{} loaded ({} triangles)", p.display(), m.triangle_count()),
        Err(e) => e.to_string(),
    }
}

fn material<'a>(m: &'a Model, name: &str) -> (u8, &'a sylva_geom::Material) {
    let k = m
        .materials
        .iter()
        .position(|x| x.name == name)
        .unwrap_or_else(|| panic!("no material {name}"));
    (k as u8, &m.materials[k])
}

fn pos(m: &Model, i: u32) -> Vec3 {
    Vec3::from_array(m.mesh.positions[i as usize])
}

// ---------- OBJ ----------

/// A bark quad and a leaf triangle; the leaf texture is opaque in its top row only.
const TWO_MATERIALS_OBJ: &str = "\
# two materials
mtllib mat/tree.mtl
v 0 0 0
v 1 0 0
v 1 0 -1
v 0 0 -1
v 0 1 0
v 1 1 0
v 0 2 0
vt 0 0.1
vt 1 0.1
vt 0.9 0.9
g trunk
usemtl Bark
f 1 2 3 4
usemtl LeafMat
f 5/1 6/2 7/3
";

const TWO_MATERIALS_MTL: &str = "\
newmtl Bark
Kd 0.3 0.2 0.1
newmtl LeafMat
Kd 1 1 1
map_Kd leaf.png
";

fn leaf_png() -> Vec<u8> {
    // 4×4; row 0 (the image's top) opaque green, the rest transparent.
    png(4, 4, |_, y| {
        if y == 0 {
            [40, 160, 30, 255]
        } else {
            [40, 160, 30, 0]
        }
    })
}

fn write_two_materials(dir: &Path) -> PathBuf {
    write(dir, "mat/tree.mtl", TWO_MATERIALS_MTL);
    write(dir, "mat/leaf.png", leaf_png());
    write(dir, "tree.obj", TWO_MATERIALS_OBJ)
}

#[test]
fn obj_two_materials_leaf_from_texture_alpha_and_wood() {
    let dir = tempfile::tempdir().unwrap();
    let m = load(&write_two_materials(dir.path()));
    assert_eq!(m.name, "tree");
    assert_eq!(m.triangle_count(), 3, "quad triangulated + one triangle");
    assert_eq!(m.materials.len(), 2);
    let (bark_id, bark) = material(&m, "Bark");
    assert_eq!(bark.kind, MaterialKind::Wood);
    assert!(!bark.two_sided);
    assert!(bark.texture.is_none());
    assert_eq!(bark.base_color, [0.3, 0.2, 0.1]);
    assert_eq!(m.mesh.triangles_with_material(bark_id), 2);

    let (leaf_id, leaf) = material(&m, "LeafMat");
    assert_eq!(leaf.kind, MaterialKind::Leaf);
    assert!(leaf.two_sided, "leaves are two-sided");
    let t = leaf.texture.as_ref().expect("leaf texture");
    assert_eq!((t.width, t.height), (4, 4));
    assert_eq!(m.mesh.triangles_with_material(leaf_id), 1);
    // Kd 1 leaves the texture as it is; the base colour is its mean opaque colour.
    assert_eq!(t.texel(2, 0), [40, 160, 30, 255]);
    let lin = sylva_core::colour::srgb_to_linear(160.0 / 255.0);
    assert!((leaf.base_color[1] - lin).abs() < 1e-6);

    // The leaf vertex with vt (0.9, 0.9) lies near the top of the image: sylva's v runs
    // down the image, so its uv is (0.9, 0.1), where the texture is opaque.
    let tri = m.mesh.indices[m
        .mesh
        .material_ids
        .iter()
        .position(|&id| id == leaf_id)
        .unwrap()];
    let top = tri
        .iter()
        .copied()
        .find(|&i| pos(&m, i) == Vec3::new(0.0, 2.0, 0.0))
        .unwrap();
    let uv = m.mesh.uvs[top as usize];
    assert!(
        (uv[0] - 0.9).abs() < 1e-6 && (uv[1] - 0.1).abs() < 1e-6,
        "{uv:?}"
    );
    assert!(t.alpha(uv[0], uv[1]) >= 0.5);
    let bottom = tri
        .iter()
        .copied()
        .find(|&i| pos(&m, i) == Vec3::new(0.0, 1.0, 0.0))
        .unwrap();
    let uv = m.mesh.uvs[bottom as usize];
    assert!(
        t.alpha(uv[0], uv[1]) < 0.5,
        "vt (0, 0.1) is in the image's bottom row"
    );

    // No normals in the file: computed from the winding. The bark quad (1,2,3,4) turns
    // counter-clockwise seen from +y; the leaf triangle from +z.
    for (k, t) in m.mesh.indices.iter().enumerate() {
        let want = if m.mesh.material_ids[k] == bark_id {
            Vec3::Y
        } else {
            Vec3::Z
        };
        for &i in t {
            let n = Vec3::from_array(m.mesh.normals[i as usize]);
            assert!((n - want).length() < 1e-6, "triangle {k}: {n}");
        }
    }
    assert_eq!(m.bounds.max, Vec3::new(1.0, 2.0, 0.0));
}

#[test]
fn obj_map_d_makes_a_leaf_and_kd_tints_the_texture() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Opaque RGB colour map; coverage from a grey map_d (left column black = cut).
    write(d, "white.png", png(2, 1, |_, _| [255, 255, 255, 255]));
    write(
        d,
        "cut.png",
        grey_png(2, 1, |x, _| if x == 0 { 0 } else { 255 }),
    );
    write(
        d,
        "m.mtl",
        "newmtl frond\nKd 0.5 1 1\nmap_Kd white.png\nmap_d -clamp on cut.png\nnewmtl stem\nKd 0.2 0.1 0.05\nmap_Kd white.png\n",
    );
    let p = write(
        d,
        "fern.obj",
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nusemtl frond\nf 1/1/1 2/2/1 3/3/1\nusemtl stem\nf -3/-3/-1 -2/-2/-1 -1/-1/-1\n",
    );
    let m = load(&p);
    let (_, frond) = material(&m, "frond");
    assert_eq!(frond.kind, MaterialKind::Leaf);
    let t = frond.texture.as_ref().unwrap();
    assert_eq!(t.texel(0, 0)[3], 0);
    assert_eq!(t.texel(1, 0)[3], 255);
    // Kd multiplies in linear space: red 1.0 × 0.5 → sRGB 188.
    assert_eq!(&t.texel(1, 0)[..3], &[188, 255, 255]);
    // An opaque texture without map_d is wood (its alpha carries no mask).
    let (_, stem) = material(&m, "stem");
    assert_eq!(stem.kind, MaterialKind::Wood);
    // Normals from the file are kept.
    assert!(m.mesh.normals.iter().all(|n| *n == [0.0, 0.0, 1.0]));
}

#[test]
fn obj_polygons_are_triangulated_and_negative_indices_resolve() {
    let dir = tempfile::tempdir().unwrap();
    // A pentagon with relative indices: three triangles, no materials → one default wood.
    let p = write(
        dir.path(),
        "penta.obj",
        "v 0 0 0\nv 2 0 0\nv 3 0 -1\nv 1 0 -2\nv -1 0 -1\nf -5 -4 -3 -2 -1\n",
    );
    let m = load(&p);
    assert_eq!(m.triangle_count(), 3);
    assert_eq!(m.materials.len(), 1);
    assert_eq!(m.materials[0].kind, MaterialKind::Wood);
    // The fan covers the pentagon: total area equals the shoelace area.
    let area: f32 = m
        .mesh
        .indices
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| pos(&m, i));
            0.5 * (b - a).cross(c - a).length()
        })
        .sum();
    let xz = [
        (0.0f32, 0.0f32),
        (2.0, 0.0),
        (3.0, -1.0),
        (1.0, -2.0),
        (-1.0, -1.0),
    ];
    let shoelace = 0.5
        * (0..5)
            .map(|i| {
                let (a, b) = (xz[i], xz[(i + 1) % 5]);
                a.0 * b.1 - b.0 * a.1
            })
            .sum::<f32>()
            .abs();
    assert!((area - shoelace).abs() < 1e-5, "{area} vs {shoelace}");
}

#[test]
fn name_patterns_override_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_two_materials(dir.path());
    let opts = ImportOptions {
        leaf_materials: vec!["BARK".into()],
        wood_materials: vec!["*leaf*".into()],
        ..Default::default()
    };
    let m = load_mesh_file(&p, &opts).unwrap();
    assert_eq!(material(&m, "Bark").1.kind, MaterialKind::Leaf);
    assert!(material(&m, "Bark").1.two_sided);
    assert_eq!(material(&m, "LeafMat").1.kind, MaterialKind::Wood);
    assert!(!material(&m, "LeafMat").1.two_sided);

    // A pattern matching nothing is most likely a typo.
    let opts = ImportOptions {
        leaf_materials: vec!["*leav*".into()],
        ..Default::default()
    };
    let e = load_err(&p, &opts);
    assert!(
        e.contains("tree.obj")
            && e.contains("'*leav*' matches no material")
            && e.contains("'LeafMat'"),
        "{e}"
    );
    // A material in both lists.
    let opts = ImportOptions {
        leaf_materials: vec!["*".into()],
        wood_materials: vec!["bark".into()],
        ..Default::default()
    };
    let e = load_err(&p, &opts);
    assert!(
        e.contains("'Bark' matches leaf pattern '*' and wood pattern 'bark'"),
        "{e}"
    );
}

#[test]
fn scale_and_up_axis() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "z.obj", "v 0 0 0\nv 1 0 0\nv 0 0 3\nf 1 2 3\n");
    let opts = ImportOptions {
        scale: 0.5,
        up: UpAxis::Z,
        ..Default::default()
    };
    let m = load_mesh_file(&p, &opts).unwrap();
    // z-up (0, 0, 3) is y-up (0, 3, 0), then halved.
    assert_eq!(m.mesh.positions[2], [0.0, 1.5, 0.0]);
    assert_eq!(m.bounds.max, Vec3::new(0.5, 1.5, 0.0));
    let opts = ImportOptions {
        scale: -1.0,
        ..Default::default()
    };
    assert!(load_err(&p, &opts).contains("scale must be a positive number"));
}

#[test]
fn too_many_materials_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut mtl = String::new();
    let mut obj = String::from("mtllib many.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for k in 0..257 {
        mtl.push_str(&format!("newmtl m{k}\nKd 0.5 0.5 0.5\n"));
        obj.push_str(&format!("usemtl m{k}\nf 1 2 3\n"));
    }
    write(dir.path(), "many.mtl", &mtl);
    let p = write(dir.path(), "many.obj", &obj);
    let e = load_err(&p, &ImportOptions::default());
    assert!(
        e.contains("257 materials are used") && e.contains("at most 256"),
        "{e}"
    );
    // 256 is fine.
    let cut = obj.rfind("usemtl m256").unwrap();
    let p = write(dir.path(), "many.obj", &obj[..cut]);
    assert_eq!(load(&p).materials.len(), 256);
}

/// Writes `obj` (and the two-material MTL and texture) and returns the error text.
fn obj_error(obj: &str) -> (String, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "mat/tree.mtl", TWO_MATERIALS_MTL);
    write(dir.path(), "mat/leaf.png", leaf_png());
    let p = write(dir.path(), "bad.obj", obj);
    let e = load_err(&p, &ImportOptions::default());
    // Keep the directory alive until the error is read.
    drop(dir);
    (e, p)
}

#[test]
fn obj_errors_name_file_line_and_problem() {
    let v3 = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let cases: Vec<(String, &str, &str)> = vec![
        (
            format!("{v3}v 1 abc 3\nf 1 2 3\n"),
            "line 4",
            "bad number 'abc' in vertex",
        ),
        (format!("{v3}f 1 x 3\n"), "line 4", "bad face index 'x'"),
        (
            format!("{v3}f 1 2 9\n"),
            "line 4",
            "face index 9 in '9' is out of range: 3 vertices are defined",
        ),
        (format!("{v3}f 1 2 -4\n"), "line 4", "face index -4"),
        (format!("{v3}f 1 2 0\n"), "line 4", "face index 0"),
        (
            format!("{v3}f 1/5 2/1 3/1\nvt 0 0\n"),
            "line 4",
            "face index 5 in '1/5' is out of range: 1 texture coordinate is defined",
        ),
        (
            format!("v nan 0 0\n{v3}f 1 2 3\n"),
            "line 1",
            "non-finite number 'nan'",
        ),
        (
            format!("{v3}v 0 inf 0\nf 1 2 3\n"),
            "line 4",
            "non-finite number 'inf'",
        ),
        (
            format!("{v3}vn 0 1\nf 1 2 3\n"),
            "line 4",
            "a normal needs 3 numbers",
        ),
        (
            format!("{v3}f 1 2\n"),
            "line 4",
            "a face needs at least 3 vertices",
        ),
        (
            format!("{v3}usemtl Nope\nf 1 2 3\n"),
            "line 4",
            "usemtl 'Nope': no such material (the file has no mtllib)",
        ),
        (
            format!("mtllib mat/tree.mtl\n{v3}usemtl Nope\nf 1 2 3\n"),
            "line 5",
            "usemtl 'Nope': no such material",
        ),
        (
            format!("mtllib missing.mtl\n{v3}f 1 2 3\n"),
            "line 1",
            "mtllib 'missing.mtl': cannot read",
        ),
    ];
    for (obj, line, want) in cases {
        let (e, p) = obj_error(&obj);
        assert!(
            e.starts_with(&format!("{}: {line}: ", p.display())),
            "{obj:?}: {e}"
        );
        assert!(e.contains(want), "{obj:?}: {e}");
    }
    // Vertices but no faces.
    let (e, p) = obj_error(&format!("{v3}l 1 2\n"));
    assert!(
        e.starts_with(&p.display().to_string())
            && e.contains("the mesh is empty: it has no triangles"),
        "{e}"
    );
}

#[test]
fn mtl_and_texture_errors_name_the_mtl_file_and_line() {
    let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n";
    let cases = [
        ("newmtl a\nKd 1 x 1\n", "line 2", "bad number 'x' in Kd"),
        ("Kd 1 1 1\nnewmtl a\n", "line 1", "'Kd' before any newmtl"),
        (
            "newmtl a\nmap_Kd missing.png\n",
            "line 2: map_Kd 'missing.png'",
            "cannot read",
        ),
        (
            "newmtl a\nmap_d -clamp on nothere.png\n",
            "line 2: map_d 'nothere.png'",
            "cannot read",
        ),
        (
            "newmtl a\nmap_Kd corrupt.png\n",
            "line 2: map_Kd 'corrupt.png'",
            "cannot decode image",
        ),
    ];
    for (mtl, element, want) in cases {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "corrupt.png",
            b"\x89PNG\r\n\x1a\nthis is not a png",
        );
        let mtl_path = write(dir.path(), "m.mtl", mtl);
        let p = write(dir.path(), "t.obj", obj);
        let e = load_err(&p, &ImportOptions::default());
        assert!(
            e.starts_with(&format!("{}: {element}: ", mtl_path.display())),
            "{mtl:?}: {e}"
        );
        assert!(e.contains(want), "{mtl:?}: {e}");
    }
}

#[test]
fn unknown_extension_and_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "tree.fbx", "x");
    assert!(load_err(&p, &ImportOptions::default()).contains("unknown mesh format '.fbx'"));
    let p = dir.path().join("gone.obj");
    let e = load_err(&p, &ImportOptions::default());
    assert!(
        e.starts_with(&p.display().to_string()) && e.contains("cannot read"),
        "{e}"
    );
}

// ---------- glTF ----------

/// A glTF document with one binary buffer, built up in tests.
struct Doc {
    json: Value,
    bin: Vec<u8>,
}

impl Doc {
    fn new() -> Doc {
        Doc {
            json: json!({
                "asset": {"version": "2.0"},
                "bufferViews": [], "accessors": [], "buffers": [],
            }),
            bin: Vec::new(),
        }
    }

    fn push(&mut self, key: &str, v: Value) -> usize {
        let a = self.json[key].as_array_mut().unwrap();
        a.push(v);
        a.len() - 1
    }

    fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let off = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.push(
            "bufferViews",
            json!({"buffer": 0, "byteOffset": off, "byteLength": bytes.len()}),
        )
    }

    fn floats(&mut self, data: &[f32], ty: &str) -> usize {
        let n = match ty {
            "VEC2" => 2,
            _ => 3,
        };
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let v = self.view(&bytes);
        let mut acc =
            json!({"bufferView": v, "componentType": 5126, "count": data.len() / n, "type": ty});
        if n == 3 {
            let mut min = [f32::INFINITY; 3];
            let mut max = [f32::NEG_INFINITY; 3];
            for p in data.chunks(3) {
                for c in 0..3 {
                    min[c] = min[c].min(p[c]);
                    max[c] = max[c].max(p[c]);
                }
            }
            acc["min"] = json!(min);
            acc["max"] = json!(max);
        }
        self.push("accessors", acc)
    }

    fn indices(&mut self, data: &[u16]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let v = self.view(&bytes);
        self.push(
            "accessors",
            json!({"bufferView": v, "componentType": 5123, "count": data.len(), "type": "SCALAR"}),
        )
    }

    fn buffer_json(&self, uri: Option<String>) -> Value {
        let mut b = json!({"byteLength": self.bin.len()});
        if let Some(u) = uri {
            b["uri"] = json!(u);
        }
        b
    }

    /// `.gltf` with the buffer as a data URI.
    fn write_data_uri(mut self, dir: &Path, name: &str) -> PathBuf {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&self.bin)
        );
        self.json["buffers"] = json!([self.buffer_json(Some(uri))]);
        write(dir, name, serde_json::to_string_pretty(&self.json).unwrap())
    }

    /// `.gltf` with an external `.bin` beside it.
    fn write_external(mut self, dir: &Path, name: &str, bin_name: &str) -> PathBuf {
        write(dir, bin_name, &self.bin);
        self.json["buffers"] = json!([self.buffer_json(Some(bin_name.replace(' ', "%20")))]);
        write(dir, name, serde_json::to_string_pretty(&self.json).unwrap())
    }

    /// `.glb`: header, JSON chunk, BIN chunk.
    fn write_glb(mut self, dir: &Path, name: &str) -> PathBuf {
        self.json["buffers"] = json!([self.buffer_json(None)]);
        let mut js = serde_json::to_vec(&self.json).unwrap();
        while !js.len().is_multiple_of(4) {
            js.push(b' ');
        }
        let mut bin = self.bin;
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + js.len() + 8 + bin.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(js.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&js);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        write(dir, name, out)
    }
}

/// One triangle (0,0,0), (1,0,0), (0,1,0) with normal +z, placed by a node hierarchy:
/// node 0 translates by (10, 0, 0) and holds node 1 (rotation 90° about z, scale 2) and
/// node 2 (a matrix mirroring x and translating by (0, 5, 0)); node 3 is outside the scene.
fn hierarchy_doc() -> Doc {
    let mut d = Doc::new();
    let p = d.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], "VEC3");
    let n = d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC3");
    let i = d.indices(&[0, 1, 2]);
    let s = std::f32::consts::FRAC_1_SQRT_2;
    d.json["meshes"] =
        json!([{"primitives": [{"attributes": {"POSITION": p, "NORMAL": n}, "indices": i}]}]);
    d.json["nodes"] = json!([
        {"translation": [10.0, 0.0, 0.0], "children": [1, 2]},
        {"rotation": [0.0, 0.0, s, s], "scale": [2.0, 2.0, 2.0], "mesh": 0},
        {"matrix": [-1.0, 0.0, 0.0, 0.0,  0.0, 1.0, 0.0, 0.0,  0.0, 0.0, 1.0, 0.0,  0.0, 5.0, 0.0, 1.0], "mesh": 0},
        {"translation": [100.0, 0.0, 0.0], "mesh": 0}
    ]);
    d.json["scenes"] = json!([{"nodes": [0]}, {"nodes": [3]}]);
    d.json["scene"] = json!(0);
    d
}

fn check_hierarchy(m: &Model) {
    assert_eq!(m.triangle_count(), 2, "node 3 is not in the default scene");
    // By hand: node 1 maps (1,0,0) → S (2,0,0) → R (0,2,0) → T (10,2,0); (0,1,0) → (8,0,0).
    // Node 2 maps (1,0,0) → (-1,5,0) → (9,5,0); (0,1,0) → (10,6,0).
    let tri = |k: usize| m.mesh.indices[k].map(|i| pos(m, i));
    let mut want = [
        vec![
            Vec3::new(10.0, 0.0, 0.0),
            Vec3::new(10.0, 2.0, 0.0),
            Vec3::new(8.0, 0.0, 0.0),
        ],
        vec![
            Vec3::new(10.0, 5.0, 0.0),
            Vec3::new(9.0, 5.0, 0.0),
            Vec3::new(10.0, 6.0, 0.0),
        ],
    ];
    for (k, w) in want.iter_mut().enumerate() {
        let t = tri(k);
        for p in w.iter() {
            assert!(
                t.iter().any(|q| (*q - *p).length() < 1e-5),
                "triangle {k} {t:?} lacks {p}"
            );
        }
        // The stored normal is +z and the winding agrees with it, the mirrored one too.
        let [a, b, c] = t;
        let geometric = (b - a).cross(c - a).normalize();
        for &i in &m.mesh.indices[k] {
            let n = Vec3::from_array(m.mesh.normals[i as usize]);
            assert!((n - Vec3::Z).length() < 1e-5, "{n}");
            assert!(
                geometric.dot(n) > 0.99,
                "triangle {k}: winding {geometric} vs normal {n}"
            );
        }
    }
    assert_eq!(m.materials.len(), 1);
    assert_eq!(
        m.materials[0].kind,
        MaterialKind::Wood,
        "default material: opaque"
    );
}

#[test]
fn gltf_hierarchy_data_uri_external_bin_and_glb_agree() {
    let dir = tempfile::tempdir().unwrap();
    let a = load(&hierarchy_doc().write_data_uri(dir.path(), "a.gltf"));
    let b = load(&hierarchy_doc().write_external(dir.path(), "b.gltf", "b data.bin"));
    let c = load(&hierarchy_doc().write_glb(dir.path(), "c.glb"));
    for m in [&a, &b, &c] {
        check_hierarchy(m);
    }
    assert_eq!(a.mesh.geometry_hash(), b.mesh.geometry_hash());
    assert_eq!(a.mesh.geometry_hash(), c.mesh.geometry_hash());
}

#[test]
fn gltf_without_scenes_uses_root_nodes_and_strips_and_fans_keep_winding() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = Doc::new();
    // A unit square in z = 0 as a strip (0,1,2,3) and as a fan (0,1,3,2).
    let p = d.floats(
        &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0],
        "VEC3",
    );
    let strip = d.indices(&[0, 1, 2, 3]);
    let fan = d.indices(&[0, 1, 3, 2]);
    d.json["meshes"] = json!([{"primitives": [
        {"attributes": {"POSITION": p}, "indices": strip, "mode": 5},
        {"attributes": {"POSITION": p}, "indices": fan, "mode": 6},
        {"attributes": {"POSITION": p}, "mode": 1}
    ]}]);
    d.json["nodes"] = json!([{"mesh": 0}]);
    let m = load(&d.write_data_uri(dir.path(), "s.gltf"));
    assert_eq!(m.triangle_count(), 4, "lines are skipped");
    for t in &m.mesh.indices {
        let [a, b, c] = t.map(|i| pos(&m, i));
        let n = (b - a).cross(c - a);
        assert!((n.normalize() - Vec3::Z).length() < 1e-6, "{n}");
        assert!((n.length() - 1.0).abs() < 1e-6, "each is half the square");
    }
}

/// A textured unit quad whose 4×1 texture has alpha 0, 100, 150, 255 left to right, with
/// the given material JSON (its baseColorTexture is filled in).
fn textured_doc(material: Value) -> Doc {
    let mut d = Doc::new();
    let p = d.floats(
        &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0],
        "VEC3",
    );
    let uv = d.floats(&[0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0], "VEC2");
    let i = d.indices(&[0, 1, 2, 0, 2, 3]);
    let alphas = [0u8, 100, 150, 255];
    let image = png(4, 1, |x, _| [255, 255, 255, alphas[x as usize]]);
    let iv = d.view(&image);
    d.json["images"] = json!([{"bufferView": iv, "mimeType": "image/png"}]);
    d.json["samplers"] = json!([{"wrapS": 33071, "wrapT": 33071}]);
    d.json["textures"] = json!([{"source": 0, "sampler": 0}]);
    let mut mat = material;
    if mat["pbrMetallicRoughness"].is_null() {
        mat["pbrMetallicRoughness"] = json!({});
    }
    mat["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
    d.json["materials"] = json!([mat]);
    d.json["meshes"] = json!([{"primitives": [{"attributes": {"POSITION": p, "TEXCOORD_0": uv}, "indices": i, "material": 0}]}]);
    d.json["nodes"] = json!([{"mesh": 0}]);
    d.json["scenes"] = json!([{"nodes": [0]}]);
    d
}

/// Which of the four texels are opaque by sylva's rule, sampled at texel centres.
fn opaque_texels(m: &Model) -> [bool; 4] {
    let t = m.materials[0].texture.as_ref().expect("texture");
    [0, 1, 2, 3].map(|x| t.alpha((x as f32 + 0.5) / 4.0, 0.5) >= 0.5)
}

#[test]
fn gltf_alpha_modes_and_cutoff() {
    let dir = tempfile::tempdir().unwrap();
    let m = load(&textured_doc(json!({"name": "o"})).write_glb(dir.path(), "opaque.glb"));
    assert_eq!(m.materials[0].kind, MaterialKind::Wood);
    assert_eq!(opaque_texels(&m), [true; 4], "OPAQUE ignores alpha");
    assert_eq!(
        m.materials[0].texture.as_ref().unwrap().wrap,
        sylva_geom::Wrap::Clamp
    );

    let m = load(
        &textured_doc(json!({"alphaMode": "MASK", "alphaCutoff": 0.6}))
            .write_glb(dir.path(), "mask.glb"),
    );
    assert_eq!(m.materials[0].kind, MaterialKind::Leaf);
    assert!(m.materials[0].two_sided);
    // 150/255 = 0.588 < 0.6.
    assert_eq!(opaque_texels(&m), [false, false, false, true]);

    let m = load(
        &textured_doc(json!({"alphaMode": "MASK", "alphaCutoff": 0.3}))
            .write_glb(dir.path(), "mask3.glb"),
    );
    // 100/255 = 0.392 ≥ 0.3.
    assert_eq!(opaque_texels(&m), [false, true, true, true]);

    let m = load(&textured_doc(json!({"alphaMode": "MASK"})).write_glb(dir.path(), "maskdef.glb"));
    assert_eq!(
        opaque_texels(&m),
        [false, false, true, true],
        "default cutoff 0.5"
    );

    let m = load(&textured_doc(json!({"alphaMode": "BLEND"})).write_glb(dir.path(), "blend.glb"));
    assert_eq!(m.materials[0].kind, MaterialKind::Leaf);
    assert_eq!(
        opaque_texels(&m),
        [false, false, true, true],
        "BLEND is a mask at 0.5"
    );

    // The factor's alpha multiplies the texture's: 0.5 × 255/255 reaches the cutoff 0.5,
    // 0.5 × 150/255 does not.
    let m = load(&textured_doc(json!({"alphaMode": "MASK", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 1.0, 1.0, 0.5]}})).write_glb(dir.path(), "factor.glb"));
    assert_eq!(opaque_texels(&m), [false, false, false, true]);
    // The colour factor is multiplied in linear space: white × 0.5 → sRGB 188.
    let t = m.materials[0].texture.as_ref().unwrap();
    assert_eq!(&t.texel(3, 0)[..3], &[188, 255, 255]);
}

#[test]
fn gltf_double_sided_and_diffuse_transmission() {
    let dir = tempfile::tempdir().unwrap();
    let m = load(&textured_doc(json!({"doubleSided": true})).write_glb(dir.path(), "ds.glb"));
    assert_eq!(m.materials[0].kind, MaterialKind::Wood);
    assert!(m.materials[0].two_sided);
    let m = load(&textured_doc(json!({})).write_glb(dir.path(), "ss.glb"));
    assert!(!m.materials[0].two_sided);

    let ext = |f: f64| json!({"extensions": {"KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": f}}});
    let m = load(&textured_doc(ext(0.4)).write_glb(dir.path(), "dt.glb"));
    assert_eq!(
        m.materials[0].kind,
        MaterialKind::Leaf,
        "diffuse transmission makes a leaf"
    );
    assert!(m.materials[0].two_sided);
    assert_eq!(opaque_texels(&m), [true; 4], "still OPAQUE");
    let m = load(&textured_doc(ext(0.0)).write_glb(dir.path(), "dt0.glb"));
    assert_eq!(
        m.materials[0].kind,
        MaterialKind::Wood,
        "factor 0 transmits nothing"
    );
    let e = load_err(
        &textured_doc(ext(1.5)).write_glb(dir.path(), "dtbad.glb"),
        &ImportOptions::default(),
    );
    assert!(
        e.contains(
            "materials[0]: KHR_materials_diffuse_transmission.diffuseTransmissionFactor 1.5"
        ),
        "{e}"
    );

    // Patterns work on glTF material names too.
    let opts = ImportOptions {
        wood_materials: vec!["needle*".into()],
        ..Default::default()
    };
    let mut named = ext(0.4);
    named["name"] = json!("Needles");
    let m = load_mesh_file(&textured_doc(named).write_glb(dir.path(), "n.glb"), &opts).unwrap();
    assert_eq!(m.materials[0].kind, MaterialKind::Wood);
}

#[test]
fn gltf_external_image_and_texture_transform() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = textured_doc(json!({"alphaMode": "MASK"}));
    write(
        dir.path(),
        "tex/leaf.png",
        png(2, 2, |x, y| [x as u8 * 200, y as u8 * 200, 0, 255]),
    );
    d.json["images"] = json!([{"uri": "tex/leaf.png"}]);
    d.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] =
        json!({"KHR_texture_transform": {"offset": [0.5, 0.0], "scale": [0.5, 1.0]}});
    let m = load(&d.write_data_uri(dir.path(), "ext.gltf"));
    let t = m.materials[0].texture.as_ref().unwrap();
    assert_eq!((t.width, t.height), (2, 2));
    assert_eq!(t.texel(1, 0), [200, 0, 0, 255]);
    // uv (1, 0) → (0.5·1 + 0.5, 0) = (1, 0).
    let k = m
        .mesh
        .positions
        .iter()
        .position(|p| *p == [1.0, 0.0, 0.0])
        .unwrap();
    assert_eq!(m.mesh.uvs[k], [1.0, 0.0]);
    let k = m
        .mesh
        .positions
        .iter()
        .position(|p| *p == [0.0, 1.0, 0.0])
        .unwrap();
    assert_eq!(m.mesh.uvs[k], [0.5, 1.0]);
}

#[test]
fn gltf_errors_name_file_element_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let check = |p: &Path, element: &str, want: &str| {
        let e = load_err(p, &ImportOptions::default());
        assert!(
            e.starts_with(&format!("{}: {element}", p.display())),
            "{element}: {e}"
        );
        assert!(e.contains(want), "{want}: {e}");
    };

    let p = write(
        d,
        "syntax.gltf",
        "{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [,]\n}\n",
    );
    check(&p, "line 3, column", "JSON syntax error");

    // Buffer too short: byteLength says 200, the data URI holds fewer.
    let mut doc = hierarchy_doc();
    doc.bin.truncate(40);
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&doc.bin)
    );
    doc.json["buffers"] = json!([{"byteLength": 200, "uri": uri}]);
    let p = write(d, "short.gltf", doc.json.to_string());
    check(&p, "buffers[0]", "byteLength is 200 but 'data:application/octet-stream;ba…' holds only 40 bytes (buffer too short)");

    // A buffer view past its buffer.
    let mut doc = hierarchy_doc();
    doc.json["bufferViews"][0]["byteLength"] = json!(4000);
    let p = doc.write_data_uri(d, "view.gltf");
    check(&p, "bufferViews[0]", "lie outside buffers[0]");

    // An accessor reading past its view.
    let mut doc = hierarchy_doc();
    doc.json["accessors"][0]["count"] = json!(30);
    let p = doc.write_data_uri(d, "acc.gltf");
    check(
        &p,
        "accessors[0] (POSITION of meshes[0].primitives[0])",
        "run past the end of bufferViews[0]",
    );

    // An index past the vertices.
    let mut doc = hierarchy_doc();
    let i = doc.indices(&[0, 1, 7]);
    doc.json["meshes"][0]["primitives"][0]["indices"] = json!(i);
    let p = doc.write_data_uri(d, "index.gltf");
    check(
        &p,
        &format!("accessors[{i}] (indices of meshes[0].primitives[0])"),
        "index 7 at position 2 is out of range: 3 vertices",
    );

    // A NaN position.
    let mut doc = hierarchy_doc();
    doc.bin[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
    let p = doc.write_glb(d, "nan.glb");
    check(
        &p,
        "accessors[0] (POSITION of meshes[0].primitives[0])",
        "element 0",
    );

    // Missing external buffer and image; a corrupt embedded image; a missing GLB chunk.
    let mut doc = hierarchy_doc();
    doc.json["buffers"] = json!([{"byteLength": 80, "uri": "nowhere.bin"}]);
    let p = write(d, "nobin.gltf", doc.json.to_string());
    check(&p, "buffers[0]", "cannot read");
    let mut doc = textured_doc(json!({}));
    doc.json["images"] = json!([{"uri": "gone.png"}]);
    let p = doc.write_data_uri(d, "noimg.gltf");
    check(&p, "images[0] (used by materials[0])", "cannot read");
    let mut doc = textured_doc(json!({}));
    let bad = doc.view(b"\x89PNG\r\n\x1a\nnot really");
    doc.json["images"] = json!([{"bufferView": bad, "mimeType": "image/png"}]);
    let p = doc.write_glb(d, "corrupt.glb");
    check(
        &p,
        "images[0] (used by materials[0])",
        "cannot decode image",
    );
    let mut doc = hierarchy_doc();
    doc.json["buffers"] = json!([{"byteLength": 80}]);
    let p = write(d, "nochunk.gltf", doc.json.to_string());
    check(&p, "buffers[0]", "GLB binary chunk");

    // Structural validation by the gltf crate names the JSON path.
    let mut doc = hierarchy_doc();
    doc.json["nodes"][1]["mesh"] = json!(9);
    let p = doc.write_data_uri(d, "mesh9.gltf");
    check(&p, "nodes[1].mesh", "");

    // A node hierarchy with a cycle.
    let mut doc = hierarchy_doc();
    doc.json["nodes"][1]["children"] = json!([0]);
    let p = doc.write_data_uri(d, "cycle.gltf");
    check(&p, "nodes[0]", "reached twice");

    // Truncated GLB.
    let p = hierarchy_doc().write_glb(d, "full.glb");
    let bytes = std::fs::read(&p).unwrap();
    let p = write(d, "trunc.glb", &bytes[..bytes.len() - 20]);
    check(&p, "GLB header", "declares");
    let p = write(d, "tiny.glb", &bytes[..10]);
    check(&p, "GLB header", "shorter than a GLB header");

    // Nothing to draw.
    let mut doc = hierarchy_doc();
    doc.json["scenes"] = json!([{"nodes": []}]);
    let p = doc.write_data_uri(d, "empty.gltf");
    check(&p, "", "the mesh is empty: it has no triangles");
}

/// Issue 19's hostile inputs: each refused with the file, the element and the problem.
#[test]
fn hostile_gltf_and_unbounded_references_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let check = |p: &Path, element: &str, want: &str| {
        let e = load_err(p, &ImportOptions::default());
        assert!(
            e.starts_with(&format!("{}: {element}", p.display())),
            "{element}: {e}"
        );
        assert!(e.contains(want), "{want}: {e}");
    };
    // Item 1: an attribute naming an accessor that does not exist (the gltf crate's own
    // validation indexed it unchecked and panicked).
    let mut doc = hierarchy_doc();
    doc.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(42);
    let p = doc.write_data_uri(d, "pos42.gltf");
    check(
        &p,
        "meshes[0].primitives[0].attributes.POSITION",
        "accessor 42 does not exist (the file has 3)",
    );
    // Item 13: integer positions and a glTF 3 asset are not read silently.
    let mut doc = hierarchy_doc();
    let q = doc.view(&[0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0]);
    doc.json["accessors"][0] = json!({"bufferView": q, "componentType": 5121, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]});
    let p = doc.write_data_uri(d, "u8.gltf");
    check(&p, "accessors[0] (POSITION", "positions must be FLOAT");
    let mut doc = hierarchy_doc();
    doc.json["asset"]["version"] = json!("3.0");
    let p = doc.write_data_uri(d, "v3.gltf");
    check(&p, "asset.version", "only glTF 2.x is read");
    // Item 7: buffers outside the model's folder, relative or absolute.
    for uri in ["../../etc/passwd", "/etc/passwd", "sub/../../x.bin"] {
        let mut doc = hierarchy_doc();
        doc.json["buffers"] = json!([{"byteLength": 80, "uri": uri}]);
        let p = write(d, "escape.gltf", doc.json.to_string());
        check(&p, "buffers[0]", "outside the model's folder");
    }
    // Item 5: references to /dev/zero and to a FIFO are refused before a byte is read.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink("/dev/zero", d.join("zero.bin")).unwrap();
        let mut doc = hierarchy_doc();
        doc.json["buffers"] = json!([{"byteLength": 80, "uri": "zero.bin"}]);
        let p = write(d, "zero.gltf", doc.json.to_string());
        // A link that leads out of the folder is outside it.
        check(&p, "buffers[0]", "outside the model's folder");
        std::os::unix::fs::symlink("/dev/zero", d.join("zero.obj")).unwrap();
        let e = load_err(&d.join("zero.obj"), &ImportOptions::default());
        assert!(e.contains("zero.obj: is not a regular file"), "{e}");
        let fifo = d.join("fifo.mtl");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        let p = write(
            d,
            "fifo.obj",
            "mtllib fifo.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        );
        let e = load_err(&p, &ImportOptions::default());
        assert!(
            e.contains("line 1: mtllib 'fifo.mtl'") && e.contains("is not a regular file"),
            "{e}"
        );
        let mut doc = hierarchy_doc();
        doc.json["buffers"] = json!([{"byteLength": 80, "uri": "fifo.mtl"}]);
        let p = write(d, "fifo.gltf", doc.json.to_string());
        check(&p, "buffers[0]", "is not a regular file");
    }
}

// ---------- scenes ----------

#[test]
fn scene_file_imports_a_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write(d, "models/mat/tree.mtl", TWO_MATERIALS_MTL);
    write(d, "models/mat/leaf.png", leaf_png());
    write(d, "models/fern.obj", TWO_MATERIALS_OBJ);
    let scene = write(
        d,
        "forest.toml",
        r#"
[[models]]
name = "fern"
mesh = "models/fern.obj"
leaf_materials = ["bark"]
scale = 2.0

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "fern"
position = [3.0, 0.0, 0.0]

[[instances]]
model = "rose"
position = [-3.0, 0.0, 0.0]
"#,
    );
    let s = sylva_scene::load(scene.to_str().unwrap()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.models.len(), 2);
    let fern = &s.models[0];
    assert_eq!(fern.name, "fern");
    assert_eq!(fern.triangle_count(), 3);
    assert_eq!(fern.bounds.max, Vec3::new(2.0, 4.0, 0.0), "scale 2");
    assert_eq!(
        s.model_origins,
        [
            ModelOrigin::MeshFile(d.join("models/fern.obj")),
            ModelOrigin::Species("dogrose".into())
        ]
    );
    let stats = SceneStats::of(&s);
    assert_eq!(stats.models[0].species, "fern.obj");
    // Bark forced to leaf by the pattern: every triangle is a leaf.
    assert_eq!(stats.models[0].leaf_triangles, 3);
    assert_eq!(stats.models[0].wood_triangles, 0);
    // The species model's leaves are counted by material kind as before.
    let rose = &s.models[1];
    assert_eq!(
        stats.models[1].leaf_triangles,
        rose.mesh
            .triangles_with_material(sylva_grow::weber_penn::LEAF)
    );
    let wb = s.instances[0].world_bounds(fern);
    assert_eq!(wb.min.x, 3.0);
}

#[test]
fn scene_mesh_errors_name_the_scene_line_and_the_mesh_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let obj = write(d, "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n");
    let scene = write(
        d,
        "s.toml",
        "name = \"x\"\n\n[[models]]\nname = \"b\"\nmesh = \"bad.obj\"\n\
         [[instances]]\nmodel = \"b\"\nposition = [0.0, 0.0, 0.0]\n",
    );
    let desc = SceneDesc::load_file(&scene).unwrap();
    let e = desc.build().unwrap_err().to_string();
    assert!(
        e.starts_with(&format!(
            "{}: line 3: model 'b': {}: line 4: face index 4",
            scene.display(),
            obj.display()
        )),
        "{e}"
    );
    let cases = [
        ("up = \"x\"", "up = 'x': expected \"y\" or \"z\""),
        ("scale = 0.0", "scale must be a positive number"),
        ("seed = 3", "'seed' applies to grown models"),
        ("leaf_material = [\"a\"]", "unknown field `leaf_material`"),
    ];
    write(d, "ok.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    for (key, want) in cases {
        let text = format!("[[models]]\nname = \"b\"\nmesh = \"ok.obj\"\n{key}\n");
        let e = SceneDesc::parse(&text, "t.toml", Some(d))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("t.toml: line ") && e.contains(want),
            "{key}: {e}"
        );
    }
    // The up axis reaches the importer.
    let text = "[[models]]\nname = \"b\"\nmesh = \"ok.obj\"\nup = \"Z\"\n[[instances]]\nmodel = \"b\"\nposition = [0.0, 0.0, 0.0]\n";
    let s = SceneDesc::parse(text, "t.toml", Some(d))
        .unwrap()
        .build()
        .unwrap();
    assert_eq!(s.models[0].mesh.positions[2], [0.0, 0.0, -1.0]);
}

// ---------- a whole species through OBJ ----------

/// The dogrose species written as OBJ + MTL + PNG textures (material names with spaces,
/// v/vt/vn faces) reads back with the same triangles, materials and texels.
#[test]
fn species_written_as_obj_reads_back() {
    use std::fmt::Write;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let orig = sylva_grow::Species::builtin("dogrose")
        .unwrap()
        .build_model()
        .unwrap();
    let mut mtl = String::new();
    for (k, m) in orig.materials.iter().enumerate() {
        let t = m.texture.as_ref().unwrap();
        let img = image::RgbaImage::from_fn(t.width, t.height, |x, y| image::Rgba(t.texel(x, y)));
        img.save(d.join(format!("tex{k}.png"))).unwrap();
        writeln!(mtl, "newmtl {}\nKd 1 1 1\nmap_Kd tex{k}.png", m.name).unwrap();
    }
    write(d, "rose.mtl", &mtl);
    let mesh = &orig.mesh;
    let mut obj = String::from("mtllib rose.mtl\n");
    for p in &mesh.positions {
        writeln!(obj, "v {} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for uv in &mesh.uvs {
        writeln!(obj, "vt {} {}", uv[0], 1.0 - uv[1]).unwrap();
    }
    for n in &mesh.normals {
        writeln!(obj, "vn {} {} {}", n[0], n[1], n[2]).unwrap();
    }
    let mut order = Vec::new();
    for (k, m) in orig.materials.iter().enumerate() {
        writeln!(obj, "usemtl {}", m.name).unwrap();
        for (t, tri) in mesh.indices.iter().enumerate() {
            if mesh.material_ids[t] as usize == k {
                let [a, b, c] = tri.map(|i| i + 1);
                writeln!(obj, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}").unwrap();
                order.push(t);
            }
        }
    }
    let m = load(&write(d, "rose.obj", &obj));
    assert_eq!(m.triangle_count(), orig.triangle_count());
    assert_eq!(m.bounds, orig.bounds);
    for (a, b) in m.materials.iter().zip(&orig.materials) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.kind, b.kind, "{}", a.name);
        assert_eq!(a.two_sided, b.two_sided, "{}", a.name);
        assert_eq!(
            a.texture.as_ref().unwrap().pixels,
            b.texture.as_ref().unwrap().pixels
        );
        for c in 0..3 {
            assert!((a.base_color[c] - b.base_color[c]).abs() < 1e-6);
        }
    }
    for (new_t, &old_t) in order.iter().enumerate() {
        assert_eq!(m.mesh.material_ids[new_t], mesh.material_ids[old_t]);
        for (&i, &j) in m.mesh.indices[new_t].iter().zip(&mesh.indices[old_t]) {
            let (i, j) = (i as usize, j as usize);
            assert_eq!(m.mesh.positions[i], mesh.positions[j]);
            for c in 0..2 {
                assert!((m.mesh.uvs[i][c] - mesh.uvs[j][c]).abs() < 1e-6);
            }
            let (n, o) = (
                Vec3::from_array(m.mesh.normals[i]),
                Vec3::from_array(mesh.normals[j]),
            );
            assert!((n - o.normalize()).length() < 1e-5, "{n} vs {o}");
        }
    }
}

/// Issue 31 item 5: an OBJ's `mtllib` and an MTL's texture maps stay inside the model's folder,
/// as glTF's buffers and images do; an MTL in a subfolder may still name a texture beside it.
#[test]
fn obj_references_outside_the_model_folder_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("a/b/model");
    write(tmp.path(), "a/secret.mtl", "newmtl Bark\nKd 1 0 0\n");
    write(tmp.path(), "a/secret.png", png(2, 2, |_, _| [9, 9, 9, 255]));
    let obj = |mtllib: &str| {
        format!("mtllib {mtllib}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl Bark\nf 1 2 3\n")
    };
    for reference in ["../../secret.mtl", "sub/../../../secret.mtl"] {
        let p = write(&d, "t.obj", obj(reference));
        let e = load_err(&p, &ImportOptions::default());
        assert!(
            e.contains(&format!("t.obj: line 1: mtllib '{reference}'"))
                && e.contains("outside the model's folder"),
            "{e}"
        );
    }
    let abs = tmp.path().join("a/secret.mtl");
    let p = write(&d, "t.obj", obj(abs.to_str().unwrap()));
    let e = load_err(&p, &ImportOptions::default());
    assert!(e.contains("outside the model's folder"), "{e}");
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&abs, d.join("link.mtl")).unwrap();
        let p = write(&d, "t.obj", obj("link.mtl"));
        let e = load_err(&p, &ImportOptions::default());
        assert!(e.contains("outside the model's folder"), "{e}");
    }

    // Texture maps: against the model's folder, not the MTL's.
    let p = write(&d, "t.obj", obj("mtl/t.mtl"));
    write(&d, "mtl/t.mtl", "newmtl Bark\nmap_Kd ../../../secret.png\n");
    let e = load_err(&p, &ImportOptions::default());
    assert!(
        e.contains("t.mtl: line 2: map_Kd '../../../secret.png'")
            && e.contains("outside the model's folder"),
        "{e}"
    );
    write(&d, "tex/ok.png", png(2, 2, |_, _| [200, 10, 10, 255]));
    write(&d, "mtl/t.mtl", "newmtl Bark\nmap_Kd ../tex/ok.png\n");
    assert_eq!(load(&p).triangle_count(), 1);
}
