//! Spectral bands (a scene's `[bands]`): N named bands, each with its leaf reflectance and
//! transmittance, bark and soil albedo, sun irradiance and sky radiance, in place of the
//! default linear RGB. Everything downstream (the LB, both shaders, the tracer) works on
//! three channels, so bands are carried three at a time: band group `g` puts bands
//! `3g, 3g + 1, 3g + 2` into the red, green and blue channels of an otherwise unchanged
//! scene ([`crate::Scene::apply_band_group`]), and a band render is one render per group.

/// The most bands a scene may name: a hyperspectral sensor's few hundred, with room.
pub const MAX_BANDS: usize = 1024;

/// The scene's bands, validated ([`Bands::validate`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Bands {
    pub names: Vec<String>,
    /// Per band: a leaf's hemispherical reflectance and transmittance.
    pub leaf_reflectance: Vec<f32>,
    pub leaf_transmittance: Vec<f32>,
    /// Per band: the mean albedo of bark (the texture shapes its pattern) and of the soil.
    pub bark: Vec<f32>,
    pub soil: Vec<f32>,
    /// Per band: the sun's irradiance on a surface facing it, and the sky's radiance.
    pub sun: Vec<f32>,
    pub sky: Vec<f32>,
    /// The bands shown as red, green and blue in the false-colour image.
    pub false_colour: [usize; 3],
}

impl Bands {
    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Renders needed: one per three bands.
    pub fn groups(&self) -> usize {
        self.len().div_ceil(3)
    }

    /// The bands group `g` carries in red, green and blue; a last group of one or two bands
    /// repeats its last band in the spare channels.
    pub fn group(&self, g: usize) -> [usize; 3] {
        let first = 3 * g;
        let last = self.len() - 1;
        [0, 1, 2].map(|c| (first + c).min(last))
    }

    /// One-line errors: names unique and not empty, every list one value per band, values
    /// finite, albedos in [0, 1], `r + t ≤ 1`, the sun and sky ≥ 0, false colour of known
    /// bands.
    pub fn validate(&self) -> Result<(), String> {
        if self.names.is_empty() {
            return Err("names: at least one band".into());
        }
        if self.names.len() > MAX_BANDS {
            return Err(format!(
                "names: {} bands, at most {MAX_BANDS} (each group of three is a render)",
                self.names.len()
            ));
        }
        for (i, n) in self.names.iter().enumerate() {
            if n.trim().is_empty() {
                return Err(format!("names: band {} has an empty name", i + 1));
            }
            if self.names[..i].contains(n) {
                return Err(format!("names: '{n}' is named twice"));
            }
        }
        let n = self.len();
        let lists: [(&str, &[f32], f32); 6] = [
            ("leaf_reflectance", &self.leaf_reflectance, 1.0),
            ("leaf_transmittance", &self.leaf_transmittance, 1.0),
            ("bark", &self.bark, 1.0),
            ("soil", &self.soil, 1.0),
            ("sun", &self.sun, f32::INFINITY),
            ("sky", &self.sky, f32::INFINITY),
        ];
        for (key, values, max) in lists {
            if values.len() != n {
                return Err(format!(
                    "{key}: {} values for {n} bands ({}); give one per band",
                    values.len(),
                    self.names.join(", ")
                ));
            }
            for (v, name) in values.iter().zip(&self.names) {
                if !(v.is_finite() && *v >= 0.0 && *v <= max) {
                    let range = if max == 1.0 {
                        "0 to 1"
                    } else {
                        "finite and ≥ 0"
                    };
                    return Err(format!("{key}: {v} in band '{name}' must be {range}"));
                }
            }
        }
        for ((r, t), name) in self
            .leaf_reflectance
            .iter()
            .zip(&self.leaf_transmittance)
            .zip(&self.names)
        {
            if r + t > 1.0 {
                return Err(format!(
                    "leaf_reflectance + leaf_transmittance in band '{name}' is {r} + {t} > 1"
                ));
            }
        }
        if self.false_colour.iter().any(|&b| b >= n) {
            return Err("false_colour: a band that is not in names".into());
        }
        Ok(())
    }

    /// Per channel of group `g`, the value of `per_band`.
    pub fn channels(&self, g: usize, per_band: &[f32]) -> [f32; 3] {
        self.group(g).map(|b| per_band[b])
    }
}
