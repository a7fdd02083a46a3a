//! A canopy ready for the photons: its leaves as meshes (`sylva_grow::stand`: the crown models
//! and their placements, or the layer) and, in a cyclic plot, the instances reaching over a
//! side repeated one plot over on the opposite side, so that a ray inside the plot meets every
//! leaf of the periodic stand there.

use crate::BudgetError;
use glam::Vec3;
use sylva_geom::{Instance, Model};
use sylva_grow::stand::{placements, top, unit_count, unit_model, CanopySpec};

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
        let models: Vec<Model> = (0..unit_count(spec)).map(|k| unit_model(spec, k)).collect();
        let mut instances = placements(spec)?;
        let placed = instances.len();
        let leaf_area = spec.leaves_per_unit() as f64 * spec.leaves.area() * placed as f64;
        let cover = spec
            .crowns
            .as_ref()
            .map(|c| placed as f64 * std::f64::consts::PI * c.radius * c.radius / (sx * sz));
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
            top: top(spec) + 1e-3 * top(spec).max(1.0),
            lai: leaf_area / (sx * sz),
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
    use sylva_grow::stand::plot_distance;

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
