//! Placeholder module; owned by the volume_formats work.
