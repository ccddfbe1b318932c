//! Density-volume readers (SPEC §3 input): NumPy `.npy`, NRRD, raw float32, OpenVDB.
