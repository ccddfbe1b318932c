//! Snow cover on meshes (SPEC §2): Tokoi and Moriki's shadow-map snow probability, accumulation,
//! stabilization by the angle of repose and falling, exported as glTF.
//!
//! This module holds the *model* (SPEC §2 steps 1–5), one file per paper step:
//! [`maps`] (the layered snow maps), [`region`] (§2.1 snow-possible regions, by depth peeling),
//! [`shadow`] and [`probability`] (§2.2 shadow maps and snow probability), [`snowfall`] (§2.3 and
//! the time loop [`simulate`]), [`settle`] (§2.4.1 stabilization and §2.4.2 falling). Everything is
//! deterministic for a seed and bit-identical for any number of rayon threads.

mod coarse;
pub mod maps;
pub mod params;
pub mod probability;
mod queue;
pub mod region;
mod route;
pub mod run;
#[doc(hidden)]
pub mod settle;
pub mod shadow;
pub mod shape;
pub mod simplify;
pub mod snowfall;
pub mod sparse;

pub use maps::{MapLayer, SnowMaps, SNOW_UNIT_M};
pub use probability::{snow_probability, snowfall_directions, Receiver, Wind};
pub use region::build_snow_maps;
pub use settle::{SettleReport, Settler};
pub use snowfall::{accumulate, simulate, MassBalance, ModelParams, ModelReport, Snowfall};

/// Stabilize `maps` once (allocates a [`Settler`]; reuse one across steps instead).
pub fn stabilize(
    maps: &mut SnowMaps,
    repose_deg: f32,
    max_iterations: usize,
    ctl: &dyn crate::Control,
) -> Result<SettleReport, crate::Canceled> {
    Settler::new(maps).stabilize(maps, repose_deg, max_iterations, ctl)
}

pub use params::SnowCoverParams;
pub use run::run;
