//! Leaf and bark textures generated in code: leaf outlines in alpha, colour and veins in RGB;
//! bark patterns that repeat. No files are read, so the built-in species need no downloads.

use std::f32::consts::PI;
use sylva_geom::{Texture, Wrap};

/// Leaf outlines (the `LeafShape` parameter of species files selects one by index).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LeafOutline {
    Elliptic,
    /// Three main lobes and two small ones, toothed (red maple).
    Palmate,
    /// Widest below the middle, doubly toothed (birch, beech).
    OvateSerrate,
    /// Heart-shaped with a notch at the base (catalpa).
    Cordate,
    /// Five leaflets from one point (buckeye).
    PalmatelyCompound,
    /// A fan of needles (pine fascicle).
    Needles,
    /// Leaflets in pairs along a rachis with a terminal one (rose).
    Pinnate,
    Round,
    Lanceolate,
    Oblong,
}

impl LeafOutline {
    /// Arbaro's `LeafShape` index → outline.
    pub fn from_index(i: u32) -> LeafOutline {
        use LeafOutline::*;
        [
            Elliptic,
            Palmate,
            OvateSerrate,
            Cordate,
            PalmatelyCompound,
            Needles,
            Pinnate,
            Round,
            Lanceolate,
            Oblong,
        ][(i as usize).min(9)]
    }

    /// Whether leaf-local point (x across in [-1, 1], y along in [0, 1]) is inside the leaf.
    pub fn contains(self, x: f32, y: f32) -> bool {
        use LeafOutline::*;
        let ax = x.abs();
        match self {
            Elliptic => ax * ax + (2.0 * y - 1.0).powi(2) < 0.95,
            Round => x * x + (2.0 * y - 1.0).powi(2) < 0.9,
            Lanceolate => ax < 0.95 * (PI * y).sin().powf(1.3) * (1.0 - 0.4 * y),
            Oblong => {
                let dy = ((2.0 * y - 1.0).abs() - 0.6).max(0.0) / 0.35;
                ax < 0.85 * (1.0 - dy * dy).max(0.0).sqrt()
            }
            OvateSerrate => {
                if y <= 0.02 || y >= 0.99 {
                    return petiole(ax, y);
                }
                let yy = (y - 0.02) / 0.97;
                // Widest below the middle, tapering to a pointed tip.
                let w = (PI * yy.powf(0.75)).sin().max(0.0).powf(0.8) * (1.0 - 0.5 * yy.powi(3));
                let teeth = 1.0 - 0.07 * (yy * 22.0 * PI).sin().abs() * (1.0 - yy * 0.5);
                ax < 0.95 * w * teeth || petiole(ax, y)
            }
            Cordate => {
                let w = (PI * y.powf(0.85)).sin().max(0.0).powf(0.55) * (1.0 + 0.15 * (1.0 - y));
                let notch = y < 0.14 * (1.0 - ax / 0.35).max(0.0);
                (ax < 0.93 * w.min(1.07) && !notch) || petiole(ax, y)
            }
            Palmate => {
                // Polar outline about the petiole tip.
                let cy = 0.28;
                let (dx, dy) = (x, (y - cy) * 2.0);
                let r = (dx * dx + dy * dy).sqrt();
                let phi = dx.atan2(dy); // 0 = towards the tip
                let lobes: [(f32, f32); 5] = [
                    (0.0, 1.44),
                    (0.95, 1.2),
                    (-0.95, 1.2),
                    (1.9, 0.6),
                    (-1.9, 0.6),
                ];
                let mut reach: f32 = 0.3;
                for (a, len) in lobes {
                    let d = phi - a;
                    let c = (d * 2.4).cos().max(0.0);
                    reach = reach.max(len * c.powf(1.6));
                }
                let teeth = 1.0 - 0.08 * (phi * 24.0).sin().abs();
                r < reach * teeth * 0.95 || petiole(ax, y)
            }
            PalmatelyCompound => {
                let oy = 0.1;
                let leaflets: [(f32, f32); 5] = [
                    (0.0, 0.88),
                    (0.72, 0.8),
                    (-0.72, 0.8),
                    (1.4, 0.6),
                    (-1.4, 0.6),
                ];
                let (dx, dy) = (x * 0.5, y - oy);
                leaflets.iter().any(|&(a, len)| {
                    let along = dx * a.sin() + dy * a.cos();
                    let across = dx * a.cos() - dy * a.sin();
                    let t = along / len;
                    (0.04..1.0).contains(&t)
                        && across.abs() < 0.15 * len * (PI * t.powf(0.8)).sin().powf(0.9)
                }) || (y < oy && ax < 0.04)
            }
            Needles => {
                let (dx, dy) = (x * 0.5, y);
                (0..9).any(|k| {
                    let a = (k as f32 / 8.0 - 0.5) * 0.7;
                    let along = dx * a.sin() + dy * a.cos();
                    let across = dx * a.cos() - dy * a.sin();
                    (0.0..0.98).contains(&along) && across.abs() < 0.012 + 0.006 * (1.0 - along)
                })
            }
            Pinnate => {
                let rachis = ax < 0.035 && y < 0.85;
                let mut leaf = false;
                for (k, &py) in [0.22f32, 0.45, 0.66].iter().enumerate() {
                    let len = 0.42 - 0.05 * k as f32;
                    for side in [-1.0f32, 1.0] {
                        let a = side * 1.0; // leaflets angle ~57° off the rachis
                        let (dx, dy) = (x * 0.5, y - py);
                        let along = dx * a.sin() + dy * a.cos();
                        let across = dx * a.cos() - dy * a.sin();
                        let t = along / (len * 0.5);
                        let serr = 1.0 - 0.12 * (t * 9.0 * PI).sin().abs();
                        if (0.02..1.0).contains(&t)
                            && across.abs() < 0.09 * (PI * t).sin().powf(0.7) * serr
                        {
                            leaf = true;
                        }
                    }
                }
                let (dx, dy) = (x * 0.5, y - 0.76);
                let t = dy / 0.23;
                let terminal = (0.0..1.0).contains(&t) && dx.abs() < 0.1 * (PI * t).sin().powf(0.7);
                rachis || leaf || terminal
            }
        }
    }
}

fn petiole(ax: f32, y: f32) -> bool {
    y < 0.06 && ax < 0.04
}

/// Integer hash → [0, 1).
fn hash(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Smooth value noise in [0, 1), periodic with `fx` × `fy` cells over the unit square.
fn noise(u: f32, v: f32, fx: i32, fy: i32, seed: u32) -> f32 {
    let (x, y) = (u * fx as f32, v * fy as f32);
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (x - x0, y - y0);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (x0 as i32, y0 as i32);
    let h = |i: i32, j: i32| hash(i.rem_euclid(fx), j.rem_euclid(fy), seed);
    let a = h(ix, iy) + (h(ix + 1, iy) - h(ix, iy)) * sx;
    let b = h(ix, iy + 1) + (h(ix + 1, iy + 1) - h(ix, iy + 1)) * sx;
    a + (b - a) * sy
}

fn mix(a: [u8; 3], b: [u8; 3], t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    [0, 1, 2].map(|i| (a[i] as f32 + (b[i] as f32 - a[i] as f32) * t).round() as u8)
}

fn scale(c: [u8; 3], f: f32) -> [u8; 3] {
    c.map(|v| (v as f32 * f).round().clamp(0.0, 255.0) as u8)
}

/// Leaf texture: `outline` in alpha, `color` (sRGB) with lighter veins and mottling in RGB.
pub fn leaf_texture(outline: LeafOutline, color: [u8; 3], seed: u32) -> Texture {
    const N: u32 = 128;
    let vein = scale(color, 1.25);
    Texture::from_fn(N, N, Wrap::Clamp, |u, v| {
        let x = 2.0 * u - 1.0;
        let inside = outline.contains(x, v);
        let mottle = 0.88 + 0.24 * noise(u, v, 8, 8, seed);
        let mut c = scale(color, mottle);
        // Midrib and side veins.
        let midrib = x.abs() < 0.025;
        let side = ((v - x.abs() * 0.6) * 9.0).fract() < 0.08 && x.abs() > 0.05;
        if midrib || side {
            c = mix(c, vein, 0.6);
        }
        if !inside {
            // Transparent texels keep the leaf colour so bilinear filtering has no dark fringe.
            return [color[0], color[1], color[2], 0];
        }
        [c[0], c[1], c[2], 255]
    })
}

/// Bark patterns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BarkPattern {
    /// Vertical furrows (maple, buckeye, catalpa).
    Furrowed,
    /// Smooth with faint mottling (beech).
    Smooth,
    /// Light with dark horizontal lenticels (paper birch).
    Birch,
    /// Irregular plates (pine).
    Plated,
}

/// Opaque repeating bark texture: `base` colour (sRGB) with `pattern` in a darker tone.
pub fn bark_texture(pattern: BarkPattern, base: [u8; 3], seed: u32) -> Texture {
    let dark = scale(base, 0.55);
    Texture::from_fn(64, 128, Wrap::Repeat, |u, v| {
        let n = noise(u, v, 16, 8, seed);
        let c = match pattern {
            BarkPattern::Furrowed => {
                let furrow = ((u * 12.0 + 0.6 * noise(u, v, 4, 16, seed + 1)) * PI)
                    .sin()
                    .abs();
                mix(base, dark, (1.0 - furrow).powi(3) * 1.2 + 0.2 * n)
            }
            BarkPattern::Smooth => mix(base, dark, 0.35 * noise(u, v, 6, 12, seed + 2)),
            BarkPattern::Birch => {
                let lenticel = noise(u, v, 6, 48, seed + 3) > 0.72;
                if lenticel {
                    scale(base, 0.3)
                } else {
                    mix(base, dark, 0.2 * n)
                }
            }
            BarkPattern::Plated => {
                let cell = noise(u, v, 8, 12, seed + 4);
                let crack = (cell * 10.0).fract() < 0.15;
                if crack {
                    dark
                } else {
                    mix(base, scale(base, 1.2), n)
                }
            }
        };
        [c[0], c[1], c[2], 255]
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_outline_is_a_leaf_not_a_square() {
        for i in 0..10 {
            let o = LeafOutline::from_index(i);
            let t = leaf_texture(o, [60, 120, 40], 1);
            let f = t.opaque_fraction();
            // Needles and leaflets are thin; everything else covers a good part but not the whole quad.
            let lo = match o {
                LeafOutline::Needles => 0.03,
                LeafOutline::Pinnate => 0.1,
                _ => 0.2,
            };
            assert!(f > lo && f < 0.9, "{o:?}: opaque fraction {f}");
            // Corners of the quad are transparent: the shape is in alpha.
            assert_eq!(t.texel(0, 127)[3], 0, "{o:?}");
            assert_eq!(t.texel(127, 127)[3], 0, "{o:?}");
            let c = t.mean_opaque_color();
            assert!(c[1] > c[0] && c[1] > c[2], "{o:?} is not green: {c:?}");
        }
    }

    #[test]
    fn bark_is_opaque_and_tiles() {
        let t = bark_texture(BarkPattern::Birch, [225, 220, 210], 3);
        assert_eq!(t.opaque_fraction(), 1.0);
        assert_eq!(t.wrap, Wrap::Repeat);
        let c = t.mean_opaque_color();
        assert!(c[0] > 0.6, "birch bark should be light: {c:?}");
    }
}
