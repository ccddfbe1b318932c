//! `phenomena-engine`: formats, geometry, rendering and the pipelines of `phenomena`.
//!
//! Nothing here is async and nothing knows about HTTP. A pipeline is a plain function from a decoded
//! input and validated parameters (plus a [`Control`] handle for progress and cancellation) to named
//! [`Output`]s; the CLI and the server's workers call the same functions.

pub mod cloud;
pub mod control;
pub mod dust;
pub mod error;
pub mod formats;
pub mod geom;
pub mod output;
pub mod params;
pub mod registry;
pub mod render;
pub mod snow_cover;
pub mod snow_terrain;
#[cfg(feature = "testkit")]
pub mod testkit;

pub use control::{Canceled, Control, NoControl, Span};
pub use error::{InputError, ParamError, Refusal};
pub use output::Output;
