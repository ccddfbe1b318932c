// Parameter forms generated from openapi.yaml's schemas. One widget per property, chosen by the
// schema's shape:
//
//   boolean                         checkbox
//   string enum                     select ("(default)" first when the schema has no default)
//   "#rrggbb" string                colour picker; without a default, a "set" checkbox first
//   integer / number                number input with the documented range
//   fixed-length number array       a row of number inputs (a linear-RGB triple also gets a picker)
//   variable-length number array    comma-separated text
//   array of number arrays          rows of number inputs (add/remove rows unless the count is fixed)
//   array of enum strings           a group of checkboxes
//   object with properties          a fieldset of the above; optional ones behind a "set" checkbox
//   the camera                      orbit (azimuth, elevation, distance, fov) or eye/target
//   oneOf / anyOf                   a choice of alternative, then that alternative's widget
//
// Every widget's get() returns the JSON value to send, or undefined to leave the name out (so the
// API's default applies); values() sends only what differs from the documented default.

import { el } from "./app.js";

/** Human labels for the parts of structured values the schema only names in prose. */
const PARTS = {
  snowfall: { columns: ["hour", "rate (m/h)"] },
  bounds: { rows: ["min", "max"], columns: ["x", "y", "z"] },
  dims: { columns: ["nx", "ny", "nz"] },
  sun_color: { columns: ["r", "g", "b"] },
  ambient: { columns: ["r", "g", "b"] },
};
const XYZ = ["x", "y", "z", "w"];

/** Names handled by their tab (not by the generated form). */
const OUTSIDE = new Set(["sweep"]);

const same = (a, b) => JSON.stringify(a) === JSON.stringify(b);
const firstType = (t) => (Array.isArray(t) ? t.find((x) => x !== "null") : t);

/** Follows `$ref`s (keeping the referring schema's own description). */
export function resolve(spec, schema) {
  let s = schema;
  const own = schema.description;
  for (let n = 0; s && s.$ref && n < 8; n++) {
    let t = spec;
    for (const part of s.$ref.replace(/^#\//, "").split("/")) t = t[part];
    s = t;
  }
  return own && s.description !== own ? { ...s, description: own } : s;
}

const isHex = (p) => firstType(p.type) === "string" && typeof p.pattern === "string" && p.pattern.includes("#");
const isNumber = (p) => ["integer", "number"].includes(firstType(p.type));
const isNumArray = (p) => firstType(p.type) === "array" && p.items && isNumber(p.items);
const isRows = (p) => firstType(p.type) === "array" && p.items && isNumArray(p.items);
const isEnumArray = (p) => firstType(p.type) === "array" && p.items && p.items.enum;
const isCamera = (p) => p.properties && p.properties.eye && p.properties.azimuth_deg;
const isLinearRgb = (p) => isNumArray(p) && p.minItems === 3 && p.maxItems === 3 && /RGB/.test(p.description || "");

const srgbToLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const linearToSrgb = (c) => (c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055);

/** A number input; get() is undefined when empty, NaN when invalid. */
function numberInput(prop, id, value, label) {
  const input = el("input", {
    type: "number", id, step: prop.type === "integer" ? 1 : "any", min: prop.minimum, max: prop.maximum,
    value: value ?? undefined, "aria-label": label, inputmode: "decimal",
    placeholder: value === undefined || value === null ? (prop.default !== undefined ? String(prop.default) : "(unset)") : undefined,
  });
  const get = () => {
    if (input.value === "") return undefined;
    return input.checkValidity() ? Number(input.value) : NaN;
  };
  return { input, get };
}

/** A value is invalid when it holds a NaN anywhere. */
const invalid = (v) => (typeof v === "number" ? Number.isNaN(v) : Array.isArray(v) ? v.some(invalid) : v && typeof v === "object" ? Object.values(v).some(invalid) : false);

/** A row of fixed-length number inputs; each cell's bounds from `prefixItems` (a tuple) or `items`. */
function tuple(prop, id, label, def, columns) {
  const n = prop.minItems;
  const cells = Array.from({ length: n }, (_, k) => numberInput((prop.prefixItems && prop.prefixItems[k]) || prop.items, `${id}-${k}`, def ? def[k] : undefined, `${label} ${columns[k] || k + 1}`));
  const node = el("div", { class: "tuple", style: `--n:${n}`, role: "group", "aria-label": label },
    cells.map((c, k) => el("span", {}, el("small", { "aria-hidden": "true" }, columns[k] || String(k + 1)), c.input)));
  return {
    node,
    inputs: cells.map((c) => c.input),
    get() {
      const v = cells.map((c) => c.get());
      if (v.every((x) => x === undefined)) return undefined;
      return v.map((x) => (x === undefined ? NaN : x));
    },
    set(v) {
      cells.forEach((c, k) => { c.input.value = v && v[k] !== undefined ? String(v[k]) : ""; });
    },
  };
}

/** Builds the widget of one property. `ctx` = { spec, onChange }. */
export function widget(ctx, name, prop0, id, label = name) {
  const prop = resolve(ctx.spec, prop0);
  const def = prop.default;

  if (prop.oneOf || prop.anyOf) return choice(ctx, name, prop, id, label);
  if (isCamera(prop)) return cameraWidget(ctx, prop, id, label);

  const type = firstType(prop.type);
  if (type === "boolean") {
    const input = el("input", { type: "checkbox", id, name, checked: def === true });
    return { input, inline: true, get: () => input.checked };
  }
  if (prop.enum) {
    const input = el("select", { id, name },
      def === undefined ? el("option", { value: "" }, "(default)") : null,
      prop.enum.map((v) => el("option", { value: v, selected: v === def }, v)));
    return { input, get: () => (input.value === "" ? undefined : input.value) };
  }
  if (isHex(prop)) {
    const input = el("input", { type: "color", id, name, value: def || "#808080" });
    if (def !== undefined) return { input, get: () => input.value };
    // No default (absent = the API decides, e.g. a transparent background): off until set.
    const on = el("input", { type: "checkbox", id: `${id}-on`, "aria-label": `set ${label}` });
    input.disabled = true;
    on.addEventListener("change", () => { input.disabled = !on.checked; });
    const node = el("span", { class: "optional" }, on, " ", el("label", { for: on.id, class: "inline" }, "set"), " ", input);
    return { input, node, get: () => (on.checked ? input.value : undefined) };
  }
  if (isNumber(prop)) {
    const { input, get } = numberInput(prop, id, def, undefined);
    input.name = name;
    return { input, get };
  }
  if (isRows(prop)) return rows(prop, id, label, def, PARTS[name] || {});
  if (isNumArray(prop)) {
    const columns = (PARTS[name] && PARTS[name].columns) || XYZ;
    if (prop.minItems !== undefined && prop.minItems === prop.maxItems && prop.minItems <= 4) {
      const t = tuple(prop, id, label, def, columns);
      if (isLinearRgb(prop)) withPicker(t, label);
      return { node: t.node, input: t.inputs[0], get: t.get, set: t.set };
    }
    // A list of any length: comma-separated numbers.
    const input = el("input", {
      type: "text", id, name, inputmode: "decimal", value: def ? def.join(", ") : undefined,
      placeholder: "e.g. 1, 2, 3", pattern: "^\\s*[-+0-9.eE]+(\\s*[,\\s]\\s*[-+0-9.eE]+)*\\s*$",
    });
    return {
      input,
      get() {
        const parts = input.value.split(/[,\s]+/).filter(Boolean);
        if (!parts.length) return undefined;
        return parts.map(Number);
      },
    };
  }
  if (isEnumArray(prop)) {
    const boxes = prop.items.enum.map((v) => el("input", { type: "checkbox", id: `${id}-${v}`, value: v, checked: Array.isArray(def) && def.includes(v) }));
    const node = el("span", { class: "checks", role: "group", "aria-label": label },
      boxes.map((b) => el("span", {}, b, " ", el("label", { for: b.id, class: "inline" }, b.value))));
    return { node, input: boxes[0], get: () => boxes.filter((b) => b.checked).map((b) => b.value) };
  }
  if (type === "object" && prop.properties) return objectWidget(ctx, name, prop, id, label);
  return null;
}

/** A linear-RGB triple gets a colour picker that writes the triple (and follows it). */
function withPicker(t, label) {
  const hex = (v) => "#" + v.map((c) => Math.round(255 * Math.min(1, Math.max(0, linearToSrgb(c)))).toString(16).padStart(2, "0")).join("");
  const picker = el("input", { type: "color", "aria-label": `${label} as a colour`, title: "Pick a colour (sets the linear RGB values)" });
  const follow = () => {
    const v = t.get();
    if (v && !invalid(v)) picker.value = hex(v);
  };
  follow();
  picker.addEventListener("input", () => {
    const v = [1, 3, 5].map((k) => srgbToLinear(parseInt(picker.value.slice(k, k + 2), 16) / 255));
    t.set(v.map((x) => Number(x.toFixed(4))));
    t.inputs[0].dispatchEvent(new Event("change", { bubbles: true }));
  });
  for (const i of t.inputs) i.addEventListener("change", follow);
  t.node.append(el("span", {}, el("small", { "aria-hidden": "true" }, "pick"), picker));
}

/** Rows of number tuples (a snowfall schedule, a box). */
function rows(prop, id, label, def, parts) {
  const row = prop.items;
  const fixed = prop.minItems !== undefined && prop.minItems === prop.maxItems;
  const columns = parts.columns || XYZ;
  const list = el("div", { class: "rows", role: "group", "aria-label": label });
  const items = [];
  let serial = 0;
  const add = (v) => {
    const k = serial++;
    const rl = parts.rows ? parts.rows[items.length] : `row ${items.length + 1}`;
    const t = tuple(row, `${id}-r${k}`, `${label} ${rl}`, v, columns);
    const line = el("div", { class: "row" }, parts.rows ? el("small", { class: "rowlabel" }, rl) : null, t.node);
    const item = { t, line };
    if (!fixed) {
      line.append(el("button", {
        type: "button", class: "secondary small", "aria-label": `remove ${label} ${rl}`,
        onclick: () => {
          if (items.length <= (prop.minItems || 0)) return;
          items.splice(items.indexOf(item), 1);
          line.remove();
          list.dispatchEvent(new Event("change", { bubbles: true }));
        },
      }, "−"));
    }
    items.push(item);
    list.append(line);
    return item;
  };
  const n = Array.isArray(def) ? def.length : Math.max(prop.minItems || 1, 1);
  for (let k = 0; k < n; k++) add(Array.isArray(def) ? def[k] : undefined);
  const node = el("div", {}, list);
  if (!fixed) {
    node.append(el("button", {
      type: "button", class: "secondary small",
      onclick: () => {
        if (prop.maxItems && items.length >= prop.maxItems) return;
        add(undefined).t.inputs[0].focus();
      },
    }, `+ ${parts.columns ? "row" : "item"}`));
  }
  return {
    node,
    input: items[0] && items[0].t.inputs[0],
    get() {
      const v = items.map((i) => i.t.get());
      if (v.every((x) => x === undefined)) return undefined;
      return v.map((x) => (x === undefined ? row.items && Array(row.minItems).fill(NaN) : x));
    },
  };
}

/** An object with named properties: a fieldset; an optional object without a default is off
 * until its "set" box is ticked (absent = the API's default, e.g. no wind). */
function objectWidget(ctx, name, prop, id, label) {
  const required = new Set(prop.required || []);
  const subs = [];
  const box = el("div", { class: "sub" });
  for (const [k, p] of Object.entries(prop.properties)) {
    const w = widget(ctx, k, p, `${id}-${k}`, `${label}.${k}`);
    if (!w) continue;
    const rp = resolve(ctx.spec, p);
    const range = rp.minimum !== undefined && rp.maximum !== undefined ? ` (${rp.minimum}–${rp.maximum})` : "";
    box.append(el("div", { class: "field" }, el("label", { for: w.input ? w.input.id : undefined }, k + range + (required.has(k) ? " *" : "")), w.node || w.input));
    subs.push([k, w]);
  }
  const on = el("input", { type: "checkbox", id: `${id}-on`, "aria-label": `set ${label}` });
  const setAll = () => { for (const e of box.querySelectorAll("input, select, button")) e.disabled = !on.checked; };
  on.addEventListener("change", setAll);
  setAll();
  const node = el("div", {}, el("span", { class: "optional" }, on, " ", el("label", { for: on.id, class: "inline" }, `set ${name}`)), box);
  return {
    node,
    input: on,
    get() {
      if (!on.checked) return undefined;
      const out = {};
      for (const [k, w] of subs) {
        const v = w.get();
        if (v !== undefined) out[k] = v;
        else if (required.has(k)) out[k] = NaN;
      }
      return out;
    },
  };
}

/** oneOf / anyOf: pick the alternative, then fill it in. */
function choice(ctx, name, prop, id, label) {
  const alts = (prop.oneOf || prop.anyOf).map((a) => resolve(ctx.spec, a));
  const title = (a) => {
    if (isRows(a)) return "schedule";
    if (isEnumArray(a)) return "list";
    const t = firstType(a.type);
    return t === "number" || t === "integer" ? "constant" : t === "boolean" ? "all or none" : t;
  };
  const fits = (a, v) => {
    const t = firstType(a.type);
    if (v === undefined) return false;
    if (Array.isArray(v)) return t === "array";
    return t === typeof v || (t === "integer" && typeof v === "number");
  };
  let current = Math.max(0, alts.findIndex((a) => fits(a, prop.default)));
  const select = el("select", { id, "aria-label": `${label}: kind` }, alts.map((a, k) => el("option", { value: k, selected: k === current }, title(a))));
  const ws = alts.map((a, k) => {
    const w = widget(ctx, name, { ...a, default: k === current ? prop.default : a.default }, `${id}-alt${k}`, `${label} (${title(a)})`);
    if (w.input && !w.inline && !w.input.getAttribute("aria-label")) w.input.setAttribute("aria-label", `${label} (${title(a)})`);
    const holder = el("div", { class: "alt", hidden: k !== current }, w.inline ? el("span", {}, w.input, " ", el("label", { for: w.input.id, class: "inline" }, "yes")) : w.node || w.input);
    return { w, holder };
  });
  select.addEventListener("change", () => {
    current = Number(select.value);
    ws.forEach((x, k) => { x.holder.hidden = k !== current; });
  });
  return { input: select, node: el("div", {}, select, ws.map((x) => x.holder)), get: () => ws[current].w.get() };
}

/** The camera: the pipeline's default view, an orbit around the input's centre, or eye/target. */
function cameraWidget(ctx, prop, id, label) {
  const P = prop.properties;
  const mode = el("select", { id, "aria-label": `${label}: kind` },
    el("option", { value: "default" }, "default view"),
    el("option", { value: "orbit" }, "orbit"),
    el("option", { value: "eye" }, "eye & target"));
  const orbit = {};
  for (const k of ["azimuth_deg", "elevation_deg", "distance", "fov_deg"]) {
    orbit[k] = numberInput(P[k], `${id}-${k}`, undefined, `${label}.${k}`);
  }
  const eye = tuple(P.eye, `${id}-eye`, `${label}.eye`, undefined, XYZ);
  const target = tuple(P.target, `${id}-target`, `${label}.target`, undefined, XYZ);
  const fovEye = numberInput(P.fov_deg, `${id}-eye-fov`, undefined, `${label}.fov_deg`);
  const f = (k, w, extra) => el("div", { class: "field" }, el("label", { for: w.input ? w.input.id : w.inputs[0].id }, k + extra), w.input || w.node);
  const rng = (p) => (p.minimum !== undefined ? ` (${p.minimum}–${p.maximum})` : "");
  const orbitBox = el("div", { class: "sub", hidden: true },
    Object.entries(orbit).map(([k, w]) => f(k, w, rng(P[k]))),
    el("span", { class: "desc" }, "Empty fields take the pipeline's default. Dragging the render (or the arrow keys on it) orbits."));
  const eyeBox = el("div", { class: "sub", hidden: true },
    el("div", { class: "field" }, el("label", { for: eye.inputs[0].id }, "eye *"), eye.node),
    el("div", { class: "field" }, el("label", { for: target.inputs[0].id }, "target *"), target.node),
    f("fov_deg", fovEye, rng(P.fov_deg)),
    el("span", { class: "desc" }, "In the input's world frame, metres (X east, Y up, Z south)."));
  const show = () => {
    orbitBox.hidden = mode.value !== "orbit";
    eyeBox.hidden = mode.value !== "eye";
  };
  mode.addEventListener("change", show);
  const put = (w, v) => { w.input.value = v === undefined || v === null ? "" : String(Math.round(v * 1000) / 1000); };
  return {
    input: mode,
    node: el("div", {}, mode, orbitBox, eyeBox),
    get() {
      if (mode.value === "orbit") {
        const out = {};
        for (const [k, w] of Object.entries(orbit)) {
          const v = w.get();
          if (v !== undefined) out[k] = v;
        }
        return Object.keys(out).length ? out : undefined;
      }
      if (mode.value === "eye") {
        const out = { eye: eye.get() ?? [NaN, NaN, NaN], target: target.get() ?? [NaN, NaN, NaN] };
        const v = fovEye.get();
        if (v !== undefined) out.fov_deg = v;
        return out;
      }
      return undefined;
    },
    /** Switches to orbit with these values (from a drag on the render). */
    setOrbit(c) {
      mode.value = "orbit";
      show();
      for (const k of Object.keys(orbit)) if (k in c) put(orbit[k], c[k]);
    },
    /** The orbit values typed in (undefined where empty). */
    orbitValues() {
      if (mode.value !== "orbit") return {};
      return Object.fromEntries(Object.entries(orbit).map(([k, w]) => [k, w.get()]).filter(([, v]) => v !== undefined && !Number.isNaN(v)));
    },
  };
}

/** The whole form of a params schema: the `main` names up front in `labels`' words (label,
 * unit, help; the API name small), the rest under a closed "Advanced" section. */
export function buildForm(spec, schema, idBase, onChange, { main = [], labels = (n) => ({ label: n, unit: "", help: "" }), skip = [] } = {}) {
  const form = el("form", { class: "params", onsubmit: (e) => e.preventDefault(), novalidate: true });
  const mainBox = el("div", { class: "main-fields" });
  const moreBox = el("div", { class: "advanced-fields" });
  const advanced = el("details", { class: "advanced", id: `advanced-${idBase}` }, el("summary", {}, "Advanced settings"), moreBox);
  form.append(mainBox, advanced);
  const read = {};
  const ctx = { spec, onChange };
  const names = Object.keys(schema.properties || {}).filter((n) => !OUTSIDE.has(n) && !skip.includes(n));
  const ordered = [...main.filter((n) => names.includes(n)), ...names.filter((n) => !main.includes(n))];
  let more = 0;
  for (const name of ordered) {
    const prop = resolve(spec, schema.properties[name]);
    const id = `p-${idBase}-${name}`;
    const w = widget(ctx, name, prop, id);
    if (!w) continue;
    const { label, unit, help } = labels(name);
    const desc = el("span", { class: "desc", id: `${id}-d` }, help || prop.description || "");
    if (help && prop.description) desc.title = prop.description;
    if (w.input) w.input.setAttribute("aria-describedby", desc.id);
    const range = prop.minimum !== undefined && prop.maximum !== undefined ? ` · ${prop.minimum}–${prop.maximum}` : "";
    const api = el("code", { class: "api", title: "The parameter's name in the API" }, name + range);
    const text = [label, unit ? el("span", { class: "unit" }, ` (${unit})`) : null];
    const field = w.inline
      ? el("div", { class: "field check", "data-name": name }, w.input, " ", el("label", { for: id }, text), " ", api, desc)
      : el("div", { class: "field", "data-name": name }, el("label", { for: w.input ? w.input.id : id }, text), " ", api, w.node || w.input, desc);
    if (main.includes(name)) mainBox.append(field);
    else {
      moreBox.append(field);
      more++;
    }
    read[name] = { w, def: prop.default, field };
  }
  advanced.firstChild.textContent = `Advanced settings (${more})`;
  advanced.hidden = more === 0;
  form.addEventListener("input", (e) => { if (e.target.type !== "text") onChange(); });
  form.addEventListener("change", () => onChange());
  return {
    form,
    widgets: Object.fromEntries(Object.entries(read).map(([k, r]) => [k, r.w])),
    /** The parameters that differ from their defaults, and the names whose input is invalid. */
    values() {
      const out = {};
      const bad = [];
      for (const [name, { w, def, field }] of Object.entries(read)) {
        const v = w.get();
        const wrong = v !== undefined && invalid(v);
        field.classList.toggle("invalid", wrong);
        if (wrong) bad.push(name);
        else if (v !== undefined && !same(v, def)) out[name] = v;
      }
      return { values: out, bad };
    },
    /** Marks the field a problem+json names (opening "Advanced" when it is there). */
    mark(name) {
      for (const [n, { field }] of Object.entries(read)) field.classList.toggle("invalid", n === name);
      if (name && read[name] && moreBox.contains(read[name].field)) advanced.open = true;
    },
    /** Sets a scalar field (a preset); undefined = back to its default. No change event. */
    set(name, v) {
      const r = read[name];
      if (!r) return;
      const x = v === undefined ? r.def : v;
      if (r.w.set) return r.w.set(x);
      const i = r.w.input;
      if (i.type === "checkbox") i.checked = x === true;
      else i.value = x === undefined || x === null ? "" : String(x);
    },
    /** The current value of a field as it would be sent (undefined = its default). */
    get(name) {
      return read[name] && read[name].w.get();
    },
  };
}
