//! DEM readers (in progress)
