//! A relit sequence (`sylva relight`, 004 Table 1): its suns ([`SunSequence`]: 004's path
//! over 90° about the zenith, or a day's path at a place), each frame relit from the base
//! solutions and rendered ([`PreparedScene::relight_frame`]), and the frame times
//! ([`SequenceTimes`]).

use std::fmt;
use std::time::Instant;

use glam::Vec3;
use sylva_core::solar::{DayPath, SunPath};
use sylva_light::relight::sun_path;
use sylva_light::Silent;
use sylva_render::render::{mean_luminance, FrameTimings, Mode, RenderSettings};

use crate::{PipelineError, PreparedScene, Runner};

/// The suns of a sequence, and each frame's label (the clock time on a day's path, else its
/// number) for its file name.
pub struct SunSequence {
    pub suns: Vec<Vec3>,
    pub labels: Vec<String>,
    /// The day's path and its suns above the horizon, when the suns are a day's.
    day: Option<(SunPath, DayPath)>,
    azimuth: f64,
}

impl SunSequence {
    /// 004's sequence: `count` suns over 90° about the zenith, the path's azimuth `azimuth`
    /// degrees.
    pub fn zenith(count: usize, azimuth: f64) -> SunSequence {
        let suns = sun_path(count, azimuth);
        let labels = (0..suns.len()).map(|k| format!("{k:02}")).collect();
        SunSequence {
            suns,
            labels,
            day: None,
            azimuth,
        }
    }

    /// The suns above the horizon of `day`, the path `path` over one day.
    pub fn day(path: SunPath, day: DayPath) -> SunSequence {
        let (suns, labels) = day
            .up
            .iter()
            .map(|s| (s.sun.to_sun().as_vec3(), s.time.compact(day.has_seconds())))
            .unzip();
        SunSequence {
            suns,
            labels,
            day: Some((path, day)),
            azimuth: 0.0,
        }
    }

    /// Where the suns are.
    pub fn describe(&self) -> String {
        match &self.day {
            Some((path, _)) => format!(
                "from {} to {} every {} at {} on {} ({}): the day's path (north -z, east +x)",
                path.from(),
                path.to(),
                path.step(),
                path.place(),
                path.date(),
                path.offset()
            ),
            None => format!(
                "over 90° about the zenith, path azimuth {:.1}°",
                self.azimuth
            ),
        }
    }

    /// Frame `k`'s sun as its line shows it: the clock time and the sun's compass angles on
    /// a day's path, else its elevation and world azimuth.
    pub fn at(&self, k: usize) -> String {
        match &self.day {
            Some((_, d)) => format!(
                " at {}: sun elevation {:5.1}° azimuth {:5.1}° from north",
                d.up[k].time, d.up[k].angles.elevation_deg, d.up[k].angles.azimuth_deg
            ),
            None => {
                let sun = self.suns[k];
                format!(
                    ": sun elevation {:5.1}° azimuth {:5.1}°",
                    sun.y.asin().to_degrees(),
                    sun.z.atan2(sun.x).to_degrees().rem_euclid(360.0)
                )
            }
        }
    }

    /// The note on a day's times left out with the sun below the horizon.
    pub fn night_note(&self) -> Option<String> {
        self.day.as_ref().and_then(|(_, d)| d.night_note())
    }
}

/// One frame of a sequence: its full-mode linear image and its times.
pub struct RelitFrame {
    pub hdr: Vec<[f32; 3]>,
    pub relight_seconds: f64,
    pub render_seconds: f64,
    pub timings: FrameTimings,
}

impl fmt::Display for RelitFrame {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            o,
            "{:.3} s (relight {:.4} s, render {:.3} s: primary {:.3}, shadow {:.3}, shading {:.3})",
            self.relight_seconds + self.render_seconds,
            self.relight_seconds,
            self.render_seconds,
            self.timings.primary_seconds,
            self.timings.shadow_seconds,
            self.timings.shading_seconds
        )
    }
}

impl PreparedScene {
    /// Moves the sun to `sun` (no LB solve) and renders a frame: every process of `runner`
    /// relights (cheap) and renders its share; the root gets the frame (`None` elsewhere).
    pub fn relight_frame(
        &mut self,
        runner: &dyn Runner,
        settings: &RenderSettings,
        sun: Vec3,
    ) -> Result<Option<RelitFrame>, PipelineError> {
        let t0 = Instant::now();
        self.set_sun(sun)?;
        let t1 = Instant::now();
        let Some(split) = self.render_split(runner, settings, &Silent)? else {
            return Ok(None);
        };
        let render_seconds = t1.elapsed().as_secs_f64();
        let frame = split.frame;
        Ok(Some(RelitFrame {
            hdr: frame.compose(Mode::Full),
            relight_seconds: (t1 - t0).as_secs_f64(),
            render_seconds,
            timings: frame.timings,
        }))
    }
}

/// A sequence's frame times and the mean luminance of its first and last frames.
#[derive(Debug, Clone, Default)]
pub struct SequenceTimes {
    pub seconds: Vec<f64>,
    pub first_luminance: f64,
    pub last_luminance: f64,
}

impl SequenceTimes {
    pub fn push(&mut self, frame: &RelitFrame) {
        let y = mean_luminance(&frame.hdr);
        if self.seconds.is_empty() {
            self.first_luminance = y;
        }
        self.last_luminance = y;
        self.seconds
            .push(frame.relight_seconds + frame.render_seconds);
    }
}

impl fmt::Display for SequenceTimes {
    /// Mean, median, least and most of the frame times, and the luminances.
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        let times = &self.seconds;
        let mean = times.iter().sum::<f64>() / times.len() as f64;
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        write!(
            o,
            "frame time: mean {mean:.3} s, median {:.3} s, min {:.3} s, max {:.3} s; mean luminance first {:.4}, last {:.4}; no LB solve while the sun moves",
            sorted[sorted.len() / 2],
            sorted[0],
            sorted[sorted.len() - 1],
            self.first_luminance,
            self.last_luminance
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 004's sequence: one label per sun, numbered; each frame's line gives its sun's
    /// elevation and world azimuth.
    #[test]
    fn zenith_sequence_labels_and_angles() {
        let s = SunSequence::zenith(3, 30.0);
        assert_eq!(s.labels, ["00", "01", "02"]);
        assert_eq!(s.at(1), ": sun elevation  90.0° azimuth   0.0°");
        assert_eq!(s.at(2), ": sun elevation  45.0° azimuth  30.0°");
        assert!(s.describe().ends_with("path azimuth 30.0°"));
        assert!(s.night_note().is_none());
    }

    /// Mean, median, least and most of the frame times, and the first and last frames'
    /// luminance.
    #[test]
    fn sequence_times_summarise_the_frames() {
        let frame = |seconds: f64, y: f32| RelitFrame {
            hdr: vec![[y; 3]; 4],
            relight_seconds: 0.0,
            render_seconds: seconds,
            timings: FrameTimings::default(),
        };
        let mut times = SequenceTimes::default();
        for (s, y) in [(3.0, 1.0), (1.0, 0.5), (2.0, 0.25)] {
            times.push(&frame(s, y));
        }
        assert_eq!(times.seconds, [3.0, 1.0, 2.0]);
        assert!((times.first_luminance - 1.0).abs() < 1e-6);
        assert!((times.last_luminance - 0.25).abs() < 1e-6);
        let text = times.to_string();
        assert!(
            text.starts_with("frame time: mean 2.000 s, median 2.000 s, min 1.000 s, max 3.000 s"),
            "{text}"
        );
    }
}
