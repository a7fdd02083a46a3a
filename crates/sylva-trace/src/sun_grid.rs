//! The sun-aligned grid for shadow rays (004 §4.1, SPEC §3): a 2-D grid of tiles on a plane
//! whose normal is the sun direction, each tile listing the instances whose world boxes,
//! projected along the sun, overlap it. Rebuilt whenever the sun moves (one pass over the
//! instances' boxes).
//!
//! Every shadow ray towards the sun is parallel to the plane's normal, so it projects to one
//! point: the instances it can meet are those of one tile, found in O(1), instead of a walk
//! through the top-level kd-tree. Inside an instance the ray is traced through the model's
//! kd-tree as usual (the paper uses a uniform grid there; our per-model kd-trees are already
//! built and measured). The answer is exactly the kd path's: a box meets the ray only if the
//! ray's point lies in the box's projection, tiles list every instance whose (slightly
//! enlarged) projected rectangle overlaps them, and the instances found are entered in the
//! same order (nearest box first) with the same tests.

use glam::{Vec2, Vec3};

use crate::kdtree::{TraceStats, TraversalConfig};
use crate::query::{KdTracer, RayQuery, ShadowRay};
use crate::ray::{Hit, Ray};
use crate::scene::{OccluderCache, SceneAccel, TraceInstance};

/// At most this many tiles along a side.
const MAX_TILES: usize = 1024;

/// Instances binned by their projection along the sun.
#[derive(Debug, Clone)]
pub struct SunGrid {
    /// Unit vector towards the sun (the plane's normal).
    to_sun: Vec3,
    /// Orthonormal axes of the plane.
    u: Vec3,
    v: Vec3,
    /// Plane coordinates of tile (0, 0)'s corner.
    origin: Vec2,
    /// One past the far corner of the last tile.
    end: Vec2,
    inv_cell: f32,
    nu: usize,
    nv: usize,
    /// Tile `t` lists `items[starts[t]..starts[t + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl SunGrid {
    /// Bins the instances of `accel` for rays towards `to_sun` (any length). A zero or
    /// non-finite direction gives a grid that serves no ray ([`SunGrid::serves`]).
    pub fn build(accel: &SceneAccel, to_sun: Vec3) -> SunGrid {
        let d = to_sun.normalize_or_zero();
        let empty = SunGrid {
            to_sun: d,
            u: Vec3::ZERO,
            v: Vec3::ZERO,
            origin: Vec2::ZERO,
            end: Vec2::ZERO,
            inv_cell: 0.0,
            nu: 0,
            nv: 0,
            starts: vec![0],
            items: Vec::new(),
        };
        if !d.is_finite() || d == Vec3::ZERO {
            return SunGrid {
                to_sun: Vec3::ZERO,
                ..empty
            };
        }
        let u = d.any_orthonormal_vector();
        let v = d.cross(u);
        let rects: Vec<Option<[Vec2; 2]>> = accel
            .instances()
            .iter()
            .map(|i| project(&i.world_bounds, u, v))
            .collect();
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        let mut side = 0.0f64;
        let mut count = 0usize;
        for [a, b] in rects.iter().flatten() {
            lo = lo.min(*a);
            hi = hi.max(*b);
            side += ((b.x - a.x) as f64 * (b.y - a.y) as f64).sqrt();
            count += 1;
        }
        if count == 0 {
            return SunGrid { u, v, ..empty };
        }
        let extent = (hi - lo).max_element().max(1e-6);
        // Tiles about half an instance's projected side: a box covers a few tiles, a tile
        // holds the handful of trees that can shade its point.
        let cell = ((side / count as f64) as f32 * 0.5)
            .max(extent / MAX_TILES as f32)
            .max(1e-6);
        let nu = (((hi.x - lo.x) / cell).floor() as usize + 1).min(MAX_TILES);
        let nv = (((hi.y - lo.y) / cell).floor() as usize + 1).min(MAX_TILES);
        let mut grid = SunGrid {
            to_sun: d,
            u,
            v,
            origin: lo,
            end: hi,
            inv_cell: 1.0 / cell,
            nu,
            nv,
            starts: vec![0; nu * nv + 1],
            items: Vec::new(),
        };
        // Two passes: count per tile, then fill (instance order within a tile).
        let span = |g: &SunGrid, [a, b]: [Vec2; 2]| {
            let (u0, v0) = g.tile_of(a);
            let (u1, v1) = g.tile_of(b);
            (u0, v0, u1, v1)
        };
        for r in rects.iter().flatten() {
            let (u0, v0, u1, v1) = span(&grid, *r);
            for tv in v0..=v1 {
                for tu in u0..=u1 {
                    grid.starts[tv * nu + tu + 1] += 1;
                }
            }
        }
        for t in 0..nu * nv {
            grid.starts[t + 1] += grid.starts[t];
        }
        let mut fill = grid.starts.clone();
        grid.items = vec![0; grid.starts[nu * nv] as usize];
        for (i, r) in rects.iter().enumerate() {
            let Some(r) = r else { continue };
            let (u0, v0, u1, v1) = span(&grid, *r);
            for tv in v0..=v1 {
                for tu in u0..=u1 {
                    let t = tv * nu + tu;
                    grid.items[fill[t] as usize] = i as u32;
                    fill[t] += 1;
                }
            }
        }
        grid
    }

    /// The tile of plane point `p` (clamped to the grid).
    fn tile_of(&self, p: Vec2) -> (usize, usize) {
        let c = |x: f32, o: f32, n: usize| {
            (((x - o) * self.inv_cell).floor().max(0.0) as usize).min(n - 1)
        };
        (
            c(p.x, self.origin.x, self.nu),
            c(p.y, self.origin.y, self.nv),
        )
    }

    /// Unit vector towards the sun the grid was built for (zero for an unusable direction).
    pub fn to_sun(&self) -> Vec3 {
        self.to_sun
    }

    /// Tiles along each axis of the plane.
    pub fn tiles(&self) -> (usize, usize) {
        (self.nu, self.nv)
    }

    /// Whether a ray along `dir` is parallel to the sun direction, so the grid answers it.
    #[inline]
    pub fn serves(&self, dir: Vec3) -> bool {
        self.to_sun != Vec3::ZERO && dir.normalize_or_zero().dot(self.to_sun) >= 1.0 - 1e-6
    }

    /// Whether `ray` meets an opaque surface, as [`SceneAccel::any_hit_from`] answers, with
    /// the instances taken from the ray's tile when this grid serves its direction.
    pub fn any_hit(
        &self,
        accel: &SceneAccel,
        ray: &Ray,
        from: Option<u32>,
        cfg: TraversalConfig,
        stats: &mut TraceStats,
        cache: &mut OccluderCache,
    ) -> bool {
        let candidates = self.serves(ray.dir).then(|| self.candidates(ray.origin));
        accel.any_hit_among(candidates, ray, from, cfg, stats, cache)
    }

    /// The instances whose projected box covers the projection of world point `p` (a
    /// superset of those a ray from `p` towards the sun can meet).
    #[inline]
    pub fn candidates(&self, p: Vec3) -> &[u32] {
        if self.nu == 0 {
            return &[];
        }
        let q = Vec2::new(p.dot(self.u), p.dot(self.v));
        // Also false for NaN.
        if !(q.cmpge(self.origin).all() && q.cmple(self.end).all()) {
            return &[];
        }
        let (tu, tv) = self.tile_of(q);
        let t = tv * self.nu + tu;
        &self.items[self.starts[t] as usize..self.starts[t + 1] as usize]
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        ((self.starts.capacity() + self.items.capacity()) * 4 + std::mem::size_of::<Self>()) as u64
    }
}

/// The rectangle, in plane coordinates (axes `u`, `v`), that covers the projection of `b`,
/// enlarged a little so that rounding in projecting a point can never leave it out.
fn project(b: &sylva_geom::Aabb, u: Vec3, v: Vec3) -> Option<[Vec2; 2]> {
    if b.is_empty() || !(b.min.is_finite() && b.max.is_finite()) {
        return None;
    }
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for c in b.corners() {
        let q = Vec2::new(c.dot(u), c.dot(v));
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let eps = 1e-4 * (1.0 + b.min.abs().max(b.max.abs()).max_element());
    Some([lo - eps, hi + eps])
}

/// The CPU tracer with shadow rays towards the sun answered through a [`SunGrid`]; other
/// rays (closest hits, shadow rays in other directions) go to the kd-tree tracer.
pub struct SunGridQuery<'a> {
    pub tracer: &'a KdTracer,
    pub grid: &'a SunGrid,
}

impl<'a> SunGridQuery<'a> {
    pub fn new(tracer: &'a KdTracer, grid: &'a SunGrid) -> SunGridQuery<'a> {
        SunGridQuery { tracer, grid }
    }
}

impl RayQuery for SunGridQuery<'_> {
    fn preferred_batch(&self) -> usize {
        self.tracer.preferred_batch()
    }

    fn closest_hits(&self, rays: &[Ray], hits: &mut [Option<Hit>], stats: &mut TraceStats) {
        self.tracer.closest_hits(rays, hits, stats)
    }

    /// In order, one occluder cache for the batch, as the kd-tree tracer does.
    fn any_hits(&self, rays: &[ShadowRay], blocked: &mut [bool], stats: &mut TraceStats) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        let mut cache = OccluderCache::new();
        let (accel, cfg) = (&self.tracer.accel, self.tracer.traversal);
        for (r, b) in rays.iter().zip(blocked) {
            *b = if self.grid.serves(r.ray.dir) {
                self.grid
                    .any_hit(accel, &r.ray, r.from, cfg, stats, &mut cache)
            } else {
                accel.any_hit_from(&r.ray, r.from, cfg, stats, &mut cache)
            };
        }
    }

    fn instances(&self) -> &[TraceInstance] {
        self.tracer.instances()
    }

    fn geometric_normal(&self, hit: &Hit) -> Vec3 {
        self.tracer.geometric_normal(hit)
    }
}
