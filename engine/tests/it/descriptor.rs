//! descriptor tests
