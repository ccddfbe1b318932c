//! Clouds: volume rendering and the three intuitive editing modes (SPEC §3; Iwasaki, Dobashi and
//! Yamamoto). Filled in by the cloud pipeline work.
