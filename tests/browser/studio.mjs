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
// overflow) and 1366×768. Fails on any console error (but the deliberate 422's failed load),
// page error, or request to anything but the server.

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
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"],
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
  page.on("request", (r) => {
    if (!r.url().startsWith(base) && !r.url().startsWith("data:")) problems.push(`request beyond the server: ${r.url()}`);
    const m = r.method() === "POST" && r.url().match(/\/edits\/([a-z-]+)$/);
    if (m) edits.push({ kind: m[1], body: JSON.parse(r.postData()) });
  });
  const shot = (name) => page.screenshot({ path: path.join(shots, `${name}.png`), fullPage: true });
  const bytesOf = (url) => page.evaluate(async (u) => {
    const b = new Uint8Array(await (await fetch(u)).arrayBuffer());
    return Array.from(b.slice(0, 8)).concat([b.length]);
  }, url);
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
  await st.locator("input[name=snowline]").fill("700");
  await page.waitForFunction((j) => {
    const p = document.getElementById("panel-snow-terrain");
    const img = p.querySelector("img[data-output='render.png']");
    return p.dataset.job !== j && p.dataset.status === "succeeded" && img && img.src.includes(p.dataset.job) && img.complete;
  }, firstJob);
  const secondSrc = await st.locator("img[data-output='render.png']").getAttribute("src");
  assert.notEqual(secondSrc, firstSrc, "the render did not change job");
  assert.notEqual(await hashOf(secondSrc), await hashOf(firstSrc), "the snowline changed nothing in the image");
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
} finally {
  await browser.close();
}
assert.deepEqual(problems, [], `the page had problems:\n${problems.join("\n")}`);
log("ok");
