//! The sun from date, time and place on the command line: `render --lat --lon --date --time`
//! and `relight --lat --lon --date --from --to --step`, with `--utc-offset`. Only parsing
//! here; `sylva_core::solar` places the sun (NREL's SPA; north is -z, east +x).

use anyhow::{anyhow, Result};
use clap::Args;
use sylva_core::solar::{ClockTime, Date, Place, SolarError, SolarTime, Step, SunPath, UtcOffset};

/// `sylva render`'s sun at a moment: `--lat 48.1 --lon 11.6 --date 2026-06-21 --time 14:30`.
#[derive(Args, Debug, Clone, Default)]
pub struct SunTimeArgs {
    /// Latitude in degrees, north positive (-90 to 90): with --lon, --date and --time the sun
    /// stands where it stands there and then (NREL's SPA, apparent position). The world's
    /// north is -z and east +x.
    #[arg(long, allow_negative_numbers = true, requires_all = ["lon", "date", "time"],
          conflicts_with_all = ["sun", "elevation", "azimuth"])]
    pub lat: Option<f64>,
    /// Longitude in degrees, east positive (-180 to 180).
    #[arg(long, allow_negative_numbers = true, requires_all = ["lat", "date", "time"],
          conflicts_with_all = ["sun", "elevation", "azimuth"])]
    pub lon: Option<f64>,
    /// Date, YYYY-MM-DD.
    #[arg(long, requires_all = ["lat", "lon", "time"],
          conflicts_with_all = ["sun", "elevation", "azimuth"])]
    pub date: Option<String>,
    /// Local clock time, HH:MM or HH:MM:SS (at --utc-offset); the sun must be up.
    #[arg(long, requires = "date", conflicts_with_all = ["sun", "elevation", "azimuth"])]
    pub time: Option<String>,
    /// Offset of the local clock from UTC, e.g. +02:00 or -07:00. Default: the zone of the
    /// longitude, round(lon / 15) hours (no daylight saving: Munich is +01:00).
    #[arg(long, requires = "date", allow_hyphen_values = true)]
    pub utc_offset: Option<String>,
}

impl SunTimeArgs {
    /// The moment asked for, or `None` without `--date`.
    pub fn moment(&self) -> Result<Option<SolarTime>> {
        let (Some(lat), Some(lon), Some(date), Some(time)) =
            (self.lat, self.lon, &self.date, &self.time)
        else {
            return Ok(None);
        };
        let (place, date, offset) = place_date_offset(lat, lon, date, &self.utc_offset)?;
        let time: ClockTime = time.parse().map_err(|e| anyhow!("--time: {e}"))?;
        Ok(Some(SolarTime {
            place,
            date,
            time,
            offset,
        }))
    }
}

/// `sylva relight`'s day: `--lat 48.1 --lon 11.6 --date 2026-06-21 --from 05:00 --to 21:00
/// --step 15m`.
#[derive(Args, Debug, Clone, Default)]
pub struct SunDayArgs {
    /// Latitude in degrees, north positive (-90 to 90): with --lon and --date the sun moves
    /// along its path of that day there (NREL's SPA, apparent position), one frame every
    /// --step from --from to --to, instead of 004's sequence. Frames with the sun below the
    /// horizon are left out (one note says which). The world's north is -z and east +x.
    #[arg(long, allow_negative_numbers = true, requires_all = ["lon", "date"],
          conflicts_with_all = ["suns", "path_azimuth"])]
    pub lat: Option<f64>,
    /// Longitude in degrees, east positive (-180 to 180).
    #[arg(long, allow_negative_numbers = true, requires_all = ["lat", "date"],
          conflicts_with_all = ["suns", "path_azimuth"])]
    pub lon: Option<f64>,
    /// Date, YYYY-MM-DD.
    #[arg(long, requires_all = ["lat", "lon"],
          conflicts_with_all = ["suns", "path_azimuth"])]
    pub date: Option<String>,
    /// First frame's local clock time, HH:MM or HH:MM:SS [default: 00:00].
    #[arg(long, requires = "date")]
    pub from: Option<String>,
    /// Last frame's local clock time at most (included when a step lands on it)
    /// [default: 23:59].
    #[arg(long, requires = "date")]
    pub to: Option<String>,
    /// Time between frames: 15m, 1h, 90s, 1h30m [default: 1h].
    #[arg(long, requires = "date")]
    pub step: Option<String>,
    /// Offset of the local clock from UTC, e.g. +02:00 or -07:00. Default: the zone of the
    /// longitude, round(lon / 15) hours (no daylight saving: Munich is +01:00).
    #[arg(long, requires = "date", allow_hyphen_values = true)]
    pub utc_offset: Option<String>,
}

impl SunDayArgs {
    /// The day's path asked for, or `None` without `--date`.
    pub fn path(&self) -> Result<Option<SunPath>> {
        let (Some(lat), Some(lon), Some(date)) = (self.lat, self.lon, &self.date) else {
            return Ok(None);
        };
        let (place, date, offset) = place_date_offset(lat, lon, date, &self.utc_offset)?;
        let time = |flag: &str, v: &Option<String>, default: &str| -> Result<ClockTime> {
            v.as_deref()
                .unwrap_or(default)
                .parse()
                .map_err(|e| anyhow!("--{flag}: {e}"))
        };
        let from = time("from", &self.from, "00:00")?;
        let to = time("to", &self.to, "23:59")?;
        let step: Step = self
            .step
            .as_deref()
            .unwrap_or("1h")
            .parse()
            .map_err(|e| anyhow!("--step: {e}"))?;
        Ok(Some(SunPath::new(place, date, offset, from, to, step)?))
    }
}

fn place_date_offset(
    lat: f64,
    lon: f64,
    date: &str,
    offset: &Option<String>,
) -> Result<(Place, Date, UtcOffset)> {
    let place = Place::new(lat, lon).map_err(|e| match e {
        SolarError::Latitude(_) => anyhow!("--lat: {e}"),
        _ => anyhow!("--lon: {e}"),
    })?;
    let date: Date = date.parse().map_err(|e| anyhow!("--date: {e}"))?;
    let offset = match offset {
        Some(o) => o.parse().map_err(|e| anyhow!("--utc-offset: {e}"))?,
        None => place.zone_offset(),
    };
    Ok((place, date, offset))
}
