//! Snow cover on meshes (SPEC §2): Tokoi and Moriki's shadow-map snow probability, accumulation,
//! stabilization by the angle of repose and falling, exported as glTF.
