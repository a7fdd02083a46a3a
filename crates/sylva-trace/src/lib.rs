//! The ray-tracing core of sylva (SPEC §2, paper 000 §3-4): what the renderer asks "what
//! does this ray hit first?" and "is this point in the sun?".
//!
//! * [`ray`]: [`Ray`], [`Hit`], the slab test and Möller-Trumbore with its edge rule.
//! * [`kdtree`]: SAH kd-trees (binned, exact triangle clipping, parallel and deterministic
//!   build, 8-byte nodes) and the short-stack traversal of 000 Fig. 1 with kd-restart.
//! * [`model`]: one model's tree plus triangle and alpha data; the alpha rule for leaves.
//! * [`scene`]: [`SceneAccel`], the two levels (instances over models) and the ground.
//! * [`camera`]: [`PinholeCamera`], primary rays from a scene's camera.
//! * [`query`]: [`RayQuery`], the batched closest-hit and shadow queries a renderer makes,
//!   and [`KdTracer`], the CPU tracer answering them.
//! * [`sun_grid`]: the sun-aligned tile grid of 004 §4.1 for shadow rays ([`SunGrid`]) and
//!   [`SunGridQuery`], the CPU tracer with shadow rays found through it.
//!
//! Shading, images and the `sylva render` command live elsewhere; see `docs/trace.md`.

pub mod camera;
pub mod kdtree;
pub mod model;
pub mod query;
pub mod ray;
pub mod scene;
pub mod sun_grid;

pub use camera::PinholeCamera;
pub use kdtree::{
    KdNode, KdTree, TraceStats, TraversalConfig, TreeStats, DEFAULT_STACK_SIZE, MAX_DEPTH, PACKET,
};
pub use model::{AlphaMask, ModelAccel};
pub use query::{KdTracer, RayQuery, ShadowRay};
pub use ray::{intersect_triangle, intersect_triangle_vertices, ray_box, Hit, Ray, TriangleData};
pub use scene::{
    AccelMemory, OccluderCache, SceneAccel, TraceError, TraceInstance, TreeCacheReport, KD_TREE,
};
pub use sun_grid::{SunGrid, SunGridQuery};
