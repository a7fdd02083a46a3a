//! Tracer benchmark: `cargo run --release -p sylva-trace --example trace_bench -- [SCENE...]
//! [--runs N] [--stack S] [--no-obvhs] [--packets] [--size WxH]` (default scenes: beech
//! catalpa; 5 runs; the scene camera's image size).
//!
//! `--packets` traces the primary rays of full tiles in 2×2 packets, as `sylva render`
//! does; the shadow-ray statistics split lit from blocked rays.
//!
//! For each scene: builds the two-level kd-trees, traces one primary ray per pixel of the
//! scene camera's image over rayon in 8×8 tiles, then one shadow ray to the sun from every
//! hit, and prints build time, Mrays/s, frame time (primary + shadow), restarts and the
//! structures' memory; then the same rays through obvhs 0.4 (one CWBVH per model, one over
//! the instances' world boxes, the same alpha rule) and how many results agree. Times are
//! medians over the runs.

use glam::{Vec3, Vec3A};
use obvhs::{
    aabb::Aabb as OAabb, cwbvh::builder::build_cwbvh, cwbvh::builder::build_cwbvh_from_tris,
    cwbvh::CwBvh, ray::Ray as ORay, ray::RayHit, triangle::Triangle as OTri, BvhBuildParams,
};
use rayon::prelude::*;
use std::time::{Duration, Instant};
use sylva_geom::Scene;
use sylva_trace::{Hit, PinholeCamera, Ray, SceneAccel, TraceStats, TraversalConfig};

const TILE: u32 = 8;

/// CPU seconds used by the whole process so far (all threads): with other jobs on the host,
/// wall time over-states the cost; CPU time divided by the thread count does less so.
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Wall and CPU seconds of repeated runs.
#[derive(Default)]
struct Times {
    wall: Vec<f64>,
    cpu: Vec<f64>,
}

impl Times {
    fn run<T>(&mut self, f: impl FnOnce() -> T) -> T {
        let (w, c) = (Instant::now(), cpu_seconds());
        let out = f();
        self.wall.push(w.elapsed().as_secs_f64());
        self.cpu.push(cpu_seconds() - c);
        out
    }
    fn wall(&self) -> f64 {
        median(self.wall.clone())
    }
    fn cpu(&self) -> f64 {
        median(self.cpu.clone())
    }
    /// "wall s (cpu s)".
    fn show(&self) -> String {
        format!("{:.3} s (cpu {:.3} s)", self.wall(), self.cpu())
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Tiles of the image, each a list of pixel indices (row-major within the tile).
/// `--packets`: primary rays in 2×2 packets ([`SceneAccel::closest_hit_packet`]).
static PACKETS: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn tiles(w: u32, h: u32) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    for ty in (0..h).step_by(TILE as usize) {
        for tx in (0..w).step_by(TILE as usize) {
            let mut t = Vec::with_capacity((TILE * TILE) as usize);
            for y in ty..(ty + TILE).min(h) {
                for x in tx..(tx + TILE).min(w) {
                    t.push(y * w + x);
                }
            }
            out.push(t);
        }
    }
    out
}

/// Shadow ray from a hit: from the hit point, nudged off the surface on the sun's side.
fn shadow_ray(ray: &Ray, t: f32, n: Vec3, sun: Vec3) -> Ray {
    let p = ray.at(t);
    let side = if n.dot(sun) >= 0.0 { 1.0 } else { -1.0 };
    let eps = 1e-4 * p.abs().max_element().max(1.0);
    Ray::new(p + n * (side * eps), sun)
}

/// The alpha rule at obvhs's hit, with barycentrics in sylva's convention.
fn opaque(model: &sylva_trace::ModelAccel, id: u32, tri: &OTri, r: &ORay) -> bool {
    let ray = Ray::segment(
        r.origin.into(),
        r.direction.into(),
        f32::NEG_INFINITY,
        f32::INFINITY,
    );
    match sylva_trace::ray::intersect_triangle_vertices(
        &ray,
        tri.v0.into(),
        tri.v1.into(),
        tri.v2.into(),
    ) {
        Some((_, u, v)) => model.is_opaque_at(id, u, v),
        None => true,
    }
}

struct Obvhs {
    models: Vec<CwBvh>,
    /// Triangles of each model in its BVH's primitive order.
    tris: Vec<Vec<OTri>>,
    /// Original triangle id per BVH primitive slot.
    ids: Vec<Vec<u32>>,
    top: CwBvh,
}

fn build_obvhs(scene: &Scene, accel: &SceneAccel) -> Obvhs {
    /// A model's BVH, its triangles in BVH order, and their original ids.
    type Built = (CwBvh, (Vec<OTri>, Vec<u32>));
    let built: Vec<Built> = scene
        .models
        .par_iter()
        .map(|m| {
            let tris: Vec<OTri> = m
                .mesh
                .indices
                .iter()
                .map(|t| {
                    let p = |k: u32| Vec3A::from_array(m.mesh.positions[k as usize]);
                    OTri {
                        v0: p(t[0]),
                        v1: p(t[1]),
                        v2: p(t[2]),
                    }
                })
                .collect();
            let bvh = build_cwbvh_from_tris(
                &tris,
                BvhBuildParams::medium_build(),
                &mut Duration::default(),
            );
            let ids = bvh.primitive_indices.clone();
            let ordered = ids.iter().map(|&i| tris[i as usize]).collect();
            (bvh, (ordered, ids))
        })
        .collect();
    let (models, rest): (Vec<CwBvh>, Vec<_>) = built.into_iter().unzip();
    let (tris, ids) = rest.into_iter().unzip();
    let boxes: Vec<OAabb> = accel
        .instances()
        .iter()
        .map(|i| {
            OAabb::new(
                Vec3A::from(i.world_bounds.min),
                Vec3A::from(i.world_bounds.max),
            )
        })
        .collect();
    let top = build_cwbvh(
        &boxes,
        BvhBuildParams::medium_build(),
        &mut Duration::default(),
    );
    Obvhs {
        models,
        tris,
        ids,
        top,
    }
}

impl Obvhs {
    /// Closest hit with the same alpha rule (via the kd-tree side's alpha data).
    fn closest(&self, scene: &Scene, accel: &SceneAccel, ray: &Ray) -> Option<(f32, u32, u32)> {
        // The ground plane is analytic on both sides: it bounds the ray first.
        let ground = accel.ground_hit(ray);
        let t_max = ground.unwrap_or(ray.t_max);
        let oray = ORay::new(
            Vec3A::from(ray.origin),
            Vec3A::from(ray.dir),
            ray.t_min,
            t_max,
        );
        let mut hit = RayHit::none();
        let mut best: Option<(u32, u32)> = None;
        self.top.ray_traverse(oray, &mut hit, |r, slot| {
            let inst_id = self.top.primitive_indices[slot];
            let inst = &accel.instances()[inst_id as usize];
            let m = inst.model as usize;
            let lr = ORay::new(
                inst.to_model.transform_point3a(r.origin),
                inst.to_model.transform_vector3a(r.direction),
                r.tmin,
                r.tmax,
            );
            let mut lh = RayHit::none();
            let model = &accel.models()[m];
            if self.models[m].ray_traverse(lr, &mut lh, |lr2, s| {
                let tri = &self.tris[m][s];
                let t = tri.intersect(lr2);
                if t.is_finite() && !opaque(model, self.ids[m][s], tri, lr2) {
                    return f32::INFINITY;
                }
                t
            }) {
                best = Some((inst_id, self.ids[m][lh.primitive_id as usize]));
                lh.t
            } else {
                f32::INFINITY
            }
        });
        let _ = scene;
        best.map(|(i, t)| (hit.t, i, t))
            .or(ground.map(|t| (t, Hit::GROUND, 0)))
    }

    fn occluded(&self, accel: &SceneAccel, ray: &Ray) -> bool {
        if accel.ground_hit(ray).is_some() {
            return true;
        }
        let oray = ORay::new(
            Vec3A::from(ray.origin),
            Vec3A::from(ray.dir),
            ray.t_min,
            ray.t_max,
        );
        !self.top.ray_traverse_miss(oray, |r, slot| {
            let inst_id = self.top.primitive_indices[slot];
            let inst = &accel.instances()[inst_id as usize];
            let m = inst.model as usize;
            let model = &accel.models()[m];
            let lr = ORay::new(
                inst.to_model.transform_point3a(r.origin),
                inst.to_model.transform_vector3a(r.direction),
                r.tmin,
                r.tmax,
            );
            let miss = self.models[m].ray_traverse_miss(lr, |lr2, s| {
                let tri = &self.tris[m][s];
                let t = tri.intersect(lr2);
                if t.is_finite() && !opaque(model, self.ids[m][s], tri, lr2) {
                    return f32::INFINITY;
                }
                t
            });
            if miss {
                f32::INFINITY
            } else {
                r.tmin.max(0.0)
            }
        })
    }

    fn memory_bytes(&self) -> u64 {
        let bvh = |b: &CwBvh| {
            (b.nodes.capacity() * std::mem::size_of_val(&b.nodes[0])
                + b.primitive_indices.capacity() * 4) as u64
        };
        self.models.iter().map(bvh).sum::<u64>()
            + bvh(&self.top)
            + self
                .tris
                .iter()
                .map(|t| (t.capacity() * std::mem::size_of::<OTri>()) as u64)
                .sum::<u64>()
            + self
                .ids
                .iter()
                .map(|i| i.capacity() as u64 * 4)
                .sum::<u64>()
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut scenes = Vec::new();
    let mut runs = 5usize;
    let mut stack = sylva_trace::DEFAULT_STACK_SIZE;
    let mut with_obvhs = true;
    let mut size = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--runs" => runs = it.next().and_then(|s| s.parse().ok()).expect("--runs N"),
            "--stack" => stack = it.next().and_then(|s| s.parse().ok()).expect("--stack S"),
            "--no-obvhs" => with_obvhs = false,
            "--packets" => PACKETS.store(true, std::sync::atomic::Ordering::Relaxed),
            "--size" => {
                let wh = it
                    .next()
                    .and_then(|s| s.split_once('x'))
                    .expect("--size WxH");
                size = Some((
                    wh.0.parse().expect("--size WxH"),
                    wh.1.parse().expect("--size WxH"),
                ));
            }
            s => scenes.push(s.to_string()),
        }
    }
    if scenes.is_empty() {
        scenes = vec!["beech".into(), "catalpa".into()];
    }
    let cfg = TraversalConfig::with_stack(stack);
    println!(
        "threads: {}, stack: {}, runs: {runs}",
        rayon::current_num_threads(),
        cfg.stack_size
    );
    for name in &scenes {
        bench_scene(name, runs, cfg, with_obvhs, size);
    }
}

fn bench_scene(
    name: &str,
    runs: usize,
    cfg: TraversalConfig,
    with_obvhs: bool,
    size: Option<(u32, u32)>,
) {
    let mut scene = sylva_scene::load(name).unwrap_or_else(|e| panic!("{e}"));
    if let Some((w, h)) = size {
        scene.camera.width = w;
        scene.camera.height = h;
    }
    let cam = PinholeCamera::new(&scene.camera).unwrap_or_else(|e| panic!("{e}"));
    let (w, h) = (cam.width, cam.height);
    let sun = scene.sun.to_sun().as_vec3();
    let tiles = tiles(w, h);
    println!(
        "\n== {name}: {} instances, {} unique / {} instanced triangles, {w}x{h}",
        scene.instances.len(),
        scene.unique_triangles(),
        scene.instanced_triangles()
    );

    let mut build_s = Times::default();
    let mut accel = None;
    for _ in 0..runs.max(1) {
        accel = Some(build_s.run(|| SceneAccel::build(&scene).unwrap_or_else(|e| panic!("{e}"))));
    }
    let accel = accel.unwrap();
    let mem = accel.memory();
    let refs: usize = accel
        .models()
        .iter()
        .map(|m| m.tree().stats().references)
        .sum();
    let nodes: usize = accel.models().iter().map(|m| m.tree().stats().nodes).sum();
    let depth = accel
        .models()
        .iter()
        .map(|m| m.tree().stats().max_depth)
        .max()
        .unwrap_or(0);
    println!(
        "build: {} (median of {runs}); {nodes} nodes, {refs} references, max depth {depth}; top level {} nodes",
        build_s.show(),
        accel.top_stats().nodes
    );
    println!(
        "memory: models {:.1} MiB (trees + triangle + alpha data), top level {:.3} MiB; scene meshes {:.1} MiB",
        mem.models as f64 / 1048576.0,
        mem.top as f64 / 1048576.0,
        scene.memory_bytes() as f64 / 1048576.0
    );

    // Primary rays.
    let mut prim_s = Times::default();
    let mut shadow_s = Times::default();
    let mut hits: Vec<Option<Hit>> = Vec::new();
    let mut pstats = TraceStats::default();
    let mut sstats = TraceStats::default();
    let mut split = [TraceStats::default(); 2];
    let mut lit = 0usize;
    for _ in 0..runs.max(1) {
        let per_tile: Vec<(Vec<Option<Hit>>, TraceStats)> = prim_s.run(|| {
            tiles
                .par_iter()
                .map(|tile| {
                    let mut st = TraceStats::default();
                    let full = tile.len() == (TILE * TILE) as usize;
                    if !(PACKETS.load(std::sync::atomic::Ordering::Relaxed) && full) {
                        let hs = tile
                            .iter()
                            .map(|&p| accel.closest_hit(&cam.pixel_ray(p % w, p / w), cfg, &mut st))
                            .collect();
                        return (hs, st);
                    }
                    let t = TILE as usize;
                    let mut hs = vec![None; tile.len()];
                    for by in (0..t).step_by(2) {
                        for bx in (0..t).step_by(2) {
                            let ids = [
                                by * t + bx,
                                by * t + bx + 1,
                                (by + 1) * t + bx,
                                (by + 1) * t + bx + 1,
                            ];
                            let rays = ids.map(|i| cam.pixel_ray(tile[i] % w, tile[i] / w));
                            let got = accel.closest_hit_packet(&rays, 0b1111, cfg, &mut st);
                            for (l, &i) in ids.iter().enumerate() {
                                hs[i] = got[l];
                            }
                        }
                    }
                    (hs, st)
                })
                .collect()
        });
        hits = vec![None; (w * h) as usize];
        pstats = TraceStats::default();
        for (tile, (hs, st)) in tiles.iter().zip(per_tile) {
            pstats += st;
            for (&p, hit) in tile.iter().zip(hs) {
                hits[p as usize] = hit;
            }
        }
        // Shadow rays from every hit.
        let per_tile: Vec<(usize, [TraceStats; 2])> = shadow_s.run(|| {
            tiles
                .par_iter()
                .map(|tile| {
                    // [lit, occluded]
                    let mut st = [TraceStats::default(); 2];
                    let mut lit = 0usize;
                    for &p in tile {
                        if let Some(hit) = hits[p as usize] {
                            let ray = cam.pixel_ray(p % w, p / w);
                            let s = shadow_ray(&ray, hit.t, accel.geometric_normal(&hit), sun);
                            let mut one = TraceStats::default();
                            let occluded = accel.any_hit_from(
                                &s,
                                (!hit.is_ground()).then_some(hit.instance),
                                cfg,
                                &mut one,
                                &mut sylva_trace::OccluderCache::new(),
                            );
                            lit += !occluded as usize;
                            st[occluded as usize] += one;
                        }
                    }
                    (lit, st)
                })
                .collect()
        });
        sstats = TraceStats::default();
        split = [TraceStats::default(); 2];
        lit = 0;
        for (l, st) in per_tile {
            lit += l;
            sstats += st[0];
            sstats += st[1];
            split[0] += st[0];
            split[1] += st[1];
        }
    }
    let (tp, ts) = (prim_s.wall(), shadow_s.wall());
    let n_hits = hits.iter().filter(|h| h.is_some()).count();
    println!(
        "kd-tree: primary {} ({:.2} Mrays/s), shadow {} ({} rays, {:.2} Mrays/s), frame {:.3} s (cpu {:.3} s)",
        prim_s.show(),
        pstats.rays as f64 / tp / 1e6,
        shadow_s.show(),
        sstats.rays,
        sstats.rays as f64 / ts / 1e6,
        tp + ts,
        prim_s.cpu() + shadow_s.cpu()
    );
    let per = |s: &TraceStats, v: u64| v as f64 / s.rays.max(1) as f64;
    println!(
        "  primary per ray: {:.1} nodes, {:.1} leaves, {:.1} triangle tests, {:.2} instances, {:.3} restarts, {:.2} alpha rejects; {} hits, {} ground",
        per(&pstats, pstats.nodes), per(&pstats, pstats.leaves), per(&pstats, pstats.triangle_tests),
        per(&pstats, pstats.instance_visits), per(&pstats, pstats.restarts), per(&pstats, pstats.alpha_rejects),
        n_hits, hits.iter().flatten().filter(|h| h.is_ground()).count()
    );
    println!(
        "  shadow per ray: {:.1} nodes, {:.1} triangle tests, {:.2} instances, {:.3} restarts; {} lit",
        per(&sstats, sstats.nodes), per(&sstats, sstats.triangle_tests),
        per(&sstats, sstats.instance_visits), per(&sstats, sstats.restarts), lit
    );
    for (name, s) in ["lit", "occluded"].iter().zip(&split) {
        println!(
            "    {name} rays: {}, per ray {:.1} nodes, {:.1} triangle tests, {:.2} instances; {:.0} % of all nodes",
            s.rays, per(s, s.nodes), per(s, s.triangle_tests), per(s, s.instance_visits),
            100.0 * s.nodes as f64 / sstats.nodes.max(1) as f64
        );
    }

    if !with_obvhs {
        return;
    }
    // obvhs on the same rays; the ground plane is analytic on both sides.
    let mut ob_build = Times::default();
    let ob = ob_build.run(|| build_obvhs(&scene, &accel));
    let mut prim_s = Times::default();
    let mut shadow_s = Times::default();
    let mut agree = 0usize;
    let mut ob_lit = 0usize;
    for _ in 0..runs.max(1) {
        let ohits: Vec<Vec<Option<(f32, u32, u32)>>> = prim_s.run(|| {
            tiles
                .par_iter()
                .map(|tile| {
                    tile.iter()
                        .map(|&p| {
                            let ray = cam.pixel_ray(p % w, p / w);
                            ob.closest(&scene, &accel, &ray)
                        })
                        .collect()
                })
                .collect()
        });
        agree = 0;
        for (tile, hs) in tiles.iter().zip(&ohits) {
            for (&p, oh) in tile.iter().zip(hs) {
                let same = match (hits[p as usize], oh) {
                    (None, None) => true,
                    (Some(a), Some(b)) => a.instance == b.1 && a.triangle == b.2,
                    _ => false,
                };
                agree += same as usize;
            }
        }
        ob_lit = shadow_s.run(|| {
            tiles
                .par_iter()
                .map(|tile| {
                    let mut lit = 0usize;
                    for &p in tile {
                        if let Some(hit) = hits[p as usize] {
                            let ray = cam.pixel_ray(p % w, p / w);
                            let s = shadow_ray(&ray, hit.t, accel.geometric_normal(&hit), sun);
                            lit += !ob.occluded(&accel, &s) as usize;
                        }
                    }
                    lit
                })
                .sum()
        });
    }
    let (op, os) = (prim_s.wall(), shadow_s.wall());
    println!(
        "obvhs 0.4 (CWBVH, medium_build): build {}, memory {:.1} MiB; primary {} ({:.2} Mrays/s), shadow {} ({:.2} Mrays/s), frame {:.3} s (cpu {:.3} s)",
        ob_build.show(),
        ob.memory_bytes() as f64 / 1048576.0,
        prim_s.show(),
        pstats.rays as f64 / op / 1e6,
        shadow_s.show(),
        sstats.rays as f64 / os / 1e6,
        op + os,
        prim_s.cpu() + shadow_s.cpu()
    );
    println!(
        "  agreement: {agree}/{} primary pixels same instance+triangle, lit {ob_lit} vs {lit}",
        w * h
    );
}
