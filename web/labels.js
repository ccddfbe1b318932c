// The parameter forms in the user's words (issue 23): per pipeline, the few main controls shown
// up front (the rest go under "Advanced"), and for every parameter a plain label, its unit and a
// one-line help. The API name is shown small beside each label for those who script the API;
// the schema's own description (openapi.yaml) stays as the field's longer help in "Advanced".

/** [label, unit, help]; unit and help may be empty. Shared names first, per-pipeline below. */
const COMMON = {
  width: ["Image width", "px", ""],
  height: ["Image height", "px", ""],
  camera: ["Camera", "", "The default view frames the whole input; orbit turns around it."],
  seed: ["Random seed", "", "The same seed gives the same image."],
  up_axis: ["Up axis of the mesh", "", "Which axis of the file points up."],
  sun_azimuth_deg: ["Sun direction (compass)", "°", "180 = from the south, 90 = from the east."],
  sun_elevation_deg: ["Sun height above the horizon", "°", "Low sun = long shadows, like morning or evening."],
  fog: ["Haze", "", "Aerial perspective: far things fade to the sky colour."],
  shadows: ["Cast shadows", "", ""],
};

const PER = {
  "snow-terrain": {
    preset: ["Look", "", "winter: snow on the upper part of any terrain; paper: the paper's exact settings."],
    snowline: ["Snowline", "m", "No snow below this elevation. Empty: chosen from the terrain's own elevations."],
    snowline_quantile: ["Snowline as a share of the terrain", "0–1", "0.3 = the snowline sits above the lowest 30 % of the land."],
    full_snow_quantile: ["Full snow from", "0–1", "Above this share of the land's elevations the snow is complete."],
    snow_band: ["Snowline transition", "m", "Height over which snow goes from none to full."],
    sun_strength: ["Sun melts snow on sunny slopes", "0–1", "0 = no melting, 1 = sunny faces bare."],
    swept_snow: ["Snow on open ground", "0–1", "How much snow the wind leaves on ridges and open slopes."],
    probe_radius: ["Hollow size that holds snow", "m", "Hollows smaller than this count as sheltered."],
    vertical_exaggeration: ["Vertical exaggeration", "×", "Stretches heights to show the relief."],
    auto_exaggeration: ["Automatic exaggeration", "", "Choose the vertical exaggeration from the terrain's size."],
    tsa_window: ["Descriptor window", "cells", "Neighbourhood of the tangent-sphere test (paper: 1)."],
    tsa_max: ["Largest sphere", "m", "Upper bound of the tangent-sphere radius."],
    b: ["Blend with the smoothed field", "0–1", "The paper's b."],
    smooth_radius: ["Smoothing radius", "cells", ""],
    smooth_iterations: ["Smoothing passes", "", ""],
    smooth_length: ["Smoothing length", "m", ""],
    sea_level: ["Sea level", "m", "Ground at or below this stays snow-free, in the sea colour."],
    altitude_exponent: ["Snow increase with height", "", "1 = linear, 2 = the paper's quadratic."],
    descriptor_smooth_iterations: ["Smooth the snow map", "passes", ""],
    sun_spread_deg: ["Sun-facing angle", "°", "Slopes facing within this angle of the sun lose snow."],
    sun_min_slope_deg: ["Flattest slope the sun affects", "°", ""],
    slope_start_deg: ["Snow slides from", "°", "Slopes steeper than this start to lose snow."],
    slope_end_deg: ["Bare from", "°", "Slopes steeper than this hold no snow."],
    rock_color: ["Rock colour", "", ""],
    snow_color: ["Snow colour", "", ""],
    sea_color: ["Sea colour", "", ""],
    shading: ["Shading", "", ""],
    ambient: ["Sky light", "0–1", ""],
    haze: ["Haze", "0–1", ""],
    samples: ["Anti-aliasing samples", "per pixel", "More = smoother edges, slower."],
    mesh_max_vertices: ["3-D model detail", "vertices", "Largest number of vertices in terrain.glb."],
    cell_size: ["Cell size", "m", "Overrides the file's georeferencing."],
    vertical_scale: ["Height unit", "m per unit", "For DEMs not in metres."],
    outputs: ["Files to write", "", ""],
    ambient_occlusion: ["Ambient occlusion", "0–1", "Darkens valleys and creases."],
    sky_tint: ["Sky tint", "0–1", "Blue sky light in the shadows."],
  },
  "snow-cover": {
    resolution: ["Detail of the snow simulation", "cells", "Grid cells along the scene's longest side."],
    directions: ["Snowfall directions", "", "More = smoother snow, slower."],
    spread_deg: ["Snowfall spread", "°", "How far flakes fall from vertical."],
    wind: ["Wind", "", "Tilts the snowfall; off = calm."],
    weight_directions: ["Weight the directions", "", ""],
    snowfall: ["Snowfall", "m/h", "A constant rate, or a schedule of [hour, rate] rows."],
    duration_h: ["Snowfall duration", "h", ""],
    steps: ["Simulation steps", "", "More = finer, slower."],
    reproject_every: ["Re-project every", "steps", ""],
    repose_angle_deg: ["Steepest slope snow holds", "°", "Snow slides off anything steeper."],
    max_stabilize_iterations: ["Sliding passes", "", ""],
    snow_max_triangles: ["3-D snow detail", "triangles", ""],
    sparse_depth: ["Thin snow", "m", ""],
    max_edge_length: ["Longest mesh edge", "m", ""],
    frames: ["Time-lapse frames", "", "0 = none."],
  },
  dust: {
    stickiness: ["How well dust sticks", "", "The dust amount on an open, level face (1 = fully dusty)."],
    slipperiness: ["How easily dust slides off", "", ""],
    dust_source: ["Where dust comes from", "", ""],
    exposure: ["Exposure to the air", "", ""],
    exposure_rays: ["Exposure rays", "", ""],
    shells: ["Dust shells", "", "Layers of fibres over the surface."],
    max_thickness: ["Thickest dust", "m", ""],
    noise_scale: ["Patchiness size", "m", ""],
    noise_octaves: ["Patchiness detail", "", ""],
    texture_size: ["Fibre texture size", "px", ""],
    fiber_tile: ["Fibre tile", "", ""],
    fibers: ["Fibres per tile", "", ""],
    fiber_length: ["Fibre length", "", ""],
    bends: ["Bends per fibre", "", ""],
    bend_angle_deg: ["Bend angle", "°", ""],
    fiber_decay: ["Fibre fade", "", ""],
    fiber_opacity: ["Fibre opacity", "0–1", ""],
    dust_color: ["Dust colour", "", ""],
    close_up: ["Close-up", "", ""],
  },
  cloud: {
    kappa: ["Density (extinction κ)", "per unit", "Higher = thicker, darker cloud. Empty: chosen from the volume."],
    kappa_auto: ["Choose κ automatically", "", ""],
    sun_direction: ["Sun direction vector", "x, y, z", "Overrides the compass and height below."],
    sun_color: ["Sun colour", "linear RGB", ""],
    ambient: ["Sky (ambient) colour", "linear RGB", ""],
    ambient_scale: ["Sky light strength", "×", ""],
    anisotropy: ["Forward scattering", "−1–1", "0 = even, near 1 = bright silver lining towards the sun."],
    background: ["Background colour", "", "Off = transparent."],
    step: ["Ray step", "cells", "Smaller = finer, slower."],
    scattering: ["Light bounces", "", "single: the paper; multiple: brighter, softer thick clouds."],
    albedo: ["Albedo", "0–1", "Share of light scattered rather than absorbed."],
    layers: ["Light layers", "", "Which light terms to render."],
    bounds: ["World box", "m", "Where the volume sits in the world."],
    dims: ["Grid size", "cells", "For raw volumes without a header."],
  },
};

/** The main controls per pipeline, in order; everything else is under "Advanced". */
export const MAIN = {
  "snow-terrain": ["snowline", "sun_strength", "sun_azimuth_deg", "sun_elevation_deg", "camera", "width", "height"],
  "snow-cover": ["snowfall", "duration_h", "wind", "repose_angle_deg", "sun_azimuth_deg", "sun_elevation_deg", "camera", "width", "height"],
  cloud: ["kappa", "scattering", "sun_azimuth_deg", "sun_elevation_deg", "sun_color", "ambient", "background", "camera", "width", "height"],
  dust: ["max_thickness", "stickiness", "dust_color", "shells", "sun_azimuth_deg", "sun_elevation_deg", "camera", "width", "height"],
};

/** Page-side presets: a name, a line of help, the parameters it sets (others go back to their
 * defaults). `winter` and `paper` are the engine's own presets (`preset`); `spring` is winter
 * with a higher snowline and a stronger sun. */
export const PRESETS = {
  "snow-terrain": [
    { key: "winter", label: "Winter", help: "Deep snow on the upper part of the terrain (the default).", set: { preset: "winter" } },
    { key: "spring", label: "Spring", help: "Snow only high up; sunny and steep slopes melt out.", set: { preset: "winter", snowline_quantile: 0.6, full_snow_quantile: 0.9, sun_strength: 0.9, swept_snow: 0.4, slope_start_deg: 28, slope_end_deg: 45 } },
    { key: "paper", label: "Paper", help: "The paper's settings and look (Nakatani et al.).", set: { preset: "paper" } },
  ],
};

/** The label, unit and help of a parameter. */
export function labelOf(pipeline, name) {
  const l = (PER[pipeline] && PER[pipeline][name]) || COMMON[name];
  return l ? { label: l[0], unit: l[1], help: l[2] } : { label: name.replace(/_/g, " "), unit: "", help: "" };
}
