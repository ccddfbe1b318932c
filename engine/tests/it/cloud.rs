//! Placeholder module; owned by the cloud work.
