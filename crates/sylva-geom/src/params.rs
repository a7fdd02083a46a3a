//! Scattering parameters per colour, the shipped presets (SPEC §1) and the Knapp & Carter
//! derivation of 000 §3.

use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum ParamError {
    #[error("{name} = {value} is not a finite number")]
    NotFinite { name: String, value: f64 },
    #[error("{name} = {value} must lie in [{lo}, {hi}]")]
    OutOfRange {
        name: String,
        value: f64,
        lo: f64,
        hi: f64,
    },
    #[error(
        "σ_t = σ_a + σ_s = {0} must lie in (0, 1]: the lattice update is stable only for σ_t ≤ 1"
    )]
    Extinction(f64),
    #[error("unknown preset '{0}': expected one of leaf, dogrose, cloud, pmma")]
    UnknownPreset(String),
    #[error("forward + backward scattering fs + bs = 0: g is undefined")]
    NoScattering,
}

/// Scattering coefficients of one colour (one wavelength band).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourParams {
    /// Absorption coefficient σ_a per lattice step.
    pub sigma_a: f64,
    /// Scattering coefficient σ_s per lattice step.
    pub sigma_s: f64,
    /// Henyey-Greenstein asymmetry g ∈ [-1, 1].
    pub g: f64,
}

impl ColourParams {
    pub fn new(sigma_a: f64, sigma_s: f64, g: f64) -> Result<Self, ParamError> {
        let p = ColourParams {
            sigma_a,
            sigma_s,
            g,
        };
        p.validate("")?;
        Ok(p)
    }

    pub fn sigma_t(&self) -> f64 {
        self.sigma_a + self.sigma_s
    }

    /// Checks finiteness and ranges; `label` prefixes the parameter names in errors.
    pub fn validate(&self, label: &str) -> Result<(), ParamError> {
        for (name, value, lo, hi) in [
            ("sigma_a", self.sigma_a, 0.0, 1.0),
            ("sigma_s", self.sigma_s, 0.0, 1.0),
            ("g", self.g, -1.0, 1.0),
        ] {
            let name = format!("{label}{name}");
            if !value.is_finite() {
                return Err(ParamError::NotFinite { name, value });
            }
            if !(lo..=hi).contains(&value) {
                return Err(ParamError::OutOfRange {
                    name,
                    value,
                    lo,
                    hi,
                });
            }
        }
        let t = self.sigma_t();
        if t <= 0.0 || t > 1.0 + 1e-12 {
            return Err(ParamError::Extinction(t));
        }
        Ok(())
    }
}

/// Names of the colours, in storage order.
pub const COLOUR_NAMES: [&str; 3] = ["red", "green", "blue"];

/// The full medium description the solver needs.
#[derive(Debug, Clone, PartialEq)]
pub struct MediumParams {
    /// Per-colour coefficients (R, G, B).
    pub colours: [ColourParams; 3],
    /// Zero `f_0` on green (leaf) sites after every step: the visible light a leaf absorbs is
    /// lost (000 §3). On for every preset: the cloud's and the plastic's σ_a (002 §3.2.1,
    /// Table 2: albedo 0.99) are absorbed too; kept in `f_0`, the absorbed part would re-enter
    /// through `Ω_i0` and the medium would lose no light (`sylva lb --keep-f0` does that).
    pub zero_f0_on_green: bool,
    /// Zero `f_0` on brown (wood) sites too. The papers are silent; bark absorbs visible light
    /// and does not re-emit it, so the default is `true`.
    pub zero_f0_on_brown: bool,
    /// A site is brown when its wood fraction exceeds this (000 §3: "a significant portion").
    pub brown_threshold: f64,
    /// Per-colour coefficients of brown (wood) sites; `None`: the green ones with g = -1
    /// (000 §3). The physical model (docs/light.md) gives bark its own albedo.
    pub brown: Option<[ColourParams; 3]>,
}

impl MediumParams {
    /// The coefficients brown sites use for colour `c`.
    pub fn brown_colour(&self, c: usize) -> ColourParams {
        match &self.brown {
            Some(b) => b[c],
            None => ColourParams {
                g: -1.0,
                ..self.colours[c]
            },
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        for (c, name) in self.colours.iter().zip(COLOUR_NAMES) {
            c.validate(&format!("{name} "))?;
        }
        if let Some(b) = &self.brown {
            for (c, name) in b.iter().zip(COLOUR_NAMES) {
                c.validate(&format!("brown {name} "))?;
            }
        }
        let t = self.brown_threshold;
        if !t.is_finite() {
            return Err(ParamError::NotFinite {
                name: "brown_threshold".into(),
                value: t,
            });
        }
        if !(0.0..=1.0).contains(&t) {
            return Err(ParamError::OutOfRange {
                name: "brown_threshold".into(),
                value: t,
                lo: 0.0,
                hi: 1.0,
            });
        }
        Ok(())
    }
}

/// The parameter sets SPEC §1 ships.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    /// Forest leaves, 000 Table 1.
    Leaf,
    /// The dogrose plant, 002 Table 1.
    Dogrose,
    /// A grey cloud, 002 §3.2.1.
    Cloud,
    /// Polymethyl methacrylate, 002 Table 2.
    Pmma,
}

impl Preset {
    pub const ALL: [Preset; 4] = [Preset::Leaf, Preset::Dogrose, Preset::Cloud, Preset::Pmma];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Leaf => "leaf",
            Preset::Dogrose => "dogrose",
            Preset::Cloud => "cloud",
            Preset::Pmma => "pmma",
        }
    }

    pub fn source(self) -> &'static str {
        match self {
            Preset::Leaf => "000 Table 1 (Knapp & Carter leaves)",
            Preset::Dogrose => "002 Table 1",
            Preset::Cloud => "002 §3.2.1",
            Preset::Pmma => "002 Table 2",
        }
    }

    pub fn parse(s: &str) -> Result<Preset, ParamError> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| ParamError::UnknownPreset(s.to_string()))
    }

    pub fn params(self) -> MediumParams {
        let plant = |g: [f64; 3]| {
            let sa = [0.109, 0.091, 0.118];
            [0, 1, 2].map(|c| ColourParams {
                sigma_a: sa[c],
                sigma_s: 1.0 - sa[c],
                g: g[c],
            })
        };
        let (colours, zero_f0) = match self {
            Preset::Leaf => (plant([-0.120, 0.091, -0.333]), true),
            Preset::Dogrose => (plant([-0.231, 0.103, -0.750]), true),
            // 002 §3.2.1: σ_a and σ_s "together give a relatively high scattering albedo,
            // σ_s/σ_t = 0.99": the absorbed part is lost, as on leaves. Kept in f_0 it would
            // re-enter through Ω_i0 and make the cloud conservative (albedo 1), which the
            // Mitsuba reference measures as 1.33× the light of the albedo-0.99 cloud
            // (docs/media.md, "Against Mitsuba").
            Preset::Cloud => (
                [ColourParams {
                    sigma_a: 0.008,
                    sigma_s: 0.792,
                    g: 0.9,
                }; 3],
                true,
            ),
            // 002 Table 2's σ_a = 0.01 is absorbed as the cloud's is (albedo 0.99).
            Preset::Pmma => (
                [0.80, -0.88, -0.88].map(|g| ColourParams {
                    sigma_a: 0.01,
                    sigma_s: 0.99,
                    g,
                }),
                true,
            ),
        };
        MediumParams {
            colours,
            zero_f0_on_green: zero_f0,
            zero_f0_on_brown: true,
            brown_threshold: 0.5,
            brown: None,
        }
    }
}

/// 000 eq. 10: `g = (fs - bs) / (fs + bs)` from the forward (transmitted) and backward
/// (reflected) scattering fractions of Knapp & Carter.
pub fn g_from_forward_backward(fs: f64, bs: f64) -> Result<f64, ParamError> {
    for (name, value) in [("fs", fs), ("bs", bs)] {
        if !value.is_finite() {
            return Err(ParamError::NotFinite {
                name: name.into(),
                value,
            });
        }
        if value < 0.0 {
            return Err(ParamError::OutOfRange {
                name: name.into(),
                value,
                lo: 0.0,
                hi: f64::INFINITY,
            });
        }
    }
    if fs + bs == 0.0 {
        return Err(ParamError::NoScattering);
    }
    Ok((fs - bs) / (fs + bs))
}

/// 000 §3: Knapp & Carter absorptance scaled by 0.125 gives σ_a, and σ_s = 1 - σ_a.
pub fn leaf_params_from_measurements(
    absorptance: f64,
    forward: f64,
    backward: f64,
) -> Result<ColourParams, ParamError> {
    const SCALE: f64 = 0.125;
    let sigma_a = absorptance * SCALE;
    ColourParams::new(
        sigma_a,
        1.0 - sigma_a,
        g_from_forward_backward(forward, backward)?,
    )
}

/// Changes to a preset's parameters asked for on a command line (`sylva lb solve`): σ_a,
/// σ_s and g each as one value for every colour or `R,G,B`, and the f_0 and wood switches.
#[derive(Debug, Clone, PartialEq)]
pub struct MediumOverrides {
    /// `--sigma-a`; σ_s follows it as in 000 (σ_s = 1 - σ_a) unless given too.
    pub sigma_a: Option<String>,
    /// `--sigma-s`.
    pub sigma_s: Option<String>,
    /// `--g`.
    pub g: Option<String>,
    /// Keep f_0 on green sites (a conservative medium).
    pub keep_f0: bool,
    /// Do not zero f_0 on brown sites.
    pub brown_keeps_f0: bool,
    pub brown_threshold: f64,
}

/// A parameter override that is not one number or three.
#[derive(Debug, Error, PartialEq)]
pub enum OverrideError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("--{flag} '{text}': expected a number or three comma-separated numbers")]
    NotNumbers {
        flag: &'static str,
        text: String,
        #[source]
        source: std::num::ParseFloatError,
    },
    #[error("--{flag} '{text}': expected one value or three (R,G,B), got {count}")]
    Count {
        flag: &'static str,
        text: String,
        count: usize,
    },
}

/// Parses `V` or `R,G,B` (flag `--flag`) into three values.
pub fn per_colour(flag: &'static str, text: &str) -> Result<[f64; 3], OverrideError> {
    let v: Vec<f64> = text
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|source| OverrideError::NotNumbers {
            flag,
            text: text.to_string(),
            source,
        })?;
    match v.as_slice() {
        [a] => Ok([*a; 3]),
        [r, g, b] => Ok([*r, *g, *b]),
        _ => Err(OverrideError::Count {
            flag,
            text: text.to_string(),
            count: v.len(),
        }),
    }
}

impl MediumOverrides {
    /// Preset `preset`'s parameters with these changes, validated.
    pub fn apply(&self, preset: &str) -> Result<MediumParams, OverrideError> {
        let mut m = Preset::parse(preset)?.params();
        if let Some(s) = &self.sigma_a {
            for (colour, value) in m.colours.iter_mut().zip(per_colour("sigma-a", s)?) {
                colour.sigma_a = value;
                if self.sigma_s.is_none() {
                    colour.sigma_s = 1.0 - value;
                }
            }
        }
        if let Some(s) = &self.sigma_s {
            for (colour, value) in m.colours.iter_mut().zip(per_colour("sigma-s", s)?) {
                colour.sigma_s = value;
            }
        }
        if let Some(s) = &self.g {
            for (colour, value) in m.colours.iter_mut().zip(per_colour("g", s)?) {
                colour.g = value;
            }
        }
        if self.keep_f0 {
            m.zero_f0_on_green = false;
        }
        if self.brown_keeps_f0 {
            m.zero_f0_on_brown = false;
        }
        m.brown_threshold = self.brown_threshold;
        m.validate()?;
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn knapp_carter_reproduces_table_1() {
        // 000 Table 1: fs = (0.055, 0.150, 0.020), bs = (0.070, 0.125, 0.040),
        // g = (-0.120, 0.091, -0.333) to the three digits printed.
        let fs = [0.055, 0.150, 0.020];
        let bs = [0.070, 0.125, 0.040];
        let leaf = Preset::Leaf.params();
        for c in 0..3 {
            let g = g_from_forward_backward(fs[c], bs[c]).unwrap();
            assert!((g - leaf.colours[c].g).abs() < 5e-4, "colour {c}: {g}");
        }
        // Absorptance 0.872 (87.2 %, a typical red-band leaf) scales to σ_a = 0.109.
        let p = leaf_params_from_measurements(0.872, 0.055, 0.070).unwrap();
        assert!((p.sigma_a - 0.109).abs() < 1e-12);
        assert!((p.sigma_s - 0.891).abs() < 1e-12);
    }

    #[test]
    fn presets_are_valid_and_parse() {
        for p in Preset::ALL {
            p.params().validate().unwrap();
            assert_eq!(Preset::parse(p.name()).unwrap(), p);
        }
        assert_eq!(
            Preset::parse("fog"),
            Err(ParamError::UnknownPreset("fog".into()))
        );
        // 000 §3: a plant medium scatters all it does not absorb, σ_s = 1 - σ_a.
        for p in [Preset::Leaf, Preset::Dogrose] {
            for c in p.params().colours {
                assert!((c.sigma_a + c.sigma_s - 1.0).abs() < 1e-12, "{p:?}: {c:?}");
            }
        }
    }

    #[test]
    fn bad_values_are_named() {
        let e = ColourParams::new(f64::NAN, 0.5, 0.0).unwrap_err();
        assert!(e.to_string().contains("sigma_a"), "{e}");
        let e = ColourParams::new(0.1, 0.5, 1.5).unwrap_err();
        assert!(e.to_string().contains("g = 1.5"), "{e}");
        assert!(matches!(
            ColourParams::new(0.6, 0.6, 0.0),
            Err(ParamError::Extinction(_))
        ));
        assert!(matches!(
            ColourParams::new(0.0, 0.0, 0.0),
            Err(ParamError::Extinction(_))
        ));
        assert_eq!(
            g_from_forward_backward(0.0, 0.0),
            Err(ParamError::NoScattering)
        );
    }

    /// σ_s follows σ_a (σ_s = 1 - σ_a) unless given too; per-colour values land per colour;
    /// a count other than one or three, or a non-number, is refused with the flag named.
    #[test]
    fn overrides_change_the_preset_per_colour() {
        let none = MediumOverrides {
            sigma_a: None,
            sigma_s: None,
            g: None,
            keep_f0: false,
            brown_keeps_f0: false,
            brown_threshold: 0.5,
        };
        assert_eq!(none.apply("leaf").unwrap(), Preset::Leaf.params());
        let a = MediumOverrides {
            sigma_a: Some("0.2".into()),
            g: Some("0.1,0.2,0.3".into()),
            keep_f0: true,
            ..none.clone()
        };
        let m = a.apply("leaf").unwrap();
        for (c, g) in m.colours.iter().zip([0.1, 0.2, 0.3]) {
            assert_eq!((c.sigma_a, c.sigma_s, c.g), (0.2, 0.8, g));
        }
        assert!(!m.zero_f0_on_green && m.zero_f0_on_brown);
        let both = MediumOverrides {
            sigma_s: Some("0.3".into()),
            ..a.clone()
        };
        assert_eq!(both.apply("leaf").unwrap().colours[1].sigma_s, 0.3);
        let e = per_colour("sigma-a", "1,2").unwrap_err();
        assert_eq!(
            e.to_string(),
            "--sigma-a '1,2': expected one value or three (R,G,B), got 2"
        );
        assert!(matches!(
            per_colour("g", "x"),
            Err(OverrideError::NotNumbers { flag: "g", .. })
        ));
        let unstable = MediumOverrides {
            sigma_s: Some("0.9".into()),
            ..a
        };
        assert!(matches!(
            unstable.apply("leaf"),
            Err(OverrideError::Param(ParamError::Extinction(_)))
        ));
    }
}
