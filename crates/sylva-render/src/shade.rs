//! Shading (SPEC §2, paper 000 §3): the local sunlight at a hit, split into the parts the
//! comparison modes of 000 Fig. 2 recombine.
//!
//! * Local light: diffuse `k_d (N·L)` and specular `k_s (V·R)^s` with the sun's 6500 K black-body
//!   colour, zero where the shadow ray is blocked. Leaves are two-sided: the normal faces the
//!   viewer, and a leaf lit from behind transmits `k_d · T/R · |N·L|` (light through leaves),
//!   with the transmittance/reflectance ratio `T/R = (1 + g) / (1 - g)` of the LB preset's `g`
//!   per colour (000 Table 1 defines `g = (T - R) / (T + R)`).
//! * Indirect light: the model's LB solution at the hit (normalised so free-space sunlight is 1)
//!   times the texture colour, the sun colour and [`ShadingParams::indirect`].
//! * Albedo: texture colour × sun colour, what a constant ambient multiplies (the "ambient" mode).
//! * The ground takes the sun and, as indirect light, a constant sky ambient.

use glam::{Vec2, Vec3};
use sylva_core::colour::srgb_to_linear;
use sylva_geom::{Material, MaterialKind, Model, Texture, Wrap};

/// Shading constants that the papers leave open (documented in docs/render.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadingParams {
    /// Sun irradiance on a surface facing it (luminance units; the sun colour has luminance 1).
    pub sun_irradiance: f32,
    /// Scale of the LB light added as indirect light.
    pub indirect: f32,
    /// Constant sky light on the ground, as a fraction of the sun irradiance.
    pub sky_ambient: f32,
    /// Specular coefficient and exponent of leaves (waxy cuticle) and of bark.
    pub leaf_specular: (f32, f32),
    pub wood_specular: (f32, f32),
    /// Transmittance / reflectance per colour of leaves (from the LB preset's `g`).
    pub leaf_transmission: [f32; 3],
}

impl Default for ShadingParams {
    fn default() -> Self {
        ShadingParams {
            sun_irradiance: 1.0,
            indirect: 0.5,
            sky_ambient: 0.25,
            leaf_specular: (0.06, 24.0),
            wood_specular: (0.02, 8.0),
            leaf_transmission: transmission_from_g([-0.120, 0.091, -0.333]),
        }
    }
}

/// `T/R = (1 + g) / (1 - g)`, inverted from `g = (T - R) / (T + R)`; `g` clamped off ±1.
pub fn transmission_from_g(g: [f32; 3]) -> [f32; 3] {
    g.map(|g| {
        let g = g.clamp(-0.99, 0.99);
        (1.0 + g) / (1.0 - g)
    })
}

impl ShadingParams {
    pub fn validate(&self) -> Result<(), String> {
        let named = [
            ("sun irradiance", self.sun_irradiance),
            ("indirect scale", self.indirect),
            ("sky ambient", self.sky_ambient),
            ("leaf specular", self.leaf_specular.0),
            ("leaf shininess", self.leaf_specular.1),
            ("wood specular", self.wood_specular.0),
            ("wood shininess", self.wood_specular.1),
        ];
        for (what, v) in named {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{what} {v} must be a finite number ≥ 0"));
            }
        }
        if !self
            .leaf_transmission
            .iter()
            .all(|t| t.is_finite() && *t >= 0.0)
        {
            return Err(format!(
                "leaf transmission {:?} must be finite and ≥ 0",
                self.leaf_transmission
            ));
        }
        Ok(())
    }
}

/// A texture decoded to linear RGB once, so shading samples without `powf`.
#[derive(Debug, Clone)]
pub struct LinearTexture {
    width: u32,
    height: u32,
    wrap: Wrap,
    texels: Vec<Vec3>,
}

impl LinearTexture {
    pub fn new(t: &Texture) -> LinearTexture {
        let lut: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
        LinearTexture {
            width: t.width,
            height: t.height,
            wrap: t.wrap,
            texels: t
                .pixels
                .iter()
                .map(|p| Vec3::new(lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize]))
                .collect(),
        }
    }

    /// Width, height, wrap and the linear texels row by row (for the GPU frame).
    pub(crate) fn raw(&self) -> (u32, u32, Wrap, &[Vec3]) {
        (self.width, self.height, self.wrap, &self.texels)
    }

    fn texel(&self, x: i64, y: i64) -> Vec3 {
        let (x, y) = (
            self.wrap.apply(x, self.width),
            self.wrap.apply(y, self.height),
        );
        self.texels[y as usize * self.width as usize + x as usize]
    }

    /// Bilinear, texel centres at `(x + 0.5) / width` as in [`Texture`].
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let uv = if uv.is_finite() { uv } else { Vec2::ZERO };
        let g = uv * Vec2::new(self.width as f32, self.height as f32) - 0.5;
        let f = g.floor();
        let t = g - f;
        let (x, y) = (f.x as i64, f.y as i64);
        let top = self.texel(x, y).lerp(self.texel(x + 1, y), t.x);
        let bottom = self.texel(x, y + 1).lerp(self.texel(x + 1, y + 1), t.x);
        top.lerp(bottom, t.y)
    }
}

/// A material as the shader needs it.
#[derive(Debug, Clone)]
pub struct ShadeMaterial {
    pub leaf: bool,
    pub base: Vec3,
    pub texture: Option<LinearTexture>,
}

impl ShadeMaterial {
    pub fn new(m: &Material) -> ShadeMaterial {
        ShadeMaterial {
            leaf: m.kind == MaterialKind::Leaf,
            base: Vec3::from_array(m.base_color),
            texture: m.texture.as_deref().map(LinearTexture::new),
        }
    }

    pub fn colour(&self, uv: Vec2) -> Vec3 {
        match &self.texture {
            Some(t) => t.sample(uv),
            None => self.base,
        }
    }
}

/// The materials of every model, decoded once per render.
pub fn shade_materials(models: &[Model]) -> Vec<Vec<ShadeMaterial>> {
    models
        .iter()
        .map(|m| m.materials.iter().map(ShadeMaterial::new).collect())
        .collect()
}

/// What one sample contributes, before the modes combine the parts.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Radiance {
    /// Direct sunlight (diffuse, specular, transmitted).
    pub local: Vec3,
    /// LB light on plants, sky ambient on the ground.
    pub indirect: Vec3,
    /// Surface colour × sun colour: the response to a unit constant ambient.
    pub albedo: Vec3,
    /// Sky seen directly.
    pub sky: Vec3,
}

impl std::ops::AddAssign for Radiance {
    fn add_assign(&mut self, o: Radiance) {
        self.local += o.local;
        self.indirect += o.indirect;
        self.albedo += o.albedo;
        self.sky += o.sky;
    }
}

impl std::ops::Mul<f32> for Radiance {
    type Output = Radiance;
    fn mul(self, k: f32) -> Radiance {
        Radiance {
            local: self.local * k,
            indirect: self.indirect * k,
            albedo: self.albedo * k,
            sky: self.sky * k,
        }
    }
}

/// The geometry of a surface point, in world space.
#[derive(Debug, Clone, Copy)]
pub struct SurfacePoint {
    /// Unit normal turned towards the viewer (two-sided surfaces).
    pub normal: Vec3,
    /// Unit vector towards the viewer.
    pub view: Vec3,
    /// Surface colour (linear).
    pub colour: Vec3,
    pub leaf: bool,
}

/// How much of the sun's light reaches the viewer from a surface, per unit sun irradiance and
/// before the sun colour; zero terms where the sun is behind an opaque surface.
///
/// `to_sun` is the unit vector towards the sun; `lit` says whether the shadow ray got through.
pub fn local_light(s: &SurfacePoint, to_sun: Vec3, lit: bool, p: &ShadingParams) -> Vec3 {
    if !lit {
        return Vec3::ZERO;
    }
    let cos = s.normal.dot(to_sun);
    if cos > 0.0 {
        let (ks, shininess) = if s.leaf {
            p.leaf_specular
        } else {
            p.wood_specular
        };
        let r = 2.0 * cos * s.normal - to_sun;
        let spec = ks * r.dot(s.view).max(0.0).powf(shininess);
        s.colour * cos + Vec3::splat(spec)
    } else if s.leaf {
        s.colour * Vec3::from_array(p.leaf_transmission) * (-cos)
    } else {
        Vec3::ZERO
    }
}

/// Whether a shadow ray is worth tracing: something reaches the viewer if the surface is lit.
pub fn needs_shadow_ray(s: &SurfacePoint, to_sun: Vec3) -> bool {
    let cos = s.normal.dot(to_sun);
    cos > 0.0 || (s.leaf && cos < 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(normal: Vec3, leaf: bool) -> SurfacePoint {
        SurfacePoint {
            normal,
            view: Vec3::Y,
            colour: Vec3::new(0.2, 0.5, 0.1),
            leaf,
        }
    }

    #[test]
    fn diffuse_follows_lambert_and_shadow_zeroes_it() {
        let p = ShadingParams {
            leaf_specular: (0.0, 1.0),
            wood_specular: (0.0, 1.0),
            ..Default::default()
        };
        let s = point(Vec3::Y, false);
        let sun = Vec3::new(0.6, 0.8, 0.0);
        let l = local_light(&s, sun, true, &p);
        assert!((l - s.colour * 0.8).abs().max_element() < 1e-6);
        assert_eq!(local_light(&s, sun, false, &p), Vec3::ZERO);
        // Wood lit from behind gets nothing; a leaf transmits T/R of the colour.
        assert_eq!(local_light(&s, -sun, true, &p), Vec3::ZERO);
        let leaf = point(Vec3::Y, true);
        let t = local_light(&leaf, -sun, true, &p);
        let want = leaf.colour * Vec3::from_array(p.leaf_transmission) * 0.8;
        assert!((t - want).abs().max_element() < 1e-6);
    }

    #[test]
    fn specular_peaks_in_the_mirror_direction() {
        let p = ShadingParams::default();
        let mut s = point(Vec3::Y, true);
        s.colour = Vec3::ZERO;
        let sun = Vec3::new(0.6, 0.8, 0.0);
        s.view = Vec3::new(-0.6, 0.8, 0.0);
        let peak = local_light(&s, sun, true, &p);
        assert!((peak.x - p.leaf_specular.0).abs() < 1e-5);
        s.view = Vec3::new(0.6, 0.8, 0.0);
        let off = local_light(&s, sun, true, &p);
        let cos_vr = Vec3::new(-0.6, 0.8, 0.0).dot(s.view);
        assert!((off.x - p.leaf_specular.0 * cos_vr.powf(p.leaf_specular.1)).abs() < 1e-6);
    }

    #[test]
    fn transmission_inverts_table_1_g() {
        for g in [-0.333f32, -0.12, 0.0, 0.091, 0.5] {
            let tr = transmission_from_g([g; 3])[0];
            // g = (T - R) / (T + R) with R = 1, T = tr.
            assert!(((tr - 1.0) / (tr + 1.0) - g).abs() < 1e-6);
        }
    }

    #[test]
    fn linear_texture_matches_decoded_texels() {
        let px = vec![
            [0, 0, 64, 255],
            [255, 0, 64, 255],
            [0, 128, 64, 255],
            [255, 128, 64, 255],
        ];
        let t = Texture::new(2, 2, px, Wrap::Repeat);
        let lt = LinearTexture::new(&t);
        // Texel centres.
        let c = lt.sample(Vec2::new(0.75, 0.25));
        assert!((c.x - 1.0).abs() < 1e-6 && c.y.abs() < 1e-6);
        assert!((c.z - srgb_to_linear(64.0 / 255.0)).abs() < 1e-6);
        // Halfway between two texels (wrapping) is their mean.
        let m = lt.sample(Vec2::new(0.0, 0.25));
        assert!((m.x - 0.5).abs() < 1e-6);
        assert!(ShadingParams {
            indirect: f32::NAN,
            ..Default::default()
        }
        .validate()
        .unwrap_err()
        .contains("indirect"));
    }
}
