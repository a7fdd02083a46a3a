//! Weber & Penn tree parameters with the names and defaults of the Arbaro program.
//!
//! General parameters use Arbaro's names (`Shape`, `BaseSize`, ...); per-level parameters are
//! written with the level digit in place of Weber & Penn's `n` (`0Length`, `1DownAngle`, ...),
//! as in Arbaro's species files. Levels 0 (trunk) to 3 exist.

use std::fmt;

/// Range and kind of one parameter.
#[derive(Debug, Clone, Copy)]
pub struct ParamSpec {
    pub name: &'static str,
    pub default: f64,
    pub min: f64,
    pub max: f64,
    pub integer: bool,
    pub doc: &'static str,
}

/// A rejected parameter.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("unknown parameter '{0}'")]
    Unknown(String),
    #[error("parameter '{name}' = {value} is not a finite number")]
    NotFinite { name: String, value: f64 },
    #[error("parameter '{name}' = {value} is outside [{min}, {max}]")]
    OutOfRange {
        name: String,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("parameter '{name}' = {value} must be a whole number")]
    NotInteger { name: String, value: f64 },
}

macro_rules! param_struct {
    ($struct:ident, $specs:ident, $( $field:ident : $name:literal = $default:expr, [$min:expr, $max:expr], $int:expr, $doc:literal; )*) => {
        /// Parameter values; see the table of specs for names, ranges and defaults.
        #[derive(Debug, Clone, PartialEq, serde::Serialize)]
        pub struct $struct {
            $( #[doc = $doc] pub $field: f64, )*
        }

        pub const $specs: &[ParamSpec] = &[
            $( ParamSpec { name: $name, default: $default, min: $min, max: $max, integer: $int, doc: $doc }, )*
        ];

        impl Default for $struct {
            fn default() -> Self {
                $struct { $( $field: $default, )* }
            }
        }

        impl $struct {
            fn field_mut(&mut self, name: &str) -> Option<&mut f64> {
                match name {
                    $( $name => Some(&mut self.$field), )*
                    _ => None,
                }
            }

            fn field(&self, name: &str) -> Option<f64> {
                match name {
                    $( $name => Some(self.$field), )*
                    _ => None,
                }
            }
        }
    };
}

param_struct!(GeneralParams, GENERAL_SPECS,
    shape: "Shape" = 0.0, [0.0, 8.0], true, "Crown shape: 0 conical, 1 spherical, 2 hemispherical, 3 cylindrical, 4 tapered cylindrical, 5 flame, 6 inverse conical, 7 tend flame, 8 envelope";
    base_size: "BaseSize" = 0.25, [0.0, 1.0], false, "Fraction of the trunk without branches";
    scale: "Scale" = 10.0, [0.001, 1000.0], false, "Tree size in metres";
    scale_v: "ScaleV" = 0.0, [0.0, 1000.0], false, "Variation of Scale";
    z_scale: "ZScale" = 1.0, [0.001, 100.0], false, "Vertical stretch of the whole tree";
    z_scale_v: "ZScaleV" = 0.0, [0.0, 100.0], false, "Variation of ZScale";
    levels: "Levels" = 3.0, [1.0, 4.0], true, "Levels of recursion: 1 = trunk only";
    ratio: "Ratio" = 0.015, [0.000001, 1.0], false, "Trunk radius / trunk length";
    ratio_power: "RatioPower" = 1.2, [-5.0, 5.0], false, "How child radius falls with child length";
    lobes: "Lobes" = 0.0, [0.0, 20.0], true, "Lobes of the trunk cross-section";
    lobe_depth: "LobeDepth" = 0.0, [0.0, 10.0], false, "Depth of the trunk lobes";
    flare: "Flare" = 0.5, [-1.0, 10.0], false, "Widening of the trunk base";
    leaves: "Leaves" = 0.0, [-10000.0, 10000.0], false, "Leaves per last-level stem (sign chooses Arbaro's fan arrangement; its size is used)";
    leaf_shape: "LeafShape" = 0.0, [0.0, 9.0], true, "Leaf outline used for species files (0 elliptic, 1 palmate, 2 ovate serrate, 3 cordate, 4 palmately compound, 5 needles, 6 pinnate, 7 round, 8 lanceolate, 9 oblong)";
    leaf_scale: "LeafScale" = 0.2, [0.0001, 100.0], false, "Leaf length in metres";
    leaf_scale_x: "LeafScaleX" = 0.5, [0.0001, 100.0], false, "Leaf width / leaf length";
    leaf_bend: "LeafBend" = 0.3, [0.0, 1.0], false, "How far leaves turn to face up";
    leaf_stem_len: "LeafStemLen" = 0.5, [-10.0, 10.0], false, "Petiole length as a fraction of the leaf length";
    leaf_distrib: "LeafDistrib" = 4.0, [0.0, 8.0], true, "Shape used to distribute leaves along the parent (Arbaro)";
    leaf_quality: "LeafQuality" = 1.0, [0.000001, 1.0], false, "Fewer but larger leaves below 1";
    smooth: "Smooth" = 0.5, [0.0, 1.0], false, "Mesh smoothness: more sides per stem";
    attraction_up: "AttractionUp" = 0.0, [-10.0, 10.0], false, "Upward (negative: downward) bending of level 2+ stems";
    prune_ratio: "PruneRatio" = 0.0, [0.0, 1.0], false, "Weight of the pruning envelope";
    prune_width: "PruneWidth" = 0.5, [0.0001, 10.0], false, "Envelope width / tree height";
    prune_width_peak: "PruneWidthPeak" = 0.5, [0.0, 1.0], false, "Height (fraction) of the envelope's widest point";
    prune_power_low: "PrunePowerLow" = 0.5, [-100.0, 100.0], false, "Curvature of the envelope below the peak";
    prune_power_high: "PrunePowerHigh" = 0.5, [-100.0, 100.0], false, "Curvature of the envelope above the peak";
);

param_struct!(LevelParams, LEVEL_SPECS,
    scale: "Scale" = 1.0, [0.000001, 1000.0], false, "Radius factor of this level's stems (0Scale: the trunk's)";
    scale_v: "ScaleV" = 0.0, [0.0, 1000.0], false, "Variation of nScale";
    base_splits: "BaseSplits" = 0.0, [0.0, 20.0], true, "Clones at the stem base (trunk)";
    length: "Length" = 0.5, [0.0, 1000.0], false, "Length relative to the parent (0Length: trunk / Scale)";
    length_v: "LengthV" = 0.0, [0.0, 1000.0], false, "Variation of nLength";
    taper: "Taper" = 1.0, [0.0, 2.99999], false, "0 cylinder, 1 cone, 1-2 spherical end, 2-3 periodic";
    curve_res: "CurveRes" = 3.0, [1.0, 100.0], true, "Segments per stem";
    curve: "Curve" = 0.0, [-3600.0, 3600.0], false, "Total curvature of the stem in degrees";
    curve_back: "CurveBack" = 0.0, [-3600.0, 3600.0], false, "Curvature of the stem's second half (S shapes)";
    curve_v: "CurveV" = 0.0, [-90.0, 3600.0], false, "Random curvature (its size is used)";
    seg_splits: "SegSplits" = 0.0, [0.0, 2.0], false, "Clones per segment";
    split_angle: "SplitAngle" = 0.0, [0.0, 360.0], false, "Angle between clones";
    split_angle_v: "SplitAngleV" = 0.0, [0.0, 360.0], false, "Variation of nSplitAngle";
    branches: "Branches" = 0.0, [0.0, 2000.0], true, "Maximum child stems (level 1 and deeper)";
    down_angle: "DownAngle" = 30.0, [-180.0, 180.0], false, "Angle between child and parent";
    down_angle_v: "DownAngleV" = 0.0, [-180.0, 180.0], false, "Variation of nDownAngle (negative: by position)";
    rotate: "Rotate" = 120.0, [-360.0, 360.0], false, "Rotation about the parent between children (negative: alternating)";
    rotate_v: "RotateV" = 0.0, [-360.0, 360.0], false, "Variation of nRotate";
);

/// Names a species file may carry that do not shape the tree.
pub const IGNORED_NAMES: &[&str] = &["Species", "RandomSeed"];

/// A complete parameter set: general parameters and four levels.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Params {
    pub general: GeneralParams,
    pub levels: [LevelParams; 4],
}

impl Default for Params {
    /// Arbaro's defaults, except 0Length = 1 (Arbaro's trunk default) and Levels 1-3
    /// branches 0 (a bare trunk until a file says otherwise).
    fn default() -> Self {
        let mut levels: [LevelParams; 4] = Default::default();
        levels[0].length = 1.0;
        Params {
            general: GeneralParams::default(),
            levels,
        }
    }
}

fn check(spec: &ParamSpec, name: &str, value: f64) -> Result<(), ParamError> {
    if !value.is_finite() {
        return Err(ParamError::NotFinite {
            name: name.to_string(),
            value,
        });
    }
    if value < spec.min || value > spec.max {
        return Err(ParamError::OutOfRange {
            name: name.to_string(),
            value,
            min: spec.min,
            max: spec.max,
        });
    }
    if spec.integer && value.fract() != 0.0 {
        return Err(ParamError::NotInteger {
            name: name.to_string(),
            value,
        });
    }
    Ok(())
}

/// `"1DownAngle"` → `(1, "DownAngle")`.
fn split_level(name: &str) -> Option<(usize, &str)> {
    let digit = name.chars().next()?.to_digit(10)? as usize;
    (digit < 4).then(|| (digit, &name[1..]))
}

impl Params {
    /// Sets parameter `name` (Arbaro spelling) after checking its range.
    pub fn set(&mut self, name: &str, value: f64) -> Result<(), ParamError> {
        if let Some(spec) = GENERAL_SPECS.iter().find(|s| s.name == name) {
            check(spec, name, value)?;
            *self.general.field_mut(name).expect("spec and struct agree") = value;
            return Ok(());
        }
        if let Some((level, rest)) = split_level(name) {
            if let Some(spec) = LEVEL_SPECS.iter().find(|s| s.name == rest) {
                check(spec, name, value)?;
                *self.levels[level]
                    .field_mut(rest)
                    .expect("spec and struct agree") = value;
                return Ok(());
            }
        }
        Err(ParamError::Unknown(name.to_string()))
    }

    /// Value of parameter `name` (Arbaro spelling).
    pub fn get(&self, name: &str) -> Option<f64> {
        if let Some(v) = self.general.field(name) {
            return Some(v);
        }
        let (level, rest) = split_level(name)?;
        self.levels[level].field(rest)
    }

    /// Every parameter as (Arbaro name, value), general first, then level by level.
    pub fn entries(&self) -> Vec<(String, f64)> {
        let mut out: Vec<(String, f64)> = GENERAL_SPECS
            .iter()
            .map(|s| (s.name.to_string(), self.general.field(s.name).unwrap()))
            .collect();
        for (l, lp) in self.levels.iter().enumerate() {
            for s in LEVEL_SPECS {
                out.push((format!("{l}{}", s.name), lp.field(s.name).unwrap()));
            }
        }
        out
    }

    /// Re-checks every value (for parameter sets built in code).
    pub fn validate(&self) -> Result<(), ParamError> {
        for (name, value) in self.entries() {
            let spec = match split_level(&name) {
                Some((_, rest)) => LEVEL_SPECS.iter().find(|s| s.name == rest),
                None => GENERAL_SPECS.iter().find(|s| s.name == name),
            }
            .expect("entries come from the specs");
            check(spec, &name, value)?;
        }
        Ok(())
    }

    pub fn levels(&self) -> usize {
        self.general.levels as usize
    }
}

impl fmt::Display for Params {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (name, value) in self.entries() {
            writeln!(f, "{name:<16} {value}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_get_by_arbaro_names() {
        let mut p = Params::default();
        p.set("Shape", 7.0).unwrap();
        p.set("2DownAngle", -45.0).unwrap();
        assert_eq!(p.general.shape, 7.0);
        assert_eq!(p.levels[2].down_angle, -45.0);
        assert_eq!(p.get("2DownAngle"), Some(-45.0));
        assert_eq!(p.get("0Length"), Some(1.0));
        assert_eq!(p.get("BaseSize"), Some(0.25));
        assert_eq!(
            p.entries().len(),
            GENERAL_SPECS.len() + 4 * LEVEL_SPECS.len()
        );
    }

    #[test]
    fn bad_values_are_named() {
        let mut p = Params::default();
        assert_eq!(
            p.set("Bogus", 1.0),
            Err(ParamError::Unknown("Bogus".into()))
        );
        assert_eq!(
            p.set("4Length", 1.0),
            Err(ParamError::Unknown("4Length".into()))
        );
        assert!(
            matches!(p.set("BaseSize", 1.5), Err(ParamError::OutOfRange { name, .. }) if name == "BaseSize")
        );
        assert!(
            matches!(p.set("Levels", 2.5), Err(ParamError::NotInteger { name, .. }) if name == "Levels")
        );
        assert!(
            matches!(p.set("1Curve", f64::NAN), Err(ParamError::NotFinite { name, .. }) if name == "1Curve")
        );
        // A rejected value leaves the old one.
        assert_eq!(p.general.base_size, 0.25);
        p.levels[1].branches = 1e9;
        assert!(p.validate().is_err());
    }
}
