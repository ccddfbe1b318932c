// The Map tab (issue 22): a DEM as a web map in MapLibre GL JS. The DEM is uploaded once
// (POST /v1/assets); each (debounced) change of the form — the snow-terrain parameters that shape
// the map's tiles — creates the map resource again (POST /v1/maps: the same DEM and parameters
// give the same map id) and rebuilds the map from its TileJSON documents: our `relief` or `snow`
// layer over our `hillshade`, 3-D terrain from our `terrain-rgb` tiles (a raster-dem source,
// encoding mapbox), a legend, and the coordinates and ground height under the cursor.
//
// MapLibre GL JS is installed from the npm registry when the server is built (web/package.json,
// web/vendor.txt) and served under /web/vendor/; built without npm, the tab says in words that
// the map viewer is not installed, and still makes the map and lists its TileJSON links (any
// map client can use them).

import { el, say, problemOf, inputBox } from "./app.js";
import { buildForm, resolve } from "./form.js";
import { MAIN, labelOf } from "./labels.js";
import { vendorInfo } from "./viewer.js";

/** The viewer's module and style sheet under /web/vendor/ (web/vendor.txt). */
const MODULE = "maplibre-gl/dist/maplibre-gl.mjs";
const CSS = "/web/vendor/maplibre-gl/dist/maplibre-gl.css";

/** Snow-terrain parameters that shape only `render.png` and the other job outputs, never a
 * tile: left out of the map's form (they would make a new map id for the same tiles). */
const RENDER_ONLY = ["width", "height", "camera", "seed", "samples", "haze", "sky_tint", "ambient_occlusion",
  "vertical_exaggeration", "auto_exaggeration", "mesh_max_vertices", "outputs"];

/** The overlays a user can choose, drawn over the hillshade. */
const OVERLAYS = [
  ["relief", "Snowy relief", "the snowy landscape seen from above: rock and snow colours, sun shading and cast shadows"],
  ["snow", "Snow cover", "snow cover as white, transparent where the ground is bare"],
];

let maplibre = null;
function loadMaplibre() {
  maplibre ??= (async () => {
    if (!document.querySelector(`link[href="${CSS}"]`)) {
      const link = el("link", { rel: "stylesheet", href: CSS });
      document.head.append(link);
      await new Promise((ok) => { link.onload = ok; link.onerror = ok; });
    }
    const m = await import("maplibre-gl");
    return m.default || m;
  })();
  return maplibre;
}

const abs = (path) => new URL(path, location.href).href;

/** The MapLibre style of a map (`view`: the map resource), with `overlay` over the hillshade. */
function styleOf(view, overlay, opacity, terrain) {
  const tj = (layer) => abs(`${view.tilejson_url}?layer=${layer}`);
  return {
    version: 8,
    sources: {
      hillshade: { type: "raster", url: tj("hillshade"), tileSize: 256 },
      overlay: { type: "raster", url: tj(overlay), tileSize: 256 },
      dem: { type: "raster-dem", url: tj("terrain-rgb"), tileSize: 256, encoding: "mapbox" },
    },
    layers: [
      { id: "background", type: "background", paint: { "background-color": "#2b3a4a" } },
      { id: "hillshade", type: "raster", source: "hillshade" },
      { id: "overlay", type: "raster", source: "overlay", paint: { "raster-opacity": opacity } },
    ],
    ...(terrain ? { terrain: { source: "dem", exaggeration: terrain } } : {}),
  };
}

/** The Map tab in `panel`, its form built from `spec` (openapi.yaml). */
export function initMap(panel, spec) {
  const schema = spec.components.schemas.SnowTerrainParams;
  const state = { asset: null, timer: 0, seq: 0, view: null, map: null, overlay: "relief", terrain: 1.5, opacity: 0.85 };
  const status = el("p", { class: "status", role: "status", "aria-live": "polite", id: "status-map" });
  const empty = el("div", { class: "empty-state", id: "empty-map" },
    el("p", {}, el("strong", {}, "No map yet."), " Drop a georeferenced DEM (a GeoTIFF with its CRS) in the box, or press “Try the example”: the snow on it appears here as a map you can pan, zoom and tilt."),
    el("p", { class: "hint" }, "Every change of a setting makes the map again; tiles are computed as the map asks for them."));
  const stage = el("div", { class: "map-stage", id: "map-view", hidden: true });
  const msg = el("p", { class: "map-msg", id: "map-msg", "aria-live": "polite", hidden: true });
  const coords = el("p", { class: "map-coords", id: "map-coords", "aria-live": "off", hidden: true }, "Move the pointer over the map to read its coordinates.");
  const legend = el("figure", { class: "map-legend", id: "map-legend", hidden: true });
  const links = el("div", { class: "map-links", id: "map-links", hidden: true });
  const error = (m, detail) => say(status, m, { error: true, detail });

  const { form, values } = buildForm(spec, schema, "map", () => schedule(),
    { main: (MAIN["snow-terrain"] || []).filter((n) => !RENDER_ONLY.includes(n)), labels: (n) => labelOf("snow-terrain", n), skip: RENDER_ONLY });

  // What the map shows: the overlay, its opacity, and the 3-D terrain's exaggeration.
  const show = el("fieldset", { class: "map-choice", id: "map-choice" }, el("legend", {}, "Show"));
  for (const [key, label, help] of OVERLAYS) {
    const r = el("input", { type: "radio", name: "map-overlay", id: `map-overlay-${key}`, value: key, checked: key === state.overlay, "aria-describedby": `map-overlay-${key}-d` });
    r.addEventListener("change", () => { state.overlay = key; rebuild(); });
    show.append(el("span", { class: "preset" }, r, " ", el("label", { for: r.id, class: "inline" }, `${label} over the hillshade`),
      el("small", { class: "desc", id: `map-overlay-${key}-d` }, help)));
  }
  const opacity = el("input", { type: "range", id: "map-opacity", min: 0, max: 1, step: 0.05, value: state.opacity });
  opacity.addEventListener("input", () => {
    state.opacity = Number(opacity.value);
    if (state.map && state.map.getLayer("overlay")) state.map.setPaintProperty("overlay", "raster-opacity", state.opacity);
  });
  const terrain = el("input", { type: "checkbox", id: "map-terrain", checked: true });
  const exag = el("input", { type: "number", id: "map-exaggeration", min: 0.5, max: 5, step: 0.5, value: state.terrain });
  const setTerrain = () => {
    const x = Number(exag.value);
    state.terrain = terrain.checked && Number.isFinite(x) && x > 0 ? x : 0;
    exag.disabled = !terrain.checked;
    if (!state.map) return;
    state.map.setTerrain(state.terrain ? { source: "dem", exaggeration: state.terrain } : null);
    if (state.terrain && state.map.getPitch() < 30) state.map.easeTo({ pitch: 55, duration: 0 });
    stage.dataset.terrain = state.terrain ? "on" : "off";
  };
  terrain.addEventListener("change", setTerrain);
  exag.addEventListener("change", setTerrain);
  show.append(
    el("span", {}, el("label", { for: opacity.id, class: "inline" }, "Overlay opacity"), " ", opacity),
    el("span", {}, terrain, " ", el("label", { for: terrain.id, class: "inline" }, "3-D terrain (from the terrain-rgb tiles)")),
    el("span", {}, el("label", { for: exag.id, class: "inline" }, "Height exaggeration (×)"), " ", exag));

  function schedule() {
    clearTimeout(state.timer);
    if (state.asset) state.timer = setTimeout(make, 350);
  }

  /** POST /v1/maps with the asset and the form's parameters, then (re)builds the map. */
  async function make() {
    clearTimeout(state.timer);
    if (!state.asset) return;
    const seq = ++state.seq;
    const { values: p, bad } = values();
    if (bad.length) return error(`Not sent: fix ${bad.map((n) => labelOf("snow-terrain", n).label).join(", ")} (a number out of its range, or an incomplete value).`);
    say(status, "Making the map…");
    const resp = await fetch("/v1/maps", {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ asset: state.asset.id, params: p }),
    });
    if (seq !== state.seq) return;
    if (!resp.ok) {
      const pr = await problemOf(resp);
      panel.dataset.status = "rejected";
      return error(pr.message, pr.detail);
    }
    const view = await resp.json();
    if (seq !== state.seq) return;
    state.view = view;
    panel.dataset.map = view.id;
    panel.dataset.status = "ready";
    empty.hidden = true;
    linksOf(view);
    await rebuild();
  }

  /** Draws the current map: creates the MapLibre map on the first call, else swaps its style. */
  async function rebuild() {
    const view = state.view;
    if (!view) return;
    legendOf();
    const info = await vendorInfo();
    if (!info.installed || !(info.files || []).includes(MODULE)) {
      stage.hidden = true;
      coords.hidden = true;
      msg.hidden = false;
      stage.dataset.state = "unavailable";
      msg.textContent = `The map viewer is not installed on this server: it was built without npm, so MapLibre GL JS (from the npm registry) is missing${info.reason ? ` (${info.reason})` : ""}. ${info.install || "Install Node.js with npm and rebuild the server"}. The map itself works: its TileJSON links below open in any map client (QGIS, MapLibre, OpenLayers).`;
      panel.dataset.viewer = "unavailable";
      return say(status, `Map ${view.id.slice(0, 12)}… made (${view.width} × ${view.height} cells, ${view.crs}).`);
    }
    stage.hidden = false;
    coords.hidden = false;
    msg.hidden = true;
    let lib;
    try {
      lib = await loadMaplibre();
    } catch (e) {
      msg.hidden = false;
      msg.textContent = `The map viewer could not be loaded: ${e.message || e}`;
      return;
    }
    const style = styleOf(view, state.overlay, state.opacity, state.terrain);
    stage.dataset.state = "loading";
    if (!state.map) {
      const [w, s, e, n] = view.bounds;
      const map = new lib.Map({
        container: stage,
        style,
        bounds: [[w, s], [e, n]],
        fitBoundsOptions: { padding: 20 },
        pitch: state.terrain ? 55 : 0,
        maxPitch: 80,
        attributionControl: { compact: true },
        // The screenshot in the browser test reads the canvas.
        canvasContextAttributes: { preserveDrawingBuffer: true },
      });
      map.addControl(new lib.NavigationControl({ visualizePitch: true }), "top-right");
      map.addControl(new lib.ScaleControl({ unit: "metric" }), "bottom-left");
      map.on("mousemove", (ev) => {
        const { lng, lat } = ev.lngLat;
        const t = map.getTerrain();
        const z = t ? map.queryTerrainElevation(ev.lngLat) : null;
        const h = z !== null && z !== undefined && t ? ` · ground ≈ ${Math.round(z / t.exaggeration)} m` : "";
        coords.textContent = `${lat.toFixed(5)}° ${lat >= 0 ? "N" : "S"}, ${Math.abs(lng).toFixed(5)}° ${lng >= 0 ? "E" : "W"}${h}`;
        coords.dataset.lng = String(lng);
        coords.dataset.lat = String(lat);
      });
      map.on("mouseout", () => { coords.textContent = "Move the pointer over the map to read its coordinates."; });
      map.on("idle", () => {
        stage.dataset.state = "ready";
        stage.dataset.shown = state.view.id;
      });
      map.on("error", (ev) => {
        // A tile that failed (not a 204 outside the DEM: MapLibre takes an empty body as no tile).
        const m = ev.error && ev.error.message ? ev.error.message : String(ev.error || ev);
        say(status, `The map could not load a part: ${m}`, { error: true });
      });
      state.map = map;
      // For scripts and the browser test: the MapLibre map of this tab.
      stage.maplibre = map;
      const canvas = map.getCanvas();
      canvas.setAttribute("aria-label", "Map of the snow on the terrain: drag to pan, scroll to zoom, right-drag or Ctrl+drag to tilt and turn");
    } else {
      stage.dataset.shown = "";
      state.map.setStyle(style, { diff: false });
    }
    stage.dataset.terrain = state.terrain ? "on" : "off";
    stage.dataset.overlay = state.overlay;
    say(status, `Map ${view.id.slice(0, 12)}…: ${view.width} × ${view.height} cells (${view.crs}), zoom ${view.minzoom}–${view.maxzoom}.`);
  }

  /** The legend of the overlay: snow cover from none to full, in the colours the tiles use. */
  function legendOf() {
    const { values: p } = values();
    const colour = (name) => p[name] || resolve(spec, schema.properties[name]).default;
    const relief = state.overlay === "relief";
    const from = relief ? colour("rock_color") : "rgba(255,255,255,0)";
    const to = relief ? colour("snow_color") : "#ffffff";
    legend.hidden = false;
    legend.dataset.overlay = state.overlay;
    legend.replaceChildren(
      el("figcaption", {}, relief ? "Snow cover (relief: bare rock to full snow, lit by the sun)" : "Snow cover s (white, over the hillshade)"),
      el("div", { class: "ramp", role: "img", "aria-label": `A colour ramp from ${relief ? "the rock colour" : "transparent"} at no snow to ${relief ? "the snow colour" : "white"} at full snow`, style: `--from: ${from}; --to: ${to}` }),
      el("div", { class: "ticks" }, el("span", {}, "0 % (bare)"), el("span", {}, "50 %"), el("span", {}, "100 % (full snow)")));
  }

  /** TileJSON and tile URLs of the map, for use in other map clients. */
  function linksOf(view) {
    links.hidden = false;
    links.replaceChildren(el("h3", { class: "dl-head" }, "Use this map elsewhere (TileJSON 3.0.0)"),
      el("ul", { class: "downloads" }, ...view.layers.map((l) =>
        el("li", {}, el("a", { class: "button secondary", href: `${view.tilejson_url}?layer=${l}`, target: "_blank", rel: "noopener", "data-layer": l }, `${l} TileJSON`)))),
      el("p", { class: "hint" }, "XYZ template: ", el("code", {}, location.origin + view.tiles[state.overlay])));
  }

  const input = inputBox("georeferenced DEM (GeoTIFF with a CRS)", "dem.tif", (asset) => {
    state.asset = asset;
    panel.dataset.asset = asset.id;
    schedule();
  }, error);
  panel.append(
    el("h2", {}, "Map"),
    el("div", { class: "layout" },
      el("div", { class: "area-in" }, input, show),
      el("div", { class: "area-out" }, status, el("div", { class: "result" }, empty, msg, stage), coords, legend, links),
      el("div", { class: "area-more" }, el("h3", { class: "form-head" }, "Settings"), form)));
}
