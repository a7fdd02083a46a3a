//! The sun from date, time and place on the command line: `render --lat --lon --date --time`
//! and `relight --lat --lon --date --from --to --step`, with `--utc-offset`. Only parsing
//! here; `sylva_core::solar` checks the flags and places the sun (NREL's SPA; north is -z,
//! east +x).

use anyhow::Result;
use clap::Args;
use sylva_core::solar::{DayFlags, SolarTime, SunPath};

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
        let utc_offset = self.utc_offset.as_deref();
        Ok(Some(
            DayFlags {
                lat,
                lon,
                date,
                utc_offset,
            }
            .moment(time)?,
        ))
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
        let utc_offset = self.utc_offset.as_deref();
        let day = DayFlags {
            lat,
            lon,
            date,
            utc_offset,
        };
        Ok(Some(day.path(
            self.from.as_deref(),
            self.to.as_deref(),
            self.step.as_deref(),
        )?))
    }
}
