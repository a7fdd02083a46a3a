//! Scenes and rays for the tracers' tests (the CPU tracer's, and the GPU tracer's against it).

use glam::Vec3;
use std::sync::Arc;
use sylva_core::SplitMix64;
use sylva_geom::{Instance, Material, MaterialKind, Mesh, Model, Texture, Wrap};
use sylva_trace::{Ray, SceneAccel};

/// The tests' random numbers, from `seed`.
pub fn rng(seed: u64) -> SplitMix64 {
    SplitMix64::new(seed)
}

/// Uniform in [lo, hi).
pub fn uniform(r: &mut SplitMix64, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * r.next_f64() as f32
}

/// A random unit vector.
pub fn unit(r: &mut SplitMix64) -> Vec3 {
    loop {
        let v = Vec3::new(
            uniform(r, -1.0, 1.0),
            uniform(r, -1.0, 1.0),
            uniform(r, -1.0, 1.0),
        );
        let l = v.length();
        if l > 0.05 && l <= 1.0 {
            return v / l;
        }
    }
}

/// Opaque bark.
pub fn wood() -> Material {
    Material {
        name: "wood".into(),
        kind: MaterialKind::Wood,
        base_color: [0.4, 0.3, 0.2],
        texture: None,
        two_sided: false,
        optics: sylva_geom::Optics::OPAQUE,
    }
}

/// `n` random triangles in the cube [-1, 1]³ (sizes mixed, some thin slivers, some tiny),
/// one opaque material.
pub fn soup(n: usize, seed: u64) -> Model {
    let mut r = rng(seed);
    let mut m = Mesh::default();
    for i in 0..n {
        let c = Vec3::new(
            uniform(&mut r, -1.0, 1.0),
            uniform(&mut r, -1.0, 1.0),
            uniform(&mut r, -1.0, 1.0),
        );
        let size = match i % 4 {
            0 => 0.02,
            1 => 0.1,
            2 => 0.4,
            _ => 0.004,
        };
        let a = m.push_vertex(c + unit(&mut r) * size, Vec3::Y, [0.0, 0.0]);
        let b = m.push_vertex(c + unit(&mut r) * size, Vec3::Y, [1.0, 0.0]);
        let d = m.push_vertex(c + unit(&mut r) * size, Vec3::Y, [0.0, 1.0]);
        m.push_triangle(a, b, d, 0);
    }
    Model::new("soup", m, vec![wood()])
}

/// A random ray starting outside or inside the cube [-s, s]³, aimed near the origin.
pub fn random_ray(r: &mut SplitMix64, s: f32) -> Ray {
    let o = unit(r) * uniform(r, 0.0, 2.5 * s);
    let target = Vec3::new(uniform(r, -s, s), uniform(r, -s, s), uniform(r, -s, s));
    let d = (target - o).normalize_or(Vec3::X);
    Ray::new(o, d)
}

/// An `n`×`n` checkerboard RGBA texture; squares with (i + j) even are opaque.
pub fn checker_texture(n: u32) -> Texture {
    Texture::from_fn(n, n, Wrap::Clamp, |u, v| {
        let (i, j) = ((u * n as f32) as u32, (v * n as f32) as u32);
        if (i + j) % 2 == 0 {
            [20, 200, 20, 255]
        } else {
            [0, 0, 0, 0]
        }
    })
}

/// A two-sided forest leaf cut out by `tex`'s alpha.
pub fn leaf_material(tex: Texture) -> Material {
    Material {
        name: "leaf".into(),
        kind: MaterialKind::Leaf,
        base_color: [0.1, 0.6, 0.1],
        texture: Some(Arc::new(tex)),
        two_sided: true,
        optics: sylva_geom::Optics::FOREST_LEAF,
    }
}

/// 40 instances of two soups piled on nearly the same spot, plus an exact copy of instance
/// 7 (ties between instances), on a ground: top-level leaves hold more instances than the
/// closest-hit query sorts by entry (16).
pub fn crowded_scene() -> SceneAccel {
    let models = vec![soup(120, 21), soup(80, 22)];
    let mut instances = Vec::new();
    let mut r = rng(23);
    for k in 0..40 {
        instances.push(Instance {
            model: (k % 2) as u32,
            position: Vec3::new(
                uniform(&mut r, -0.3, 0.3),
                1.0 + uniform(&mut r, -0.3, 0.3),
                uniform(&mut r, -0.3, 0.3),
            ),
            rotation_deg: uniform(&mut r, 0.0, 360.0),
            scale: uniform(&mut r, 0.5, 1.5),
        });
    }
    instances.push(instances[7]);
    SceneAccel::from_parts(&models, &instances, Some([4.0, 4.0])).unwrap()
}
