//! Rasterises a scene through its camera into a raw RGB file (to check framing and look):
//! `cargo run --release -p sylva-scene --example scene_preview -- SCENE OUT.rgb [DIVISOR]`
//! renders at the camera's resolution divided by DIVISOR (default 2). Z-buffered, leaves
//! alpha-tested, Lambert shading from the scene's sun, sky and ground colours.

use glam::{Vec2, Vec3, Vec4};
use sylva_geom::Filter;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map(String::as_str).unwrap_or("demo");
    let out = args.get(2).map(String::as_str).unwrap_or("scene.rgb");
    let div: u32 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(2).max(1);
    let scene = sylva_scene::load(name).unwrap_or_else(|e| panic!("{e}"));
    let cam = scene.camera;
    let (w, h) = (
        (cam.width / div).max(1) as usize,
        (cam.height / div).max(1) as usize,
    );
    let fwd = (cam.look_at - cam.position).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let tan_half = (0.5 * cam.fov_deg.to_radians()).tan();
    let aspect = w as f32 / h as f32;
    // World point → (pixel, depth along the view axis), None behind the camera.
    let project = |p: Vec3| {
        let d = p - cam.position;
        let z = d.dot(fwd);
        (z > 0.1).then(|| {
            let nx = d.dot(right) / (z * tan_half * aspect);
            let ny = d.dot(up) / (z * tan_half);
            (
                Vec2::new((nx * 0.5 + 0.5) * w as f32, (0.5 - ny * 0.5) * h as f32),
                z,
            )
        })
    };
    let light = scene.sun.to_sun().as_vec3();
    let sky = Vec3::from_array(scene.sky_color);
    let mut color = vec![sky; w * h];
    let mut depth = vec![f32::INFINITY; w * h];
    // Ground: colour pixels whose view ray hits y = 0 inside the ground rectangle.
    let half = scene
        .ground
        .size
        .map(|s| Vec2::new(s[0], s[1]) * 0.5)
        .unwrap_or(Vec2::ZERO);
    for y in 0..h {
        for x in 0..w {
            let ndc = Vec2::new(
                (x as f32 + 0.5) / w as f32 * 2.0 - 1.0,
                1.0 - (y as f32 + 0.5) / h as f32 * 2.0,
            );
            let dir = (fwd + right * ndc.x * tan_half * aspect + up * ndc.y * tan_half).normalize();
            if scene.ground.enabled && dir.y < 0.0 {
                let t = -cam.position.y / dir.y;
                let p = cam.position + dir * t;
                if p.x.abs() <= half.x && p.z.abs() <= half.y {
                    let k = y * w + x;
                    color[k] =
                        Vec3::from_array(scene.ground.color) * (0.3 + 0.7 * light.y.max(0.0)) * 2.0;
                    depth[k] = (p - cam.position).dot(fwd);
                }
            }
        }
    }
    for (inst, model) in scene.instances_with_models() {
        let to_world = inst.transform();
        let m = &model.mesh;
        let world: Vec<Vec3> = m
            .positions
            .iter()
            .map(|p| to_world.transform_point3(Vec3::from_array(*p)))
            .collect();
        let screen: Vec<Option<(Vec2, f32)>> = world.iter().map(|&p| project(p)).collect();
        for (t, tri) in m.indices.iter().enumerate() {
            let [Some(a), Some(b), Some(c)] = tri.map(|i| screen[i as usize]) else {
                continue;
            };
            let s = [a.0, b.0, c.0];
            let z = [a.1, b.1, c.1];
            let area = (s[1] - s[0]).perp_dot(s[2] - s[0]);
            if area.abs() < 1e-12 {
                continue;
            }
            let lo = s[0].min(s[1]).min(s[2]).max(Vec2::ZERO);
            let hi = s[0]
                .max(s[1])
                .max(s[2])
                .min(Vec2::new(w as f32 - 1.0, h as f32 - 1.0));
            if lo.x > hi.x || lo.y > hi.y {
                continue;
            }
            let mat = &model.materials[m.material_ids[t] as usize];
            let n = to_world
                .transform_vector3(Vec3::from_array(m.normals[tri[0] as usize]))
                .normalize_or_zero();
            let ndl = if mat.two_sided {
                n.dot(light).abs()
            } else {
                n.dot(light).max(0.0)
            };
            for y in lo.y.floor() as usize..=hi.y as usize {
                for x in lo.x.floor() as usize..=hi.x as usize {
                    let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = (s[1] - q).perp_dot(s[2] - q) / area;
                    let w1 = (s[2] - q).perp_dot(s[0] - q) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let d = w0 * z[0] + w1 * z[1] + w2 * z[2];
                    let k = y * w + x;
                    if d >= depth[k] {
                        continue;
                    }
                    let uv = Vec2::from_array(m.uvs[tri[0] as usize]) * w0
                        + Vec2::from_array(m.uvs[tri[1] as usize]) * w1
                        + Vec2::from_array(m.uvs[tri[2] as usize]) * w2;
                    let texel = mat
                        .texture
                        .as_ref()
                        .map(|t| t.sample(uv.x, uv.y, Filter::Nearest))
                        .unwrap_or(Vec4::ONE);
                    if texel.w < 0.5 {
                        continue;
                    }
                    depth[k] = d;
                    color[k] = texel.truncate() * (0.35 + 0.65 * ndl);
                }
            }
        }
    }
    let bytes: Vec<u8> = color
        .iter()
        .flat_map(|c| c.to_array().map(|v| (v.clamp(0.0, 1.0) * 255.0) as u8))
        .collect();
    std::fs::write(out, bytes).expect("write");
    println!("{w}x{h}");
}
