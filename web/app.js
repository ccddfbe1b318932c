// The studio page: one tab per pipeline. Each pipeline tab uploads its input once
// (POST /v1/assets), builds its parameter form from openapi.yaml's schema, submits JSON naming the
// asset on every (debounced) change, follows the job's server-sent events into a progress bar and
// shows the images and download links of the finished job. The cloud editor lives in cloud.js.

import { parseYaml } from "./yaml.js";
import { initEditor } from "./cloud.js";
import { buildForm, resolve } from "./form.js";
import { createViewer } from "./viewer.js";
import { initMap } from "./map.js";
import { MAIN, PRESETS, labelOf } from "./labels.js";

/** Per pipeline: the schema of its params, the multipart part name (for labels), the example. */
const PIPELINES = {
  "snow-terrain": {
    schema: "SnowTerrainParams",
    input: "DEM (GeoTIFF, .asc, .hgt, 16-bit PNG, .npy)",
    example: "dem.asc",
    empty: "the render, the snow map and a 3-D model of the snowy terrain appear here",
    models: true,
    images: [["render.png", "render"], ["descriptor.png", "snow-cover map (white = snow)"], ["sweep.png", "parameter sweep"]],
    // An optional orthophoto whose colours replace rock_color (`ortho_asset`).
    ortho: true,
  },
  "snow-cover": {
    schema: "SnowCoverParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
    empty: "the render, a time-lapse and 3-D models of your mesh under its snow appear here",
    models: true,
    images: [["render.png", "render"], ["timelapse.png", "time-lapse"]],
  },
  cloud: {
    schema: "CloudParams",
    input: "density volume (.npy, NRRD, .vdb)",
    example: "volume.npy",
    empty: "the render and its light layers (direct, multiple scattering, sky) appear here",
    images: [["render.png", "render"], ["direct.png", "direct light (single scattering)"], ["multiple.png", "multiple scattering"], ["ambient.png", "ambient light"]],
  },
  dust: {
    schema: "DustParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
    empty: "the render, the fibre textures, the dust map and a 3-D model with its dust shells appear here",
    models: true,
    images: [["render.png", "render"], ["fibers.png", "fibre textures (atlas)"], ["dust_amount.png", "dust amount D"]],
    closeUp: true,
  },
};

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

/** Words for the HTTP statuses a page user may meet, when the body says nothing better. */
const STATUS_WORDS = {
  400: "The request could not be read", 404: "Not found", 413: "The file is too large for this server",
  415: "This file type is not supported here", 422: "A parameter is not valid", 429: "The server is busy: try again in a moment",
  503: "The server is busy or shutting down: try again in a moment",
};

/** Reads a problem+json (or any) error response into an Error whose message is in words and
 * whose `detail` line holds the HTTP code and problem type. */
export async function problem(resp) {
  const p = await problemOf(resp);
  return Object.assign(new Error(p.message), { detail: p.detail });
}

/** A problem+json response as { message, field, detail }: "A parameter is not valid: wind:
 * missing field …", detail "HTTP 422 · invalid-parameter". */
export async function problemOf(resp) {
  const words = STATUS_WORDS[resp.status] || (resp.status >= 500 ? "The server failed" : "The request was refused");
  let p = {};
  try {
    p = await resp.json();
  } catch { /* not JSON: words only */ }
  const type = typeof p.type === "string" && p.type !== "about:blank" ? ` · ${p.type.split("/").pop()}` : "";
  const title = p.title || words;
  const message = p.detail ? `${title}: ${p.detail}` : title;
  return { message, field: p.field, detail: `HTTP ${resp.status}${type}` };
}

/** Writes a message into a status line; errors get the class and a small detail line. */
export function say(node, text, { error = false, detail = "" } = {}) {
  node.replaceChildren(text, ...(detail ? [" ", el("small", { class: "detail" }, detail)] : []));
  node.classList.toggle("error", error);
}

/** Uploads bytes once; the server dedupes by SHA-256, so a second upload returns the same id. */
export async function uploadAsset(blob, filename) {
  const resp = await fetch(`/v1/assets?filename=${encodeURIComponent(filename)}`, {
    method: "POST",
    headers: { "content-type": "application/octet-stream" },
    body: blob,
  });
  if (!resp.ok) throw await problem(resp);
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

/** A drop zone with a file input and an example button; calls onAsset(asset) after uploading,
 * onError(message, detail) on a failure. The file input shows the name of a dropped file or the
 * example too. */
export function inputBox(label, example, onAsset, onError) {
  const id = `file-${Math.random().toString(36).slice(2)}`;
  const info = el("p", { class: "asset", "aria-live": "polite" }, "No input yet.");
  const take = async (blob, name) => {
    info.textContent = `Uploading ${name}…`;
    try {
      const asset = await uploadAsset(blob, name);
      info.replaceChildren(el("strong", {}, name), ` — uploaded (${(asset.size / 1024).toFixed(1)} KiB, asset ${asset.id.slice(0, 12)}…)`);
      onAsset(asset);
    } catch (e) {
      info.textContent = `${name}: not uploaded.`;
      onError(e.message, e.detail);
    }
  };
  /** Puts the file into the file input, so that it names it rather than "No file chosen". */
  const show = (f) => {
    try {
      const dt = new DataTransfer();
      dt.items.add(f);
      file.files = dt.files;
    } catch { /* an old browser: the info line names it */ }
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
        if (!r.ok) {
          const p = await problemOf(r);
          return onError(p.message, p.detail);
        }
        const f = new File([await r.blob()], example);
        show(f);
        take(f, example);
      },
    }, `Try the example (${example})`)),
    info);
  zone.addEventListener("dragover", (e) => { e.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    zone.classList.remove("over");
    const f = e.dataTransfer.files[0];
    if (!f) return;
    show(f);
    take(f, f.name);
  });
  return zone;
}

/** Starting values for a sweep of `param`: five values around its current value, in its range. */
function sweepValues(prop, current) {
  const lo = prop.minimum ?? 0;
  const hi = prop.maximum ?? (current || 1) * 4;
  const v = current ?? prop.default ?? (lo + hi) / 2;
  let vals;
  if (v > 0 && lo >= 0 && hi / Math.max(lo, 1e-9) > 1000) {
    vals = [v / 4, v / 2, v, v * 2, v * 4]; // wide ranges (metres): geometric
  } else {
    const span = Math.min(hi - lo, Math.max(Math.abs(v), (hi - lo) / 2));
    vals = [-1, -0.5, 0, 0.5, 1].map((k) => v + (k * span) / 2);
  }
  const round = prop.type === "integer" ? Math.round : (x) => Number(x.toPrecision(3));
  return [...new Set(vals.map((x) => round(Math.min(hi, Math.max(lo, x)))))];
}

/** The glTF outputs in the order the viewer offers them (the most telling first). */
const MODEL_ORDER = ["terrain.glb", "displaced.glb", "dusty.glb", "scene.glb", "snow.glb"];

/** A pipeline tab: input, form, preview with orbit, progress, outputs, 3-D viewer. */
function pipelineTab(panel, name, spec) {
  const cfg = PIPELINES[name];
  const schema = spec.components.schemas[cfg.schema];
  const cameraSchema = resolve(spec, spec.components.schemas.Camera).properties;
  const state = { asset: null, timer: 0, follow: null, job: null, seq: 0, resolvedCamera: null, size: null, closeUp: false, far: null, ortho: null, preview: true, shown: false };
  const status = el("p", { class: "status", role: "status", "aria-live": "polite", id: `status-${name}` });
  const bar = el("progress", { max: 1, value: 0, "aria-label": `${name} progress`, hidden: true });
  const cancel = el("button", { type: "button", class: "secondary", id: `cancel-${name}`, disabled: true, title: "Stop the running job" }, "Cancel");
  // After a refused or invalid change the last results stay, marked out of date (dimmed, a
  // label, and the images described by the label and the error) until the next success.
  const staleNote = el("p", { class: "stale-note", id: `stale-${name}`, hidden: true },
    "Out of date: the results below are the last successful ones, not of the current parameters (see the message above).");
  // Before the first result: what to do, in the box the results will take.
  const empty = el("div", { class: "empty-state", id: `empty-${name}` },
    el("p", {}, el("strong", {}, "No result yet."), ` Drop a ${cfg.input.split(" (")[0]} in the box${window.matchMedia("(max-width: 760px)").matches ? " above" : " on the left"}, or press “Try the example”: ${cfg.empty}.`),
    el("p", { class: "hint" }, "Every change of a setting renders again; the last good result stays until the new one has loaded."));
  const views = el("div", { class: "views" });
  const viewer = cfg.models ? createViewer(name) : null;
  const dlHead = el("h3", { class: "dl-head", hidden: true, id: `downloads-${name}-h` }, "Downloads");
  const downloads = el("ul", { class: "downloads", "aria-labelledby": dlHead.id });
  const error = (m, detail) => say(status, m, { error: true, detail });
  const stale = (on) => {
    on = on && views.childElementCount > 0;
    views.classList.toggle("stale", on);
    staleNote.hidden = !on;
    if (on) panel.dataset.stale = "true";
    else delete panel.dataset.stale;
    for (const i of views.querySelectorAll("img")) {
      if (on) i.setAttribute("aria-describedby", `${staleNote.id} ${status.id}`);
      else i.removeAttribute("aria-describedby");
    }
  };
  const refuse = (m, detail) => { error(m, detail); stale(true); };

  const { form, values, widgets, mark, set: setField } = buildForm(spec, schema, name, () => { sizeLabel(); schedule(); },
    { main: MAIN[name] || [], labels: (n) => labelOf(name, n) });

  // Preview or full size: says which size the images and the download links are.
  const sizeBox = el("fieldset", { class: "size-choice" }, el("legend", {}, "Size"));
  const fullLabel = el("span", {});
  for (const [key, text] of [["preview", `Preview (at most ${PREVIEW_MAX} px, quick)`], ["full", fullLabel]]) {
    const r = el("input", { type: "radio", name: `size-${name}`, id: `size-${name}-${key}`, value: key, checked: key === "preview" });
    r.addEventListener("change", () => { state.preview = key === "preview"; schedule(); });
    sizeBox.append(el("span", {}, r, " ", el("label", { for: r.id, class: "inline" }, text)));
  }
  function fullSize() {
    const { values: p } = values();
    return [p.width ?? schema.properties.width.default, p.height ?? schema.properties.height.default];
  }
  function sizeLabel() {
    const [w, h] = fullSize();
    // What to expect: the last preview's time and how many more pixels full size has.
    const last = state.lastPreview;
    const hint = last && w * h > last.px ? `, ${(w * h / last.px).toFixed(1)}× the preview's pixels; the preview took ${(last.ms / 1000).toFixed(1)} s` : ", slower";
    fullLabel.textContent = `Full size (${w} × ${h} px${hint})`;
  }
  sizeLabel();

  // Presets (snow-terrain): a look in one click; it fills the form's fields.
  let presetBox = null;
  const presets = PRESETS[name];
  if (presets) {
    const touched = [...new Set(presets.flatMap((p) => Object.keys(p.set)))];
    presetBox = el("fieldset", { class: "presets", id: `presets-${name}` }, el("legend", {}, "Look"));
    for (const p of presets) {
      const r = el("input", { type: "radio", name: `preset-${name}`, id: `preset-${name}-${p.key}`, value: p.key, checked: p.key === presets[0].key, "aria-describedby": `preset-${name}-${p.key}-d` });
      r.addEventListener("change", () => {
        for (const k of touched) setField(k, p.set[k]);
        panel.dataset.preset = p.key;
        schedule();
      });
      presetBox.append(el("span", { class: "preset" }, r, " ", el("label", { for: r.id, class: "inline" }, p.label),
        el("small", { class: "desc", id: `preset-${name}-${p.key}-d` }, p.help)));
    }
    panel.dataset.preset = presets[0].key;
  }

  // A parameter sweep (snow-terrain's `sweep`): one numeric parameter over a list of values,
  // rendered into sweep.png beside the render and the snow-cover map.
  let sweep = null;
  const sweepProp = schema.properties.sweep;
  if (sweepProp) {
    const vp = sweepProp.properties.values;
    const param = el("select", { id: `sweep-${name}-param` },
      el("option", { value: "" }, "(no sweep)"),
      sweepProp.properties.param.enum.map((v) => el("option", { value: v }, `${labelOf(name, v).label} (${v})`)));
    const vals = el("input", { type: "text", id: `sweep-${name}-values`, placeholder: "e.g. 1000, 5000, 20000", inputmode: "decimal", "aria-describedby": `sweep-${name}-d` });
    param.addEventListener("change", () => {
      // Suggest values around the parameter's current value; the user edits them.
      if (param.value) {
        const w = widgets[param.value];
        const cur = w && w.get();
        vals.value = sweepValues(resolve(spec, schema.properties[param.value]), typeof cur === "number" && !Number.isNaN(cur) ? cur : undefined).join(", ");
      }
      schedule();
    });
    vals.addEventListener("change", () => schedule());
    sweep = {
      box: el("details", { class: "sweep-box" }, el("summary", {}, "Compare values side by side (sweep)"),
        el("fieldset", { class: "field sweep" }, el("legend", {}, "Parameter sweep"),
          el("label", { for: param.id }, "Setting to vary"), param,
          el("label", { for: vals.id }, `Values (${vp.minItems}–${vp.maxItems}, comma-separated)`), vals,
          el("span", { class: "desc", id: `sweep-${name}-d` }, "One render per value, side by side in sweep.png."))),
      value() {
        const v = vals.value.split(/[,\s]+/).filter(Boolean).map(Number);
        return param.value && v.length >= vp.minItems && v.length <= vp.maxItems && v.every(Number.isFinite) ? { param: param.value, values: v } : undefined;
      },
    };
  }

  // Dust's close-up (`close_up`): the orbit camera at a tenth of the mesh's size from the
  // dustiest point the far view sees, so single fibres show.
  let closeUp = null;
  if (cfg.closeUp) {
    closeUp = el("button", {
      type: "button", class: "secondary", id: `closeup-${name}`, "aria-pressed": "false", disabled: true,
      title: "Render from a camera at a tenth of the mesh's size from the dustiest point in view (the far view stays beside it)",
      onclick: () => {
        state.closeUp = !state.closeUp;
        closeUp.setAttribute("aria-pressed", String(state.closeUp));
        closeUp.textContent = state.closeUp ? "Close-up: on" : "Close-up: off";
        run();
      },
    }, "Close-up: off");
  }

  function params() {
    const { values: p, bad } = values();
    if (bad.length) return { bad };
    if (state.preview) {
      const [w, h] = fullSize();
      const k = Math.min(1, PREVIEW_MAX / Math.max(w, h));
      p.width = Math.max(16, Math.round(w * k));
      p.height = Math.max(16, Math.round(h * k));
    }
    const sw = sweep && sweep.value();
    if (sw) p.sweep = sw;
    if (state.closeUp && state.size) {
      const c = p.camera && !p.camera.eye ? p.camera : {};
      p.camera = { ...c, distance: Number((state.size / 10).toPrecision(4)) };
      p.close_up = true;
    }
    return { params: p };
  }

  function schedule() {
    clearTimeout(state.timer);
    if (state.asset) state.timer = setTimeout(run, 350);
  }

  const running = (job) => {
    state.job = job;
    cancel.disabled = !job;
    panel.dataset.running = job ? job.id : "";
  };
  cancel.addEventListener("click", async () => {
    const job = state.job;
    if (!job) return;
    cancel.disabled = true;
    say(status, "Canceling…");
    const r = await fetch(job.url, { method: "DELETE" });
    if (!r.ok && r.status !== 409) {
      const p = await problemOf(r);
      error(`Could not cancel: ${p.message}`, p.detail);
    }
  });

  async function run() {
    clearTimeout(state.timer);
    if (!state.asset) return;
    const seq = ++state.seq;
    if (state.follow) state.follow.close();
    running(null);
    const { params: p, bad } = params();
    if (bad) {
      const names = bad.map((n) => labelOf(name, n).label).join(", ");
      return refuse(`Not sent: fix ${names} (a number out of its range, or an incomplete value).`);
    }
    mark(null);
    say(status, "Submitting…");
    bar.hidden = false;
    bar.value = 0;
    const resp = await fetch(`/v1/${name}`, {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ asset: state.asset.id, ...(state.ortho ? { ortho_asset: state.ortho.id } : {}), params: p }),
    });
    if (!resp.ok) {
      const pr = await problemOf(resp);
      if (seq !== state.seq) return;
      if (pr.field) mark(pr.field.replace(/^params\./, "").split(/[.[]/)[0]);
      panel.dataset.status = "rejected";
      return refuse(pr.message, pr.detail);
    }
    const job = await resp.json();
    if (seq !== state.seq) return;
    panel.dataset.job = job.id;
    delete panel.dataset.status;
    running(job);
    state.follow = followJob(job, (f, stage) => {
      if (seq !== state.seq) return;
      bar.value = f;
      panel.dataset.progress = String(f);
      if (!status.textContent.startsWith("Canceling")) say(status, `${stage} — ${Math.round(f * 100)} %`);
    });
    let done;
    try {
      done = await state.follow.job;
    } catch (e) {
      if (seq === state.seq) running(null);
      return seq === state.seq ? refuse(e.message) : undefined;
    }
    if (seq !== state.seq) return;
    running(null);
    await show(done, p, seq);
  }

  /** Loads an image; resolves when it can be shown (or failed: then it shows its alt text). */
  const loaded = (img) => (img.decode ? img.decode() : Promise.resolve()).catch(() => {});

  async function show(job, sent, seq) {
    if (job.status === "canceled") {
      panel.dataset.status = "canceled";
      return refuse(views.childElementCount ? "Canceled. The results below are from the last finished render." : "Canceled. Change a setting or press “Try the example” to render again.");
    }
    if (job.status !== "succeeded") {
      panel.dataset.status = job.status;
      return refuse(job.error ? `The render failed: ${job.error.detail || job.error.title}` : `The job ended: ${job.status}`, job.error ? job.error.title : "");
    }
    if (job.params && job.params.camera) state.resolvedCamera = job.params.camera;
    if (closeUp && state.size === null) {
      // The mesh's size, for the close-up: the report's input bounds.
      const rep = job.outputs.find((o) => o.name === "report.json");
      if (rep) {
        const r = await fetch(rep.url);
        const b = r.ok && (await r.json()).input?.bounds;
        if (b) state.size = Math.max(b[1][0] - b[0][0], b[1][1] - b[0][1], b[1][2] - b[0][2]);
      }
      closeUp.disabled = !state.size;
    }
    const close = state.closeUp && sent.camera && sent.camera.distance;
    const figs = [];
    if (close && state.far) {
      figs.push(el("figure", { class: "far" }, el("img", { src: state.far, alt: "far view (the last render without the close-up)", "data-output": "far" }), el("figcaption", {}, "far view")));
    }
    for (const [img, caption] of cfg.images) {
      const out = job.outputs.find((o) => o.name === img);
      if (!out) continue;
      const main = img === "render.png";
      if (main && !close) state.far = out.url;
      const image = el("img", {
        src: out.url, alt: `${caption} (${img}) of job ${job.id}`, class: main ? "preview" : img.replace(".png", ""),
        tabindex: main ? 0 : undefined, "data-output": img,
        title: main ? "Drag (or use the arrow keys) to orbit the camera" : undefined,
      });
      if (main) orbit(image);
      const cap = main && close ? `close-up render (${sent.camera.distance} m from the dustiest point in view)` : caption;
      figs.push(el("figure", { class: main ? "main" : img === "sweep.png" ? "wide" : undefined }, image,
        el("figcaption", {}, cap, main ? null : [" · ", el("a", { href: out.url, target: "_blank", rel: "noopener" }, "open")])));
    }
    // Replace the old images only once the new ones have loaded: the result area keeps its box.
    await Promise.all(figs.map((f) => loaded(f.querySelector("img"))));
    if (seq !== state.seq) return;
    views.replaceChildren(...figs);
    empty.hidden = true;
    const [w, h] = [sent.width ?? schema.properties.width.default, sent.height ?? schema.properties.height.default];
    dlHead.hidden = false;
    dlHead.textContent = state.preview
      ? `Downloads — preview size (${w} × ${h} px); choose “Full size” for full-size files`
      : `Downloads — full size (${w} × ${h} px)`;
    downloads.replaceChildren(...job.outputs.map((out) => el("li", {}, el("a", { class: "button secondary", href: out.url, download: out.name }, `${out.name} (${(out.size / 1024).toFixed(1)} KiB)`))));
    if (viewer) {
      const models = job.outputs.filter((o) => o.name.endsWith(".glb"))
        .sort((a, b) => MODEL_ORDER.indexOf(a.name) - MODEL_ORDER.indexOf(b.name));
      viewer.show(models.map((o) => ({ name: o.name, url: o.url })));
    }
    if (state.preview) {
      state.lastPreview = { px: w * h, ms: (job.timings || []).reduce((a, t) => a + t.ms, 0) };
      sizeLabel();
    }
    say(status, `Done: ${state.preview ? "preview" : "full size"}, ${w} × ${h} px.`);
    stale(false);
    panel.dataset.status = job.status;
  }

  // Orbit: dragging the render turns the camera (azimuth by x, elevation by y); arrow keys too.
  // The camera fields of the form switch to "orbit" and show the new values.
  function turn(dAz, dEl) {
    const cam = widgets.camera;
    const base = {
      azimuth_deg: cameraSchema.azimuth_deg.default,
      elevation_deg: cameraSchema.elevation_deg.default,
      ...(state.resolvedCamera || {}),
      ...cam.orbitValues(),
    };
    cam.setOrbit({
      azimuth_deg: ((base.azimuth_deg + dAz) % 360 + 360) % 360,
      elevation_deg: Math.max(-89, Math.min(89, base.elevation_deg + dEl)),
    });
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

  const input = inputBox(cfg.input, cfg.example, (asset) => {
    if (!state.asset || state.asset.id !== asset.id) {
      state.size = null;
      state.far = null;
    }
    state.asset = asset;
    panel.dataset.asset = asset.id;
    schedule();
  }, error);
  // The orthophoto (snow-terrain): uploaded once like the input, sent as `ortho_asset`.
  let orthoBox = null;
  if (cfg.ortho) {
    const id = `ortho-${name}`;
    const none = " none: the rock colour setting is used";
    const info = el("span", { class: "asset", "aria-live": "polite" }, none);
    const clear = el("button", {
      type: "button", class: "secondary", hidden: true,
      onclick: () => { state.ortho = null; file.value = ""; info.textContent = none; clear.hidden = true; schedule(); },
    }, "Remove");
    const file = el("input", {
      type: "file", id, class: "file", accept: ".tif,.tiff,.png,.jpg,.jpeg,image/png,image/jpeg,image/tiff",
      onchange: async (e) => {
        const f = e.target.files[0];
        if (!f) return;
        info.textContent = ` uploading ${f.name}…`;
        try {
          state.ortho = await uploadAsset(f, f.name);
          info.textContent = ` ${f.name} (${(state.ortho.size / 1024).toFixed(1)} KiB)`;
          panel.dataset.ortho = state.ortho.id;
          clear.hidden = false;
          schedule();
        } catch (err) {
          info.textContent = "";
          error(err.message, err.detail);
        }
      },
    });
    orthoBox = el("details", { class: "ortho" }, el("summary", {}, "Colour the rock from an aerial photo (optional)"),
      el("div", { class: "field" },
        el("label", { for: id }, "Orthophoto (GeoTIFF, PNG, JPEG) covering the DEM:"), el("br"),
        file, info, " ", clear));
  }
  panel.append(
    el("h2", {}, document.getElementById(panel.getAttribute("aria-labelledby")).textContent),
    el("div", { class: "layout" },
      el("div", { class: "area-in" }, input, presetBox, sizeBox, orthoBox, sweep ? sweep.box : null),
      el("div", { class: "area-out" },
        el("div", { class: "run-line" }, bar, cancel), status, staleNote,
        closeUp ? el("div", { class: "toolbar" }, closeUp) : null,
        el("div", { class: "result" }, empty, views), viewer ? viewer.node : null, dlHead, downloads),
      el("div", { class: "area-more" }, el("h3", { class: "form-head" }, "Settings"), form)));
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
  initMap(document.getElementById("panel-map"), spec);
  document.body.dataset.ready = "true";
}

main().catch((e) => {
  const f = document.getElementById("fatal");
  f.hidden = false;
  f.textContent = `The page could not start: ${e.message}`;
});
