//! `sylva view`: paper 004's interactive relighting as a local web app. A person drags the
//! sun over a forest (or sets a date, a time and a place) in the browser and the light
//! follows: the relit light's weights change, no LB solve is made.
//!
//! - [`server`]: HTTP and WebSocket (axum on tokio), the token and Origin checks, limits.
//! - [`worker`]: the one thread that owns the prepared scene and renders for every page:
//!   previews while input moves, refinement passes once it stops, latest input wins.
//! - [`protocol`]: the messages, checked before they reach the renderer (docs/view.md).
//! - [`orbit`]: the page's camera (orbit, pan, zoom) as the renderer's camera.
//! - [`assets`]: the page, embedded in the binary (no build step).
//! - [`bench`]: a client that drives the WebSocket as the page does and measures latency
//!   and frame rate (`sylva bench view`).
//!
//! Imports the pipeline (the prepared scene), the renderer (frames, tone mapping, images)
//! and the LB crate's solve counter; nothing imports it but the CLI.

pub mod assets;
pub mod bench;
pub mod orbit;
pub mod protocol;
pub mod server;
pub mod worker;

pub use server::{ReadyScene, ServeOptions, Server, ViewError};
pub use worker::WorkerOptions;
