//! GPU access for sylva's compute work, through wgpu: which adapter runs it and the device
//! opened on it. Shared by the GPU LB solver (`sylva-lb-gpu`) and the GPU ray tracer
//! (`sylva-trace-gpu`); one render opens one device for both.
//!
//! Owns adapter choice ([`GpuContext`] with [`AdapterChoice`]: hardware only, or any adapter
//! including software ones such as Mesa's lavapipe), the device and its granted limits,
//! buffer creation and read-back with out-of-memory and validation errors turned into
//! [`GpuError`]s, and the GPU's copy bandwidth; [`open_device`] turns a user's
//! `cpu|gpu|auto` ([`Device`]) into a GPU or none.

pub mod context;
pub mod select;
pub mod timer;

pub use context::{AdapterChoice, ContextOptions, GpuContext};
pub use select::{open_device, quiet_headless_probing, Device, OpenedDevice};
pub use timer::PassTimer;
/// The wgpu version this crate is built on (for [`ContextOptions::backends`]).
pub use wgpu;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error("no {} adapter found (adapters seen: {seen}); {}", if *hardware_only { "hardware GPU" } else { "GPU" }, if *hardware_only { "use --device gpu to allow a software adapter such as lavapipe" } else { "install a Vulkan driver (e.g. mesa-vulkan-drivers for lavapipe) or use --device cpu" })]
    NoAdapter { hardware_only: bool, seen: String },
    #[error("cannot open a device on adapter '{adapter}': {message}")]
    Device { adapter: String, message: String },
    #[error("too large for this GPU: {0}")]
    TooLarge(String),
    #[error("GPU out of memory allocating {what}: {message}")]
    OutOfMemory { what: String, message: String },
    #[error("GPU error while {what}: {message}")]
    Wgpu { what: String, message: String },
}
