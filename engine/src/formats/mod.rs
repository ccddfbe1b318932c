//! Input decoders and output encoders.
