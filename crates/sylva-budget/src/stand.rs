//! A canopy's leaves as meshes: crowns (a few distinct crown models, each crown an instance
//! turned at random about the vertical) placed without overlap by random sequential
//! addition in the cyclic plot, or a homogeneous layer; every leaf a flat disc (a regular
//! octagon of the disc's area) or square, its centre uniform in the crown or layer and its
//! normal uniform over the sphere (so the leaf projection function G is 1/2 in every
//! direction).
//!
//! The plot is `[-x/2, x/2] × [-z/2, z/2]` around the origin, the soil at y = 0. Instances
//! reaching over a side are repeated one plot over on the opposite side, so that a ray inside
//! the plot meets every leaf of the periodic stand there.

use crate::spec::{octagon_scale, BudgetError, CanopySpec, LeafShape, CROWN_VARIANTS};
use glam::{Quat, Vec3};
use sylva_core::SplitMix64;
use sylva_geom::{Instance, Material, MaterialKind, Mesh, Model, Optics};

/// The leaves of a canopy, ready to trace.
pub struct Stand {
    pub models: Vec<Model>,
    /// The crowns (or the layer) inside the plot, then their repeats over the sides.
    pub instances: Vec<Instance>,
    /// Instances inside the plot (the first of `instances`).
    pub placed: usize,
    /// Half extents of the plot (x, z), m.
    pub half: [f64; 2],
    /// Above every leaf, m: where photons start.
    pub top: f64,
    /// One-sided leaf area of the placed instances over the plot's area.
    pub lai: f64,
    /// Fraction of the plot under crowns (crown stands), as placed.
    pub cover: Option<f64>,
}

fn leaf_material() -> Material {
    Material {
        name: "leaf".into(),
        kind: MaterialKind::Leaf,
        base_color: [0.1, 0.3, 0.05],
        texture: None,
        two_sided: true,
        optics: Optics::FOREST_LEAF,
    }
}

/// A unit vector uniform over the sphere.
fn isotropic(u1: f64, u2: f64) -> Vec3 {
    let z = 2.0 * u1 - 1.0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * u2;
    Vec3::new((r * phi.cos()) as f32, z as f32, (r * phi.sin()) as f32)
}

/// Adds one leaf centred on `c` with unit normal `n`, turned by `spin` in its plane.
fn push_leaf(mesh: &mut Mesh, shape: LeafShape, size: f64, c: Vec3, n: Vec3, spin: f32) {
    let rot = Quat::from_rotation_arc(Vec3::Y, n) * Quat::from_rotation_y(spin);
    let corners: Vec<Vec3> = match shape {
        LeafShape::Square => {
            let h = 0.5 * size as f32;
            [(-h, -h), (h, -h), (h, h), (-h, h)]
                .iter()
                .map(|&(x, z)| c + rot * Vec3::new(x, 0.0, z))
                .collect()
        }
        LeafShape::Disc => {
            let r = (0.5 * size * octagon_scale()) as f32;
            (0..8)
                .map(|k| {
                    let a = k as f32 * std::f32::consts::FRAC_PI_4;
                    c + rot * Vec3::new(r * a.cos(), 0.0, r * a.sin())
                })
                .collect()
        }
    };
    let ids: Vec<u32> = corners
        .iter()
        .map(|&p| mesh.push_vertex(p, n, [0.0, 0.0]))
        .collect();
    for k in 1..ids.len() - 1 {
        mesh.push_triangle(ids[0], ids[k], ids[k + 1], 0);
    }
}

/// One crown's leaves around the origin (its centre): `count` leaves uniform in the
/// ellipsoid of horizontal radius `radius` and vertical semi-axis `half_height`.
fn crown_model(spec: &CanopySpec, radius: f64, half_height: f64, count: u64, seed: u64) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Mesh::default();
    let leaves = &spec.leaves;
    let mut placed = 0;
    while placed < count {
        let (x, y, z) = (
            2.0 * rng.next_f64() - 1.0,
            2.0 * rng.next_f64() - 1.0,
            2.0 * rng.next_f64() - 1.0,
        );
        if x * x + y * y + z * z > 1.0 {
            continue;
        }
        let c = Vec3::new(
            (x * radius) as f32,
            (y * half_height) as f32,
            (z * radius) as f32,
        );
        let n = isotropic(rng.next_f64(), rng.next_f64());
        let spin = (rng.next_f64() * std::f64::consts::TAU) as f32;
        push_leaf(&mut mesh, leaves.shape, leaves.size, c, n, spin);
        placed += 1;
    }
    Model::new("crown", mesh, vec![leaf_material()])
}

/// The layer's leaves over the whole plot: centres uniform in x and z and, in y, within
/// `[reach, height − reach]` so that no leaf pierces the soil or rises over the layer.
fn layer_model(spec: &CanopySpec, height: f64, count: u64, seed: u64) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Mesh::default();
    let [hx, hz] = [0.5 * spec.plot.size[0], 0.5 * spec.plot.size[1]];
    let reach = spec.leaves.reach();
    for _ in 0..count {
        let c = Vec3::new(
            ((2.0 * rng.next_f64() - 1.0) * hx) as f32,
            (reach + rng.next_f64() * (height - 2.0 * reach)) as f32,
            ((2.0 * rng.next_f64() - 1.0) * hz) as f32,
        );
        let n = isotropic(rng.next_f64(), rng.next_f64());
        let spin = (rng.next_f64() * std::f64::consts::TAU) as f32;
        push_leaf(&mut mesh, spec.leaves.shape, spec.leaves.size, c, n, spin);
    }
    Model::new("layer", mesh, vec![leaf_material()])
}

/// The shortest distance between two points of the cyclic plot (or the plain one).
fn plot_distance(a: [f64; 2], b: [f64; 2], size: [f64; 2], cyclic: bool) -> f64 {
    let d = |k: usize| {
        let d = (a[k] - b[k]).abs();
        if cyclic {
            d.min(size[k] - d)
        } else {
            d
        }
    };
    d(0).hypot(d(1))
}

/// Crown centres (x, z) placed one after another at random, each refused when it would
/// overlap one placed before.
fn place_crowns(spec: &CanopySpec, radius: f64, count: u64) -> Result<Vec<[f64; 2]>, BudgetError> {
    let [sx, sz] = spec.plot.size;
    let cyclic = spec.plot.cyclic;
    // An isolated plot keeps whole crowns inside it.
    let margin = if cyclic { 0.0 } else { radius };
    let mut rng = SplitMix64::new(spec.seed ^ 0x5eed_c0de);
    let mut centres: Vec<[f64; 2]> = Vec::with_capacity(count as usize);
    // A uniform grid of cells no smaller than a crown's diameter: a new crown can only
    // overlap crowns in its own and the neighbouring cells.
    let cells = [
        ((sx / (2.0 * radius)).floor() as usize).max(1),
        ((sz / (2.0 * radius)).floor() as usize).max(1),
    ];
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); cells[0] * cells[1]];
    let cell_of = |p: [f64; 2]| {
        [
            (((p[0] + 0.5 * sx) / sx * cells[0] as f64) as usize).min(cells[0] - 1),
            (((p[1] + 0.5 * sz) / sz * cells[1] as f64) as usize).min(cells[1] - 1),
        ]
    };
    let attempts = 20_000 + 2_000 * count;
    let mut tried = 0u64;
    while (centres.len() as u64) < count {
        tried += 1;
        if tried > attempts {
            return Err(BudgetError::invalid(
                "crowns.cover",
                spec.crowns.as_ref().map_or(0.0, |c| c.cover),
                format!(
                    "only {} of {count} non-overlapping crowns of radius {radius} m found room in the {sx} m × {sz} m plot after {attempts} tries",
                    centres.len()
                ),
            ));
        }
        let p = [
            (rng.next_f64() - 0.5) * (sx - 2.0 * margin),
            (rng.next_f64() - 0.5) * (sz - 2.0 * margin),
        ];
        let [cx, cz] = cell_of(p);
        let mut free = true;
        'near: for dx in [cells[0] - 1, 0, 1] {
            for dz in [cells[1] - 1, 0, 1] {
                let (ix, iz) = ((cx + dx) % cells[0], (cz + dz) % cells[1]);
                for &k in &grid[ix * cells[1] + iz] {
                    if plot_distance(p, centres[k as usize], spec.plot.size, cyclic) < 2.0 * radius
                    {
                        free = false;
                        break 'near;
                    }
                }
            }
        }
        if free {
            grid[cx * cells[1] + cz].push(centres.len() as u32);
            centres.push(p);
        }
    }
    Ok(centres)
}

impl Stand {
    /// The leaves of `spec`.
    pub fn build(spec: &CanopySpec) -> Result<Stand, BudgetError> {
        spec.validate()?;
        sylva_core::check_memory(
            "the stand's leaf meshes and kd-trees",
            spec.triangles().saturating_mul(160),
        )?;
        let [sx, sz] = spec.plot.size;
        let half = [0.5 * sx, 0.5 * sz];
        let leaves = spec.leaves_per_unit();
        let leaf_area = leaves as f64 * spec.leaves.area();
        let (models, mut instances, top, lai, cover) = if let Some(c) = &spec.crowns {
            let n = spec.crown_count();
            let variants = spec.crown_variants();
            let hh = c.half_height();
            let models: Vec<Model> = (0..variants)
                .map(|v| {
                    crown_model(
                        spec,
                        c.radius,
                        hh,
                        leaves,
                        SplitMix64::for_chunk(spec.seed, v).next_u64(),
                    )
                })
                .collect();
            let centres = place_crowns(spec, c.radius, n)?;
            let mut rng = SplitMix64::new(spec.seed ^ 0x7075_726e);
            let instances = centres
                .iter()
                .enumerate()
                .map(|(k, p)| Instance {
                    model: (k as u64 % variants.min(CROWN_VARIANTS)) as u32,
                    position: Vec3::new(p[0] as f32, c.centre_height as f32, p[1] as f32),
                    rotation_deg: (rng.next_f64() * 360.0) as f32,
                    scale: 1.0,
                })
                .collect::<Vec<_>>();
            let area = std::f64::consts::PI * c.radius * c.radius;
            (
                models,
                instances,
                c.centre_height + hh + spec.leaves.reach(),
                n as f64 * leaf_area / (sx * sz),
                Some(n as f64 * area / (sx * sz)),
            )
        } else {
            let l = spec.layer.as_ref().expect("validated: crowns or a layer");
            let model = layer_model(spec, l.height, leaves, spec.seed);
            let instance = Instance {
                model: 0,
                position: Vec3::ZERO,
                rotation_deg: 0.0,
                scale: 1.0,
            };
            (
                vec![model],
                vec![instance],
                l.height,
                leaf_area / (sx * sz),
                None,
            )
        };
        let placed = instances.len();
        if spec.plot.cyclic {
            // Repeats of whatever reaches over a side, one plot over.
            for k in 0..placed {
                let inst = instances[k];
                let b = models[inst.model as usize].bounds;
                let reach = b.min.abs().max(b.max.abs());
                let r = reach.x.max(reach.z) as f64;
                for ox in [-1.0, 0.0, 1.0] {
                    for oz in [-1.0, 0.0, 1.0] {
                        if ox == 0.0 && oz == 0.0 {
                            continue;
                        }
                        let (x, z) = (
                            inst.position.x as f64 + ox * sx,
                            inst.position.z as f64 + oz * sz,
                        );
                        if (x.abs() - r) < half[0] && (z.abs() - r) < half[1] {
                            instances.push(Instance {
                                position: Vec3::new(x as f32, inst.position.y, z as f32),
                                ..inst
                            });
                        }
                    }
                }
            }
        }
        Ok(Stand {
            models,
            instances,
            placed,
            half,
            top: top + 1e-3 * top.max(1.0),
            lai,
            cover,
        })
    }

    /// Leaf triangles of the distinct models.
    pub fn triangles(&self) -> usize {
        self.models.iter().map(Model::triangle_count).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_crowns(cover: f64) -> CanopySpec {
        CanopySpec::parse(&format!(
            "[plot]\nsize = [20.0, 15.0]\n[crowns]\nradius = 1.5\ncentre_height = 3.0\nlai = 2.0\ncover = {cover}\n[leaves]\nsize = 0.2\n"
        ))
        .unwrap()
    }

    #[test]
    fn crowns_do_not_overlap_and_carry_their_leaf_area() {
        let spec = small_crowns(0.4);
        let stand = Stand::build(&spec).unwrap();
        let placed = &stand.instances[..stand.placed];
        assert_eq!(placed.len() as u64, spec.crown_count());
        for (i, a) in placed.iter().enumerate() {
            for b in &placed[..i] {
                let d = plot_distance(
                    [a.position.x as f64, a.position.z as f64],
                    [b.position.x as f64, b.position.z as f64],
                    spec.plot.size,
                    true,
                );
                assert!(d >= 3.0 - 1e-4, "{d}");
            }
        }
        // The leaf area of a crown is the crown LAI times its cross-section, within one leaf.
        let area: f64 = stand.models[0]
            .mesh
            .indices
            .iter()
            .map(|t| {
                let p = |k: usize| Vec3::from_array(stand.models[0].mesh.positions[t[k] as usize]);
                0.5 * (p(1) - p(0)).cross(p(2) - p(0)).length() as f64
            })
            .sum();
        let want = 2.0 * std::f64::consts::PI * 1.5 * 1.5;
        assert!(
            (area - want).abs() < spec.leaves.area() + 1e-3 * want,
            "{area} vs {want}"
        );
        // Every leaf lies in its crown, up to a leaf's reach.
        let reach = spec.leaves.reach() as f32 + 1e-4;
        for p in &stand.models[0].mesh.positions {
            assert!(Vec3::from_array(*p).length() <= 1.5 + reach);
        }
        // Each repeat is a placed crown moved by whole plots and reaches into the plot.
        for r in &stand.instances[stand.placed..] {
            let twin = placed
                .iter()
                .find(|p| {
                    let (dx, dz) = (
                        (r.position.x - p.position.x) / 20.0,
                        (r.position.z - p.position.z) / 15.0,
                    );
                    (dx - dx.round()).abs() < 1e-5 && (dz - dz.round()).abs() < 1e-5
                })
                .expect("a repeat of a placed crown");
            assert_eq!(twin.model, r.model);
            assert!(
                r.position.x.abs() - 1.5 - reach < 10.0 && r.position.z.abs() - 1.5 - reach < 7.5
            );
        }
        assert!(stand.instances.len() > stand.placed);
        assert!((stand.cover.unwrap() - 0.4).abs() < 0.02);
    }

    #[test]
    fn the_same_seed_makes_the_same_stand() {
        let a = Stand::build(&small_crowns(0.3)).unwrap();
        let b = Stand::build(&small_crowns(0.3)).unwrap();
        assert_eq!(a.models[3].mesh.positions, b.models[3].mesh.positions);
        assert_eq!(
            a.instances.iter().map(|i| i.position).collect::<Vec<_>>(),
            b.instances.iter().map(|i| i.position).collect::<Vec<_>>()
        );
        let mut other = small_crowns(0.3);
        other.seed = 2;
        let c = Stand::build(&other).unwrap();
        assert_ne!(a.models[0].mesh.positions, c.models[0].mesh.positions);
    }

    #[test]
    fn layer_leaves_stay_inside_the_layer() {
        let spec = CanopySpec::parse(
            "[plot]\nsize = [4.0, 4.0]\n[layer]\nlai = 2.0\nheight = 1.0\n[leaves]\nshape = \"square\"\nsize = 0.05\n",
        )
        .unwrap();
        let stand = Stand::build(&spec).unwrap();
        let m = &stand.models[0];
        assert!(m.bounds.min.y >= -1e-6 && m.bounds.max.y <= 1.0 + 1e-6);
        assert!((stand.lai - 2.0).abs() < 1e-3);
        // The layer reaches over every side: its eight repeats.
        assert_eq!(stand.instances.len(), 9);
    }
}
