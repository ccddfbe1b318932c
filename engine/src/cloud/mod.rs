//! Clouds: volume rendering and the three intuitive editing modes (SPEC §3; Iwasaki, Dobashi and
//! Yamamoto, "cloud volume editing").
//!
//! - [`state`]: a version's parameters ([`CloudState`], `state.json`) and the per-voxel ambient
//!   field ([`AmbientField`]).
//! - [`light`]: the sun transmittance on the grid, once per light direction (slice sweep).
//! - [`march`]: the camera-ray march of paper Eqs. 1–3, with the linear layers Ī and A.
//! - [`params`], [`run`]: the one-shot `cloud` pipeline.

pub mod grid;
pub mod light;
pub mod march;
pub mod params;
pub mod run;
pub mod state;

pub use params::{Layer, Params, View};
pub use run::run;
pub use state::{AmbientField, CloudState};
