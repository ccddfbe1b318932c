// The 3-D viewer of a tab's glTF outputs (issue 23): three.js with its GLTFLoader and
// OrbitControls, installed from the npm registry when the server was built and served under
// /web/vendor/ (index.html's import map names them). Drag to orbit, wheel or pinch to zoom,
// right-drag (or Shift+drag) to pan; "Reset view" frames the model again. The model keeps its
// own materials (vertex colours, textures, blending); its layers — the snow layer, the falling
// flakes, the dust shells — are found by their node and material names and get a toggle each.
//
// Built without npm, /web/vendor.json says so and the viewer says in words that it is not
// installed and how to install it; the rest of the page works.

import { el } from "./app.js";

/** What the server's build installed (fetched once). */
let vendor = null;
export function vendorInfo() {
  vendor ??= fetch("/web/vendor.json")
    .then((r) => (r.ok ? r.json() : { installed: false, reason: `the server answered ${r.status}` }))
    .catch((e) => ({ installed: false, reason: e.message }));
  return vendor;
}

/** three.js and its two add-ons (loaded once, on the first model). */
let three = null;
function loadThree() {
  three ??= Promise.all([
    import("three"),
    import("three/addons/loaders/GLTFLoader.js"),
    import("three/addons/controls/OrbitControls.js"),
  ]).then(([THREE, g, o]) => ({ THREE, GLTFLoader: g.GLTFLoader, OrbitControls: o.OrbitControls }));
  return three;
}

/** The layers a toggle can hide, by the names the engine gives their nodes and materials. */
const LAYERS = [
  { key: "flakes", label: "Falling flakes", test: (n) => /flake/.test(n) },
  { key: "dust", label: "Dust shells", test: (n) => /dust_shell/.test(n) },
  { key: "snow", label: "Snow", test: (n) => /snow/.test(n) },
];
const layerOf = (mesh) => {
  const names = [mesh.name, mesh.parent && mesh.parent.name, mesh.material && mesh.material.name].filter(Boolean).join(" ").toLowerCase();
  const l = LAYERS.find((x) => x.test(names));
  return l ? l.key : null;
};

/** Plain-words descriptions of the models the pipelines write. */
const MODELS = {
  "terrain.glb": "terrain with its snow colours",
  "displaced.glb": "your mesh under its snow, with the falling flakes",
  "snow.glb": "the snow alone",
  "scene.glb": "your mesh and its snow as separate parts",
  "dusty.glb": "your mesh with its dust shells",
};

/**
 * A viewer for one tab. `show(models)` takes the job's glTF outputs ({ name, url }) and loads
 * the chosen one; the container's `data-state` is empty | loading | ready | error | unavailable.
 */
export function createViewer(name) {
  const id = `viewer-${name}`;
  const stage = el("div", { class: "viewer-stage" });
  const msg = el("p", { class: "viewer-msg", id: `${id}-msg`, "aria-live": "polite" },
    "No 3-D model yet: it appears here after the first render.");
  stage.append(msg);
  const pick = el("select", { id: `${id}-model`, "aria-label": "3-D model to show", disabled: true });
  const toggles = el("span", { class: "checks", role: "group", "aria-label": "Layers shown" });
  const reset = el("button", { type: "button", class: "secondary", id: `${id}-reset`, disabled: true }, "Reset view");
  const root = el("figure", { class: "viewer", id, "data-state": "empty" },
    el("div", { class: "toolbar" }, el("label", { for: pick.id }, "3-D model"), pick, toggles, reset),
    stage,
    el("figcaption", { id: `${id}-help` }, "Drag to turn the model, scroll or pinch to zoom, right-drag or Shift+drag to pan; with the view focused, the arrow keys pan and Shift+arrows turn it."));

  const v = { renderer: null, scene: null, camera: null, controls: null, model: null, fitted: null, models: [], seq: 0 };
  const say = (state, text) => {
    root.dataset.state = state;
    msg.textContent = text;
    msg.hidden = !text;
  };
  const draw = () => v.renderer && v.camera && v.renderer.render(v.scene, v.camera);

  async function setup() {
    const { THREE, OrbitControls } = await loadThree();
    const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(Math.min(2, window.devicePixelRatio || 1));
    const canvas = renderer.domElement;
    canvas.tabIndex = 0;
    canvas.setAttribute("role", "img");
    canvas.setAttribute("aria-label", "3-D view of the model");
    canvas.setAttribute("aria-describedby", `${id}-help`);
    stage.prepend(canvas);
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0x2b3a4a);
    scene.add(new THREE.HemisphereLight(0xe4ecff, 0x3a3530, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 2.2);
    scene.add(sun);
    scene.add(sun.target);
    const camera = new THREE.PerspectiveCamera(40, 4 / 3, 0.01, 1000);
    const controls = new OrbitControls(camera, canvas);
    controls.listenToKeyEvents(canvas);
    controls.addEventListener("change", draw);
    Object.assign(v, { THREE, renderer, scene, camera, controls, sun });
    const size = () => {
      const w = stage.clientWidth;
      const h = stage.clientHeight;
      if (!w || !h) return;
      renderer.setSize(w, h, false);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
      draw();
    };
    new ResizeObserver(size).observe(stage);
    size();
  }

  /** Frames the model: the camera looks at its box's centre from the south-east, above. */
  function fit() {
    const { THREE, camera, controls, sun } = v;
    const box = new THREE.Box3().setFromObject(v.model);
    const c = box.getCenter(new THREE.Vector3());
    const r = Math.max(1e-6, box.getSize(new THREE.Vector3()).length() / 2);
    camera.near = r / 500;
    camera.far = r * 50;
    camera.position.copy(c).add(new THREE.Vector3(0.75, 0.6, 1.0).normalize().multiplyScalar(r * 2.9));
    camera.updateProjectionMatrix();
    controls.target.copy(c);
    controls.minDistance = r / 50;
    controls.maxDistance = r * 20;
    controls.update();
    sun.position.copy(c).add(new THREE.Vector3(1, 2, 1.5).multiplyScalar(r));
    sun.target.position.copy(c);
    v.fitted = r;
    draw();
  }

  function dispose(obj) {
    obj.traverse((o) => {
      if (!o.isMesh) return;
      o.geometry.dispose();
      for (const m of [].concat(o.material)) {
        for (const t of Object.values(m)) if (t && t.isTexture) t.dispose();
        m.dispose();
      }
    });
  }

  function layerToggles() {
    const present = new Map();
    v.model.traverse((o) => {
      if (!o.isMesh) return;
      const k = layerOf(o);
      if (k) present.set(k, (present.get(k) || []).concat(o));
    });
    toggles.replaceChildren(...LAYERS.filter((l) => present.has(l.key)).map((l) => {
      const box = el("input", { type: "checkbox", id: `${id}-layer-${l.key}`, checked: true, "data-layer": l.key });
      box.addEventListener("change", () => {
        for (const m of present.get(l.key)) m.visible = box.checked;
        draw();
      });
      return el("span", {}, box, " ", el("label", { for: box.id, class: "inline" }, l.label));
    }));
    root.dataset.layers = [...present.keys()].join(" ");
  }

  /** How many vertex colours are snow (every linear channel ≥ 0.7) and how many are not, over the
   * vertex-coloured meshes (`data-colors`: what the page shows of the model's own colours). */
  function colourCounts() {
    let snow = 0;
    let other = 0;
    v.model.traverse((o) => {
      const c = o.isMesh && o.material.vertexColors && o.geometry.attributes.color;
      if (!c) return;
      for (let i = 0; i < c.count; i++) {
        if (Math.min(c.getX(i), c.getY(i), c.getZ(i)) >= 0.7) snow++;
        else other++;
      }
    });
    root.dataset.colors = JSON.stringify({ snow, other });
  }

  async function load(model) {
    const seq = ++v.seq;
    const info = await vendorInfo();
    if (!info.installed) {
      pick.disabled = true;
      return say("unavailable", `The 3-D viewer is not installed on this server: it was built without npm, so three.js (from the npm registry) is missing${info.reason ? ` (${info.reason})` : ""}. ${info.install || "Install Node.js with npm and rebuild the server"}. The model downloads below work without it.`);
    }
    say("loading", `Loading ${model.name}…`);
    try {
      if (!v.renderer) await setup();
      const { GLTFLoader } = await loadThree();
      const gltf = await new GLTFLoader().loadAsync(model.url);
      if (seq !== v.seq) return dispose(gltf.scene);
      if (v.model) {
        v.scene.remove(v.model);
        dispose(v.model);
      }
      v.model = gltf.scene;
      v.scene.add(v.model);
      layerToggles();
      colourCounts();
      // Keep the user's view across re-renders of the same kind of model; frame a new one.
      const r = new v.THREE.Box3().setFromObject(v.model).getSize(new v.THREE.Vector3()).length() / 2;
      if (!v.fitted || root.dataset.model !== model.name || r > 2 * v.fitted || r < v.fitted / 2) fit();
      else draw();
      root.dataset.model = model.name;
      root.dataset.url = model.url;
      reset.disabled = false;
      pick.disabled = v.models.length < 2;
      say("ready", "");
    } catch (e) {
      if (seq !== v.seq) return;
      say("error", `The 3-D model ${model.name} could not be shown: ${e.message || e}`);
    }
  }

  pick.addEventListener("change", () => {
    const m = v.models.find((x) => x.name === pick.value);
    if (m) load(m);
  });
  reset.addEventListener("click", () => v.model && fit());

  return {
    node: root,
    /** Shows the chosen (or first) of these glTF outputs; none: says why. */
    show(models) {
      v.models = models;
      const keep = models.find((m) => m.name === pick.value) || models[0];
      pick.replaceChildren(...models.map((m) => el("option", { value: m.name, selected: m === keep }, `${m.name} — ${MODELS[m.name] || "model"}`)));
      if (!keep) {
        pick.disabled = true;
        return say("empty", "This job wrote no 3-D model (add a .glb to the outputs to get one).");
      }
      load(keep);
    },
  };
}
