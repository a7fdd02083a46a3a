// Batches of rays through the traversal: one invocation per ray, 64 per workgroup (an 8×8
// tile at one ray per pixel, in the order the renderer sends them).

struct Batch {
    count: u32,
    // Workgroups along x of the dispatch (a large batch is dispatched in two dimensions).
    groups_x: u32,
    pad0: u32,
    pad1: u32,
}

@group(1) @binding(0) var<uniform> batch: Batch;
// Two per ray: (origin, t_min), (direction, t_max).
@group(1) @binding(1) var<storage, read> rays: array<vec4<f32>>;
// Shadow rays: the instance each starts on (NONE: none).
@group(1) @binding(2) var<storage, read> from_instance: array<u32>;
// Closest hits: two per ray, (t, instance, triangle, 1 when the CPU must answer), (u, v, 0, 0).
// Shadow rays: one per ray, (1 when blocked, 1 when the CPU must answer, 0, 0).
@group(1) @binding(3) var<storage, read_write> answers: array<vec4<u32>>;

fn ray_index(wg: vec3<u32>, l: u32) -> u32 {
    return (wg.y * batch.groups_x + wg.x) * 64u + l;
}

@compute @workgroup_size(64)
fn closest(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) l: u32) {
    let i = ray_index(wg, l);
    if (i >= batch.count) {
        return;
    }
    let a = rays[2u * i];
    let b = rays[2u * i + 1u];
    let c = closest_hit(a.xyz, b.xyz, a.w, b.w);
    answers[2u * i] = vec4<u32>(bitcast<u32>(c.best.t), c.best.instance, c.best.triangle, select(0u, 1u, c.fallback));
    answers[2u * i + 1u] = vec4<u32>(bitcast<u32>(c.best.u), bitcast<u32>(c.best.v), 0u, 0u);
}

@compute @workgroup_size(64)
fn shadow(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) l: u32) {
    let i = ray_index(wg, l);
    if (i >= batch.count) {
        return;
    }
    let a = rays[2u * i];
    let b = rays[2u * i + 1u];
    let r = any_hit(a.xyz, b.xyz, a.w, b.w, from_instance[i]);
    answers[i] = vec4<u32>(r.x, r.y, 0u, 0u);
}
