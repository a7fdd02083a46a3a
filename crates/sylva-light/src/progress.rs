//! Progress of the long stages, reported to whoever drives them (the CLI draws bars, a
//! server streams it to a page); nothing in the libraries prints.

use sylva_geom::{Medium, Model};

use crate::lighting::{LightingReport, ShadedDensity};
use crate::relight::{BasisReport, GlobalReport};

/// What a long stage reports while it works. Every method has a default that ignores it;
/// calls may come from worker threads.
pub trait Progress: Sync {
    /// Work named `what` begins: `total` units.
    fn start(&self, _what: &str, _total: u64) {}
    /// `done` of `total` units (the total may change as the work learns its size).
    fn set(&self, _done: u64, _total: u64) {}
    /// `n` more units done.
    fn advance(&self, _n: u64) {}
    /// The work begun last is over.
    fn finish(&self) {}
    /// Model `model`'s LB lighting is ready: read from the cache, solved, or solved again
    /// because the cache entry was bad ([`LightingReport::source`]).
    fn model_lit(&self, _model: &Model, _report: &LightingReport) {}
    /// Medium `medium`'s LB lighting is ready: the reports of its sun and sky solves.
    fn medium_lit(&self, _medium: &Medium, _reports: &[LightingReport]) {}
    /// Model `model`'s base solutions are ready ([`BasisReport::source`] says from where).
    fn model_basis(&self, _model: &Model, _report: &BasisReport) {}
    /// The coarse global grid is ready.
    fn global_grid(&self, _report: &GlobalReport) {}
    /// The neighbours' foliage added to a model's density in a forest.
    fn neighbour_shade(&self, _model: &Model, _shade: &ShadedDensity) {}
    /// A model's cached density could not be used (voxelized again) or kept: why.
    fn density_warning(&self, _model: &Model, _warning: &str) {}
    /// A forest's cached neighbours' foliage could not be used (measured again) or kept: why.
    fn shade_warning(&self, _warning: &str) {}
    /// The models' kd-trees are ready: `cached` read from the cache, `built` built; why an
    /// entry could not be used (built again) or kept, naming the file.
    fn kd_trees(&self, _cached: usize, _built: usize, _warnings: &[String]) {}
}

/// Reports nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Progress for Silent {}
