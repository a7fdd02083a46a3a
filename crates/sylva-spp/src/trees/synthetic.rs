//! Models with known answers for checking the tree machinery: a "tree" shaped like a slab
//! (square leaves with random positions and orientations filling a wide, thin box: the
//! plane-parallel condition) and stacks of large horizontal plates (closed-form
//! inter-reflection); and a grown tree's planophile limit ([`horizontal_leaves`]: every leaf
//! turned flat where it hangs), for telling the leaves' angles from the crown's shape.

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

/// `model` with every leaf mesh (a connected group of leaf triangles: one leaf quad of a
/// grown tree) turned horizontal: rotated about its area-weighted centroid by the smallest
/// rotation that takes its mean normal to the nearer of up and down. Position, area, outline
/// and texture coordinates stay; wood stays as it is, and so does a leaf group that shares a
/// vertex with wood (the generator's never do). Leaves of the result all have `|n·y| = 1`:
/// the planophile limit of the same crown.
pub fn horizontal_leaves(model: &Model) -> Model {
    let mut mesh = model.mesh.clone();
    let n = mesh.vertex_count();
    let is_leaf = |t: usize| {
        model
            .materials
            .get(mesh.material_ids[t] as usize)
            .is_some_and(|m| m.kind == MaterialKind::Leaf)
    };
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            let next = parent[parent[x as usize] as usize];
            parent[x as usize] = next;
            x = next;
        }
        x
    }
    let mut on_wood = vec![false; n];
    let mut on_leaf = vec![false; n];
    for (t, tri) in mesh.indices.iter().enumerate() {
        if !is_leaf(t) {
            tri.iter().for_each(|&v| on_wood[v as usize] = true);
            continue;
        }
        tri.iter().for_each(|&v| on_leaf[v as usize] = true);
        let a = find(&mut parent, tri[0]);
        for &v in &tri[1..] {
            let b = find(&mut parent, v);
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    // Per group (root vertex): twice the area-weighted normal, area-weighted centroid × 6,
    // twice the area, and whether it touches wood.
    let mut normal = vec![Vec3::ZERO; n];
    let mut centroid = vec![Vec3::ZERO; n];
    let mut area = vec![0.0f32; n];
    let mut touches_wood = vec![false; n];
    for (t, tri) in mesh.indices.iter().enumerate() {
        if !is_leaf(t) {
            continue;
        }
        let r = find(&mut parent, tri[0]) as usize;
        let [a, b, c] = tri.map(|v| Vec3::from_array(mesh.positions[v as usize]));
        let cross = (b - a).cross(c - a);
        let twice_area = cross.length();
        normal[r] += cross;
        centroid[r] += (a + b + c) * twice_area;
        area[r] += twice_area;
        touches_wood[r] |= tri.iter().any(|&v| on_wood[v as usize]);
    }
    let mut turn = vec![None; n];
    for r in 0..n {
        if find(&mut parent, r as u32) as usize != r || area[r] <= 0.0 || touches_wood[r] {
            continue;
        }
        let nrm = normal[r].normalize_or_zero();
        if nrm == Vec3::ZERO {
            continue;
        }
        let up = if nrm.y >= 0.0 { Vec3::Y } else { Vec3::NEG_Y };
        turn[r] = Some((
            centroid[r] / (3.0 * area[r]),
            Quat::from_rotation_arc(nrm, up),
        ));
    }
    for (v, _) in on_leaf.iter().enumerate().filter(|(_, &leaf)| leaf) {
        let r = find(&mut parent, v as u32) as usize;
        if let Some((c, q)) = turn[r] {
            let p = Vec3::from_array(mesh.positions[v]);
            mesh.positions[v] = (c + q * (p - c)).to_array();
            if let Some(nv) = mesh.normals.get_mut(v) {
                *nv = (q * Vec3::from_array(*nv)).to_array();
            }
        }
    }
    Model::new(model.name.clone(), mesh, model.materials.clone())
}
