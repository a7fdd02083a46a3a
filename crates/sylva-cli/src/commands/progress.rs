//! Progress bars that stay quiet when stderr is not a terminal (CI logs, pipes), and the
//! render pipeline's [`Progress`] drawn with them.

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sylva_geom::{Medium, Model};
use sylva_light::lighting::LightingReport;
use sylva_light::lighting::ShadedDensity;
use sylva_light::relight::{BasisReport, GlobalReport};
use sylva_light::report::LightEvent;
use sylva_light::Progress;

/// A bar over `len` units of work, labelled `what`.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>12} [{bar:32}] {pos}/{len} {msg} ({elapsed}, eta {eta})",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb
}

/// One bar per piece of pipeline work; `on_report` hears each LB report.
pub struct Bars<F> {
    current: Mutex<Option<ProgressBar>>,
    on_report: F,
}

impl<F: Fn(LightEvent) + Sync> Bars<F> {
    pub fn new(on_report: F) -> Bars<F> {
        Bars {
            current: Mutex::new(None),
            on_report,
        }
    }

    fn with(&self, f: impl FnOnce(&ProgressBar)) {
        if let Some(pb) = self.current.lock().expect("progress bar").as_ref() {
            f(pb);
        }
    }
}

impl<F: Fn(LightEvent) + Sync> Progress for Bars<F> {
    fn start(&self, what: &str, total: u64) {
        *self.current.lock().expect("progress bar") = Some(bar(total, what));
    }

    fn set(&self, done: u64, total: u64) {
        self.with(|pb| {
            pb.set_length(total);
            pb.set_position(done);
        });
    }

    fn advance(&self, n: u64) {
        self.with(|pb| pb.inc(n));
    }

    fn finish(&self) {
        if let Some(pb) = self.current.lock().expect("progress bar").take() {
            pb.finish_and_clear();
        }
    }

    fn model_lit(&self, model: &Model, report: &LightingReport) {
        self.finish();
        (self.on_report)(LightEvent::Lit(&model.name, report));
    }

    fn medium_lit(&self, medium: &Medium, reports: &[LightingReport]) {
        self.finish();
        for (report, which) in reports.iter().zip(["sun", "sky"]) {
            (self.on_report)(LightEvent::Lit(
                &format!("{} ({which})", medium.name),
                report,
            ));
        }
    }

    fn model_basis(&self, model: &Model, report: &BasisReport) {
        self.finish();
        (self.on_report)(LightEvent::Basis(model, report));
    }

    fn global_grid(&self, report: &GlobalReport) {
        self.finish();
        (self.on_report)(LightEvent::Global(report));
    }

    fn neighbour_shade(&self, model: &Model, shade: &ShadedDensity) {
        self.finish();
        (self.on_report)(LightEvent::Shade(
            &model.name,
            shade.own_depth,
            shade.added_depth,
        ));
    }

    fn density_warning(&self, model: &Model, warning: &str) {
        self.finish();
        (self.on_report)(LightEvent::Density(&model.name, warning));
    }

    fn shade_warning(&self, warning: &str) {
        self.finish();
        (self.on_report)(LightEvent::Shades(warning));
    }

    fn kd_trees(&self, cached: usize, built: usize, warnings: &[String]) {
        self.finish();
        (self.on_report)(LightEvent::KdTrees(cached, built, warnings));
    }
}
