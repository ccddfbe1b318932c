// The studio page: one tab per pipeline. Each pipeline tab uploads its input once
// (POST /v1/assets), builds its parameter form from openapi.yaml's schema, submits JSON naming the
// asset on every (debounced) change, follows the job's server-sent events into a progress bar and
// shows the images and download links of the finished job. The cloud editor lives in cloud.js.

import { parseYaml } from "./yaml.js";
import { initEditor } from "./cloud.js";
import { buildForm, resolve } from "./form.js";

/** Per pipeline: the schema of its params, the multipart part name (for labels), the example. */
const PIPELINES = {
  "snow-terrain": {
    schema: "SnowTerrainParams",
    input: "DEM (GeoTIFF, .asc, .hgt, 16-bit PNG, .npy)",
    example: "dem.asc",
    images: [["render.png", "render"], ["descriptor.png", "snow-cover map (white = snow)"], ["sweep.png", "parameter sweep"]],
    // An optional orthophoto whose colours replace rock_color (`ortho_asset`).
    ortho: true,
  },
  "snow-cover": {
    schema: "SnowCoverParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
    images: [["render.png", "render"], ["timelapse.png", "time-lapse"]],
  },
  cloud: {
    schema: "CloudParams",
    input: "density volume (.npy, NRRD, .vdb)",
    example: "volume.npy",
    images: [["render.png", "render"], ["direct.png", "direct light (single scattering)"], ["multiple.png", "multiple scattering"], ["ambient.png", "ambient light"]],
  },
  dust: {
    schema: "DustParams",
    input: "mesh (glTF/GLB, OBJ, STL, PLY)",
    example: "mesh.obj",
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

/** Reads a problem+json (or any) error response into a message. */
export async function problem(resp) {
  return (await problemOf(resp)).message;
}

/** A problem+json response as { message, field }: "Invalid parameter: wind: missing field …". */
export async function problemOf(resp) {
  try {
    const p = await resp.json();
    const message = p.title && p.detail ? `${p.title} (${resp.status}): ${p.detail}` : p.detail || p.title || `HTTP ${resp.status}`;
    return { message, field: p.field };
  } catch {
    return { message: `HTTP ${resp.status}` };
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

/** A pipeline tab: input, form, preview with orbit, progress, outputs. */
function pipelineTab(panel, name, spec) {
  const cfg = PIPELINES[name];
  const schema = spec.components.schemas[cfg.schema];
  const cameraSchema = resolve(spec, spec.components.schemas.Camera).properties;
  const state = { asset: null, timer: 0, follow: null, seq: 0, resolvedCamera: null, size: null, closeUp: false, far: null, ortho: null };
  const status = el("p", { class: "status", role: "status", "aria-live": "polite", id: `status-${name}` });
  const bar = el("progress", { max: 1, value: 0, "aria-label": `${name} progress` });
  // After a refused or invalid change the last results stay, marked out of date (dimmed, a
  // label, and the images described by the label and the error) until the next success.
  const staleNote = el("p", { class: "stale-note", id: `stale-${name}`, hidden: true },
    "Out of date: the results below are the last successful ones, not of the current parameters (see the message above).");
  const views = el("div", { class: "views" });
  const downloads = el("ul", { class: "downloads", "aria-label": "Downloads" });
  const quick = el("input", { type: "checkbox", id: `quick-${name}`, checked: true });
  const error = (m) => { status.textContent = m; status.classList.add("error"); };
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
  const refuse = (m) => { error(m); stale(true); };

  const { form, values, widgets, mark } = buildForm(spec, schema, name, () => schedule());
  quick.addEventListener("change", () => schedule());

  // A parameter sweep (snow-terrain's `sweep`): one numeric parameter over a list of values,
  // rendered into sweep.png beside the render and the snow-cover map.
  let sweep = null;
  const sweepProp = schema.properties.sweep;
  if (sweepProp) {
    const vp = sweepProp.properties.values;
    const param = el("select", { id: `sweep-${name}-param` },
      el("option", { value: "" }, "(no sweep)"),
      sweepProp.properties.param.enum.map((v) => el("option", { value: v }, v)));
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
      box: el("fieldset", { class: "field sweep" }, el("legend", {}, "Parameter sweep"),
        el("label", { for: param.id }, "param"), param,
        el("label", { for: vals.id }, `values (${vp.minItems}–${vp.maxItems}, comma-separated)`), vals,
        el("span", { class: "desc", id: `sweep-${name}-d` }, sweepProp.description)),
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
    if (quick.checked) {
      const w = p.width ?? schema.properties.width.default;
      const h = p.height ?? schema.properties.height.default;
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

  async function run() {
    clearTimeout(state.timer);
    if (!state.asset) return;
    const seq = ++state.seq;
    if (state.follow) state.follow.close();
    status.classList.remove("error");
    const { params: p, bad } = params();
    if (bad) return refuse(`Not sent: fix ${bad.join(", ")} (a number out of its range, or an incomplete value).`);
    mark(null);
    status.textContent = "Submitting…";
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
      return refuse(pr.message);
    }
    const job = await resp.json();
    panel.dataset.job = job.id;
    delete panel.dataset.status;
    state.follow = followJob(job, (f, stage) => {
      if (seq !== state.seq) return;
      bar.value = f;
      panel.dataset.progress = String(f);
      status.textContent = `${stage} — ${Math.round(f * 100)} %`;
    });
    let done;
    try {
      done = await state.follow.job;
    } catch (e) {
      return refuse(e.message);
    }
    if (seq !== state.seq) return;
    await show(done, p);
  }

  async function show(job, sent) {
    if (job.status !== "succeeded") {
      panel.dataset.status = job.status;
      return refuse(job.error ? `${job.error.title}: ${job.error.detail}` : `job ${job.status}`);
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
    status.textContent = `Done (job ${job.id.slice(0, 12)}…).`;
    views.replaceChildren();
    downloads.replaceChildren();
    for (const out of job.outputs) {
      downloads.append(el("li", {}, el("a", { class: "button secondary", href: out.url, download: out.name }, `${out.name} (${(out.size / 1024).toFixed(1)} KiB)`)));
    }
    if (close && state.far) {
      views.append(el("figure", { class: "far" }, el("img", { src: state.far, alt: "far view (the last render without the close-up)", "data-output": "far" }), el("figcaption", {}, "far view")));
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
      views.append(el("figure", { class: main ? "main" : img === "sweep.png" ? "wide" : undefined }, image,
        el("figcaption", {}, cap, main ? null : [" · ", el("a", { href: out.url, target: "_blank", rel: "noopener" }, "full size")])));
    }
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
    const info = el("span", { class: "asset", "aria-live": "polite" }, " none (rock_color)");
    const clear = el("button", {
      type: "button", class: "secondary", hidden: true,
      onclick: () => { state.ortho = null; file.value = ""; info.textContent = " none (rock_color)"; clear.hidden = true; schedule(); },
    }, "Remove");
    const file = el("input", {
      type: "file", id, class: "file", accept: ".tif,.tiff,.png,.jpg,.jpeg,image/png,image/jpeg,image/tiff",
      onchange: async (e) => {
        const f = e.target.files[0];
        if (!f) return;
        info.textContent = ` uploading ${f.name}…`;
        try {
          state.ortho = await uploadAsset(f, f.name);
          info.textContent = ` ${f.name} (${state.ortho.size} bytes)`;
          panel.dataset.ortho = state.ortho.id;
          clear.hidden = false;
          schedule();
        } catch (err) {
          info.textContent = "";
          error(err.message);
        }
      },
    });
    orthoBox = el("div", { class: "field" },
      el("label", { for: id }, "Orthophoto for the rock colour (GeoTIFF, PNG, JPEG; optional):"), el("br"),
      file, info, " ", clear);
  }
  panel.append(
    el("h2", {}, document.getElementById(panel.getAttribute("aria-labelledby")).textContent),
    el("div", { class: "layout" },
      el("div", { class: "area-in" }, input, orthoBox,
        el("div", { class: "field check" }, quick, " ", el("label", { for: `quick-${name}` }, `Quick preview (at most ${PREVIEW_MAX} px)`)),
        sweep ? sweep.box : null),
      el("div", { class: "area-out" }, bar, status, staleNote, closeUp ? el("div", { class: "toolbar" }, closeUp) : null, views, downloads),
      el("div", { class: "area-more" }, form)));
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
