//! Stage timing from `tracing` spans. The pipeline opens one span per stage (names in
//! [`stage`]); [`StageClock`] is a `tracing-subscriber` layer that adds up, per span name, how
//! long the spans lived, for the `sylva render` stage summary and `bench trace --json`.
//!
//! A frame's passes (primary rays, shadow rays, shading) are not spans: they run fused inside
//! parallel loops, and their seconds are busy time split per pass ([`crate::FrameTimings`]).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tracing::span::{Attributes, Id};
use tracing::Subscriber;
use tracing_subscriber::layer::{Context, Layer};
use tracing_subscriber::registry::LookupSpan;

/// The stage span names.
pub mod stage {
    /// Reading or generating the scene, the sun override.
    pub const SCENE_BUILD: &str = "scene build";
    /// All models' LB lighting.
    pub const LB_PRECOMPUTE: &str = "LB precompute";
    /// One model's LB lighting (inside [`LB_PRECOMPUTE`]; field `model`).
    pub const LB_MODEL: &str = "LB model";
    /// The acceleration structure.
    pub const ACCEL_BUILD: &str = "acceleration build";
    /// One frame (its passes are [`crate::FrameTimings`]).
    pub const FRAME: &str = "frame";
    pub const TONE_MAPPING: &str = "tone mapping";
    pub const IMAGE_OUTPUT: &str = "image output";
}

/// Seconds and count of the closed spans of each name.
#[derive(Debug, Default)]
struct Totals(HashMap<&'static str, (f64, u64)>);

/// Collects span durations by name. Clone it freely: clones share the totals. A program
/// installs it (`tracing_subscriber::registry().with(clock)`); this library only opens spans.
#[derive(Debug, Clone, Default)]
pub struct StageClock {
    totals: Arc<Mutex<Totals>>,
}

/// When a span was created.
struct Opened(Instant);

impl StageClock {
    pub fn new() -> StageClock {
        StageClock::default()
    }

    /// Total seconds of the closed spans named `name` (0 when there were none).
    pub fn seconds(&self, name: &str) -> f64 {
        self.totals
            .lock()
            .expect("stage totals")
            .0
            .get(name)
            .map_or(0.0, |t| t.0)
    }

    /// How many spans named `name` have closed.
    pub fn count(&self, name: &str) -> u64 {
        self.totals
            .lock()
            .expect("stage totals")
            .0
            .get(name)
            .map_or(0, |t| t.1)
    }

    /// Forgets everything recorded so far.
    pub fn reset(&self) {
        self.totals.lock().expect("stage totals").0.clear();
    }
}

impl<S> Layer<S> for StageClock
where
    S: Subscriber + for<'a> LookupSpan<'a>,
{
    fn on_new_span(&self, _: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().insert(Opened(Instant::now()));
        }
    }

    fn on_close(&self, id: Id, ctx: Context<'_, S>) {
        let Some(span) = ctx.span(&id) else { return };
        let Some(seconds) = span
            .extensions()
            .get::<Opened>()
            .map(|o| o.0.elapsed().as_secs_f64())
        else {
            return;
        };
        let mut totals = self.totals.lock().expect("stage totals");
        let t = totals.0.entry(span.name()).or_default();
        t.0 += seconds;
        t.1 += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tracing_subscriber::layer::SubscriberExt;

    #[test]
    fn spans_are_timed_by_name_nested_and_summed() {
        let clock = StageClock::new();
        let subscriber = tracing_subscriber::registry().with(clock.clone());
        tracing::subscriber::with_default(subscriber, || {
            let outer = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
            for model in ["a", "b"] {
                let _m = tracing::info_span!(stage::LB_MODEL, model).entered();
                std::thread::sleep(Duration::from_millis(20));
            }
            drop(outer);
            // A span entered on another thread counts too.
            let span = tracing::info_span!(stage::FRAME);
            std::thread::scope(|s| {
                s.spawn(|| {
                    let _e = span.enter();
                    std::thread::sleep(Duration::from_millis(5));
                });
            });
            drop(span);
        });
        assert_eq!(clock.count(stage::LB_MODEL), 2);
        assert_eq!(clock.count(stage::LB_PRECOMPUTE), 1);
        let (models, all) = (
            clock.seconds(stage::LB_MODEL),
            clock.seconds(stage::LB_PRECOMPUTE),
        );
        assert!(models >= 0.04, "{models}");
        assert!(all >= models, "{all} < {models}");
        assert!(clock.seconds(stage::FRAME) >= 0.005);
        assert_eq!(clock.seconds(stage::ACCEL_BUILD), 0.0);
        clock.reset();
        assert_eq!(clock.count(stage::LB_MODEL), 0);
    }
}
