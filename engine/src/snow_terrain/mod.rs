//! Snow on terrain (SPEC §1): Nakatani, Fujishiro and Ohno's surface descriptor.
//!
//! One module per step of the paper's algorithm (§4.1): [`smooth`] (lines 1–3 and 9), [`tsa`]
//! (line 5, Eq. 3), [`transfer`] (line 6, Eq. 4), [`altitude`] (line 7), [`sun`] (lines 10–15),
//! composed by [`descriptor`]; then [`colour`] (§4.2) and [`run`] (rendering and outputs).

pub mod altitude;
// LANDING pub mod colour;
pub mod descriptor;
// LANDING pub mod params;
// LANDING pub mod run;
pub mod smooth;
pub mod sun;
pub mod transfer;
pub mod tsa;

// LANDING pub use params::Params;
// LANDING pub use run::run;
