//! Ray/box and ray/triangle edge cases, the alpha rule, the camera, transforms, bad input.

use glam::{Vec2, Vec3};
use sylva_geom::{Aabb, Camera, Instance, Mesh, Model, Texture, Wrap};
use sylva_testkit::scenes::*;
use sylva_trace::ray::intersect_triangle_vertices;
use sylva_trace::{
    ray::inverse_dir, ray_box, AlphaMask, Hit, ModelAccel, PinholeCamera, Ray, SceneAccel,
    TraceError, TraceStats, TraversalConfig,
};

fn unit_box() -> (Vec3, Vec3) {
    (Vec3::ZERO, Vec3::ONE)
}

fn slab(o: Vec3, d: Vec3) -> Option<(f32, f32)> {
    let (lo, hi) = unit_box();
    ray_box(o, inverse_dir(d), lo, hi, 0.0, f32::INFINITY)
}

#[test]
fn ray_box_hits_misses_grazes_and_parallel_rays() {
    // Straight through: enters at 1, leaves at 2.
    assert_eq!(slab(Vec3::new(0.5, 0.5, -1.0), Vec3::Z), Some((1.0, 2.0)));
    // Origin inside: interval starts at t_min = 0.
    assert_eq!(slab(Vec3::splat(0.5), Vec3::X), Some((0.0, 0.5)));
    // Pointing away.
    assert_eq!(slab(Vec3::new(0.5, 0.5, 2.0), Vec3::Z), None);
    // Parallel to a slab, outside it: miss for every t (1/0 = ∞ must not leak NaN).
    assert_eq!(slab(Vec3::new(1.5, 0.5, -1.0), Vec3::Z), None);
    assert_eq!(slab(Vec3::new(-0.0001, 0.5, -1.0), Vec3::Z), None);
    // Grazing: running inside the face x = 1 (closed box) and along an edge.
    assert_eq!(slab(Vec3::new(1.0, 0.5, -1.0), Vec3::Z), Some((1.0, 2.0)));
    assert_eq!(slab(Vec3::new(1.0, 1.0, -1.0), Vec3::Z), Some((1.0, 2.0)));
    // Negative zero direction components behave like positive zero.
    assert_eq!(
        slab(Vec3::new(0.5, 0.5, -1.0), Vec3::new(-0.0, -0.0, 1.0)),
        Some((1.0, 2.0))
    );
    // Touching a corner diagonally: a single point.
    let d = Vec3::new(1.0, 1.0, 1.0);
    let h = slab(Vec3::new(-1.0, -1.0, -1.0), d).unwrap();
    assert_eq!(h, (1.0, 2.0));
    let c = slab(Vec3::new(2.0, 0.0, 0.0), Vec3::new(-1.0, 1.0, 0.0)).unwrap();
    assert_eq!(c.0, 1.0);
    assert_eq!(c.1, 1.0);
    // Segment clipping.
    let (lo, hi) = unit_box();
    let o = Vec3::new(0.5, 0.5, -1.0);
    assert_eq!(ray_box(o, inverse_dir(Vec3::Z), lo, hi, 0.0, 0.5), None);
    assert_eq!(
        ray_box(o, inverse_dir(Vec3::Z), lo, hi, 1.25, 1.5),
        Some((1.25, 1.5))
    );
}

#[test]
fn triangle_interior_edges_vertices_parallel_and_degenerate() {
    let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
    let down = |x: f32, y: f32| Ray::new(Vec3::new(x, y, 1.0), -Vec3::Z);
    // Interior: t and barycentrics (p = (1-u-v) a + u b + v c).
    let (t, u, v) = intersect_triangle_vertices(&down(0.25, 0.5), a, b, c).unwrap();
    assert_eq!((t, u, v), (1.0, 0.25, 0.5));
    // Edges and vertices are inclusive.
    for (x, y) in [
        (0.5, 0.0),
        (0.0, 0.5),
        (0.5, 0.5),
        (0.0, 0.0),
        (1.0, 0.0),
        (0.0, 1.0),
    ] {
        assert!(
            intersect_triangle_vertices(&down(x, y), a, b, c).is_some(),
            "({x}, {y})"
        );
    }
    // Within the 1e-5 margin of an edge: a hit; clearly outside: a miss.
    for (x, y) in [(0.5, -5e-6), (-5e-6, 0.5), (0.5 + 3e-6, 0.5)] {
        assert!(intersect_triangle_vertices(&down(x, y), a, b, c).is_some());
    }
    for (x, y) in [(0.5, -1e-4), (-1e-4, 0.5), (0.5 + 1e-4, 0.5)] {
        assert!(intersect_triangle_vertices(&down(x, y), a, b, c).is_none());
    }
    // Both sides: no back-face culling (leaves are two-sided).
    let up = Ray::new(Vec3::new(0.25, 0.25, -1.0), Vec3::Z);
    assert_eq!(intersect_triangle_vertices(&up, a, b, c).unwrap().0, 1.0);
    // Parallel (in the plane, and above it): never a hit.
    let inplane = Ray::new(Vec3::new(-1.0, 0.25, 0.0), Vec3::X);
    assert!(intersect_triangle_vertices(&inplane, a, b, c).is_none());
    let above = Ray::new(Vec3::new(-1.0, 0.25, 0.5), Vec3::X);
    assert!(intersect_triangle_vertices(&above, a, b, c).is_none());
    // Degenerate triangles never hit.
    assert!(intersect_triangle_vertices(&down(0.5, 0.0), a, b, Vec3::new(2.0, 0.0, 0.0)).is_none());
    assert!(intersect_triangle_vertices(&down(0.0, 0.0), a, a, a).is_none());
    // Interval: t_min < t ≤ t_max.
    let mut r = down(0.25, 0.25);
    r.t_max = 1.0;
    assert!(intersect_triangle_vertices(&r, a, b, c).is_some());
    r.t_max = 0.999;
    assert!(intersect_triangle_vertices(&r, a, b, c).is_none());
    r = down(0.25, 0.25);
    r.t_min = 1.0;
    assert!(intersect_triangle_vertices(&r, a, b, c).is_none());
}

/// A quad split along its diagonal, a fan of triangles around a vertex, in one model.
fn shared_edges_model() -> Model {
    let mut m = Mesh::default();
    let p = |m: &mut Mesh, x: f32, y: f32| m.push_vertex(Vec3::new(x, y, 0.0), Vec3::Z, [x, y]);
    // Quad [0,1]²: triangles 0 and 1 share the diagonal (0,0)-(1,1).
    let (a, b, c, d) = (
        p(&mut m, 0.0, 0.0),
        p(&mut m, 1.0, 0.0),
        p(&mut m, 1.0, 1.0),
        p(&mut m, 0.0, 1.0),
    );
    m.push_triangle(a, b, c, 0);
    m.push_triangle(a, c, d, 0);
    // Fan around (3, 0): six triangles (ids 2..8) meeting at the centre.
    let centre = p(&mut m, 3.0, 0.0);
    let ring: Vec<u32> = (0..6)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / 6.0;
            p(&mut m, 3.0 + a.cos(), a.sin())
        })
        .collect();
    for k in 0..6 {
        m.push_triangle(centre, ring[k], ring[(k + 1) % 6], 0);
    }
    Model::new("edges", m, vec![wood()])
}

#[test]
fn shared_edge_and_vertex_report_the_lowest_id_everywhere() {
    let model = shared_edges_model();
    let accel = ModelAccel::build(&model);
    let scene = SceneAccel::from_parts(
        std::slice::from_ref(&model),
        &[Instance {
            model: 0,
            position: Vec3::ZERO,
            rotation_deg: 0.0,
            scale: 1.0,
        }],
        None,
    )
    .unwrap();
    let check = |o: Vec3, d: Vec3, expect: u32| {
        let ray = Ray::new(o, d);
        for cfg in [
            TraversalConfig::default(),
            TraversalConfig::UNBOUNDED,
            TraversalConfig::with_stack(1),
        ] {
            let mut st = TraceStats::default();
            let kd = accel.closest_hit(&ray, cfg, &mut st).expect("hit");
            let bf = accel.brute_closest_hit(&ray).expect("hit");
            let sc = scene.closest_hit(&ray, cfg, &mut st).expect("hit");
            assert_eq!(
                (kd.triangle, bf.triangle, sc.triangle),
                (expect, expect, expect),
                "{o}"
            );
            assert_eq!(kd.t, bf.t);
        }
    };
    // On the diagonal (exact arithmetic): both triangles hit at the same t; id 0 reported.
    for s in [0.125f32, 0.25, 0.5, 0.75] {
        check(Vec3::new(s, s, 1.0), -Vec3::Z, 0);
        check(Vec3::new(s, s, -1.0), Vec3::Z, 0);
    }
    // At the fan's centre all six meet, but the corners come from sin/cos, so t differs by
    // an ulp between them: every query must still agree with brute force (smallest t, then
    // lowest id), even though the centre lies on split planes.
    let ray = Ray::new(Vec3::new(3.0, 0.0, 2.0), -Vec3::Z);
    let bf = accel.brute_closest_hit(&ray).unwrap();
    assert!((2..8).contains(&bf.triangle));
    check(ray.origin, ray.dir, bf.triangle);
    // Oblique rays through the diagonal's midpoint also hit (one of) the pair, never a gap.
    let mut r = rng(3);
    let target = Vec3::new(0.5, 0.5, 0.0);
    for _ in 0..500 {
        let o = target + unit(&mut r) * 2.0;
        if o.z.abs() < 0.1 {
            continue;
        }
        let ray = Ray::new(o, target - o);
        let mut st = TraceStats::default();
        let h = accel.closest_hit(&ray, TraversalConfig::default(), &mut st);
        let b = accel.brute_closest_hit(&ray);
        assert_eq!(h.map(|h| (h.t, h.triangle)), b.map(|h| (h.t, h.triangle)));
        assert!(
            h.is_some_and(|h| h.triangle <= 1),
            "gap at the shared edge: {o}"
        );
    }
}

#[test]
fn alpha_checkerboard_lets_rays_through_transparent_squares_only() {
    // A 1×1 quad (two triangles) on z = 0 with an 8×8 checkerboard alpha, over an opaque
    // backstop on z = -1.
    let tex = checker_texture(8);
    let mut m = Mesh::default();
    let q =
        |m: &mut Mesh, x: f32, y: f32, z: f32| m.push_vertex(Vec3::new(x, y, z), Vec3::Z, [x, y]);
    let (a, b, c, d) = (
        q(&mut m, 0.0, 0.0, 0.0),
        q(&mut m, 1.0, 0.0, 0.0),
        q(&mut m, 1.0, 1.0, 0.0),
        q(&mut m, 0.0, 1.0, 0.0),
    );
    m.push_triangle(a, b, c, 0);
    m.push_triangle(a, c, d, 0);
    let (e, f, g, h) = (
        q(&mut m, -1.0, -1.0, -1.0),
        q(&mut m, 2.0, -1.0, -1.0),
        q(&mut m, 2.0, 2.0, -1.0),
        q(&mut m, -1.0, 2.0, -1.0),
    );
    m.push_triangle(e, f, g, 1);
    m.push_triangle(e, g, h, 1);
    let model = Model::new("checker", m, vec![leaf_material(tex.clone()), wood()]);
    let accel = ModelAccel::build(&model);
    let mut st = TraceStats::default();
    let mut through = 0;
    for j in 0..8 {
        for i in 0..8 {
            let (x, y) = ((i as f32 + 0.5) / 8.0, (j as f32 + 0.5) / 8.0);
            let opaque = (i + j) % 2 == 0;
            assert_eq!(tex.alpha(x, y) >= 0.5, opaque);
            let ray = Ray::new(Vec3::new(x, y, 1.0), -Vec3::Z);
            let hit = accel
                .closest_hit(&ray, TraversalConfig::default(), &mut st)
                .unwrap();
            assert_eq!(hit.t, if opaque { 1.0 } else { 2.0 }, "square ({i}, {j})");
            assert_eq!(hit.triangle >= 2, !opaque);
            assert_eq!(accel.brute_closest_hit(&ray), Some(hit));
            // Shadow rays: the same rule. Stop before the backstop.
            let seg = Ray::segment(ray.origin, ray.dir, 0.0, 1.5);
            assert_eq!(
                accel.any_hit(&seg, TraversalConfig::default(), &mut st),
                opaque
            );
            assert_eq!(accel.brute_any_hit(&seg), opaque);
            through += !opaque as usize;
        }
    }
    assert_eq!(through, 32);
    assert_eq!(
        st.alpha_rejects, 64,
        "each transparent square rejected once per query"
    );
}

#[test]
fn alpha_mask_agrees_with_texture_alpha() {
    let mut r = rng(17);
    for wrap in [Wrap::Clamp, Wrap::Repeat] {
        let tex = Texture::from_fn(13, 7, wrap, |u, v| {
            [0, 0, 0, ((u * 97.0 + v * 131.0) as u32 % 256) as u8]
        });
        let mask = AlphaMask::new(&tex);
        for _ in 0..5000 {
            let (u, v) = (uniform(&mut r, -2.0, 3.0), uniform(&mut r, -2.0, 3.0));
            assert_eq!(
                mask.opaque(u, v),
                tex.alpha(u, v) >= 0.5,
                "({u}, {v}) {wrap:?}"
            );
        }
        assert_eq!(mask.opaque(f32::NAN, 0.5), tex.alpha(f32::NAN, 0.5) >= 0.5);
    }
}

fn camera(pos: Vec3, at: Vec3, fov: f32, w: u32, h: u32) -> Camera {
    Camera {
        position: pos,
        look_at: at,
        fov_deg: fov,
        width: w,
        height: h,
        rays_per_pixel: 1,
    }
}

#[test]
fn camera_round_trip_and_fov_convention() {
    let mut r = rng(23);
    for (pos, at, fov, w, h) in [
        (
            Vec3::new(0.0, 2.0, -10.0),
            Vec3::new(0.0, 1.0, 0.0),
            40.0,
            896,
            448,
        ),
        (
            Vec3::new(5.0, 30.0, 7.0),
            Vec3::new(-3.0, 0.0, 2.0),
            75.0,
            512,
            512,
        ),
        (
            Vec3::new(-1.0, 0.5, 3.0),
            Vec3::new(4.0, 0.7, -2.0),
            10.0,
            300,
            700,
        ),
    ] {
        let cam = PinholeCamera::new(&camera(pos, at, fov, w, h)).unwrap();
        // The centre pixel looks at look_at; the top edge is fov/2 above the axis.
        let c = cam.ray(w as f32 / 2.0, h as f32 / 2.0);
        assert!((c.dir - (at - pos).normalize()).length() < 1e-5);
        let top = cam.ray(w as f32 / 2.0, 0.0);
        let angle = top.dir.angle_between(c.dir).to_degrees();
        assert!((angle - fov / 2.0).abs() < 1e-3, "{angle} vs {fov}/2");
        assert!(top.dir.y > c.dir.y, "+y is up: row 0 is the top");
        let right = cam.ray(w as f32, h as f32 / 2.0);
        assert!(right.dir.dot(cam.right) > 0.0);
        for _ in 0..200 {
            // Project a random point in front, trace through its pixel: the ray passes it.
            let p = pos
                + cam.forward * uniform(&mut r, 0.5, 50.0)
                + cam.right * uniform(&mut r, -5.0, 5.0)
                + cam.up * uniform(&mut r, -5.0, 5.0);
            let px = cam.project(p).unwrap();
            let ray = cam.ray(px.x, px.y);
            let t = (p - ray.origin).dot(ray.dir);
            let miss = (ray.at(t) - p).length();
            assert!(miss <= 1e-4 * (1.0 + t), "{miss} at distance {t}");
            // And back: the point along the pixel's ray projects to the pixel.
            let q = cam.pixel_ray(7, 3).at(uniform(&mut r, 1.0, 20.0));
            let back = cam.project(q).unwrap();
            assert!((back - Vec2::new(7.5, 3.5)).length() < 1e-2, "{back}");
        }
        assert!(
            cam.project(pos - cam.forward).is_none(),
            "behind the camera"
        );
    }
}

#[test]
fn bad_cameras_are_errors() {
    let ok = camera(Vec3::new(0.0, 1.0, -5.0), Vec3::ZERO, 40.0, 64, 32);
    assert!(PinholeCamera::new(&ok).is_ok());
    for bad in [
        Camera { fov_deg: 0.0, ..ok },
        Camera {
            fov_deg: 180.0,
            ..ok
        },
        Camera {
            fov_deg: f32::NAN,
            ..ok
        },
        Camera { width: 0, ..ok },
        Camera {
            look_at: ok.position,
            ..ok
        },
        Camera {
            look_at: ok.position + Vec3::Y,
            ..ok
        },
        Camera {
            position: Vec3::new(f32::INFINITY, 0.0, 0.0),
            ..ok
        },
    ] {
        let e = PinholeCamera::new(&bad).unwrap_err();
        assert!(matches!(e, TraceError::Camera(_)), "{e}");
        assert!(e.to_string().starts_with("camera: "));
    }
}

/// Box of the transformed vertices that triangles use.
fn vertex_box(model: &Model, m: &glam::Affine3A) -> Aabb {
    let mut b = Aabb::EMPTY;
    for t in &model.mesh.indices {
        for &k in t {
            b.grow(m.transform_point3(Vec3::from_array(model.mesh.positions[k as usize])));
        }
    }
    b
}

#[test]
fn instance_world_bounds_are_tight_and_contain_every_vertex() {
    let mut r = rng(77);
    for seed in 0..4 {
        let model = soup(300, 90 + seed);
        let accel = ModelAccel::build(&model);
        // The hull prism holds every vertex and is a small set.
        let hull = accel.hull_points();
        assert!(hull.len() >= 6 && hull.len() <= 2 * 900, "{}", hull.len());
        for _ in 0..25 {
            let inst = Instance {
                model: 0,
                position: Vec3::new(
                    uniform(&mut r, -100.0, 100.0),
                    uniform(&mut r, -5.0, 5.0),
                    uniform(&mut r, -100.0, 100.0),
                ),
                rotation_deg: uniform(&mut r, -360.0, 360.0),
                scale: uniform(&mut r, 0.1, 10.0),
            };
            let m = inst.transform();
            let wb = accel.world_bounds(&m);
            let exact = vertex_box(&model, &m);
            // Contains every transformed vertex ...
            assert!(
                exact.min.cmpge(wb.min).all() && exact.max.cmple(wb.max).all(),
                "{exact:?} not in {wb:?}"
            );
            // ... is exact up to the margin for rotations about y (the corner box of the
            // rotated model box is not: it is what this replaced) ...
            let ext = (exact.max - exact.min).max_element();
            let tol = 1e-4 * ext + 1e-5 * exact.max.abs().max(exact.min.abs()).max_element();
            assert!(
                (wb.min - exact.min).max_element() <= tol
                    && (wb.max - exact.max).max_element() <= tol,
                "{wb:?} vs {exact:?}"
            );
            // ... and never larger than the old corner box.
            let mut corner = Aabb::EMPTY;
            for c in accel.bounds().corners() {
                corner.grow(m.transform_point3(c));
            }
            assert!(wb.min.cmpge(corner.min - tol).all() && wb.max.cmple(corner.max + tol).all());
        }
        // Any affine map (tilted rotation, non-uniform scale): still contains every vertex.
        for _ in 0..25 {
            let m = glam::Affine3A::from_scale_rotation_translation(
                Vec3::new(
                    uniform(&mut r, 0.1, 4.0),
                    uniform(&mut r, 0.1, 4.0),
                    uniform(&mut r, 0.1, 4.0),
                ),
                glam::Quat::from_axis_angle(unit(&mut r), uniform(&mut r, -3.0, 3.0)),
                Vec3::new(uniform(&mut r, -50.0, 50.0), 0.0, 0.0),
            );
            let wb = accel.world_bounds(&m);
            let exact = vertex_box(&model, &m);
            assert!(
                exact.min.cmpge(wb.min).all() && exact.max.cmple(wb.max).all(),
                "{exact:?} not in {wb:?}"
            );
        }
    }
    // A model without triangles has empty bounds.
    let empty = Model {
        mesh: Mesh::default(),
        ..soup(1, 1)
    };
    assert!(ModelAccel::build(&empty)
        .world_bounds(&glam::Affine3A::IDENTITY)
        .is_empty());
}

#[test]
fn instance_transforms_round_trip_and_keep_t() {
    let model = soup(200, 31);
    let mut r = rng(41);
    for k in 0..20 {
        let inst = Instance {
            model: 0,
            position: Vec3::new(
                uniform(&mut r, -50.0, 50.0),
                0.0,
                uniform(&mut r, -50.0, 50.0),
            ),
            rotation_deg: uniform(&mut r, -360.0, 360.0),
            scale: uniform(&mut r, 0.2, 5.0),
        };
        let scene = SceneAccel::from_parts(std::slice::from_ref(&model), &[inst], None).unwrap();
        let ti = &scene.instances()[0];
        // World ↔ model round trip.
        for _ in 0..20 {
            let p = Vec3::new(
                uniform(&mut r, -9.0, 9.0),
                uniform(&mut r, -9.0, 9.0),
                uniform(&mut r, -9.0, 9.0),
            );
            let back = ti
                .to_world
                .transform_point3(ti.to_model.transform_point3(p));
            assert!(
                (back - p).length() < 1e-4 * (1.0 + p.length()),
                "{p} {back}"
            );
        }
        // World bounds contain every transformed vertex (no tolerance: the margin is
        // built in).
        for v in &model.mesh.positions {
            let w = ti.to_world.transform_point3(Vec3::from_array(*v));
            assert!(
                w.cmpge(ti.world_bounds.min).all() && w.cmple(ti.world_bounds.max).all(),
                "{w} outside {:?}",
                ti.world_bounds
            );
        }
        // A world-space hit lies on the world-space triangle at the same t.
        let mut st = TraceStats::default();
        let mut hits = 0;
        for _ in 0..100 {
            let mut ray = random_ray(&mut r, inst.scale);
            ray.origin += inst.position;
            if let Some(h) = scene.closest_hit(&ray, TraversalConfig::default(), &mut st) {
                let tri = model.mesh.indices[h.triangle as usize].map(|i| {
                    ti.to_world
                        .transform_point3(Vec3::from_array(model.mesh.positions[i as usize]))
                });
                let p = tri[0] * (1.0 - h.u - h.v) + tri[1] * h.u + tri[2] * h.v;
                assert!(
                    (ray.at(h.t) - p).length() < 1e-3 * inst.scale,
                    "instance {k}"
                );
                hits += 1;
            }
        }
        assert!(hits > 5, "{hits}");
    }
}

#[test]
fn ground_plane_hits_and_shadows() {
    let scene = SceneAccel::from_parts(&[], &[], Some([5.0, 5.0])).unwrap();
    let mut st = TraceStats::default();
    let ray = Ray::new(Vec3::new(1.0, 2.0, 1.0), Vec3::new(0.0, -1.0, 0.0));
    let h = scene
        .closest_hit(&ray, TraversalConfig::default(), &mut st)
        .unwrap();
    assert!(h.is_ground() && h.t == 2.0 && (h.u, h.v) == (1.0, 1.0));
    assert_eq!(scene.brute_closest_hit(&ray), Some(h));
    // Outside the rectangle, or pointing up: nothing.
    assert!(scene
        .closest_hit(
            &Ray::new(Vec3::new(6.0, 2.0, 0.0), -Vec3::Y),
            TraversalConfig::default(),
            &mut st
        )
        .is_none());
    assert!(!scene.any_hit(
        &Ray::new(Vec3::new(0.0, 0.1, 0.0), Vec3::Y),
        TraversalConfig::default(),
        &mut st
    ));
    let _ = Hit::GROUND;
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let model = soup(10, 1);
    let inst = |model: u32, scale: f32| Instance {
        model,
        position: Vec3::ZERO,
        rotation_deg: 0.0,
        scale,
    };
    let e =
        SceneAccel::from_parts(std::slice::from_ref(&model), &[inst(1, 1.0)], None).unwrap_err();
    assert!(matches!(e, TraceError::BadModel { model: 1, .. }), "{e}");
    for s in [0.0, f32::NAN, f32::INFINITY] {
        let e =
            SceneAccel::from_parts(std::slice::from_ref(&model), &[inst(0, s)], None).unwrap_err();
        assert!(matches!(e, TraceError::BadTransform { .. }), "{e}");
    }
    // Invalid rays hit nothing rather than panicking.
    let scene = SceneAccel::from_parts(
        std::slice::from_ref(&model),
        &[inst(0, 1.0)],
        Some([1.0, 1.0]),
    )
    .unwrap();
    let mut st = TraceStats::default();
    for ray in [
        Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
        Ray::new(Vec3::ZERO, Vec3::ZERO),
        Ray::new(Vec3::ZERO, Vec3::new(f32::INFINITY, 0.0, 0.0)),
        Ray::segment(Vec3::ZERO, Vec3::X, 2.0, 1.0),
    ] {
        assert!(scene
            .closest_hit(&ray, TraversalConfig::default(), &mut st)
            .is_none());
        assert!(!scene.any_hit(&ray, TraversalConfig::default(), &mut st));
    }
    // An empty model and an empty scene are fine.
    let empty = Model::new("empty", Mesh::default(), vec![wood()]);
    let a = ModelAccel::build(&empty);
    assert!(a
        .closest_hit(
            &Ray::new(Vec3::ZERO, Vec3::X),
            TraversalConfig::default(),
            &mut st
        )
        .is_none());
    assert!(a.bounds().is_empty());
    let _ = Aabb::EMPTY;
}

#[test]
fn rays_lying_in_a_split_plane_are_exact() {
    // A grid of small axis-aligned squares; axis-aligned rays along the grid lines lie in the
    // kd-tree's split planes (zero direction components, origins on the planes).
    let mut m = Mesh::default();
    for i in 0..16 {
        for j in 0..16 {
            let (x, y) = (i as f32 * 0.25, j as f32 * 0.25);
            let z = ((i * 7 + j * 3) % 5) as f32 * 0.25;
            let v = |m: &mut Mesh, dx: f32, dy: f32| {
                m.push_vertex(Vec3::new(x + dx, y + dy, z), Vec3::Z, [0.0, 0.0])
            };
            let (a, b, c, d) = (
                v(&mut m, 0.0, 0.0),
                v(&mut m, 0.25, 0.0),
                v(&mut m, 0.25, 0.25),
                v(&mut m, 0.0, 0.25),
            );
            m.push_triangle(a, b, c, 0);
            m.push_triangle(a, c, d, 0);
        }
    }
    let model = Model::new("grid", m, vec![wood()]);
    let accel = ModelAccel::build(&model);
    let mut st = TraceStats::default();
    for i in 0..=16 {
        for j in 0..=16 {
            let o = Vec3::new(i as f32 * 0.25, j as f32 * 0.25, 3.0);
            for d in [
                -Vec3::Z,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, -1.0, 0.0),
            ] {
                let ray = Ray::new(o - d * 5.0 * (d.z == 0.0) as u8 as f32, d);
                for cfg in [TraversalConfig::default(), TraversalConfig::with_stack(1)] {
                    let kd = accel.closest_hit(&ray, cfg, &mut st);
                    let bf = accel.brute_closest_hit(&ray);
                    assert_eq!(
                        kd.map(|h| (h.t, h.triangle)),
                        bf.map(|h| (h.t, h.triangle)),
                        "{ray:?}"
                    );
                }
            }
        }
    }
}
