// A frame on the GPU: per pixel, each sample's primary ray, its shadow ray and its shading,
// the CPU renderer's functions one for one (same names, same operations in the same order):
//
//   render.rs       sample_ray, Renderer::sample_geometry, Renderer::shadow_ray, Renderer::shade
//   shade.rs        local_light (paper and physical), indirect_light, needs_shadow_ray,
//                   LinearTexture::sample
//   indirect.rs     ModelGridLight::plant, ground_shade, GroundIndex::at
//   lighting.rs     ModelLighting::sample, ModelLighting::ground_sky
//   gather.rs       the final gather's directions (hash32, sample_point, cos_sin_turn, basis,
//                   cosine_direction; Renderer::gather_rays and Renderer::gathered)
//   relight/light.rs RelitLight::sample_instance (base solutions combined per instance, 004)
//
// Included after the scene's WGSL (sylva-trace-gpu: closest_hit, any_hit, to_model, ...)
// and a generated prelude that binds the shading data: `shade_word_at(i) -> u32`, one pool
// of words holding per model its mesh data, materials, linear textures and LB light (a grid
// solved for the sun, or the stored fields of its base solutions), the instances' world transforms and
// the ground index (offsets in `shading.tables` and in the records), `relit_word_at(i)`, the
// relit light's per-instance combinations (rewritten when the sun moves), and
// `shading: ShadeParams`. A change to the shading formulas changes both sides; the tests in
// crates/sylva-render/tests/gpu.rs compare them.

struct ShadeParams {
    // Sun colour × irradiance; w: +∞ (the shadow rays' t_max).
    sun: vec4<f32>,
    to_sun: vec4<f32>,
    ground_colour: vec4<f32>,
    sky: vec4<f32>,
    leaf_transmission: vec4<f32>,
    // indirect, sky_ambient, leaf k_s, leaf shininess
    k: vec4<f32>,
    // wood k_s, wood shininess, SHEET_RADIANCE_PER_FLUENCE, the relit light's free-space
    // luminance (1 + ambient)
    k2: vec4<f32>,
    // Pool offsets: model records (8 words each), instances' world transforms (12 words
    // each); the light model (0 paper, 1 physical); the indirect light (0 per-model grids,
    // 1 relit from base solutions).
    tables: vec4<u32>,
    // Ground index: cell starts (nx·nz + 1 words), instance lists, nx, nz (0: no index).
    ground: vec4<u32>,
    // Ground index: origin x, origin z, end x, end z.
    ground_box: vec4<f32>,
    // Ground index: 1 / cell size.
    ground_cell: vec4<f32>,
    // The final gather: rays per plant sample (0: none), the seed's low and high 32 bits, and
    // one in how many of its rays traces the sun at its hit (gather::SUN_SHADOW_EVERY, ≥ 1).
    gather: vec4<u32>,
}

const PHYSICAL: u32 = 1u;
const RELIT: u32 = 1u;

struct FrameParams {
    // Pixels of the band: width, rows; samples per pixel; 1 / samples as f32 bits.
    size: vec4<u32>,
    // The band's first pixel (x0, y0) in the image; the image's width and height.
    origin: vec4<u32>,
    // The camera (PinholeCamera): position, forward, right, up; tan(fov / 2), aspect.
    position: vec4<f32>,
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    lens: vec4<f32>,
}

@group(2) @binding(0) var<uniform> frame: FrameParams;
// Sub-pixel offsets per sample, pixel by pixel, where the host draws them (jittered
// sampling: samples per pixel other than 1 and 4).
@group(2) @binding(1) var<storage, read> frame_offsets: array<vec2<f32>>;
// Twelve per pixel: local, indirect, albedo, sky (Radiance's parts).
@group(2) @binding(2) var<storage, read_write> frame_pixels: array<f32>;
// One per pixel: bit 31 when the CPU must render the pixel, else the shadow rays traced.
@group(2) @binding(3) var<storage, read_write> frame_flags: array<u32>;

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
    // LB light record (NONE: no LB light on this model): a grid solved for the sun, or
    // the stored fields of its base solutions (relit).
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

// Material record (16 words): leaf, base colour (3), linear texels (NONE: untextured),
// width, height, wrap, reflect (3), transmit (3): sylva_geom::Optics.
const MATERIAL_WORDS: u32 = 16u;

fn material_word(sm: ShadeModel, mat: u32, k: u32) -> u32 {
    return shade_word_at(sm.materials + MATERIAL_WORDS * mat + k);
}

fn material_vec3(sm: ShadeModel, mat: u32, k: u32) -> vec3<f32> {
    return word_vec3(sm.materials + MATERIAL_WORDS * mat + k);
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
    reflect: vec3<f32>,
    transmit: vec3<f32>,
}

// SurfacePoint::reflectance and SurfacePoint::transmittance.
fn reflectance(s: SurfacePoint) -> vec3<f32> {
    return s.colour * s.reflect;
}

fn transmittance(s: SurfacePoint) -> vec3<f32> {
    if (s.leaf) {
        return s.colour * s.transmit;
    }
    return vec3<f32>(0.0, 0.0, 0.0);
}

// shade::local_light.
fn local_light(s: SurfacePoint, to_sun: vec3<f32>, lit: bool) -> vec3<f32> {
    if (!lit) {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    let cos = dot_(s.normal, to_sun);
    if (shading.tables.z == PHYSICAL) {
        if (cos > 0.0) {
            return reflectance(s) * cos;
        }
        return transmittance(s) * (-cos);
    }
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

// shade::indirect_light: the light a surface sends to the viewer from the LB light `lb`.
fn indirect_light(s: SurfacePoint, lb: vec3<f32>, sun: vec3<f32>) -> vec3<f32> {
    if (shading.tables.z == PHYSICAL) {
        return lb * (reflectance(s) + transmittance(s)) * (shading.k2.z * shading.k.x);
    }
    return lb * s.colour * sun * shading.k.x;
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

// ---- lighting.rs, indirect.rs, relight/light.rs --------------------------------------------

// An LB light record: nx, ny, nz, values (first word of the values or stored fields),
// origin (3), inv_cell (3), last (3), model bounds min (3), max (3), then 9 words: a grid's
// free field (physical light: 1, open sky (3), open bottom (3)) and its forest-grid parts
// (LIGHT_PARTS: where the parts start, NONE: none; where the instances' weights start), or a
// relit record's kind
// (RELIT_FIELDS, RELIT_HAAR_SPLIT, RELIT_HAAR_PACKED), field count, site count, Haar blocks
// along y and z, and where the Haar starts, counts, indices or packed words, and values or
// steps begin.
const LIGHT_OPEN: u32 = 19u;
const LIGHT_PARTS: u32 = 26u;
const RELIT_KIND: u32 = 19u;
const RELIT_FIELDS: u32 = 0u;
const RELIT_HAAR_SPLIT: u32 = 1u;

// relight::Footprint::at of relight::Placement::grid_coords: the lower corner of the 2×2×2
// sites a trilinear lookup at model-space point p reads, and the fractions.
struct Corner {
    i: vec3<u32>,
    t: vec3<f32>,
}

fn corner(g: u32, p: vec3<f32>) -> Corner {
    let origin = word_vec3(g + 4u);
    let inv_cell = word_vec3(g + 7u);
    let last = word_vec3(g + 10u);
    // `max` before `min` turns NaN into 0.
    let f = fmin3(fmax3((p - origin) * inv_cell, vec3<f32>(0.0, 0.0, 0.0)), last);
    let i = fmin3(floor(f), last - vec3<f32>(1.0, 1.0, 1.0));
    return Corner(vec3<u32>(i), f - i);
}

// Footprint::sites and Footprint::weights (corner (dx, dy, dz) at index 4 dx + 2 dy + dz).
struct Footprint {
    sites: array<u32, 8>,
    weights: array<f32, 8>,
}

fn footprint(g: u32, p: vec3<f32>) -> Footprint {
    let ny = shade_word_at(g + 1u);
    let nz = shade_word_at(g + 2u);
    let c = corner(g, p);
    let base = (c.i.x * ny + c.i.y) * nz + c.i.z;
    var fp: Footprint;
    for (var k = 0u; k < 8u; k++) {
        let dx = k >> 2u;
        let dy = (k >> 1u) & 1u;
        let dz = k & 1u;
        fp.sites[k] = base + (dx * ny + dy) * nz + dz;
        let wx = select(1.0 - c.t.x, c.t.x, dx == 1u);
        let wy = select(1.0 - c.t.y, c.t.y, dy == 1u);
        let wz = select(1.0 - c.t.z, c.t.z, dz == 1u);
        fp.weights[k] = wx * wy * wz;
    }
    return fp;
}

// ModelLighting::sample: trilinear RGB at model-space point p of the grid record `g`.
fn lighting_sample(g: u32, p: vec3<f32>) -> vec3<f32> {
    let values = shade_word_at(g + 3u);
    let fp = footprint(g, p);
    var out = vec3<f32>(0.0, 0.0, 0.0);
    for (var k = 0u; k < 8u; k++) {
        out += word_vec3(values + 3u * fp.sites[k]) * fp.weights[k];
    }
    return out;
}

// Byte k of the bytes packed 4 per word from word `at`.
fn byte_at(at: u32, k: u32) -> u32 {
    return (shade_word_at(at + k / 4u) >> (8u * (k % 4u))) & 0xffu;
}

// haar::kernel: the 64 weights K of a footprint whose lower corner sits at local
// coordinates o in its block, with fractions t: the interpolated value is Σ coef_k K[k].
fn haar_kernel(o: vec3<u32>, t: vec3<f32>) -> array<f32, 64> {
    var e: array<vec2<f32>, 3>;
    var f: array<array<vec2<f32>, 2>, 3>;
    for (var a = 0u; a < 3u; a++) {
        for (var s = 0u; s < 2u; s++) {
            let v = o[a] + s;
            let w = select(1.0 - t[a], t[a], s == 1u);
            let cell = v >> 1u;
            let pos = v & 1u;
            e[a][0] += w;
            e[a][1] += w * select(-1.0, 1.0, cell == 0u);
            f[a][cell][0] += w;
            f[a][cell][1] += w * select(-1.0, 1.0, pos == 0u);
        }
    }
    var k: array<f32, 64>;
    for (var q = 0u; q < 8u; q++) {
        k[q] = e[0][q >> 2u] * e[1][(q >> 1u) & 1u] * e[2][q & 1u];
    }
    for (var c = 0u; c < 8u; c++) {
        let cx = c >> 2u;
        let cy = (c >> 1u) & 1u;
        let cz = c & 1u;
        for (var q = 1u; q < 8u; q++) {
            k[8u + 7u * c + q - 1u] = f[0][cx][q >> 2u] * f[1][cy][(q >> 1u) & 1u] * f[2][cz][q & 1u];
        }
    }
    return k;
}

// RelitLight::sample_instance: instance i's combination of its model's base solutions at
// model-space point p (its relit record `g`): constant + Σ terms weight · field, where a
// field is looked up as the CPU's stored set does: BasisSet::sample and DenseFields (every
// site stored) or HaarFields::sample_into (one block's coefficients against the
// footprint's kernel). The instance's entry in the relit words: first term, term count,
// constant (3); each term: field, weight (3); terms sorted by field.
fn relit_sample(g: u32, i: u32, p: vec3<f32>) -> vec3<f32> {
    let constant = vec3<f32>(bitcast<f32>(relit_word_at(8u * i + 2u)), bitcast<f32>(relit_word_at(8u * i + 3u)),
        bitcast<f32>(relit_word_at(8u * i + 4u)));
    return relit_terms(g, relit_word_at(8u * i), relit_word_at(8u * i + 1u), constant, p);
}

// `constant` + Σ the `count` terms from `first` in the relit words, at model-space point p of
// relit record g.
fn relit_terms(g: u32, first: u32, count: u32, constant: vec3<f32>, p: vec3<f32>) -> vec3<f32> {
    var out = constant;
    let kind = shade_word_at(g + RELIT_KIND);
    if (kind == RELIT_FIELDS) {
        let fields = shade_word_at(g + 3u);
        let sites = shade_word_at(g + RELIT_KIND + 2u);
        let fp = footprint(g, p);
        for (var k = 0u; k < count; k++) {
            let term = first + 4u * k;
            let field = fields + relit_word_at(term) * sites;
            var v = 0.0;
            for (var c = 0u; c < 8u; c++) {
                v += fp.weights[c] * word_f(field + fp.sites[c]);
            }
            let w = vec3<f32>(bitcast<f32>(relit_word_at(term + 1u)), bitcast<f32>(relit_word_at(term + 2u)),
                bitcast<f32>(relit_word_at(term + 3u)));
            out += w * v;
        }
        return out;
    }
    // HaarFields::block_of: blocks own 3 lower corners per axis.
    let nf = shade_word_at(g + RELIT_KIND + 1u);
    let blocks_y = shade_word_at(g + RELIT_KIND + 3u);
    let blocks_z = shade_word_at(g + RELIT_KIND + 4u);
    let starts = shade_word_at(g + RELIT_KIND + 5u);
    let counts = shade_word_at(g + RELIT_KIND + 6u);
    let coef_a = shade_word_at(g + RELIT_KIND + 7u);
    let coef_b = shade_word_at(g + RELIT_KIND + 8u);
    let c = corner(g, p);
    let b = c.i / 3u;
    let o = c.i - 3u * b;
    let block = (b.x * blocks_y + b.y) * blocks_z + b.z;
    let kernel = haar_kernel(o, c.t);
    var pos = shade_word_at(starts + block);
    var next = 0u;
    for (var k = 0u; k < count; k++) {
        let term = first + 4u * k;
        let f = relit_word_at(term);
        for (; next < f; next++) {
            pos += byte_at(counts, block * nf + next);
        }
        let n = byte_at(counts, block * nf + f);
        var v = 0.0;
        if (kind == RELIT_HAAR_SPLIT) {
            for (var j = pos; j < pos + n; j++) {
                v += word_f(coef_b + j) * kernel[byte_at(coef_a, j)];
            }
        } else {
            // Packed: the value in the top 10 bits (signed), the index in the low 6, the
            // sum scaled by the field's step.
            for (var j = pos; j < pos + n; j++) {
                let w16 = (shade_word_at(coef_a + j / 2u) >> (16u * (j % 2u))) & 0xffffu;
                let q = f32(bitcast<i32>(w16 << 16u) >> 22u);
                v += q * kernel[w16 & 63u];
            }
            v = v * word_f(coef_b + f);
        }
        pos += n;
        next = f + 1u;
        let w = vec3<f32>(bitcast<f32>(relit_word_at(term + 1u)), bitcast<f32>(relit_word_at(term + 2u)),
            bitcast<f32>(relit_word_at(term + 3u)));
        out += w * v;
    }
    return out;
}

// ModelLighting::sample_weighted: the four parts (sun, sky through the top, through the sides,
// ground; RGB each, 12 words per site at `parts`) trilinearly at p, weighed by instance i's
// weights (12 words per instance at `weights`): the physical light's forest grid.
fn parts_sample(g: u32, parts: u32, weights: u32, i: u32, p: vec3<f32>) -> vec3<f32> {
    let fp = footprint(g, p);
    let w = weights + 12u * i;
    let w_sun = word_vec3(w);
    let w_top = word_vec3(w + 3u);
    let w_side = word_vec3(w + 6u);
    let w_ground = word_vec3(w + 9u);
    var out = vec3<f32>(0.0, 0.0, 0.0);
    for (var k = 0u; k < 8u; k++) {
        let v = parts + 12u * fp.sites[k];
        let c = word_vec3(v) * w_sun + word_vec3(v + 3u) * w_top + word_vec3(v + 6u) * w_side
            + word_vec3(v + 9u) * w_ground;
        out += c * fp.weights[k];
    }
    return out;
}

// IndirectLight::plant: the LB light on instance i at world point p; w = 0 when it gets none.
fn plant_light(i: u32, p: vec3<f32>) -> vec4<f32> {
    let g = shade_model(instance_model(i)).grid;
    if (g == NONE) {
        return vec4<f32>(0.0, 0.0, 0.0, 0.0);
    }
    let pm = model_point(i, p);
    if (shading.tables.w == RELIT) {
        return vec4<f32>(relit_sample(g, i, pm), 1.0);
    }
    let parts = shade_word_at(g + LIGHT_PARTS);
    if (parts != NONE) {
        return vec4<f32>(parts_sample(g, parts, shade_word_at(g + LIGHT_PARTS + 1u), i, pm), 1.0);
    }
    return vec4<f32>(lighting_sample(g, pm), 1.0);
}

// ModelLighting::ground_sky (physical light): the share of the open sky's light reaching the
// ground at model-space point p, per colour, from the grid's two lowest layers.
fn physical_ground_sky(g: u32, p: vec3<f32>) -> vec3<f32> {
    let origin = word_vec3(g + 4u);
    let inv_cell_y = word_f(g + 8u);
    var cell_y = 0.0;
    if (inv_cell_y > 0.0) {
        cell_y = 1.0 / inv_cell_y;
    }
    let open_sky = word_vec3(g + LIGHT_OPEN + 1u);
    let open_bottom = word_vec3(g + LIGHT_OPEN + 4u);
    let floor_ = lighting_sample(g, vec3<f32>(p.x, origin.y, p.z));
    let lowest = lighting_sample(g, vec3<f32>(p.x, origin.y + cell_y, p.z));
    return ground_share(floor_, lowest, open_sky, open_bottom);
}

// PhysicalRelitLight::ground_sky at model-space point p of instance i: as physical_ground_sky,
// the two lowest layers from the instance's ground terms, the open field from the relit words.
fn relit_physical_ground_sky(g: u32, i: u32, p: vec3<f32>) -> vec3<f32> {
    let origin = word_vec3(g + 4u);
    let inv_cell_y = word_f(g + 8u);
    var cell_y = 0.0;
    if (inv_cell_y > 0.0) {
        cell_y = 1.0 / inv_cell_y;
    }
    let first = relit_word_at(8u * i + 5u);
    let count = relit_word_at(8u * i + 6u);
    let open = relit_word_at(8u * i + 7u);
    let open_sky = vec3<f32>(bitcast<f32>(relit_word_at(open)), bitcast<f32>(relit_word_at(open + 1u)),
        bitcast<f32>(relit_word_at(open + 2u)));
    let open_bottom = vec3<f32>(bitcast<f32>(relit_word_at(open + 3u)), bitcast<f32>(relit_word_at(open + 4u)),
        bitcast<f32>(relit_word_at(open + 5u)));
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    let floor_ = relit_terms(g, first, count, zero, vec3<f32>(p.x, origin.y, p.z));
    let lowest = relit_terms(g, first, count, zero, vec3<f32>(p.x, origin.y + cell_y, p.z));
    return ground_share(floor_, lowest, open_sky, open_bottom);
}

// lighting::physical_ground_sky: from the floor's and the lowest layer's light and the open
// field, the share of the open sky's light reaching the ground.
fn ground_share(floor_: vec3<f32>, lowest: vec3<f32>, open_sky: vec3<f32>, open_bottom: vec3<f32>) -> vec3<f32> {
    let ground = fmax3(floor_ - open_bottom, vec3<f32>(0.0, 0.0, 0.0));
    let sky = open_sky * 0.5;
    let share = (lowest - 2.0 * ground) * 0.5 / fmax3(sky, vec3<f32>(1.17549435e-38, 1.17549435e-38, 1.17549435e-38));
    let clamped = clamp(share, vec3<f32>(0.0, 0.0, 0.0), vec3<f32>(1.0, 1.0, 1.0));
    return select(vec3<f32>(1.0, 1.0, 1.0), clamped, sky > vec3<f32>(0.0, 0.0, 0.0));
}

// The share of the open sky's light instance i's LB light lets through at its model-space
// point pm (1 in free space): ModelLighting::ground_sky, or the relit light's luminance over
// its free-space value.
fn instance_ground_sky(g: u32, i: u32, pm: vec3<f32>) -> vec3<f32> {
    if (shading.tables.w == RELIT && shading.tables.z == PHYSICAL) {
        return relit_physical_ground_sky(g, i, pm);
    }
    if (shading.tables.w == RELIT) {
        let l = luminance(relit_sample(g, i, pm)) / shading.k2.w;
        return vec3<f32>(l, l, l);
    }
    if (shading.tables.z == PHYSICAL && shade_word_at(g + LIGHT_OPEN) == 1u) {
        return physical_ground_sky(g, pm);
    }
    let l = clamp(luminance(lighting_sample(g, pm)), 0.0, 1.0);
    return vec3<f32>(l, l, l);
}

// indirect::ground_shade: the product over the trees whose LB light covers ground point p of
// the share of the sky's light they let through, faded to 1 over each footprint's outer 20 %.
fn ground_sky(p: vec3<f32>) -> vec3<f32> {
    var f = vec3<f32>(1.0, 1.0, 1.0);
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
    let one = vec3<f32>(1.0, 1.0, 1.0);
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
            let lb = instance_ground_sky(g, i, pm);
            let edge = fmin_(fmin_(fmin_(pm.x - bmin.x, bmax.x - pm.x), pm.z - bmin.z), bmax.z - pm.z);
            let width = 0.2 * fmin_(bmax.x - bmin.x, bmax.z - bmin.z);
            var w = 1.0;
            if (width > 0.0) {
                w = clamp(edge / width, 0.0, 1.0);
            }
            f *= one - w * (one - clamp(lb, vec3<f32>(0.0, 0.0, 0.0), one));
        }
    }
    return f;
}

// ---- gather.rs ------------------------------------------------------------------------------

fn hash32(v: u32) -> u32 {
    var x = v;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

// gather::side_key with the frame's seed.
fn gather_key(pixel: u32, side: u32) -> u32 {
    let seed_lo = shading.gather.y;
    let seed_hi = shading.gather.z;
    return hash32(hash32(pixel ^ hash32(seed_lo ^ hash32(seed_hi))) ^ (side * 0x9e3779b9u));
}

// gather::sample_point with the frame's seed.
fn gather_point(pixel: u32, side: u32, index: u32) -> vec2<f32> {
    let key = gather_key(pixel, side);
    let sx = hash32(key);
    let sy = hash32(key ^ 0x85ebca6bu);
    let unit = 1.0 / 16777216.0;
    return vec2<f32>(f32((sx + index * 3242174889u) >> 8u) * unit, f32((sy + index * 2447445413u) >> 8u) * unit);
}

// gather::traces_sun with the frame's seed; shading.gather.w is gather::SUN_SHADOW_EVERY.
fn gather_traces_sun(pixel: u32, side: u32, index: u32) -> bool {
    return (hash32(gather_key(pixel, side) ^ 0x27d4eb2fu) + index) % shading.gather.w == 0u;
}

fn cos_sin_turn(t: f32) -> vec2<f32> {
    let q = floor(4.0 * t);
    let a = (4.0 * t - q) * 1.5707964;
    let a2 = a * a;
    let s = a * (1.0 + a2 * (-0.16666667 + a2 * (0.008333334 + a2 * (-0.0001984127 + a2 * (2.7557319e-6 + a2 * -2.5052108e-8)))));
    let c = 1.0 + a2 * (-0.5 + a2 * (0.041666668 + a2 * (-0.0013888889 + a2 * (2.4801588e-5 + a2 * (-2.755732e-7 + a2 * 2.0876758e-9)))));
    let k = i32(q);
    if (k == 0) {
        return vec2<f32>(c, s);
    }
    if (k == 1) {
        return vec2<f32>(-s, c);
    }
    if (k == 2) {
        return vec2<f32>(-c, -s);
    }
    return vec2<f32>(s, -c);
}

fn cosine_direction(n: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let cs = cos_sin_turn(u.y);
    let z = sqrt(fmax_(1.0 - u.x, 0.0));
    var sign = -1.0;
    if (n.z >= 0.0) {
        sign = 1.0;
    }
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let b1 = vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let b2 = vec3<f32>(b, sign + n.y * n.y * a, -n.y);
    return b1 * (r * cs.x) + b2 * (r * cs.y) + n * z;
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
    // The geometric normal on the viewer's side (plants).
    ng: vec3<f32>,
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
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    var g = Geom(0u, zero, zero, zero, false, zero, NONE);
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
    let one = vec3<f32>(1.0, 1.0, 1.0);
    let probe = SurfacePoint(normal, view, one, is_leaf(sm, h.triangle), one, one);
    g.kind = 2u;
    g.normal = normal;
    g.ng = ng_view;
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
        if (shading.tables.z == PHYSICAL) {
            // The open ground takes π L_sky from the sky: L_sky in units of E0.
            let ground = shading.ground_colour.xyz;
            return Radiance(local, ground * shading.sky.xyz * ground_sky(g.point), ground, zero);
        }
        return Radiance(local, c * (shading.k.y * ground_sky(g.point).x), c, zero);
    }
    let s = plant_surface(d, h, g);
    let sm = shade_model(instance_model(h.instance));
    let mat = material_id(sm, h.triangle);
    var albedo = s.colour * sun;
    if (shading.tables.z == PHYSICAL) {
        albedo = reflectance(s) + transmittance(s);
    }
    var indirect = zero;
    let l = plant_light(h.instance, g.point);
    if (l.w != 0.0) {
        indirect = indirect_light(s, l.xyz, sun);
    }
    return Radiance(local_light(s, to_sun, lit) * sun, indirect, albedo, zero);
}

// The plant surface a hit shades (Renderer::shade's SurfacePoint).
fn plant_surface(d: vec3<f32>, h: Best, g: Geom) -> SurfacePoint {
    let sm = shade_model(instance_model(h.instance));
    let mat = material_id(sm, h.triangle);
    var colour = material_vec3(sm, mat, 1u);
    if (material_word(sm, mat, 4u) != NONE && sm.uvs != NONE) {
        let t0 = shade_word_at(sm.indices + 3u * h.triangle);
        let t1 = shade_word_at(sm.indices + 3u * h.triangle + 1u);
        let t2 = shade_word_at(sm.indices + 3u * h.triangle + 2u);
        let uv0 = vec2<f32>(word_f(sm.uvs + 2u * t0), word_f(sm.uvs + 2u * t0 + 1u));
        let uv1 = vec2<f32>(word_f(sm.uvs + 2u * t1), word_f(sm.uvs + 2u * t1 + 1u));
        let uv2 = vec2<f32>(word_f(sm.uvs + 2u * t2), word_f(sm.uvs + 2u * t2 + 1u));
        colour = linear_texture_sample(sm, mat, uv0 * (1.0 - h.u - h.v) + uv1 * h.u + uv2 * h.v);
    }
    return SurfacePoint(g.normal, -d, colour, material_word(sm, mat, 0u) == 1u, material_vec3(sm, mat, 8u),
        material_vec3(sm, mat, 11u));
}

// Whether a plant hit's surface transmits (Renderer::sample_geometry): a leaf material with
// some transmittance.
fn transmits(h: Best) -> bool {
    let sm = shade_model(instance_model(h.instance));
    let m = material_id(sm, h.triangle);
    return m < sm.material_count && material_word(sm, m, 0u) == 1u
        && any(material_vec3(sm, m, 11u) > vec3<f32>(0.0, 0.0, 0.0));
}

struct Gathered {
    // R of the light in front plus T of the light behind, times the indirect scale.
    light: vec3<f32>,
    // Rays traced (gather and shadow rays).
    rays: u32,
    // The CPU must render the pixel.
    to_cpu: bool,
}

// gather::split, Renderer::gather_rays, Renderer::gathered and the gathered indirect light of
// Renderer::shade: what sample s's gather rays bring back to the plant point g (the front's
// rays, then the back's).
fn gather(d: vec3<f32>, h: Best, g: Geom, pixel: u32, s: u32) -> Gathered {
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    let k = shading.gather.x;
    var front_count = k;
    var back_count = 0u;
    // gather::side_weight: a single ray on a leaf that transmits stands for both sides.
    var weight = 1.0;
    if (transmits(h)) {
        if (k == 1u) {
            weight = 2.0;
            if ((hash32(gather_key(pixel, 0u) ^ 0x165667b1u) + s) % 2u == 0u) {
                front_count = 0u;
                back_count = 1u;
            }
        } else {
            front_count = k - k / 2u;
            back_count = k / 2u;
        }
    }
    var front = zero;
    var back_sum = zero;
    let a = abs(g.point);
    let eps = 1e-4f * fmax_(fmax_(fmax_(a.x, a.y), a.z), 1.0);
    let t_max = bitcast<f32>(0x7f800000u);
    var rays = 0u;
    var to_cpu = false;
    for (var i = 0u; i < k; i++) {
        var side = 0u;
        var count = front_count;
        var j = i;
        var n = g.normal;
        if (i >= front_count) {
            side = 1u;
            count = back_count;
            j = i - front_count;
            n = -g.normal;
        }
        let index = s * count + j;
        let dir = cosine_direction(n, gather_point(pixel, side, index));
        var off = -eps;
        if (dot_(dir, g.ng) >= 0.0) {
            off = eps;
        }
        let o = g.point + g.ng * off;
        // A ray the CPU must trace flags the pixel; the loop goes on (its light is dropped).
        let c = closest_hit(o, dir, 0.0, t_max);
        to_cpu = to_cpu || c.fallback;
        rays += 1u;
        let g2 = sample_geometry(o, dir, c.best);
        var lit = false;
        if (g2.shadow && gather_traces_sun(pixel, side, index)) {
            let blocked = any_hit(g2.shadow_origin, shading.to_sun.xyz, 0.0, shading.sun.w, g2.from_instance);
            to_cpu = to_cpu || blocked.y != 0u;
            lit = blocked.x == 0u;
            rays += 1u;
        }
        let r = shade(dir, c.best, g2, lit);
        // One ray in shading.gather.w traced the sun: its sunlight counts for them all.
        let l = (r.local * f32(shading.gather.w) + r.indirect + r.sky) * weight / f32(count);
        if (side == 0u) {
            front += l;
        } else {
            back_sum += l;
        }
    }
    if (to_cpu) {
        return Gathered(zero, 0u, true);
    }
    let sp = plant_surface(d, h, g);
    return Gathered((reflectance(sp) * front + transmittance(sp) * back_sum) * shading.k.x, rays, false);
}

// render::sample_offset for 1 and 4 samples per pixel (the others come from the host).
fn sample_offset(pixel: u32, s: u32) -> vec2<f32> {
    let n = frame.size.z;
    if (n == 1u) {
        return vec2<f32>(0.5, 0.5);
    }
    if (n == 4u) {
        return vec2<f32>(0.25 + 0.5 * f32(s % 2u), 0.25 + 0.5 * f32(s / 2u));
    }
    return frame_offsets[pixel * n + s];
}

// PinholeCamera::ray through continuous pixel coordinates (px, py): its unit direction
// (glam's normalize: the vector times 1 / length).
fn camera_dir(px: f32, py: f32) -> vec3<f32> {
    let nx = (px / f32(frame.origin.z)) * 2.0 - 1.0;
    let ny = 1.0 - (py / f32(frame.origin.w)) * 2.0;
    let d = frame.forward.xyz + frame.right.xyz * ((nx * frame.lens.x) * frame.lens.y)
        + frame.up.xyz * (ny * frame.lens.x);
    return d * (1.0 / sqrt(dot_(d, d)));
}

// One pixel of the band: its samples traced, shaded and averaged, as the CPU renderer does
// (render::sample_ray, Renderer::trace_unit, then the shading pass's sum and 1 / n).
@compute @workgroup_size(8, 8)
fn render_frame(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = frame.size.x;
    if (id.x >= width || id.y >= frame.size.y) {
        return;
    }
    let pixel = id.y * width + id.x;
    let x = frame.origin.x + id.x;
    let y = frame.origin.y + id.y;
    let n = frame.size.z;
    let origin = frame.position.xyz;
    let t_max = bitcast<f32>(0x7f800000u);
    let zero = vec3<f32>(0.0, 0.0, 0.0);
    var acc = Radiance(zero, zero, zero, zero);
    var to_cpu = false;
    var shadow_rays = 0u;
    for (var s = 0u; s < n; s++) {
        let o = sample_offset(pixel, s);
        let d = camera_dir(f32(x) + o.x, f32(y) + o.y);
        let c = closest_hit(origin, d, 0.0, t_max);
        if (c.fallback) {
            to_cpu = true;
            break;
        }
        let g = sample_geometry(origin, d, c.best);
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
        var r = shade(d, c.best, g, lit);
        if (g.kind == 2u && shading.gather.x > 0u) {
            let gathered = gather(d, c.best, g, y * frame.origin.z + x, s);
            if (gathered.to_cpu) {
                to_cpu = true;
                break;
            }
            shadow_rays += gathered.rays;
            r.indirect = gathered.light;
        }
        acc.local += r.local;
        acc.indirect += r.indirect;
        acc.albedo += r.albedo;
        acc.sky += r.sky;
    }
    let inv_n = bitcast<f32>(frame.size.w);
    let parts = array<vec3<f32>, 4>(acc.local * inv_n, acc.indirect * inv_n, acc.albedo * inv_n, acc.sky * inv_n);
    for (var k = 0u; k < 4u; k++) {
        frame_pixels[12u * pixel + 3u * k] = parts[k].x;
        frame_pixels[12u * pixel + 3u * k + 1u] = parts[k].y;
        frame_pixels[12u * pixel + 3u * k + 2u] = parts[k].z;
    }
    frame_flags[pixel] = select(shadow_rays, 0x80000000u, to_cpu);
}
