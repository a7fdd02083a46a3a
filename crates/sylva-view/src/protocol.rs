//! What the page and the server say to each other over the WebSocket (docs/view.md).
//!
//! The page sends JSON text messages ([`ClientMessage`]); the server answers with JSON text
//! ([`ServerMessage`]) and with frames as binary messages ([`encode_frame`]: a little-endian
//! `u32` header length, the header as JSON, then the JPEG). Everything the page sends is
//! checked here ([`ViewRequest::resolve`]) before it reaches the renderer: a message that does
//! not parse, or asks for a NaN, an absurd size or an unknown mode, is answered with an
//! error and changes nothing.

use glam::Vec3;
use serde::{Deserialize, Serialize};
use sylva_core::solar::{ClockTime, Date, Place, SolarTime, UtcOffset};
use sylva_core::Sun;
use sylva_geom::Camera;
use sylva_render::Mode;

use crate::orbit::Orbit;

/// The largest text message the server reads; a view request is about 300 bytes.
pub const MAX_MESSAGE_BYTES: usize = 4096;
/// The largest frame side the page may ask for, in pixels.
pub const MAX_SIDE: u32 = 4096;
/// Messages a client may send per second (the page sends at most one per animation frame);
/// more are answered with an error and dropped.
pub const MAX_MESSAGES_PER_SECOND: u32 = 240;
/// The most final-gather rays per sample a page may ask for.
pub const MAX_GATHER_RAYS: u32 = sylva_render::gather::MAX_GATHER_RAYS;
/// Exposure range in stops about the automatic exposure.
pub const EXPOSURE_STOPS: f32 = 12.0;

/// A message from the page.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMessage {
    /// What to show now: the latest one wins, earlier ones still waiting are dropped.
    View(ViewRequest),
    /// Write the refined frame as it stands (`png` or `exr`) into the server's output folder.
    Save { format: String },
}

/// The page's controls.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ViewRequest {
    /// Increases with every request; frames carry the one they answer.
    pub seq: u64,
    pub sun: SunControl,
    pub camera: Orbit,
    /// `full`, `local` or `lb` (paper 000 Fig. 2; `ambient` too).
    pub mode: String,
    /// Final-gather rays per sample of the refined frames (previews use none).
    pub gather_rays: u32,
    /// Stops above (+) or below (-) the automatic exposure.
    pub exposure: f32,
    /// The refined frame's size (the canvas's pixels).
    pub width: u32,
    pub height: u32,
    /// The user is dragging: answer with a preview now, refine once input stops.
    pub interacting: bool,
}

/// Where the sun is: dragged on the compass, or the sun of a moment at a place.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "by", rename_all = "snake_case", deny_unknown_fields)]
pub enum SunControl {
    /// Degrees above the horizon, and compass degrees from north towards east (north is -z,
    /// east +x).
    Angles { elevation: f64, azimuth: f64 },
    /// NREL's SPA (`sylva_core::solar`): `date` as 2026-06-21, `time` as 14:30 local clock
    /// time, `utc_offset` as +01:00 (default: round(longitude / 15) hours).
    Clock {
        lat: f64,
        lon: f64,
        date: String,
        time: String,
        #[serde(default)]
        utc_offset: Option<String>,
    },
}

/// The sun resolved: its direction and where it stands, for the page's compass.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SunPosition {
    pub elevation: f64,
    /// Compass degrees from north towards east.
    pub azimuth: f64,
}

/// A [`ViewRequest`] checked and resolved: what the renderer needs.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    pub seq: u64,
    pub to_sun: Vec3,
    pub sun: SunPosition,
    pub orbit: Orbit,
    pub mode: Mode,
    pub gather_rays: u32,
    pub exposure: f32,
    pub width: u32,
    pub height: u32,
    pub interacting: bool,
}

impl View {
    /// The camera of this view at `width × height`, with the scene camera's field of view.
    pub fn camera(&self, scene: &Camera, width: u32, height: u32) -> Camera {
        self.orbit.camera(scene, width, height)
    }

    /// Whether `other` differs from this view only in what refining keeps (nothing: any
    /// change restarts the refinement, but an equal request need not).
    pub fn same_image(&self, other: &View) -> bool {
        View {
            seq: other.seq,
            interacting: other.interacting,
            ..self.clone()
        } == *other
    }
}

impl ViewRequest {
    /// Checks every field and resolves the sun; `max_pixels` bounds the frame's area.
    pub fn resolve(&self, max_pixels: u64) -> Result<View, String> {
        let mode = match self.mode.as_str() {
            "full" => Mode::Full,
            "local" => Mode::Local,
            "lb" => Mode::Lb,
            "ambient" => Mode::Ambient,
            m => return Err(format!("mode '{m}': expected full, local, lb or ambient")),
        };
        if self.gather_rays > MAX_GATHER_RAYS {
            return Err(format!(
                "gather_rays {}: 0 to {MAX_GATHER_RAYS}",
                self.gather_rays
            ));
        }
        if !(self.exposure.is_finite() && self.exposure.abs() <= EXPOSURE_STOPS) {
            return Err(format!(
                "exposure {}: -{EXPOSURE_STOPS} to {EXPOSURE_STOPS} stops",
                self.exposure
            ));
        }
        if !(1..=MAX_SIDE).contains(&self.width) || !(1..=MAX_SIDE).contains(&self.height) {
            return Err(format!(
                "frame {}x{}: each side 1 to {MAX_SIDE} pixels",
                self.width, self.height
            ));
        }
        if self.width as u64 * self.height as u64 > max_pixels {
            return Err(format!(
                "frame {}x{}: at most {max_pixels} pixels on this server (sylva view \
                 --max-pixels)",
                self.width, self.height
            ));
        }
        self.camera.check()?;
        let (sun, to_sun) = self.sun.resolve()?;
        Ok(View {
            seq: self.seq,
            to_sun,
            sun,
            orbit: self.camera,
            mode,
            gather_rays: self.gather_rays,
            exposure: self.exposure,
            width: self.width,
            height: self.height,
            interacting: self.interacting,
        })
    }
}

impl SunControl {
    /// The sun's position and the direction towards it; a sun below the horizon is refused
    /// with when and how far below.
    pub fn resolve(&self) -> Result<(SunPosition, Vec3), String> {
        let (elevation, azimuth) = match self {
            SunControl::Angles { elevation, azimuth } => {
                if !(elevation.is_finite() && azimuth.is_finite()) {
                    return Err(format!(
                        "sun elevation {elevation}, azimuth {azimuth}: not numbers"
                    ));
                }
                if !(*elevation > 0.0 && *elevation <= 90.0) {
                    return Err(format!(
                        "sun elevation {elevation}°: above the horizon, (0, 90]"
                    ));
                }
                (*elevation, azimuth.rem_euclid(360.0))
            }
            SunControl::Clock {
                lat,
                lon,
                date,
                time,
                utc_offset,
            } => {
                let place = Place::new(*lat, *lon).map_err(|e| e.to_string())?;
                let date: Date = date.parse().map_err(|e| format!("date: {e}"))?;
                let time: ClockTime = time.parse().map_err(|e| format!("time: {e}"))?;
                let offset = match utc_offset {
                    Some(o) => o
                        .parse::<UtcOffset>()
                        .map_err(|e| format!("utc_offset: {e}"))?,
                    None => place.zone_offset(),
                };
                let moment = SolarTime {
                    place,
                    date,
                    time,
                    offset,
                };
                let (_, angles) = moment.sun().map_err(|e| e.to_string())?;
                (angles.elevation_deg, angles.azimuth_deg)
            }
        };
        let sun = Sun::from_angles(elevation, sylva_core::solar::world_azimuth(azimuth))
            .map_err(|e| e.to_string())?;
        let d = sun.to_sun();
        Ok((
            SunPosition { elevation, azimuth },
            Vec3::new(d.x as f32, d.y as f32, d.z as f32),
        ))
    }
}

/// A message from the server, as JSON text.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// While the scene is prepared: what is being done (base solutions, kd-trees).
    Status { line: String },
    /// The scene is ready: what the page starts from.
    Hello(Hello),
    /// A request was refused (or the server failed): the page shows `message`.
    Error { seq: Option<u64>, message: String },
    /// A frame was written (the answer to a save), with the samples per pixel it holds.
    Saved { path: String, samples: u32 },
}

/// What the page needs to draw its controls.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Hello {
    pub scene: String,
    pub camera: Orbit,
    pub sun: SunPosition,
    /// Frame size the server suggests (the scene camera's).
    pub width: u32,
    pub height: u32,
    pub max_pixels: u64,
    pub gather_rays: u32,
    pub max_gather_rays: u32,
    /// Samples per pixel a refined frame accumulates before it stops.
    pub max_samples: u32,
    /// What lights the scene ("the physical light relit from its base solutions", ...).
    pub light: String,
    /// Whether moving the sun is free (base solutions), else the sun is fixed.
    pub sun_moves: bool,
    pub device: String,
    /// A suggested place and date for the time-of-day control.
    pub lat: f64,
    pub lon: f64,
}

/// What a frame carries besides its JPEG.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// The request it answers.
    pub seq: u64,
    /// `false`: a preview (reduced size, no gather, 1 sample); `true`: a refinement pass.
    pub refined: bool,
    pub width: u32,
    pub height: u32,
    /// Samples per pixel accumulated so far.
    pub samples: u32,
    /// Milliseconds rendering this pass (the refined frame: all its passes so far).
    pub render_ms: f64,
    pub encode_ms: f64,
    /// Milliseconds the last move of the sun took (no LB solve: the relit light's weights
    /// and the sun grid).
    pub relight_ms: f64,
    pub sun_elevation: f64,
    pub sun_azimuth: f64,
    /// LB solves since the scene was prepared (moving the sun solves nothing: 0).
    pub lb_solves: u64,
}

/// A frame as one binary message: header length (u32 LE), header JSON, JPEG bytes.
pub fn encode_frame(header: &FrameHeader, jpeg: &[u8]) -> Vec<u8> {
    let json = serde_json::to_vec(header).expect("a frame header serialises");
    let mut out = Vec::with_capacity(4 + json.len() + jpeg.len());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&json);
    out.extend_from_slice(jpeg);
    out
}

/// The inverse of [`encode_frame`] (the benchmark client and the tests read frames).
pub fn decode_frame(bytes: &[u8]) -> Result<(FrameHeader, &[u8]), String> {
    let len = bytes
        .get(..4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        .ok_or("frame shorter than its header length")?;
    let json = bytes
        .get(4..4 + len)
        .ok_or("frame shorter than its header")?;
    let header = serde_json::from_slice(json).map_err(|e| format!("frame header: {e}"))?;
    Ok((header, &bytes[4 + len..]))
}

/// Parses one text message from the page, bounded in size.
pub fn parse_client_message(text: &str) -> Result<ClientMessage, String> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(format!(
            "message of {} bytes: at most {MAX_MESSAGE_BYTES}",
            text.len()
        ));
    }
    serde_json::from_str(text).map_err(|e| format!("bad message: {e}"))
}
