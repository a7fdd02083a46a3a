// Closest-hit and any-hit queries over sylva's two-level kd-trees: the CPU tracer's
// (crates/sylva-trace) traversal, function by function, on the arrays it built.
//
// The generated prelude (src/shader.rs) declares the scene's storage bindings and defines:
//   const STACK: u32                         short-stack entries (TraversalConfig::stack_size)
//   const BARY_EPS, ROUNDING, SLACK: f32     the CPU's constants, bit for bit
//   fn node_at(i) -> vec2<u32>               kd-tree nodes of every tree (KdNode::raw)
//   fn prim_at(i) -> u32                     leaf primitive lists
//   fn tri_at(i) -> vec4<f32>                3 per triangle: (v0, alpha entry), (e1, 0), (e2, 0)
//   fn alpha_at(i) -> vec4<f32>              2 per alpha-tested triangle: (uv0, uv1), (uv2, mask, 0)
//   fn mask_word_at(i) -> u32                opacity bits of every leaf texture
//   fn inst_at(i) -> vec4<f32>               4 per instance: world → model (x, y, z axes with
//                                            the model id in x.w, translation)
//   fn box_at(i) -> vec4<f32>                2 per instance: world box min, max
//   models: array<ModelRec>, masks: array<vec4<u32>>, scene: SceneParams
//
// Arithmetic follows the CPU expression by expression (same operand order, dot and cross
// written out as glam computes them), so on an adapter that rounds each f32 operation as
// IEEE does and does not contract a * b + c into a fused multiply-add (lavapipe), every
// t, u and v is the CPU's bit for bit. Comparisons that must see NaN or ∞ test the bits:
// drivers may assume finite values in ordinary float comparisons.

struct ModelRec {
    node_base: u32,
    prim_base: u32,
    tri_base: u32,
    alpha_base: u32,
    mask_base: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    bmin: vec4<f32>,
    bmax: vec4<f32>,
}

struct SceneParams {
    // x: 1 when the scene has a ground rectangle on y = 0, y and z: its half extents.
    ground: vec4<f32>,
    // x: models (the top-level tree's record follows them), y: instances.
    counts: vec4<u32>,
}

const NONE: u32 = 0xffffffffu;
const GROUND: u32 = 0xffffffffu;
// Instances a ray remembers having tested, and instances of a top-level leaf sorted by box
// entry. Both only save work: the tie rule makes the result independent of visiting order.
const MAILBOX: u32 = 8u;
const SORTED: u32 = 8u;

fn is_nan_(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn is_inf_(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) == 0x7f800000u;
}

fn is_finite_(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// glam's Vec3::dot and Vec3::cross.
fn dot_(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn cross_(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

// ray::ray_box: the parameter interval inside [bmin, bmax] clipped to [t_min, t_max];
// w = 1 when it is not empty.
fn ray_box(o: vec3<f32>, inv: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>, t_min: f32, t_max: f32) -> vec3<f32> {
    var t0 = t_min;
    var t1 = t_max;
    for (var k = 0u; k < 3u; k++) {
        if (is_inf_(inv[k])) {
            if (o[k] < bmin[k] || o[k] > bmax[k]) {
                return vec3<f32>(0.0, 0.0, 0.0);
            }
            continue;
        }
        let a = (bmin[k] - o[k]) * inv[k];
        let b = (bmax[k] - o[k]) * inv[k];
        var lo = b;
        var hi = a;
        if (a <= b) {
            lo = a;
            hi = b;
        }
        if (lo > t0) {
            t0 = lo;
        }
        if (hi < t1) {
            t1 = hi;
        }
    }
    return vec3<f32>(t0, t1, select(0.0, 1.0, t0 <= t1));
}

// ray::intersect_triangle (Möller-Trumbore with the widened edge rule): (t, u, v, 1) on a
// hit with t_min < t ≤ t_max, w = 0 otherwise.
fn intersect_triangle(o: vec3<f32>, d: vec3<f32>, v0: vec3<f32>, e1: vec3<f32>, e2: vec3<f32>, t_min: f32, t_max: f32) -> vec4<f32> {
    let miss = vec4<f32>(0.0, 0.0, 0.0, 0.0);
    let p = cross_(d, e2);
    let det = dot_(e1, p);
    if (det == 0.0 || !is_finite_(det)) {
        return miss;
    }
    let inv = 1.0 / det;
    if (!is_finite_(inv)) {
        return miss;
    }
    let s = o - v0;
    let u = dot_(s, p) * inv;
    // The edge margin grows with the rounding of the dot products (ray.rs module docs).
    let margin_u = max(BARY_EPS, ROUNDING * dot_(abs(s), abs(p)) * abs(inv));
    if (!(u >= -margin_u && u <= 1.0 + margin_u)) {
        return miss;
    }
    let q = cross_(s, e1);
    let v = dot_(d, q) * inv;
    let margin = max(margin_u, ROUNDING * dot_(abs(d), abs(q)) * abs(inv));
    if (v < -margin || u + v > 1.0 + margin) {
        return miss;
    }
    let t = dot_(e2, q) * inv;
    if (t > t_min && t <= t_max) {
        return vec4<f32>(t, u, v, 1.0);
    }
    return miss;
}

// sylva_geom::Wrap::apply on a texel index (repeat: rem_euclid, clamp: into 0..n).
fn wrap_index(i: i32, n: u32, wrap: u32) -> u32 {
    if (wrap == 0u) {
        let m = i % i32(n);
        return u32(select(m, m + i32(n), m < 0));
    }
    return u32(clamp(i, 0, i32(n) - 1));
}

// model::AlphaMask::opaque (sylva_geom::nearest_texel_coords): the nearest texel's bit.
fn mask_opaque(mask: u32, u_in: f32, v_in: f32) -> bool {
    let info = masks[mask]; // width, height, wrap (0 repeat, 1 clamp), first word
    var u = 0.0;
    var v = 0.0;
    if (is_finite_(u_in) && is_finite_(v_in)) {
        u = u_in;
        v = v_in;
    }
    let x = wrap_index(i32(floor(u * f32(info.x))), info.x, info.z);
    let y = wrap_index(i32(floor(v * f32(info.y))), info.y, info.z);
    let i = y * info.x + x;
    return ((mask_word_at(info.w + i / 32u) >> (i % 32u)) & 1u) == 1u;
}

// ModelAccel::passes_alpha: does a hit at (u, v) on a triangle with alpha entry `alpha` stand?
fn passes_alpha(rec: ModelRec, alpha: u32, u: f32, v: f32) -> bool {
    if (alpha == NONE) {
        return true;
    }
    let a0 = alpha_at(2u * (rec.alpha_base + alpha));
    let a1 = alpha_at(2u * (rec.alpha_base + alpha) + 1u);
    let uv = a0.xy * (1.0 - u - v) + a0.zw * u + a1.xy * v;
    return mask_opaque(rec.mask_base + bitcast<u32>(a1.z), uv.x, uv.y);
}

// ---- Short-stack traversal (KdTree::traverse, 000 Fig. 1) ----------------------------------

struct Trav {
    node_base: u32,
    o: vec3<f32>,
    inv: vec3<f32>,
    scene_min: f32,
    scene_max: f32,
    // The current leaf's interval.
    tmin: f32,
    tmax: f32,
    // Restart node: pushed down while the stack is empty.
    root: u32,
    first: bool,
    // Ring buffer of STACK entries: next free slot and entries held.
    top: u32,
    len: u32,
    // The ray lies in a split plane (a NaN split distance): the CPU answers it.
    fallback: bool,
    stack_node: array<u32, STACK>,
    stack_tmin: array<f32, STACK>,
    stack_tmax: array<f32, STACK>,
}

// Starts a traversal of tree `rec` over [t_min, t_max]; false when the ray misses its box.
fn trav_begin(s: ptr<function, Trav>, rec: ModelRec, o: vec3<f32>, inv: vec3<f32>, t_min: f32, t_max: f32) -> bool {
    let hit = ray_box(o, inv, rec.bmin.xyz, rec.bmax.xyz, t_min, t_max);
    if (hit.z == 0.0) {
        return false;
    }
    (*s).node_base = rec.node_base;
    (*s).o = o;
    (*s).inv = inv;
    (*s).scene_min = hit.x;
    (*s).scene_max = hit.y;
    (*s).tmax = hit.x;
    (*s).root = 0u;
    (*s).first = true;
    (*s).top = 0u;
    (*s).len = 0u;
    (*s).fallback = false;
    return true;
}

fn trav_push(s: ptr<function, Trav>, node: u32, tmin: f32, tmax: f32) {
    let k = (*s).top;
    (*s).stack_node[k] = node;
    (*s).stack_tmin[k] = tmin;
    (*s).stack_tmax[k] = tmax;
    (*s).top = select(k + 1u, 0u, k + 1u == STACK);
    (*s).len = min((*s).len + 1u, STACK);
}

// The next leaf front to back, as its node words (count << 2 | 3, offset), with its
// interval in (*s).tmin, (*s).tmax; vec2(0) when the interval is used up or the ray must go
// to the CPU ((*s).fallback). The caller ends the walk early by the termination rule.
fn trav_next_leaf(s: ptr<function, Trav>) -> vec2<u32> {
    if (!((*s).tmax < (*s).scene_max || (*s).first)) {
        return vec2<u32>(0u, 0u);
    }
    var node: u32;
    var pushdown: bool;
    if ((*s).len == 0u) {
        (*s).first = false;
        node = (*s).root;
        (*s).tmin = (*s).tmax;
        (*s).tmax = (*s).scene_max;
        pushdown = true;
    } else {
        let k = select((*s).top - 1u, STACK - 1u, (*s).top == 0u);
        (*s).top = k;
        (*s).len -= 1u;
        node = (*s).stack_node[k];
        (*s).tmin = (*s).stack_tmin[k];
        (*s).tmax = (*s).stack_tmax[k];
        pushdown = false;
    }
    var n = node_at((*s).node_base + node);
    loop {
        if ((n.x & 3u) == 3u) {
            break;
        }
        let axis = n.x & 3u;
        let inv_a = (*s).inv[axis];
        let t_split = (bitcast<f32>(n.y) - (*s).o[axis]) * inv_a;
        let below = node + 1u;
        let above = n.x >> 2u;
        var one = below;
        var two = above;
        if (inv_a < 0.0) {
            one = above;
            two = below;
        }
        // Where the CPU would find both comparisons false and walk every leaf instead.
        if (is_nan_(t_split)) {
            (*s).fallback = true;
            return vec2<u32>(0u, 0u);
        }
        if (t_split >= (*s).tmax) {
            node = one;
        } else if (t_split <= (*s).tmin) {
            node = two;
        } else {
            trav_push(s, two, t_split, (*s).tmax);
            node = one;
            (*s).tmax = t_split;
            pushdown = false;
        }
        if (pushdown) {
            (*s).root = node;
        }
        n = node_at((*s).node_base + node);
    }
    return n;
}

// Whether a leaf's best distance ends the walk (KdTree::traverse's termination rule).
fn trav_done(s: ptr<function, Trav>, best: f32) -> bool {
    return best + SLACK * abs((*s).tmax) < (*s).tmax;
}

// ---- One model (ModelAccel) -----------------------------------------------------------------

struct Best {
    t: f32,
    instance: u32,
    triangle: u32,
    u: f32,
    v: f32,
}

// ModelAccel::offer: triangle p of `instance` against the model-space ray; becomes `best`
// when closer (ties: lower (instance, triangle)) and opaque there.
fn offer(rec: ModelRec, o: vec3<f32>, d: vec3<f32>, t_min: f32, instance: u32, p: u32, best: ptr<function, Best>) {
    let k = 3u * (rec.tri_base + p);
    let a = tri_at(k);
    let h = intersect_triangle(o, d, a.xyz, tri_at(k + 1u).xyz, tri_at(k + 2u).xyz, t_min, (*best).t);
    if (h.w == 0.0) {
        return;
    }
    if (h.x == (*best).t && (instance > (*best).instance || (instance == (*best).instance && p >= (*best).triangle))) {
        return;
    }
    if (!passes_alpha(rec, bitcast<u32>(a.w), h.y, h.z)) {
        return;
    }
    *best = Best(h.x, instance, p, h.y, h.z);
}

// ModelAccel::closest: improves `best` with model m's triangles; true when the ray must go to
// the CPU.
fn model_closest(m: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, instance: u32, best: ptr<function, Best>) -> bool {
    let rec = models[m];
    var s: Trav;
    if (!trav_begin(&s, rec, o, 1.0 / d, t_min, (*best).t)) {
        return false;
    }
    loop {
        let leaf = trav_next_leaf(&s);
        if (leaf.x == 0u) {
            break;
        }
        let off = rec.prim_base + leaf.y;
        for (var k = 0u; k < (leaf.x >> 2u); k++) {
            offer(rec, o, d, t_min, instance, prim_at(off + k), best);
        }
        if (trav_done(&s, (*best).t)) {
            break;
        }
    }
    return s.fallback;
}

// ModelAccel::any: an opaque hit with t_min < t ≤ t_max. x: 1 when found, y: 1 when the ray
// must go to the CPU.
fn model_any(m: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> vec2<u32> {
    let rec = models[m];
    var s: Trav;
    if (!trav_begin(&s, rec, o, 1.0 / d, t_min, t_max)) {
        return vec2<u32>(0u, 0u);
    }
    loop {
        let leaf = trav_next_leaf(&s);
        if (leaf.x == 0u) {
            break;
        }
        let off = rec.prim_base + leaf.y;
        for (var k = 0u; k < (leaf.x >> 2u); k++) {
            let p = prim_at(off + k);
            let t = 3u * (rec.tri_base + p);
            let a = tri_at(t);
            let h = intersect_triangle(o, d, a.xyz, tri_at(t + 1u).xyz, tri_at(t + 2u).xyz, t_min, t_max);
            if (h.w != 0.0 && passes_alpha(rec, bitcast<u32>(a.w), h.y, h.z)) {
                return vec2<u32>(1u, 0u);
            }
        }
    }
    return vec2<u32>(0u, select(0u, 1u, s.fallback));
}

// ---- The scene (SceneAccel) -----------------------------------------------------------------

struct Placed {
    model: u32,
    o: vec3<f32>,
    d: vec3<f32>,
}

// The world-space ray in instance i's model space (Affine3A::transform_point3 and
// transform_vector3 of its world → model map).
fn to_model(i: u32, o: vec3<f32>, d: vec3<f32>) -> Placed {
    let x = inst_at(4u * i);
    let y = inst_at(4u * i + 1u).xyz;
    let z = inst_at(4u * i + 2u).xyz;
    let t = inst_at(4u * i + 3u).xyz;
    let mo = x.xyz * o.x + y * o.y + z * o.z + t;
    let md = x.xyz * d.x + y * d.y + z * d.z;
    return Placed(bitcast<u32>(x.w), mo, md);
}

// SceneAccel::ground_t: x = t where the ray meets the ground rectangle, y = 1 if it does.
fn ground_t(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> vec2<f32> {
    if (scene.ground.x == 0.0 || d.y == 0.0) {
        return vec2<f32>(0.0, 0.0);
    }
    let t = -o.y / d.y;
    let p = o + d * t;
    let ok = t > t_min && t <= t_max && abs(p.x) <= scene.ground.y && abs(p.z) <= scene.ground.z;
    return vec2<f32>(t, select(0.0, 1.0, ok));
}

struct Mailbox {
    ids: array<u32, MAILBOX>,
    next: u32,
}

fn mailbox_new() -> Mailbox {
    var m: Mailbox;
    for (var k = 0u; k < MAILBOX; k++) {
        m.ids[k] = NONE;
    }
    m.next = 0u;
    return m;
}

// Records instance `id`; false when it was seen recently.
fn first_visit(m: ptr<function, Mailbox>, id: u32) -> bool {
    for (var k = 0u; k < MAILBOX; k++) {
        if ((*m).ids[k] == id) {
            return false;
        }
    }
    (*m).ids[(*m).next] = id;
    (*m).next = ((*m).next + 1u) % MAILBOX;
    return true;
}

// A top-level leaf's instances met by the ray, sorted by box entry (stable: ties keep leaf
// order), as SceneAccel::entries.
struct Candidates {
    t: array<f32, SORTED>,
    i: array<u32, SORTED>,
    n: u32,
}

// Inserts instance `i` entered at `t`; false when the list is full (the caller enters it at
// once).
fn candidates_insert(c: ptr<function, Candidates>, t: f32, i: u32) -> bool {
    if ((*c).n == SORTED) {
        return false;
    }
    var j = (*c).n;
    while (j > 0u && (*c).t[j - 1u] > t) {
        (*c).t[j] = (*c).t[j - 1u];
        (*c).i[j] = (*c).i[j - 1u];
        j -= 1u;
    }
    (*c).t[j] = t;
    (*c).i[j] = i;
    (*c).n += 1u;
    return true;
}

struct Closest {
    best: Best,
    fallback: bool,
}

// SceneAccel::closest_hit for a valid ray: the closest of the ground and every instance's
// triangles with t_min < t ≤ t_max; ties go to the lowest (instance, triangle), the ground
// loses them.
fn closest_hit(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> Closest {
    var best = Best(t_max, NONE, NONE, 0.0, 0.0);
    let g = ground_t(o, d, t_min, t_max);
    if (g.y != 0.0) {
        let p = o + d * g.x;
        best = Best(g.x, GROUND, 0u, p.x, p.z);
    }
    var fallback = false;
    let top = models[scene.counts.x];
    let inv = 1.0 / d;
    var s: Trav;
    var mailbox = mailbox_new();
    if (trav_begin(&s, top, o, inv, t_min, best.t)) {
        loop {
            let leaf = trav_next_leaf(&s);
            if (leaf.x == 0u) {
                break;
            }
            // The leaf's instances whose box the ray meets before the closest hit, nearest
            // entry first (the first SORTED of them; further ones are entered at once).
            var cand = Candidates();
            let t_end = best.t;
            let off = top.prim_base + leaf.y;
            for (var k = 0u; k < (leaf.x >> 2u); k++) {
                let i = prim_at(off + k);
                let hit = ray_box(o, inv, box_at(2u * i).xyz, box_at(2u * i + 1u).xyz, t_min, t_end);
                if (hit.z != 0.0 && !candidates_insert(&cand, hit.x, i) && first_visit(&mailbox, i)) {
                    let r = to_model(i, o, d);
                    let f = model_closest(r.model, r.o, r.d, t_min, i, &best);
                    fallback = fallback || f;
                }
            }
            for (var k = 0u; k < cand.n; k++) {
                // Equal entry still enters: a hit at exactly best.t may win the tie.
                if (cand.t[k] > best.t) {
                    break;
                }
                let i = cand.i[k];
                if (first_visit(&mailbox, i)) {
                    let r = to_model(i, o, d);
                    let f = model_closest(r.model, r.o, r.d, t_min, i, &best);
                    fallback = fallback || f;
                }
            }
            if (trav_done(&s, best.t)) {
                break;
            }
        }
    }
    return Closest(best, fallback || s.fallback);
}

// SceneAccel::any_hit_from for a valid ray: anything opaque on t_min < t ≤ t_max (the ground
// included)? `start` (NONE: none) is the instance the ray starts on, tested first. x: 1 when
// blocked, y: 1 when the ray must go to the CPU.
fn any_hit(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32, start: u32) -> vec2<u32> {
    if (ground_t(o, d, t_min, t_max).y != 0.0) {
        return vec2<u32>(1u, 0u);
    }
    var fallback = 0u;
    var mailbox = mailbox_new();
    if (start < scene.counts.y) {
        _ = first_visit(&mailbox, start);
        let r = to_model(start, o, d);
        let a = model_any(r.model, r.o, r.d, t_min, t_max);
        if (a.x == 1u) {
            return a;
        }
        fallback = a.y;
    }
    let top = models[scene.counts.x];
    let inv = 1.0 / d;
    var s: Trav;
    if (!trav_begin(&s, top, o, inv, t_min, t_max)) {
        return vec2<u32>(0u, fallback);
    }
    loop {
        let leaf = trav_next_leaf(&s);
        if (leaf.x == 0u) {
            break;
        }
        var cand = Candidates();
        let off = top.prim_base + leaf.y;
        for (var k = 0u; k < (leaf.x >> 2u); k++) {
            let i = prim_at(off + k);
            let hit = ray_box(o, inv, box_at(2u * i).xyz, box_at(2u * i + 1u).xyz, t_min, t_max);
            if (hit.z != 0.0 && !candidates_insert(&cand, hit.x, i) && first_visit(&mailbox, i)) {
                let r = to_model(i, o, d);
                let a = model_any(r.model, r.o, r.d, t_min, t_max);
                if (a.x == 1u) {
                    return a;
                }
                fallback = fallback | a.y;
            }
        }
        for (var k = 0u; k < cand.n; k++) {
            let i = cand.i[k];
            if (first_visit(&mailbox, i)) {
                let r = to_model(i, o, d);
                let a = model_any(r.model, r.o, r.d, t_min, t_max);
                if (a.x == 1u) {
                    return a;
                }
                fallback = fallback | a.y;
            }
        }
    }
    return vec2<u32>(0u, fallback | select(0u, 1u, s.fallback));
}
