// The cloud editor (SPEC §3, "Editing"): a scene kept on the server, edited on the image of a
// view with the paper's three modes — a sun-colour brush (§3.1), an ambient brush (§3.2) and a
// shadow drag (§3.3) — plus camera orbit and a version history whose undo/redo selects versions
// (versions are immutable on the server; undo is rendering or editing an older one). Every tool
// works from the keyboard too: a crosshair on the focused image (keys in the help text below it).

import { $, el, problem, say, followJob, inputBox } from "./app.js";

/** The size of the edited view, pixels (edits are sent with this view). */
const VIEW_W = 400;
const VIEW_H = 300;
/** Brush radius in image pixels. */
const BRUSH = 4;
/** At most this many painted pixels per stroke. */
const MAX_PIXELS = 4000;
/** Keyboard cursor steps, image pixels (with Shift: the big one). */
const STEP = 4;
const BIG_STEP = 20;
/** The tools in the order of their number keys. */
const TOOLS = ["sun-color", "ambient", "sun-direction", "orbit"];
/** The editor image's keys (aria-keyshortcuts). */
const KEYS = [
  "1", "2", "3", "4",
  "ArrowLeft", "ArrowRight", "ArrowUp", "ArrowDown",
  "Shift+ArrowLeft", "Shift+ArrowRight", "Shift+ArrowUp", "Shift+ArrowDown",
  "Home", "Space", "Enter", "C", "Escape",
];

/** Version kinds in words. */
const KINDS = { upload: "upload", "sun-color": "sun colour", ambient: "ambient", "sun-direction": "shadow drag", set: "settings" };
/** The state's fields in words, in the table's order (others follow under their own names). */
const STATE_LABELS = [
  ["kappa", "Density κ"],
  ["sun_direction", "Sun"],
  ["sun_color", "Sun colour"],
  ["ambient", "Ambient colour"],
  ["ambient_scale", "Ambient strength"],
  ["scattering", "Light bounces"],
  ["albedo", "Albedo"],
  ["anisotropy", "Forward scattering"],
  ["background", "Background"],
  ["step", "Ray step"],
];

export function initEditor(panel, spec) {
  const cam = spec.components.schemas.Camera.properties;
  const st = {
    scene: null,
    current: null,
    redo: [],
    camera: { azimuth_deg: cam.azimuth_deg.default, elevation_deg: 12 },
    tool: "sun-color",
    busy: false,
    /** The last render seen of each version (the upload has no render_url of its own). */
    thumbs: {},
  };
  const status = el("p", { class: "status", role: "status", "aria-live": "polite" });
  const bar = el("progress", { max: 1, value: 0, "aria-label": "cloud editor progress", hidden: true });
  // No image before a scene (no broken-image icon): the stage shows what to do instead.
  const img = el("img", { alt: "The current version of the cloud", width: VIEW_W, height: VIEW_H, id: "editor-image", hidden: true });
  const emptyStage = el("div", { class: "empty-state stage-empty", id: "editor-empty" },
    el("p", {}, el("strong", {}, "No cloud yet."), " Drop a density volume (.npy, NRRD, .vdb) in the box, or press “Try the example”. Its render appears here; then paint on it or drag a shadow."));
  const canvas = el("canvas", {
    width: VIEW_W, height: VIEW_H, tabindex: 0, id: "editor-canvas",
    "aria-label": "Cloud image: paint or drag on it with the selected tool, with the pointer or the keyboard",
    "aria-describedby": "editor-keys",
    "aria-keyshortcuts": KEYS.join(" "),
  });
  // The keyboard cursor: a crosshair (with the brush's size) over the image, shown while the
  // image has focus.
  const cursor = el("div", { class: "kbd-cursor", "aria-hidden": "true" });
  const help = el("p", { class: "keys", id: "editor-keys" },
    "Keyboard, with the image focused: ", el("kbd", {}, "1"), "–", el("kbd", {}, "4"), " pick the tool (sun-colour brush, ambient brush, shadow drag, orbit); ",
    "the arrow keys move the crosshair (", el("kbd", {}, "Shift"), " for bigger steps; ", el("kbd", {}, "Home"), " centres it), or orbit the camera with the orbit tool; ",
    "brushes: ", el("kbd", {}, "Space"), " or ", el("kbd", {}, "Enter"), " paints at the crosshair (hold it while moving to paint a line), ",
    el("kbd", {}, "C"), " applies the stroke; shadow drag: ", el("kbd", {}, "Space"), " or ", el("kbd", {}, "Enter"), " marks the shadowed spot, again marks where its shadow should be; ",
    el("kbd", {}, "Esc"), " discards; ", el("kbd", {}, "Ctrl+Z"), " / ", el("kbd", {}, "Ctrl+Shift+Z"), " undo and redo.");
  const ctx = canvas.getContext("2d");
  const versions = el("ul", { class: "versions", "aria-label": "Versions" }, el("li", { class: "hint" }, "No versions yet: the upload becomes version 1, every edit a new one."));
  const count = el("span", { id: "version-count" }, "0");
  const stateBox = el("pre", { class: "state", "aria-label": "Renderer state of the current version (JSON)" });
  const stateTable = el("table", { class: "state-table", id: "state-table" },
    el("caption", {}, "The current version's renderer state"),
    el("tbody", {}, el("tr", {}, el("td", { colspan: 2, class: "hint" }, "No scene yet: the state of the shown version appears here."))));
  const stateRaw = el("details", { class: "state-raw", hidden: true }, el("summary", {}, "As JSON"), stateBox);
  // Before/after: two versions' renders stacked, the "after" one clipped at the slider.
  const cmpA = el("select", { id: "compare-before", "aria-label": "Before: version" });
  const cmpB = el("select", { id: "compare-after", "aria-label": "After: version" });
  const cmpImgA = el("img", { alt: "Before", class: "cmp-before", width: VIEW_W, height: VIEW_H });
  const cmpImgB = el("img", { alt: "After", class: "cmp-after", width: VIEW_W, height: VIEW_H });
  const cmpSlider = el("input", { type: "range", id: "compare-slider", min: 0, max: 100, value: 50, "aria-label": "Before/after divider, % from the left" });
  const cmpBox = el("section", { class: "compare", id: "compare", hidden: true, "aria-labelledby": "compare-h" },
    el("h3", { id: "compare-h" }, "Compare two versions"),
    el("div", { class: "toolbar" }, el("label", { for: cmpA.id }, "Before"), cmpA, el("label", { for: cmpB.id }, "After"), cmpB),
    el("div", { class: "cmp-stage" }, cmpImgA, cmpImgB, el("div", { class: "cmp-line", "aria-hidden": "true" })),
    cmpSlider,
    el("p", { class: "hint" }, "Left of the line: before; right: after. Each version as rendered when it was made."));
  const ambScale = el("input", { type: "number", id: "ambient-scale", min: 0, max: 100, step: "any", value: 1, "aria-describedby": "ambient-scale-d" });
  const sunColor = el("input", { type: "color", id: "sun-color", value: "#ffa060" });
  const ambColor = el("input", { type: "color", id: "ambient-color", value: "#4060ff" });
  const undoBtn = el("button", { type: "button", class: "secondary", id: "undo", onclick: undo, "aria-keyshortcuts": "Control+Z", title: "Undo (Ctrl+Z)" }, "Undo");
  const redoBtn = el("button", { type: "button", class: "secondary", id: "redo", onclick: redo, "aria-keyshortcuts": "Control+Shift+Z Control+Y", title: "Redo (Ctrl+Shift+Z or Ctrl+Y)" }, "Redo");
  // Direct settings (the `set` edit): κ, the sun's azimuth and elevation, the sun colour. They
  // show the current version's values and apply as a new version.
  const kappaIn = el("input", { type: "number", id: "set-kappa", min: 0, max: 10000, step: "any", "aria-describedby": "set-kappa-how" });
  const kappaHow = el("span", { id: "set-kappa-how", class: "hint" });
  const azIn = el("input", { type: "number", id: "set-sun-az", min: 0, max: 360, step: 1 });
  const elIn = el("input", { type: "number", id: "set-sun-el", min: -90, max: 90, step: 1 });
  const sunIn = el("input", { type: "color", id: "set-sun-color", value: "#fff8f0" });
  // The scattering mode and albedo (issue 24): multiple scattering brightens and softens thick
  // clouds; the paint and drag tools work in both modes.
  const modeIn = el("select", { id: "set-scattering" },
    el("option", { value: "single" }, "single (the paper)"),
    el("option", { value: "multiple" }, "multiple"));
  const albedoIn = el("input", { type: "number", id: "set-albedo", min: 0, max: 1, step: 0.01, value: 1 });
  const applyBtn = el("button", { type: "button", id: "set-apply", onclick: applySettings, disabled: true }, "Apply settings");
  const settingInputs = [kappaIn, azIn, elIn, sunIn, modeIn, albedoIn, applyBtn];
  for (const i of settingInputs) i.disabled = true;
  undoBtn.disabled = true;
  redoBtn.disabled = true;
  const error = (m, detail) => say(status, m instanceof Error ? m.message : m, { error: true, detail: detail || (m && m.detail) || "" });
  const note = (m) => say(status, m);

  const tool = (value, label, extra) => {
    const id = `tool-${value}`;
    const r = el("input", { type: "radio", name: "tool", id, value, checked: value === st.tool, onchange: () => setTool(value) });
    return el("span", {}, r, " ", el("label", { for: id }, label), extra ? [" ", extra] : []);
  };

  const view = () => ({ width: VIEW_W, height: VIEW_H, camera: { ...st.camera } });
  const version = (n) => st.scene && st.scene.versions.find((v) => v.version === n);
  const imageOf = (v) => v && (v.render_url || st.thumbs[v.version]);

  async function refresh() {
    const r = await fetch(st.scene.url);
    if (!r.ok) return error(await problem(r));
    st.scene = await r.json();
    versions.replaceChildren(...st.scene.versions.map((v) => el("li", {},
      el("button", {
        type: "button", "aria-current": v.version === st.current ? "true" : undefined,
        disabled: v.status !== "ready", onclick: () => select(v.version, true),
      }, imageOf(v) ? el("img", { src: imageOf(v), alt: "", width: 64, height: 48, class: "thumb", loading: "lazy" }) : el("span", { class: "thumb" }),
      el("span", {}, `v${v.version} · ${KINDS[v.kind] || v.kind}${v.parent ? ` (from v${v.parent})` : ""}`, v.status === "ready" ? null : ` · ${v.status}`)))));
    compareOptions();
    count.textContent = String(st.scene.versions.length);
    panel.dataset.versions = String(st.scene.versions.length);
    panel.dataset.current = String(st.current);
    const cur = version(st.current);
    stateBox.textContent = cur && cur.state ? JSON.stringify(cur.state, null, 1) : "";
    stateRaw.hidden = !(cur && cur.state);
    if (cur && cur.state) {
      showSettings(cur.state);
      stateTable.tBodies[0].replaceChildren(...stateRows(cur.state));
    }
    for (const i of settingInputs) i.disabled = false;
    undoBtn.disabled = !(cur && cur.parent);
    redoBtn.disabled = st.redo.length === 0;
  }

  // Linear ↔ sRGB hex for the sun colour (the state holds linear RGB; values over 1 are shown
  // clipped).
  const toSrgb = (c) => { const v = Math.max(0, Math.min(1, c)); return v <= 0.0031308 ? 12.92 * v : 1.055 * v ** (1 / 2.4) - 0.055; };
  const hex = (rgb) => "#" + rgb.map((c) => Math.round(toSrgb(c) * 255).toString(16).padStart(2, "0")).join("");
  function showSettings(state) {
    if (typeof state.kappa === "number") kappaIn.value = String(Number(state.kappa.toPrecision(4)));
    kappaHow.textContent = state.kappa_auto ? " (chosen from the volume: median optical depth " + state.kappa_auto.optical_depth + ")" : " (given)";
    const d = state.sun_direction;
    if (Array.isArray(d)) {
      const elv = Math.asin(Math.max(-1, Math.min(1, d[1]))) * 180 / Math.PI;
      const az = ((Math.atan2(d[0], -d[2]) * 180 / Math.PI) + 360) % 360;
      azIn.value = azIn.dataset.shown = String(Math.round(az));
      elIn.value = elIn.dataset.shown = String(Math.round(elv));
    }
    if (Array.isArray(state.sun_color)) sunIn.value = sunIn.dataset.shown = hex(state.sun_color);
    modeIn.value = modeIn.dataset.shown = state.scattering || "single";
    const a = typeof state.albedo === "number" ? state.albedo : 1;
    albedoIn.value = albedoIn.dataset.shown = String(a);
  }
  function applySettings() {
    if (!st.scene || st.busy) return;
    const cur = version(st.current);
    const body = {};
    const k = Number(kappaIn.value);
    if (kappaIn.value !== "" && (!cur || !cur.state || Math.abs(k - cur.state.kappa) > 1e-9 * Math.max(1, Math.abs(k)))) body.kappa = k;
    const before = { az: azIn.dataset.shown, el: elIn.dataset.shown, sun: sunIn.dataset.shown };
    if (azIn.value !== before.az || elIn.value !== before.el) {
      body.sun_azimuth_deg = Number(azIn.value);
      body.sun_elevation_deg = Number(elIn.value);
    }
    if (sunIn.value !== before.sun) body.sun_color = sunIn.value;
    if (modeIn.value !== modeIn.dataset.shown) body.scattering = modeIn.value;
    if (albedoIn.value !== albedoIn.dataset.shown && albedoIn.value !== "") body.albedo = Number(albedoIn.value);
    if (!Object.keys(body).length) return note("Nothing to apply: change κ, the sun, its colour, the scattering or the albedo first.");
    edit("set", body);
  }

  async function job(resp) {
    const j = await resp.json();
    const f = followJob(j, (p, stage) => {
      bar.value = p;
      note(`${stage} — ${Math.round(p * 100)} %`);
    });
    return f.job;
  }

  /** Shows a render once it has loaded (the old one stays until then: no flash, no jump). */
  async function showImage(url) {
    const next = new Image();
    next.src = url;
    await next.decode().catch(() => {});
    img.src = url;
    img.hidden = false;
    emptyStage.hidden = true;
    panel.dataset.image = url;
    ctx.clearRect(0, 0, VIEW_W, VIEW_H);
  }

  /** The state as readable rows: names in words, angles for the sun, swatches for colours. */
  function stateRows(state) {
    const num = (x) => (typeof x === "number" ? String(Number(x.toPrecision(4))) : typeof x === "string" ? x : x === null ? "none" : JSON.stringify(x));
    const swatch = (rgb) => el("span", {}, el("span", { class: "swatch", style: `background:${hex(rgb)}`, "aria-hidden": "true" }), ` ${hex(rgb)} (linear ${rgb.map(num).join(", ")})`);
    const rows = [];
    const row = (k, label, value) => rows.push(el("tr", { "data-key": k }, el("th", { scope: "row" }, label), el("td", {}, value)));
    const seen = new Set();
    for (const [k, label] of STATE_LABELS) {
      if (!(k in state)) continue;
      seen.add(k);
      const v = state[k];
      if (k === "sun_direction" && Array.isArray(v)) {
        const elv = Math.asin(Math.max(-1, Math.min(1, v[1]))) * 180 / Math.PI;
        const az = ((Math.atan2(v[0], -v[2]) * 180 / Math.PI) + 360) % 360;
        row(k, label, `from ${Math.round(az)}° (compass), ${Math.round(elv)}° above the horizon`);
      } else if (k === "kappa") {
        row(k, label, `${num(v)}${state.kappa_auto ? " (chosen from the volume)" : " (given)"}`);
      } else if (Array.isArray(v) && v.length === 3 && v.every((x) => typeof x === "number") && /color|ambient/.test(k)) {
        row(k, label, swatch(v));
      } else row(k, label, v !== null && typeof v === "object" ? JSON.stringify(v) : num(v));
    }
    for (const [k, v] of Object.entries(state)) {
      if (seen.has(k) || k === "kappa_auto") continue;
      row(k, k.replace(/_/g, " "), v !== null && typeof v === "object" ? JSON.stringify(v) : num(v));
    }
    return rows;
  }

  function compareOptions() {
    const ready = st.scene.versions.filter((v) => v.status === "ready" && imageOf(v));
    cmpBox.hidden = ready.length < 2;
    if (ready.length < 2) return;
    const cur = version(st.current);
    const keepA = cmpA.dataset.user && ready.some((v) => String(v.version) === cmpA.value) ? cmpA.value : String((cur && cur.parent) || ready[ready.length - 2].version);
    const keepB = cmpB.dataset.user && ready.some((v) => String(v.version) === cmpB.value) ? cmpB.value : String(st.current ?? ready[ready.length - 1].version);
    const opts = (keep) => ready.map((v) => el("option", { value: v.version, selected: String(v.version) === keep }, `v${v.version} · ${KINDS[v.kind] || v.kind}`));
    cmpA.replaceChildren(...opts(keepA));
    cmpB.replaceChildren(...opts(keepB));
    compareShow();
  }
  function compareShow() {
    const a = version(Number(cmpA.value));
    const b = version(Number(cmpB.value));
    if (imageOf(a) && cmpImgA.getAttribute("src") !== imageOf(a)) cmpImgA.src = imageOf(a);
    if (imageOf(b) && cmpImgB.getAttribute("src") !== imageOf(b)) cmpImgB.src = imageOf(b);
    const x = Number(cmpSlider.value);
    cmpImgB.style.clipPath = `inset(0 0 0 ${x}%)`;
    cmpBox.style.setProperty("--split", `${x}%`);
  }
  cmpA.addEventListener("change", () => { cmpA.dataset.user = "1"; compareShow(); });
  cmpB.addEventListener("change", () => { cmpB.dataset.user = "1"; compareShow(); });
  cmpSlider.addEventListener("input", compareShow);

  async function render() {
    st.busy = true;
    panel.dataset.busy = "true";
    try {
      const r = await fetch(`${st.scene.url}/renders`, {
        method: "POST",
        headers: { "content-type": "application/json" },
        body: JSON.stringify({ version: st.current, ...view() }),
      });
      if (!r.ok) return error(await problem(r));
      const done = await job(r);
      if (done.status !== "succeeded") return error(done.error ? `The render failed: ${done.error.detail}` : `The render ended: ${done.status}`);
      const out = done.outputs.find((o) => o.name === "render.png");
      st.thumbs[st.current] ??= out.url;
      await showImage(out.url);
      note(`Showing v${st.current}.`);
    } finally {
      st.busy = false;
      await refresh();
      panel.dataset.busy = "false";
    }
  }

  async function select(n, clearRedo) {
    if (clearRedo) st.redo = [];
    st.current = n;
    // Busy from here on, so that a second undo/redo waits for this one's image.
    st.busy = true;
    panel.dataset.busy = "true";
    await refresh();
    await render();
  }

  async function undo() {
    const cur = version(st.current);
    if (!cur || !cur.parent || st.busy) return;
    st.redo.push(st.current);
    await select(cur.parent, false);
  }

  async function redo() {
    if (!st.redo.length || st.busy) return;
    await select(st.redo.pop(), false);
  }

  async function edit(kind, body) {
    st.busy = true;
    panel.dataset.busy = "true";
    try {
      note(`Editing (${kind})…`);
      const r = await fetch(`${st.scene.url}/edits/${kind}`, {
        method: "POST",
        headers: { "content-type": "application/json" },
        body: JSON.stringify({ base_version: st.current, ...view(), ...body }),
      });
      if (!r.ok) return error(await problem(r));
      const v = await r.json();
      const jr = await fetch(v.job_url);
      if (jr.ok) await job(jr);
      const r2 = await fetch(st.scene.url);
      st.scene = await r2.json();
      const nv = version(v.version);
      if (!nv || nv.status !== "ready") {
        error(nv && nv.error ? `The edit failed: ${nv.error.detail}` : "The edit failed.", nv && nv.error ? nv.error.title : "");
        ctx.clearRect(0, 0, VIEW_W, VIEW_H);
        return;
      }
      st.current = nv.version;
      st.redo = [];
      await showImage(nv.render_url);
      note(`v${nv.version} (${kind}) is ready.`);
    } finally {
      st.busy = false;
      await refresh();
      panel.dataset.busy = "false";
    }
  }

  // Input on the overlay, in image pixels. A pointer drag and the keyboard build the same
  // `drag` (start, last point, painted pixels) and end it through the same commit, so both
  // send the same requests.
  const at = (e) => {
    const b = canvas.getBoundingClientRect();
    return [
      Math.max(0, Math.min(VIEW_W - 1, ((e.clientX - b.left) / b.width) * VIEW_W)),
      Math.max(0, Math.min(VIEW_H - 1, ((e.clientY - b.top) / b.height) * VIEW_H)),
    ];
  };
  let drag = null;
  const brush = () => st.tool === "sun-color" || st.tool === "ambient";
  const paint = (p) => {
    const color = st.tool === "sun-color" ? sunColor.value : ambColor.value;
    ctx.fillStyle = color + "aa";
    const steps = drag.last ? Math.ceil(Math.hypot(p[0] - drag.last[0], p[1] - drag.last[1])) + 1 : 1;
    for (let s = 0; s < steps; s++) {
      const t = steps === 1 ? 1 : s / (steps - 1);
      const q = drag.last ? [drag.last[0] + (p[0] - drag.last[0]) * t, drag.last[1] + (p[1] - drag.last[1]) * t] : p;
      ctx.beginPath();
      ctx.arc(q[0], q[1], BRUSH, 0, 2 * Math.PI);
      ctx.fill();
      for (let dy = -BRUSH; dy <= BRUSH; dy++) {
        for (let dx = -BRUSH; dx <= BRUSH; dx++) {
          if (dx * dx + dy * dy > BRUSH * BRUSH) continue;
          const x = Math.round(q[0]) + dx;
          const y = Math.round(q[1]) + dy;
          if (x < 0 || y < 0 || x >= VIEW_W || y >= VIEW_H || drag.pixels.size >= MAX_PIXELS) continue;
          drag.pixels.add(y * VIEW_W + x);
        }
      }
    }
    drag.last = p;
  };
  const shadowLine = (from, to) => {
    ctx.clearRect(0, 0, VIEW_W, VIEW_H);
    ctx.strokeStyle = "#ff3030";
    ctx.fillStyle = "#ff3030";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(from[0], from[1], 3, 0, 2 * Math.PI);
    ctx.fill();
    ctx.beginPath();
    ctx.moveTo(from[0], from[1]);
    ctx.lineTo(to[0], to[1]);
    ctx.stroke();
  };
  /** Ends a drag at `p`: sends the stroke or the shadow drag (false if there was nothing to send). */
  const commit = (d, p) => {
    if (brush()) {
      if (!d.pixels.size) return false;
      const pixels = [...d.pixels].map((i) => [i % VIEW_W, Math.floor(i / VIEW_W)]);
      const color = st.tool === "sun-color" ? sunColor.value : ambColor.value;
      const extra = st.tool === "ambient" && ambScale.value !== "" && Number(ambScale.value) !== 1 ? { ambient_scale: Number(ambScale.value) } : {};
      edit(st.tool, { strokes: [{ color, pixels }], ...extra });
      return true;
    }
    if (st.tool === "sun-direction") {
      if (Math.hypot(p[0] - d.start[0], p[1] - d.start[1]) < 2) return false;
      edit("sun-direction", { from: d.start.map(Math.round), to: p.map(Math.round) });
      return true;
    }
    return false;
  };
  const discard = (why) => {
    if (!drag) return;
    drag = null;
    ctx.clearRect(0, 0, VIEW_W, VIEW_H);
    if (why) note(why);
  };
  function setTool(value) {
    if (drag && drag.keys) discard(`Discarded the unfinished ${drag.tool === "sun-direction" ? "shadow drag" : "stroke"}.`);
    st.tool = value;
    const r = $(`#tool-${value}`, panel);
    if (r) r.checked = true;
    placeCursor();
  }

  canvas.addEventListener("pointerdown", (e) => {
    if (!st.scene || st.busy) return;
    e.preventDefault();
    canvas.setPointerCapture(e.pointerId);
    discard();
    drag = { start: at(e), last: null, pixels: new Set(), client: [e.clientX, e.clientY], tool: st.tool };
    kbd.pos = drag.start.map(Math.round);
    placeCursor();
    if (brush()) paint(drag.start);
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag || drag.keys) return;
    const p = at(e);
    if (brush()) paint(p);
    else if (st.tool === "sun-direction") shadowLine(drag.start, p);
  });
  canvas.addEventListener("pointerup", (e) => {
    if (!drag || drag.keys) return;
    const d = drag;
    drag = null;
    const p = at(e);
    kbd.pos = p.map(Math.round);
    placeCursor();
    if (st.tool === "orbit") {
      turn(-(e.clientX - d.client[0]) * 0.5, (e.clientY - d.client[1]) * 0.3);
      render();
    } else commit(d, p);
  });

  // The keyboard: a crosshair moved by the arrow keys; Space/Enter paint (held: along the
  // way) or mark the shadow drag's ends; C applies a stroke; Escape discards.
  const kbd = { pos: [VIEW_W / 2, VIEW_H / 2], pen: false };
  function placeCursor() {
    cursor.style.left = `${(kbd.pos[0] / VIEW_W) * 100}%`;
    cursor.style.top = `${(kbd.pos[1] / VIEW_H) * 100}%`;
    cursor.style.width = cursor.style.height = `${((2 * BRUSH + 1) / VIEW_W) * 100}%`;
    cursor.classList.toggle("brush", brush());
  }
  placeCursor();
  const where = () => `${kbd.pos[0]}, ${kbd.pos[1]}`;
  const keyDrag = () => {
    if (!drag) drag = { start: [...kbd.pos], last: null, pixels: new Set(), keys: true, tool: st.tool };
    return drag;
  };
  canvas.addEventListener("keydown", (e) => {
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    const arrow = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] }[e.key];
    const key = e.key === " " ? "Space" : e.key.length === 1 ? e.key.toUpperCase() : e.key;
    const n = /^[1-4]$/.test(key) ? Number(key) - 1 : -1;
    if (!arrow && !["Home", "Space", "Enter", "C", "Escape"].includes(key) && n < 0) return;
    e.preventDefault();
    if (n >= 0) {
      setTool(TOOLS[n]);
      return note(`Tool: ${$(`label[for=tool-${TOOLS[n]}]`, panel).textContent}.`);
    }
    if (!st.scene) return note("Create a scene first.");
    if (key === "Escape") {
      kbd.pen = false;
      return drag ? discard(`Discarded the unfinished ${drag.tool === "sun-direction" ? "shadow drag" : "stroke"}.`) : undefined;
    }
    if (st.tool === "orbit") {
      if (!arrow || st.busy) return;
      turn(arrow[0] * 10, -arrow[1] * 5);
      note(`Orbiting to azimuth ${st.camera.azimuth_deg}°, elevation ${st.camera.elevation_deg}°…`);
      return render();
    }
    if (arrow || key === "Home") {
      const k = e.shiftKey ? BIG_STEP : STEP;
      kbd.pos = key === "Home" ? [VIEW_W / 2, VIEW_H / 2] : [
        Math.max(0, Math.min(VIEW_W - 1, kbd.pos[0] + arrow[0] * k)),
        Math.max(0, Math.min(VIEW_H - 1, kbd.pos[1] + arrow[1] * k)),
      ];
      placeCursor();
      if (kbd.pen && drag && drag.keys && brush()) {
        paint([...kbd.pos]);
        return note(`Painting at ${where()} (${drag.pixels.size} pixels).`);
      }
      if (drag && drag.keys && st.tool === "sun-direction") shadowLine(drag.start, kbd.pos);
      return note(`Crosshair at ${where()}.`);
    }
    if (st.busy) return note("Busy: wait for the current edit or render.");
    if (key === "C") {
      if (!drag || !drag.keys || !brush()) return note("Nothing to apply: paint with Space or Enter first.");
      const d = drag;
      drag = null;
      kbd.pen = false;
      if (!commit(d, kbd.pos)) note("Nothing to apply.");
      return;
    }
    // Space / Enter.
    if (brush()) {
      const d = keyDrag();
      if (!kbd.pen) d.last = null; // a new dab, not a line from the last one
      kbd.pen = true;
      paint([...kbd.pos]);
      return e.repeat ? undefined : note(`Painted at ${where()} (${d.pixels.size} pixels in the stroke; C applies it).`);
    }
    if (e.repeat) return;
    if (!drag) {
      keyDrag();
      shadowLine(drag.start, kbd.pos);
      return note(`Shadow drag from ${where()}: move to where the shadow should be and press Space or Enter again.`);
    }
    const d = drag;
    drag = null;
    if (!commit(d, kbd.pos)) {
      ctx.clearRect(0, 0, VIEW_W, VIEW_H);
      note("The shadow drag's ends are the same spot: discarded.");
    }
  });
  canvas.addEventListener("keyup", (e) => {
    if (e.key === " " || e.key === "Enter") kbd.pen = false;
  });
  canvas.addEventListener("blur", () => { kbd.pen = false; });
  // Ctrl+Z / Ctrl+Shift+Z (or Ctrl+Y) anywhere in the editor but in a text field.
  panel.addEventListener("keydown", (e) => {
    if (!(e.ctrlKey || e.metaKey) || e.altKey) return;
    if (e.target.matches("input[type=text], input[type=number], textarea")) return;
    const k = e.key.toLowerCase();
    if (k === "z" && !e.shiftKey) {
      e.preventDefault();
      undo();
    } else if ((k === "z" && e.shiftKey) || k === "y") {
      e.preventDefault();
      redo();
    }
  });
  function turn(dAz, dEl) {
    st.camera = {
      azimuth_deg: ((st.camera.azimuth_deg + dAz) % 360 + 360) % 360,
      elevation_deg: Math.max(-89, Math.min(89, st.camera.elevation_deg + dEl)),
    };
  }

  const input = inputBox("density volume (.npy, NRRD, .vdb)", "volume.npy", async (asset) => {
    note("Creating the scene…");
    const r = await fetch("/v1/clouds", {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ asset: asset.id }),
    });
    if (!r.ok) return error(await problem(r));
    st.scene = await r.json();
    st.redo = [];
    bar.hidden = false;
    panel.dataset.scene = st.scene.id;
    await select(1, true);
  }, error);

  const row = (id, label, unit, ...controls) => el("div", { class: "set-row" },
    el("label", { for: id }, label, unit ? el("span", { class: "unit" }, ` (${unit})`) : null), el("span", {}, ...controls));
  panel.append(
    el("h2", {}, "Cloud editor"),
    el("p", {}, "Create a scene from a volume, then edit it on the image: paint where the sunlit cloud should take a colour (the sun colour follows by least squares), paint ambient colour into the shadows, or drag from a shadowed spot to where its shadow should be (the sun moves). Every edit is a new version; undo selects an older one."),
    el("div", { class: "layout" },
      el("div", { class: "area-in" }, input,
        el("fieldset", { class: "settings" }, el("legend", {}, "Light and density"),
          row("set-kappa", "Density κ", "extinction per unit length", kappaIn, kappaHow),
          row("set-sun-az", "Sun direction", "compass °", azIn),
          row("set-sun-el", "Sun height", "° above the horizon", elIn),
          row("set-sun-color", "Sun colour", "", sunIn),
          row("set-scattering", "Light bounces", "", modeIn),
          row("set-albedo", "Albedo", "0–1", albedoIn),
          el("p", {}, applyBtn, el("span", { class: "hint" }, " Applies the changed values as a new version.")),
          row("ambient-scale", "Ambient brush strength", "×", ambScale),
          el("span", { class: "desc", id: "ambient-scale-d" }, "How strongly a painted ambient colour lights the cloud (ambient_scale, sent with the ambient brush's strokes; 1 = as painted)."))),
      el("div", { class: "area-out" },
        el("div", { class: "toolbar" },
          el("fieldset", {}, el("legend", {}, "Tool"),
            tool("sun-color", "Sun-colour brush", sunColor),
            tool("ambient", "Ambient brush", ambColor),
            tool("sun-direction", "Shadow drag"),
            tool("orbit", "Orbit camera"))),
        bar, status,
        el("div", { class: "stage" }, img, emptyStage, canvas, cursor), help,
        cmpBox),
      el("div", { class: "area-more" },
        el("h3", {}, "Versions (", count, ")"),
        el("div", { class: "toolbar" }, undoBtn, redoBtn),
        versions,
        el("h3", {}, "State"), stateTable, stateRaw)));
  $("#sun-color", panel).setAttribute("aria-label", "Sun colour");
  $("#ambient-color", panel).setAttribute("aria-label", "Ambient colour");
}
