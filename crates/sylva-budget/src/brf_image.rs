//! The BRF as an image (issue 29 item 3): the plot seen from one view direction, each pixel
//! the BRF of the stretch of the plot's top it covers. The photons' local estimates towards
//! the view ([`crate::photons`]) are binned by where their ray to the sky leaves the top
//! (across the cyclic sides); a pixel of area A / P of the top (P pixels) gets
//! P · Σ π p_v T_v / (N cos θ_v) over the estimates leaving through it, so the mean of the
//! pixels of a cyclic plot is the view's BRF. In an isolated plot the estimates that leave
//! through a side fall outside the image, which then shows the top's share only.
//!
//! Columns run along +x and rows along +z, as the plot seen from above: the image is the
//! top face orthographically, whatever the view's zenith (the pixels are cells of the top,
//! not of the view's image plane, so a tilted view is not foreshortened).
//!
//! Tallies are fixed-point integers added atomically, so the image of a seed is the same
//! whatever the thread count and the order the chunks finish in.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::angles::ViewAngles;
use crate::BudgetError;
use glam::Vec3;

/// The longest side an image may have.
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Fixed-point scale of the tallies: an estimate (at most 1 / cos θ_v, θ_v < 90°) is kept
/// to 2^-32, far below the noise of any pixel.
const SCALE: f64 = 4_294_967_296.0;

/// What image to make: the view and the longer side in pixels (the other follows the
/// plot's aspect, so pixels are square on the ground).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrfImageSpec {
    pub view: ViewAngles,
    pub side: u32,
}

impl BrfImageSpec {
    pub fn validate(&self) -> Result<(), BudgetError> {
        self.view.validate_view()?;
        if !(1..=MAX_IMAGE_SIDE).contains(&self.side) {
            return Err(BudgetError::invalid(
                "--brf-image-size",
                self.side,
                format!("pixels along the plot's longer side, 1 to {MAX_IMAGE_SIDE}"),
            ));
        }
        Ok(())
    }

    /// Width and height over a plot of half sizes `half` (x, z), metres.
    pub fn size(&self, half: [f64; 2]) -> (u32, u32) {
        let [x, z] = half;
        let (s, long) = (f64::from(self.side), x.max(z));
        let w = ((s * x / long).round() as u32).max(1);
        let h = ((s * z / long).round() as u32).max(1);
        (w, h)
    }

    /// The memory the images of `bands` bands need: the tallies of one band and the
    /// finished images of all.
    pub fn memory_bytes(&self, half: [f64; 2], bands: usize) -> u64 {
        let (w, h) = self.size(half);
        let pixels = u64::from(w) * u64::from(h);
        pixels * 8 + pixels * 4 * bands as u64
    }
}

/// One band's BRF image: `pixels[row * width + col]`, row 0 at the plot's −z side,
/// column 0 at its −x side.
#[derive(Debug, Clone, PartialEq)]
pub struct BrfImage {
    pub view: ViewAngles,
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<f32>,
}

impl BrfImage {
    /// The mean over the pixels: the view's BRF, in a cyclic plot.
    pub fn mean(&self) -> f64 {
        self.pixels.iter().map(|&p| f64::from(p)).sum::<f64>() / self.pixels.len() as f64
    }
}

/// The running sums of one band's image while its photons are traced.
pub(crate) struct ImageTally {
    width: u32,
    height: u32,
    /// The plot's top: `[-hx, hx] × [-hz, hz]` at `y = top`.
    hx: f32,
    hz: f32,
    top: f32,
    sums: Vec<AtomicU64>,
    /// A pixel's sum passed 2^64 (some 4 × 10^9 estimates of 1 in one pixel).
    overflowed: AtomicBool,
}

impl ImageTally {
    pub(crate) fn new(spec: &BrfImageSpec, half: [f64; 2], top: f64) -> ImageTally {
        let (width, height) = spec.size(half);
        ImageTally {
            width,
            height,
            hx: half[0] as f32,
            hz: half[1] as f32,
            top: top as f32,
            sums: (0..u64::from(width) * u64::from(height))
                .map(|_| AtomicU64::new(0))
                .collect(),
            overflowed: AtomicBool::new(false),
        }
    }

    /// Adds `estimate` (π p_v T_v / cos θ_v) for a ray to the sky along `v` that left the
    /// plot's box at `exit`: at the top, or through an isolated plot's side (then continued
    /// to the top's plane, outside the image).
    pub(crate) fn add(&self, exit: Vec3, v: Vec3, estimate: f64) {
        let p = exit + v * ((self.top - exit.y) / v.y).max(0.0);
        let u = (p.x + self.hx) / (2.0 * self.hx);
        let w = (p.z + self.hz) / (2.0 * self.hz);
        if !(0.0..=1.0).contains(&u) || !(0.0..=1.0).contains(&w) {
            return;
        }
        let col = ((u * self.width as f32) as u32).min(self.width - 1);
        let row = ((w * self.height as f32) as u32).min(self.height - 1);
        let i = (row * self.width + col) as usize;
        let add = (estimate * SCALE).round() as u64;
        let before = self.sums[i].fetch_add(add, Ordering::Relaxed);
        if before.checked_add(add).is_none() {
            self.overflowed.store(true, Ordering::Relaxed);
        }
    }

    /// The image of `photons` photons: each pixel P · Σ / N; refused where a pixel's sum
    /// wrapped.
    pub(crate) fn finish(self, view: ViewAngles, photons: u64) -> Result<BrfImage, BudgetError> {
        if self.overflowed.into_inner() {
            return Err(BudgetError::invalid(
                "--brf-image-size",
                self.width.max(self.height),
                format!(
                    "with {photons} photons a pixel's tally overflowed: use more pixels or fewer photons"
                ),
            ));
        }
        let p = self.sums.len() as f64;
        Ok(BrfImage {
            view,
            width: self.width,
            height: self.height,
            pixels: self
                .sums
                .into_iter()
                .map(|s| (s.into_inner() as f64 / SCALE * p / photons as f64) as f32)
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photons::{trace_budget, BudgetConfig, SunAngles};
    use crate::{CanopySpec, Stand};

    /// Crowns of bright leaves over a black soil, seen from straight above, `cyclic` or not.
    fn crowns(cyclic: bool) -> (CanopySpec, Stand, sylva_trace::SceneAccel) {
        let spec = CanopySpec::parse(&format!(
            "[plot]\nsize = [10.0, 8.0]\ncyclic = {cyclic}\n\
             [crowns]\nradius = 1.0\ncentre_height = 2.0\nlai = 3.0\ncover = 0.3\n\
             [leaves]\nsize = 0.1\n\
             [[bands]]\nname = \"nir\"\nleaf_reflectance = 0.45\nleaf_transmittance = 0.4\nsoil_albedo = 0.0\n"
        ))
        .unwrap();
        let stand = Stand::build(&spec).unwrap();
        let accel =
            sylva_trace::SceneAccel::from_parts(&stand.models, &stand.instances, None).unwrap();
        (spec, stand, accel)
    }

    fn config(view: ViewAngles, side: u32) -> BudgetConfig {
        BudgetConfig {
            photons: 60_000,
            seed: 3,
            sun: SunAngles {
                zenith_deg: 20.0,
                azimuth_deg: 0.0,
            },
            views: vec![view],
            image: Some(BrfImageSpec { view, side }),
        }
    }

    const NADIR: ViewAngles = ViewAngles {
        zenith_deg: 0.0,
        azimuth_deg: 0.0,
    };

    #[test]
    fn the_nadir_image_shows_the_crowns_where_they_stand_and_averages_to_the_brf() {
        let (spec, stand, accel) = crowns(true);
        let b = trace_budget(
            &stand,
            &accel,
            &spec.bands,
            true,
            &config(NADIR, 40),
            &|_| {},
        )
        .unwrap()
        .remove(0);
        let img = b.image.as_ref().unwrap();
        // Square pixels: 40 along the 10 m side, 32 along the 8 m one.
        assert_eq!((img.width, img.height), (40, 32));
        let brf = b.brf[0].brf.value;
        assert!(
            (img.mean() - brf).abs() < 1e-6 * brf,
            "image mean {} against the BRF {brf}",
            img.mean()
        );
        // A black soil: only leaves send light up, so a pixel whose vertical column misses
        // every crown is black, and one over a crown's middle is lit. Column x, row z.
        let centres: Vec<[f64; 2]> = stand.instances[..stand.placed]
            .iter()
            .map(|i| [f64::from(i.position.x), f64::from(i.position.z)])
            .collect();
        let (mut lit, mut dark) = (0, 0);
        for row in 0..img.height {
            for col in 0..img.width {
                let p = [
                    -5.0 + (f64::from(col) + 0.5) * 0.25,
                    -4.0 + (f64::from(row) + 0.5) * 0.25,
                ];
                let d = centres
                    .iter()
                    .map(|&c| sylva_grow::stand::plot_distance(p, c, [10.0, 8.0], true))
                    .fold(f64::INFINITY, f64::min);
                let v = img.pixels[(row * img.width + col) as usize];
                if d > 1.0 + 0.25 + 0.1 {
                    assert_eq!(v, 0.0, "pixel ({col}, {row}), {d:.2} m from any crown");
                    dark += 1;
                } else if d < 0.5 {
                    assert!(v > 0.0, "pixel ({col}, {row}) over a crown is black");
                    lit += 1;
                }
            }
        }
        assert!(
            lit > 20 && dark > 200,
            "{lit} lit, {dark} dark pixels checked"
        );
    }

    #[test]
    fn an_isolated_plot_shows_only_what_leaves_through_its_top() {
        // Towards a grazing view some light leaves an isolated plot through its sides: it
        // counts in the BRF but falls outside the image of the top.
        let view = ViewAngles {
            zenith_deg: 70.0,
            azimuth_deg: 0.0,
        };
        let (spec, stand, accel) = crowns(false);
        let b = trace_budget(
            &stand,
            &accel,
            &spec.bands,
            false,
            &config(view, 16),
            &|_| {},
        )
        .unwrap()
        .remove(0);
        let (mean, brf) = (b.image.as_ref().unwrap().mean(), b.brf[0].brf.value);
        assert!(mean > 0.0 && mean < 0.95 * brf, "image {mean}, BRF {brf}");
    }

    #[test]
    fn a_tally_that_overflows_is_an_error_not_a_wrapped_image() {
        let spec = BrfImageSpec {
            view: NADIR,
            side: 1,
        };
        let tally = ImageTally::new(&spec, [1.0, 1.0], 2.0);
        let up = Vec3::Y;
        tally.add(Vec3::new(0.0, 2.0, 0.0), up, 0.5);
        let img = ImageTally::new(&spec, [1.0, 1.0], 2.0);
        img.add(Vec3::new(0.0, 2.0, 0.0), up, 0.5);
        let one = img.finish(NADIR, 1).unwrap();
        assert_eq!(one.pixels, [0.5]);
        // 2^64 / 2^32 = 2^32 in one pixel wraps the sum.
        tally.add(Vec3::new(0.0, 2.0, 0.0), up, 4_294_967_296.0);
        let e = tally.finish(NADIR, 1).unwrap_err().to_string();
        assert!(e.contains("overflowed") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn sizes_and_bad_settings() {
        let spec = BrfImageSpec {
            view: NADIR,
            side: 100,
        };
        assert_eq!(spec.size([50.0, 25.0]), (100, 50));
        assert_eq!(spec.size([1.0, 1000.0]), (1, 100));
        for bad in [
            BrfImageSpec { side: 0, ..spec },
            BrfImageSpec {
                side: MAX_IMAGE_SIDE + 1,
                ..spec
            },
            BrfImageSpec {
                view: ViewAngles {
                    zenith_deg: 90.0,
                    azimuth_deg: 0.0,
                },
                ..spec
            },
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("--brf") && !e.contains('\n'), "{e}");
        }
    }
}
