//! Shading (SPEC §2, paper 000 §3, docs/light.md): the light at a hit, split into the parts
//! the comparison modes of 000 Fig. 2 recombine. Two light models ([`Light`]):
//!
//! * **Physical** (default). A surface of colour `c` reflects `R = c ⊙ reflect` and (leaves)
//!   transmits `T = c ⊙ transmit` ([`sylva_geom::Optics`]), both Lambertian, the same
//!   material the LB medium and the Mitsuba export use. Local light: the sun's `R (N·L)` on
//!   the lit side, `T |N·L|` through a leaf lit from behind, zero where the shadow ray is
//!   blocked. Indirect light: a sheet in the LB light `u` (scattered sunlight, sky and ground;
//!   fluence in units of `E0`) sends `(R + T) u / 4` to either side (bark `R u / 4`), times
//!   [`ShadingParams::indirect`] (1). The ground reflects its albedo of the sun and of the
//!   sky's light that reaches it.
//! * **Paper** (000). Diffuse `k_d (N·L)` and specular `k_s (V·R)^s`; a leaf lit from behind
//!   transmits `k_d · T/R · |N·L|` with `T/R = (1 + g) / (1 - g)` of the LB preset's `g`;
//!   indirect light is the normalised LB total times `k_d`, the sun colour and
//!   [`ShadingParams::indirect`]; the ground takes a constant sky ambient.
//! * Albedo: what a constant ambient multiplies (the "ambient" mode): physical, the response
//!   to a uniform unit radiance (`R + T`, bark `R`, ground `ρ`); paper, `k_d` × sun colour.

use glam::{Vec2, Vec3};
use sylva_core::colour::srgb_to_linear;
use sylva_geom::{Material, MaterialKind, Model, Optics, Texture, Wrap};
use sylva_lb::light::SHEET_RADIANCE_PER_FLUENCE;

use sylva_light::lighting::Light;

/// Shading constants that the papers leave open (documented in docs/render.md).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadingParams {
    /// Sun irradiance on a surface facing it (luminance units; the sun colour has luminance 1).
    pub sun_irradiance: f32,
    /// The light model.
    pub light: Light,
    /// Scale of the indirect light (the LB light, or on plants the gathered light; 1: as
    /// computed).
    pub indirect: f32,
    /// Physical light: final-gather rays per camera sample on a plant ([`crate::gather`]), up to
    /// [`crate::gather::MAX_GATHER_RAYS`]; 0: the LB light at the point itself (faster, less
    /// exact).
    pub gather_rays: u32,
    /// Paper light: constant sky light on the ground, as a fraction of the sun irradiance.
    pub sky_ambient: f32,
    /// Paper light: specular coefficient and exponent of leaves (waxy cuticle) and of bark.
    pub leaf_specular: (f32, f32),
    pub wood_specular: (f32, f32),
    /// Paper light: transmittance / reflectance per colour of leaves (from the LB preset's
    /// `g`).
    pub leaf_transmission: [f32; 3],
}

impl Default for ShadingParams {
    fn default() -> Self {
        ShadingParams {
            sun_irradiance: 1.0,
            light: Light::Physical,
            indirect: 1.0,
            gather_rays: crate::gather::DEFAULT_GATHER_RAYS,
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
        if self.gather_rays > crate::gather::MAX_GATHER_RAYS {
            return Err(format!(
                "gather rays {} must be 0 to {} per sample",
                self.gather_rays,
                crate::gather::MAX_GATHER_RAYS
            ));
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
    pub optics: Optics,
}

impl ShadeMaterial {
    pub fn new(m: &Material) -> ShadeMaterial {
        ShadeMaterial {
            leaf: m.kind == MaterialKind::Leaf,
            base: Vec3::from_array(m.base_color),
            texture: m.texture.as_deref().map(LinearTexture::new),
            optics: m.optics,
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
    /// Reflectance and transmittance as factors of the colour (physical light).
    pub optics: Optics,
}

impl SurfacePoint {
    /// Lambertian reflectance `R`.
    pub fn reflectance(&self) -> Vec3 {
        self.colour * Vec3::from_array(self.optics.reflect)
    }

    /// Lambertian transmittance `T` (zero for opaque surfaces).
    pub fn transmittance(&self) -> Vec3 {
        if self.leaf {
            self.colour * Vec3::from_array(self.optics.transmit)
        } else {
            Vec3::ZERO
        }
    }

    /// What a uniform unit radiance from all directions makes the surface send back (the
    /// ambient mode's albedo): physical `R + T`; paper `k_d`.
    pub fn albedo(&self, light: Light) -> Vec3 {
        match light {
            Light::Physical => self.reflectance() + self.transmittance(),
            Light::Paper => self.colour,
        }
    }
}

/// The indirect light a surface sends to the viewer from the LB light `lb` at its point
/// (physical: LB units, coloured; paper: normalised, times `sun`, the sun's colour).
pub fn indirect_light(s: &SurfacePoint, lb: Vec3, sun: Vec3, p: &ShadingParams) -> Vec3 {
    match p.light {
        Light::Physical => {
            lb * s.albedo(Light::Physical) * (SHEET_RADIANCE_PER_FLUENCE * p.indirect)
        }
        Light::Paper => lb * s.colour * sun * p.indirect,
    }
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
    if p.light == Light::Physical {
        return if cos > 0.0 {
            s.reflectance() * cos
        } else {
            s.transmittance() * (-cos)
        };
    }
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
            optics: if leaf {
                Optics::leaf([0.5, 1.5, 0.25])
            } else {
                Optics::OPAQUE
            },
        }
    }

    fn paper() -> ShadingParams {
        ShadingParams {
            light: Light::Paper,
            indirect: 0.5,
            ..Default::default()
        }
    }

    #[test]
    fn physical_leaves_reflect_r_and_transmit_t() {
        let p = ShadingParams::default();
        assert_eq!(p.light, Light::Physical);
        let sun = Vec3::new(0.6, 0.8, 0.0);
        let leaf = point(Vec3::Y, true);
        let (r, t) = (leaf.colour, leaf.colour * Vec3::new(0.5, 1.5, 0.25));
        // Front-lit: R cos, no specular lobe, whatever the view.
        for view in [Vec3::Y, Vec3::new(-0.6, 0.8, 0.0)] {
            let s = SurfacePoint { view, ..leaf };
            let l = local_light(&s, sun, true, &p);
            assert!((l - r * 0.8).abs().max_element() < 1e-6, "{l}");
        }
        // Back-lit: T |cos|; in shadow nothing.
        let l = local_light(&leaf, -sun, true, &p);
        assert!((l - t * 0.8).abs().max_element() < 1e-6, "{l}");
        assert_eq!(local_light(&leaf, sun, false, &p), Vec3::ZERO);
        // Bark: R cos in front, nothing behind.
        let bark = point(Vec3::Y, false);
        assert!(
            (local_light(&bark, sun, true, &p) - bark.colour * 0.8)
                .abs()
                .max_element()
                < 1e-6
        );
        assert_eq!(local_light(&bark, -sun, true, &p), Vec3::ZERO);
        // Indirect: (R + T) u / 4, bark R u / 4; the sun's colour is in u already.
        let u = Vec3::new(0.4, 0.8, 1.2);
        let i = indirect_light(&leaf, u, Vec3::splat(9.0), &p);
        assert!((i - (r + t) * u * 0.25).abs().max_element() < 1e-6, "{i}");
        let i = indirect_light(&bark, u, Vec3::splat(9.0), &p);
        assert!(
            (i - bark.colour * u * 0.25).abs().max_element() < 1e-6,
            "{i}"
        );
        assert_eq!(leaf.albedo(Light::Physical), r + t);
        assert_eq!(leaf.albedo(Light::Paper), leaf.colour);
        // An isolated leaf under a sky of radiance L alone (ground black): the LB value is
        // 2 L, the leaf sends (R + T) L / 2, the orientation average of R L (facing the sky)
        // and T L (facing the ground).
        let sky = Vec3::new(0.55, 0.7, 0.95);
        let i = indirect_light(&leaf, 2.0 * sky, Vec3::ONE, &p);
        assert!((i - (r + t) * sky * 0.5).abs().max_element() < 1e-6);
    }

    #[test]
    fn diffuse_follows_lambert_and_shadow_zeroes_it() {
        let p = ShadingParams {
            leaf_specular: (0.0, 1.0),
            wood_specular: (0.0, 1.0),
            ..paper()
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
        let p = paper();
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
