// A small YAML reader for the subset openapi.yaml uses: block mappings and sequences by
// indentation, `|` block scalars, flow sequences/mappings ([a, b], {}), single- and
// double-quoted scalars, numbers, booleans and null. Not a general YAML parser: anchors, tags,
// multi-document streams and folded plain scalars are not supported (the spec has none).

const KEY = /^("(?:[^"\\]|\\.)*"|'(?:[^']|'')*'|[^\s"'\[{#-][^:]*?|-[^\s:][^:]*?):(?:\s+|$)/;

export function parseYaml(text) {
  const lines = text.split("\n").map((l) => l.replace(/\r$/, ""));
  let i = 0;
  const indentOf = (l) => l.length - l.trimStart().length;
  const skip = () => {
    while (i < lines.length && (lines[i].trim() === "" || lines[i].trim().startsWith("#"))) i++;
  };
  const isSeqItem = (t) => t === "-" || t.startsWith("- ");

  function parseNode(minIndent) {
    skip();
    if (i >= lines.length) return null;
    const ind = indentOf(lines[i]);
    if (ind < minIndent) return null;
    return isSeqItem(lines[i].trim()) ? parseSeq(ind) : parseMap(ind);
  }

  function parseMap(ind) {
    const obj = {};
    for (;;) {
      skip();
      if (i >= lines.length) break;
      const li = indentOf(lines[i]);
      const t = lines[i].trim();
      if (li < ind || (li === ind && isSeqItem(t))) break;
      if (li > ind) throw new Error(`yaml: unexpected indentation at line ${i + 1}`);
      const m = KEY.exec(t);
      if (!m) throw new Error(`yaml: expected "key:" at line ${i + 1}`);
      const key = scalar(m[1]);
      const rest = t.slice(m[0].length);
      i++;
      obj[String(key)] = parseValue(rest, ind);
    }
    return obj;
  }

  function parseValue(rest, ind) {
    if (rest === "" || rest.startsWith("#")) {
      skip();
      if (i >= lines.length) return null;
      const li = indentOf(lines[i]);
      if (li > ind) return parseNode(li);
      if (li === ind && isSeqItem(lines[i].trim())) return parseSeq(ind);
      return null;
    }
    if (/^[|>][-+]?$/.test(rest)) {
      const out = [];
      let blockIndent = -1;
      while (i < lines.length) {
        const l = lines[i];
        if (l.trim() === "") {
          out.push("");
          i++;
          continue;
        }
        const li = indentOf(l);
        if (li <= ind) break;
        if (blockIndent < 0) blockIndent = li;
        out.push(l.slice(Math.min(li, blockIndent)));
        i++;
      }
      while (out.length && out[out.length - 1] === "") out.pop();
      const sep = rest[0] === ">" ? " " : "\n";
      return out.join(sep) + (rest.endsWith("-") ? "" : "\n");
    }
    return scalar(rest);
  }

  function parseSeq(ind) {
    const arr = [];
    for (;;) {
      skip();
      if (i >= lines.length) break;
      const li = indentOf(lines[i]);
      const t = lines[i].trim();
      if (li !== ind || !isSeqItem(t)) break;
      const rest = t.slice(1).trim();
      if (rest === "") {
        i++;
        arr.push(parseNode(ind + 1));
      } else if (KEY.test(rest)) {
        // "- key: value" starts a mapping whose keys sit two columns in.
        lines[i] = " ".repeat(ind + 2) + rest;
        arr.push(parseMap(ind + 2));
      } else {
        i++;
        arr.push(scalar(rest));
      }
    }
    return arr;
  }

  return parseNode(0);
}

function scalar(s) {
  s = s.trim();
  if (s.startsWith("[") || s.startsWith("{")) {
    const p = { s, pos: 0 };
    const v = flow(p);
    return v;
  }
  if (s.startsWith('"')) return JSON.parse(s);
  if (s.startsWith("'")) return s.slice(1, -1).replace(/''/g, "'");
  // A comment after a plain scalar.
  const hash = s.indexOf(" #");
  if (hash >= 0) s = s.slice(0, hash).trim();
  if (s === "true") return true;
  if (s === "false") return false;
  if (s === "null" || s === "~" || s === "") return null;
  if (/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(s)) return Number(s);
  return s;
}

function flow(p) {
  const ws = () => {
    while (p.pos < p.s.length && /\s/.test(p.s[p.pos])) p.pos++;
  };
  ws();
  const c = p.s[p.pos];
  if (c === "[" || c === "{") {
    const close = c === "[" ? "]" : "}";
    p.pos++;
    const out = c === "[" ? [] : {};
    for (;;) {
      ws();
      if (p.s[p.pos] === close) {
        p.pos++;
        return out;
      }
      if (c === "[") {
        out.push(flow(p));
      } else {
        const k = flow(p);
        ws();
        if (p.s[p.pos] !== ":") throw new Error("yaml: expected ':' in flow mapping");
        p.pos++;
        out[String(k)] = flow(p);
      }
      ws();
      if (p.s[p.pos] === ",") p.pos++;
      else if (p.s[p.pos] !== close) throw new Error(`yaml: bad flow collection: ${p.s}`);
    }
  }
  if (c === '"' || c === "'") {
    let j = p.pos + 1;
    while (j < p.s.length && !(p.s[j] === c && p.s[j - 1] !== "\\")) j++;
    const raw = p.s.slice(p.pos, j + 1);
    p.pos = j + 1;
    return scalar(raw);
  }
  let j = p.pos;
  while (j < p.s.length && !",]}:".includes(p.s[j])) j++;
  const raw = p.s.slice(p.pos, j);
  p.pos = j;
  return scalar(raw);
}
