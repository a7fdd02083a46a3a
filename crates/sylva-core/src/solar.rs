//! The sun from date, time and place: NREL's Solar Position Algorithm (SPA, Reda & Andreas,
//! NREL/TP-560-34302, revised 2008; ±0.0003° for years -2000 to 6000) through the
//! `solar-positioning` crate, turned into sylva's [`Sun`].
//!
//! **The world's compass.** sylva's world is right-handed with +y up, and azimuths of
//! [`Sun::from_angles`] run from +x towards +z. North is **-z** and east is **+x** (so south
//! is +z and west is -x; east × north = up). A compass azimuth `A` (degrees from north
//! towards east, the SPA's convention) is the world azimuth `A - 90°`: a sun due south
//! (A = 180°) stands over +z, a sun due east (A = 90°) over +x. [`world_azimuth`] does the
//! conversion and [`NORTH`] and [`EAST`] name the axes.
//!
//! **Times** are local clock times (`HH:MM` or `HH:MM:SS`) on a date (`YYYY-MM-DD`, the
//! proleptic Gregorian calendar) at a fixed offset from UTC ([`UtcOffset`]; by default the
//! zone of the longitude, `round(longitude / 15)` hours, [`Place::zone_offset`]: no daylight
//! saving). ΔT (TT − UT) is the crate's estimate for the date (Espenak & Meeus with updated
//! fits); the position is topocentric at sea level and apparent, refracted by the standard
//! atmosphere (1013.25 hPa, 15 °C), as a camera would see it ([`Atmosphere`] for others).
//!
//! A day's path ([`SunPath`]) is one sun per time step from `from` to `to`; the steps with
//! the sun below the horizon are left out ([`DayPath::below`]), and a path whose sun never
//! rises is an error ([`SolarError::NeverRises`]).

use std::fmt;
use std::str::FromStr;

use glam::DVec3;
use solar_positioning::time::JulianDate;
use solar_positioning::{delta_t, Location, RefractionCorrection, SolarPositions};
use thiserror::Error;

use crate::{Sun, SunError};

/// The world axis that points north (see the module's doc).
pub const NORTH: DVec3 = DVec3::new(0.0, 0.0, -1.0);
/// The world axis that points east.
pub const EAST: DVec3 = DVec3::new(1.0, 0.0, 0.0);

/// The most suns one day's path holds (before the night's are left out).
pub const MAX_PATH_SUNS: usize = 1000;

/// Offsets from UTC that exist on Earth's clocks, in seconds: -12:00 to +14:00.
const OFFSET_RANGE: std::ops::RangeInclusive<i32> = -12 * 3600..=14 * 3600;

#[derive(Debug, Error, PartialEq)]
pub enum SolarError {
    #[error("latitude {0}°: degrees north of the equator, -90 to 90")]
    Latitude(f64),
    #[error("longitude {0}°: degrees east of Greenwich, -180 to 180")]
    Longitude(f64),
    #[error("date '{0}': expected YYYY-MM-DD, e.g. 2026-06-21")]
    DateSyntax(String),
    #[error("date '{text}' does not exist: {month_name} {year} has {days} days")]
    NoSuchDay {
        text: String,
        month_name: &'static str,
        year: i32,
        days: u32,
    },
    #[error("time '{0}': expected a local clock time HH:MM or HH:MM:SS, 00:00 to 23:59:59")]
    TimeSyntax(String),
    #[error("UTC offset '{0}': expected +HH:MM or -HH:MM, -12:00 to +14:00, e.g. +02:00")]
    Offset(String),
    #[error("step '{0}': expected hours, minutes and seconds such as 15m, 1h, 90s or 1h30m")]
    StepSyntax(String),
    #[error("step '{0}': the sun needs a step longer than zero")]
    StepZero(String),
    #[error("the path starts at {from}, after it ends at {to}: --from must not be after --to")]
    FromAfterTo { from: ClockTime, to: ClockTime },
    #[error(
        "{count} suns from {from} to {to} every {step}: at most {MAX_PATH_SUNS}; take a longer step"
    )]
    TooManySuns {
        count: usize,
        from: ClockTime,
        to: ClockTime,
        step: Step,
    },
    #[error(
        "the sun never rises above the horizon at {latitude} on {date} between {from} and {to}"
    )]
    NeverRises {
        latitude: String,
        date: Date,
        from: ClockTime,
        to: ClockTime,
    },
    #[error("the sun is {depth:.1}° below the horizon at {at}: sylva lights scenes by the sun, so pick a time of day")]
    BelowHorizon { depth: f64, at: String },
    #[error("solar position at {at}: {message}")]
    Spa { at: String, message: String },
}

/// A place on Earth: latitude (degrees north) and longitude (degrees east).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Place {
    latitude: f64,
    longitude: f64,
}

impl Place {
    pub fn new(latitude: f64, longitude: f64) -> Result<Place, SolarError> {
        if !(latitude.is_finite() && (-90.0..=90.0).contains(&latitude)) {
            return Err(SolarError::Latitude(latitude));
        }
        if !(longitude.is_finite() && (-180.0..=180.0).contains(&longitude)) {
            return Err(SolarError::Longitude(longitude));
        }
        Ok(Place {
            latitude,
            longitude,
        })
    }

    pub fn latitude(&self) -> f64 {
        self.latitude
    }

    pub fn longitude(&self) -> f64 {
        self.longitude
    }

    /// The zone of the longitude: `round(longitude / 15)` hours east of UTC (no daylight
    /// saving; Munich at 11.6°E is +01:00, Denver at 105.2°W -07:00).
    pub fn zone_offset(&self) -> UtcOffset {
        UtcOffset((self.longitude / 15.0).round() as i32 * 3600)
    }

    /// The latitude as people write it: `48.1°N`, `33.9°S`.
    pub fn latitude_text(&self) -> String {
        format!(
            "{}°{}",
            degrees(self.latitude.abs()),
            if self.latitude < 0.0 { 'S' } else { 'N' }
        )
    }
}

impl fmt::Display for Place {
    /// `48.1°N 11.6°E`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {}°{}",
            self.latitude_text(),
            degrees(self.longitude.abs()),
            if self.longitude < 0.0 { 'W' } else { 'E' }
        )
    }
}

/// A number of degrees as given, with at least one decimal: `80.0`, `48.137`.
fn degrees(v: f64) -> String {
    let s = v.to_string();
    if s.contains('.') {
        s
    } else {
        format!("{s}.0")
    }
}

/// A calendar date (proleptic Gregorian), `YYYY-MM-DD`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Date {
    year: i32,
    month: u32,
    day: u32,
}

const MONTHS: [&str; 12] = [
    "January",
    "February",
    "March",
    "April",
    "May",
    "June",
    "July",
    "August",
    "September",
    "October",
    "November",
    "December",
];

fn days_in_month(year: i32, month: u32) -> u32 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

impl Date {
    pub fn year(&self) -> i32 {
        self.year
    }

    pub fn month(&self) -> u32 {
        self.month
    }

    pub fn day(&self) -> u32 {
        self.day
    }

    /// Days from 1970-01-01 (negative before it): Hinnant's `days_from_civil`.
    fn days_since_epoch(&self) -> i64 {
        let y = i64::from(self.year) - i64::from(self.month <= 2);
        let era = y.div_euclid(400);
        let yoe = y - era * 400;
        let m = i64::from(self.month);
        let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + i64::from(self.day) - 1;
        let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
        era * 146_097 + doe - 719_468
    }
}

impl FromStr for Date {
    type Err = SolarError;

    fn from_str(s: &str) -> Result<Date, SolarError> {
        let syntax = || SolarError::DateSyntax(s.to_string());
        let parts: Vec<&str> = s.trim().split('-').collect();
        let [y, m, d] = parts.as_slice() else {
            return Err(syntax());
        };
        let digits = |p: &str, n: usize| p.len() == n && p.bytes().all(|b| b.is_ascii_digit());
        if !(digits(y, 4) && digits(m, 2) && digits(d, 2)) {
            return Err(syntax());
        }
        let (year, month, day): (i32, u32, u32) = (
            y.parse().map_err(|_| syntax())?,
            m.parse().map_err(|_| syntax())?,
            d.parse().map_err(|_| syntax())?,
        );
        if !(1..=12).contains(&month) || day == 0 {
            return Err(syntax());
        }
        let days = days_in_month(year, month);
        if day > days {
            return Err(SolarError::NoSuchDay {
                text: s.trim().to_string(),
                month_name: MONTHS[month as usize - 1],
                year,
                days,
            });
        }
        Ok(Date { year, month, day })
    }
}

impl fmt::Display for Date {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

/// A local clock time of day, to the second: `HH:MM` or `HH:MM:SS`, 00:00 to 23:59:59.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct ClockTime(u32);

impl ClockTime {
    /// The last second of the day, 23:59:59.
    pub const LAST: ClockTime = ClockTime(86_399);

    /// From seconds after midnight (`None` from 24:00 on).
    pub fn from_seconds(s: u32) -> Option<ClockTime> {
        (s < 86_400).then_some(ClockTime(s))
    }

    pub fn seconds(&self) -> u32 {
        self.0
    }

    /// For file names: `0530`, or `053015` with `seconds`.
    pub fn compact(&self, seconds: bool) -> String {
        let (h, m, s) = (self.0 / 3600, self.0 / 60 % 60, self.0 % 60);
        if seconds {
            format!("{h:02}{m:02}{s:02}")
        } else {
            format!("{h:02}{m:02}")
        }
    }
}

impl FromStr for ClockTime {
    type Err = SolarError;

    fn from_str(s: &str) -> Result<ClockTime, SolarError> {
        let syntax = || SolarError::TimeSyntax(s.to_string());
        let parts: Vec<&str> = s.trim().split(':').collect();
        if !(2..=3).contains(&parts.len()) {
            return Err(syntax());
        }
        let mut fields = [0u32; 3];
        for (k, p) in parts.iter().enumerate() {
            let ok = (1..=2).contains(&p.len()) && p.bytes().all(|b| b.is_ascii_digit());
            fields[k] = p.parse().ok().filter(|_| ok).ok_or_else(syntax)?;
        }
        let [h, m, sec] = fields;
        if h > 23 || m > 59 || sec > 59 {
            return Err(syntax());
        }
        Ok(ClockTime(h * 3600 + m * 60 + sec))
    }
}

impl fmt::Display for ClockTime {
    /// `HH:MM`, with `:SS` when the seconds are not zero.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (h, m, s) = (self.0 / 3600, self.0 / 60 % 60, self.0 % 60);
        if s == 0 {
            write!(f, "{h:02}:{m:02}")
        } else {
            write!(f, "{h:02}:{m:02}:{s:02}")
        }
    }
}

/// A fixed offset of local clock time from UTC, -12:00 to +14:00: `+02:00`, `-07:00`,
/// `+05:30` (`+2`, `-0700` and `Z` too).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UtcOffset(i32);

impl UtcOffset {
    pub const UTC: UtcOffset = UtcOffset(0);

    /// Seconds east of UTC (local time minus UTC).
    pub fn seconds(&self) -> i32 {
        self.0
    }
}

impl FromStr for UtcOffset {
    type Err = SolarError;

    fn from_str(s: &str) -> Result<UtcOffset, SolarError> {
        let bad = || SolarError::Offset(s.to_string());
        let t = s.trim();
        if t.eq_ignore_ascii_case("z") {
            return Ok(UtcOffset::UTC);
        }
        let (sign, rest) = match t.as_bytes().first() {
            Some(b'+') => (1, &t[1..]),
            Some(b'-') => (-1, &t[1..]),
            _ => return Err(bad()),
        };
        if !rest.is_ascii() {
            return Err(bad());
        }
        let (h, m) = match rest.split_once(':') {
            Some((h, m)) => (h, m),
            None if rest.len() == 4 => rest.split_at(2),
            None => (rest, "00"),
        };
        let field = |p: &str| {
            ((1..=2).contains(&p.len()) && p.bytes().all(|b| b.is_ascii_digit()))
                .then(|| p.parse::<i32>().ok())
                .flatten()
        };
        let (Some(h), Some(m)) = (field(h), field(m)) else {
            return Err(bad());
        };
        let seconds = sign * (h * 3600 + m * 60);
        if m > 59 || !OFFSET_RANGE.contains(&seconds) {
            return Err(bad());
        }
        Ok(UtcOffset(seconds))
    }
}

impl fmt::Display for UtcOffset {
    /// `UTC+02:00`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.unsigned_abs();
        let sign = if self.0 < 0 { '-' } else { '+' };
        write!(f, "UTC{sign}{:02}:{:02}", a / 3600, a / 60 % 60)
    }
}

/// A time step: `15m`, `1h`, `90s`, `1h30m` (hours, minutes, seconds in that order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Step(u32);

impl Step {
    pub fn seconds(&self) -> u32 {
        self.0
    }
}

impl FromStr for Step {
    type Err = SolarError;

    fn from_str(s: &str) -> Result<Step, SolarError> {
        let t = s.trim();
        let syntax = || SolarError::StepSyntax(s.to_string());
        if !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()) {
            // A bare number: zero is zero in any unit, anything else needs one.
            return Err(if t.bytes().all(|b| b == b'0') {
                SolarError::StepZero(s.to_string())
            } else {
                syntax()
            });
        }
        let mut total: u64 = 0;
        let mut number = String::new();
        let mut last_unit = 0; // h = 1, m = 2, s = 3: units in order, each once
        for c in t.chars() {
            if c.is_ascii_digit() {
                number.push(c);
                continue;
            }
            let (unit, scale) = match c {
                'h' => (1, 3600),
                'm' => (2, 60),
                's' => (3, 1),
                _ => return Err(syntax()),
            };
            if number.is_empty() || number.len() > 6 || unit <= last_unit {
                return Err(syntax());
            }
            total += number.parse::<u64>().map_err(|_| syntax())? * scale;
            number.clear();
            last_unit = unit;
        }
        if !number.is_empty() || last_unit == 0 {
            return Err(syntax());
        }
        if total == 0 {
            return Err(SolarError::StepZero(s.to_string()));
        }
        // A step past a day gives one sun: cap it there.
        Ok(Step(total.min(86_400) as u32))
    }
}

impl fmt::Display for Step {
    /// `1h30m`, `15m`, `90s` → `1m30s`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (h, m, s) = (self.0 / 3600, self.0 / 60 % 60, self.0 % 60);
        let mut out = String::new();
        for (v, unit) in [(h, 'h'), (m, 'm'), (s, 's')] {
            if v > 0 {
                out.push_str(&format!("{v}{unit}"));
            }
        }
        f.write_str(&out)
    }
}

/// A compass azimuth (degrees from north towards east) as sylva's world azimuth (degrees
/// from +x towards +z, [`Sun::from_angles`]): north is -z, east +x, so `A - 90°`, in [0, 360).
pub fn world_azimuth(compass_deg: f64) -> f64 {
    (compass_deg - 90.0).rem_euclid(360.0)
}

/// The air the sun is seen through, and ΔT.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Atmosphere {
    /// Metres above sea level (parallax only).
    pub height_m: f64,
    /// Pressure and temperature for the refraction; `None` for the geometric position.
    pub refraction: Option<(f64, f64)>,
    /// ΔT = TT − UT in seconds; `None` for the crate's estimate for the date.
    pub delta_t_s: Option<f64>,
}

impl Default for Atmosphere {
    /// Sea level, the standard atmosphere (1013.25 hPa, 15 °C), ΔT estimated.
    fn default() -> Self {
        Atmosphere {
            height_m: 0.0,
            refraction: Some((1013.25, 15.0)),
            delta_t_s: None,
        }
    }
}

/// Where the sun stands in the sky: apparent elevation above the horizon and compass
/// azimuth (from north towards east), both in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolarAngles {
    pub elevation_deg: f64,
    pub azimuth_deg: f64,
}

impl SolarAngles {
    /// One line on the sun `sun` (these angles) at moment `at`: its compass angles and its
    /// world azimuth.
    pub fn describe(&self, at: &SolarTime, sun: &Sun) -> String {
        format!(
            "sun at {at}: elevation {:.1}°, azimuth {:.1}° from north (world azimuth {:.1}°: north -z, east +x)",
            self.elevation_deg,
            self.azimuth_deg,
            sun.azimuth_deg()
        )
    }

    /// sylva's sun for these angles (north = -z, east = +x). Below the horizon too: the
    /// renderer refuses such a sun, [`SolarTime::sun`] explains it first.
    pub fn sun(&self) -> Result<Sun, SunError> {
        Sun::from_angles(self.elevation_deg, world_azimuth(self.azimuth_deg))
    }
}

/// A moment at a place: a local clock time on a date at an offset from UTC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolarTime {
    pub place: Place,
    pub date: Date,
    pub time: ClockTime,
    pub offset: UtcOffset,
}

impl SolarTime {
    /// The sun's apparent position at sea level through the standard atmosphere.
    pub fn angles(&self) -> Result<SolarAngles, SolarError> {
        self.angles_in(&Atmosphere::default())
    }

    /// The sun's topocentric position (SPA) seen through `atmosphere`.
    pub fn angles_in(&self, atmosphere: &Atmosphere) -> Result<SolarAngles, SolarError> {
        let spa = |e: solar_positioning::Error| SolarError::Spa {
            at: self.to_string(),
            message: e.to_string(),
        };
        let d = self.date;
        let delta_t = match atmosphere.delta_t_s {
            Some(dt) => dt,
            None => delta_t::estimate(f64::from(d.year) + (f64::from(d.month) - 0.5) / 12.0)
                .map_err(spa)?,
        };
        // Julian date of the moment in UT: the date's midnight, then the clock time less
        // the offset (which may cross midnight either way).
        let utc_seconds = f64::from(self.time.seconds()) - f64::from(self.offset.seconds());
        let jd = 2_440_587.5 + d.days_since_epoch() as f64 + utc_seconds / 86_400.0;
        let refraction = atmosphere
            .refraction
            .map(|(p, t)| RefractionCorrection::new(p, t))
            .transpose()
            .map_err(spa)?;
        let position = SolarPositions::new()
            .at_from_julian(
                JulianDate::new(jd, delta_t).map_err(spa)?,
                Location {
                    latitude: self.place.latitude,
                    longitude: self.place.longitude,
                },
                atmosphere.height_m,
                refraction,
            )
            .map_err(spa)?;
        Ok(SolarAngles {
            elevation_deg: position.elevation_angle(),
            azimuth_deg: position.azimuth(),
        })
    }

    /// sylva's sun at this moment; a sun below the horizon is an error that says how far
    /// below, and when and where.
    pub fn sun(&self) -> Result<(Sun, SolarAngles), SolarError> {
        let angles = self.angles()?;
        if angles.elevation_deg < 0.0 {
            return Err(SolarError::BelowHorizon {
                depth: -angles.elevation_deg,
                at: self.to_string(),
            });
        }
        let sun = angles.sun().map_err(|e| SolarError::Spa {
            at: self.to_string(),
            message: e.to_string(),
        })?;
        Ok((sun, angles))
    }
}

impl fmt::Display for SolarTime {
    /// `48.1°N 11.6°E on 2026-06-21 at 14:30 (UTC+01:00)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} on {} at {} ({})",
            self.place, self.date, self.time, self.offset
        )
    }
}

/// The sun over one day at a place: a sun every `step` from `from` to `to` (local clock
/// times, `to` included when a step lands on it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunPath {
    place: Place,
    date: Date,
    offset: UtcOffset,
    from: ClockTime,
    to: ClockTime,
    step: Step,
}

/// One sun of a [`DayPath`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathSun {
    pub time: ClockTime,
    pub angles: SolarAngles,
    pub sun: Sun,
}

/// A day's suns above the horizon, and the times left out with the sun below it.
#[derive(Debug, Clone, PartialEq)]
pub struct DayPath {
    pub up: Vec<PathSun>,
    pub below: Vec<ClockTime>,
    step: Step,
}

impl SunPath {
    pub fn new(
        place: Place,
        date: Date,
        offset: UtcOffset,
        from: ClockTime,
        to: ClockTime,
        step: Step,
    ) -> Result<SunPath, SolarError> {
        if from > to {
            return Err(SolarError::FromAfterTo { from, to });
        }
        let path = SunPath {
            place,
            date,
            offset,
            from,
            to,
            step,
        };
        let count = path.count();
        if count > MAX_PATH_SUNS {
            return Err(SolarError::TooManySuns {
                count,
                from,
                to,
                step,
            });
        }
        Ok(path)
    }

    pub fn place(&self) -> Place {
        self.place
    }

    pub fn date(&self) -> Date {
        self.date
    }

    pub fn offset(&self) -> UtcOffset {
        self.offset
    }

    pub fn from(&self) -> ClockTime {
        self.from
    }

    pub fn to(&self) -> ClockTime {
        self.to
    }

    pub fn step(&self) -> Step {
        self.step
    }

    /// Suns on the path, night included (at least one).
    pub fn count(&self) -> usize {
        ((self.to.0 - self.from.0) / self.step.0) as usize + 1
    }

    /// The clock times of the path's suns.
    pub fn times(&self) -> impl Iterator<Item = ClockTime> + '_ {
        (0..self.count() as u32).map(|k| ClockTime(self.from.0 + k * self.step.0))
    }

    /// The moment of one time on the path.
    pub fn at(&self, time: ClockTime) -> SolarTime {
        SolarTime {
            place: self.place,
            date: self.date,
            time,
            offset: self.offset,
        }
    }

    /// Every sun on the path, those below the horizon set apart; an error if none is above.
    pub fn day(&self) -> Result<DayPath, SolarError> {
        let mut day = DayPath {
            up: Vec::new(),
            below: Vec::new(),
            step: self.step,
        };
        for time in self.times() {
            let angles = self.at(time).angles()?;
            if angles.elevation_deg < 0.0 {
                day.below.push(time);
                continue;
            }
            let sun = angles.sun().map_err(|e| SolarError::Spa {
                at: self.at(time).to_string(),
                message: e.to_string(),
            })?;
            day.up.push(PathSun { time, angles, sun });
        }
        if day.up.is_empty() {
            return Err(SolarError::NeverRises {
                latitude: self.place.latitude_text(),
                date: self.date,
                from: self.from,
                to: self.to,
            });
        }
        Ok(day)
    }
}

impl DayPath {
    /// Whether any time on the path has seconds (file names then carry them).
    pub fn has_seconds(&self) -> bool {
        self.up.iter().any(|s| s.time.0 % 60 != 0)
    }

    /// One line on the times left out (`None` when the sun is up at every step):
    /// `5 of 17 suns left out, below the horizon: 00:00 to 04:00, 21:00 to 23:00`.
    pub fn night_note(&self) -> Option<String> {
        if self.below.is_empty() {
            return None;
        }
        // Runs of consecutive steps, each as `first to last` (or the one time).
        let mut runs: Vec<(ClockTime, ClockTime)> = Vec::new();
        for &t in &self.below {
            match runs.last_mut() {
                Some((_, last)) if t.0 == last.0 + self.step.0 => *last = t,
                _ => runs.push((t, t)),
            }
        }
        let runs: Vec<String> = runs
            .iter()
            .map(|(a, b)| {
                if a == b {
                    a.to_string()
                } else {
                    format!("{a} to {b}")
                }
            })
            .collect();
        Some(format!(
            "{} of {} suns left out, below the horizon: {}",
            self.below.len(),
            self.below.len() + self.up.len(),
            runs.join(", ")
        ))
    }
}

/// A [`SolarError`] from a command-line flag, named in its message (`--lat: latitude 95°:
/// ...`); errors of the flags together (a path that ends before it starts) name none.
#[derive(Debug, PartialEq)]
pub struct FlagError {
    pub flag: Option<&'static str>,
    pub error: SolarError,
}

impl std::fmt::Display for FlagError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.flag {
            Some(flag) => write!(f, "--{flag}: {}", self.error),
            None => write!(f, "{}", self.error),
        }
    }
}

impl std::error::Error for FlagError {}

impl From<SolarError> for FlagError {
    fn from(error: SolarError) -> FlagError {
        FlagError { flag: None, error }
    }
}

fn flag(flag: &'static str) -> impl Fn(SolarError) -> FlagError {
    move |error| FlagError {
        flag: Some(flag),
        error,
    }
}

/// The place and day of the command-line flags `--lat`, `--lon`, `--date` and `--utc-offset`
/// (default: the zone of the longitude), as given.
#[derive(Debug, Clone, Copy)]
pub struct DayFlags<'a> {
    pub lat: f64,
    pub lon: f64,
    pub date: &'a str,
    pub utc_offset: Option<&'a str>,
}

impl DayFlags<'_> {
    fn place_date_offset(&self) -> Result<(Place, Date, UtcOffset), FlagError> {
        let place = Place::new(self.lat, self.lon).map_err(|e| match e {
            SolarError::Latitude(_) => flag("lat")(e),
            _ => flag("lon")(e),
        })?;
        let date: Date = self.date.parse().map_err(flag("date"))?;
        let offset = match self.utc_offset {
            Some(o) => o.parse().map_err(flag("utc-offset"))?,
            None => place.zone_offset(),
        };
        Ok((place, date, offset))
    }

    /// The moment of local clock time `time` (`--time`) that day.
    pub fn moment(&self, time: &str) -> Result<SolarTime, FlagError> {
        let (place, date, offset) = self.place_date_offset()?;
        let time: ClockTime = time.parse().map_err(flag("time"))?;
        Ok(SolarTime {
            place,
            date,
            time,
            offset,
        })
    }

    /// The sun's path that day: `--from` (default 00:00) to `--to` (23:59) every `--step`
    /// (1h).
    pub fn path(
        &self,
        from: Option<&str>,
        to: Option<&str>,
        step: Option<&str>,
    ) -> Result<SunPath, FlagError> {
        let (place, date, offset) = self.place_date_offset()?;
        let from: ClockTime = from.unwrap_or("00:00").parse().map_err(flag("from"))?;
        let to: ClockTime = to.unwrap_or("23:59").parse().map_err(flag("to"))?;
        let step: Step = step.unwrap_or("1h").parse().map_err(flag("step"))?;
        Ok(SunPath::new(place, date, offset, from, to, step)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each flag's error names it; errors of the flags together name none; the offset
    /// defaults to the longitude's zone and the path to the whole day, hourly.
    #[test]
    fn day_flags_name_the_bad_flag() {
        let day = DayFlags {
            lat: 48.1,
            lon: 11.6,
            date: "2026-06-21",
            utc_offset: None,
        };
        let m = day.moment("14:30").unwrap();
        assert_eq!(m.offset, munich().zone_offset());
        let path = day.path(None, None, None).unwrap();
        assert_eq!(path.count(), 24);
        let bad = |d: DayFlags, time: &str| day_error(d.moment(time));
        assert!(bad(DayFlags { lat: 95.0, ..day }, "12:00").starts_with("--lat: latitude 95"));
        assert!(bad(DayFlags { lon: 200.0, ..day }, "12:00").starts_with("--lon: "));
        assert!(bad(
            DayFlags {
                date: "2026-02-30",
                ..day
            },
            "12:00"
        )
        .starts_with("--date: "));
        let offset = DayFlags {
            utc_offset: Some("x"),
            ..day
        };
        assert!(bad(offset, "12:00").starts_with("--utc-offset: "));
        assert!(bad(day, "25:00").starts_with("--time: "));
        assert!(day_error(day.path(Some("x"), None, None)).starts_with("--from: "));
        assert!(day_error(day.path(None, None, Some("0m"))).starts_with("--step: "));
        let late = day_error(day.path(Some("12:00"), Some("11:00"), None));
        assert!(late.starts_with("the path starts at 12:00"), "{late}");
    }

    fn day_error<T: std::fmt::Debug>(r: Result<T, FlagError>) -> String {
        r.unwrap_err().to_string()
    }

    fn munich() -> Place {
        Place::new(48.1, 11.6).unwrap()
    }

    fn date(s: &str) -> Date {
        s.parse().unwrap()
    }

    fn time(s: &str) -> ClockTime {
        s.parse().unwrap()
    }

    /// NREL/TP-560-34302 (Reda & Andreas), the report's example: 17 October 2003, 12:30:30
    /// local time at UTC-7, 39.742476°N 105.1786°W, 1830.14 m, 820 mbar, 11 °C, ΔT 67 s:
    /// topocentric zenith 50.11162°, azimuth 194.34024° (from north, eastward). The crate
    /// claims ±0.0003°; through sylva's date and zone conversion it agrees to 1e-5°.
    #[test]
    fn nrel_spa_report_example() {
        let t = SolarTime {
            place: Place::new(39.742476, -105.1786).unwrap(),
            date: date("2003-10-17"),
            time: time("12:30:30"),
            offset: "-07:00".parse().unwrap(),
        };
        let a = t
            .angles_in(&Atmosphere {
                height_m: 1830.14,
                refraction: Some((820.0, 11.0)),
                delta_t_s: Some(67.0),
            })
            .unwrap();
        let zenith = 90.0 - a.elevation_deg;
        assert!((zenith - 50.11162).abs() < 1e-5, "zenith {zenith}");
        assert!(
            (a.azimuth_deg - 194.34024).abs() < 1e-5,
            "{}",
            a.azimuth_deg
        );
        // The default zone of the longitude is the report's UTC-7.
        assert_eq!(t.place.zone_offset(), t.offset);
        // With sylva's defaults (sea level, standard atmosphere, ΔT estimated) the sun moves
        // by far less than a pixel's worth: under 0.01°.
        let d = t.angles().unwrap();
        assert!((d.elevation_deg - a.elevation_deg).abs() < 0.01, "{d:?}");
        assert!((d.azimuth_deg - a.azimuth_deg).abs() < 0.01, "{d:?}");
    }

    /// At the March equinox the sun passes (almost) through the zenith on the equator at
    /// local solar noon (12:07 UTC at longitude 0: the equation of time is -7.5 min).
    #[test]
    fn equinox_noon_on_the_equator_is_near_the_zenith() {
        let path = SunPath::new(
            Place::new(0.0, 0.0).unwrap(),
            date("2026-03-20"),
            UtcOffset::UTC,
            time("11:30"),
            time("12:45"),
            "1m".parse().unwrap(),
        )
        .unwrap();
        let day = path.day().unwrap();
        let top = day
            .up
            .iter()
            .max_by(|a, b| a.angles.elevation_deg.total_cmp(&b.angles.elevation_deg))
            .unwrap();
        assert!(top.angles.elevation_deg > 89.5, "{top:?}");
        assert!(
            (time("12:04")..=time("12:10")).contains(&top.time),
            "{top:?}"
        );
        assert!((top.sun.to_sun() - DVec3::Y).length() < 0.01);
    }

    /// North is -z and east +x: the noon sun of a northern summer stands over +z (south),
    /// the morning sun over +x (east), the evening sun over -x; in the southern hemisphere
    /// the noon sun is in the north (-z).
    #[test]
    fn world_mapping_puts_north_at_minus_z_and_east_at_plus_x() {
        assert_eq!(world_azimuth(180.0), 90.0);
        assert_eq!(world_azimuth(90.0), 0.0);
        assert_eq!(world_azimuth(0.0), 270.0);
        let at = |place: Place, t: &str| {
            SolarTime {
                place,
                date: date("2026-06-21"),
                time: time(t),
                offset: place.zone_offset(),
            }
            .sun()
            .unwrap()
        };
        // Munich's solar noon is 12:14 at UTC+1.
        // The sun's direction on the ground.
        let ground = |s: Sun| (s.to_sun() * DVec3::new(1.0, 0.0, 1.0)).normalize();
        let (noon, angles) = at(munich(), "12:14");
        assert!((angles.azimuth_deg - 180.0).abs() < 2.0, "{angles:?}");
        assert!(ground(noon).dot(-NORTH) > 0.999, "{noon:?}");
        assert!((noon.elevation_deg() - 65.3).abs() < 0.2, "{noon:?}");
        assert!((noon.azimuth_deg() - 90.0).abs() < 2.0, "{noon:?}");
        let (morning, _) = at(munich(), "07:00");
        assert!(ground(morning).dot(EAST) > 0.95, "{morning:?}");
        let (evening, _) = at(munich(), "19:00");
        assert!(ground(evening).dot(-EAST) > 0.9, "{evening:?}");
        // Sydney in its winter: the noon sun is in the north.
        let (south_noon, _) = at(Place::new(-33.9, 151.2).unwrap(), "11:55");
        assert!(ground(south_noon).dot(NORTH) > 0.99, "{south_noon:?}");
        // Right-handed with +y up: east × north = up.
        assert!((EAST.cross(NORTH) - DVec3::Y).length() < 1e-12);
    }

    #[test]
    fn a_day_leaves_out_the_night_and_says_when() {
        let path = SunPath::new(
            munich(),
            date("2026-06-21"),
            munich().zone_offset(),
            time("00:00"),
            time("23:00"),
            "1h".parse().unwrap(),
        )
        .unwrap();
        assert_eq!(path.count(), 24);
        let day = path.day().unwrap();
        // Sunrise 04:13, sunset 20:17 at UTC+1.
        assert_eq!(day.up.first().unwrap().time, time("05:00"));
        assert_eq!(day.up.last().unwrap().time, time("20:00"));
        assert_eq!(day.up.len(), 16);
        assert_eq!(
            day.night_note().unwrap(),
            "8 of 24 suns left out, below the horizon: 00:00 to 04:00, 21:00 to 23:00"
        );
        assert!(day.up.iter().all(|s| s.sun.elevation_deg() >= 0.0));
        assert!(!day.has_seconds());
        // The polar night: nothing to render, and the error says where and when.
        let polar = SunPath::new(
            Place::new(80.0, 15.0).unwrap(),
            date("2026-12-21"),
            UtcOffset::UTC,
            time("00:00"),
            time("23:59"),
            "15m".parse().unwrap(),
        )
        .unwrap();
        assert_eq!(
            polar.day().unwrap_err().to_string(),
            "the sun never rises above the horizon at 80.0°N on 2026-12-21 between 00:00 and 23:59"
        );
        // The midnight sun: no note.
        let polar = SunPath::new(
            Place::new(80.0, 15.0).unwrap(),
            date("2026-06-21"),
            UtcOffset::UTC,
            time("00:00"),
            time("23:59"),
            "1h".parse().unwrap(),
        )
        .unwrap();
        assert_eq!(polar.day().unwrap().night_note(), None);
    }

    #[test]
    fn a_sun_below_the_horizon_is_refused_with_its_depth() {
        let t = SolarTime {
            place: munich(),
            date: date("2026-06-21"),
            time: time("23:30"),
            offset: "+02:00".parse().unwrap(),
        };
        let e = t.sun().unwrap_err().to_string();
        assert!(
            e.starts_with("the sun is ")
                && e.contains(
                    "° below the horizon at 48.1°N 11.6°E on 2026-06-21 at 23:30 (UTC+02:00)"
                ),
            "{e}"
        );
    }

    #[test]
    fn places_dates_times_offsets_and_steps_parse_or_say_why_not() {
        assert_eq!(Place::new(91.0, 0.0), Err(SolarError::Latitude(91.0)));
        assert_eq!(Place::new(0.0, 200.0), Err(SolarError::Longitude(200.0)));
        assert!(Place::new(f64::NAN, 0.0).is_err());
        assert_eq!(
            Place::new(-33.9, -70.6).unwrap().to_string(),
            "33.9°S 70.6°W"
        );
        assert_eq!(
            Place::new(39.7, -105.2).unwrap().zone_offset().seconds(),
            -7 * 3600
        );
        assert_eq!(
            Place::new(0.0, 180.0).unwrap().zone_offset().seconds(),
            12 * 3600
        );

        assert_eq!(date("2024-02-29").to_string(), "2024-02-29");
        assert_eq!(
            "2026-02-30".parse::<Date>().unwrap_err().to_string(),
            "date '2026-02-30' does not exist: February 2026 has 28 days"
        );
        for bad in [
            "2026-13-01",
            "2026-6-21",
            "21.06.2026",
            "2026-06-00",
            "",
            "2026-06-21x",
        ] {
            assert!(
                matches!(bad.parse::<Date>(), Err(SolarError::DateSyntax(_))),
                "{bad}"
            );
        }
        assert!("1900-02-29".parse::<Date>().is_err());
        assert_eq!(date("1970-01-01").days_since_epoch(), 0);
        assert_eq!(date("2000-03-01").days_since_epoch(), 11_017);
        assert_eq!(date("1969-12-31").days_since_epoch(), -1);

        assert_eq!(time("14:30").seconds(), 14 * 3600 + 30 * 60);
        assert_eq!(time("05:00:30").to_string(), "05:00:30");
        assert_eq!(time("5:07").to_string(), "05:07");
        assert_eq!(time("05:07").compact(false), "0507");
        assert_eq!(time("05:07:09").compact(true), "050709");
        for bad in ["24:00", "12:60", "12", "12:00:60", "1230", "12:3x", "-1:00"] {
            assert!(bad.parse::<ClockTime>().is_err(), "{bad}");
        }

        for (s, secs) in [
            ("+02:00", 7200),
            ("-07:00", -25_200),
            ("+05:30", 19_800),
            ("+2", 7200),
            ("-0700", -25_200),
            ("Z", 0),
            ("+14:00", 50_400),
        ] {
            assert_eq!(s.parse::<UtcOffset>().unwrap().seconds(), secs, "{s}");
        }
        assert_eq!(
            "-07:00".parse::<UtcOffset>().unwrap().to_string(),
            "UTC-07:00"
        );
        for bad in [
            "02:00", "+15:00", "-13:00", "+02:60", "+", "+2h", "UTC+2", "+1é2",
        ] {
            assert!(bad.parse::<UtcOffset>().is_err(), "{bad}");
        }

        for (s, secs) in [
            ("15m", 900),
            ("1h", 3600),
            ("90s", 90),
            ("1h30m", 5400),
            ("2h0m5s", 7205),
        ] {
            let step: Step = s.parse().unwrap();
            assert_eq!(step.seconds(), secs, "{s}");
        }
        assert_eq!("90s".parse::<Step>().unwrap().to_string(), "1m30s");
        for zero in ["0", "0m", "0h0s"] {
            assert!(
                matches!(zero.parse::<Step>(), Err(SolarError::StepZero(_))),
                "{zero}"
            );
        }
        for bad in ["15", "m", "1m1h", "1h1h", "1.5h", "", "15 m", "-15m"] {
            assert!(
                matches!(bad.parse::<Step>(), Err(SolarError::StepSyntax(_))),
                "{bad}"
            );
        }
    }

    proptest::proptest! {
        /// Any text is a value or an error, never a panic (`+1é2` once split a character).
        #[test]
        fn parsers_never_panic(text in "\\PC{0,12}", ascii in "[-+:0-9hmsZ]{0,8}") {
            for t in [&text, &ascii] {
                let _ = t.parse::<Date>();
                let _ = t.parse::<ClockTime>();
                let _ = t.parse::<UtcOffset>();
                let _ = t.parse::<Step>();
            }
        }

        /// What is written reads back as itself.
        #[test]
        fn values_round_trip_through_their_text(
            secs in 0u32..86_400,
            offset_min in -12 * 60i32..=14 * 60,
            step in 1u32..86_400,
        ) {
            let t = ClockTime(secs);
            proptest::prop_assert_eq!(t.to_string().parse::<ClockTime>().unwrap(), t);
            let o = UtcOffset(offset_min * 60);
            let text = o.to_string();
            proptest::prop_assert_eq!(text["UTC".len()..].parse::<UtcOffset>().unwrap(), o);
            let s = Step(step);
            proptest::prop_assert_eq!(s.to_string().parse::<Step>().unwrap(), s);
        }
    }

    /// Day by day from 1896 to 2104 (leap years, 1900 and 2100 not, 2000 yes), the day count
    /// grows by one, and every date reads back from its text.
    #[test]
    fn calendar_days_count_one_by_one() {
        let mut d = date("1896-01-01");
        let mut k = d.days_since_epoch();
        assert_eq!(k, -27_028);
        while d != date("2105-01-01") {
            d = if d.day < days_in_month(d.year, d.month) {
                Date {
                    day: d.day + 1,
                    ..d
                }
            } else if d.month < 12 {
                Date {
                    month: d.month + 1,
                    day: 1,
                    ..d
                }
            } else {
                Date {
                    year: d.year + 1,
                    month: 1,
                    day: 1,
                }
            };
            k += 1;
            assert_eq!(d.days_since_epoch(), k, "{d}");
            assert_eq!(d.to_string().parse::<Date>().unwrap(), d);
        }
        assert_eq!(days_in_month(1900, 2), 28);
        assert_eq!(days_in_month(2000, 2), 29);
    }

    #[test]
    fn a_path_runs_forwards_and_is_bounded() {
        let p = |from: &str, to: &str, step: &str| {
            SunPath::new(
                munich(),
                date("2026-06-21"),
                UtcOffset::UTC,
                time(from),
                time(to),
                step.parse().unwrap(),
            )
        };
        assert_eq!(
            p("21:00", "05:00", "1h").unwrap_err().to_string(),
            "the path starts at 21:00, after it ends at 05:00: --from must not be after --to"
        );
        let times: Vec<String> = p("05:00", "06:00", "25m")
            .unwrap()
            .times()
            .map(|t| t.to_string())
            .collect();
        assert_eq!(times, ["05:00", "05:25", "05:50"]);
        assert_eq!(p("12:00", "12:00", "1h").unwrap().count(), 1);
        assert!(matches!(
            p("00:00", "23:59", "1m"),
            Err(SolarError::TooManySuns { count: 1440, .. })
        ));
    }
}
