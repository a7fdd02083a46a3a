//! `sylva bench rays`' ray sets and export: what it writes is the scene the kd-tree traced
//! (each primary hit lies on the exported triangle, moved by the exported instance matrix),
//! and its rays are the kind they claim to be.

use std::fs;
use std::path::Path;

use glam::Vec3;
use sylva_pipeline::bench::{export_rays, ray_sets, Answers};
use sylva_trace::{intersect_triangle_vertices, KdTracer, RayQuery, SceneAccel, TraversalConfig};

fn two_boards(dir: &Path) -> sylva_geom::Scene {
    sylva_testkit::write_board(dir);
    let toml = r#"
name = "boards"

[[models]]
name = "board"
mesh = "board.obj"
wood_materials = ["board"]

[[instances]]
model = "board"
position = [0.0, 0.0, 0.0]

[[instances]]
model = "board"
position = [2.5, 1.0, 1.0]
rotation = 30.0
scale = 1.5

[ground]
size = [20.0, 20.0]
color = [0.2, 0.3, 0.4]

[sun]
direction = [0.3, 1.0, 0.0]

[camera]
position = [0.0, 10.0, -6.0]
look_at = [1.0, 0.0, 0.0]
fov = 60.0
resolution = [40, 30]
"#;
    let path = dir.join("boards.toml");
    fs::write(&path, toml).unwrap();
    sylva_scene::load(path.to_str().unwrap()).unwrap()
}

fn f32s(path: &Path) -> Vec<f32> {
    fs::read(path)
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

fn u32s(path: &Path) -> Vec<u32> {
    fs::read(path)
        .unwrap()
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

#[test]
fn exported_triangles_and_matrices_reproduce_the_kd_tree_hits() {
    let dir = tempfile::tempdir().unwrap();
    let scene = two_boards(dir.path());
    let tracer = KdTracer::new(
        SceneAccel::build(&scene).unwrap(),
        TraversalConfig::default(),
    );
    let to_sun = Vec3::new(0.3, 1.0, 0.0).normalize();
    let sets = ray_sets(&tracer, &scene.camera, to_sun, 5).unwrap();
    assert_eq!(sets.primary.len(), 40 * 30);
    // The same rays for the same seed.
    let again = ray_sets(&tracer, &scene.camera, to_sun, 5).unwrap();
    assert_eq!(
        format!("{:?}", sets.incoherent),
        format!("{:?}", again.incoherent)
    );

    let mut hits = vec![None; sets.primary.len()];
    tracer.closest_hits(&sets.primary, &mut hits, &mut Default::default());
    let mut blocked = vec![false; sets.shadow.len()];
    tracer.any_hits(&sets.shadow, &mut blocked, &mut Default::default());
    let mut inc = vec![None; sets.incoherent.len()];
    tracer.closest_hits(&sets.incoherent, &mut inc, &mut Default::default());
    let on_boards = hits
        .iter()
        .flatten()
        .filter(|h| !h.is_ground())
        .map(|h| h.instance)
        .collect::<std::collections::BTreeSet<_>>();
    assert_eq!(on_boards.len(), 2, "the view sees both boards");
    assert_eq!(sets.shadow.len(), hits.iter().flatten().count());
    // The ground under the boards is in their shadow; the boards themselves are not.
    assert!(blocked.iter().any(|&b| b) && !blocked.iter().all(|&b| b));

    let out = dir.path().join("export");
    let answers = Answers {
        primary: &hits,
        shadow: &blocked,
        incoherent: &inc,
    };
    export_rays(&out, &scene, &tracer, &sets, &answers, to_sun, None).unwrap();
    let manifest: serde_json::Value =
        serde_json::from_slice(&fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["format"], "sylva-rays-1");
    assert_eq!(manifest["instances"], 2);
    assert_eq!(manifest["sets"][1]["rays"], sets.shadow.len());

    // Rebuild the world triangles from the files alone and meet each primary ray with the
    // triangle its hit names: the same distance.
    let positions = f32s(&out.join("model0_positions.f32"));
    let indices = u32s(&out.join("model0_indices.u32"));
    let matrices = f32s(&out.join("instance_to_world.f32"));
    let rays = f32s(&out.join("primary_rays.f32"));
    let rows = u32s(&out.join("primary_hits.u32"));
    assert_eq!(rays.len(), sets.primary.len() * 8);
    assert_eq!(rows.len(), sets.primary.len() * 3);
    let corner = |inst: usize, v: u32| {
        let m = &matrices[inst * 12..inst * 12 + 12];
        let p = &positions[v as usize * 3..v as usize * 3 + 3];
        Vec3::new(
            m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3],
            m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7],
            m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11],
        )
    };
    let mut checked = 0;
    for (k, row) in rows.chunks_exact(3).enumerate() {
        let (t, inst, tri) = (f32::from_bits(row[0]), row[1], row[2]);
        let r = &rays[k * 8..k * 8 + 8];
        let ray = sylva_trace::Ray {
            origin: Vec3::new(r[0], r[1], r[2]),
            t_min: r[3],
            dir: Vec3::new(r[4], r[5], r[6]),
            t_max: r[7],
        };
        assert_eq!(ray.origin, sets.primary[k].origin);
        if inst == u32::MAX {
            continue; // the ground, or nothing
        }
        let [a, b, c] = [0, 1, 2].map(|j| corner(inst as usize, indices[tri as usize * 3 + j]));
        let (t2, _, _) = intersect_triangle_vertices(&ray, a, b, c).unwrap_or_else(|| {
            panic!("ray {k} misses the exported triangle {tri} of instance {inst}")
        });
        assert!((t2 - t).abs() <= 1e-4 * t, "ray {k}: t {t} against {t2}");
        checked += 1;
    }
    assert!(checked > 50, "{checked} board hits checked");

    // Shadow rays point at the sun; incoherent rays leave on the side the camera saw.
    for s in &sets.shadow {
        assert!((s.ray.dir - to_sun).length() < 1e-6);
    }
    let mut j = 0;
    for (ray, hit) in sets.primary.iter().zip(&hits) {
        let Some(hit) = hit else { continue };
        let ng = tracer.accel.geometric_normal(hit);
        let d = sets.incoherent[j].dir;
        assert!((d.length() - 1.0).abs() < 1e-5);
        assert!(
            d.dot(ng).signum() == -ray.dir.dot(ng).signum(),
            "ray {j} leaves on the far side"
        );
        j += 1;
    }
}
