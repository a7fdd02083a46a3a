//! `sylva bench rays SCENE`: the kd-tree alone (no shading, no light) on three sets of rays
//! from one view: primary rays (pixel centres), shadow rays (from their hits towards the sun)
//! and incoherent rays (cosine-distributed about the normal at the same hits). With an export
//! directory it also writes the scene's triangles, alpha masks, instances, the rays and the
//! kd-tree's answers as flat files, so that `tools/embree/compare.py` traces the very same
//! rays through Embree (issue 28 item 3).

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use sylva_core::measure::median;
use sylva_core::{OutputError, OutputSet, SplitMix64};
use sylva_geom::{Camera, Scene};
use sylva_trace::{Hit, KdTracer, PinholeCamera, Ray, RayQuery, ShadowRay, TraceStats};

use crate::{PipelineError, PreparedScene};

/// Rays per work unit: one 8×8 tile, as the renderer hands the tracer.
const BATCH: usize = 64;

/// Bytes a pixel of the view takes at most: its primary, shadow and incoherent rays (32,
/// 40, 32), their answers (24, 1, 24), a timed pass's copies of those and its place in the
/// order (8), rounded up.
const BYTES_PER_PIXEL: u64 = 256;

/// The three ray sets of one view.
#[derive(Debug, Clone)]
pub struct RaySets {
    /// Pixel centres, 8×8 tiles row by row, 2×2 quads within a tile (a packet is a quad).
    pub primary: Vec<Ray>,
    /// One per primary hit, towards the sun, from the hit's sun side (as the renderer
    /// starts them), in the primary rays' order.
    pub shadow: Vec<ShadowRay>,
    /// One per primary hit, cosine-distributed about the normal on the side the primary ray
    /// came from, from a generator seeded per pixel.
    pub incoherent: Vec<Ray>,
}

/// Pixels of a `width × height` image in the primary rays' order.
fn pixel_order(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut out = Vec::with_capacity((width * height) as usize);
    for ty in (0..height).step_by(8) {
        for tx in (0..width).step_by(8) {
            for qy in (ty..(ty + 8).min(height)).step_by(2) {
                for qx in (tx..(tx + 8).min(width)).step_by(2) {
                    for (x, y) in [(qx, qy), (qx + 1, qy), (qx, qy + 1), (qx + 1, qy + 1)] {
                        if x < width && y < height {
                            out.push((x, y));
                        }
                    }
                }
            }
        }
    }
    out
}

/// A cosine-distributed unit vector about `n` from two uniform numbers.
fn cosine_about(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (b1, b2) = n.any_orthonormal_pair();
    (b1 * (r * phi.cos()) + b2 * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

/// The closest hits of `rays` on `tracer`, in batches of [`BATCH`] on the thread pool, and
/// the traversal's counts.
fn closest_all(tracer: &KdTracer, rays: &[Ray]) -> (Vec<Option<Hit>>, TraceStats) {
    let mut hits = vec![None; rays.len()];
    let stats = hits
        .par_chunks_mut(BATCH)
        .zip(rays.par_chunks(BATCH))
        .map(|(h, r)| {
            let mut st = TraceStats::default();
            tracer.closest_hits(r, h, &mut st);
            st
        })
        .reduce(TraceStats::default, |mut a, b| {
            a += b;
            a
        });
    (hits, stats)
}

/// Whether each shadow ray is blocked, in batches of [`BATCH`] on the thread pool, and the
/// traversal's counts.
fn blocked_all(tracer: &KdTracer, rays: &[ShadowRay]) -> (Vec<bool>, TraceStats) {
    let mut blocked = vec![false; rays.len()];
    let stats = blocked
        .par_chunks_mut(BATCH)
        .zip(rays.par_chunks(BATCH))
        .map(|(b, r)| {
            let mut st = TraceStats::default();
            tracer.any_hits(r, b, &mut st);
            st
        })
        .reduce(TraceStats::default, |mut a, b| {
            a += b;
            a
        });
    (blocked, stats)
}

/// The three sets for `camera` (its `width × height`), the sun towards `to_sun`.
pub fn ray_sets(
    tracer: &KdTracer,
    camera: &Camera,
    to_sun: Vec3,
    seed: u64,
) -> Result<RaySets, PipelineError> {
    let pinhole = PinholeCamera::new(camera)?;
    let pixels = u64::from(camera.width) * u64::from(camera.height);
    sylva_core::check_memory(
        &format!(
            "the ray sets of a {}x{} view (rays, answers, a timed pass's copies)",
            camera.width, camera.height
        ),
        pixels * BYTES_PER_PIXEL,
    )?;
    let pixels = pixel_order(camera.width, camera.height);
    let primary: Vec<Ray> = pixels
        .iter()
        .map(|&(x, y)| pinhole.pixel_ray(x, y))
        .collect();
    let (hits, _) = closest_all(tracer, &primary);
    let accel = &tracer.accel;
    let mut shadow = Vec::new();
    let mut incoherent = Vec::new();
    for (k, (ray, hit)) in primary.iter().zip(&hits).enumerate() {
        let Some(hit) = hit else { continue };
        let point = ray.at(hit.t);
        let ng = accel.geometric_normal(hit);
        let eps = 1e-4 * point.abs().max_element().max(1.0);
        let from = (!hit.is_ground()).then_some(hit.instance);
        let sun_side = if ng.dot(to_sun) >= 0.0 { ng } else { -ng };
        shadow.push(ShadowRay {
            ray: Ray::new(point + sun_side * eps, to_sun),
            from,
        });
        let (x, y) = pixels[k];
        let mut rng =
            SplitMix64::for_chunk(seed, u64::from(y) * u64::from(camera.width) + u64::from(x));
        let facing = if ng.dot(ray.dir) <= 0.0 { ng } else { -ng };
        let dir = cosine_about(facing, rng.next_f64() as f32, rng.next_f64() as f32);
        incoherent.push(Ray::new(point + facing * eps, dir));
    }
    Ok(RaySets {
        primary,
        shadow,
        incoherent,
    })
}

/// One ray set's measure: medians of the timed passes.
#[derive(Debug, Clone, Serialize)]
pub struct RaySetMeasure {
    pub name: &'static str,
    /// `closest` or `any` (shadow rays: is anything opaque in the way).
    pub query: &'static str,
    pub rays: usize,
    /// Rays that hit something (closest), or were blocked (any).
    pub hits: usize,
    pub seconds: f64,
    pub mrays_per_second: f64,
    /// Per thread: what one core traces (the figure to set beside a single-threaded peer).
    pub mrays_per_cpu_second: f64,
    /// Per ray: kd-tree steps (a packet's step counts once), leaves, triangle tests and
    /// model parts entered (both tree levels).
    pub nodes_per_ray: f64,
    pub leaves_per_ray: f64,
    pub triangle_tests_per_ray: f64,
    pub parts_per_ray: f64,
}

/// `sylva bench rays`' report.
#[derive(Debug, Clone, Serialize)]
pub struct RaysBench {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    pub runs: u32,
    pub instances: usize,
    pub instanced_triangles: u64,
    pub sets: Vec<RaySetMeasure>,
    /// Shadow over primary rays per second (issue 28 item 3: at least 1).
    pub shadow_over_primary: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exported_to: Option<PathBuf>,
}

impl fmt::Display for RaysBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} at {}x{}: {} instances, {} triangles; kd-tree alone, {} threads, medians of {} runs",
            self.scene,
            self.width,
            self.height,
            self.instances,
            self.instanced_triangles,
            self.threads,
            self.runs
        )?;
        writeln!(
            f,
            "  {:<11} {:>8} {:>9} {:>9} {:>10} {:>12}   per ray: {:>6} {:>6} {:>9} {:>6}",
            "rays",
            "query",
            "count",
            "hit",
            "Mrays/s",
            "Mrays/CPU-s",
            "steps",
            "leaves",
            "triangles",
            "parts"
        )?;
        for s in &self.sets {
            writeln!(
                f,
                "  {:<11} {:>8} {:>9} {:>8.1}% {:>10.2} {:>12.2}            {:>6.1} {:>6.1} {:>9.1} {:>6.2}",
                s.name,
                s.query,
                s.rays,
                100.0 * s.hits as f64 / s.rays.max(1) as f64,
                s.mrays_per_second,
                s.mrays_per_cpu_second,
                s.nodes_per_ray,
                s.leaves_per_ray,
                s.triangle_tests_per_ray,
                s.parts_per_ray
            )?;
        }
        writeln!(
            f,
            "  shadow / primary rays per second: {:.2}",
            self.shadow_over_primary
        )?;
        if let Some(dir) = &self.exported_to {
            writeln!(
                f,
                "  scene, rays and answers written to {} (tools/embree/compare.py {} traces them through Embree)",
                dir.display(),
                dir.display()
            )?;
        }
        Ok(())
    }
}

/// One untimed pass of `pass` (its result: the answers and counts, and a warm-up), then the
/// median seconds of `runs` timed ones.
fn timed<T>(runs: u32, mut pass: impl FnMut() -> T) -> (T, f64) {
    let first = pass();
    let seconds = median(
        (0..runs.max(1))
            .map(|_| {
                let t = Instant::now();
                drop(pass());
                t.elapsed().as_secs_f64()
            })
            .collect(),
    );
    (first, seconds)
}

/// Traces the three sets of `camera`'s view `runs` times each on the kd-tree (the thread
/// pool's threads), and writes them with the scene to `export` when given.
pub fn rays(
    p: &PreparedScene,
    camera: Camera,
    seed: u64,
    runs: u32,
    export: Option<&Path>,
) -> Result<RaysBench, PipelineError> {
    let tracer = p.tracer.cpu();
    let to_sun = crate::scene_to_sun(&p.scene);
    let sets = ray_sets(tracer, &camera, to_sun, seed)?;
    let threads = rayon::current_num_threads();
    let measure = |name, query, rays: usize, hits: usize, st: TraceStats, seconds: f64| {
        let mrays = rays as f64 / seconds.max(1e-12) * 1e-6;
        let per = |x: u64| x as f64 / rays.max(1) as f64;
        RaySetMeasure {
            name,
            query,
            rays,
            hits,
            seconds,
            mrays_per_second: mrays,
            mrays_per_cpu_second: mrays / threads as f64,
            nodes_per_ray: per(st.nodes),
            leaves_per_ray: per(st.leaves),
            triangle_tests_per_ray: per(st.triangle_tests),
            parts_per_ray: per(st.instance_visits),
        }
    };
    let ((primary_hits, primary_stats), primary_s) =
        timed(runs, || closest_all(tracer, &sets.primary));
    let ((blocked, shadow_stats), shadow_s) = timed(runs, || blocked_all(tracer, &sets.shadow));
    let ((incoherent_hits, incoherent_stats), incoherent_s) =
        timed(runs, || closest_all(tracer, &sets.incoherent));
    let count = |h: &[Option<Hit>]| h.iter().filter(|h| h.is_some()).count();
    let measures = vec![
        measure(
            "primary",
            "closest",
            sets.primary.len(),
            count(&primary_hits),
            primary_stats,
            primary_s,
        ),
        measure(
            "shadow",
            "any",
            sets.shadow.len(),
            blocked.iter().filter(|&&b| b).count(),
            shadow_stats,
            shadow_s,
        ),
        measure(
            "incoherent",
            "closest",
            sets.incoherent.len(),
            count(&incoherent_hits),
            incoherent_stats,
            incoherent_s,
        ),
    ];
    let report = RaysBench {
        scene: p.scene.name.clone(),
        width: camera.width,
        height: camera.height,
        threads,
        runs,
        instances: p.scene.instances.len(),
        instanced_triangles: p.scene.instanced_triangles(),
        shadow_over_primary: measures[1].mrays_per_second / measures[0].mrays_per_second,
        sets: measures,
        exported_to: export.map(Path::to_path_buf),
    };
    if let Some(dir) = export {
        let answers = Answers {
            primary: &primary_hits,
            shadow: &blocked,
            incoherent: &incoherent_hits,
        };
        export_rays(
            dir,
            &p.scene,
            tracer,
            &sets,
            &answers,
            to_sun,
            Some(&report),
        )?;
    }
    Ok(report)
}

/// The kd-tree's answers to the three sets.
pub struct Answers<'a> {
    pub primary: &'a [Option<Hit>],
    pub shadow: &'a [bool],
    pub incoherent: &'a [Option<Hit>],
}

/// What `manifest.json` of an export holds (tools/embree/README.md documents the files).
#[derive(Debug, Serialize)]
struct Manifest {
    format: &'static str,
    scene: String,
    /// Half extents (x, z) of the ground square at y = 0, when the scene has one.
    ground: Option<[f32; 2]>,
    to_sun: [f32; 3],
    models: Vec<ModelEntry>,
    masks: Vec<MaskEntry>,
    instances: usize,
    sets: Vec<SetEntry>,
}

#[derive(Debug, Serialize)]
struct ModelEntry {
    name: String,
    vertices: usize,
    triangles: usize,
}

#[derive(Debug, Serialize)]
struct MaskEntry {
    width: u32,
    height: u32,
    /// `repeat` or `clamp`: how texel indices outside the mask wrap.
    wrap: &'static str,
}

#[derive(Debug, Serialize)]
struct SetEntry {
    name: &'static str,
    query: &'static str,
    rays: usize,
}

fn le_bytes<T: Copy, const N: usize>(items: &[T], bytes: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    items.iter().flat_map(|&x| bytes(x)).collect()
}

fn f32s(v: &[f32]) -> Vec<u8> {
    le_bytes(v, f32::to_le_bytes)
}

fn u32s(v: &[u32]) -> Vec<u8> {
    le_bytes(v, u32::to_le_bytes)
}

fn i32s(v: &[i32]) -> Vec<u8> {
    le_bytes(v, i32::to_le_bytes)
}

/// Rays as rows of 8 little-endian f32: origin, t_min, direction, t_max.
fn ray_rows(rays: impl Iterator<Item = Ray>) -> Vec<u8> {
    let mut v = Vec::new();
    for r in rays {
        v.extend_from_slice(&[r.origin.x, r.origin.y, r.origin.z, r.t_min]);
        v.extend_from_slice(&[r.dir.x, r.dir.y, r.dir.z, r.t_max]);
    }
    f32s(&v)
}

/// Closest hits as rows of (t as f32 bits, instance, triangle) little-endian u32; a miss is
/// (∞, u32::MAX, u32::MAX); the ground's instance is u32::MAX with triangle 0.
fn hit_rows(hits: &[Option<Hit>]) -> Vec<u8> {
    let mut v = Vec::with_capacity(hits.len() * 3);
    for h in hits {
        match h {
            Some(h) => v.extend_from_slice(&[h.t.to_bits(), h.instance, h.triangle]),
            None => v.extend_from_slice(&[f32::INFINITY.to_bits(), u32::MAX, u32::MAX]),
        }
    }
    u32s(&v)
}

/// The 3×4 row-major matrix of `a` (rotation-scale columns, then translation).
fn matrix_rows(a: &Affine3A) -> [f32; 12] {
    let (m, t) = (a.matrix3, a.translation);
    [
        m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
        m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
        m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z,
    ]
}

/// Writes the scene (model-space meshes, alpha masks, instance transforms), the three ray
/// sets, `answers` and the `report` they were measured in under `dir` (created), as one
/// output set: every file is replaced, or (on an error or Ctrl-C) none.
pub fn export_rays(
    dir: &Path,
    scene: &Scene,
    tracer: &KdTracer,
    sets: &RaySets,
    answers: &Answers<'_>,
    to_sun: Vec3,
    report: Option<&RaysBench>,
) -> Result<(), PipelineError> {
    let mut set = OutputSet::new::<&Path>(&[]);
    // A file in the directory's place is refused here, before anything is made.
    set.plan(&[dir.join("manifest.json")])?;
    std::fs::create_dir_all(dir).map_err(|source| OutputError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut write = |name: &str, bytes: &[u8]| set.write_bytes(&dir.join(name), bytes);
    let accel = &tracer.accel;
    let mut models = Vec::new();
    let mut masks = Vec::new();
    for (k, (model, ma)) in scene.models.iter().zip(accel.models()).enumerate() {
        let mesh = &model.mesh;
        let positions: Vec<f32> = mesh.positions.iter().flatten().copied().collect();
        let indices: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
        let n = mesh.indices.len();
        // Per triangle: its mask (numbered across the models), or -1, and 3 corners' uv.
        let first_mask = masks.len() as i32;
        let mut mask_ids = Vec::with_capacity(n);
        let mut uvs = Vec::with_capacity(n * 6);
        for t in 0..n as u32 {
            match ma.triangle_alpha(t) {
                Some((uv, m)) => {
                    mask_ids.push(first_mask + m as i32);
                    uvs.extend(uv.iter().flat_map(|c| [c.x, c.y]));
                }
                None => {
                    mask_ids.push(-1);
                    uvs.extend([0.0; 6]);
                }
            }
        }
        write(&format!("model{k}_positions.f32"), &f32s(&positions))?;
        write(&format!("model{k}_indices.u32"), &u32s(&indices))?;
        write(&format!("model{k}_mask.i32"), &i32s(&mask_ids))?;
        write(&format!("model{k}_uv.f32"), &f32s(&uvs))?;
        for m in ma.alpha_masks() {
            let texels = (m.width() * m.height()) as usize;
            let opaque: Vec<u8> = (0..texels)
                .map(|i| (m.bits()[i / 64] >> (i % 64) & 1) as u8)
                .collect();
            write(&format!("mask{}.u8", masks.len()), &opaque)?;
            masks.push(MaskEntry {
                width: m.width(),
                height: m.height(),
                wrap: match m.wrap() {
                    sylva_geom::Wrap::Repeat => "repeat",
                    sylva_geom::Wrap::Clamp => "clamp",
                },
            });
        }
        models.push(ModelEntry {
            name: model.name.clone(),
            vertices: mesh.positions.len(),
            triangles: n,
        });
    }
    // Per instance: its model, then its 3×4 model-to-world matrix.
    let mut inst_models = Vec::new();
    let mut inst_matrices = Vec::new();
    for i in accel.instances() {
        inst_models.push(i.model);
        inst_matrices.extend(matrix_rows(&i.to_world));
    }
    write("instance_model.u32", &u32s(&inst_models))?;
    write("instance_to_world.f32", &f32s(&inst_matrices))?;
    write("primary_rays.f32", &ray_rows(sets.primary.iter().copied()))?;
    write("primary_hits.u32", &hit_rows(answers.primary))?;
    write(
        "shadow_rays.f32",
        &ray_rows(sets.shadow.iter().map(|s| s.ray)),
    )?;
    let blocked: Vec<u8> = answers.shadow.iter().map(|&b| b as u8).collect();
    write("shadow_blocked.u8", &blocked)?;
    write(
        "incoherent_rays.f32",
        &ray_rows(sets.incoherent.iter().copied()),
    )?;
    write("incoherent_hits.u32", &hit_rows(answers.incoherent))?;
    let manifest = Manifest {
        format: "sylva-rays-1",
        scene: scene.name.clone(),
        ground: accel.ground(),
        to_sun: to_sun.to_array(),
        models,
        masks,
        instances: accel.instances().len(),
        sets: vec![
            SetEntry {
                name: "primary",
                query: "closest",
                rays: sets.primary.len(),
            },
            SetEntry {
                name: "shadow",
                query: "any",
                rays: sets.shadow.len(),
            },
            SetEntry {
                name: "incoherent",
                query: "closest",
                rays: sets.incoherent.len(),
            },
        ],
    };
    if let Some(report) = report {
        // Beside the rays, for tools/embree/compare.py to set Embree's figures against.
        let json = serde_json::to_vec_pretty(report).expect("the report serialises");
        write("sylva.json", &json)?;
    }
    let json = serde_json::to_vec_pretty(&manifest).expect("the manifest serialises");
    write("manifest.json", &json)?;
    set.commit()?;
    Ok(())
}
