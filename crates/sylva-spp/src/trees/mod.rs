//! The SPP model applied to trees (003 §4-5) and its Monte Carlo test (003 Table 3).
//!
//! * [`meshes`]: the "meshes" the paper compares (connected leaf triangles: one leaf quad of
//!   a grown tree), their opaque area, centroid and normals.
//! * [`beam`]: parallel light over a scene and eq. 29 (depth and thickness of every mesh
//!   from the surfaces the light rays through it cross).
//! * [`gfactor`]: the G-factor (eqs. 23-28, Appendix A.2-A.3).
//! * [`shading`]: the slab solution at a mesh (eq. 19 at normal incidence along the light)
//!   and eq. 32 for Lambertian leaves.
//! * [`opacity_map`]: deep opacity maps per prototype and direction.
//! * [`system`]: the §5 rendering system (maps in 16-22 directions, instance grids of about
//!   16³, eq. 31 through a forest, G per grid point, the sky) and [`system::SppLight`], the
//!   SPP light as sylva's renderer takes it.
//! * [`photons`]: the Monte Carlo reference (photons from the light, Lambertian leaves with
//!   R = T, counts per mesh), deterministic for a seed whatever the thread count.
//! * [`synthetic`]: models with known answers (a slab-shaped "tree", stacked plates).
//! * [`experiment`]: 003 Table 3 (eq. 30 over depth-thickness categories) for a scene, with
//!   sylva's LB lighting as a fourth column.

pub mod beam;
pub mod experiment;
pub mod gfactor;
pub mod meshes;
pub mod opacity_map;
pub mod photons;
pub mod shading;
pub mod synthetic;
pub mod system;

/// Why the tree experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum TreeError {
    /// A parameter is outside its valid range.
    #[error("{name} = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: String,
        reason: &'static str,
    },
    /// The scene has nothing to compare.
    #[error("no leaf meshes to compare: {0}")]
    NoLeaves(String),
    #[error(transparent)]
    Slab(#[from] crate::SppError),
    #[error(transparent)]
    Trace(#[from] sylva_trace::TraceError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error(transparent)]
    Voxelize(#[from] sylva_voxel::VoxelizeError),
    #[error("LB parameters: {0}")]
    LbParams(#[from] sylva_lb::ParamError),
    #[error("LB lighting of model '{model}': {source}")]
    Lb {
        model: String,
        source: sylva_lb::LbSolverError,
    },
}

impl TreeError {
    pub(crate) fn invalid(name: &'static str, value: String, reason: &'static str) -> TreeError {
        TreeError::InvalidParameter {
            name,
            value,
            reason,
        }
    }
}
