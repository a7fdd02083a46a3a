//! The BRF image's files (`sylva budget --brf-image`): an OpenEXR of one layer per band and
//! a grey PNG per band, written as one output set.

use std::path::{Path, PathBuf};

use sylva_budget::BrfImage;
use sylva_render::output::{encode_exr_layers, encode_png, OutputError};

/// The files [`BrfImageFiles::write`] wrote and the BRF each PNG shows as white.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenBrfImages {
    pub exr: PathBuf,
    /// Per band: its PNG and the BRF drawn white.
    pub pngs: Vec<(PathBuf, f32)>,
}

/// The BRF image's files, planned before the photons are traced (so a bad output path
/// fails at once): `out` as an OpenEXR of one layer per band (the BRF, linear, named as the
/// band) and beside it `out`'s stem + `_BAND.png` per band, grey from BRF 0 (black) to the
/// band's 99.5th-percentile pixel (white, so that a few noisy pixels do not darken the
/// rest), sRGB-encoded. One output set: every file is replaced, or none.
pub struct BrfImageFiles {
    set: sylva_core::OutputSet,
    exr: PathBuf,
    bands: Vec<String>,
    pngs: Vec<PathBuf>,
}

impl BrfImageFiles {
    pub fn plan(out: &Path, bands: &[&str]) -> Result<BrfImageFiles, OutputError> {
        let exr = out.with_extension("exr");
        let stem = exr
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "brf".into());
        let pngs: Vec<PathBuf> = bands
            .iter()
            .map(|name| exr.with_file_name(format!("{stem}_{name}.png")))
            .collect();
        let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
        let mut paths = vec![exr.clone()];
        paths.extend(pngs.iter().cloned());
        set.plan(&paths)?;
        Ok(BrfImageFiles {
            set,
            exr,
            bands: bands.iter().map(|b| b.to_string()).collect(),
            pngs,
        })
    }

    /// Writes the images, one per planned band, in the planned order.
    pub fn write(mut self, images: &[&BrfImage]) -> Result<WrittenBrfImages, OutputError> {
        assert_eq!(images.len(), self.pngs.len(), "an image per planned band");
        let Some(first) = images.first() else {
            return Ok(WrittenBrfImages {
                exr: self.exr,
                pngs: Vec::new(),
            });
        };
        let (w, h) = (first.width, first.height);
        let layers: Vec<(String, Vec<f32>)> = images
            .iter()
            .zip(&self.bands)
            .map(|(img, band)| (band.clone(), img.pixels.clone()))
            .collect();
        self.set
            .write_bytes(&self.exr, &encode_exr_layers(&self.exr, w, h, &layers)?)?;
        let mut pngs = Vec::new();
        for (img, png) in images.iter().zip(&self.pngs) {
            let white = white_point(&img.pixels);
            let grey: Vec<[u8; 3]> = img
                .pixels
                .iter()
                .map(|&p| {
                    let g = sylva_core::colour::linear_to_srgb8((p / white).clamp(0.0, 1.0));
                    [g, g, g]
                })
                .collect();
            self.set.write_bytes(png, &encode_png(png, w, h, &grey)?)?;
            pngs.push((png.clone(), white));
        }
        self.set.commit()?;
        Ok(WrittenBrfImages {
            exr: self.exr,
            pngs,
        })
    }
}

/// The 99.5th-percentile pixel (at least a tiny positive value, so a black image stays
/// black).
fn white_point(pixels: &[f32]) -> f32 {
    let mut v: Vec<f32> = pixels.iter().copied().filter(|p| p.is_finite()).collect();
    if v.is_empty() {
        return 1.0;
    }
    let k = ((v.len() - 1) as f64 * 0.995).round() as usize;
    let (_, x, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    x.max(1e-6)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sylva_budget::ViewAngles;

    const NADIR: ViewAngles = ViewAngles {
        zenith_deg: 0.0,
        azimuth_deg: 0.0,
    };

    #[test]
    fn the_written_exr_holds_a_layer_per_band_and_a_png_each() {
        let dir = tempfile::tempdir().unwrap();
        let img = |v: f32| BrfImage {
            view: NADIR,
            width: 3,
            height: 2,
            pixels: vec![0.0, v, 2.0 * v, 0.5, 0.25, v],
        };
        let (a, b) = (img(0.1), img(0.4));
        let w = BrfImageFiles::plan(&dir.path().join("out.exr"), &["red", "nir"])
            .unwrap()
            .write(&[&a, &b])
            .unwrap();
        let pngs: Vec<_> = w.pngs.iter().map(|(p, _)| p.clone()).collect();
        assert_eq!(
            pngs,
            [
                dir.path().join("out_red.png"),
                dir.path().join("out_nir.png")
            ]
        );
        assert_eq!(w.pngs[1].1, 0.8, "white is the brightest pixel here");
        let exr = sylva_render::output::read_exr_layers(&w.exr).unwrap();
        assert_eq!(exr.layers[1].1, b.pixels);
        assert_eq!(exr.names(), ["red", "nir"]);
        let png = image::open(&pngs[0]).unwrap().to_rgb8();
        assert_eq!((png.width(), png.height()), (3, 2));
        assert_eq!(png.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(
            png.get_pixel(0, 1).0,
            [255, 255, 255],
            "0.5, the brightest red pixel"
        );
    }
}
