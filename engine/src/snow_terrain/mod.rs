//! Snow on terrain (SPEC §1).
