// Drives the studio page at `/` in headless Chromium (Debian's /usr/bin/chromium through
// playwright-core). Run by tests/it/web.rs against a server it starts; by hand:
//
//   STUDIO_URL=http://127.0.0.1:8080 PLAYWRIGHT_DIR=target/browser-node \
//     SCREENSHOT_DIR=target/browser node tests/browser/studio.mjs
//
// Steps (screenshots of each under SCREENSHOT_DIR): the page loads; upload a DEM, change a
// parameter, see the image change; orbit with the arrow keys and by dragging the render with the
// mouse; a parameter sweep shows sweep.png beside the render and the snow-cover map; an eye/target
// camera the API refuses shows a readable 422 naming the field, the old images marked out of
// date (dimmed, labelled, described by the error) until the next success; download outputs and check their
// bytes; the snow-cover example runs with a snowfall schedule, a wind and a time-lapse, the
// progress bar moving and finishing; the cloud tab posts layers, a background, a sun-colour triple
// and a world box; in the cloud editor paint a sun-colour stroke (version count and image
// change), drag a shadow (the sun direction in the state changes), undo (back to the previous
// version and its image), redo (forward again), paint an ambient stroke (a new version and
// image), Ctrl+Z / Ctrl+Shift+Z, then with the keyboard only paint a sun-colour stroke (a new
// version, a changed image, the same request fields as the pointer's) and do a shadow drag (the
// sun direction changes); the dust example runs with its render, fibre atlas and amount map, and the close-up
// toggle changes the image with the far view beside it; every tab at 390×844 (no horizontal
// overflow) and 1366×768. Issue 23: before any upload every tab shows its empty state (no image,
// Cancel/Undo/Redo/Apply disabled); each 3-D viewer loads its GLB (terrain.glb with its snow
// colours, displaced/scene/snow.glb, dusty.glb) and a drag changes its canvas, a pan and "Reset
// view" too; the layer toggles (flakes, snow, dust shells) change the canvas; the Spring and
// Paper looks change the form and the render; Cancel ends a running full-size job (`canceled`);
// the result area keeps its size through a re-render; errors in words, the HTTP code in a
// detail line; the editor's thumbnails, state table and before/after slider; axe-core finds no
// serious or critical violation on any tab, before an upload and with results; with
// /web/vendor.json saying "not installed" the viewer says so in words. Fails on any console
// error (but the deliberate 422's failed load), page error, or request to anything but the
// server (and the page's own blob: URLs).

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
const log = (m) => console.log(`[studio] ${m}`);

/** A small synthetic DEM: a 48 × 48 ESRI ASCII grid, one cone-shaped peak with a hollow. */
function dem() {
  const n = 48;
  let s = `ncols ${n}\nnrows ${n}\nxllcorner 0\nyllcorner 0\ncellsize 25\nNODATA_value -9999\n`;
  for (let r = 0; r < n; r++) {
    const row = [];
    for (let c = 0; c < n; c++) {
      const d = Math.hypot(r - n / 2, c - n / 2) / (n / 2);
      const hollow = 150 * Math.exp(-((r - 16) ** 2 + (c - 30) ** 2) / 20);
      row.push((100 + 900 * Math.max(0, 1 - d) - hollow).toFixed(1));
    }
    s += row.join(" ") + "\n";
  }
  return Buffer.from(s);
}

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  // WebGL (the 3-D viewers) through SwiftShader, as in gltf_viewer.mjs.
  args: ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  page.setDefaultTimeout(TIMEOUT);
  // The one deliberate failure (the 422 step) logs a failed load; nothing else may.
  let expect422 = null;
  page.on("console", (m) => {
    if (m.type() !== "error") return;
    if (expect422 && m.text().includes("status of 422") && m.location().url === base + expect422) return;
    problems.push(`console error: ${m.text()}`);
  });
  page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
  // The cloud editor's edit requests, to compare the keyboard's with the pointer's.
  const edits = [];
  // The snow-terrain submissions' params, as sent.
  const submitted = [];
  page.on("request", (r) => {
    // blob: URLs are the page's own (three.js decodes a GLB's embedded textures through them).
    if (!r.url().startsWith(base) && !r.url().startsWith("data:") && !r.url().startsWith(`blob:${base}`)) problems.push(`request beyond the server: ${r.url()}`);
    if (r.method() === "POST" && r.url() === `${base}/v1/snow-terrain`) submitted.push(JSON.parse(r.postData()).params);
    const m = r.method() === "POST" && r.url().match(/\/edits\/([a-z-]+)$/);
    if (m) edits.push({ kind: m[1], body: JSON.parse(r.postData()) });
  });
  // STUDIO_WEB_DIR (while editing the page): its files come from that directory instead of the
  // server's embedded copies, so a change needs no rebuild.
  if (process.env.STUDIO_WEB_DIR) {
    await page.route(/\/web\/[a-z]+\.(js|css)$/, (r) => r.fulfill({
      contentType: r.request().url().endsWith(".css") ? "text/css" : "text/javascript",
      body: fs.readFileSync(path.join(process.env.STUDIO_WEB_DIR, new URL(r.request().url()).pathname.slice(5))),
    }));
  }
  const shot = (name) => page.screenshot({ path: path.join(shots, `${name}.png`), fullPage: true });
  const bytesOf = (url) => page.evaluate(async (u) => {
    const b = new Uint8Array(await (await fetch(u)).arrayBuffer());
    return Array.from(b.slice(0, 8)).concat([b.length]);
  }, url);
  // The 3-D viewer of a tab: ready with this model (of the panel's current job), and a digest
  // of its canvas's pixels.
  const viewerReady = (tab, model) => page.waitForFunction(([t, m]) => {
    const v = document.getElementById(`viewer-${t}`);
    const p = document.getElementById(`panel-${t}`);
    return v.dataset.state === "ready" && v.dataset.model === m && v.dataset.url && v.dataset.url.includes(p.dataset.job);
  }, [tab, model]);
  const canvasHash = (tab) => page.evaluate(async (t) => {
    const c = document.querySelector(`#viewer-${t} canvas`);
    const d = await crypto.subtle.digest("SHA-256", new TextEncoder().encode(c.toDataURL("image/png")));
    return Array.from(new Uint8Array(d)).map((x) => x.toString(16).padStart(2, "0")).join("");
  }, tab);
  /** Drags across the middle of a tab's 3-D view (left button: orbit; `button: "right"`: pan). */
  const dragViewer = async (tab, dx, dy, button = "left") => {
    const b = await page.locator(`#viewer-${tab} canvas`).boundingBox();
    await page.mouse.move(b.x + b.width / 2, b.y + b.height / 2);
    await page.mouse.down({ button });
    for (let i = 1; i <= 5; i++) await page.mouse.move(b.x + b.width / 2 + (dx * i) / 5, b.y + b.height / 2 + (dy * i) / 5);
    await page.mouse.up({ button });
  };
  // axe-core (from npm, web/package.json's dev dependencies) on the visible tab: no serious or
  // critical violation.
  const axeSource = fs.readFileSync(path.join(pwDir, "node_modules/axe-core/axe.min.js"), "utf8");
  const axeCheck = async (tab, when) => {
    await page.click(`#tab-${tab}`);
    if (!(await page.evaluate(() => !!window.axe))) await page.evaluate(axeSource);
    const bad = await page.evaluate(async () => {
      const r = await window.axe.run(document, { resultTypes: ["violations"] });
      return r.violations.filter((v) => ["serious", "critical"].includes(v.impact))
        .map((v) => `${v.impact} ${v.id}: ${v.help} — ${v.nodes.slice(0, 4).map((n) => n.target.join(" ")).join(" | ")}`);
    });
    assert.deepEqual(bad, [], `axe-core on the ${tab} tab (${when})`);
  };
  const TABS = ["snow-terrain", "snow-cover", "cloud", "editor", "dust"];
  const hashOf = (url) => page.evaluate(async (u) => {
    const d = await crypto.subtle.digest("SHA-256", await (await fetch(u)).arrayBuffer());
    return Array.from(new Uint8Array(d)).map((x) => x.toString(16).padStart(2, "0")).join("");
  }, url);

  // 1. The page loads and builds its forms from openapi.yaml.
  await page.goto(base + "/");
  await page.waitForSelector("body[data-ready=true]");
  assert.ok(await page.locator("#panel-snow-terrain input[name=probe_radius]").count() === 1, "no probe_radius field");
  assert.equal(await page.inputValue("#panel-snow-terrain input[name=probe_radius]"), "5000", "probe_radius default");
  // Every control has an accessible name (a label, aria-label or its text).
  const unnamed = await page.evaluate(() => [...document.querySelectorAll("input, select, textarea, button")]
    .filter((e) => !(e.labels && e.labels.length) && !e.getAttribute("aria-label") && !e.getAttribute("aria-labelledby") && !(e.tagName === "BUTTON" && e.textContent.trim()))
    .map((e) => e.id || e.outerHTML.slice(0, 80)));
  assert.deepEqual(unnamed, [], "controls without an accessible name");
  await shot("01-loaded");
  log("page loaded");

  // Before any upload: every tab says what to do, shows no image (no broken-image icon), its
  // 3-D view waits, Cancel is disabled; the editor's Undo, Redo and Apply are disabled, its
  // versions and state say there is nothing yet. axe-core finds nothing serious on any tab.
  for (const tab of ["snow-terrain", "snow-cover", "cloud", "dust"]) {
    await page.click(`#tab-${tab}`);
    const p = page.locator(`#panel-${tab}`);
    assert.ok(await p.locator(".empty-state").isVisible(), `${tab}: no empty state`);
    assert.match(await p.locator(".empty-state").textContent(), /Try the example/);
    assert.equal(await p.locator("img").count(), 0, `${tab}: images before any upload`);
    assert.equal(await p.locator(`#cancel-${tab}`).isDisabled(), true, `${tab}: Cancel enabled with nothing running`);
    assert.equal(await p.locator("progress").isVisible(), false, `${tab}: an empty progress bar`);
    if (tab !== "cloud") assert.equal(await page.getAttribute(`#viewer-${tab}`, "data-state"), "empty");
    await shot(`01-empty-${tab}`);
  }
  await page.click("#tab-editor");
  const edEmpty = page.locator("#panel-editor");
  assert.ok(await edEmpty.locator("#editor-empty").isVisible(), "the editor has no empty state");
  assert.equal(await page.locator("#editor-image").isVisible(), false, "the editor shows an image before a scene");
  for (const b of ["#undo", "#redo", "#set-apply"]) assert.equal(await page.isDisabled(b), true, `${b} is enabled before a scene`);
  assert.match(await edEmpty.locator("#state-table").textContent(), /No scene yet/);
  assert.equal(await edEmpty.locator("pre.state").isVisible(), false, "an empty State box");
  assert.match(await edEmpty.locator(".versions").textContent(), /No versions yet/);
  assert.equal(await page.locator("#compare").isVisible(), false, "a comparison with nothing to compare");
  await shot("01-empty-editor");
  for (const tab of TABS) await axeCheck(tab, "before any upload");
  await page.click("#tab-snow-terrain");
  log("empty states on every tab; axe-core: no serious or critical violation");
  // The "Advanced" sections hold most fields the steps below set: open them.
  await page.evaluate(() => document.querySelectorAll("details.advanced, details.sweep-box").forEach((d) => { d.open = true; }));

  // 2. Snow on terrain: upload a DEM, see a render; change a parameter, see it change.
  const st = page.locator("#panel-snow-terrain");
  await st.locator(".dropzone input[type=file]").setInputFiles({ name: "cone.asc", mimeType: "text/plain", buffer: dem() });
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-snow-terrain");
    return p.dataset.status && p.querySelector("img[data-output='render.png']");
  });
  assert.equal(await st.getAttribute("data-status"), "succeeded");
  const firstJob = await st.getAttribute("data-job");
  const firstSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  await shot("02-terrain-first");
  // The file input names the file that came in.
  assert.equal(await st.locator(".dropzone input[type=file]").evaluate((i) => i.files[0] && i.files[0].name), "cone.asc");
  assert.match(await st.locator(".dropzone .asset").textContent(), /cone\.asc — uploaded/);
  assert.equal(await st.locator(".empty-state").isVisible(), false, "the empty state stayed after a result");
  // The preview/full-size choice says which size the downloads are.
  assert.match(await st.locator(".dl-head").textContent(), /preview size \(480 × 320 px\)/);
  // And full size says what to expect: how many more pixels, how long the preview took.
  assert.match(await page.textContent("label[for=size-snow-terrain-full]"), /Full size \(900 × 600 px, 3\.5× the preview's pixels; the preview took \d+\.\d s\)/);

  // The 3-D viewer: terrain.glb with its snow colours loads; a drag turns it (the canvas
  // changes), a right-drag pans it, "Reset view" frames it again.
  await viewerReady("snow-terrain", "terrain.glb");
  await page.locator("#viewer-snow-terrain").scrollIntoViewIfNeeded();
  const v0 = await canvasHash("snow-terrain");
  await shot("02b-terrain-3d");
  await dragViewer("snow-terrain", -120, 30);
  const v1 = await canvasHash("snow-terrain");
  assert.notEqual(v1, v0, "dragging the 3-D view changed nothing");
  await dragViewer("snow-terrain", 60, 0, "right");
  assert.notEqual(await canvasHash("snow-terrain"), v1, "a right-drag (pan) changed nothing");
  await page.mouse.move(10, 10);
  await page.click("#viewer-snow-terrain-reset");
  assert.equal(await canvasHash("snow-terrain"), v0, "Reset view did not return to the first view");
  // Snow colours: the model's own vertex colours, snow (white) and rock, both shown.
  const tones = JSON.parse(await page.getAttribute("#viewer-snow-terrain", "data-colors"));
  assert.ok(tones.snow > 0 && tones.other > 0, `terrain.glb shows no snow and rock colours: ${JSON.stringify(tones)}`);
  log(`3-D terrain: drag, pan and reset change the canvas; vertex colours: ${tones.snow} snow, ${tones.other} rock`);
  // No layout shift while a render is replaced: the result area keeps its box.
  await page.evaluate(() => {
    const r = document.querySelector("#panel-snow-terrain .result");
    const b = r.getBoundingClientRect();
    window.__box = { first: [b.width, b.height], seen: [] };
    new ResizeObserver((es) => es.forEach((e) => window.__box.seen.push([e.contentRect.width, e.contentRect.height]))).observe(r);
  });
  await st.locator("input[name=snowline]").fill("700");
  await page.waitForFunction((j) => {
    const p = document.getElementById("panel-snow-terrain");
    const img = p.querySelector("img[data-output='render.png']");
    return p.dataset.job !== j && p.dataset.status === "succeeded" && img && img.src.includes(p.dataset.job) && img.complete;
  }, firstJob);
  const secondSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  assert.notEqual(secondSrc, firstSrc, "the render did not change job");
  assert.notEqual(await hashOf(secondSrc), await hashOf(firstSrc), "the snowline changed nothing in the image");
  const rbox = await page.evaluate(() => {
    const b = document.querySelector("#panel-snow-terrain .result").getBoundingClientRect();
    return { ...window.__box, last: [b.width, b.height] };
  });
  assert.deepEqual(rbox.last, rbox.first, `the result area changed size on a re-render: ${JSON.stringify(rbox)}`);
  const b0 = JSON.stringify([Math.round(rbox.first[0]), Math.round(rbox.first[1])]);
  assert.ok(rbox.seen.every(([w, h]) => Math.abs(w - rbox.first[0]) < 1 && Math.abs(h - rbox.first[1]) < 1), `the result area jumped during the re-render (${b0}): ${JSON.stringify(rbox.seen)}`);
  await shot("03-terrain-snowline");
  log("snow-terrain re-rendered on a parameter change");

  // Orbit from the keyboard: the focused render turns the camera and re-renders.
  const beforeOrbit = await st.getAttribute("data-job");
  await st.locator("img[data-output='render.png']").focus();
  await page.keyboard.press("ArrowRight");
  await page.waitForFunction((j) => {
    const p = document.getElementById("panel-snow-terrain");
    return p.dataset.job !== j && p.dataset.status === "succeeded" && p.querySelector("img[data-output='render.png']")?.src.includes(p.dataset.job);
  }, beforeOrbit);
  const orbitJob = await page.evaluate(async (id) => (await fetch(`/v1/jobs/${id}`)).json(), await st.getAttribute("data-job"));
  assert.equal(orbitJob.params.camera.azimuth_deg, 210, "ArrowRight should turn the camera 10° from the default 200°");
  await shot("03b-terrain-orbit");
  log("orbit re-rendered with azimuth 210°");

  // A helper: the panel's next finished job after `job` (its render loaded).
  const nextJob = async (panelId, job) => {
    await page.waitForFunction(([id, j]) => {
      const p = document.getElementById(id);
      const img = p.querySelector("img[data-output='render.png']");
      return p.dataset.job !== j && p.dataset.status === "succeeded" && img && img.src.includes(p.dataset.job) && img.complete;
    }, [panelId, job]);
    const id = await page.locator(`#${panelId}`).getAttribute("data-job");
    return page.evaluate(async (i) => (await fetch(`/v1/jobs/${i}`)).json(), id);
  };

  // Orbit with the mouse: dragging the render to the left turns the camera (+0.5° per pixel)
  // and the form's camera fields follow.
  const beforeDrag = await st.getAttribute("data-job");
  const dragSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  const rb = await st.locator("img[data-output='render.png']").boundingBox();
  await page.mouse.move(rb.x + rb.width / 2, rb.y + rb.height / 2);
  await page.mouse.down();
  await page.mouse.move(rb.x + rb.width / 2 - 30, rb.y + rb.height / 2 + 10);
  await page.mouse.move(rb.x + rb.width / 2 - 60, rb.y + rb.height / 2 + 20);
  await page.mouse.up();
  const dragJob = await nextJob("panel-snow-terrain", beforeDrag);
  assert.equal(dragJob.params.camera.azimuth_deg, 240, "dragging 60 px left should turn the camera 30° from 210°");
  assert.equal(dragJob.params.camera.elevation_deg, 36, "dragging 20 px down should raise the camera 6° from 30°");
  assert.equal(await st.locator("select#p-snow-terrain-camera").inputValue(), "orbit");
  assert.equal(await st.locator("#p-snow-terrain-camera-azimuth_deg").inputValue(), "240");
  const dragNewSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  assert.notEqual(await hashOf(dragNewSrc), await hashOf(dragSrc), "the mouse orbit changed nothing in the image");
  await shot("03c-terrain-drag-orbit");
  log("mouse drag re-rendered with azimuth 240°, elevation 36°");

  // The sweep: probe_radius over three values gives sweep.png beside the render and the
  // snow-cover map (one row at laptop width).
  await st.locator("#sweep-snow-terrain-param").selectOption("probe_radius");
  assert.match(await st.locator("#sweep-snow-terrain-values").inputValue(), /5000/, "no suggested sweep values around the current probe_radius");
  const beforeSweep = await st.getAttribute("data-job");
  await st.locator("#sweep-snow-terrain-values").fill("500, 2000, 8000");
  await st.locator("#sweep-snow-terrain-values").press("Enter");
  await st.locator("#sweep-snow-terrain-values").blur();
  let sweepJob = await nextJob("panel-snow-terrain", beforeSweep);
  while (!sweepJob.params.sweep || sweepJob.params.sweep.values.length !== 3) sweepJob = await nextJob("panel-snow-terrain", sweepJob.id);
  assert.deepEqual(sweepJob.params.sweep, { param: "probe_radius", values: [500, 2000, 8000] });
  const sheet = st.locator("img[data-output='sweep.png']");
  await sheet.waitFor();
  await page.waitForFunction(() => document.querySelector("#panel-snow-terrain img[data-output='sweep.png']").complete);
  const [sw, sh] = await sheet.evaluate((i) => [i.naturalWidth, i.naturalHeight]);
  assert.ok(sw > 2 * sh, `the contact sheet of three renders should be wide (${sw}×${sh})`);
  const tops = await st.locator(".views figure").evaluateAll((fs) => fs.map((f) => Math.round(f.getBoundingClientRect().top)));
  assert.equal(tops.length, 3, "render, snow-cover map and sweep");
  assert.ok(tops.every((t) => t === tops[0]), `the three views are not side by side: ${tops}`);
  await shot("03d-terrain-sweep");
  log(`sweep.png ${sw}×${sh} beside the render and the snow-cover map`);
  await st.locator("#sweep-snow-terrain-param").selectOption("");

  // A value the API refuses (eye = target) comes back as a readable 422 naming the field.
  expect422 = "/v1/snow-terrain";
  const cameraKind = st.locator("select#p-snow-terrain-camera");
  await cameraKind.selectOption("eye");
  for (const k of [0, 1, 2]) {
    await st.locator(`#p-snow-terrain-camera-eye-${k}`).fill("100");
    await st.locator(`#p-snow-terrain-camera-target-${k}`).fill("100");
  }
  await page.waitForFunction(() => document.getElementById("panel-snow-terrain").dataset.status === "rejected");
  const refused = await st.locator("p.status").textContent();
  assert.match(refused, /422/, `no readable 422: ${refused}`);
  assert.match(await st.locator("p.status .detail").textContent(), /^HTTP 422/, "the HTTP code is not in the detail line");
  const headline = await st.locator("p.status").evaluate((p) => p.firstChild.textContent);
  assert.match(headline, /^[A-Z][a-z]+ [a-z]+/, `the message does not start in words: ${headline}`);
  assert.ok(!/\(?422\)?/.test(headline), `the HTTP code is in the message itself: ${headline}`);
  assert.match(refused, /camera|eye|target/, `the 422 does not say what is wrong: ${refused}`);
  assert.equal(await st.locator(".field[data-name=camera]").evaluate((f) => f.classList.contains("invalid")), true, "the camera field is not marked");
  // The last good images stay, marked out of date and described by the error.
  const staleImg = st.locator("img[data-output='render.png']");
  assert.equal(await st.getAttribute("data-stale"), "true", "the old images are not marked stale after the 422");
  assert.equal(await st.locator(".views").evaluate((v) => v.classList.contains("stale")), true);
  assert.ok(await st.locator(".stale-note").isVisible(), "no visible out-of-date label");
  assert.match(await st.locator(".stale-note").textContent(), /out of date/i);
  const described = (await staleImg.getAttribute("aria-describedby") || "").split(" ");
  assert.ok(described.includes("status-snow-terrain") && described.includes("stale-snow-terrain"), `the stale image is not described by the error: ${described}`);
  assert.ok(Number(await staleImg.evaluate((i) => getComputedStyle(i).opacity)) < 0.6, "the stale image is not dimmed");
  await shot("03e-terrain-422");
  log(`refused: ${refused}`);
  await cameraKind.selectOption("orbit");
  expect422 = null;
  await page.waitForFunction(() => document.getElementById("panel-snow-terrain").dataset.status === "succeeded");
  assert.equal(await st.getAttribute("data-stale"), null, "the stale mark stayed after a success");
  assert.equal(await st.locator(".stale-note").isVisible(), false, "the out-of-date label stayed after a success");
  assert.equal(await staleImg.getAttribute("aria-describedby"), null);
  assert.equal(await st.locator(".views").evaluate((v) => v.classList.contains("stale")), false);
  log("the old images were marked out of date until the next success");


  // Download an output and check its bytes (a PNG, a GeoTIFF).
  const pngHref = await st.locator("a[download='render.png']").getAttribute("href");
  const png = await bytesOf(pngHref);
  assert.deepEqual(png.slice(0, 8), [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a], "render.png is not a PNG");
  const tifHref = await st.locator("a[download='snow_cover.tif']").getAttribute("href");
  const tif = await bytesOf(tifHref);
  assert.deepEqual(tif.slice(0, 4), [0x49, 0x49, 0x2a, 0x00], "snow_cover.tif is not a little-endian TIFF");
  log("downloads are a PNG and a TIFF");

  // Presets: "Spring" fills the form with its values and changes the result; "Paper" is the
  // engine's paper preset; "Winter" goes back.
  const before = await st.getAttribute("data-job");
  const winterSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  await page.click("label[for=preset-snow-terrain-spring]");
  assert.equal(await st.locator("input[name=snowline_quantile]").inputValue(), "0.6");
  assert.equal(await st.locator("input[name=sun_strength]").inputValue(), "0.9");
  const springJob = await nextJob("panel-snow-terrain", before);
  assert.ok(Math.abs(springJob.params.sun_strength - 0.9) < 1e-6, JSON.stringify(springJob.params));
  assert.equal(springJob.params.slope_end_deg, 45);
  const springSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  assert.notEqual(await hashOf(springSrc), await hashOf(winterSrc), "the spring preset changed nothing in the render");
  await shot("03f-terrain-spring");
  await page.click("label[for=preset-snow-terrain-paper]");
  assert.equal(await st.locator("select[name=preset]").inputValue(), "paper");
  assert.equal(await st.locator("input[name=sun_strength]").inputValue(), "0.5", "the spring values stayed under the paper preset");
  const paperJob = await nextJob("panel-snow-terrain", springJob.id);
  assert.equal(paperJob.params.preset, "paper");
  assert.equal(submitted.at(-1).preset, "paper");
  assert.equal(submitted.at(-1).sun_strength, undefined, "spring's values were sent with the paper preset");
  assert.notEqual(await hashOf(await st.locator("img[data-output='render.png']").getAttribute("src")), await hashOf(springSrc), "the paper preset changed nothing");
  await shot("03g-terrain-paper");
  await page.click("label[for=preset-snow-terrain-winter]");
  const winterJob = await nextJob("panel-snow-terrain", paperJob.id);
  assert.equal(winterJob.params.preset, "winter");
  assert.equal(submitted.at(-1).preset, undefined, "winter is the default: not sent");
  log("presets: spring and paper change the form and the render");

  // Cancel: a heavy full-size render is canceled from its button.
  await st.locator("input[name=samples]").fill("16");
  await st.locator("input[name=width]").fill("4096");
  await st.locator("input[name=height]").fill("4096");
  await page.check("#size-snow-terrain-full");
  await page.waitForFunction((j) => {
    const p = document.getElementById("panel-snow-terrain");
    return p.dataset.job !== j && !document.getElementById("cancel-snow-terrain").disabled;
  }, winterJob.id);
  const heavy = await st.getAttribute("data-job");
  await page.click("#cancel-snow-terrain");
  await page.waitForFunction(() => document.getElementById("panel-snow-terrain").dataset.status === "canceled");
  const canceled = await page.evaluate(async (i) => (await fetch(`/v1/jobs/${i}`)).json(), heavy);
  assert.equal(canceled.status, "canceled");
  assert.equal(canceled.params.width, 4096, "the full-size choice did not send the full width");
  assert.match(await st.locator("p.status").textContent(), /Canceled/);
  assert.equal(await page.isDisabled("#cancel-snow-terrain"), true, "Cancel stays enabled after the job ended");
  await shot("03h-terrain-canceled");
  log("cancel ended a running 4096 × 4096 job");
  await st.locator("input[name=samples]").fill("");
  await st.locator("input[name=width]").fill("");
  await st.locator("input[name=height]").fill("");
  await page.check("#size-snow-terrain-preview");
  await nextJob("panel-snow-terrain", heavy);

  // 3. Snow cover: the example mesh; the progress bar moves and finishes.
  await page.click("#tab-snow-cover");
  const sc = page.locator("#panel-snow-cover");
  await page.evaluate(() => {
    window.__progress = [];
    const p = document.getElementById("panel-snow-cover");
    new MutationObserver(() => window.__progress.push(Number(p.dataset.progress))).observe(p, { attributes: true, attributeFilter: ["data-progress"] });
  });
  // Smaller than the defaults, to keep the test short (still dozens of progress events).
  await sc.locator("input[name=resolution]").fill("128");
  await sc.locator("input[name=steps]").fill("24");
  // Structured parameters: a snowfall schedule [[hour, rate], …], a wind, a time-lapse.
  await sc.locator("select#p-snow-cover-snowfall").selectOption({ label: "schedule" });
  await sc.locator("#p-snow-cover-snowfall-alt1-r0-0").fill("0");
  await sc.locator("#p-snow-cover-snowfall-alt1-r0-1").fill("0.03");
  await sc.locator(".field[data-name=snowfall] button", { hasText: "+ row" }).click();
  await sc.locator("#p-snow-cover-snowfall-alt1-r1-0").fill("6");
  await sc.locator("#p-snow-cover-snowfall-alt1-r1-1").fill("0.01");
  // Each column has its own bounds (the schema's `prefixItems`: hour 0–1000, rate 0–10 m/h).
  assert.equal(await sc.locator("#p-snow-cover-snowfall-alt1-r1-0").getAttribute("max"), "1000", "the hour cell's bound");
  assert.equal(await sc.locator("#p-snow-cover-snowfall-alt1-r1-1").getAttribute("max"), "10", "the rate cell's bound");
  await sc.locator("#p-snow-cover-wind-on").check();
  await sc.locator("#p-snow-cover-wind-azimuth_deg").fill("90");
  await sc.locator("#p-snow-cover-wind-tilt_deg").fill("20");
  await sc.locator("input[name=frames]").fill("3");
  await sc.locator(".field[data-name=wind]").scrollIntoViewIfNeeded();
  await sc.locator(".field[data-name=snowfall]").screenshot({ path: path.join(shots, "04a-snow-cover-schedule.png") });
  await sc.locator(".field[data-name=wind]").screenshot({ path: path.join(shots, "04a-snow-cover-wind.png") });
  await sc.locator("button.example").click();
  await page.waitForFunction(() => document.getElementById("panel-snow-cover").dataset.status);
  assert.equal(await sc.getAttribute("data-status"), "succeeded");
  const seen = await page.evaluate(() => window.__progress);
  log(`snow-cover progress seen: ${JSON.stringify(seen)}`);
  assert.equal(seen[seen.length - 1], 1, "the progress bar did not finish");
  // The bar moves: values strictly between 0 and 1 were shown before the end. (Not asserted
  // monotonic: snow-cover reports its accumulation reaching 1 before its render stage.)
  assert.ok(seen.some((v) => v > 0 && v < 1), "the progress bar never moved before finishing");
  assert.equal(await sc.locator("progress").evaluate((b) => b.value), 1);
  await sc.locator("img[data-output='render.png']").waitFor();
  await sc.locator("img[data-output='timelapse.png']").waitFor();
  const scJob = await page.evaluate(async (i) => (await fetch(`/v1/jobs/${i}`)).json(), await sc.getAttribute("data-job"));
  assert.deepEqual(scJob.params.snowfall, [[0, 0.03], [6, 0.01]], "the schedule was not sent as [[hour, rate], …]");
  assert.deepEqual(scJob.params.wind, { azimuth_deg: 90, tilt_deg: 20 }, "the wind was not sent");
  assert.equal(scJob.params.frames, 3);
  await shot("04-snow-cover");
  log("snow-cover ran with a snowfall schedule, a wind and a 3-frame time-lapse");
  assert.equal(await sc.locator(".dropzone input[type=file]").evaluate((i) => i.files[0] && i.files[0].name), "mesh.obj", "the example's name is not in the file input");

  // Its 3-D viewer: displaced.glb (the mesh under its snow, with the flakes) first; a drag
  // turns it; the flakes and the snow layer toggle (each changes the canvas); the other two
  // models load too.
  await viewerReady("snow-cover", "displaced.glb");
  await page.locator("#viewer-snow-cover").scrollIntoViewIfNeeded();
  assert.deepEqual((await page.getAttribute("#viewer-snow-cover", "data-layers")).split(" ").sort(), ["flakes", "snow"]);
  const c0 = await canvasHash("snow-cover");
  await shot("04d-snow-cover-3d");
  await page.uncheck("#viewer-snow-cover-layer-flakes");
  const c1 = await canvasHash("snow-cover");
  assert.notEqual(c1, c0, "hiding the flakes changed nothing");
  await page.uncheck("#viewer-snow-cover-layer-snow");
  const c2 = await canvasHash("snow-cover");
  assert.notEqual(c2, c1, "hiding the snow layer changed nothing");
  await shot("04e-snow-cover-3d-bare");
  await page.check("#viewer-snow-cover-layer-snow");
  await page.check("#viewer-snow-cover-layer-flakes");
  assert.equal(await canvasHash("snow-cover"), c0, "showing the layers again did not restore the view");
  await dragViewer("snow-cover", 100, -40);
  assert.notEqual(await canvasHash("snow-cover"), c0, "dragging the snow-cover 3-D view changed nothing");
  const models = await page.locator("#viewer-snow-cover-model option").evaluateAll((o) => o.map((x) => x.value));
  assert.deepEqual(models, ["displaced.glb", "scene.glb", "snow.glb"]);
  for (const m of ["scene.glb", "snow.glb"]) {
    await page.selectOption("#viewer-snow-cover-model", m);
    await viewerReady("snow-cover", m);
    await shot(`04f-snow-cover-3d-${m.replace(".glb", "")}`);
  }
  await page.selectOption("#viewer-snow-cover-model", "displaced.glb");
  await viewerReady("snow-cover", "displaced.glb");
  log("snow-cover 3-D: displaced, scene and snow models; flakes and snow toggles change the canvas");

  // The cloud tab with structured parameters: layers as a list, a background colour (off by
  // default, so absent = transparent), a sun-colour triple, a world box.
  await page.click("#tab-cloud");
  const cl = page.locator("#panel-cloud");
  assert.equal(await cl.locator("#p-cloud-background").isDisabled(), true, "the background colour should be unset by default");
  await cl.locator("#p-cloud-layers-alt1-direct").check();
  await cl.locator("#p-cloud-layers-alt1-ambient").check();
  await cl.locator("#p-cloud-background-on").check();
  await cl.locator("#p-cloud-background").fill("#203040");
  await cl.locator("#p-cloud-sun_color-0").fill("2");
  for (const [r, v] of [[0, [0, 0, 0]], [1, [2, 1.6, 2]]]) {
    for (const k of [0, 1, 2]) await cl.locator(`#p-cloud-bounds-r${r}-${k}`).fill(String(v[k]));
  }
  await cl.locator(".field[data-name=bounds]").scrollIntoViewIfNeeded();
  await cl.locator(".field[data-name=bounds]").screenshot({ path: path.join(shots, "04b-cloud-bounds.png") });
  await cl.locator(".field[data-name=sun_color]").screenshot({ path: path.join(shots, "04b-cloud-sun-color.png") });
  await cl.locator("button.example").click();
  await page.waitForFunction(() => document.getElementById("panel-cloud").dataset.status);
  assert.equal(await cl.getAttribute("data-status"), "succeeded", await cl.locator("p.status").textContent());
  const clJob = await page.evaluate(async (i) => (await fetch(`/v1/jobs/${i}`)).json(), await cl.getAttribute("data-job"));
  assert.deepEqual(clJob.params.layers, ["direct", "ambient"]);
  assert.equal(clJob.params.background, "#203040");
  assert.deepEqual(clJob.params.sun_color, [2, 0.97, 0.92]);
  assert.deepEqual(clJob.params.bounds, [[0, 0, 0], [2, 1.6, 2]]);
  await cl.locator("img[data-output='direct.png']").waitFor();
  await cl.locator("img[data-output='ambient.png']").waitFor();
  await shot("04c-cloud");
  log("cloud ran with layers, a background, a sun-colour triple and a world box");

  // 4. The cloud editor.
  await page.click("#tab-editor");
  const ed = page.locator("#panel-editor");
  await ed.locator("button.example").click();
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.versions === "1" && p.dataset.image && document.getElementById("editor-image").complete;
  });
  const v1Image = await ed.getAttribute("data-image");
  await shot("05-editor-v1");
  const box = await ed.locator("canvas").boundingBox();
  const px = (x, y) => [box.x + (x / 400) * box.width, box.y + (y / 300) * box.height];

  // Sun-colour stroke across the middle of the cloud.
  await page.check("#tool-sun-color");
  await page.fill("#sun-color", "#ff6020");
  let [x0, y0] = px(170, 140);
  await page.mouse.move(x0, y0);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) {
    const [x, y] = px(170 + i * 6, 140 + i * 2);
    await page.mouse.move(x, y);
  }
  await page.mouse.up();
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.versions === "2" && p.dataset.current === "2";
  });
  const v2Image = await ed.getAttribute("data-image");
  assert.notEqual(v2Image, v1Image, "the image did not change after the sun-colour stroke");
  assert.notEqual(await hashOf(v2Image), await hashOf(v1Image), "the sun-colour edit changed no pixel");
  assert.equal((await ed.locator("#version-count").textContent()).trim(), "2");
  const stateV2 = JSON.parse(await ed.locator("pre.state").textContent());
  await shot("06-editor-sun-color");
  log(`sun colour after the stroke: ${JSON.stringify(stateV2.sun_color)}`);

  // Shadow drag: from the cloud's lower middle to a point beside it.
  await page.check("#tool-sun-direction");
  [x0, y0] = px(200, 175);
  const [x1, y1] = px(230, 190);
  await page.mouse.move(x0, y0);
  await page.mouse.down();
  await page.mouse.move((x0 + x1) / 2, (y0 + y1) / 2);
  await page.mouse.move(x1, y1);
  await page.mouse.up();
  await page.waitForFunction(() => document.getElementById("panel-editor").dataset.versions === "3");
  await page.waitForFunction(() => !document.querySelector("#panel-editor .versions").textContent.includes("pending"));
  const status = await ed.locator("p.status").textContent();
  assert.equal(await ed.getAttribute("data-current"), "3", `the shadow drag did not make v3 current: ${status}`);
  const stateV3 = JSON.parse(await ed.locator("pre.state").textContent());
  assert.notDeepEqual(stateV3.sun_direction, stateV2.sun_direction, "the sun direction did not change");
  log(`sun direction ${JSON.stringify(stateV2.sun_direction)} -> ${JSON.stringify(stateV3.sun_direction)}`);
  await shot("07-editor-shadow");
  // Thumbnails, the state as a table, before/after between v2 and v3.
  assert.equal(await ed.locator(".versions img.thumb").count(), 3, "a thumbnail per version");
  assert.match(await ed.locator("#state-table tr[data-key=sun_direction]").textContent(), /from \d+° \(compass\), -?\d+° above the horizon/);
  assert.match(await ed.locator("#state-table tr[data-key=kappa]").textContent(), /Density κ/);
  assert.ok(await page.locator("#compare").isVisible(), "no before/after comparison with three versions");
  assert.equal(await page.inputValue("#compare-before"), "2");
  assert.equal(await page.inputValue("#compare-after"), "3");
  await page.waitForFunction(() => [...document.querySelectorAll("#compare img")].every((i) => i.complete && i.naturalWidth > 0));
  const clipAt = () => page.locator("#compare img.cmp-after").evaluate((i) => i.style.clipPath);
  assert.equal(await clipAt(), "inset(0px 0px 0px 50%)");
  await page.locator("#compare-slider").fill("20");
  assert.equal(await clipAt(), "inset(0px 0px 0px 20%)");
  await page.locator("#compare").scrollIntoViewIfNeeded();
  await shot("07b-editor-compare");
  log("editor: thumbnails, state table, before/after slider");

  // Undo: back to v2 and an image of v2.
  const v3Image = await ed.getAttribute("data-image");
  await page.click("#undo");
  await page.waitForFunction((prev) => {
    const p = document.getElementById("panel-editor");
    return p.dataset.current === "2" && p.dataset.busy === "false" && p.dataset.image !== prev && document.getElementById("editor-image").complete;
  }, v3Image);
  const undoImage = await ed.getAttribute("data-image");
  assert.equal(await hashOf(undoImage), await hashOf(v2Image), "undo did not show version 2 again");
  assert.equal(await ed.locator("#redo").isDisabled(), false, "redo should be possible after undo");
  await shot("08-editor-undo");
  log("undo shows version 2");

  // Redo: back to version 3 and its image.
  await page.click("#redo");
  await page.waitForFunction((prev) => {
    const p = document.getElementById("panel-editor");
    return p.dataset.current === "3" && p.dataset.busy === "false" && p.dataset.image !== prev && document.getElementById("editor-image").complete;
  }, undoImage);
  const redoImage = await ed.getAttribute("data-image");
  assert.equal(await hashOf(redoImage), await hashOf(v3Image), "redo did not show version 3 again");
  assert.deepEqual(JSON.parse(await ed.locator("pre.state").textContent()).sun_direction, stateV3.sun_direction, "redo did not restore v3's sun direction");
  assert.equal(await ed.locator("#redo").isDisabled(), true, "nothing is left to redo");
  await shot("08b-editor-redo");
  log("redo shows version 3");

  // Ambient brush: a blue stroke into the cloud makes version 4 with a new image.
  await page.check("#tool-ambient");
  await page.fill("#ambient-color", "#2040ff");
  await page.fill("#ambient-scale", "1.5");
  [x0, y0] = px(160, 150);
  await page.mouse.move(x0, y0);
  await page.mouse.down();
  for (let i = 1; i <= 10; i++) {
    const [x, y] = px(160 + i * 8, 150 + (i % 3));
    await page.mouse.move(x, y);
  }
  await page.mouse.up();
  await page.waitForFunction(() => document.getElementById("panel-editor").dataset.versions === "4");
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.busy === "false" && !p.querySelector(".versions").textContent.includes("pending");
  });
  const ambStatus = await ed.locator("p.status").textContent();
  assert.equal(await ed.getAttribute("data-current"), "4", `the ambient stroke did not make v4 current: ${ambStatus}`);
  assert.equal((await ed.locator("#version-count").textContent()).trim(), "4");
  const v4Image = await ed.getAttribute("data-image");
  await page.waitForFunction(() => document.getElementById("editor-image").complete);
  assert.notEqual(await hashOf(v4Image), await hashOf(redoImage), "the ambient edit changed no pixel");
  assert.equal(edits.filter((e) => e.kind === "ambient").pop().body.ambient_scale, 1.5, "the ambient strength was not sent");
  await shot("08c-editor-ambient");
  log("ambient stroke made version 4");

  // Undo and redo from the keyboard (Ctrl+Z, Ctrl+Shift+Z) on the focused image.
  await ed.locator("canvas").focus();
  await page.keyboard.press("Control+z");
  await page.waitForFunction((prev) => {
    const p = document.getElementById("panel-editor");
    return p.dataset.current === "3" && p.dataset.busy === "false" && p.dataset.image !== prev;
  }, v4Image);
  await page.keyboard.press("Control+Shift+Z");
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.current === "4" && p.dataset.busy === "false" && document.getElementById("editor-image").complete;
  });
  assert.equal(await hashOf(await ed.getAttribute("data-image")), await hashOf(v4Image), "Ctrl+Shift+Z did not return to version 4");
  log("Ctrl+Z / Ctrl+Shift+Z undo and redo");

  // The keyboard only: on the focused image, 1 picks the sun-colour brush, the arrow keys move
  // the crosshair, Space held paints along the way, C applies the stroke: version 5.
  const edStatus = () => ed.locator("p.status").textContent();
  const ks = await ed.locator("canvas").getAttribute("aria-keyshortcuts");
  for (const k of ["ArrowLeft", "Shift+ArrowLeft", "Home", "Space", "Enter", "C", "Escape", "1"]) assert.ok(ks.split(" ").includes(k), `aria-keyshortcuts lacks ${k}: ${ks}`);
  assert.match(await ed.locator("#editor-keys").textContent(), /arrow keys move the crosshair/);
  await page.fill("#sun-color", "#3080ff");
  await ed.locator("canvas").focus();
  await page.keyboard.press("1");
  assert.equal(await page.isChecked("#tool-sun-color"), true, "1 did not pick the sun-colour brush");
  assert.ok(await ed.locator(".kbd-cursor").isVisible(), "no crosshair on the focused image");
  // Home centres the crosshair (200, 150); to (180, 146), then paint 12 steps right.
  await page.keyboard.press("Home");
  await page.keyboard.press("Shift+ArrowLeft");
  await page.keyboard.press("ArrowUp");
  assert.match(await edStatus(), /180, 146/, "the crosshair move was not announced");
  await page.keyboard.down(" ");
  for (let i = 0; i < 12; i++) await page.keyboard.press("ArrowRight");
  await page.keyboard.up(" ");
  assert.match(await edStatus(), /Painting at 228, 146/);
  await shot("08d-editor-keyboard-stroke");
  const before5 = edits.length;
  await page.keyboard.press("c");
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.versions === "5" && p.dataset.current === "5" && p.dataset.busy === "false" && document.getElementById("editor-image").complete;
  });
  const v5Image = await ed.getAttribute("data-image");
  assert.notEqual(await hashOf(v5Image), await hashOf(v4Image), "the keyboard stroke changed no pixel");
  assert.match(await edStatus(), /v5 \(sun-color\) is ready/);
  // The same request as the pointer's: same fields, one stroke of the brush's pixels.
  const mouseStroke = edits.find((e) => e.kind === "sun-color");
  const keyStroke = edits[before5];
  assert.equal(keyStroke.kind, "sun-color");
  assert.deepEqual(Object.keys(keyStroke.body).sort(), Object.keys(mouseStroke.body).sort());
  assert.equal(keyStroke.body.base_version, 4);
  assert.equal(keyStroke.body.strokes[0].color, "#3080ff");
  assert.ok(keyStroke.body.strokes[0].pixels.length > 12 * 4, `too few painted pixels: ${keyStroke.body.strokes[0].pixels.length}`);
  const stateV5 = JSON.parse(await ed.locator("pre.state").textContent());
  log(`keyboard stroke made version 5, sun colour ${JSON.stringify(stateV5.sun_color)}`);

  // Shadow drag by keyboard: 3 picks it, Space marks the shadowed spot, Enter where its shadow
  // should be: version 6 with another sun direction.
  await page.keyboard.press("3");
  assert.equal(await page.isChecked("#tool-sun-direction"), true, "3 did not pick the shadow drag");
  for (let i = 0; i < 7; i++) await page.keyboard.press("ArrowLeft"); // (200, 146)
  await page.keyboard.press("Shift+ArrowDown"); // (200, 166)
  await page.keyboard.press("ArrowDown");
  await page.keyboard.press("ArrowDown"); // (200, 174)
  await page.keyboard.press("Space");
  assert.match(await edStatus(), /Shadow drag from 200, 174/);
  await page.keyboard.press("Shift+ArrowRight");
  await page.keyboard.press("ArrowRight");
  await page.keyboard.press("ArrowRight");
  await page.keyboard.press("Shift+ArrowDown"); // (228, 194)
  await shot("08e-editor-keyboard-shadow");
  await page.keyboard.press("Enter");
  await page.waitForFunction(() => {
    const p = document.getElementById("panel-editor");
    return p.dataset.versions === "6" && p.dataset.busy === "false" && !p.querySelector(".versions").textContent.includes("pending");
  });
  assert.equal(await ed.getAttribute("data-current"), "6", `the keyboard shadow drag did not make v6 current: ${await edStatus()}`);
  const keyDrag = edits[edits.length - 1];
  assert.deepEqual(keyDrag.body.from, [200, 174]);
  assert.deepEqual(keyDrag.body.to, [228, 194]);
  assert.deepEqual(Object.keys(keyDrag.body).sort(), Object.keys(edits.find((e) => e.kind === "sun-direction").body).sort());
  const stateV6 = JSON.parse(await ed.locator("pre.state").textContent());
  assert.notDeepEqual(stateV6.sun_direction, stateV5.sun_direction, "the keyboard shadow drag did not change the sun direction");
  log(`keyboard shadow drag: sun direction ${JSON.stringify(stateV5.sun_direction)} -> ${JSON.stringify(stateV6.sun_direction)}`);

  // 5. Dust: the example mesh, small textures; the render and the fibre atlas show.
  await page.click("#tab-dust");
  const du = page.locator("#panel-dust");
  await du.locator("input[name=shells]").fill("8");
  await du.locator("input[name=texture_size]").fill("128");
  await du.locator("input[name=fibers]").fill("400");
  await du.locator("button.example").click();
  await page.waitForFunction(() => document.getElementById("panel-dust").dataset.status);
  assert.equal(await du.getAttribute("data-status"), "succeeded");
  await du.locator("img[data-output='render.png']").waitFor();
  await du.locator("img[data-output='fibers.png']").waitFor();
  await shot("09-dust");
  log("dust rendered with its fibre atlas");
  await viewerReady("dust", "dusty.glb");
  await page.locator("#viewer-dust").scrollIntoViewIfNeeded();
  assert.match(await page.getAttribute("#viewer-dust", "data-layers"), /dust/);
  const d0 = await canvasHash("dust");
  await shot("09a-dust-3d");
  await page.uncheck("#viewer-dust-layer-dust");
  assert.notEqual(await canvasHash("dust"), d0, "hiding the dust shells changed nothing");
  await page.check("#viewer-dust-layer-dust");
  await dragViewer("dust", -80, 20);
  assert.notEqual(await canvasHash("dust"), d0, "dragging the dust 3-D view changed nothing");
  log("dust 3-D: the shells toggle and a drag change the canvas");

  // The close-up: the camera at a tenth of the mesh's size; the far view stays beside it.
  const farJob = await du.getAttribute("data-job");
  const farSrc = await du.locator("img[data-output='render.png']").getAttribute("src");
  await page.waitForFunction(() => !document.getElementById("closeup-dust").disabled);
  await page.click("#closeup-dust");
  const closeJob = await nextJob("panel-dust", farJob);
  assert.equal(await page.getAttribute("#closeup-dust", "aria-pressed"), "true");
  // The example mesh is 4 m across: distance 0.4 m.
  assert.ok(Math.abs(closeJob.params.camera.distance - 0.4) < 1e-3, `close-up distance ${closeJob.params.camera.distance}`);
  const closeSrc = await du.locator("img[data-output='render.png']").getAttribute("src");
  assert.notEqual(await hashOf(closeSrc), await hashOf(farSrc), "the close-up changed nothing in the image");
  assert.equal(await du.locator("img[data-output='far']").getAttribute("src"), farSrc, "the far view is not shown beside the close-up");
  await du.locator("img[data-output='dust_amount.png']").waitFor();
  await shot("09b-dust-close-up");
  log("dust close-up at 0.4 m beside the far view");

  // Phone and laptop: every tab at 390×844 without horizontal overflow, and at 1366×768.
  for (const [w, h, tag] of [[390, 844, "phone"], [1366, 768, "laptop"]]) {
    await page.setViewportSize({ width: w, height: h });
    for (const tab of ["snow-terrain", "snow-cover", "cloud", "editor", "dust"]) {
      await page.click(`#tab-${tab}`);
      const [sw, bw, iw] = await page.evaluate(() => [document.documentElement.scrollWidth, document.body.scrollWidth, window.innerWidth]);
      assert.ok(sw <= iw && bw <= iw, `${tab} overflows horizontally at ${w}×${h}: scrollWidth ${sw}/${bw} > ${iw}`);
      await shot(`10-${tag}-${tab}`);
    }
    log(`${tag} ${w}×${h}: no horizontal overflow on any tab`);
  }
  for (const tab of TABS) await axeCheck(tab, "with results");
  log("axe-core: no serious or critical violation on any tab with results");

  // A server built without npm: /web/vendor.json says so, and the viewer says in words that it
  // is not installed and how to install it; the rest of the tab works.
  const bare = await browser.newPage({ viewport: { width: 1280, height: 900 } });
  bare.setDefaultTimeout(TIMEOUT);
  bare.on("console", (m) => { if (m.type() === "error") problems.push(`console error (no viewer): ${m.text()}`); });
  bare.on("pageerror", (e) => problems.push(`page error (no viewer): ${e.message}`));
  await bare.route("**/web/vendor.json", (r) => r.fulfill({ contentType: "application/json", body: JSON.stringify({ installed: false, packages: {}, files: [], reason: "PHENOMENA_NPM=off", install: "Install Node.js with npm (e.g. apt-get install -y nodejs npm), then rebuild: cargo build --release" }) }));
  await bare.goto(base + "/");
  await bare.waitForSelector("body[data-ready=true]");
  await bare.locator("#panel-snow-terrain button.example").click();
  await bare.waitForFunction(() => document.getElementById("panel-snow-terrain").dataset.status === "succeeded");
  await bare.waitForFunction(() => document.getElementById("viewer-snow-terrain").dataset.state === "unavailable");
  const why = await bare.locator("#viewer-snow-terrain .viewer-msg").textContent();
  assert.match(why, /not installed/);
  assert.match(why, /npm/);
  assert.equal(await bare.locator("#viewer-snow-terrain canvas").count(), 0);
  await bare.screenshot({ path: path.join(shots, "11-no-viewer.png"), fullPage: true });
  await bare.close();
  log(`without npm: "${why}"`);
} finally {
  await browser.close();
}
assert.deepEqual(problems, [], `the page had problems:\n${problems.join("\n")}`);
log("ok");
