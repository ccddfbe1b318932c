//! Snow on terrain (SPEC §1): Nakatani, Fujishiro and Ohno's surface descriptor.
//!
//! One module per step of the paper's algorithm (§4.1): [`smooth`] (lines 1–3 and 9), [`tsa`]
//! (line 5, Eq. 3), [`transfer`] (line 6, Eq. 4), [`altitude`] (line 7), [`sun`] (lines 10–15),
//! composed by [`descriptor`]; then [`colour`] (§4.2) and [`run`] (rendering and outputs).

pub mod altitude;
pub mod colour;
pub mod descriptor;
pub mod params;
pub mod run;
pub mod smooth;
pub mod sun;
pub mod transfer;
pub mod tsa;

pub use params::Params;
pub use run::run;
