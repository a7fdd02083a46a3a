//! Scene export: the Mitsuba XML is consistent with its files and the scene; the OBJ reads
//! back to the scene's geometry; output is independent of the thread count.

use glam::{Mat4, Vec3};
use std::collections::{HashMap, HashSet};
use std::fs;
use std::path::Path;
use sylva_geom::Scene;
use sylva_io::export::{mitsuba, obj, ExportError};

/// Two models (dogroses of different seeds), one placed by hand, three scattered, rotated and
/// scaled; an explicit camera; a ground.
const SMALL: &str = r#"
name = "small"

[[models]]
name = "rose a"
species = "dogrose"

[[models]]
name = "rose b"
species = "dogrose"
seed = 9

[[instances]]
model = "rose a"
position = [1.0, 0.0, -2.0]
rotation = 35.0
scale = 1.3

[[instances]]
model = "rose b"
count = 3
area = { min = [-8.0, -8.0], max = [8.0, 8.0] }
min_spacing = 3.0
scale_jitter = 0.2
seed = 4

[ground]
size = [30.0, 24.0]
color = [0.2, 0.15, 0.1]

[sun]
elevation = 35.0
azimuth = 120.0

[sky]
color = [0.5, 0.6, 0.9]

[camera]
position = [2.0, 3.0, -15.0]
look_at = [0.0, 1.0, 0.0]
fov = 35.0
resolution = [200, 120]
rays_per_pixel = 3
"#;

fn small_scene(dir: &Path) -> Scene {
    let path = dir.join("small.toml");
    fs::write(&path, SMALL).unwrap();
    sylva_scene::load(path.to_str().unwrap()).unwrap()
}

fn floats(s: &str) -> Vec<f32> {
    s.split([',', ' '])
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().unwrap())
        .collect()
}

fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

/// Vertex positions and face indices of a binary little-endian PLY as Mitsuba reads it.
fn read_ply(path: &Path) -> (Vec<[f32; 8]>, Vec<[u32; 3]>) {
    let bytes = fs::read(path).unwrap();
    let end = b"end_header\n";
    let h = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let header = std::str::from_utf8(&bytes[..h]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    let count = |el: &str| -> usize {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {el} ")))
            .unwrap()
            .parse()
            .unwrap()
    };
    let props: Vec<&str> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float "))
        .collect();
    assert_eq!(props, ["x", "y", "z", "nx", "ny", "nz", "u", "v"]);
    assert!(header.contains("property list uchar uint vertex_indices\n"));
    let (nv, nf) = (count("vertex"), count("face"));
    assert_eq!(bytes.len(), h + nv * 32 + nf * 13, "{}", path.display());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let verts = (0..nv)
        .map(|i| std::array::from_fn(|k| f32_at(h + 32 * i + 4 * k)))
        .collect();
    let faces = (0..nf)
        .map(|i| {
            let o = h + nv * 32 + 13 * i;
            assert_eq!(bytes[o], 3);
            std::array::from_fn(|k| {
                u32::from_le_bytes(bytes[o + 1 + 4 * k..o + 5 + 4 * k].try_into().unwrap())
            })
        })
        .collect();
    (verts, faces)
}

#[test]
fn mitsuba_xml_is_consistent_with_its_files_and_the_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    let out = tmp.path().join("mi");
    let opts = mitsuba::MitsubaOptions::for_scene(&scene);
    let mut calls = Vec::new();
    let written = mitsuba::write(&scene, &out, &opts, &mut |n| {
        calls.push(n);
        true
    })
    .unwrap();
    assert_eq!(calls, [1, 2]);
    assert_eq!(
        written.files,
        mitsuba::files(&scene),
        "planned and written files differ"
    );
    assert_eq!(written.triangles, scene.instanced_triangles() + 2);
    for f in &written.files {
        assert!(out.join(f).is_file(), "{}", f.display());
    }

    let text = fs::read_to_string(out.join(mitsuba::XML_FILE)).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "scene");
    assert!(root.attribute("version").unwrap().starts_with("3."));
    let defaults: HashMap<&str, &str> = root
        .children()
        .filter(|n| n.has_tag_name("default"))
        .map(|n| (n.attribute("name").unwrap(), n.attribute("value").unwrap()))
        .collect();
    // `$name` resolves through <default>.
    let value = |n: roxmltree::Node| -> String {
        let v = n.attribute("value").unwrap();
        match v.strip_prefix('$') {
            Some(k) => defaults[k].to_string(),
            None => v.to_string(),
        }
    };
    let named = |parent: roxmltree::Node, tag: &str, name: &str| -> String {
        let n = parent
            .descendants()
            .find(|n| n.has_tag_name(tag) && n.attribute("name") == Some(name))
            .unwrap_or_else(|| panic!("no <{tag} name={name}>"));
        value(n)
    };

    // Every referenced file exists.
    let mut referenced = 0;
    for n in doc
        .descendants()
        .filter(|n| n.attribute("name") == Some("filename"))
    {
        let f = n.attribute("value").unwrap();
        assert!(out.join(f).is_file(), "{f} is referenced but missing");
        referenced += 1;
    }
    // 2 models × 2 PLYs, 2 × (wood colour, leaf alpha, leaf 2R, leaf 2T) textures (the leaf
    // colour PNG is written for viewers; the BSDF reads the linear EXRs).
    assert_eq!(referenced, 4 + 8);

    // Ids: every ref resolves; instances refer to shapegroups.
    let mut ids: HashMap<&str, roxmltree::Node> = HashMap::new();
    for n in doc.descendants().filter(|n| !n.has_tag_name("ref")) {
        if let Some(id) = n.attribute("id") {
            assert!(ids.insert(id, n).is_none(), "id {id} defined twice");
        }
    }
    let groups: HashSet<&str> = doc
        .descendants()
        .filter(|n| n.has_tag_name("shape") && n.attribute("type") == Some("shapegroup"))
        .map(|n| n.attribute("id").unwrap())
        .collect();
    assert_eq!(groups.len(), 2);
    for r in doc.descendants().filter(|n| n.has_tag_name("ref")) {
        let id = r.attribute("id").unwrap();
        let target = ids.get(id).unwrap_or_else(|| panic!("undefined id {id}"));
        let parent = r.parent_element().unwrap();
        if parent.attribute("type") == Some("instance") {
            assert!(groups.contains(id), "instance of {id}, not a shapegroup");
        } else {
            assert!(target.has_tag_name("bsdf"), "{id}");
        }
    }

    // Instances: one per plant, each with its transform; triangles add up.
    let instances: Vec<roxmltree::Node> = root
        .children()
        .filter(|n| n.has_tag_name("shape") && n.attribute("type") == Some("instance"))
        .collect();
    assert_eq!(instances.len(), scene.instances.len());
    let mut triangles = 0u64;
    for (node, inst) in instances.iter().zip(&scene.instances) {
        let m = node
            .descendants()
            .find(|n| n.has_tag_name("matrix"))
            .unwrap();
        let rows = floats(m.attribute("value").unwrap());
        let expect = Mat4::from(inst.transform()).transpose().to_cols_array();
        assert!(close(&rows, &expect, 1e-6), "{rows:?} vs {expect:?}");
        let group = ids[node
            .children()
            .find(|n| n.has_tag_name("ref"))
            .unwrap()
            .attribute("id")
            .unwrap()];
        let model = &scene.models[inst.model as usize];
        let mut faces = 0;
        for ply in group
            .children()
            .filter(|n| n.attribute("type") == Some("ply"))
        {
            let (verts, f) = read_ply(&out.join(named(ply, "string", "filename")));
            // Faces index the file's own vertices, which are the model's.
            for tri in f.iter().step_by(97) {
                for &i in tri {
                    let v = verts[i as usize];
                    assert!(model
                        .mesh
                        .positions
                        .iter()
                        .zip(&model.mesh.uvs)
                        .any(|(p, uv)| p[..] == v[..3] && uv[..] == v[6..]));
                }
            }
            faces += f.len();
        }
        assert_eq!(faces, model.triangle_count());
        triangles += faces as u64;
    }
    assert_eq!(triangles, scene.instanced_triangles());

    // Sensor: the scene's camera.
    let sensor = root.children().find(|n| n.has_tag_name("sensor")).unwrap();
    assert_eq!(sensor.attribute("type"), Some("perspective"));
    assert_eq!(named(sensor, "float", "fov"), "35");
    assert_eq!(named(sensor, "string", "fov_axis"), "y");
    assert_eq!(named(sensor, "integer", "width"), "200");
    assert_eq!(named(sensor, "integer", "height"), "120");
    assert_eq!(named(sensor, "integer", "sample_count"), "3");
    let lookat = sensor
        .descendants()
        .find(|n| n.has_tag_name("lookat"))
        .unwrap();
    assert_eq!(
        floats(lookat.attribute("origin").unwrap()),
        [2.0, 3.0, -15.0]
    );
    assert_eq!(floats(lookat.attribute("target").unwrap()), [0.0, 1.0, 0.0]);
    assert_eq!(floats(lookat.attribute("up").unwrap()), [0.0, 1.0, 0.0]);
    assert_eq!(
        root.children()
            .find(|n| n.has_tag_name("integrator"))
            .unwrap()
            .attribute("type"),
        Some("volpath")
    );
    assert_eq!(named(root, "integer", "max_depth"), "-1");

    // Lights: the sun along the direction light travels, 6500 K; the sky's colour.
    let emitter = |ty: &str| {
        root.children()
            .find(|n| n.has_tag_name("emitter") && n.attribute("type") == Some(ty))
            .unwrap()
    };
    let dir = floats(&named(emitter("directional"), "vector", "direction"));
    let travel = scene.sun.travel().as_vec3();
    assert!(close(&dir, &travel.to_array(), 1e-6));
    assert!(dir[1] < 0.0, "sunlight travels downwards");
    let e = floats(&named(emitter("directional"), "rgb", "irradiance"));
    let bb = sylva_core::blackbody_rgb(6500.0).map(|c| c * std::f32::consts::PI);
    assert!(close(&e, &bb, 1e-5), "{e:?}");
    let sky = floats(&named(emitter("constant"), "rgb", "radiance"));
    assert_eq!(sky, [0.5, 0.6, 0.9]);

    // Leaves: masked by their alpha, thin and transmissive; wood: diffuse with its bark.
    let leaf = ids["bsdf-rose_a_leaf"];
    assert_eq!(leaf.attribute("type"), Some("mask"));
    assert!(named(leaf, "string", "filename").ends_with("_alpha.png"));
    let thin = leaf
        .descendants()
        .find(|n| n.attribute("type") == Some("principledthin"))
        .unwrap();
    assert_eq!(named(thin, "float", "diff_trans"), "2");
    let wood = ids["bsdf-rose_b_wood"];
    assert_eq!(wood.attribute("type"), Some("diffuse"));
    assert_eq!(named(wood, "string", "wrap_mode"), "repeat");

    // The ground rectangle maps onto y = 0, ±size/2, normal +y.
    let ground = ids["ground"];
    let m = ground
        .descendants()
        .find(|n| n.has_tag_name("matrix"))
        .unwrap();
    let m = floats(m.attribute("value").unwrap());
    let m = Mat4::from_cols_array(&m.try_into().unwrap()).transpose();
    let corner = m.transform_point3(Vec3::new(1.0, 1.0, 0.0));
    assert!(
        close(&corner.to_array(), &[15.0, 0.0, -12.0], 1e-6),
        "{corner}"
    );
    let normal = m
        .inverse()
        .transpose()
        .transform_vector3(Vec3::Z)
        .normalize();
    assert!((normal - Vec3::Y).length() < 1e-6, "{normal}");

    // The alpha PNG is the texture's alpha channel.
    let tex = scene.models[0].materials[1].texture.as_ref().unwrap();
    let png = image::open(out.join(named(leaf, "string", "filename"))).unwrap();
    let grey = png.to_luma8();
    assert_eq!((grey.width(), grey.height()), (tex.width, tex.height));
    assert!(grey.pixels().zip(&tex.pixels).all(|(g, t)| g.0[0] == t[3]));
}

/// A face as 0-based v/vt/vn triples, with its material.
type Face = ([[usize; 3]; 3], String);

/// The parts of an OBJ this test reads: per object its vertices (v, vt, vn lines in order) and
/// faces with their material.
#[derive(Default)]
struct Obj {
    v: Vec<[f32; 3]>,
    vt: Vec<[f32; 2]>,
    vn: Vec<[f32; 3]>,
    /// (object name, first vertex index (0-based), faces as 0-based v/vt/vn triples, material).
    objects: Vec<(String, usize, Vec<Face>)>,
    mtllib: String,
}

fn read_obj(path: &Path) -> Obj {
    let text = fs::read_to_string(path).unwrap();
    let mut o = Obj::default();
    let mut mtl = String::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        let Some(kw) = it.next() else { continue };
        let rest: Vec<&str> = it.collect();
        let f = |k: usize| -> f32 { rest[k].parse().unwrap() };
        match kw {
            "#" => {}
            "mtllib" => o.mtllib = rest[0].to_string(),
            "o" => o.objects.push((rest[0].to_string(), o.v.len(), Vec::new())),
            "v" => o.v.push([f(0), f(1), f(2)]),
            "vt" => o.vt.push([f(0), f(1)]),
            "vn" => o.vn.push([f(0), f(1), f(2)]),
            "usemtl" => mtl = rest[0].to_string(),
            "f" => {
                assert_eq!(rest.len(), 3, "{line}");
                let corner = |s: &str| -> [usize; 3] {
                    let p: Vec<usize> = s.split('/').map(|x| x.parse().unwrap()).collect();
                    [p[0] - 1, p[1] - 1, p[2] - 1]
                };
                let tri = [corner(rest[0]), corner(rest[1]), corner(rest[2])];
                o.objects.last_mut().unwrap().2.push((tri, mtl.clone()));
            }
            other => panic!("unexpected OBJ keyword {other}"),
        }
    }
    o
}

#[test]
fn obj_reads_back_to_the_instanced_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    let out = tmp.path().join("obj");
    let mut last = 0;
    let written = obj::write(&scene, &out, &mut |n| {
        last = n;
        true
    })
    .unwrap();
    assert_eq!(last, scene.instances.len() as u64);
    assert_eq!(
        written.files,
        obj::files(&scene),
        "planned and written files differ"
    );
    let o = read_obj(&out.join(obj::OBJ_FILE));
    assert_eq!(o.mtllib, obj::MTL_FILE);
    assert_eq!(o.v.len(), o.vt.len());
    assert_eq!(o.v.len(), o.vn.len());

    // Triangles: the scene's instanced count plus the ground's two.
    let faces: usize = o.objects.iter().map(|ob| ob.2.len()).sum();
    assert_eq!(faces as u64, scene.instanced_triangles() + 2);
    assert_eq!(written.triangles, faces as u64);
    assert_eq!(o.objects.len(), scene.instances.len() + 1);

    // The ground: a quad of the scene's size on y = 0, facing up.
    let (name, base, gf) = &o.objects[0];
    assert_eq!((name.as_str(), *base, gf.len()), ("ground", 0, 2));
    for v in &o.v[..4] {
        assert_eq!((v[0].abs(), v[1], v[2].abs()), (15.0, 0.0, 12.0));
    }
    for (tri, mtl) in gf {
        assert_eq!(mtl, "ground");
        let [a, b, c] = tri.map(|t| Vec3::from_array(o.v[t[0]]));
        assert!((b - a).cross(c - a).normalize().dot(Vec3::Y) > 0.999);
    }

    // Each instance: the model's vertices under the instance transform (bit for bit: the
    // shortest decimal of an f32 reads back to the same f32), normals turned with it,
    // texture coordinates (u, 1 - v), and the model's triangles in its material groups.
    for ((name, base, tris), inst) in o.objects[1..].iter().zip(&scene.instances) {
        let model = &scene.models[inst.model as usize];
        let mesh = &model.mesh;
        assert!(name.starts_with("rose_"), "{name}");
        let t = inst.transform();
        for i in (0..mesh.vertex_count()).step_by(37) {
            let expect = t.transform_point3(Vec3::from_array(mesh.positions[i]));
            assert_eq!(o.v[base + i], expect.to_array(), "vertex {i} of {name}");
            let n = t
                .transform_vector3(Vec3::from_array(mesh.normals[i]))
                .normalize();
            assert!(close(&o.vn[base + i], &n.to_array(), 1e-5));
            let uv = mesh.uvs[i];
            assert!(close(&o.vt[base + i], &[uv[0], 1.0 - uv[1]], 1e-6));
        }
        assert_eq!(tris.len(), model.triangle_count());
        let mut seen = vec![false; mesh.triangle_count()];
        let mut by_index: HashMap<[usize; 3], usize> = HashMap::new();
        for (k, tri) in mesh.indices.iter().enumerate() {
            by_index.insert(tri.map(|i| i as usize), k);
        }
        for (tri, mtl) in tris {
            for c in tri {
                assert!(c[0] == c[1] && c[1] == c[2], "one index per vertex");
            }
            let local = tri.map(|c| c[0] - base);
            let k = by_index[&local];
            seen[k] = true;
            let kind = if model.materials[mesh.material_ids[k] as usize].is_leaf() {
                "leaf"
            } else {
                "wood"
            };
            assert!(mtl.ends_with(kind), "{mtl} for a {kind} triangle");
        }
        assert!(seen.iter().all(|&s| s), "every triangle of {name} once");
    }

    // The MTL defines every material used and its maps exist: RGBA colour with the alpha
    // kept, and the alpha alone for map_d.
    let mtl = fs::read_to_string(out.join(obj::MTL_FILE)).unwrap();
    let defined: HashSet<&str> = mtl
        .lines()
        .filter_map(|l| l.strip_prefix("newmtl "))
        .collect();
    for ob in &o.objects {
        for (_, m) in &ob.2 {
            assert!(defined.contains(m.as_str()), "{m}");
        }
    }
    let mut maps = 0;
    for l in mtl.lines() {
        if let Some(f) = l
            .strip_prefix("map_Kd ")
            .or_else(|| l.strip_prefix("map_d "))
        {
            assert!(out.join(f).is_file(), "{f}");
            maps += 1;
        }
    }
    assert_eq!(maps, 2 * 3);
    let tex = scene.models[1].materials[1].texture.as_ref().unwrap();
    let png = image::open(out.join("textures/rose_b_leaf.png"))
        .unwrap()
        .to_rgba8();
    assert!(png.pixels().zip(&tex.pixels).all(|(p, t)| p.0 == *t));
    assert!(tex.pixels.iter().any(|p| p[3] == 0), "leaf keeps its alpha");
    assert!(mtl.contains("Kd 0.2 0.15 0.1"), "ground colour");

    // The size estimate is close to the real size.
    let actual = fs::metadata(out.join(obj::OBJ_FILE)).unwrap().len() as f64;
    let estimate = obj::estimate_size(&scene) as f64;
    assert!(
        (estimate / actual - 1.0).abs() < 0.03,
        "estimate {estimate} vs {actual}"
    );
}

#[test]
fn output_does_not_depend_on_the_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let mut scene = small_scene(tmp.path());
    scene.instances.truncate(3);
    let run = |threads: usize, sub: &str| {
        let dir = tmp.path().join(sub);
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| obj::write(&scene, &dir, &mut |_| true).unwrap());
        fs::read(dir.join(obj::OBJ_FILE)).unwrap()
    };
    let one = run(1, "t1");
    assert!(one == run(2, "t2"));
    assert!(one == run(3, "t3"));
}

#[test]
fn untextured_two_sided_and_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let mut scene = small_scene(tmp.path());
    scene.instances.truncate(1);
    scene.ground.enabled = false;
    scene.models[0].materials[0].texture = None;
    scene.models[0].materials[0].two_sided = true;
    let out = tmp.path().join("plain");
    let opts = mitsuba::MitsubaOptions::for_scene(&scene);
    mitsuba::write(&scene, &out, &opts, &mut |_| true).unwrap();
    let text = fs::read_to_string(out.join(mitsuba::XML_FILE)).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let wood = doc
        .descendants()
        .find(|n| n.attribute("id") == Some("bsdf-rose_a_wood"))
        .unwrap();
    assert_eq!(wood.attribute("type"), Some("twosided"));
    let rgb = wood.descendants().find(|n| n.has_tag_name("rgb")).unwrap();
    let c = scene.models[0].materials[0].base_color;
    assert_eq!(floats(rgb.attribute("value").unwrap()), c);
    assert!(doc
        .descendants()
        .all(|n| n.attribute("id") != Some("ground")));
    // Only the placed model is written, with its textures alone.
    assert!(!text.contains("model-rose_b"));
    assert!(!out.join("textures/rose_b_leaf.png").exists());
    assert!(out.join("textures/rose_a_leaf.png").exists());
    let w = obj::write(&scene, &tmp.path().join("plain_obj"), &mut |_| true).unwrap();
    assert_eq!(w.triangles, scene.instanced_triangles());
    let mtl = fs::read_to_string(tmp.path().join("plain_obj").join(obj::MTL_FILE)).unwrap();
    assert!(!mtl.contains("newmtl ground"));
    assert!(mtl.contains(&format!("Kd {} {} {}", c[0], c[1], c[2])));

    // A file where the directory should be.
    let file = tmp.path().join("taken");
    fs::write(&file, "x").unwrap();
    let e = obj::write(&scene, &file, &mut |_| true).unwrap_err();
    assert!(matches!(e, ExportError::NotADirectory(_)), "{e}");
    assert!(e.to_string().contains("taken"), "{e}");

    // Bad options are refused before anything is written.
    let mut bad = opts;
    bad.max_depth = -7;
    let e = mitsuba::write(&scene, &tmp.path().join("bad"), &bad, &mut |_| true).unwrap_err();
    assert!(e.to_string().contains("-7"), "{e}");
    assert!(!tmp.path().join("bad").exists());

    // A defective model is reported by name, not written.
    scene.models[0].mesh.material_ids[0] = 7;
    let e = obj::write(&scene, &tmp.path().join("broken"), &mut |_| true).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("rose a") && msg.contains("material id 7"),
        "{msg}"
    );
}

#[test]
fn cancelling_leaves_no_partial_file() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    let dir = tmp.path().join("cancel");
    let e = obj::write(&scene, &dir, &mut |n| n < 1).unwrap_err();
    assert!(matches!(e, ExportError::Cancelled), "{e}");
    let names: Vec<String> = fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!names.iter().any(|n| n.contains("scene.obj")), "{names:?}");
    let dir = tmp.path().join("cancel_mi");
    let opts = mitsuba::MitsubaOptions::for_scene(&scene);
    let e = mitsuba::write(&scene, &dir, &opts, &mut |_| false).unwrap_err();
    assert!(matches!(e, ExportError::Cancelled), "{e}");
    assert!(!dir.join(mitsuba::XML_FILE).exists());
}

#[test]
fn leaf_reflectance_and_transmittance_round_trip_through_the_mitsuba_export() {
    // Each leaf is an even blend of a two-sided diffuse of 2R and a pure transmitter
    // (principledthin, diff_trans 2) of 2T: the EXRs hold exactly 2 × the linear texel
    // colour times the material's reflect and transmit factors.
    let tmp = tempfile::tempdir().unwrap();
    let scene = small_scene(tmp.path());
    let out = tmp.path().join("mi");
    let opts = mitsuba::MitsubaOptions::for_scene(&scene);
    mitsuba::write(&scene, &out, &opts, &mut |_| true).unwrap();
    let text = fs::read_to_string(out.join(mitsuba::XML_FILE)).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let file_of = |n: roxmltree::Node, name: &str| -> String {
        let t = n
            .children()
            .find(|t| t.has_tag_name("texture") && t.attribute("name") == Some(name))
            .unwrap_or_else(|| panic!("no texture {name}"));
        t.children()
            .find(|s| s.attribute("name") == Some("filename"))
            .unwrap()
            .attribute("value")
            .unwrap()
            .to_string()
    };
    let read = |f: &str| image::open(out.join(f)).unwrap().into_rgb32f();
    let leaves: Vec<_> = scene
        .models
        .iter()
        .flat_map(|m| m.materials.iter())
        .filter(|m| m.is_leaf())
        .collect();
    let mut checked = 0;
    for blend in doc
        .descendants()
        .filter(|n| n.has_tag_name("bsdf") && n.attribute("type") == Some("blendbsdf"))
    {
        let kids: Vec<_> = blend.children().filter(|n| n.is_element()).collect();
        let weight = kids.iter().find(|n| n.has_tag_name("float")).unwrap();
        assert_eq!(weight.attribute("value"), Some("0.5"));
        let bsdf = |ty: &str| {
            *kids
                .iter()
                .find(|n| n.attribute("type") == Some(ty))
                .unwrap_or_else(|| panic!("no {ty} in the blend"))
        };
        let diffuse = bsdf("twosided")
            .children()
            .find(|n| n.attribute("type") == Some("diffuse"))
            .unwrap();
        let thin = bsdf("principledthin");
        let diff_trans = thin
            .children()
            .find(|n| n.attribute("name") == Some("diff_trans"))
            .unwrap();
        assert_eq!(diff_trans.attribute("value"), Some("2"));
        let r2 = read(&file_of(diffuse, "reflectance"));
        let t2 = read(&file_of(thin, "base_color"));
        // The material whose texture these are: same size, 2 × its linear colour.
        let lin = |v: u8| sylva_core::colour::srgb_to_linear(v as f32 / 255.0);
        let material = leaves
            .iter()
            .find(|m| {
                let t = m.texture.as_ref().unwrap();
                t.width == r2.width()
                    && t.height == r2.height()
                    && t.pixels.iter().zip(r2.pixels()).all(|(p, q)| {
                        (0..3).all(|c| (q[c] - 2.0 * lin(p[c]) * m.optics.reflect[c]).abs() < 1e-5)
                    })
            })
            .expect("the reflectance texture is 2R of a leaf material");
        let t = material.texture.as_ref().unwrap();
        for (p, q) in t.pixels.iter().zip(t2.pixels()) {
            for c in 0..3 {
                let want = 2.0 * lin(p[c]) * material.optics.transmit[c];
                assert!((q[c] - want).abs() < 1e-5, "T texel {} vs {want}", q[c]);
            }
        }
        // Leaves transmit: the species' T/R is not zero.
        assert!(material.optics.transmit.iter().all(|&f| f > 0.0));
        // A species' leaf is exported as measured: over its opaque texels the EXRs average
        // to 2R and 2T of the species' measured leaf, what Mitsuba and sylva both see.
        let m = material
            .optics
            .measured
            .expect("a species' leaf carries its measurements");
        let opaque: Vec<usize> = (0..t.pixels.len())
            .filter(|&i| sylva_geom::is_opaque(t.pixels[i]))
            .collect();
        for c in 0..3 {
            let mean = |img: &image::Rgb32FImage| {
                let px: Vec<_> = img.pixels().collect();
                opaque.iter().map(|&i| px[i][c] as f64).sum::<f64>() / opaque.len() as f64
            };
            let (r, tr) = (mean(&r2) / 2.0, mean(&t2) / 2.0);
            assert!((r - m.reflectance[c] as f64).abs() < 1e-6, "R[{c}] {r}");
            assert!((tr - m.transmittance[c] as f64).abs() < 1e-6, "T[{c}] {tr}");
        }
        checked += 1;
    }
    assert_eq!(checked, leaves.len());
}

#[test]
fn media_export_as_heterogeneous_volumes_in_world_units() {
    // A 5×4×6 medium of 2 m cells with a distinct density per interior site.
    let tmp = tempfile::tempdir().unwrap();
    let mut scene = small_scene(tmp.path());
    let dims = [5usize, 4, 6];
    let h = 2.0f32;
    let lo = Vec3::new(-3.0, 10.0, 1.0);
    let mut rho = vec![0.0f32; dims.iter().product()];
    for x in 1..dims[0] - 1 {
        for y in 1..dims[1] - 1 {
            for z in 1..dims[2] - 1 {
                rho[(x * dims[1] + y) * dims[2] + z] =
                    0.1 * x as f32 + 0.03 * y as f32 + 0.01 * z as f32;
            }
        }
    }
    let size = Vec3::new(4.0, 3.0, 5.0) * h;
    let m = sylva_geom::Medium::new(
        "puff",
        dims,
        sylva_geom::Aabb {
            min: lo,
            max: lo + size,
        },
        rho,
        "cloud",
    )
    .unwrap();
    scene.media.push(m.clone());
    let out = tmp.path().join("media");
    let opts = mitsuba::MitsubaOptions::for_scene(&scene);
    let written = mitsuba::write(&scene, &out, &opts, &mut |_| true).unwrap();
    assert_eq!(
        written.files,
        mitsuba::files(&scene),
        "planned and written files differ"
    );

    // The VOL file: header, then x fastest, then y, then z, the density unchanged.
    let vol = fs::read(out.join("media/puff.vol")).unwrap();
    assert_eq!(&vol[..4], b"VOL\x03");
    let int = |k: usize| i32::from_le_bytes(vol[4 + 4 * k..8 + 4 * k].try_into().unwrap());
    assert_eq!((int(0), int(1), int(2), int(3), int(4)), (1, 5, 4, 6, 1));
    assert_eq!(vol.len(), 48 + 4 * m.sites());
    let value = |x: usize, y: usize, z: usize| {
        let k = 48 + 4 * ((z * dims[1] + y) * dims[0] + x);
        f32::from_le_bytes(vol[k..k + 4].try_into().unwrap())
    };
    for (x, y, z) in [(1, 1, 1), (3, 2, 4), (2, 1, 3), (0, 2, 2)] {
        assert_eq!(
            value(x, y, z),
            m.density[m.index(x, y, z)],
            "site ({x}, {y}, {z})"
        );
    }

    // The XML: σ_t per metre = σ_t per lattice step / h, albedo σ_s/σ_t, the preset's g;
    // grid values at cell centres, so the volume's box is the sites' box grown by h/2.
    let text = fs::read_to_string(out.join(mitsuba::XML_FILE)).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let medium = doc
        .descendants()
        .find(|n| n.has_tag_name("medium"))
        .unwrap();
    assert_eq!(medium.attribute("type"), Some("heterogeneous"));
    let param = |tag: &str, name: &str| {
        medium
            .descendants()
            .find(|n| n.has_tag_name(tag) && n.attribute("name") == Some(name))
            .and_then(|n| n.attribute("value"))
            .map(floats)
            .unwrap()
    };
    let cloud = sylva_geom::Preset::Cloud.params().colours[0];
    let sigma_t = cloud.sigma_t() as f32;
    assert!(close(&param("float", "scale"), &[sigma_t / h], 1e-6));
    assert!(close(
        &param("rgb", "albedo"),
        &[cloud.sigma_s as f32 / sigma_t; 3],
        1e-6
    ));
    assert!(close(&param("float", "g"), &[cloud.g as f32], 1e-6));
    let volume = medium
        .descendants()
        .find(|n| n.has_tag_name("volume"))
        .unwrap();
    let vt = |name: &str| {
        volume
            .descendants()
            .find(|n| n.has_tag_name(name))
            .and_then(|n| n.attribute("value"))
            .map(floats)
            .unwrap()
    };
    let half = Vec3::splat(h / 2.0);
    assert!(close(&vt("scale"), &(size + 2.0 * half).to_array(), 1e-4));
    assert!(close(&vt("translate"), &(lo - half).to_array(), 1e-4));
}

/// Issue 31 item 1: exporting into the folder of the scene's own OBJ must fail before any
/// file is replaced, a `scene.mtl` that the scene does not read included.
#[test]
fn an_export_onto_its_own_input_replaces_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let e = tmp.path().join("e");
    fs::create_dir(&e).unwrap();
    fs::write(e.join("scene.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let precious = "# precious\nnewmtl bark\nKd 0.5 0.3 0.1\n";
    fs::write(e.join("scene.mtl"), precious).unwrap();
    let toml = e.join("s.toml");
    fs::write(
        &toml,
        "[[models]]\nname = \"thing\"\nmesh = \"scene.obj\"\n\n[[instances]]\nmodel = \"thing\"\nposition = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let scene = sylva_scene::load(toml.to_str().unwrap()).unwrap();
    let before = |name: &str| fs::read(e.join(name)).unwrap();
    let obj_text = before("scene.obj");
    let err = obj::write(&scene, &e, &mut |_| true).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("scene.obj") && msg.contains("is an input of this command"),
        "{msg}"
    );
    assert_eq!(
        before("scene.mtl"),
        precious.as_bytes(),
        "scene.mtl replaced"
    );
    assert_eq!(before("scene.obj"), obj_text);
    let mut names: Vec<String> = fs::read_dir(&e)
        .unwrap()
        .map(|d| d.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["s.toml", "scene.mtl", "scene.obj"],
        "files left behind"
    );
}
