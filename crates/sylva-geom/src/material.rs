//! Surface materials: leaf and wood are kept apart so the LB voxelizer can mark green (leaf)
//! and brown (wood) sites, and the renderer can alpha-test leaves. Solid is the surface of an
//! object made of a scattering material (the PMMA teapot of paper 002).
//!
//! Every material also carries its [`Optics`]: how much light it reflects and transmits per
//! colour. This is the one physical material model of sylva (docs/light.md): the shader's
//! direct and indirect light, the LB medium of a model (single-scattering albedo and
//! asymmetry of its green and brown sites) and the Mitsuba export all read it, so that the
//! renderer and a path tracer of the exported scene light the same surfaces.

use crate::texture::Texture;
use std::sync::Arc;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MaterialKind {
    /// Thin, two-sided, alpha-tested, transmits light; green LB sites.
    Leaf,
    /// Bark: opaque; brown LB sites (g = -1).
    Wood,
    /// An opaque surface of a material that scatters light inside it (plastic, wax): shaded
    /// like wood, but its LB sites are plain medium sites with the model's preset (its own g),
    /// never brown.
    Solid,
}

impl MaterialKind {
    pub fn name(self) -> &'static str {
        match self {
            MaterialKind::Leaf => "leaf",
            MaterialKind::Wood => "wood",
            MaterialKind::Solid => "solid",
        }
    }
}

/// Knapp & Carter's forest-leaf transmittance / reflectance per colour (000 Table 1:
/// `fs / bs` = 0.055/0.070, 0.150/0.125, 0.020/0.040): leaves pass more green than they
/// reflect, and much less blue.
pub const FOREST_LEAF_TRANSMISSION: [f32; 3] = [0.055 / 0.070, 0.150 / 0.125, 0.020 / 0.040];

/// Knapp & Carter's mean forest leaf, as 000 Table 1 prints it: reflectance `bs` = (0.070,
/// 0.125, 0.040) and transmittance `fs` = (0.055, 0.150, 0.020) per colour (linear R, G, B).
/// The table's `σ_a` is 0.125 × (1 − R − T) of these, so they are the measured fractions
/// themselves, not the LB's scaled ones.
pub const KNAPP_CARTER_LEAF: Measured = Measured {
    reflectance: [0.070, 0.125, 0.040],
    transmittance: [0.055, 0.150, 0.020],
};

/// A surface's measured mean reflectance `R` and transmittance `T` per colour (linear R, G,
/// B): what a species' leaf is, whatever its texture looks like.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    pub reflectance: [f32; 3],
    pub transmittance: [f32; 3],
}

impl Measured {
    /// Finite, ≥ 0 and `R + T ≤ 1` per colour (a leaf cannot scatter more than it receives);
    /// `what` names the surface in the one-line error.
    pub fn validate(&self, what: &str) -> Result<(), String> {
        let (r, t) = (self.reflectance, self.transmittance);
        for (name, v) in [("reflectance", r), ("transmittance", t)] {
            if !v.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(format!("{what}: {name} {v:?} must be finite and ≥ 0"));
            }
        }
        for (c, colour) in ["red", "green", "blue"].iter().enumerate() {
            if r[c] + t[c] > 1.0 {
                return Err(format!(
                    "{what}: reflectance + transmittance in {colour} is {} + {} > 1",
                    r[c], t[c]
                ));
            }
        }
        Ok(())
    }
}

/// Which leaf optics a run uses (`--leaf-optics`): the species' measured values, the texture
/// only shaping the pattern, or the look before issue 29, where the texture's colour was
/// the reflectance (kept to compare against).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LeafOptics {
    #[default]
    Measured,
    Texture,
}

impl LeafOptics {
    pub const ALL: [LeafOptics; 2] = [LeafOptics::Measured, LeafOptics::Texture];

    pub fn name(self) -> &'static str {
        match self {
            LeafOptics::Measured => "measured",
            LeafOptics::Texture => "texture",
        }
    }
}

/// How a surface scatters light, per colour (linear R, G, B), as factors of its colour `c`
/// (the texel colour where it has a texture, else [`Material::base_color`]): Lambertian
/// reflectance `R = c ⊙ reflect` on the lit side and Lambertian transmittance
/// `T = c ⊙ transmit` through to the other side. Every consumer (the shader on both devices,
/// the LB medium, the export) reads these factors and nothing else, so they cannot disagree.
///
/// A surface with `measured` values (a species' leaf) has its factors formed from them
/// ([`Optics::with_leaf_optics`]): measured, `reflect = R / c̄` with `c̄` the texture's mean
/// colour, so the texture shapes only the pattern (texel / mean texel) and the mean is
/// `R`; texture, `reflect = 1`, `transmit = T / R`: the texture's colour is the reflectance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optics {
    pub reflect: [f32; 3],
    pub transmit: [f32; 3],
    /// The measured mean `R` and `T` the factors come from; `None`: the factors are the
    /// material's own (imported files, built-in shapes).
    pub measured: Option<Measured>,
}

impl Optics {
    /// An opaque Lambertian surface whose reflectance is its colour (bark, soil).
    pub const OPAQUE: Optics = Optics {
        reflect: [1.0; 3],
        transmit: [0.0; 3],
        measured: None,
    };

    /// A leaf that reflects its colour and transmits `transmission ⊙` its colour.
    pub const fn leaf(transmission: [f32; 3]) -> Optics {
        Optics {
            reflect: [1.0; 3],
            transmit: transmission,
            measured: None,
        }
    }

    /// The default leaf: reflects its colour, transmits [`FOREST_LEAF_TRANSMISSION`] of it.
    pub const FOREST_LEAF: Optics = Optics::leaf(FOREST_LEAF_TRANSMISSION);

    /// A leaf measured as `m`, its factors for `mode` on a surface of mean colour `mean`
    /// ([`Optics::with_leaf_optics`]).
    pub fn measured_leaf(m: Measured, mode: LeafOptics, mean: [f32; 3]) -> Result<Optics, String> {
        Optics {
            measured: Some(m),
            ..Optics::FOREST_LEAF
        }
        .with_leaf_optics(mode, mean)
    }

    /// These optics with their factors formed for `mode` from the measured values, on a
    /// surface whose mean colour is `mean`; unchanged without measured values. Measured
    /// needs every colour of `mean` above zero where `R` or `T` is (a black channel cannot
    /// be scaled to a measured value); texture needs `R > 0` where `T` is (the ratio `T / R`).
    pub fn with_leaf_optics(self, mode: LeafOptics, mean: [f32; 3]) -> Result<Optics, String> {
        let Some(m) = self.measured else {
            return Ok(self);
        };
        let (r, t) = (m.reflectance, m.transmittance);
        let mut o = self;
        for c in 0..3 {
            let (f_r, f_t) = match mode {
                LeafOptics::Measured => {
                    if mean[c] > 0.0 {
                        (r[c] / mean[c], t[c] / mean[c])
                    } else if r[c] == 0.0 && t[c] == 0.0 {
                        (0.0, 0.0)
                    } else {
                        return Err(format!(
                            "a texture of mean colour {mean:?} cannot carry the measured \
                             reflectance {r:?} and transmittance {t:?} (colour {c} is black)"
                        ));
                    }
                }
                LeafOptics::Texture => {
                    if r[c] > 0.0 {
                        (1.0, t[c] / r[c])
                    } else if t[c] == 0.0 {
                        (1.0, 0.0)
                    } else {
                        return Err(format!(
                            "--leaf-optics texture needs a reflectance above 0 where the \
                             transmittance is (T / R), got R {r:?}, T {t:?}"
                        ));
                    }
                }
            };
            o.reflect[c] = f_r;
            o.transmit[c] = f_t;
        }
        Ok(o)
    }

    /// `R = colour ⊙ reflect`.
    #[inline]
    pub fn reflectance(&self, colour: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|c| colour[c] * self.reflect[c])
    }

    /// `T = colour ⊙ transmit`.
    #[inline]
    pub fn transmittance(&self, colour: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|c| colour[c] * self.transmit[c])
    }

    /// Both factors finite and ≥ 0, and the measured values valid ([`Measured::validate`]);
    /// `what` names the material in the error.
    pub fn validate(&self, what: &str) -> Result<(), String> {
        for (name, v) in [("reflect", self.reflect), ("transmit", self.transmit)] {
            if !v.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(format!(
                    "{what}: {name} factors {v:?} must be finite and ≥ 0"
                ));
            }
        }
        match &self.measured {
            Some(m) => m.validate(what),
            None => Ok(()),
        }
    }
}

#[derive(Debug, Clone)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    /// Representative linear RGB in [0, 1] (the texture's mean opaque colour when there is
    /// one): what untextured previews use. A renderer with the texture uses the texel colour
    /// instead.
    pub base_color: [f32; 3],
    /// Leaf textures carry the leaf shape in alpha; bark textures are opaque and repeat.
    pub texture: Option<Arc<Texture>>,
    /// Leaves are single quads seen from both sides; bark tubes are closed.
    pub two_sided: bool,
    /// Reflectance and transmittance as factors of the colour.
    pub optics: Optics,
}

impl Material {
    pub fn is_leaf(&self) -> bool {
        self.kind == MaterialKind::Leaf
    }

    /// The mean linear colour over the surface: the texture's opaque texels averaged in
    /// linear RGB (what a uniformly lit leaf reflects on average), else the base colour.
    pub fn mean_colour(&self) -> [f32; 3] {
        match &self.texture {
            Some(t) => t.mean_opaque_albedo(),
            None => self.base_color,
        }
    }

    /// Mean reflectance R per colour.
    pub fn mean_reflectance(&self) -> [f32; 3] {
        self.optics.reflectance(self.mean_colour())
    }

    /// Mean transmittance T per colour.
    pub fn mean_transmittance(&self) -> [f32; 3] {
        self.optics.transmittance(self.mean_colour())
    }

    /// Forms this material's factors for `mode` from its measured values (none: unchanged);
    /// the error names the material.
    pub fn set_leaf_optics(&mut self, mode: LeafOptics) -> Result<(), String> {
        self.optics = self
            .optics
            .with_leaf_optics(mode, self.mean_colour())
            .map_err(|e| format!("material '{}': {e}", self.name))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{Texture, Wrap};

    #[test]
    fn optics_scale_the_colour() {
        let o = Optics::FOREST_LEAF;
        let c = [0.1, 0.2, 0.05];
        assert_eq!(o.reflectance(c), c);
        let t = o.transmittance(c);
        for k in 0..3 {
            assert!((t[k] - c[k] * FOREST_LEAF_TRANSMISSION[k]).abs() < 1e-7);
        }
        assert_eq!(Optics::OPAQUE.transmittance(c), [0.0; 3]);
        assert!(Optics::OPAQUE.validate("bark").is_ok());
        let bad = Optics {
            reflect: [1.0, f32::NAN, 1.0],
            ..Optics::OPAQUE
        };
        assert!(bad.validate("leaf x").unwrap_err().contains("leaf x"));
    }

    #[test]
    fn forest_leaf_optics_and_the_leaf_preset_describe_one_leaf() {
        // The surface's T / R per colour and the LB leaf medium's asymmetry come from the same
        // measurements (000 Table 1's fs and bs): g = (T - R) / (T + R) (000 eq. 10), here to
        // the three digits the table prints, the preset's values.
        let o = Optics::FOREST_LEAF;
        let preset = crate::params::Preset::Leaf.params();
        for c in 0..3 {
            let (t, r) = (o.transmit[c] as f64, o.reflect[c] as f64);
            let g = (t - r) / (t + r);
            let want = preset.colours[c].g;
            assert!(
                (g - want).abs() < 5e-4,
                "colour {c}: g {g} vs the preset's {want}"
            );
        }
        // Knapp & Carter's leaves pass more green light than they reflect, less red and blue.
        assert!(o.transmit[1] > o.reflect[1]);
        assert!(o.transmit[0] < o.reflect[0] && o.transmit[2] < o.reflect[2]);
    }

    /// A leaf texture of four opaque texels of different colours and one transparent one.
    fn patterned_leaf(optics: Optics) -> Material {
        let t = Texture::new(
            5,
            1,
            vec![
                [40, 90, 20, 255],
                [90, 160, 50, 255],
                [120, 200, 30, 255],
                [60, 110, 90, 255],
                [255, 0, 255, 0],
            ],
            Wrap::Clamp,
        );
        Material {
            name: "patterned leaf".into(),
            kind: MaterialKind::Leaf,
            base_color: t.mean_opaque_linear(),
            texture: Some(Arc::new(t)),
            two_sided: true,
            optics,
        }
    }

    #[test]
    fn a_measured_leaf_averages_to_its_measured_values_over_its_texture() {
        // Texel by texel, as the shader does (each opaque texel decoded, times the factor),
        // the mean over the leaf is R and T: texel / mean texel keeps only the pattern.
        let mut m = patterned_leaf(Optics {
            measured: Some(KNAPP_CARTER_LEAF),
            ..Optics::FOREST_LEAF
        });
        m.set_leaf_optics(LeafOptics::Measured).unwrap();
        let tex = m.texture.clone().unwrap();
        let opaque: Vec<[f32; 3]> = (0..tex.width)
            .map(|x| tex.texel(x, 0))
            .filter(|p| crate::is_opaque(*p))
            .map(|p| [0, 1, 2].map(|c| sylva_core::colour::srgb_to_linear(p[c] as f32 / 255.0)))
            .collect();
        assert_eq!(opaque.len(), 4);
        for c in 0..3 {
            let mean = |f: f32| opaque.iter().map(|t| (t[c] * f) as f64).sum::<f64>() / 4.0;
            let (r, t) = (mean(m.optics.reflect[c]), mean(m.optics.transmit[c]));
            let (want_r, want_t) = (
                KNAPP_CARTER_LEAF.reflectance[c] as f64,
                KNAPP_CARTER_LEAF.transmittance[c] as f64,
            );
            assert!(
                (r - want_r).abs() < 1e-7 * want_r.max(1.0),
                "R[{c}] {r} vs {want_r}"
            );
            assert!(
                (t - want_t).abs() < 1e-7 * want_t.max(1.0),
                "T[{c}] {t} vs {want_t}"
            );
            // The texels still differ: the pattern is kept.
            assert!(opaque.iter().any(|t| t[c] != opaque[0][c]));
        }
        // The same through the material's own means (what the LB medium reads).
        let (r, t) = (m.mean_reflectance(), m.mean_transmittance());
        for c in 0..3 {
            assert!((r[c] - KNAPP_CARTER_LEAF.reflectance[c]).abs() < 1e-7);
            assert!((t[c] - KNAPP_CARTER_LEAF.transmittance[c]).abs() < 1e-7);
        }
    }

    #[test]
    fn texture_mode_is_the_colour_look_of_before() {
        // Before issue 29 a forest leaf reflected its colour and transmitted
        // FOREST_LEAF_TRANSMISSION of it: `texture` forms exactly those factors (bit for bit)
        // from the measured leaf, and `measured` again gives back the measured factors.
        let mut m = patterned_leaf(Optics {
            measured: Some(KNAPP_CARTER_LEAF),
            ..Optics::OPAQUE
        });
        m.set_leaf_optics(LeafOptics::Texture).unwrap();
        assert_eq!(m.optics.reflect, Optics::FOREST_LEAF.reflect);
        assert_eq!(m.optics.transmit, Optics::FOREST_LEAF.transmit);
        m.set_leaf_optics(LeafOptics::Measured).unwrap();
        let mean = m.mean_colour();
        let want: [f32; 3] = std::array::from_fn(|c| KNAPP_CARTER_LEAF.reflectance[c] / mean[c]);
        assert_eq!(m.optics.reflect, want);
        // Materials without measured values (imports) keep their own factors in both modes.
        for mode in LeafOptics::ALL {
            let mut own = patterned_leaf(Optics::leaf([0.3, 0.6, 0.9]));
            own.set_leaf_optics(mode).unwrap();
            assert_eq!(own.optics, Optics::leaf([0.3, 0.6, 0.9]));
        }
    }

    #[test]
    fn knapp_and_carters_leaf_is_000_table_1() {
        // σ_a = 0.125 (1 − R − T) per colour, as the table prints it (three digits).
        let m = KNAPP_CARTER_LEAF;
        let sigma_a = [0.109, 0.091, 0.118];
        for c in 0..3 {
            let a = 0.125 * (1.0 - m.reflectance[c] as f64 - m.transmittance[c] as f64);
            assert!((a - sigma_a[c]).abs() < 5e-4, "colour {c}: {a}");
            let ratio = m.transmittance[c] / m.reflectance[c];
            assert_eq!(ratio, FOREST_LEAF_TRANSMISSION[c]);
        }
        assert!(m.validate("Knapp & Carter").is_ok());
    }

    #[test]
    fn bad_measured_optics_are_refused_in_one_line() {
        let leaf = |r: [f32; 3], t: [f32; 3]| Measured {
            reflectance: r,
            transmittance: t,
        };
        for (bad, says) in [
            (
                leaf([0.6, 0.1, 0.1], [0.5, 0.1, 0.1]),
                "in red is 0.6 + 0.5 > 1",
            ),
            (leaf([0.1, 0.1, 0.1], [0.1, -0.2, 0.1]), "transmittance"),
            (leaf([0.1, f32::NAN, 0.1], [0.1; 3]), "reflectance"),
            (leaf([0.1, 0.1, 0.9], [0.1, 0.1, 0.2]), "in blue"),
        ] {
            let e = bad.validate("model 'oak': leaf").unwrap_err();
            assert!(e.starts_with("model 'oak': leaf: "), "{e}");
            assert!(e.contains(says), "{e}");
            assert!(!e.contains('\n'), "{e}");
            // The optics carrying it are refused too (what the LB medium checks).
            let o = Optics {
                measured: Some(bad),
                ..Optics::FOREST_LEAF
            };
            assert!(o.validate("x").is_err());
        }
        // R + T = 1 exactly is a leaf that absorbs nothing: allowed.
        assert!(leaf([0.5; 3], [0.5; 3]).validate("x").is_ok());
        // A texture black in a colour cannot carry a measured value there.
        let black_green = Texture::new(1, 1, vec![[200, 0, 100, 255]], Wrap::Clamp);
        let mut m = patterned_leaf(Optics {
            measured: Some(KNAPP_CARTER_LEAF),
            ..Optics::FOREST_LEAF
        });
        m.texture = Some(Arc::new(black_green));
        let e = m.set_leaf_optics(LeafOptics::Measured).unwrap_err();
        assert!(
            e.contains("patterned leaf") && e.contains("colour 1 is black"),
            "{e}"
        );
        // Texture mode needs T / R: a leaf reflecting nothing in a colour it transmits fails.
        let mut m = patterned_leaf(Optics {
            measured: Some(leaf([0.1, 0.0, 0.1], [0.1, 0.1, 0.1])),
            ..Optics::FOREST_LEAF
        });
        assert!(m.set_leaf_optics(LeafOptics::Texture).is_err());
    }

    #[test]
    fn mean_colour_averages_linear_opaque_texels() {
        // Two opaque texels, black and white, and a transparent red one: the linear mean of
        // the opaque ones is 0.5 (the sRGB mean, decoded, would be about 0.21).
        let t = Texture::new(
            3,
            1,
            vec![[0, 0, 0, 255], [255, 255, 255, 255], [255, 0, 0, 0]],
            Wrap::Clamp,
        );
        let m = Material {
            name: "leaf".into(),
            kind: MaterialKind::Leaf,
            base_color: [0.3; 3],
            texture: Some(Arc::new(t)),
            two_sided: true,
            optics: Optics::leaf([0.5; 3]),
        };
        for c in m.mean_colour() {
            assert!((c - 0.5).abs() < 1e-6, "{c}");
        }
        for c in m.mean_transmittance() {
            assert!((c - 0.25).abs() < 1e-6, "{c}");
        }
        let plain = Material { texture: None, ..m };
        assert_eq!(plain.mean_reflectance(), [0.3; 3]);
    }
}
