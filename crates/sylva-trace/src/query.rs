//! What a renderer asks of a ray tracer, in batches: [`RayQuery`]. The CPU kd-tree tracer
//! ([`KdTracer`]) answers small batches from many threads at once and traces neighbouring
//! rays together (4-ray packets, an occluder cache per batch of shadow rays); a GPU tracer
//! would answer few large batches. Each says which batch size suits it, and the caller
//! groups its work accordingly.

use glam::Vec3;

use crate::kdtree::{TraceStats, TraversalConfig, PACKET};
use crate::ray::{Hit, Ray};
use crate::scene::{OccluderCache, SceneAccel, TraceInstance};

/// A shadow ray: is anything opaque on `ray` (`t_min < t ≤ t_max`)? `from` is the instance
/// the ray starts on, if any: the likeliest occluder, tried first. The answer does not
/// depend on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowRay {
    pub ray: Ray,
    pub from: Option<u32>,
}

/// Closest-hit and any-hit (shadow) queries over a scene, in batches. Answers are exact and
/// the same for any batching: a ray's hit is the one it would find alone.
///
/// Order matters for speed only: rays of a batch should come in coherent order, neighbours
/// next to each other (2×2 pixels, the samples of a pixel, shadow rays in the order of the
/// primary rays they continue), and the shadow rays of a region right after its primary rays.
pub trait RayQuery: Sync {
    /// Rays per call this implementation works best with. Callers gather about that many
    /// (whole image tiles) per call; calls may come from several threads at once.
    fn preferred_batch(&self) -> usize;

    /// `hits[i]`: the closest hit of `rays[i]` with `t_min < t ≤ t_max`, or `None` (ties:
    /// lowest instance, then triangle; the ground loses ties).
    fn closest_hits(&self, rays: &[Ray], hits: &mut [Option<Hit>], stats: &mut TraceStats);

    /// `blocked[i]`: whether anything opaque lies on `rays[i]`.
    fn any_hits(&self, rays: &[ShadowRay], blocked: &mut [bool], stats: &mut TraceStats);

    /// The instances as traced (model, transforms, world box), indexed as [`Hit::instance`].
    fn instances(&self) -> &[TraceInstance];

    /// World-space unit geometric normal at a hit (+y on the ground).
    fn geometric_normal(&self, hit: &Hit) -> Vec3;
}

/// The CPU tracer: a [`SceneAccel`] and how to traverse it.
#[derive(Debug, Clone)]
pub struct KdTracer {
    pub accel: SceneAccel,
    pub traversal: TraversalConfig,
}

impl KdTracer {
    pub fn new(accel: SceneAccel, traversal: TraversalConfig) -> KdTracer {
        KdTracer { accel, traversal }
    }
}

impl RayQuery for KdTracer {
    /// One 8×8 tile at one ray per pixel: batches are traced in parallel, one per thread,
    /// and a tile's rays stay in cache between its primary and shadow passes.
    fn preferred_batch(&self) -> usize {
        64
    }

    /// Consecutive rays in packets of [`PACKET`]: they share their way through the trees.
    fn closest_hits(&self, rays: &[Ray], hits: &mut [Option<Hit>], stats: &mut TraceStats) {
        assert_eq!(rays.len(), hits.len(), "one hit per ray");
        for (group, out) in rays.chunks(PACKET).zip(hits.chunks_mut(PACKET)) {
            let mut packet = [group[0]; PACKET];
            packet[..group.len()].copy_from_slice(group);
            let mask = (1u32 << group.len()) - 1;
            let found = self
                .accel
                .closest_hit_packet(&packet, mask, self.traversal, stats);
            out.copy_from_slice(&found[..group.len()]);
        }
    }

    /// In order, with one occluder cache for the whole batch: neighbouring shadow rays are
    /// often stopped by the same leaf.
    fn any_hits(&self, rays: &[ShadowRay], blocked: &mut [bool], stats: &mut TraceStats) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        let mut cache = OccluderCache::new();
        for (r, b) in rays.iter().zip(blocked) {
            *b = self
                .accel
                .any_hit_from(&r.ray, r.from, self.traversal, stats, &mut cache);
        }
    }

    fn instances(&self) -> &[TraceInstance] {
        self.accel.instances()
    }

    fn geometric_normal(&self, hit: &Hit) -> Vec3 {
        self.accel.geometric_normal(hit)
    }
}
