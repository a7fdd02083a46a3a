//! The Newell teapot: the tessellation interpolates the patch corners, the body is a surface
//! of revolution, and the patches of the body and bottom meet without gaps.

use glam::Vec3;
use sylva_geom::MaterialKind;
use sylva_grow::teapot::{teapot_mesh, teapot_model, PATCH_COUNT};

const N: usize = 8;

fn patch_vertex(mesh: &sylva_geom::Mesh, patch: usize, i: usize, j: usize) -> Vec3 {
    Vec3::from_array(mesh.positions[patch * (N + 1) * (N + 1) + i * (N + 1) + j])
}

#[test]
fn corners_are_control_points_and_bounds_are_the_teapots() {
    let mesh = teapot_mesh(N);
    assert_eq!(PATCH_COUNT, 32);
    assert_eq!(mesh.vertex_count(), 32 * (N + 1) * (N + 1));
    assert!(mesh.validate(1).is_ok());
    // Patch 0 (rim) starts at the data's first point (1.4, 0, 2.4), z up → y up.
    assert_eq!(patch_vertex(&mesh, 0, 0, 0), Vec3::new(1.4, 2.4, 0.0));
    // The lid's knob tip is the highest point, 3.15; the bottom's centre the lowest, 0.
    let b = mesh.bounds();
    assert!(
        (b.max.y - 3.15).abs() < 1e-6 && b.min.y.abs() < 1e-6,
        "{b:?}"
    );
    // Spout towards +x, handle towards -x, symmetric about the x-y plane.
    assert!(b.max.x > 3.3 && b.max.x < 3.525, "{b:?}");
    assert!(b.min.x < -2.8 && b.min.x >= -3.0, "{b:?}");
    assert!(
        (b.max.z + b.min.z).abs() < 1e-5 && (b.max.z - 2.0).abs() < 1e-5,
        "{b:?}"
    );
    // Degenerate triangles at the knob and the bottom centre are left out.
    assert!(mesh.triangle_count() < 32 * 2 * N * N);
    assert!(mesh.triangle_count() > 31 * 2 * N * N);
}

#[test]
fn the_body_is_a_surface_of_revolution() {
    // Body patches 4-7 (upper) and 8-11 (lower): along a row the radius does not depend on
    // the angle (cubic arcs with handle 0.56 approximate the quarter circles to 0.41 %).
    let mesh = teapot_mesh(N);
    for (first, i) in [4, 8]
        .into_iter()
        .flat_map(|f| (0..=N).map(move |i| (f, i)))
    {
        let radii: Vec<f32> = (first..first + 4)
            .flat_map(|p| (0..=N).map(move |j| (p, j)))
            .map(|(p, j)| {
                let v = patch_vertex(&mesh, p, i, j);
                (v.x * v.x + v.z * v.z).sqrt()
            })
            .collect();
        let max = radii.iter().cloned().fold(f32::MIN, f32::max);
        let min = radii.iter().cloned().fold(f32::MAX, f32::min);
        assert!(
            (max - min) / max < 0.0042,
            "patches {first}.. row {i}: {min}..{max}"
        );
    }
    // Normals of the body point away from the axis.
    for p in 4..12 {
        for k in 0..(N + 1) * (N + 1) {
            let idx = p * (N + 1) * (N + 1) + k;
            let pos = Vec3::from_array(mesh.positions[idx]);
            let n = Vec3::from_array(mesh.normals[idx]);
            assert!((n.length() - 1.0).abs() < 1e-4);
            let radial = Vec3::new(pos.x, 0.0, pos.z).normalize();
            assert!(n.dot(radial).abs() > 0.2, "patch {p} vertex {k}");
        }
    }
}

#[test]
fn body_and_bottom_are_closed() {
    // Every boundary vertex of the body and bottom patches lies on a boundary vertex of a
    // neighbouring patch, except the body's top edge, which meets the rim.
    let mesh = teapot_mesh(N);
    let closed: Vec<usize> = (4..12).chain(28..32).collect();
    let boundary = |p: usize| {
        (0..=N)
            .flat_map(move |i| (0..=N).map(move |j| (p, i, j)))
            .filter(|&(_, i, j)| i == 0 || j == 0 || i == N || j == N)
    };
    for &p in &closed {
        for (_, i, j) in boundary(p) {
            let v = patch_vertex(&mesh, p, i, j);
            let matched = (0..PATCH_COUNT)
                .filter(|&q| q != p)
                .flat_map(boundary)
                .any(|(q, a, b)| patch_vertex(&mesh, q, a, b).distance(v) < 1e-5);
            let degenerate = v.x.abs() < 1e-6 && v.z.abs() < 1e-6;
            assert!(matched || degenerate, "patch {p} ({i}, {j}) at {v}");
        }
    }
}

#[test]
fn the_model_is_one_solid_material() {
    let m = teapot_model(4, [0.8, 0.3, 0.2]);
    assert_eq!(m.materials.len(), 1);
    assert_eq!(m.materials[0].kind, MaterialKind::Solid);
    assert!(m.mesh.material_ids.iter().all(|&id| id == 0));
    assert_eq!(m.bounds, m.mesh.bounds());
}
