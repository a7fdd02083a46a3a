//! Models with known answers for checking the tree machinery: a "tree" shaped like a slab
//! (square leaves with random positions and orientations filling a wide, thin box: the
//! plane-parallel condition) and stacks of large horizontal plates (closed-form
//! inter-reflection).

use glam::{Quat, Vec3};
use sylva_core::SplitMix64;
use sylva_geom::{Instance, Material, MaterialKind, Mesh, Model};

/// An untextured (opaque) leaf material.
pub fn leaf_material() -> Material {
    Material {
        name: "leaf".into(),
        kind: MaterialKind::Leaf,
        base_color: [0.2, 0.5, 0.1],
        texture: None,
        two_sided: true,
        optics: sylva_geom::Optics::FOREST_LEAF,
    }
}

/// Adds a square of side `side` centred on `centre`, its normal along `normal` (unit).
fn push_square(mesh: &mut Mesh, centre: Vec3, normal: Vec3, spin: f32, side: f32) {
    let rot = Quat::from_rotation_arc(Vec3::Y, normal) * Quat::from_rotation_y(spin);
    let h = 0.5 * side;
    let corners =
        [(-h, -h), (h, -h), (h, h), (-h, h)].map(|(x, z)| centre + rot * Vec3::new(x, 0.0, z));
    let uv = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let ids: Vec<u32> = corners
        .iter()
        .zip(uv)
        .map(|(&c, uv)| mesh.push_vertex(c, normal, uv))
        .collect();
    mesh.push_triangle(ids[0], ids[1], ids[2], 0);
    mesh.push_triangle(ids[0], ids[2], ids[3], 0);
}

/// `count` square leaves of side `side`, uniformly placed in the box `[-half, half] ×
/// [bottom, bottom + thickness] × [-half, half]`, with isotropic random orientations.
/// With `n` leaves per unit volume the mean number of leaves a line crosses per unit length
/// is `n · side² / 2` (the mean of `|cos|` over the sphere is 1/2).
pub fn leaf_slab(
    half: f32,
    bottom: f32,
    thickness: f32,
    side: f32,
    count: usize,
    seed: u64,
) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut u = || rng.next_f64() as f32;
    let mut mesh = Mesh::default();
    for _ in 0..count {
        let c = Vec3::new(
            (2.0 * u() - 1.0) * half,
            bottom + u() * thickness,
            (2.0 * u() - 1.0) * half,
        );
        let z = 2.0 * u() - 1.0;
        let phi = std::f32::consts::TAU * u();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let n = Vec3::new(r * phi.cos(), z, r * phi.sin()).normalize();
        push_square(&mut mesh, c, n, std::f32::consts::TAU * u(), side);
    }
    Model::new("leaf slab", mesh, vec![leaf_material()])
}

/// Horizontal square plates of side `side` centred on the y axis at heights `ys`, each a
/// two-triangle leaf.
pub fn plates(side: f32, ys: &[f32]) -> Model {
    let mut mesh = Mesh::default();
    for &y in ys {
        push_square(&mut mesh, Vec3::new(0.0, y, 0.0), Vec3::Y, 0.0, side);
    }
    Model::new("plates", mesh, vec![leaf_material()])
}

/// One instance of model 0 at the origin.
pub fn single_instance() -> Vec<Instance> {
    vec![Instance {
        model: 0,
        position: Vec3::ZERO,
        rotation_deg: 0.0,
        scale: 1.0,
    }]
}
