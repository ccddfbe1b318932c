//! Rendering shared by the pipelines: cameras, images, the height-field ray caster.
