// The studio page: one tab per pipeline. Each pipeline tab uploads its input once
// (POST /v1/assets), builds its parameter form from openapi.yaml's schema, submits JSON naming the
// asset on every (debounced) change, follows the job's server-sent events into a progress bar and
// shows the images and download links of the finished job. The cloud editor lives in cloud.js.

import { parseYaml } from "./yaml.js";
import { initEditor } from "./cloud.js";

/** Per pipeline: the schema of its params, the multipart part name (for labels), the example. */
const PIPELINES = {
  "snow-terrain": {
    schema: "SnowTerrainParams",
    input: "DEM (GeoTIFF, .asc, .hgt, 16-bit PNG, .npy)",
    example: "dem.asc",
    images: ["render.png", "descriptor.png", "sweep.png"],
  },
  "snow-cover": {
    schema: "SnowCoverParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
    images: ["render.png", "timelapse.png"],
  },
  cloud: {
    schema: "CloudParams",
    input: "density volume (.npy, NRRD, .vdb)",
    example: "volume.npy",
    images: ["render.png", "direct.png", "ambient.png"],
  },
  dust: {
    schema: "DustParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
    images: ["render.png", "dust_amount.png", "fibers.png"],
  },
};

/** Fields the form leaves out: the camera is driven by dragging the preview; the rest are
 * structured values (lists, schedules, boxes) better sent through the API directly. */
const SKIP = new Set(["camera", "sweep", "layers", "bounds", "dims", "snowfall", "wind", "sun_direction", "sun_color", "ambient", "dust_source"]);

/** The longest side of a quick preview, pixels. */
const PREVIEW_MAX = 480;

export const $ = (sel, root = document) => root.querySelector(sel);

export function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "class") e.className = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) e.append(c);
  return e;
}

/** Reads a problem+json (or any) error response into a message. */
export async function problem(resp) {
  try {
    const p = await resp.json();
    return p.detail || p.title || `HTTP ${resp.status}`;
  } catch {
    return `HTTP ${resp.status}`;
  }
}

/** Uploads bytes once; the server dedupes by SHA-256, so a second upload returns the same id. */
export async function uploadAsset(blob, filename) {
  const resp = await fetch(`/v1/assets?filename=${encodeURIComponent(filename)}`, {
    method: "POST",
    headers: { "content-type": "application/octet-stream" },
    body: blob,
  });
  if (!resp.ok) throw new Error(await problem(resp));
  return resp.json();
}

/** Follows a job to its end through GET /v1/jobs/{id}/events, calling onProgress(fraction,
 * stage) on each `progress` event; resolves with the finished job. */
export function followJob(job, onProgress) {
  const terminal = (s) => ["succeeded", "failed", "canceled"].includes(s);
  if (terminal(job.status)) {
    onProgress(1, job.status);
    return { job: Promise.resolve(job), close() {} };
  }
  let source;
  const done = new Promise((resolve, reject) => {
    source = new EventSource(job.events_url);
    source.addEventListener("progress", (e) => {
      const p = JSON.parse(e.data);
      onProgress(p.progress, p.stage || p.status);
    });
    source.addEventListener("done", (e) => {
      source.close();
      const j = JSON.parse(e.data);
      onProgress(1, j.status);
      resolve(j);
    });
    source.onerror = () => {
      // The stream ended or broke: ask for the job itself.
      source.close();
      fetch(job.url, { headers: { Prefer: "wait=60" } })
        .then((r) => (r.ok ? r.json() : Promise.reject(new Error("lost the job"))))
        .then(resolve, reject);
    };
  });
  return { job: done, close: () => source.close() };
}

/** A drop zone with a file input and an example button; calls onAsset(asset) after uploading. */
export function inputBox(label, example, onAsset, onError) {
  const id = `file-${Math.random().toString(36).slice(2)}`;
  const info = el("p", { class: "asset", "aria-live": "polite" }, "No input yet.");
  const take = async (blob, name) => {
    info.textContent = `Uploading ${name}…`;
    try {
      const asset = await uploadAsset(blob, name);
      info.textContent = `${name} — asset ${asset.id.slice(0, 12)}… (${asset.size} bytes)`;
      onAsset(asset);
    } catch (e) {
      info.textContent = "";
      onError(e.message);
    }
  };
  const file = el("input", {
    type: "file", id, class: "file",
    onchange: (e) => e.target.files[0] && take(e.target.files[0], e.target.files[0].name),
  });
  const zone = el("div", { class: "dropzone" },
    el("label", { for: id }, `Drop a ${label} here, or choose one:`), el("br"), file,
    el("p", {}, el("button", {
      type: "button", class: "secondary example",
      onclick: async () => {
        const r = await fetch(`/v1/examples/${example}`);
        if (!r.ok) return onError(await problem(r));
        take(await r.blob(), example);
      },
    }, `Try the example (${example})`)),
    info);
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    const f = e.dataTransfer.files[0];
    if (f) take(f, f.name);
  });
  return zone;
}

/** One form control per documented scalar parameter, with its range, default and description. */
function buildForm(schema, onChange) {
  const form = el("form", { class: "params", onsubmit: (e) => e.preventDefault() });
  const read = {};
  for (const [name, prop] of Object.entries(schema.properties || {})) {
    if (SKIP.has(name)) continue;
    const id = `p-${schema.__name}-${name}`;
    const desc = el("span", { class: "desc", id: `${id}-d` }, prop.description || "");
    let input;
    let get;
    const type = Array.isArray(prop.type) ? prop.type[0] : prop.type;
    if (type === "boolean") {
      input = el("input", { type: "checkbox", id, name, "aria-describedby": `${id}-d` });
      input.checked = prop.default === true;
      get = () => input.checked;
      form.append(el("div", { class: "field check" }, input, " ", el("label", { for: id }, name), desc));
    } else {
      if (prop.enum) {
        input = el("select", { id, name, "aria-describedby": `${id}-d` },
          prop.default === undefined ? el("option", { value: "" }, "(default)") : null,
          prop.enum.map((v) => el("option", { value: v, selected: v === prop.default }, v)));
        get = () => (input.value === "" ? undefined : input.value);
      } else if (type === "string" && prop.pattern && prop.pattern.includes("#")) {
        // A colour with no default (cloud `background`: absent = transparent) has no
        // "unset" state in a colour picker; leave it to the API.
        if (prop.default === undefined) continue;
        input = el("input", { type: "color", id, name, value: prop.default || "#000000", "aria-describedby": `${id}-d` });
        get = () => input.value;
      } else if (type === "integer" || type === "number") {
        const step = type === "integer" ? 1 : "any";
        input = el("input", {
          type: "number", id, name, step, min: prop.minimum, max: prop.maximum,
          value: prop.default, placeholder: prop.default === undefined ? "(unset)" : undefined,
          "aria-describedby": `${id}-d`,
        });
        get = () => (input.value === "" || !input.checkValidity() ? undefined : Number(input.value));
      } else {
        continue;
      }
      const range = prop.minimum !== undefined && prop.maximum !== undefined ? ` (${prop.minimum}–${prop.maximum})` : "";
      form.append(el("div", { class: "field" }, el("label", { for: id }, name + range), input, desc));
    }
    read[name] = { get, def: prop.default };
    input.addEventListener("input", onChange);
    input.addEventListener("change", onChange);
  }
  return {
    form,
    /** The parameters that differ from their defaults. */
    values() {
      const out = {};
      for (const [name, { get, def }] of Object.entries(read)) {
        const v = get();
        if (v !== undefined && v !== def) out[name] = v;
      }
      return out;
    },
  };
}

/** A pipeline tab: input, form, preview with orbit, progress, outputs. */
function pipelineTab(panel, name, spec) {
  const cfg = PIPELINES[name];
  const schema = { ...spec.components.schemas[cfg.schema], __name: name };
  const cameraSchema = spec.components.schemas.Camera.properties;
  const state = { asset: null, camera: null, timer: 0, follow: null, seq: 0 };
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const bar = el("progress", { max: 1, value: 0, "aria-label": `${name} progress` });
  const views = el("div", { class: "views" });
  const downloads = el("ul", { class: "downloads", "aria-label": "Downloads" });
  const quick = el("input", { type: "checkbox", id: `quick-${name}`, checked: true });
  const error = (m) => { status.textContent = m; status.classList.add("error"); };

  const { form, values } = buildForm(schema, () => schedule());
  quick.addEventListener("change", () => schedule());

  // A parameter sweep (snow-terrain's `sweep`): one numeric parameter over a list of values,
  // rendered into sweep.png beside the render.
  let sweep = null;
  const sweepProp = schema.properties.sweep;
  if (sweepProp) {
    const param = el("select", { id: `sweep-${name}-param` },
      el("option", { value: "" }, "(no sweep)"),
      sweepProp.properties.param.enum.map((v) => el("option", { value: v }, v)));
    const vals = el("input", { type: "text", id: `sweep-${name}-values`, placeholder: "e.g. 1000, 5000, 20000", inputmode: "decimal" });
    param.addEventListener("change", () => schedule());
    vals.addEventListener("change", () => schedule());
    sweep = {
      box: el("fieldset", { class: "field" }, el("legend", {}, "Parameter sweep"),
        el("label", { for: param.id }, "param"), param,
        el("label", { for: vals.id }, `values (${sweepProp.properties.values.minItems}–${sweepProp.properties.values.maxItems}, comma-separated)`), vals,
        el("span", { class: "desc" }, sweepProp.description)),
      value() {
        const v = vals.value.split(/[,\s]+/).filter(Boolean).map(Number);
        return param.value && v.length >= 2 && v.every(Number.isFinite) ? { param: param.value, values: v } : undefined;
      },
    };
  }

  function params() {
    const p = values();
    if (quick.checked) {
      const w = p.width ?? schema.properties.width.default;
      const h = p.height ?? schema.properties.height.default;
      const k = Math.min(1, PREVIEW_MAX / Math.max(w, h));
      p.width = Math.max(16, Math.round(w * k));
      p.height = Math.max(16, Math.round(h * k));
    }
    if (state.camera) p.camera = { ...state.camera };
    const sw = sweep && sweep.value();
    if (sw) p.sweep = sw;
    return p;
  }

  function schedule() {
    clearTimeout(state.timer);
    if (state.asset) state.timer = setTimeout(run, 350);
  }

  async function run() {
    const seq = ++state.seq;
    if (state.follow) state.follow.close();
    status.classList.remove("error");
    status.textContent = "Submitting…";
    bar.value = 0;
    const resp = await fetch(`/v1/${name}`, {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ asset: state.asset.id, params: params() }),
    });
    if (!resp.ok) return error(await problem(resp));
    const job = await resp.json();
    panel.dataset.job = job.id;
    state.follow = followJob(job, (p, stage) => {
      if (seq !== state.seq) return;
      bar.value = p;
      panel.dataset.progress = String(p);
      status.textContent = `${stage} — ${Math.round(p * 100)} %`;
    });
    let done;
    try {
      done = await state.follow.job;
    } catch (e) {
      return error(e.message);
    }
    if (seq !== state.seq) return;
    show(done);
  }

  function show(job) {
    panel.dataset.status = job.status;
    if (job.status !== "succeeded") {
      return error(job.error ? `${job.error.title}: ${job.error.detail}` : `job ${job.status}`);
    }
    status.textContent = `Done (job ${job.id.slice(0, 12)}…).`;
    views.replaceChildren();
    downloads.replaceChildren();
    for (const out of job.outputs) {
      downloads.append(el("li", {}, el("a", { class: "button secondary", href: out.url, download: out.name }, `${out.name} (${(out.size / 1024).toFixed(1)} KiB)`)));
    }
    for (const img of cfg.images) {
      const out = job.outputs.find((o) => o.name === img);
      if (!out) continue;
      const main = img === "render.png";
      const image = el("img", {
        src: out.url, alt: `${img} of job ${job.id}`, class: main ? "preview" : undefined,
        tabindex: main ? 0 : undefined, "data-output": img,
        title: main ? "Drag (or use the arrow keys) to orbit the camera" : undefined,
      });
      if (main) orbit(image);
      views.append(el("figure", {}, image, el("figcaption", {}, img)));
    }
  }

  // Orbit: dragging the render turns the camera (azimuth by x, elevation by y); arrow keys too.
  function camera() {
    return state.camera || {
      azimuth_deg: cameraSchema.azimuth_deg.default,
      elevation_deg: cameraSchema.elevation_deg.default,
    };
  }
  function turn(dAz, dEl) {
    const c = camera();
    state.camera = {
      azimuth_deg: ((c.azimuth_deg + dAz) % 360 + 360) % 360,
      elevation_deg: Math.max(-89, Math.min(89, c.elevation_deg + dEl)),
    };
  }
  function orbit(img) {
    let start = null;
    img.addEventListener("pointerdown", (e) => {
      e.preventDefault();
      start = { x: e.clientX, y: e.clientY };
      img.setPointerCapture(e.pointerId);
    });
    img.addEventListener("pointerup", (e) => {
      if (!start) return;
      const dx = e.clientX - start.x;
      const dy = e.clientY - start.y;
      start = null;
      if (Math.abs(dx) + Math.abs(dy) < 3) return;
      turn(-dx * 0.5, dy * 0.3);
      schedule();
    });
    img.addEventListener("keydown", (e) => {
      const d = { ArrowLeft: [-10, 0], ArrowRight: [10, 0], ArrowUp: [0, 5], ArrowDown: [0, -5] }[e.key];
      if (!d) return;
      e.preventDefault();
      turn(d[0], d[1]);
      schedule();
    });
  }

  const input = inputBox(cfg.input, cfg.example, (asset) => { state.asset = asset; panel.dataset.asset = asset.id; schedule(); }, error);
  panel.append(
    el("h2", {}, panel.getAttribute("aria-label") || document.getElementById(panel.getAttribute("aria-labelledby")).textContent),
    el("div", { class: "layout" },
      el("div", {}, input,
        el("div", { class: "field check" }, quick, " ", el("label", { for: `quick-${name}` }, `Quick preview (at most ${PREVIEW_MAX} px)`)),
        sweep ? sweep.box : null,
        form),
      el("div", {}, bar, status, views, downloads)));
}

function tabs() {
  const list = [...document.querySelectorAll("[role=tab]")];
  const select = (tab) => {
    for (const t of list) {
      const on = t === tab;
      t.setAttribute("aria-selected", String(on));
      t.tabIndex = on ? 0 : -1;
      document.getElementById(t.getAttribute("aria-controls")).hidden = !on;
    }
    tab.focus();
  };
  list.forEach((t, i) => {
    t.addEventListener("click", () => select(t));
    t.addEventListener("keydown", (e) => {
      const d = { ArrowRight: 1, ArrowLeft: -1 }[e.key];
      if (d) select(list[(i + d + list.length) % list.length]);
    });
  });
}

async function main() {
  tabs();
  const resp = await fetch("/openapi.yaml");
  const spec = parseYaml(await resp.text());
  for (const panel of document.querySelectorAll("section.pipeline")) {
    pipelineTab(panel, panel.dataset.pipeline, spec);
  }
  initEditor(document.getElementById("panel-editor"), spec);
  document.body.dataset.ready = "true";
}

main().catch((e) => {
  const f = document.getElementById("fatal");
  f.hidden = false;
  f.textContent = `The page could not start: ${e.message}`;
});
