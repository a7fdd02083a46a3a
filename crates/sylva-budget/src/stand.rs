//! A canopy ready for the photons: its leaves as meshes (`sylva_grow::stand`: the crown models
//! and their placements, or the layer) and, in a cyclic plot, the instances reaching over a
//! side repeated one plot over on the opposite side, so that a ray inside the plot meets every
//! leaf of the periodic stand there.
//!
//! A rendered scene is a stand too ([`Stand::from_scene`]): its trees over its ground's
//! rectangle, each material with its own mean reflectance and transmittance per band (the
//! scene's `[bands]`, else its red, green and blue channels).

use crate::{Band, BudgetError};
use glam::Vec3;
use sylva_geom::{Instance, LeafOptics, MaterialKind, Mesh, Model, Scene};
use sylva_grow::stand::{placements, top, unit_count, unit_model, CanopySpec};

/// One band's surfaces: per model, per material, the mean reflectance and transmittance.
#[derive(Debug, Clone, PartialEq)]
pub struct Surfaces(pub Vec<Vec<[f64; 2]>>);

/// The leaves of a canopy, ready to trace.
pub struct Stand {
    /// The stand's or the scene's name.
    pub name: String,
    /// Light leaving a side re-enters on the opposite one.
    pub cyclic: bool,
    /// The bands the budget is made in.
    pub bands: Vec<Band>,
    /// Per band, each material's own optics (a scene's); `None`: every leaf has its band's
    /// `leaf_reflectance` and `leaf_transmittance` (an abstract stand's).
    pub surfaces: Option<Vec<Surfaces>>,
    /// Crowns placed (crown stands; 0 otherwise).
    pub crowns: usize,
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
            name: spec.name.clone(),
            cyclic: spec.plot.cyclic,
            bands: spec.bands.clone(),
            surfaces: None,
            crowns: if spec.crowns.is_some() { placed } else { 0 },
            models,
            instances,
            placed,
            half,
            top: top(spec) + 1e-3 * top(spec).max(1.0),
            lai: leaf_area / (sx * sz),
            cover,
        })
    }

    /// A rendered scene as a stand: its instances over its ground's rectangle (or, without
    /// a ground, the rectangle about the origin that holds every instance, over a black
    /// soil), each material's mean reflectance and transmittance per band from its optics
    /// formed for `leaf_optics`. The bands are the scene's `[bands]` (the blue, green, red
    /// and par bands count towards fAPAR), else its linear red, green and blue channels (all
    /// three in the PAR range). In a `cyclic` plot the instances reaching over a side are
    /// repeated one plot over. The scene's models become the stand's.
    pub fn from_scene(
        mut scene: Scene,
        leaf_optics: LeafOptics,
        cyclic: bool,
    ) -> Result<Stand, BudgetError> {
        let bad = |message: String| BudgetError::Scene {
            scene: scene.origin.clone(),
            message,
        };
        if !scene.media.is_empty() {
            return Err(bad(
                "participating media (clouds) are not part of a canopy's budget".into(),
            ));
        }
        if scene.instances.is_empty() {
            return Err(bad("no instances: nothing to intercept the light".into()));
        }
        let bounds: Vec<_> = scene
            .instances
            .iter()
            .map(|i| i.world_bounds(&scene.models[i.model as usize]))
            .collect();
        let top = bounds.iter().map(|b| b.max.y).fold(f32::MIN, f32::max) as f64;
        if !(top > 0.0 && top.is_finite()) {
            return Err(bad(format!(
                "its plants reach {top} m: nothing stands above the soil (y = 0)"
            )));
        }
        let half = match scene.ground_half_extents() {
            Some([hx, hz]) => [hx as f64, hz as f64],
            None => {
                let reach = |f: &dyn Fn(&sylva_geom::Aabb) -> f32| {
                    bounds.iter().map(f).fold(0.0f32, f32::max) as f64
                };
                [
                    reach(&|b| b.min.x.abs().max(b.max.x.abs())),
                    reach(&|b| b.min.z.abs().max(b.max.z.abs())),
                ]
            }
        };
        if !(half[0] > 0.0 && half[1] > 0.0) {
            return Err(bad(format!(
                "its plot is {} m × {} m: it needs an area",
                2.0 * half[0],
                2.0 * half[1]
            )));
        }
        // The bands' optics are formed on copies of the scene without its meshes (only the
        // materials change), so a forest's triangles are never copied.
        let meshes: Vec<Mesh> = scene
            .models
            .iter_mut()
            .map(|m| std::mem::take(&mut m.mesh))
            .collect();
        let (bands, surfaces) = scene_bands(&scene, leaf_optics).map_err(bad)?;
        for (m, mesh) in scene.models.iter_mut().zip(meshes) {
            m.mesh = mesh;
        }
        let placed = scene.instances.len();
        let mut instances = scene.instances.clone();
        if cyclic {
            let [sx, sz] = [2.0 * half[0], 2.0 * half[1]];
            for (k, b) in bounds.iter().enumerate() {
                for ox in [-1.0, 0.0, 1.0] {
                    for oz in [-1.0, 0.0, 1.0] {
                        let (dx, dz) = (ox * sx, oz * sz);
                        let reaches = (b.min.x as f64 + dx) < half[0]
                            && (b.max.x as f64 + dx) > -half[0]
                            && (b.min.z as f64 + dz) < half[1]
                            && (b.max.z as f64 + dz) > -half[1];
                        if (ox != 0.0 || oz != 0.0) && reaches {
                            let inst = scene.instances[k];
                            instances.push(Instance {
                                position: inst.position + Vec3::new(dx as f32, 0.0, dz as f32),
                                ..inst
                            });
                        }
                    }
                }
            }
        }
        // One-sided leaf area: each leaf triangle's area, scaled, times the share of its
        // texture that is leaf (the rest is cut away by the alpha test).
        let leaf_area: Vec<f64> = scene
            .models
            .iter()
            .map(|m| {
                let opaque: Vec<f64> = m
                    .materials
                    .iter()
                    .map(|mat| match (&mat.kind, &mat.texture) {
                        (MaterialKind::Leaf, Some(t)) => t.opaque_fraction(),
                        (MaterialKind::Leaf, None) => 1.0,
                        _ => 0.0,
                    })
                    .collect();
                m.mesh
                    .indices
                    .iter()
                    .zip(&m.mesh.material_ids)
                    .map(|(t, &mat)| {
                        let p = |k: usize| Vec3::from_array(m.mesh.positions[t[k] as usize]);
                        let area = 0.5 * (p(1) - p(0)).cross(p(2) - p(0)).length() as f64;
                        area * opaque.get(mat as usize).copied().unwrap_or(0.0)
                    })
                    .sum()
            })
            .collect();
        let area: f64 = scene
            .instances
            .iter()
            .map(|i| leaf_area[i.model as usize] * f64::from(i.scale).powi(2))
            .sum();
        Ok(Stand {
            name: scene.name,
            cyclic,
            bands,
            surfaces: Some(surfaces),
            crowns: 0,
            models: scene.models,
            instances,
            placed,
            half,
            top: top + 1e-3 * top.max(1.0),
            lai: area / (4.0 * half[0] * half[1]),
            cover: None,
        })
    }

    /// Reflectance and transmittance of material `material` of model `model` in band `b`
    /// (`band`, whose leaf optics an abstract stand's leaves all have).
    #[inline]
    pub fn optics(&self, b: usize, band: &Band, model: usize, material: usize) -> (f64, f64) {
        match &self.surfaces {
            None => (band.leaf_reflectance, band.leaf_transmittance),
            Some(s) => {
                let [r, t] = s[b].0[model][material];
                (r, t)
            }
        }
    }

    /// Leaf triangles of the distinct models.
    pub fn triangles(&self) -> usize {
        self.models.iter().map(Model::triangle_count).sum()
    }
}

/// A scene's bands and each band's surfaces: channel `c` of a scene whose optics are formed
/// holds, per material, the mean colour times the reflectance and transmittance factors.
fn scene_bands(
    scene: &Scene,
    leaf_optics: LeafOptics,
) -> Result<(Vec<Band>, Vec<Surfaces>), String> {
    let channels = |s: &Scene| -> [Surfaces; 3] {
        // Per model, per material, per channel: [R, T] (a texture's mean read once).
        let optics: Vec<Vec<[[f64; 2]; 3]>> = s
            .models
            .iter()
            .map(|m| {
                m.materials
                    .iter()
                    .map(|mat| {
                        let mean = mat.mean_colour();
                        std::array::from_fn(|c| {
                            let of = |factor: f32| {
                                (f64::from(mean[c]) * f64::from(factor)).clamp(0.0, 1.0)
                            };
                            [of(mat.optics.reflect[c]), of(mat.optics.transmit[c])]
                        })
                    })
                    .collect()
            })
            .collect();
        std::array::from_fn(|c| {
            Surfaces(
                optics
                    .iter()
                    .map(|m| m.iter().map(|mat| mat[c]).collect())
                    .collect(),
            )
        })
    };
    let soil = |s: &Scene, c: usize| {
        if s.ground.enabled {
            f64::from(s.ground.color[c]).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let band = |name: &str, soil: f64, par: bool| Band {
        name: name.to_string(),
        // Unused: a scene's leaves differ by material, and `Stand::surfaces` holds each.
        leaf_reflectance: 0.0,
        leaf_transmittance: 0.0,
        soil_albedo: soil,
        par,
        weight: 1.0,
    };
    let Some(bands) = &scene.bands else {
        let mut s = scene.clone();
        s.set_leaf_optics(leaf_optics)?;
        let surfaces = channels(&s);
        let names = ["red", "green", "blue"];
        let bands = (0..3).map(|c| band(names[c], soil(&s, c), true)).collect();
        return Ok((bands, surfaces.into()));
    };
    if leaf_optics != LeafOptics::Measured {
        return Err(
            "[bands] give each band's leaf reflectance and transmittance: the leaf optics must be measured (the default)"
                .into(),
        );
    }
    let mut out: Vec<Option<(Band, Surfaces)>> = vec![None; bands.len()];
    for g in 0..bands.groups() {
        let mut s = scene.clone();
        s.apply_band_group(g)?;
        s.set_leaf_optics(LeafOptics::Measured)?;
        let surfaces = channels(&s);
        for (c, b) in bands.group(g).into_iter().enumerate() {
            if out[b].is_none() {
                let name = &bands.names[b];
                let par = ["blue", "green", "red", "par"].contains(&name.to_lowercase().as_str());
                out[b] = Some((band(name, soil(&s, c), par), surfaces[c].clone()));
            }
        }
    }
    Ok(out
        .into_iter()
        .map(|b| b.expect("every band in a group"))
        .unzip())
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
