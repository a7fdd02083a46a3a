// A frame on the GPU: per pixel, each sample's primary ray, its shadow ray and its shading,
// the CPU renderer's functions one for one (same names, same operations in the same order):
//
//   render.rs    Renderer::sample_geometry, Renderer::shadow_ray, Renderer::shade
//   shade.rs     local_light, needs_shadow_ray, LinearTexture::sample
//   indirect.rs  ModelGridLight::plant, ModelGridLight::ground_sky, GroundIndex::at
//   lighting.rs  ModelLighting::sample
//
// Included after the scene's WGSL (sylva-trace-gpu: closest_hit, any_hit, to_model, ...)
// and a generated prelude that binds the shading data: `shade_word_at(i) -> u32`, one pool
// of words holding per model its mesh data, materials, linear textures and LB grid, the
// instances' world transforms and the ground index (offsets in `shading.tables` and in the
// records), and `shading: ShadeParams`. A change to the shading formulas changes both
// sides; the test `gpu_shading_matches_the_cpu_per_pixel` compares them.

struct ShadeParams {
    // Sun colour × irradiance; w: +∞ (the shadow rays' t_max).
    sun: vec4<f32>,
    to_sun: vec4<f32>,
    ground_colour: vec4<f32>,
    sky: vec4<f32>,
    leaf_transmission: vec4<f32>,
    // indirect, sky_ambient, leaf k_s, leaf shininess
    k: vec4<f32>,
    // wood k_s, wood shininess
    k2: vec4<f32>,
    // Pool offsets: model records (8 words each), instances' world transforms (12 words
    // each), 0, 0.
    tables: vec4<u32>,
    // Ground index: cell starts (nx·nz + 1 words), instance lists, nx, nz (0: no index).
    ground: vec4<u32>,
    // Ground index: origin x, origin z, end x, end z.
    ground_box: vec4<f32>,
    // Ground index: 1 / cell size.
    ground_cell: vec4<f32>,
}

struct FrameParams {
    // Pixels of the band: width, rows; samples per pixel; 1 / samples as f32 bits.
    size: vec4<u32>,
}

@group(2) @binding(0) var<uniform> frame: FrameParams;
// Two per sample, pixel by pixel, sample by sample: (origin, t_min), (direction, t_max).
@group(2) @binding(1) var<storage, read> frame_rays: array<vec4<f32>>;
// Four per pixel: local (w: 1 when the CPU must render the pixel), indirect (w: shadow rays
// traced, as bits), albedo, sky.
@group(2) @binding(2) var<storage, read_write> frame_pixels: array<vec4<f32>>;

fn word_f(i: u32) -> f32 {
    return bitcast<f32>(shade_word_at(i));
}

fn word_vec3(i: u32) -> vec3<f32> {
    return vec3<f32>(word_f(i), word_f(i + 1u), word_f(i + 2u));
}

// f32::max and f32::min: a NaN operand gives the other one.
fn fmax_(a: f32, b: f32) -> f32 {
    if (is_nan_(a)) {
        return b;
    }
    if (is_nan_(b)) {
        return a;
    }
    return select(a, b, b > a);
}

fn fmin_(a: f32, b: f32) -> f32 {
    if (is_nan_(a)) {
        return b;
    }
    if (is_nan_(b)) {
        return a;
    }
    return select(a, b, b < a);
}

fn fmax3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(fmax_(a.x, b.x), fmax_(a.y, b.y), fmax_(a.z, b.z));
}

fn fmin3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(fmin_(a.x, b.x), fmin_(a.y, b.y), fmin_(a.z, b.z));
}

// glam's Vec3::lerp.
fn lerp3(a: vec3<f32>, b: vec3<f32>, s: f32) -> vec3<f32> {
    return a * (1.0 - s) + b * s;
}

// glam's Vec3::normalize_or_zero.
fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / sqrt(dot_(v, v));
    if (is_finite_(rcp) && rcp > 0.0) {
        return v * rcp;
    }
    return vec3<f32>(0.0, 0.0, 0.0);
}

fn is_finite3(v: vec3<f32>) -> bool {
    return is_finite_(v.x) && is_finite_(v.y) && is_finite_(v.z);
}

// sylva_core::colour::luminance.
fn luminance(c: vec3<f32>) -> f32 {
    return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z;
}

// f32::powf where WGSL's pow is undefined (x = 0, y = 0).
fn powf(x: f32, y: f32) -> f32 {
    if (y == 0.0) {
        return 1.0;
    }
    if (x == 0.0) {
        return 0.0;
    }
    return pow(x, y);
}

// Affine3A::transform_vector3 and transform_point3 of instance i's model → world map.
fn world_vector(i: u32, v: vec3<f32>) -> vec3<f32> {
    let k = shading.tables.y + 12u * i;
    return word_vec3(k) * v.x + word_vec3(k + 3u) * v.y + word_vec3(k + 6u) * v.z;
}

fn model_point(i: u32, p: vec3<f32>) -> vec3<f32> {
    let x = inst_at(4u * i);
    return x.xyz * p.x + inst_at(4u * i + 1u).xyz * p.y + inst_at(4u * i + 2u).xyz * p.z
        + inst_at(4u * i + 3u).xyz;
}

fn instance_model(i: u32) -> u32 {
    return bitcast<u32>(inst_at(4u * i).w);
}

// A model's shading record.
struct ShadeModel {
    // Vertex indices, 3 words per triangle.
    indices: u32,
    // Vertex normals, 3 words per vertex (NONE: the mesh has none).
    normals: u32,
    // Vertex texture coordinates, 2 words per vertex (NONE: none).
    uvs: u32,
    // Material ids, 4 per word (NONE: all 0).
    material_ids: u32,
    // Material records (8 words each) and their count.
    materials: u32,
    material_count: u32,
    // LB grid record (NONE: no LB light on this model).
    grid: u32,
}

fn shade_model(m: u32) -> ShadeModel {
    let k = shading.tables.x + 8u * m;
    return ShadeModel(shade_word_at(k), shade_word_at(k + 1u), shade_word_at(k + 2u), shade_word_at(k + 3u),
        shade_word_at(k + 4u), shade_word_at(k + 5u), shade_word_at(k + 6u));
}

fn material_id(sm: ShadeModel, triangle: u32) -> u32 {
    if (sm.material_ids == NONE) {
        return 0u;
    }
    return (shade_word_at(sm.material_ids + triangle / 4u) >> (8u * (triangle % 4u))) & 0xffu;
}

// Material record: leaf, base colour (3), linear texels (NONE: untextured), width, height, wrap.
fn material_word(sm: ShadeModel, mat: u32, k: u32) -> u32 {
    return shade_word_at(sm.materials + 8u * mat + k);
}

// Renderer::is_leaf.
fn is_leaf(sm: ShadeModel, triangle: u32) -> bool {
    let m = material_id(sm, triangle);
    return m < sm.material_count && material_word(sm, m, 0u) == 1u;
}

// ---- shade.rs ---------------------------------------------------------------------------------

struct SurfacePoint {
    normal: vec3<f32>,
    view: vec3<f32>,
    colour: vec3<f32>,
    leaf: bool,
}

// shade::local_light.
fn local_light(s: SurfacePoint, to_sun: vec3<f32>, lit: bool) -> vec3<f32> {
    if (!lit) {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    let cos = dot_(s.normal, to_sun);
    if (cos > 0.0) {
        var ks = shading.k2.x;
        var shininess = shading.k2.y;
        if (s.leaf) {
            ks = shading.k.z;
            shininess = shading.k.w;
        }
        let r = 2.0 * cos * s.normal - to_sun;
        let spec = ks * powf(fmax_(dot_(r, s.view), 0.0), shininess);
        return s.colour * cos + vec3<f32>(spec, spec, spec);
    } else if (s.leaf) {
        return s.colour * shading.leaf_transmission.xyz * (-cos);
    }
    return vec3<f32>(0.0, 0.0, 0.0);
}

// shade::needs_shadow_ray.
fn needs_shadow_ray(s: SurfacePoint, to_sun: vec3<f32>) -> bool {
    let cos = dot_(s.normal, to_sun);
    return cos > 0.0 || (s.leaf && cos < 0.0);
}

// LinearTexture::texel and LinearTexture::sample (bilinear, texel centres at (x + 0.5) / w).
fn texel(texels: u32, w: u32, h: u32, wrap: u32, x: i32, y: i32) -> vec3<f32> {
    let i = wrap_index(y, h, wrap) * w + wrap_index(x, w, wrap);
    return word_vec3(texels + 3u * i);
}

fn linear_texture_sample(sm: ShadeModel, mat: u32, uv_in: vec2<f32>) -> vec3<f32> {
    let texels = material_word(sm, mat, 4u);
    let w = material_word(sm, mat, 5u);
    let h = material_word(sm, mat, 6u);
    let wrap = material_word(sm, mat, 7u);
    var uv = vec2<f32>(0.0, 0.0);
    if (is_finite_(uv_in.x) && is_finite_(uv_in.y)) {
        uv = uv_in;
    }
    let g = uv * vec2<f32>(f32(w), f32(h)) - 0.5;
    let f = floor(g);
    let t = g - f;
    let x = i32(f.x);
    let y = i32(f.y);
    let top = lerp3(texel(texels, w, h, wrap, x, y), texel(texels, w, h, wrap, x + 1, y), t.x);
    let bottom = lerp3(texel(texels, w, h, wrap, x, y + 1), texel(texels, w, h, wrap, x + 1, y + 1), t.x);
    return lerp3(top, bottom, t.y);
}

// ---- lighting.rs and indirect.rs ------------------------------------------------------------

// ModelLighting::sample: trilinear RGB at model-space point p of the grid record `g`
// (nx, ny, nz, values, origin (3), inv_cell (3), last (3), model bounds min (3), max (3)).
fn lighting_sample(g: u32, p: vec3<f32>) -> vec3<f32> {
    let ny = shade_word_at(g + 1u);
    let nz = shade_word_at(g + 2u);
    let values = shade_word_at(g + 3u);
    let origin = word_vec3(g + 4u);
    let inv_cell = word_vec3(g + 7u);
    let last = word_vec3(g + 10u);
    let f = fmin3(fmax3((p - origin) * inv_cell, vec3<f32>(0.0, 0.0, 0.0)), last);
    let i = fmin3(floor(f), last - vec3<f32>(1.0, 1.0, 1.0));
    let t = f - i;
    let sy = nz;
    let sx = ny * nz;
    let base = u32(i.x) * sx + u32(i.y) * sy + u32(i.z);
    let x00 = lerp3(word_vec3(values + 3u * base), word_vec3(values + 3u * (base + sx)), t.x);
    let x01 = lerp3(word_vec3(values + 3u * (base + 1u)), word_vec3(values + 3u * (base + sx + 1u)), t.x);
    let x10 = lerp3(word_vec3(values + 3u * (base + sy)), word_vec3(values + 3u * (base + sx + sy)), t.x);
    let x11 = lerp3(word_vec3(values + 3u * (base + sy + 1u)), word_vec3(values + 3u * (base + sx + sy + 1u)), t.x);
    let y0 = lerp3(x00, x10, t.y);
    let y1 = lerp3(x01, x11, t.y);
    return lerp3(y0, y1, t.z);
}

// ModelGridLight::ground_sky: the product over the trees whose LB grid covers ground point
// p of their LB luminance there, faded to 1 over each grid footprint's outer 20 %.
fn ground_sky(p: vec3<f32>) -> f32 {
    var f = 1.0;
    let nx = shading.ground.z;
    let nz = shading.ground.w;
    if (nx == 0u) {
        return f;
    }
    // GroundIndex::at (the comparisons are false for NaN).
    let q = vec2<f32>(p.x, p.z);
    if (!(q.x >= shading.ground_box.x && q.y >= shading.ground_box.y && q.x <= shading.ground_box.z && q.y <= shading.ground_box.w)) {
        return f;
    }
    let inv_cell = shading.ground_cell.x;
    let cx = min(u32(fmax_(floor((q.x - shading.ground_box.x) * inv_cell), 0.0)), nx - 1u);
    let cz = min(u32(fmax_(floor((q.y - shading.ground_box.y) * inv_cell), 0.0)), nz - 1u);
    let cell = cz * nx + cx;
    let first = shade_word_at(shading.ground.x + cell);
    let end = shade_word_at(shading.ground.x + cell + 1u);
    for (var k = first; k < end; k++) {
        let i = shade_word_at(shading.ground.y + k);
        let g = shade_model(instance_model(i)).grid;
        if (g == NONE) {
            continue;
        }
        let bmin = word_vec3(g + 13u);
        let bmax = word_vec3(g + 16u);
        let pm = model_point(i, p);
        let margin = 0.05 * (bmax.y - bmin.y) + 1e-3f;
        if (pm.x >= bmin.x && pm.x <= bmax.x && pm.z >= bmin.z && pm.z <= bmax.z && pm.y >= bmin.y - margin) {
            let edge = fmin_(fmin_(fmin_(pm.x - bmin.x, bmax.x - pm.x), pm.z - bmin.z), bmax.z - pm.z);
            let width = 0.2 * fmin_(bmax.x - bmin.x, bmax.z - bmin.z);
            var w = 1.0;
            if (width > 0.0) {
                w = clamp(edge / width, 0.0, 1.0);
            }
            let lb = clamp(luminance(lighting_sample(g, pm)), 0.0, 1.0);
            f *= 1.0 - w * (1.0 - lb);
        }
    }
    return f;
}

// ---- render.rs ------------------------------------------------------------------------------

struct Radiance {
    local: vec3<f32>,
    indirect: vec3<f32>,
    albedo: vec3<f32>,
    sky: vec3<f32>,
}

// SampleGeom with the shadow ray it needs: kind 0 sky, 1 ground, 2 plant.
struct Geom {
    kind: u32,
    point: vec3<f32>,
    normal: vec3<f32>,
    shadow: bool,
    shadow_origin: vec3<f32>,
    from_instance: u32,
}

// SceneAccel::geometric_normal.
fn geometric_normal(h: Best) -> vec3<f32> {
    if (h.instance == GROUND) {
        return vec3<f32>(0.0, 1.0, 0.0);
    }
    let rec = models[instance_model(h.instance)];
    let k = 3u * (rec.tri_base + h.triangle);
    let n = cross_(tri_at(k + 1u).xyz, tri_at(k + 2u).xyz);
    return normalize_or_zero(world_vector(h.instance, n));
}

// Renderer::shadow_ray: the origin, a little off the surface on the sun's side of `ng`.
fn shadow_origin(point: vec3<f32>, ng: vec3<f32>) -> vec3<f32> {
    var side = -1.0;
    if (dot_(ng, shading.to_sun.xyz) >= 0.0) {
        side = 1.0;
    }
    let a = abs(point);
    let eps = 1e-4f * fmax_(fmax_(fmax_(a.x, a.y), a.z), 1.0);
    return point + ng * (side * eps);
}

// Renderer::sample_geometry.
fn sample_geometry(o: vec3<f32>, d: vec3<f32>, h: Best) -> Geom {
    var g = Geom(0u, vec3<f32>(0.0, 0.0, 0.0), vec3<f32>(0.0, 0.0, 0.0), false, vec3<f32>(0.0, 0.0, 0.0), NONE);
    if (h.triangle == NONE) {
        return g;
    }
    let to_sun = shading.to_sun.xyz;
    let point = o + d * h.t;
    let view = -d;
    g.point = point;
    if (h.instance == GROUND) {
        g.kind = 1u;
        g.shadow = to_sun.y > 0.0;
        g.shadow_origin = shadow_origin(point, vec3<f32>(0.0, 1.0, 0.0));
        return g;
    }
    let ng = geometric_normal(h);
    let sm = shade_model(instance_model(h.instance));
    let t0 = shade_word_at(sm.indices + 3u * h.triangle);
    let t1 = shade_word_at(sm.indices + 3u * h.triangle + 1u);
    let t2 = shade_word_at(sm.indices + 3u * h.triangle + 2u);
    var ns = vec3<f32>(0.0, 0.0, 0.0);
    if (sm.normals != NONE) {
        let m = word_vec3(sm.normals + 3u * t0) * (1.0 - h.u - h.v) + word_vec3(sm.normals + 3u * t1) * h.u
            + word_vec3(sm.normals + 3u * t2) * h.v;
        ns = normalize_or_zero(world_vector(h.instance, m));
    }
    var normal = ns;
    if (all(ns == vec3<f32>(0.0, 0.0, 0.0)) || !is_finite3(ns)) {
        normal = ng;
    } else if (dot_(ns, ng) < 0.0) {
        normal = -ns;
    }
    // Two-sided: the side the viewer sees.
    var ng_view = ng;
    if (dot_(ng, view) < 0.0) {
        ng_view = -ng;
    }
    if (dot_(normal, ng_view) < 0.0) {
        normal = -normal;
    }
    let probe = SurfacePoint(normal, view, vec3<f32>(1.0, 1.0, 1.0), is_leaf(sm, h.triangle));
    g.kind = 2u;
    g.normal = normal;
    g.shadow = needs_shadow_ray(probe, to_sun);
    g.shadow_origin = shadow_origin(point, ng);
    g.from_instance = h.instance;
    return g;
}

// Renderer::shade.
fn shade(d: vec3<f32>, h: Best, g: Geom, lit: bool) -> Radiance {
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    let sun = shading.sun.xyz;
    let to_sun = shading.to_sun.xyz;
    if (g.kind == 0u) {
        return Radiance(zero, zero, zero, shading.sky.xyz);
    }
    if (g.kind == 1u) {
        let c = shading.ground_colour.xyz * sun;
        let cos = fmax_(to_sun.y, 0.0);
        var local = zero;
        if (lit) {
            local = c * cos;
        }
        return Radiance(local, c * (shading.k.y * ground_sky(g.point)), c, zero);
    }
    let sm = shade_model(instance_model(h.instance));
    let mat = material_id(sm, h.triangle);
    var colour = vec3<f32>(word_f(sm.materials + 8u * mat + 1u), word_f(sm.materials + 8u * mat + 2u),
        word_f(sm.materials + 8u * mat + 3u));
    if (material_word(sm, mat, 4u) != NONE && sm.uvs != NONE) {
        let t0 = shade_word_at(sm.indices + 3u * h.triangle);
        let t1 = shade_word_at(sm.indices + 3u * h.triangle + 1u);
        let t2 = shade_word_at(sm.indices + 3u * h.triangle + 2u);
        let uv0 = vec2<f32>(word_f(sm.uvs + 2u * t0), word_f(sm.uvs + 2u * t0 + 1u));
        let uv1 = vec2<f32>(word_f(sm.uvs + 2u * t1), word_f(sm.uvs + 2u * t1 + 1u));
        let uv2 = vec2<f32>(word_f(sm.uvs + 2u * t2), word_f(sm.uvs + 2u * t2 + 1u));
        colour = linear_texture_sample(sm, mat, uv0 * (1.0 - h.u - h.v) + uv1 * h.u + uv2 * h.v);
    }
    let s = SurfacePoint(g.normal, -d, colour, material_word(sm, mat, 0u) == 1u);
    let albedo = colour * sun;
    var indirect = zero;
    if (sm.grid != NONE) {
        // ModelGridLight::plant.
        let l = lighting_sample(sm.grid, model_point(h.instance, g.point));
        indirect = l * albedo * shading.k.x;
    }
    return Radiance(local_light(s, to_sun, lit) * sun, indirect, albedo, zero);
}

// One pixel of the band: its samples traced, shaded and averaged, as the CPU renderer does
// (Renderer::trace_unit, then the shading pass's sum and 1 / n).
@compute @workgroup_size(8, 8)
fn render_frame(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = frame.size.x;
    if (id.x >= width || id.y >= frame.size.y) {
        return;
    }
    let pixel = id.y * width + id.x;
    let n = frame.size.z;
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    var acc = Radiance(zero, zero, zero, zero);
    var to_cpu = false;
    var shadow_rays = 0u;
    for (var s = 0u; s < n; s++) {
        let k = 2u * (pixel * n + s);
        let a = frame_rays[k];
        let b = frame_rays[k + 1u];
        let c = closest_hit(a.xyz, b.xyz, a.w, b.w);
        if (c.fallback) {
            to_cpu = true;
            break;
        }
        let g = sample_geometry(a.xyz, b.xyz, c.best);
        var lit = false;
        if (g.shadow) {
            let blocked = any_hit(g.shadow_origin, shading.to_sun.xyz, 0.0, shading.sun.w, g.from_instance);
            if (blocked.y != 0u) {
                to_cpu = true;
                break;
            }
            lit = blocked.x == 0u;
            shadow_rays += 1u;
        }
        let r = shade(b.xyz, c.best, g, lit);
        acc.local += r.local;
        acc.indirect += r.indirect;
        acc.albedo += r.albedo;
        acc.sky += r.sky;
    }
    let inv_n = bitcast<f32>(frame.size.w);
    frame_pixels[4u * pixel] = vec4<f32>(acc.local * inv_n, select(0.0, 1.0, to_cpu));
    frame_pixels[4u * pixel + 1u] = vec4<f32>(acc.indirect * inv_n, bitcast<f32>(shadow_rays));
    frame_pixels[4u * pixel + 2u] = vec4<f32>(acc.albedo * inv_n, 0.0);
    frame_pixels[4u * pixel + 3u] = vec4<f32>(acc.sky * inv_n, 0.0);
}
