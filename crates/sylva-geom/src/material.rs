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

/// How a surface scatters light, per colour (linear R, G, B), as factors of its colour `c`
/// (the texel colour where it has a texture, else [`Material::base_color`]): Lambertian
/// reflectance `R = c ⊙ reflect` on the lit side and Lambertian transmittance
/// `T = c ⊙ transmit` through to the other side. A leaf photographed in reflected light has
/// `reflect = 1`; bark has `transmit = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optics {
    pub reflect: [f32; 3],
    pub transmit: [f32; 3],
}

impl Optics {
    /// An opaque Lambertian surface whose reflectance is its colour (bark, soil).
    pub const OPAQUE: Optics = Optics {
        reflect: [1.0; 3],
        transmit: [0.0; 3],
    };

    /// A leaf that reflects its colour and transmits `transmission ⊙` its colour.
    pub const fn leaf(transmission: [f32; 3]) -> Optics {
        Optics {
            reflect: [1.0; 3],
            transmit: transmission,
        }
    }

    /// The default leaf: reflects its colour, transmits [`FOREST_LEAF_TRANSMISSION`] of it.
    pub const FOREST_LEAF: Optics = Optics::leaf(FOREST_LEAF_TRANSMISSION);

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

    /// Both factors finite and ≥ 0; `what` names the material in the error.
    pub fn validate(&self, what: &str) -> Result<(), String> {
        for (name, v) in [("reflect", self.reflect), ("transmit", self.transmit)] {
            if !v.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(format!(
                    "{what}: {name} factors {v:?} must be finite and ≥ 0"
                ));
            }
        }
        Ok(())
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
            transmit: [0.0; 3],
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
