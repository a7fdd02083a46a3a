//! Voxelization: hand-computed densities and wood fractions of known shapes, agreement with a
//! brute-force reference, determinism across thread counts, bad input.

use std::sync::Arc;

use glam::Vec3;
use sylva_core::SplitMix64;
use sylva_geom::{Material, MaterialKind, Mesh, Model, Texture, Wrap};
use sylva_grid::Dims;
use sylva_grow::Species;
use sylva_voxel::{
    plant_area, subcell_bit, voxelize, voxelize_masks, GridPlacement, Occupancy, SubcellMasks,
    VoxelizeError, VoxelizeOptions, SUB, SUBCELLS,
};

const WOOD: u8 = 0;
const LEAF: u8 = 1;

fn materials(leaf_texture: Option<Texture>) -> Vec<Material> {
    vec![
        Material {
            name: "bark".into(),
            kind: MaterialKind::Wood,
            base_color: [0.3, 0.2, 0.1],
            texture: None,
            two_sided: false,
            optics: sylva_geom::Optics::OPAQUE,
        },
        Material {
            name: "leaf".into(),
            kind: MaterialKind::Leaf,
            base_color: [0.1, 0.5, 0.1],
            texture: leaf_texture.map(Arc::new),
            two_sided: true,
            optics: sylva_geom::Optics::FOREST_LEAF,
        },
    ]
}

/// Quad `x0..x1` × `z0..z1` at height `y`, u along x and v along z, each from 0 to 1.
fn push_quad(m: &mut Mesh, x: [f32; 2], y: f32, z: [f32; 2], material: u8) {
    let n = Vec3::Y;
    let a = m.push_vertex(Vec3::new(x[0], y, z[0]), n, [0.0, 0.0]);
    let b = m.push_vertex(Vec3::new(x[1], y, z[0]), n, [1.0, 0.0]);
    let c = m.push_vertex(Vec3::new(x[1], y, z[1]), n, [1.0, 1.0]);
    let d = m.push_vertex(Vec3::new(x[0], y, z[1]), n, [0.0, 1.0]);
    m.push_triangle(a, b, c, material);
    m.push_triangle(a, c, d, material);
}

/// 5³ sites, cells of edge 3 from the origin: sub-cells are unit cubes, sub-cell k = [k, k+1],
/// and the interior cells 1..=3 hold sub-cells 3..=11.
fn unit_placement() -> GridPlacement {
    GridPlacement {
        dims: Dims::cube(5).unwrap(),
        origin: [0.0; 3],
        cell: 3.0,
    }
}

/// Mask of the sub-cells of a cell whose local coordinate along `axis` is `layer`.
fn layer(axis: usize, layer: usize) -> u32 {
    let mut m = 0;
    for a in 0..SUB {
        for b in 0..SUB {
            let s = match axis {
                0 => [layer, a, b],
                1 => [a, layer, b],
                _ => [a, b, layer],
            };
            m |= subcell_bit(s[0], s[1], s[2]);
        }
    }
    m
}

fn masks(model: &Model, p: &GridPlacement) -> SubcellMasks {
    voxelize_masks(model, p, true).unwrap()
}

/// Expected masks per cell from a function of the cell; asserts every cell.
fn assert_cells(m: &SubcellMasks, what: &str, expect: impl Fn(usize, usize, usize) -> (u32, u32)) {
    let d = m.placement.dims;
    for x in 0..d.nx {
        for y in 0..d.ny {
            for z in 0..d.nz {
                let i = d.index(x, y, z);
                assert_eq!(
                    (m.any(i), m.wood(i)),
                    expect(x, y, z),
                    "{what}: cell ({x}, {y}, {z})"
                );
            }
        }
    }
}

fn interior(d: Dims, x: usize, y: usize, z: usize) -> bool {
    !d.on_shell(x, y, z)
}

#[test]
fn axis_aligned_plane_fills_one_or_two_sub_cell_layers() {
    let p = unit_placement();
    let d = p.dims;
    // (height, cells met with the layers they get)
    let cases: [(f32, &[(usize, u32)]); 3] = [
        // Inside sub-cell layer 4 = layer 1 of cell 1: density 1/3.
        (4.5, &[(1, layer(1, 1))]),
        // On the face between layers 4 and 5, both in cell 1: closed boxes count both, 2/3.
        (5.0, &[(1, layer(1, 1) | layer(1, 2))]),
        // On the face between cells 1 and 2: layer 2 of cell 1 and layer 0 of cell 2, 1/3 each.
        (6.0, &[(1, layer(1, 2)), (2, layer(1, 0))]),
    ];
    for (y, want) in cases {
        let mut mesh = Mesh::default();
        push_quad(&mut mesh, [3.0, 12.0], y, [3.0, 12.0], LEAF);
        let model = Model::new("plane", mesh, materials(None));
        let m = masks(&model, &p);
        assert_cells(&m, &format!("plane y = {y}"), |x, cy, z| {
            let hit = want.iter().find(|(c, _)| *c == cy);
            match hit {
                Some((_, bits)) if interior(d, x, cy, z) => (*bits, 0),
                _ => (0, 0),
            }
        });
        let g = m.to_density_grid().unwrap();
        let expect_density = want[0].1.count_ones() as f32 / 27.0;
        assert_eq!(g.density[d.index(2, want[0].0, 2)], expect_density);
    }
    assert_eq!(layer(1, 1).count_ones(), 9);
}

#[test]
fn flat_model_gets_one_interior_cell_across_and_sits_in_its_middle_layer() {
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [0.0, 9.0], 0.0, [0.0, 9.0], LEAF);
    let model = Model::new("plane", mesh, materials(None));
    let g = voxelize(
        &model,
        &VoxelizeOptions {
            grid: 5,
            alpha_test: true,
            occupancy: Occupancy::SubCells,
        },
    )
    .unwrap();
    assert_eq!(g.dims, Dims::new(5, 3, 5).unwrap());
    // Site centres: cells of edge 3 from -3 (x, z) and -4.5 (y, centred on the plane).
    assert_eq!(g.bounds.min, [-1.5, -3.0, -1.5]);
    assert_eq!(g.bounds.max, [10.5, 3.0, 10.5]);
    for x in 0..5 {
        for z in 0..5 {
            let i = g.dims.index(x, 1, z);
            let want = if g.dims.on_shell(x, 1, z) {
                0.0
            } else {
                1.0 / 3.0
            };
            assert_eq!(g.density[i], want, "({x}, 1, {z})");
        }
    }
    let (mean, occupied) = g.occupancy();
    assert_eq!(occupied, 9);
    assert!((mean - 9.0 / 3.0 / 75.0).abs() < 1e-7, "{mean}");
}

#[test]
fn box_surface_fills_shell_cells_and_leaves_the_inside_empty() {
    // Cube [0, 18]³ at N = 8: cell edge 18 / 6 = 3, interior cells 1..=6, faces on the
    // interior's outer faces.
    let c = [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(18.0, 0.0, 0.0),
        Vec3::new(18.0, 18.0, 0.0),
        Vec3::new(0.0, 18.0, 0.0),
        Vec3::new(0.0, 0.0, 18.0),
        Vec3::new(18.0, 0.0, 18.0),
        Vec3::new(18.0, 18.0, 18.0),
        Vec3::new(0.0, 18.0, 18.0),
    ];
    let faces = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [3, 7, 6, 2],
        [0, 4, 7, 3],
        [1, 2, 6, 5],
    ];
    let mut mesh = Mesh::default();
    for f in faces {
        let v = f.map(|i| mesh.push_vertex(c[i], Vec3::Y, [0.0, 0.0]));
        mesh.push_triangle(v[0], v[1], v[2], WOOD);
        mesh.push_triangle(v[0], v[2], v[3], WOOD);
    }
    let model = Model::new("box", mesh, materials(None));
    let g = voxelize(
        &model,
        &VoxelizeOptions {
            grid: 8,
            alpha_test: true,
            occupancy: Occupancy::SubCells,
        },
    )
    .unwrap();
    let d = g.dims;
    assert_eq!(d, Dims::cube(8).unwrap());
    let mut counts = [0usize; 4];
    for x in 0..8 {
        for y in 0..8 {
            for z in 0..8 {
                let i = d.index(x, y, z);
                let faces = [x, y, z].iter().filter(|&&c| c == 1 || c == 6).count();
                // The touched layer of each face; 27 minus the sub-cells in none of them.
                let want = if d.on_shell(x, y, z) {
                    0
                } else {
                    27 - 3u32.pow(3 - faces as u32) * 2u32.pow(faces as u32)
                };
                assert_eq!(g.density[i], want as f32 / 27.0, "({x}, {y}, {z})");
                assert_eq!(g.wood[i], if want > 0 { 1.0 } else { 0.0 });
                if !d.on_shell(x, y, z) {
                    counts[faces] += 1;
                }
            }
        }
    }
    // 4³ empty inside cells, 6 · 4² face cells (9/27), 12 · 4 edge cells (15/27), 8 corners
    // (19/27).
    assert_eq!(counts, [64, 96, 48, 8]);
}

/// 2×1 texture: texel 0 (u < 1/2) opaque, texel 1 transparent.
fn half_texture(wrap: Wrap) -> Texture {
    Texture::new(2, 1, vec![[0, 200, 0, 255], [0, 200, 0, 0]], wrap)
}

#[test]
fn half_transparent_quad_keeps_exactly_its_opaque_half() {
    let p = unit_placement();
    let d = p.dims;
    // x from 3 to 9 maps u 0 → 1: the opaque half is x ≤ 6, cell 1 exactly.
    let build = |tex: Option<Texture>| {
        let mut mesh = Mesh::default();
        push_quad(&mut mesh, [3.0, 9.0], 4.5, [3.0, 12.0], LEAF);
        Model::new("leaf", mesh, materials(tex))
    };
    let plain = masks(&build(None), &p);
    let textured = masks(&build(Some(half_texture(Wrap::Clamp))), &p);
    let untested = voxelize_masks(&build(Some(half_texture(Wrap::Clamp))), &p, false).unwrap();
    assert_eq!(plain, untested);
    let on_plane = |x: usize, y: usize, z: usize| interior(d, x, y, z) && y == 1;
    // Untextured: cells 1 and 2 get layer 1 (1/3); the quad's edge x = 9 touches sub-cell 9,
    // the first of cell 3.
    assert_cells(&plain, "untextured", |x, y, z| match x {
        1 | 2 if on_plane(x, y, z) => (layer(1, 1), 0),
        3 if on_plane(x, y, z) => (layer(1, 1) & layer(0, 0), 0),
        _ => (0, 0),
    });
    // Textured: sub-cell 5 (u ∈ [1/3, 1/2]) reaches texel 0; sub-cell 6 (u ∈ [1/2, 2/3])
    // samples only texel 1, and so on: cell 2 and the edge in cell 3 drop out.
    assert_cells(&textured, "textured", |x, y, z| match x {
        1 if on_plane(x, y, z) => (layer(1, 1), 0),
        _ => (0, 0),
    });
    let total = |m: &SubcellMasks| m.bits.iter().map(|&b| (b as u32).count_ones()).sum::<u32>();
    assert_eq!(2 * total(&textured), total(&plain) - 9);
}

#[test]
fn wood_and_leaf_fractions_and_a_mixed_cell() {
    let p = unit_placement();
    let d = p.dims;
    // Wood from x = 3 to 7.5, leaf from 7.5 to 12: sub-cell 7 (in cell 2) holds both.
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [3.0, 7.5], 4.5, [3.0, 12.0], WOOD);
    push_quad(&mut mesh, [7.5, 12.0], 4.5, [3.0, 12.0], LEAF);
    let model = Model::new("mixed", mesh, materials(None));
    let m = masks(&model, &p);
    let row = layer(1, 1);
    assert_cells(&m, "wood/leaf", |x, y, z| {
        if !(interior(d, x, y, z) && y == 1) {
            return (0, 0);
        }
        match x {
            1 => (row, row),
            2 => (row, row & (layer(0, 0) | layer(0, 1))),
            _ => (row, 0),
        }
    });
    let g = m.to_density_grid().unwrap();
    for z in 1..4 {
        let w = |x| g.wood[d.index(x, 1, z)];
        assert_eq!((w(1), w(2), w(3)), (1.0, 2.0 / 3.0, 0.0));
        assert_eq!(g.density[d.index(2, 1, z)], 1.0 / 3.0);
    }
}

// ---------- brute-force reference ----------

/// Akenine-Möller's triangle/box test as published (box centre and half size, 13 axes).
fn reference_overlap(v: [[f64; 3]; 3], centre: [f64; 3], half: f64) -> bool {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let v = v.map(|p| sub(p, centre));
    let e = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];
    let mut axes: Vec<[f64; 3]> = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    axes.push(cross(e[0], e[1]));
    for ei in e {
        for a in 0..3 {
            let mut u = [0.0; 3];
            u[a] = 1.0;
            axes.push(cross(ei, u));
        }
    }
    axes.iter().all(|&a| {
        let p = v.map(|x| dot(x, a));
        let r = half * (a[0].abs() + a[1].abs() + a[2].abs());
        let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        !(lo > r || hi < -r)
    })
}

/// Triangle ∩ box [lo, lo + 1] as a polygon of (x, y, z, u, v), by clipping against each face.
fn reference_clip(tri: [[f64; 5]; 3], lo: [f64; 3]) -> Vec<[f64; 5]> {
    let mut poly = tri.to_vec();
    for a in 0..3 {
        for (sign, off) in [(1.0, lo[a]), (-1.0, lo[a] + 1.0)] {
            let inside = |p: &[f64; 5]| sign * (p[a] - off);
            let mut out = Vec::new();
            for k in 0..poly.len() {
                let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
                let (dp, dq) = (inside(&p), inside(&q));
                if dp >= 0.0 {
                    out.push(p);
                }
                if dp * dq < 0.0 {
                    let t = dp / (dp - dq);
                    out.push(std::array::from_fn(|c| p[c] + t * (q[c] - p[c])));
                }
            }
            poly = out;
        }
    }
    poly
}

/// Closed convex polygon vs closed square [k, k+1] × [l, l+1]: 2-D separating axes.
fn polygon_meets_square(pts: &[[f64; 2]], k: f64, l: f64) -> bool {
    let sq = [[k, l], [k + 1.0, l], [k + 1.0, l + 1.0], [k, l + 1.0]];
    let mut axes = vec![[1.0, 0.0], [0.0, 1.0]];
    for i in 0..pts.len() {
        let (p, q) = (pts[i], pts[(i + 1) % pts.len()]);
        axes.push([q[1] - p[1], p[0] - q[0]]);
    }
    axes.iter().all(|a| {
        let proj = |s: &[[f64; 2]]| {
            s.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    let d = p[0] * a[0] + p[1] * a[1];
                    (lo.min(d), hi.max(d))
                })
        };
        let (a0, a1) = proj(pts);
        let (b0, b1) = proj(&sq);
        !(a1 < b0 || b1 < a0)
    })
}

/// Every interior sub-cell against every triangle; textured leaves against every opaque texel.
fn reference_masks(model: &Model, p: &GridPlacement) -> Vec<u64> {
    let d = p.dims;
    let mut bits = vec![0u64; d.sites()];
    let inv = 3.0 / p.cell;
    let mesh = &model.mesh;
    for (t, &mat) in mesh.indices.iter().zip(&mesh.material_ids) {
        let material = &model.materials[mat as usize];
        let v = t.map(|i| {
            let q = mesh.positions[i as usize];
            [0, 1, 2].map(|a| (q[a] as f64 - p.origin[a]) * inv)
        });
        for x in 3..3 * (d.nx - 1) {
            for y in 3..3 * (d.ny - 1) {
                for z in 3..3 * (d.nz - 1) {
                    let lo = [x as f64, y as f64, z as f64];
                    if !reference_overlap(v, lo.map(|c| c + 0.5), 0.5) {
                        continue;
                    }
                    if let (MaterialKind::Leaf, Some(tex)) = (material.kind, &material.texture) {
                        let (w, h) = (tex.width as f64, tex.height as f64);
                        let tri: [[f64; 5]; 3] = std::array::from_fn(|k| {
                            let uv = mesh.uvs[t[k] as usize];
                            [
                                v[k][0],
                                v[k][1],
                                v[k][2],
                                uv[0] as f64 * w,
                                uv[1] as f64 * h,
                            ]
                        });
                        let poly: Vec<[f64; 2]> = reference_clip(tri, lo)
                            .iter()
                            .map(|q| [q[3], q[4]])
                            .collect();
                        if poly.is_empty() {
                            continue;
                        }
                        let (mut u0, mut u1, mut v0, mut v1) = (1e9f64, -1e9f64, 1e9f64, -1e9f64);
                        for q in &poly {
                            u0 = u0.min(q[0]);
                            u1 = u1.max(q[0]);
                            v0 = v0.min(q[1]);
                            v1 = v1.max(q[1]);
                        }
                        let mut opaque = false;
                        for k in u0.floor() as i64..=u1.floor() as i64 {
                            for l in v0.floor() as i64..=v1.floor() as i64 {
                                let texel = tex.texel(
                                    tex.wrap.apply(k, tex.width),
                                    tex.wrap.apply(l, tex.height),
                                );
                                if sylva_geom::is_opaque(texel)
                                    && polygon_meets_square(&poly, k as f64, l as f64)
                                {
                                    opaque = true;
                                }
                            }
                        }
                        if !opaque {
                            continue;
                        }
                    }
                    let cell = d.index(x / 3, y / 3, z / 3);
                    let bit = subcell_bit(x % 3, y % 3, z % 3) as u64;
                    bits[cell] |= bit;
                    if material.kind == MaterialKind::Wood {
                        bits[cell] |= bit << 32;
                    }
                }
            }
        }
    }
    bits
}

fn random_texture(rng: &mut SplitMix64, w: u32, h: u32, wrap: Wrap) -> Texture {
    let px = (0..w * h)
        .map(|_| [10, 200, 10, if rng.next_f64() < 0.4 { 255 } else { 0 }])
        .collect();
    Texture::new(w, h, px, wrap)
}

/// A random mesh in [0, 10]³: small and large triangles, wood, plain leaves and textured
/// leaves (third material) with texture coordinates beyond [0, 1].
fn random_model(seed: u64, wrap: Wrap) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Mesh::default();
    let mut r = |lo: f64, hi: f64| (lo + (hi - lo) * rng.next_f64()) as f32;
    for t in 0..60 {
        let size = if t % 5 == 0 { 6.0 } else { 1.2 };
        let c = Vec3::new(r(1.0, 9.0), r(1.0, 9.0), r(1.0, 9.0));
        let v: Vec<u32> = (0..3)
            .map(|_| {
                let p = c + Vec3::new(r(-size, size), r(-size, size), r(-size, size));
                let p = p.clamp(Vec3::ZERO, Vec3::splat(10.0));
                mesh.push_vertex(p, Vec3::Y, [r(-1.5, 2.5), r(-1.5, 2.5)])
            })
            .collect();
        mesh.push_triangle(v[0], v[1], v[2], (t % 3) as u8);
    }
    let mut rng = SplitMix64::new(seed ^ 0xabc);
    let mut mats = materials(None);
    mats.push(Material {
        name: "textured leaf".into(),
        kind: MaterialKind::Leaf,
        base_color: [0.1, 0.5, 0.1],
        texture: Some(Arc::new(random_texture(&mut rng, 7, 5, wrap))),
        two_sided: true,
        optics: sylva_geom::Optics::FOREST_LEAF,
    });
    let mut model = Model::new("random", mesh, mats);
    // Corners pin the bounding box to [0, 10]³ (isolated degenerate triangles: points).
    for p in [Vec3::ZERO, Vec3::splat(10.0)] {
        let i = model.mesh.push_vertex(p, Vec3::Y, [0.0, 0.0]);
        model.mesh.push_triangle(i, i, i, WOOD);
    }
    model.bounds = model.mesh.bounds();
    model
}

#[test]
fn agrees_with_brute_force_on_random_meshes() {
    for (seed, wrap) in [(1, Wrap::Repeat), (2, Wrap::Clamp), (3, Wrap::Repeat)] {
        let model = random_model(seed, wrap);
        let p = GridPlacement::fit([0.0; 3], [10.0; 3], 11).unwrap();
        let fast = masks(&model, &p);
        let reference = reference_masks(&model, &p);
        let mut textured_cells = 0;
        for (i, (&a, &b)) in fast.bits.iter().zip(&reference).enumerate() {
            assert_eq!(a, b, "seed {seed}: cell {:?}", p.dims.coords(i));
            textured_cells += (a != 0) as usize;
        }
        // The comparison is not vacuous: many cells are occupied, some partly.
        assert!(textured_cells > 100, "{textured_cells}");
        // Alpha testing only ever removes sub-cells.
        let plain = voxelize_masks(&model, &p, false).unwrap();
        let mut removed = 0;
        for (&a, &b) in fast.bits.iter().zip(&plain.bits) {
            assert_eq!(a & !b, 0);
            removed += (b & !a).count_ones();
        }
        assert!(removed > 0, "seed {seed}: the texture removed nothing");
    }
}

#[test]
fn same_grid_on_one_and_two_threads() {
    let model = Species::builtin("red_maple")
        .unwrap()
        .build_model()
        .unwrap();
    let opts = VoxelizeOptions {
        grid: 48,
        alpha_test: true,
        occupancy: Occupancy::SubCells,
    };
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let one = pool(1).install(|| voxelize(&model, &opts).unwrap());
    let two = pool(2).install(|| voxelize(&model, &opts).unwrap());
    assert_eq!(one, two);
    assert_eq!(one.dims.longest_edge(), 48);
    // A tree: brown cells (mostly wood) and green ones, nothing on the shell.
    let brown = (0..one.dims.sites())
        .filter(|&i| one.density[i] > 0.0 && one.wood[i] > 0.5)
        .count();
    let (_, occupied) = one.occupancy();
    assert!(brown > 0 && brown < occupied / 2, "{brown} of {occupied}");
    for i in 0..one.dims.sites() {
        let (x, y, z) = one.dims.coords(i);
        if one.dims.on_shell(x, y, z) {
            assert_eq!(one.density[i], 0.0);
        }
    }
    // Densities are multiples of 1/27.
    assert!(one
        .density
        .iter()
        .all(|&r| (r * SUBCELLS as f32 - (r * SUBCELLS as f32).round()).abs() < 1e-4));
}

#[test]
fn bad_input_is_refused_with_a_reason() {
    let opts = |grid| VoxelizeOptions {
        grid,
        alpha_test: true,
        occupancy: Occupancy::SubCells,
    };
    let empty = Model::new("nothing", Mesh::default(), materials(None));
    let e = voxelize(&empty, &opts(32)).unwrap_err();
    assert!(matches!(e, VoxelizeError::Empty(_)), "{e}");
    assert!(e.to_string().contains("nothing"));

    let quad = || {
        let mut mesh = Mesh::default();
        push_quad(&mut mesh, [0.0, 1.0], 0.0, [0.0, 1.0], LEAF);
        mesh
    };
    let mut mesh = quad();
    mesh.positions[2][1] = f32::NAN;
    let e = voxelize(&Model::new("nan", mesh, materials(None)), &opts(32)).unwrap_err();
    assert!(e.to_string().contains("vertex 2"), "{e}");

    let ok = Model::new("quad", quad(), materials(None));
    for n in [0, 3, 100_000] {
        let e = voxelize(&ok, &opts(n)).unwrap_err();
        assert!(matches!(e, VoxelizeError::BadGrid(m) if m == n), "{e}");
    }
    assert!(voxelize(&ok, &opts(4)).is_ok());

    let mut point = Mesh::default();
    let i = point.push_vertex(Vec3::ONE, Vec3::Y, [0.0, 0.0]);
    point.push_triangle(i, i, i, WOOD);
    let e = voxelize(&Model::new("dot", point, materials(None)), &opts(32)).unwrap_err();
    assert!(
        matches!(e, VoxelizeError::ZeroExtent(ref n) if n == "dot"),
        "{e}"
    );

    let mut mesh = quad();
    mesh.material_ids[0] = 7;
    let e = voxelize(&Model::new("mat", mesh, materials(None)), &opts(32)).unwrap_err();
    assert!(e.to_string().contains("material id 7"), "{e}");

    let mut mesh = quad();
    mesh.uvs[1][0] = f32::INFINITY;
    let tex = Some(half_texture(Wrap::Clamp));
    let model = Model::new("uv", mesh, materials(tex));
    let e = voxelize(&model, &opts(32)).unwrap_err();
    assert!(matches!(e, VoxelizeError::BadUv { triangle: 0, .. }), "{e}");
    // The plant-area voxelizer (the physical occupancy) refuses it the same way.
    let e = plant_area(&model, &unit_placement(), true).unwrap_err();
    assert!(matches!(e, VoxelizeError::BadUv { triangle: 0, .. }), "{e}");
}

// ---------- plant area (the physical occupancy) ----------

/// Relative closeness.
fn near(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-12)
}

#[test]
fn leaf_area_lands_in_the_cells_it_lies_in() {
    let p = unit_placement();
    let d = p.dims;
    // A 2 × 2 quad inside cell (1, 1, 1) (x, z in [3.5, 5.5], y = 4.5): area 4 in that cell.
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [3.5, 5.5], 4.5, [3.5, 5.5], LEAF);
    let model = Model::new("leaf", mesh, materials(None));
    let a = plant_area(&model, &p, true).unwrap();
    assert!(
        near(a.leaf[d.index(1, 1, 1)], 4.0, 1e-6),
        "{}",
        a.leaf[d.index(1, 1, 1)]
    );
    assert!(near(a.total_leaf_area(), 4.0, 1e-6));
    assert_eq!(a.total_bark_area(), 0.0);
    // Across the face x = 6 between cells 1 and 2: 3 in each.
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [4.5, 7.5], 4.5, [3.5, 5.5], LEAF);
    let model = Model::new("leaf", mesh, materials(None));
    let a = plant_area(&model, &p, true).unwrap();
    for x in [1, 2] {
        let v = a.leaf[d.index(x, 1, 1)];
        assert!(near(v, 3.0, 1e-6), "cell {x}: {v}");
    }
    // Bark goes to the bark channel.
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [3.5, 5.5], 4.5, [3.5, 5.5], WOOD);
    let model = Model::new("bark", mesh, materials(None));
    let a = plant_area(&model, &p, true).unwrap();
    assert!(near(a.total_bark_area(), 4.0, 1e-6));
    assert_eq!(a.total_leaf_area(), 0.0);
}

#[test]
fn leaf_area_counts_only_opaque_texels() {
    // Left half of the texture transparent: half the area counts.
    let mut px = vec![[40u8, 160, 40, 255]; 64];
    for y in 0..8 {
        for x in 0..4 {
            px[y * 8 + x][3] = 0;
        }
    }
    let tex = Texture::new(8, 8, px, Wrap::Clamp);
    let p = unit_placement();
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [3.5, 5.5], 4.5, [3.5, 5.5], LEAF);
    let model = Model::new("half", mesh, materials(Some(tex)));
    let a = plant_area(&model, &p, true).unwrap();
    assert!(
        near(a.total_leaf_area(), 2.0, 0.02),
        "{}",
        a.total_leaf_area()
    );
    // Without the alpha test the whole quad counts.
    let all = plant_area(&model, &p, false).unwrap();
    assert!(near(all.total_leaf_area(), 4.0, 1e-6));
}

#[test]
fn area_density_is_the_collision_probability() {
    let p = unit_placement();
    let d = p.dims;
    let mut mesh = Mesh::default();
    push_quad(&mut mesh, [3.5, 5.5], 4.5, [3.5, 5.5], LEAF);
    push_quad(&mut mesh, [3.5, 5.5], 5.0, [3.5, 5.5], WOOD);
    let model = Model::new("both", mesh, materials(None));
    let a = plant_area(&model, &p, true).unwrap();
    let g = a.to_density_grid().unwrap();
    let i = d.index(1, 1, 1);
    let (want, wood) = sylva_grid::density::collision_probability(4.0, 4.0, 3.0);
    assert!(near(g.density[i] as f64, want, 1e-6) && want > 0.0);
    assert!(near(g.wood[i] as f64, wood, 1e-6));
    // Bark counts a quarter of its area, leaves half: the wood share is 1/3.
    assert!(near(wood, 1.0 / 3.0, 1e-12));
    // Empty cells stay empty.
    assert_eq!(g.density[d.index(3, 3, 3)], 0.0);
    // voxelize() with the area occupancy is the same grid.
    let species = Species::builtin("dogrose").unwrap().build_model().unwrap();
    let opts = VoxelizeOptions {
        grid: 24,
        alpha_test: true,
        occupancy: Occupancy::Area,
    };
    let v = voxelize(&species, &opts).unwrap();
    let placement = sylva_voxel::placement_for(&species, 24).unwrap();
    let direct = plant_area(&species, &placement, true)
        .unwrap()
        .to_density_grid()
        .unwrap();
    assert_eq!(v, direct);
    assert!(v.density.iter().all(|&x| (0.0..=1.0).contains(&x)));
}

#[test]
fn plant_area_is_the_same_on_any_thread_count() {
    let model = Species::builtin("dogrose").unwrap().build_model().unwrap();
    let placement = sylva_voxel::placement_for(&model, 32).unwrap();
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let one = pool(1).install(|| plant_area(&model, &placement, true).unwrap());
    let two = pool(2).install(|| plant_area(&model, &placement, true).unwrap());
    assert_eq!(one, two);
    // The total leaf area is the leaves' opaque area: the triangles' area times the
    // texture's opaque fraction, to the sampling's accuracy.
    let leaf = &model.materials[1];
    let mesh = &model.mesh;
    let mut area = 0.0f64;
    for (t, &m) in mesh.indices.iter().zip(&mesh.material_ids) {
        if m == 1 {
            let p = t.map(|i| Vec3::from_array(mesh.positions[i as usize]).as_dvec3());
            area += 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
        }
    }
    let opaque = area * leaf.texture.as_ref().unwrap().opaque_fraction();
    assert!(
        near(one.total_leaf_area(), opaque, 0.03),
        "{} vs {opaque}",
        one.total_leaf_area()
    );
}

/// The plant area piece by piece, as the rule states it: each of a triangle's `k²`
/// sub-triangles gives its area to the cell holding its centroid, a leaf's only where the
/// nearest texel there is opaque. The voxelizer counts pieces a run or a cell at a time; its
/// sums must be these, exactly.
fn reference_plant_area(
    model: &Model,
    p: &GridPlacement,
    alpha_test: bool,
) -> (Vec<f64>, Vec<f64>) {
    const FIXED: f64 = 4_294_967_296.0;
    let dims = p.dims;
    let (mut leaf, mut bark) = (vec![0u64; dims.sites()], vec![0u64; dims.sites()]);
    let hi = [dims.nx - 2, dims.ny - 2, dims.nz - 2].map(|n| n as i64);
    let inv_cell = 1.0 / p.cell;
    let origin = glam::DVec3::from_array(p.origin);
    let mesh = &model.mesh;
    for (t, &m) in mesh.indices.iter().zip(&mesh.material_ids) {
        let material = &model.materials[m as usize];
        let texture = match (material.kind, &material.texture) {
            (MaterialKind::Leaf, Some(t)) if alpha_test => Some(t),
            _ => None,
        };
        let pos = t.map(|i| glam::DVec3::from_array(mesh.positions[i as usize].map(f64::from)));
        let (e1, e2) = (pos[1] - pos[0], pos[2] - pos[0]);
        let area = 0.5 * e1.cross(e2).length() * inv_cell * inv_cell;
        if area.is_nan() || area <= 0.0 {
            continue;
        }
        let longest = e1.length().max(e2.length()).max((pos[2] - pos[1]).length()) * inv_cell;
        let mut k = ((longest * 8.0).ceil() as usize).clamp(1, 256);
        if texture.is_some() {
            k = k.max(32);
        }
        let piece = ((area / (k * k) as f64) * FIXED).round() as u64;
        let uv = t.map(|i| mesh.uvs[i as usize].map(f64::from));
        for (offset, rows) in [(1.0 / 3.0, k), (2.0 / 3.0, k - 1)] {
            for i in 0..rows {
                for j in 0..rows - i {
                    let inv_k = 1.0 / k as f64;
                    let (s, r) = ((i as f64 + offset) * inv_k, (j as f64 + offset) * inv_k);
                    if let Some(tex) = texture {
                        let u = uv[0][0] + (uv[1][0] - uv[0][0]) * s + (uv[2][0] - uv[0][0]) * r;
                        let v = uv[0][1] + (uv[1][1] - uv[0][1]) * s + (uv[2][1] - uv[0][1]) * r;
                        let (x, y) = sylva_geom::nearest_texel_coords(
                            u as f32, v as f32, tex.width, tex.height, tex.wrap,
                        );
                        if !sylva_geom::is_opaque(tex.pixels[(y * tex.width + x) as usize]) {
                            continue;
                        }
                    }
                    let q = (pos[0] + e1 * s + e2 * r - origin) * inv_cell;
                    let c = |v: f64, a: usize| (v.floor() as i64).clamp(1, hi[a]) as usize;
                    let cell = dims.index(c(q.x, 0), c(q.y, 1), c(q.z, 2));
                    match material.kind {
                        MaterialKind::Wood => bark[cell] += piece,
                        _ => leaf[cell] += piece,
                    }
                }
            }
        }
    }
    let area = |v: Vec<u64>| {
        v.into_iter()
            .map(|a| a as f64 / FIXED * (p.cell * p.cell))
            .collect()
    };
    (area(leaf), area(bark))
}

#[test]
fn plant_area_is_the_sum_over_every_piece() {
    // Random meshes: small and large triangles (up to 256 pieces an edge), textured leaves
    // with texture coordinates beyond [0, 1].
    let mut models: Vec<(Model, GridPlacement)> = [(1, Wrap::Repeat), (2, Wrap::Clamp)]
        .into_iter()
        .map(|(seed, wrap)| {
            let model = random_model(seed, wrap);
            (model, GridPlacement::fit([0.0; 3], [10.0; 3], 11).unwrap())
        })
        .collect();
    // Leaf quads with their corners on cell faces and edges (cells of edge 3 from the
    // origin), two sharing one uv layout and a dozen with layouts of their own (more than a
    // worker keeps), some reaching past the grid into its clamped end cells.
    let mut rng = SplitMix64::new(7);
    let tex = random_texture(&mut rng, 16, 16, Wrap::Clamp);
    let mut mesh = Mesh::default();
    let snap = |v: f64| ((v * 4.0).round() / 4.0 * 3.0) as f32;
    for n in 0..16 {
        let mut r = || snap(rng.next_f64() * 6.0 - 0.5);
        let (x, y, z) = (r(), r(), r());
        let (w, d) = (r().abs() + 0.75, r().abs() + 0.75);
        let uv = |u: f32, v: f32| {
            if n < 2 {
                [u, v]
            } else {
                [u * 0.5 + n as f32 * 0.03, v * 0.7]
            }
        };
        let a = mesh.push_vertex(Vec3::new(x, y, z), Vec3::Y, uv(0.0, 0.0));
        let b = mesh.push_vertex(Vec3::new(x + w, y, z), Vec3::Y, uv(1.0, 0.0));
        let c = mesh.push_vertex(Vec3::new(x + w, y + d, z + d), Vec3::Y, uv(1.0, 1.0));
        let e = mesh.push_vertex(Vec3::new(x, y + d, z + d), Vec3::Y, uv(0.0, 1.0));
        mesh.push_triangle(a, b, c, LEAF);
        mesh.push_triangle(a, c, e, if n % 4 == 3 { WOOD } else { LEAF });
    }
    models.push((
        Model::new("snapped", mesh, materials(Some(tex))),
        unit_placement(),
    ));
    for (model, p) in &models {
        for alpha_test in [true, false] {
            let a = plant_area(model, p, alpha_test).unwrap();
            let (leaf, bark) = reference_plant_area(model, p, alpha_test);
            let occupied = leaf.iter().filter(|&&v| v > 0.0).count();
            assert!(occupied > 10, "{}: only {occupied} leaf cells", model.name);
            for (i, (got, want)) in a.leaf.iter().zip(&leaf).enumerate() {
                assert_eq!(
                    got,
                    want,
                    "{}: leaf area of cell {:?}",
                    model.name,
                    p.dims.coords(i)
                );
            }
            for (i, (got, want)) in a.bark.iter().zip(&bark).enumerate() {
                assert_eq!(
                    got,
                    want,
                    "{}: bark area of cell {:?}",
                    model.name,
                    p.dims.coords(i)
                );
            }
        }
    }
}
