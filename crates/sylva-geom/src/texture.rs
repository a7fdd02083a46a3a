//! RGBA8 textures with nearest and bilinear sampling. Leaf shapes live in alpha, and
//! [`is_opaque`] is the one rule that says which texels are leaf: the voxelizer counts only
//! opaque texels, the tracer's alpha test discards hits on the others, and LB cache keys hash
//! the opaque/transparent pattern.

use glam::Vec4;
use sylva_core::colour::srgb_to_linear;

/// Alpha byte from which a texel is opaque: `alpha / 255 ≥ 0.5`.
pub const OPAQUE_ALPHA: u8 = 128;

/// Whether an RGBA texel is opaque (alpha ≥ [`OPAQUE_ALPHA`]): THE texel opacity rule.
#[inline]
pub fn is_opaque(texel: [u8; 4]) -> bool {
    texel[3] >= OPAQUE_ALPHA
}

/// How coordinates outside [0, 1] are mapped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrap {
    Repeat,
    Clamp,
}

impl Wrap {
    /// Texel index `i` (any integer) mapped into `0..n`.
    #[inline]
    pub fn apply(self, i: i64, n: u32) -> u32 {
        match self {
            Wrap::Repeat => i.rem_euclid(n as i64) as u32,
            Wrap::Clamp => i.clamp(0, n as i64 - 1) as u32,
        }
    }
}

/// Texel lookup.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    Nearest,
    Bilinear,
}

/// The texel `(x, y)` of a `width × height` grid nearest `(u, v)` (the one whose square holds
/// it), with `wrap`; non-finite coordinates give the texel at (0, 0), as [`Texture::sample`]
/// does. For structures that keep a texture's layout without its pixels (the tracer's alpha
/// bitmasks).
#[inline]
pub fn nearest_texel_coords(u: f32, v: f32, width: u32, height: u32, wrap: Wrap) -> (u32, u32) {
    let (u, v) = if u.is_finite() && v.is_finite() {
        (u, v)
    } else {
        (0.0, 0.0)
    };
    (
        wrap.apply((u * width as f32).floor() as i64, width),
        wrap.apply((v * height as f32).floor() as i64, height),
    )
}

/// An 8-bit RGBA image; texel (x, y) sits at u = (x + 0.5) / width, v = (y + 0.5) / height,
/// row 0 at v = 0. Colours are sRGB-encoded as stored; alpha is linear coverage.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[u8; 4]>,
    /// How the texture is meant to be addressed (leaves clamp, bark repeats).
    pub wrap: Wrap,
}

impl Texture {
    /// A texture from `pixels` (row-major, `width * height` of them).
    pub fn new(width: u32, height: u32, pixels: Vec<[u8; 4]>, wrap: Wrap) -> Texture {
        assert!(width > 0 && height > 0, "texture must not be empty");
        assert_eq!(pixels.len(), (width * height) as usize, "pixel count");
        Texture {
            width,
            height,
            pixels,
            wrap,
        }
    }

    /// Fills each texel from `f(u, v)` evaluated at its centre.
    pub fn from_fn(
        width: u32,
        height: u32,
        wrap: Wrap,
        f: impl Fn(f32, f32) -> [u8; 4],
    ) -> Texture {
        let mut pixels = Vec::with_capacity((width * height) as usize);
        for y in 0..height {
            for x in 0..width {
                let u = (x as f32 + 0.5) / width as f32;
                let v = (y as f32 + 0.5) / height as f32;
                pixels.push(f(u, v));
            }
        }
        Texture::new(width, height, pixels, wrap)
    }

    pub fn texel(&self, x: u32, y: u32) -> [u8; 4] {
        self.pixels[(y * self.width + x) as usize]
    }

    fn texel_f(&self, x: i64, y: i64, wrap: Wrap) -> Vec4 {
        let t = self.texel(wrap.apply(x, self.width), wrap.apply(y, self.height));
        Vec4::new(t[0] as f32, t[1] as f32, t[2] as f32, t[3] as f32) / 255.0
    }

    /// RGBA in [0, 1] at (u, v) with the texture's own wrap mode.
    pub fn sample(&self, u: f32, v: f32, filter: Filter) -> Vec4 {
        self.sample_with(u, v, filter, self.wrap)
    }

    /// RGBA in [0, 1] at (u, v). Non-finite coordinates sample at (0, 0).
    pub fn sample_with(&self, u: f32, v: f32, filter: Filter, wrap: Wrap) -> Vec4 {
        let (u, v) = if u.is_finite() && v.is_finite() {
            (u, v)
        } else {
            (0.0, 0.0)
        };
        let fx = u * self.width as f32;
        let fy = v * self.height as f32;
        match filter {
            Filter::Nearest => self.texel_f(fx.floor() as i64, fy.floor() as i64, wrap),
            Filter::Bilinear => {
                let (gx, gy) = (fx - 0.5, fy - 0.5);
                let (x0, y0) = (gx.floor(), gy.floor());
                let (tx, ty) = (gx - x0, gy - y0);
                let (x0, y0) = (x0 as i64, y0 as i64);
                let a = self.texel_f(x0, y0, wrap);
                let b = self.texel_f(x0 + 1, y0, wrap);
                let c = self.texel_f(x0, y0 + 1, wrap);
                let d = self.texel_f(x0 + 1, y0 + 1, wrap);
                a.lerp(b, tx).lerp(c.lerp(d, tx), ty)
            }
        }
    }

    /// Coverage at (u, v), nearest texel.
    pub fn alpha(&self, u: f32, v: f32) -> f32 {
        self.sample(u, v, Filter::Nearest).w
    }

    /// Whether the nearest texel at (u, v) is opaque ([`is_opaque`]): the alpha test.
    pub fn is_opaque_at(&self, u: f32, v: f32) -> bool {
        is_opaque(self.nearest_texel(u, v))
    }

    /// The texel nearest (u, v) with the texture's wrap mode ([`nearest_texel_coords`]).
    pub fn nearest_texel(&self, u: f32, v: f32) -> [u8; 4] {
        let (x, y) = nearest_texel_coords(u, v, self.width, self.height, self.wrap);
        self.texel(x, y)
    }

    /// Fraction of opaque texels.
    pub fn opaque_fraction(&self) -> f64 {
        self.pixels.iter().filter(|p| is_opaque(**p)).count() as f64 / self.pixels.len() as f64
    }

    /// Mean colour (RGB in [0, 1], as stored: sRGB-encoded) over opaque texels; black when
    /// none are.
    pub fn mean_opaque_color(&self) -> [f32; 3] {
        let mut sum = [0f64; 3];
        let mut n = 0usize;
        for p in self.pixels.iter().filter(|p| is_opaque(**p)) {
            for c in 0..3 {
                sum[c] += p[c] as f64 / 255.0;
            }
            n += 1;
        }
        if n == 0 {
            return [0.0; 3];
        }
        sum.map(|s| (s / n as f64) as f32)
    }

    /// [`Texture::mean_opaque_color`] decoded to linear RGB: a textured material's
    /// representative colour.
    pub fn mean_opaque_linear(&self) -> [f32; 3] {
        self.mean_opaque_color().map(srgb_to_linear)
    }

    /// Mean linear colour over opaque texels (each texel decoded, then averaged): the
    /// mean albedo of the surface the texture paints; black when no texel is opaque.
    pub fn mean_opaque_albedo(&self) -> [f32; 3] {
        let mut sum = [0f64; 3];
        let mut n = 0usize;
        for p in self.pixels.iter().filter(|p| is_opaque(**p)) {
            for c in 0..3 {
                sum[c] += srgb_to_linear(p[c] as f32 / 255.0) as f64;
            }
            n += 1;
        }
        if n == 0 {
            return [0.0; 3];
        }
        sum.map(|s| (s / n as f64) as f32)
    }

    pub fn memory_bytes(&self) -> u64 {
        self.pixels.capacity() as u64 * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        // 2×2: black, white / white, black; alpha 0 on the first texel only.
        Texture::new(
            2,
            2,
            vec![
                [0, 0, 0, 0],
                [255, 255, 255, 255],
                [255, 255, 255, 255],
                [0, 0, 0, 255],
            ],
            Wrap::Repeat,
        )
    }

    #[test]
    fn nearest_and_wrap() {
        let t = checker();
        assert_eq!(t.sample(0.25, 0.25, Filter::Nearest).x, 0.0);
        assert_eq!(t.sample(0.75, 0.25, Filter::Nearest).x, 1.0);
        // Repeat: u = 1.25 is u = 0.25; clamp: u = 1.25 is the last column.
        assert_eq!(t.sample(1.25, 0.25, Filter::Nearest).x, 0.0);
        assert_eq!(
            t.sample_with(1.25, 0.25, Filter::Nearest, Wrap::Clamp).x,
            1.0
        );
        assert_eq!(t.alpha(0.25, 0.25), 0.0);
        assert_eq!(t.alpha(0.25, 0.75), 1.0);
        assert_eq!(t.sample(f32::NAN, 0.3, Filter::Nearest).w, 0.0);
    }

    #[test]
    fn bilinear_interpolates_between_centres() {
        let t = checker();
        // Midway between texel centres (0,0) and (1,0): half black, half white.
        let s = t.sample_with(0.5, 0.25, Filter::Bilinear, Wrap::Clamp);
        assert!((s.x - 0.5).abs() < 1e-6, "{s}");
        // At a texel centre bilinear equals nearest.
        let c = t.sample_with(0.75, 0.75, Filter::Bilinear, Wrap::Clamp);
        assert!(c.x.abs() < 1e-6 && (c.w - 1.0).abs() < 1e-6);
        assert_eq!(t.opaque_fraction(), 0.75);
    }

    #[test]
    fn opacity_rule_is_alpha_at_least_half() {
        assert!(!is_opaque([255, 255, 255, 127]));
        assert!(is_opaque([0, 0, 0, 128]));
        // The nearest-texel test agrees with the coverage `alpha` for every byte and wrap.
        for wrap in [Wrap::Repeat, Wrap::Clamp] {
            let t = Texture::from_fn(16, 16, wrap, |u, v| {
                [0, 0, 0, (u * 16.0) as u8 * 16 + (v * 16.0) as u8]
            });
            for i in -20..40 {
                for j in -20..40 {
                    let (u, v) = (i as f32 * 0.031, j as f32 * 0.029);
                    let want = t.alpha(u, v) >= 0.5;
                    assert_eq!(t.is_opaque_at(u, v), want, "{wrap:?} {u} {v}");
                }
            }
            assert_eq!(t.is_opaque_at(f32::NAN, 0.3), t.alpha(f32::NAN, 0.3) >= 0.5);
        }
    }
}
