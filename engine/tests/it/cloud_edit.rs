//! Placeholder module; owned by the cloud_edit work.
