// Drives the studio's Map tab (issue 22) in headless Chromium (Debian's /usr/bin/chromium through
// playwright-core; WebGL through SwiftShader). Run by tests/it/web.rs against a server it starts;
// by hand:
//
//   STUDIO_URL=http://127.0.0.1:8080 PLAYWRIGHT_DIR=target/browser-node \
//     SCREENSHOT_DIR=target/browser node tests/browser/map.mjs
//
// Steps: the tab shows its empty state; "Try the example" uploads dem.tif and POSTs /v1/maps;
// MapLibre GL JS (served from /web/vendor/, installed from npm at build time) loads our
// hillshade, relief and terrain-rgb tiles through our TileJSON, all answered 200 (or 204 off the
// DEM) and the canvas shows a picture, not a blank; the 3-D terrain is on (map.getTerrain():
// the raster-dem source, encoding mapbox); the pointer's coordinates fall inside the map's
// bounds with a ground height in the DEM's range; panning (a mouse drag) fetches tiles not
// fetched before; a parameter change makes a new map (a new id) whose tiles load and change
// the picture; the snow overlay loads our `snow` tiles and the legend follows; axe-core finds
// no serious or critical violation; no horizontal overflow at 390×844; with /web/vendor.json
// saying "not installed" the tab says so in words and still lists the TileJSON links. Fails on
// any console error, page error, failed tile or request to anything but the server.
// Screenshots: SCREENSHOT_DIR/map-*.png.

import assert from "node:assert/strict";
import { createRequire } from "node:module";
import fs from "node:fs";
import path from "node:path";

const base = process.env.STUDIO_URL;
assert.ok(base, "STUDIO_URL is not set");
const pwDir = path.resolve(process.env.PLAYWRIGHT_DIR || "target/browser-node");
const shots = path.resolve(process.env.SCREENSHOT_DIR || "target/browser");
fs.mkdirSync(shots, { recursive: true });
const require = createRequire(path.join(pwDir, "package.json"));
const { chromium } = require("playwright-core");

const TIMEOUT = 120_000;
const problems = [];
const log = (m) => console.log(`[map] ${m}`);
const TILE = /\/v1\/maps\/([0-9a-f]{64})\/tiles\/([a-z-]+)\/(\d+)\/(\d+)\/(\d+)\.png/;

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  // WebGL (MapLibre) through SwiftShader, as in studio.mjs.
  args: ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  page.setDefaultTimeout(TIMEOUT);
  page.on("console", (m) => { if (m.type() === "error") problems.push(`console error: ${m.text()}`); });
  page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
  page.on("request", (r) => {
    // blob: URLs are the page's own (MapLibre may start its worker from one).
    if (!r.url().startsWith(base) && !r.url().startsWith("data:") && !r.url().startsWith(`blob:${base}`)) problems.push(`request beyond the server: ${r.url()}`);
  });
  /** Every tile response: { id, layer, z, x, y, status }. */
  const tiles = [];
  page.on("response", (r) => {
    const m = r.url().match(TILE);
    if (!m) return;
    const t = { id: m[1], layer: m[2], z: +m[3], x: +m[4], y: +m[5], status: r.status() };
    tiles.push(t);
    if (![200, 204].includes(t.status)) problems.push(`tile ${r.url()} answered ${t.status}`);
  });
  page.on("requestfailed", (r) => {
    // MapLibre cancels the tiles that left the view while loading: not a failure.
    if (TILE.test(r.url()) && r.failure() && /ERR_ABORTED/.test(r.failure().errorText)) return;
    problems.push(`request failed: ${r.url()} ${r.failure() && r.failure().errorText}`);
  });
  if (process.env.STUDIO_WEB_DIR) {
    await page.route(/\/web\/[a-z]+\.(js|css)$/, (r) => r.fulfill({
      contentType: r.request().url().endsWith(".css") ? "text/css" : "text/javascript",
      body: fs.readFileSync(path.join(process.env.STUDIO_WEB_DIR, new URL(r.request().url()).pathname.slice(5))),
    }));
  }
  const shot = (name) => page.screenshot({ path: path.join(shots, `map-${name}.png`), fullPage: true });
  /** Waits until the map shows map `id` with every tile in view loaded. */
  const settled = (id) => page.waitForFunction((want) => {
    const s = document.getElementById("map-view");
    const m = s.maplibre;
    return m && s.dataset.shown === want && m.loaded() && m.areTilesLoaded() && m.isStyleLoaded() && !m.isMoving();
  }, id);
  /** Statistics of the map's canvas: distinct colours (quantised), share of snow-bright pixels (every channel above 200)
   * and a digest. */
  const canvasStats = () => page.evaluate(async () => {
    const src = document.getElementById("map-view").maplibre.getCanvas();
    const c = document.createElement("canvas");
    c.width = 320;
    c.height = Math.round((320 * src.height) / src.width);
    const g = c.getContext("2d");
    g.drawImage(src, 0, 0, c.width, c.height);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    const colours = new Set();
    let bright = 0;
    let ground = 0;
    let sum = 0;
    let sum2 = 0;
    for (let i = 0; i < d.length; i += 4) {
      colours.add(((d[i] >> 3) << 10) | ((d[i + 1] >> 3) << 5) | (d[i + 2] >> 3));
      if (d[i] > 200 && d[i + 1] > 200 && d[i + 2] > 200) bright++;
      // Not the map's background (#2b3a4a): the terrain is drawn there.
      if (Math.abs(d[i] - 0x2b) + Math.abs(d[i + 1] - 0x3a) + Math.abs(d[i + 2] - 0x4a) > 12) {
        ground++;
        const l = 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2];
        sum += l;
        sum2 += l * l;
      }
    }
    const n = d.length / 4;
    const mean = sum / Math.max(1, ground);
    const h = await crypto.subtle.digest("SHA-256", d);
    return {
      colours: colours.size, bright: bright / n, ground: ground / n,
      // The spread of the terrain's brightness: shading, shadows and snow, not one flat colour.
      spread: Math.sqrt(Math.max(0, sum2 / Math.max(1, ground) - mean * mean)),
      digest: Array.from(new Uint8Array(h)).map((x) => x.toString(16).padStart(2, "0")).join(""),
    };
  });
  const mapId = () => page.getAttribute("#panel-map", "data-map");
  const key = (t) => `${t.id}/${t.layer}/${t.z}/${t.x}/${t.y}`;

  // 1. The tab, before any upload: its empty state, no map.
  await page.goto(base + "/");
  await page.waitForSelector("body[data-ready=true]");
  await page.click("#tab-map");
  const panel = page.locator("#panel-map");
  assert.ok(await panel.locator(".empty-state").isVisible(), "the Map tab has no empty state");
  assert.match(await panel.locator(".empty-state").textContent(), /Try the example/);
  assert.equal(await panel.locator("canvas").count(), 0, "a map before any DEM");
  // The same parameter form as the snow-terrain tab, without the render-only fields.
  for (const name of ["snowline", "sun_strength", "sun_azimuth_deg", "probe_radius", "snow_color"]) {
    assert.equal(await panel.locator(`[data-name=${name}]`).count(), 1, `the form has no ${name}`);
  }
  for (const name of ["width", "height", "camera", "samples"]) {
    assert.equal(await panel.locator(`[data-name=${name}]`).count(), 0, `the form has the render-only ${name}`);
  }
  await shot("01-empty");

  // 2. The example DEM: a map, our tiles through our TileJSON, a picture on the canvas.
  await panel.locator("button.example").click();
  await page.waitForFunction(() => document.getElementById("panel-map").dataset.map);
  const first = await mapId();
  await settled(first);
  const view = await page.evaluate(async (id) => (await fetch(`/v1/maps/${id}`)).json(), first);
  const ok = (id, layer) => tiles.filter((t) => t.id === id && t.layer === layer && t.status === 200);
  for (const layer of ["hillshade", "relief", "terrain-rgb"]) {
    assert.ok(ok(first, layer).length >= 1, `no ${layer} tile loaded: ${JSON.stringify(tiles.slice(0, 20))}`);
  }
  assert.equal(ok(first, "snow").length, 0, "snow tiles with the relief overlay");
  const sources = await page.evaluate(() => {
    const m = document.getElementById("map-view").maplibre;
    const t = m.getTerrain();
    const dem = m.getSource("dem");
    return { terrain: t && { source: t.source, exaggeration: t.exaggeration }, type: dem.type, encoding: dem.encoding, pitch: m.getPitch(), tiles: dem.tiles };
  });
  assert.deepEqual(sources.terrain, { source: "dem", exaggeration: 1.5 }, "3-D terrain is not on");
  assert.equal(sources.type, "raster-dem");
  assert.equal(sources.encoding, "mapbox");
  assert.ok(sources.pitch > 30, `pitch ${sources.pitch}: the terrain is seen from straight above`);
  assert.match(sources.tiles[0], new RegExp(`/v1/maps/${first}/tiles/terrain-rgb/`), "the DEM source's tiles come from our TileJSON");
  assert.equal(await page.getAttribute("#map-view", "data-terrain"), "on");
  await shot("02-relief-3d");
  await page.locator("#map-view").screenshot({ path: path.join(shots, "map-02-relief-3d-view.png") });
  const s1 = await canvasStats();
  log(`canvas: ${JSON.stringify({ ...s1, digest: undefined })}`);
  assert.ok(s1.ground > 0.3, `the terrain covers ${(100 * s1.ground).toFixed(1)} % of the map: blank?`);
  assert.ok(s1.colours > 40 && s1.spread > 10, `a flat picture: ${s1.colours} colours, brightness spread ${s1.spread.toFixed(1)}`);
  assert.ok(s1.bright > 0.02, `no snow-bright pixels on the map (${s1.bright})`);
  assert.equal(await page.locator("#status-map.error").count(), 0, `status: ${await page.textContent("#status-map")}`);
  assert.equal(await page.getAttribute("#map-legend", "data-overlay"), "relief");
  log(`map ${first.slice(0, 12)}: ${tiles.length} tiles, terrain ${JSON.stringify(sources.terrain)}, pitch ${sources.pitch.toFixed(0)}°, terrain on ${(100 * s1.ground).toFixed(0)} % of the view, ${s1.colours} colours, brightness spread ${s1.spread.toFixed(1)}, ${(100 * s1.bright).toFixed(1)} % snow-bright`);

  // 3. Coordinates under the cursor: inside the map's bounds, with a ground height.
  const box = await page.locator("#map-view canvas").boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await page.mouse.move(box.x + box.width / 2 + 5, box.y + box.height / 2 + 5);
  await page.waitForFunction(() => document.getElementById("map-coords").dataset.lat);
  const [lng, lat] = await page.evaluate(() => [Number(document.getElementById("map-coords").dataset.lng), Number(document.getElementById("map-coords").dataset.lat)]);
  const [w, s, e, n] = view.bounds;
  assert.ok(lng > w && lng < e && lat > s && lat < n, `the cursor at ${lng}, ${lat} is outside the map's bounds ${view.bounds}`);
  const words = await page.textContent("#map-coords");
  const hm = words.match(/ground ≈ (-?\d+) m/);
  assert.ok(hm, `no ground height under the cursor: ${words}`);
  assert.ok(+hm[1] >= 150 && +hm[1] <= 2300, `ground height ${hm[1]} m is outside the example's 200–2200 m`);
  log(`under the cursor: ${words}`);

  // 4. Panning fetches new tiles: close in on the west of the DEM (at the tiles' finest zoom),
  // then drag the map to the left with the mouse.
  await page.evaluate(([lo, la, z]) => document.getElementById("map-view").maplibre.jumpTo({ center: [lo, la], zoom: z, pitch: 0, bearing: 0 }), [w + (e - w) * 0.12, (s + n) / 2, view.maxzoom + 0.5]);
  await settled(first);
  const before = new Set(tiles.map(key));
  const c0 = await page.evaluate(() => document.getElementById("map-view").maplibre.getCenter().toArray());
  // Two drags of 60 % of the map's width each (about 2½ tiles to the east in all).
  for (let k = 0; k < 2; k++) {
    await page.mouse.move(box.x + box.width * 0.8, box.y + box.height / 2);
    await page.mouse.down();
    for (let i = 1; i <= 8; i++) await page.mouse.move(box.x + box.width * (0.8 - (0.6 * i) / 8), box.y + box.height / 2);
    await page.mouse.up();
    await settled(first);
  }
  const c1 = await page.evaluate(() => document.getElementById("map-view").maplibre.getCenter().toArray());
  assert.ok(c1[0] > c0[0], `the drag did not pan east: ${c0} → ${c1}`);
  const fresh = tiles.filter((t) => t.status === 200 && !before.has(key(t)));
  if (process.env.MAP_DEBUG) log(`before ${[...before].map((k) => k.slice(65)).join(" ")}\nafter ${tiles.map(key).map((k) => k.slice(65)).join(" ")}\nview ${JSON.stringify(view)} zoom ${await page.evaluate(() => document.getElementById("map-view").maplibre.getZoom())}`);
  assert.ok(fresh.some((t) => t.layer === "relief"), `panning fetched no new relief tile (${fresh.length} new tiles)`);
  await shot("03-panned");
  log(`pan ${c0.map((v) => v.toFixed(4))} → ${c1.map((v) => v.toFixed(4))}: ${fresh.length} new tiles (${[...new Set(fresh.map((t) => t.layer))].join(", ")})`);

  // 5. A parameter change makes a new map and the picture changes.
  await page.evaluate(([lo, la, z]) => document.getElementById("map-view").maplibre.jumpTo({ center: [lo, la], zoom: z, pitch: 55 }), [(w + e) / 2, (s + n) / 2, view.minzoom + 1]);
  await settled(first);
  const sBefore = await canvasStats();
  await panel.locator("input[name=snowline]").fill("1500");
  await panel.locator("input[name=snowline]").dispatchEvent("change");
  await page.waitForFunction((old) => { const m = document.getElementById("panel-map").dataset.map; return m && m !== old; }, first);
  const second = await mapId();
  await settled(second);
  assert.ok(ok(second, "relief").length >= 1, "the new map's relief tiles did not load");
  const posted = await page.evaluate(async (id) => (await fetch(`/v1/maps/${id}`)).json(), second);
  assert.equal(posted.params.snowline, 1500, "the new map does not have the new snowline");
  const sAfter = await canvasStats();
  assert.notEqual(sAfter.digest, sBefore.digest, "the picture did not change with the snowline");
  assert.ok(sAfter.bright < sBefore.bright, `a higher snowline (1500 m) left as much snow: ${sBefore.bright} → ${sAfter.bright}`);
  await shot("04-snowline-1500");
  log(`snowline 1500 m: map ${second.slice(0, 12)}, snow-bright ${(100 * sBefore.bright).toFixed(1)} % → ${(100 * sAfter.bright).toFixed(1)} %`);

  // 6. The snow overlay over the hillshade: our snow tiles, the legend follows.
  await page.check("#map-overlay-snow");
  await page.waitForFunction(() => document.getElementById("map-view").dataset.overlay === "snow");
  await settled(second);
  assert.ok(ok(second, "snow").length >= 1, "no snow tile loaded");
  assert.equal(await page.getAttribute("#map-legend", "data-overlay"), "snow");
  assert.match(await page.textContent("#map-legend"), /100 %/);
  assert.equal(await page.evaluate(() => document.getElementById("map-view").maplibre.getTerrain()?.source), "dem", "the terrain went away with the overlay");
  await shot("05-snow-overlay");
  await page.locator("#map-view").screenshot({ path: path.join(shots, "map-05-snow-overlay-view.png") });

  // 7. The terrain toggle turns the 3-D terrain off and on.
  await page.uncheck("#map-terrain");
  assert.equal(await page.evaluate(() => document.getElementById("map-view").maplibre.getTerrain()), null);
  await page.check("#map-terrain");
  assert.equal(await page.evaluate(() => document.getElementById("map-view").maplibre.getTerrain()?.exaggeration), 1.5);

  // 8. axe-core on the tab; a phone's width without horizontal overflow.
  const axeSource = fs.readFileSync(path.join(pwDir, "node_modules/axe-core/axe.min.js"), "utf8");
  await page.evaluate(axeSource);
  const bad = await page.evaluate(async () => {
    const r = await window.axe.run(document.getElementById("panel-map"), { resultTypes: ["violations"] });
    return r.violations.filter((v) => ["serious", "critical"].includes(v.impact))
      .map((v) => `${v.impact} ${v.id}: ${v.help} — ${v.nodes.slice(0, 4).map((x) => x.target.join(" ")).join(" | ")}`);
  });
  assert.deepEqual(bad, [], "axe-core on the Map tab");
  await page.setViewportSize({ width: 390, height: 844 });
  await page.waitForTimeout(300);
  const [sw, iw] = await page.evaluate(() => [document.documentElement.scrollWidth, window.innerWidth]);
  assert.ok(sw <= iw, `the Map tab overflows at 390×844: ${sw} > ${iw}`);
  await shot("06-phone");
  log("axe-core: nothing serious; no overflow at 390×844");

  // 9. A server built without npm: the tab says so in words, and the TileJSON links still work.
  const bare = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  bare.setDefaultTimeout(TIMEOUT);
  bare.on("console", (m) => { if (m.type() === "error") problems.push(`console error (no viewer): ${m.text()}`); });
  bare.on("pageerror", (err) => problems.push(`page error (no viewer): ${err.message}`));
  await bare.route("**/web/vendor.json", (r) => r.fulfill({ contentType: "application/json", body: JSON.stringify({ installed: false, packages: {}, files: [], reason: "PHENOMENA_NPM=off", install: "Install Node.js with npm (e.g. apt-get install -y nodejs npm), then rebuild: cargo build --release" }) }));
  await bare.goto(base + "/");
  await bare.waitForSelector("body[data-ready=true]");
  await bare.click("#tab-map");
  await bare.locator("#panel-map button.example").click();
  await bare.waitForFunction(() => document.getElementById("panel-map").dataset.viewer === "unavailable");
  const why = await bare.textContent("#map-msg");
  assert.match(why, /not installed/);
  assert.match(why, /npm/);
  assert.equal(await bare.locator("#panel-map canvas").count(), 0);
  assert.equal(await bare.locator("#map-coords").isVisible(), false, "coordinates of a map that is not shown");
  const link = await bare.getAttribute("#map-links a[data-layer=relief]", "href");
  const tj = await bare.evaluate(async (u) => (await fetch(u)).json(), link);
  assert.equal(tj.tilejson, "3.0.0");
  await bare.screenshot({ path: path.join(shots, "map-07-no-viewer.png"), fullPage: true });
  await bare.close();
  log(`without npm: "${why.slice(0, 90)}…"`);
} finally {
  await browser.close();
}
assert.deepEqual(problems, [], `the Map tab had problems:\n${problems.join("\n")}`);
log("ok");
