//! Reinhard et al.'s global tone-mapping operator (2002, eqs. 1-4; paper 000 §4.1) and sRGB
//! encoding.
//!
//! World luminance `L_w` is scaled by `key / L̄_w`, where `L̄_w` is the log-average luminance;
//! the scaled `L` is compressed by `L_d = L (1 + L / L_white²) / (1 + L)`, so `L_white` (in
//! scaled units) maps exactly to 1. Colours keep their ratios: `rgb_d = rgb · L_d / L_w`.
//!
//! The default `L_white` is the image's largest scaled colour value (any channel), not its
//! largest luminance: a saturated brightest colour (the blue sky, once measured leaves made
//! the sky the brightest thing in view) would otherwise map its luminance to 1 and its blue
//! channel above it, burning out as cyan-white.

use sylva_core::colour::{linear_to_srgb8, luminance};

/// `δ` of the log average: keeps black pixels from sending the average to zero.
const LOG_DELTA: f64 = 1e-6;

/// Parameters of the global operator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneMap {
    /// The key `a`: the scaled luminance the log-average maps to (0.18: "middle grey").
    pub key: f32,
    /// `L_white` in scaled units; `None` uses the largest scaled colour value of the image
    /// (any channel), so the brightest pixels keep their hue.
    pub white: Option<f32>,
}

impl Default for ToneMap {
    fn default() -> Self {
        ToneMap {
            key: 0.18,
            white: None,
        }
    }
}

/// What the operator measured on an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneStats {
    pub log_average: f32,
    pub white: f32,
}

/// `exp(mean(ln(δ + L)))` over the pixels, in f64 so large images add up exactly enough.
pub fn log_average_luminance(pixels: &[[f32; 3]]) -> f32 {
    if pixels.is_empty() {
        return 0.0;
    }
    let sum: f64 = pixels
        .iter()
        .map(|p| (LOG_DELTA + luminance(*p).max(0.0) as f64).ln())
        .sum();
    (sum / pixels.len() as f64).exp() as f32
}

/// What [`ToneMap::measure`] needs of a sequence of images, gathered one image at a time so
/// a sequence too large for memory gets one exposure.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ToneAccumulator {
    log_sum: f64,
    count: u64,
    max_value: f32,
}

/// What the default white point takes the maximum of: a pixel's largest channel where its
/// luminance is positive (the pixels the operator maps), else 0.
fn white_value(p: [f32; 3]) -> f32 {
    if luminance(p) > 0.0 {
        p[0].max(p[1]).max(p[2])
    } else {
        0.0
    }
}

impl ToneAccumulator {
    /// Adds an image's pixels (in the order of the sequence: the sum is the one a single
    /// pass over all of them makes).
    pub fn add(&mut self, pixels: &[[f32; 3]]) {
        for p in pixels {
            let l = luminance(*p);
            self.log_sum += (LOG_DELTA + l.max(0.0) as f64).ln();
            self.max_value = self.max_value.max(white_value(*p));
        }
        self.count += pixels.len() as u64;
    }
}

impl ToneMap {
    /// Checks the parameters: a clear message rather than a black or NaN image.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.key.is_finite() && self.key > 0.0) {
            return Err(format!("tone-mapping key {} must be positive", self.key));
        }
        if let Some(w) = self.white {
            if !(w.is_finite() && w > 0.0) {
                return Err(format!("tone-mapping white point {w} must be positive"));
            }
        }
        Ok(())
    }

    /// What the operator measures on `pixels`: the log-average and the white point.
    pub fn measure(&self, pixels: &[[f32; 3]]) -> ToneStats {
        let log_average = log_average_luminance(pixels);
        let scale = self.scale(log_average);
        let white = self.white.unwrap_or_else(|| {
            pixels
                .iter()
                .map(|p| white_value(*p) * scale)
                .fold(0.0f32, f32::max)
                .max(f32::MIN_POSITIVE)
        });
        ToneStats { log_average, white }
    }

    /// [`ToneMap::measure`] of the pixels `acc` was given, image by image, without holding
    /// them: the same statistics as measuring them all at once.
    pub fn measure_accumulated(&self, acc: &ToneAccumulator) -> ToneStats {
        let log_average = if acc.count == 0 {
            0.0
        } else {
            (acc.log_sum / acc.count as f64).exp() as f32
        };
        let scale = self.scale(log_average);
        // Scaling by a positive factor keeps the order of values (rounding is monotonic):
        // the brightest scaled value is the brightest value scaled.
        let white = self
            .white
            .unwrap_or_else(|| (acc.max_value * scale).max(f32::MIN_POSITIVE));
        ToneStats { log_average, white }
    }

    fn scale(&self, log_average: f32) -> f32 {
        if log_average > 0.0 {
            self.key / log_average
        } else {
            1.0
        }
    }

    /// Linear HDR pixels → display-linear pixels in [0, 1].
    pub fn apply(&self, pixels: &[[f32; 3]]) -> (Vec<[f32; 3]>, ToneStats) {
        let stats = self.measure(pixels);
        (self.apply_with(pixels, stats), stats)
    }

    /// Maps with the statistics of another image, so that several images (the comparison
    /// modes) share one exposure.
    pub fn apply_with(&self, pixels: &[[f32; 3]], stats: ToneStats) -> Vec<[f32; 3]> {
        let scale = self.scale(stats.log_average);
        let inv_white2 = 1.0 / (stats.white * stats.white);
        pixels
            .iter()
            .map(|p| {
                let lw = luminance(*p);
                // Also catches NaN.
                if lw.is_nan() || lw <= 0.0 {
                    return [0.0; 3];
                }
                let l = lw * scale;
                let ld = l * (1.0 + l * inv_white2) / (1.0 + l);
                let k = ld / lw;
                p.map(|c| (c * k).clamp(0.0, 1.0))
            })
            .collect()
    }
}

/// Display-linear [0, 1] → 8-bit sRGB, rounded to nearest.
pub fn srgb8(rgb: [f32; 3]) -> [u8; 3] {
    rgb.map(linear_to_srgb8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accumulated_statistics_are_those_of_all_pixels_at_once() {
        let images: Vec<Vec<[f32; 3]>> = (0..4)
            .map(|k| {
                (0..50)
                    .map(|i| {
                        let v = ((i * 7 + k * 13) % 23) as f32 * 0.37;
                        [v, 0.5 * v + k as f32, if i == 3 { f32::NAN } else { 0.1 }]
                    })
                    .collect()
            })
            .collect();
        let all: Vec<[f32; 3]> = images.iter().flatten().copied().collect();
        for tm in [
            ToneMap::default(),
            ToneMap {
                key: 0.3,
                white: Some(2.0),
            },
        ] {
            let mut acc = ToneAccumulator::default();
            for im in &images {
                acc.add(im);
            }
            assert_eq!(tm.measure_accumulated(&acc), tm.measure(&all));
        }
    }

    #[test]
    fn a_blue_sky_brightest_keeps_its_hue() {
        // Catalpa with measured leaves: the sky (radiance (0.55, 0.70, 0.95)) is the
        // brightest thing in view, over dark leaves and a grey ground. Its blue is 1.385 × its
        // luminance: with the white point at the largest luminance it would map above 1 and
        // clip (cyan-white); with the largest channel its colour ratios survive, blue just
        // below 1 (`M (1 + L / M²) / (1 + L)` ≤ 1 for a pixel's luminance L ≤ its largest
        // channel M ≤ 1, scaled).
        let sky = [0.55f32, 0.70, 0.95];
        let mut px = vec![sky; 37];
        px.extend(vec![[0.15f32, 0.15, 0.13]; 33]);
        px.extend(vec![[0.02f32, 0.05, 0.015]; 30]);
        let (out, st) = ToneMap::default().apply(&px);
        let s = out[0];
        assert!(s.iter().all(|&c| c < 1.0 + 1e-6), "{s:?}");
        assert!(s[2] > 0.95, "{s:?}");
        for c in 0..2 {
            assert!(close(s[c] / s[2], sky[c] / sky[2], 1e-5), "{s:?}");
        }
        // The luminance white point (still available as `white`) clips that blue.
        let lum_white = luminance(sky) * 0.18 / st.log_average;
        let clipped = ToneMap {
            white: Some(lum_white),
            ..ToneMap::default()
        }
        .apply(&px)
        .0[0];
        assert_eq!(clipped[2], 1.0);
        assert!(
            clipped[1] / clipped[2] > sky[1] / sky[2] + 0.05,
            "{clipped:?}"
        );
    }

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol * b.abs().max(1e-6)
    }

    #[test]
    fn log_average_of_two_values_is_their_geometric_mean() {
        // Grey pixels: luminance equals the value.
        let px = [[0.02f32; 3], [2.0; 3]];
        let want = (0.02f64 * 2.0).sqrt() as f32;
        assert!(close(log_average_luminance(&px), want, 1e-4));
    }

    #[test]
    fn uniform_image_maps_to_key_compressed() {
        // L̄ = L, so every scaled luminance is the key a; with white = a (the maximum),
        // L_d = a (1 + a / a²) / (1 + a) = 1.
        let px = vec![[3.0f32; 3]; 16];
        let (out, st) = ToneMap::default().apply(&px);
        assert!(close(st.white, 0.18, 1e-5));
        assert!(out.iter().all(|p| p.iter().all(|&c| close(c, 1.0, 1e-5))));
        // With an explicit white of 1: L_d = a (1 + a) / (1 + a) = a.
        let tm = ToneMap {
            key: 0.18,
            white: Some(1.0),
        };
        let (out, _) = tm.apply(&px);
        assert!(out.iter().all(|p| p.iter().all(|&c| close(c, 0.18, 1e-5))));
    }

    #[test]
    fn two_level_image_matches_the_closed_form() {
        let (lo, hi) = (0.1f32, 10.0f32);
        let px = [[lo; 3], [hi; 3]];
        let tm = ToneMap {
            key: 0.36,
            white: Some(2.0),
        };
        let (out, st) = tm.apply(&px);
        let avg = (lo * hi).sqrt();
        assert!(close(st.log_average, avg, 1e-4));
        for (p, lw) in out.iter().zip([lo, hi]) {
            let l = 0.36 * lw / avg;
            let ld = l * (1.0 + l / 4.0) / (1.0 + l);
            assert!(close(p[0], ld.min(1.0), 1e-4), "{} vs {}", p[0], ld);
        }
    }

    #[test]
    fn hue_is_kept_and_black_stays_black() {
        let px = [[0.5f32, 0.25, 0.125], [1.0, 1.0, 1.0]];
        let (out, _) = ToneMap::default().apply(&px);
        assert!(out[0][0] < 1.0);
        assert!(close(out[0][1] / out[0][0], 0.5, 1e-5));
        assert!(close(out[0][2] / out[0][0], 0.25, 1e-5));
        let (out, _) = ToneMap::default().apply(&[[0.0; 3], [1.0, 0.5, 0.2]]);
        assert_eq!(out[0], [0.0; 3]);
        assert!(out.iter().flatten().all(|&c| (0.0..=1.0).contains(&c)));
    }

    #[test]
    fn bad_parameters_are_named() {
        let e = ToneMap {
            key: f32::NAN,
            white: None,
        }
        .validate()
        .unwrap_err();
        assert!(e.contains("key"));
        assert!(ToneMap {
            key: 0.18,
            white: Some(-1.0)
        }
        .validate()
        .unwrap_err()
        .contains("white"));
    }
}
