//! Clouds: volume rendering and the three intuitive editing modes (SPEC §3; Iwasaki, Dobashi and
//! Yamamoto, "cloud volume editing").
//!
//! - [`floor`]: the default density floor that takes a scan's noisy background out.
//! - [`state`]: a version's parameters ([`CloudState`], `state.json`) and the per-voxel ambient
//!   field ([`AmbientField`]).
//! - [`sun`]: the default sun direction, turned to graze a slab's plane.
//! - [`light`]: the sun transmittance on the grid, once per light direction (sheared line sweep).
//! - [`march`]: the camera-ray march of paper Eqs. 1–3, with the linear layers Ī and A.
//! - [`params`], [`run`]: the one-shot `cloud` pipeline.
//! - [`edit`]: sun colour from paint (§3.1), ambient from paint (§3.2, propagated by
//!   [`multigrid`]), sun direction by dragging a shadow (§3.3).

pub mod edit;
pub mod fastexp;
pub mod floor;
pub mod grid;
pub mod input;
pub mod kappa;
pub mod layers;
pub mod light;
pub mod march;
pub mod multigrid;
pub mod multiple;
pub mod params;
pub mod run;
pub mod skip;
pub mod state;
pub mod sun;

pub use edit::job::CloudEditParams;
pub use edit::{apply_edit, edit_outputs, edit_outputs_with, Edit, EditError, EditOutcome};
pub use input::{AMBIENT_FIELD, LAYERS};
pub use multiple::Scattering;
pub use params::{CloudParams, LayerOutput, View};
pub use run::run;
pub use state::{AmbientField, CloudState};
