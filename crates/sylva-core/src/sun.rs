use glam::DVec3;
use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum SunError {
    #[error("sun direction ({0}, {1}, {2}) is not finite")]
    NotFinite(f64, f64, f64),
    #[error("sun direction is the zero vector")]
    Zero,
    #[error("sun elevation {0}° is outside [-90, 90]")]
    Elevation(f64),
    #[error("sun azimuth {0}° is not finite")]
    Azimuth(f64),
    #[error(
        "cannot parse sun direction '{0}': expected three comma-separated numbers, e.g. 0.3,1,0.2"
    )]
    Parse(String),
}

/// Why the sun of the command-line flags (`--sun`, `--elevation`, `--azimuth`) was refused;
/// the message names the flag.
#[derive(Debug, Error, PartialEq)]
pub enum SunFlagError {
    #[error("--sun")]
    Vector(#[source] SunError),
    /// Above the zenith is a typing error; below the horizon the pipeline explains why the
    /// sun must be up.
    #[error("--elevation {0}: degrees above the horizon, 0 to 90")]
    AboveZenith(f64),
    #[error("--elevation/--azimuth")]
    Angles(#[source] SunError),
}

/// The sun as an infinitely distant light: the unit vector pointing *towards* it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    to_sun: DVec3,
}

impl Sun {
    /// From a vector pointing towards the sun (any non-zero length).
    pub fn from_direction(x: f64, y: f64, z: f64) -> Result<Sun, SunError> {
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            return Err(SunError::NotFinite(x, y, z));
        }
        let v = DVec3::new(x, y, z);
        let len = v.length();
        if len == 0.0 || !len.is_finite() {
            return Err(SunError::Zero);
        }
        Ok(Sun { to_sun: v / len })
    }

    /// Elevation above the horizon and azimuth from +x towards +z, both in degrees.
    pub fn from_angles(elevation_deg: f64, azimuth_deg: f64) -> Result<Sun, SunError> {
        if !elevation_deg.is_finite() || !(-90.0..=90.0).contains(&elevation_deg) {
            return Err(SunError::Elevation(elevation_deg));
        }
        if !azimuth_deg.is_finite() {
            return Err(SunError::Azimuth(azimuth_deg));
        }
        let (e, a) = (elevation_deg.to_radians(), azimuth_deg.to_radians());
        Sun::from_direction(e.cos() * a.cos(), e.sin(), e.cos() * a.sin())
    }

    /// Parses `"x,y,z"`.
    pub fn parse_vector(s: &str) -> Result<Sun, SunError> {
        let parts: Vec<f64> = s
            .split(',')
            .map(|p| p.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| SunError::Parse(s.to_string()))?;
        match parts.as_slice() {
            [x, y, z] => Sun::from_direction(*x, *y, *z),
            _ => Err(SunError::Parse(s.to_string())),
        }
    }

    /// The sun the flags give: `--sun X,Y,Z`, or `--elevation` and `--azimuth` (50° and 30°
    /// where one is missing); none of them: [`Sun::default`].
    pub fn from_flags(
        sun: Option<&str>,
        elevation: Option<f64>,
        azimuth: Option<f64>,
    ) -> Result<Sun, SunFlagError> {
        Ok(match (sun, elevation, azimuth) {
            (Some(v), _, _) => Sun::parse_vector(v).map_err(SunFlagError::Vector)?,
            (None, None, None) => Sun::default(),
            (None, e, a) => {
                if let Some(e) = e.filter(|e| e.is_nan() || *e > 90.0) {
                    return Err(SunFlagError::AboveZenith(e));
                }
                Sun::from_angles(e.unwrap_or(50.0), a.unwrap_or(30.0))
                    .map_err(SunFlagError::Angles)?
            }
        })
    }

    /// [`Sun::from_flags`] when any of the flags is given, else `None` (the scene's sun).
    pub fn given(
        sun: Option<&str>,
        elevation: Option<f64>,
        azimuth: Option<f64>,
    ) -> Result<Option<Sun>, SunFlagError> {
        let any = sun.is_some() || elevation.is_some() || azimuth.is_some();
        any.then(|| Sun::from_flags(sun, elevation, azimuth))
            .transpose()
    }

    /// Unit vector towards the sun.
    pub fn to_sun(&self) -> DVec3 {
        self.to_sun
    }

    /// Unit vector along which sunlight travels (`-to_sun`).
    pub fn travel(&self) -> DVec3 {
        -self.to_sun
    }

    /// Elevation in degrees above the horizon.
    pub fn elevation_deg(&self) -> f64 {
        self.to_sun.y.clamp(-1.0, 1.0).asin().to_degrees()
    }

    /// Azimuth in degrees from +x towards +z, in [0, 360).
    pub fn azimuth_deg(&self) -> f64 {
        self.to_sun
            .z
            .atan2(self.to_sun.x)
            .to_degrees()
            .rem_euclid(360.0)
    }
}

impl Default for Sun {
    /// A late-morning sun: 50° up, from azimuth 30°.
    fn default() -> Self {
        Sun::from_angles(50.0, 30.0).expect("valid default")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn zenith_and_horizon() {
        let s = Sun::from_angles(90.0, 0.0).unwrap();
        assert!((s.to_sun() - DVec3::Y).length() < 1e-12);
        assert!((s.travel() + DVec3::Y).length() < 1e-12);
        let s = Sun::from_angles(0.0, 90.0).unwrap();
        assert!((s.to_sun() - DVec3::Z).length() < 1e-12);
    }

    /// Each flag alone takes the other's default; the errors name the flag.
    #[test]
    fn flags_give_the_sun_or_name_the_bad_flag() {
        let s = Sun::from_flags(None, Some(20.0), None).unwrap();
        let s20 = s;
        assert!((s.elevation_deg() - 20.0).abs() < 1e-9 && (s.azimuth_deg() - 30.0).abs() < 1e-9);
        let s = Sun::from_flags(None, None, Some(100.0)).unwrap();
        assert!((s.elevation_deg() - 50.0).abs() < 1e-9 && (s.azimuth_deg() - 100.0).abs() < 1e-9);
        assert_eq!(Sun::from_flags(None, None, None).unwrap(), Sun::default());
        assert_eq!(Sun::given(None, None, None), Ok(None));
        assert_eq!(Sun::given(None, Some(20.0), None), Ok(Some(s20)));
        let s = Sun::from_flags(Some("0,1,0"), None, None).unwrap();
        assert!((s.to_sun() - DVec3::Y).length() < 1e-12);
        assert_eq!(
            Sun::from_flags(None, Some(95.0), None),
            Err(SunFlagError::AboveZenith(95.0))
        );
        assert!(matches!(
            Sun::from_flags(Some("1,2"), None, None),
            Err(SunFlagError::Vector(SunError::Parse(_)))
        ));
        assert!(matches!(
            Sun::from_flags(None, Some(-95.0), None),
            Err(SunFlagError::Angles(SunError::Elevation(_)))
        ));
    }

    #[test]
    fn bad_input() {
        assert_eq!(Sun::from_direction(0.0, 0.0, 0.0), Err(SunError::Zero));
        assert!(matches!(
            Sun::from_direction(f64::NAN, 1.0, 0.0),
            Err(SunError::NotFinite(..))
        ));
        assert!(matches!(
            Sun::from_angles(91.0, 0.0),
            Err(SunError::Elevation(_))
        ));
        assert!(matches!(Sun::parse_vector("1,2"), Err(SunError::Parse(_))));
        assert!(matches!(
            Sun::parse_vector("a,b,c"),
            Err(SunError::Parse(_))
        ));
        assert!(Sun::parse_vector(" 1, 2 ,3").is_ok());
    }

    proptest! {
        #[test]
        fn angles_round_trip(e in -89.0f64..89.0, a in 0.0f64..359.9) {
            let s = Sun::from_angles(e, a).unwrap();
            prop_assert!((s.elevation_deg() - e).abs() < 1e-9);
            prop_assert!((s.azimuth_deg() - a).abs() < 1e-9);
            prop_assert!((s.to_sun().length() - 1.0).abs() < 1e-12);
        }
    }
}
