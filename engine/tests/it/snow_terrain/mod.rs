//! Snow on terrain (SPEC §1): the descriptor, the pipeline's run and outputs, the view, the winter look.

mod cog_tiles;
mod descriptor;
mod run;
mod tiles;
mod view;
mod winter;
