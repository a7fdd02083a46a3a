//! A spectral render's images: each band's linear image, filled from the renders of the
//! scene's band groups (three bands a render, [`sylva_geom::Bands::group`]), written as one
//! multi-layer OpenEXR (a layer per band) and a false-colour PNG of three chosen bands.

use std::path::{Path, PathBuf};

use sylva_geom::Bands;
use sylva_render::output::{encode_exr_layers, encode_png, OutputError};
use sylva_render::tonemap::{srgb8, ToneMap};
use sylva_render::{Frame, Mode};

/// Each band's linear image (the full mode: sun, LB light and sky), as the groups come in.
#[derive(Debug, Clone)]
pub struct BandImages {
    bands: Bands,
    width: u32,
    height: u32,
    layers: Vec<Option<Vec<f32>>>,
}

/// The files [`BandImages::write`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct WrittenBands {
    pub exr: PathBuf,
    pub png: PathBuf,
}

impl BandImages {
    pub fn new(bands: &Bands, width: u32, height: u32) -> BandImages {
        BandImages {
            bands: bands.clone(),
            width,
            height,
            layers: vec![None; bands.len()],
        }
    }

    /// Takes the bands of group `g` from its frame: band `group(g)[c]` is channel `c`.
    pub fn add_group(&mut self, g: usize, frame: &Frame) {
        assert_eq!(
            (frame.width, frame.height),
            (self.width, self.height),
            "one size for every group"
        );
        let full = frame.compose(Mode::Full);
        for (c, b) in self.bands.group(g).into_iter().enumerate() {
            if self.layers[b].is_none() {
                self.layers[b] = Some(full.iter().map(|p| p[c]).collect());
            }
        }
    }

    /// Band `name`'s image, once its group was added.
    pub fn band(&self, name: &str) -> Option<&[f32]> {
        let b = self.bands.names.iter().position(|n| n == name)?;
        self.layers[b].as_deref()
    }

    /// Whether every group was added.
    pub fn complete(&self) -> bool {
        self.layers.iter().all(Option::is_some)
    }

    /// The false-colour image: the bands of [`Bands::false_colour`] as red, green and blue,
    /// tone mapped together with `tm`.
    pub fn false_colour(&self, tm: &ToneMap) -> Vec<[u8; 3]> {
        let [r, g, b] = self.bands.false_colour.map(|k| {
            self.layers[k]
                .as_deref()
                .expect("every group added before the false colour")
        });
        let rgb: Vec<[f32; 3]> = (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect();
        let (ldr, _) = tm.apply(&rgb);
        ldr.into_iter().map(srgb8).collect()
    }

    /// `base.exr` (a layer per band, named as the band) and the false-colour `base` PNG, as
    /// one output set: both are replaced, or (on an error or Ctrl-C) neither.
    pub fn write(&self, base: &Path, tm: &ToneMap) -> Result<WrittenBands, OutputError> {
        let exr = base.with_extension("exr");
        let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
        set.plan(&[exr.clone(), base.to_path_buf()])?;
        let layers: Vec<(String, Vec<f32>)> = self
            .bands
            .names
            .iter()
            .zip(&self.layers)
            .map(|(n, l)| {
                let l = l.as_ref().expect("every group added before writing");
                (n.clone(), l.clone())
            })
            .collect();
        set.write_bytes(
            &exr,
            &encode_exr_layers(&exr, self.width, self.height, &layers)?,
        )?;
        let png = base.to_path_buf();
        set.write_bytes(
            &png,
            &encode_png(&png, self.width, self.height, &self.false_colour(tm))?,
        )?;
        set.commit()?;
        Ok(WrittenBands { exr, png })
    }

    /// "R = nir, G = red, B = green": what the false colour shows.
    pub fn false_colour_legend(&self) -> String {
        let n = |k: usize| self.bands.names[self.bands.false_colour[k]].as_str();
        format!("R = {}, G = {}, B = {}", n(0), n(1), n(2))
    }
}
