//! Mesh import speed: the american beech species (about 493 k triangles, two textured
//! materials) written as OBJ + MTL + PNG and as GLB, then read back with `load_mesh_file`.

use criterion::{criterion_group, criterion_main, Criterion};
use std::fmt::Write as _;
use std::hint::black_box;
use std::path::Path;
use sylva_geom::Model;
use sylva_grow::Species;
use sylva_io::import::{load_mesh_file, ImportOptions};

fn png(t: &sylva_geom::Texture) -> Vec<u8> {
    let img = image::RgbaImage::from_fn(t.width, t.height, |x, y| image::Rgba(t.texel(x, y)));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

fn write_obj(m: &Model, dir: &Path) -> std::path::PathBuf {
    let mut mtl = String::new();
    for (k, mat) in m.materials.iter().enumerate() {
        std::fs::write(
            dir.join(format!("tex{k}.png")),
            png(mat.texture.as_ref().unwrap()),
        )
        .unwrap();
        writeln!(mtl, "newmtl {}\nmap_Kd tex{k}.png", mat.name).unwrap();
    }
    std::fs::write(dir.join("tree.mtl"), mtl).unwrap();
    let mut obj = String::from("mtllib tree.mtl\n");
    for p in &m.mesh.positions {
        writeln!(obj, "v {} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for uv in &m.mesh.uvs {
        writeln!(obj, "vt {} {}", uv[0], 1.0 - uv[1]).unwrap();
    }
    for n in &m.mesh.normals {
        writeln!(obj, "vn {} {} {}", n[0], n[1], n[2]).unwrap();
    }
    for (k, mat) in m.materials.iter().enumerate() {
        writeln!(obj, "usemtl {}", mat.name).unwrap();
        for (t, tri) in m.mesh.indices.iter().enumerate() {
            if m.mesh.material_ids[t] as usize == k {
                let [a, b, c] = tri.map(|i| i + 1);
                writeln!(obj, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}").unwrap();
            }
        }
    }
    let p = dir.join("tree.obj");
    std::fs::write(&p, obj).unwrap();
    p
}

fn write_glb(m: &Model, dir: &Path) -> std::path::PathBuf {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8]| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}),
        );
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let f32s =
        |v: &[[f32; 3]]| -> Vec<u8> { v.iter().flatten().flat_map(|f| f.to_le_bytes()).collect() };
    let n = m.mesh.positions.len();
    let b = m.bounds;
    let pv = view(&mut bin, &f32s(&m.mesh.positions));
    let nv = view(&mut bin, &f32s(&m.mesh.normals));
    let uvb: Vec<u8> = m
        .mesh
        .uvs
        .iter()
        .flatten()
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let uv = view(&mut bin, &uvb);
    let mut accessors = vec![
        serde_json::json!({"bufferView": pv, "componentType": 5126, "count": n, "type": "VEC3",
            "min": b.min.to_array(), "max": b.max.to_array()}),
        serde_json::json!({"bufferView": nv, "componentType": 5126, "count": n, "type": "VEC3"}),
        serde_json::json!({"bufferView": uv, "componentType": 5126, "count": n, "type": "VEC2"}),
    ];
    let mut prims = Vec::new();
    let mut images = Vec::new();
    let mut materials = Vec::new();
    for (k, mat) in m.materials.iter().enumerate() {
        let idx: Vec<u8> = m
            .mesh
            .indices
            .iter()
            .zip(&m.mesh.material_ids)
            .filter(|(_, &id)| id as usize == k)
            .flat_map(|(t, _)| t.iter().flat_map(|i| i.to_le_bytes()))
            .collect();
        let iv = view(&mut bin, &idx);
        accessors.push(serde_json::json!({"bufferView": iv, "componentType": 5125, "count": idx.len() / 4, "type": "SCALAR"}));
        prims.push(
            serde_json::json!({"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
            "indices": accessors.len() - 1, "material": k}),
        );
        let img = view(&mut bin, &png(mat.texture.as_ref().unwrap()));
        images.push(serde_json::json!({"bufferView": img, "mimeType": "image/png"}));
        let mut mj = serde_json::json!({"name": mat.name, "pbrMetallicRoughness": {"baseColorTexture": {"index": k}}});
        if mat.is_leaf() {
            mj["alphaMode"] = "MASK".into();
        }
        materials.push(mj);
    }
    let textures: Vec<_> = (0..images.len())
        .map(|k| serde_json::json!({"source": k}))
        .collect();
    let json = serde_json::json!({
        "asset": {"version": "2.0"}, "buffers": [{"byteLength": bin.len()}], "bufferViews": views,
        "accessors": accessors, "images": images, "textures": textures, "materials": materials,
        "meshes": [{"primitives": prims}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}],
    });
    let mut js = serde_json::to_vec(&json).unwrap();
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((28 + js.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    let p = dir.join("tree.glb");
    std::fs::write(&p, out).unwrap();
    p
}

fn import(c: &mut Criterion) {
    let model = Species::builtin("american_beech")
        .unwrap()
        .build_model()
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let obj = write_obj(&model, dir.path());
    let glb = write_glb(&model, dir.path());
    let opts = ImportOptions::default();
    for p in [&obj, &glb] {
        let m = load_mesh_file(p, &opts).unwrap();
        assert_eq!(m.triangle_count(), model.triangle_count());
        assert_eq!(m.bounds, model.bounds);
    }
    let mut g = c.benchmark_group("import");
    g.sample_size(10);
    g.bench_function("american_beech_obj", |b| {
        b.iter(|| black_box(load_mesh_file(&obj, &opts).unwrap()))
    });
    g.bench_function("american_beech_glb", |b| {
        b.iter(|| black_box(load_mesh_file(&glb, &opts).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, import);
criterion_main!(benches);
