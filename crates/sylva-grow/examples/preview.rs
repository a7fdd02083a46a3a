//! Rasterises a built-in species from the side into a raw RGB file (for eyeballing forms):
//! `cargo run --release -p sylva-grow --example preview -- NAME OUT.rgb [SIZE]`.
//! Orthographic, z-buffered, leaves alpha-tested with their texture, Lambert shading.

use glam::{Vec2, Vec3};
use sylva_geom::Filter;
use sylva_grow::Species;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map(String::as_str).unwrap_or("red_maple");
    let out = args.get(2).map(String::as_str).unwrap_or("preview.rgb");
    let size: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(400);
    let species = Species::builtin(name).expect("built-in species");
    let model = species.build_model().expect("generate");
    let m = &model.mesh;
    let b = model.bounds;
    let extent = b.size().max_element() * 1.05;
    let center = (b.min + b.max) * 0.5;
    let light = Vec3::new(0.4, 0.8, -0.45).normalize();
    let mut color = vec![[200u8, 220, 240]; size * size];
    let mut depth = vec![f32::INFINITY; size * size];
    let to_px = |p: Vec3| {
        Vec2::new(
            ((p.x - center.x) / extent + 0.5) * size as f32,
            (1.0 - ((p.y - center.y) / extent + 0.5)) * size as f32,
        )
    };
    for (t, tri) in m.indices.iter().enumerate() {
        let mat = &model.materials[m.material_ids[t] as usize];
        let p: Vec<Vec3> = tri
            .iter()
            .map(|&i| Vec3::from_array(m.positions[i as usize]))
            .collect();
        let uv: Vec<Vec2> = tri
            .iter()
            .map(|&i| Vec2::from_array(m.uvs[i as usize]))
            .collect();
        let n: Vec<Vec3> = tri
            .iter()
            .map(|&i| Vec3::from_array(m.normals[i as usize]))
            .collect();
        let s: Vec<Vec2> = p.iter().map(|&q| to_px(q)).collect();
        let area = (s[1] - s[0]).perp_dot(s[2] - s[0]);
        if area.abs() < 1e-12 {
            continue;
        }
        let lo = s[0].min(s[1]).min(s[2]).max(Vec2::ZERO);
        let hi = s[0].max(s[1]).max(s[2]).min(Vec2::splat(size as f32 - 1.0));
        for y in lo.y as usize..=hi.y as usize {
            for x in lo.x as usize..=hi.x as usize {
                let q = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let w0 = (s[1] - q).perp_dot(s[2] - q) / area;
                let w1 = (s[2] - q).perp_dot(s[0] - q) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p[0].z + w1 * p[1].z + w2 * p[2].z;
                let k = y * size + x;
                if z >= depth[k] {
                    continue;
                }
                let tuv = uv[0] * w0 + uv[1] * w1 + uv[2] * w2;
                let texel = match &mat.texture {
                    Some(t) => t.sample(tuv.x, tuv.y, Filter::Nearest),
                    None => glam::Vec4::ONE,
                };
                if texel.w < 0.5 {
                    continue;
                }
                let nn = (n[0] * w0 + n[1] * w1 + n[2] * w2).normalize_or_zero();
                let ndl = if mat.two_sided {
                    nn.dot(light).abs()
                } else {
                    nn.dot(light).max(0.0)
                };
                let shade = 0.35 + 0.65 * ndl;
                depth[k] = z;
                color[k] = [0, 1, 2].map(|c| (texel[c] * 255.0 * shade).clamp(0.0, 255.0) as u8);
            }
        }
    }
    let bytes: Vec<u8> = color.into_iter().flatten().collect();
    std::fs::write(out, bytes).expect("write");
    println!(
        "{name}: {} triangles, size {:?}",
        m.triangle_count(),
        b.size()
    );
}
