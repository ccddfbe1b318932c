// Loads a GLB in three.js (GLTFLoader, a real glTF viewer's code) in headless Chromium and
// renders it twice from the same camera: every primitive drawn, then with the alpha-blended
// primitives hidden. Prints one JSON line: what the loader made of the file (meshes, their
// material names, alpha mode, texture, attributes) and pixel counts (model pixels, pixels the
// blended primitives change, and how many of those they brighten). Run by tests/it/web.rs
// (`displaced_glb_shows_its_flakes_in_three_js`); by hand:
//
//   GLB=/tmp/out/displaced.glb PLAYWRIGHT_DIR=target/browser-node \
//     SCREENSHOT=target/browser/flakes.png node tests/browser/gltf_viewer.mjs
//
// Files are served from a fake origin through Playwright's request routing (no server): the
// page, three.js from PLAYWRIGHT_DIR/node_modules/three, and the model.

import assert from "node:assert/strict";
import { createRequire } from "node:module";
import fs from "node:fs";
import path from "node:path";

const glb = process.env.GLB;
assert.ok(glb, "GLB is not set");
const pwDir = path.resolve(process.env.PLAYWRIGHT_DIR || "target/browser-node");
const shot = process.env.SCREENSHOT;
const require = createRequire(path.join(pwDir, "package.json"));
const { chromium } = require("playwright-core");
const threeDir = path.join(pwDir, "node_modules/three");
const ORIGIN = "http://viewer.test";
// Camera: direction from the model's centre and distance in bounding-box diagonals.
const dir = (process.env.VIEW_DIR || "0.55,0.45,0.7").split(",").map(Number);
const dist = Number(process.env.VIEW_DIST || "0.45");

const page = `<!doctype html><html><body style="margin:0">
<script type="importmap">{"imports":{"three":"/three/build/three.module.js",
"three/addons/":"/three/examples/jsm/"}}</script>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
const W = 640, H = 480;
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setSize(W, H);
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x203040);
scene.add(new THREE.HemisphereLight(0xdde8ff, 0x404040, 1.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(1, 2, 1.5);
scene.add(sun);
const pixels = () => {
  renderer.render(scene, window.cam);
  const gl = renderer.getContext();
  const px = new Uint8Array(W * H * 4);
  gl.readPixels(0, 0, W, H, gl.RGBA, gl.UNSIGNED_BYTE, px);
  return px;
};
new GLTFLoader().load("/model.glb", (g) => {
  scene.add(g.scene);
  const box = new THREE.Box3().setFromObject(g.scene);
  const c = box.getCenter(new THREE.Vector3());
  const r = box.getSize(new THREE.Vector3()).length();
  const d = new THREE.Vector3(${dir.join(",")}).normalize().multiplyScalar(r * ${dist});
  window.cam = new THREE.PerspectiveCamera(35, W / H, r / 1000, r * 10);
  window.cam.position.copy(c).add(d);
  window.cam.lookAt(c);
  const meshes = [];
  g.scene.traverse((o) => {
    if (o.isMesh) meshes.push(o);
  });
  const all = pixels();
  const blended = meshes.filter((m) => m.material.transparent);
  blended.forEach((m) => (m.visible = false));
  const bare = pixels();
  blended.forEach((m) => (m.visible = true));
  renderer.render(scene, window.cam); // the screenshot shows every primitive
  let model = 0, changed = 0, brighter = 0;
  const bg = [0x20, 0x30, 0x40];
  for (let i = 0; i < W * H * 4; i += 4) {
    const diff = [0, 1, 2].map((k) => all[i + k] - bare[i + k]);
    if ([0, 1, 2].some((k) => Math.abs(bare[i + k] - bg[k]) > 2)) model++;
    if (diff.some((x) => Math.abs(x) > 6)) {
      changed++;
      if (diff.reduce((a, b) => a + b, 0) > 0) brighter++;
    }
  }
  window.result = {
    meshes: meshes.map((m) => ({
      material: m.material.name,
      transparent: m.material.transparent,
      texture: !!m.material.map,
      vertexColors: m.material.vertexColors,
      attributes: Object.keys(m.geometry.attributes).sort(),
    })),
    model, changed, brighter,
  };
}, undefined, (e) => { window.result = { error: String(e) }; });
</script></body></html>`;

const browser = await chromium.launch({
  executablePath: "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-background-networking"],
});
const problems = [];
try {
  const p = await browser.newPage({ viewport: { width: 640, height: 480 } });
  p.on("console", (m) => { if (m.type() === "error") problems.push(`console: ${m.text()}`); });
  p.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
  await p.route("**/*", async (route) => {
    const url = new URL(route.request().url());
    if (url.origin !== ORIGIN) return route.abort();
    const file = url.pathname === "/" ? null
      : url.pathname === "/model.glb" ? glb
      : url.pathname.startsWith("/three/") ? path.join(threeDir, url.pathname.slice(7))
      : undefined;
    if (file === null) return route.fulfill({ contentType: "text/html", body: page });
    if (file === undefined || !fs.existsSync(file)) return route.fulfill({ status: 404 });
    const type = file.endsWith(".js") ? "text/javascript" : "model/gltf-binary";
    return route.fulfill({ contentType: type, body: fs.readFileSync(file) });
  });
  await p.goto(`${ORIGIN}/`);
  await p.waitForFunction(() => window.result, null, { timeout: 120_000 });
  const result = await p.evaluate(() => window.result);
  if (shot) {
    fs.mkdirSync(path.dirname(shot), { recursive: true });
    await p.screenshot({ path: shot });
  }
  console.log(JSON.stringify({ ...result, problems }));
} finally {
  await browser.close();
}
