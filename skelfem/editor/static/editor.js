// skelfem editor: the design (rest, editable) drawn over the equilibrium the server solves for it.
// Plain JavaScript, no build step. Talks to the server over /api/live (websocket) and /api/* (JSON).
"use strict";

const SVGNS = "http://www.w3.org/2000/svg";
const $ = (id) => document.getElementById(id);
// "New": a small two-bone finger with one tendon, to start from (saved under a name you give)
const TEMPLATE = {
  format: 1, name: "untitled", dim: 2, thickness: 10.0, mesh: { size: 2.0, degree: 1 },
  materials: { silicone: { E: 0.1, nu: 0.45 }, pla: { E: 3000.0, nu: 0.35 } },
  body: { outline: [[0, 0], [16, 0], [16, 60], [12, 66], [4, 66], [0, 60]], material: "silicone" },
  bones: [{ name: "lower", outline: [[5, 6], [11, 6], [11, 26], [5, 26]], material: "pla" },
          { name: "upper", outline: [[5, 32], [11, 32], [11, 52], [5, 52]], material: "pla" }],
  cables: [{ name: "flexor", kind: "tendon", path: [[2.5, 0], [2.5, 56]], stiffness: 20.0, contraction: 4.0 }],
  pins: [{ name: "base", region: [[-1, -1], [17, 0.01]], kind: "fixed" }],
  markers: { tip: [8, 66] },
};
const SLIDER_KEYS = new Set(["ArrowLeft", "ArrowRight", "ArrowUp", "ArrowDown", "PageUp", "PageDown", "Home", "End"]);
const REGION_FILL = { body: "#f4b6a6", bone: "#e8e4d8", object: "#b9cbe4" };
const REGION_LABEL = { body: "body", bone: "bones", object: "objects" };
const PALETTE = ["#440154", "#482475", "#414487", "#355f8d", "#2a788e", "#21908d", "#22a884", "#42be71",
  "#7ad151", "#bddf26", "#fde725"];
const SNAP = 100;                      // coordinates are rounded to 1/SNAP mm
const GO_ON_WAIT = 40;                 // ms a "go on" waits for the next move while a handle or slider moves
const MOVING = 100;                    // ... which it does if its last input is at most this old (ms)

const S = {
  design: null, file: "", dim: 2, readonly: false,
  answer: null, failed: null,            // last valid answer; message of the last failure
  undo: [], redo: [],
  view: { x0: 0, y0: 0, k: 1 }, size: { W: 800, H: 600 },
  drag: null,
  ik: { on: false, marker: null, target: null, info: null },
  ws: null, reqSeq: 0, inflight: null, queued: null, goOnTimer: null, lastInput: 0,
  topo: null,                            // the mesh's cells and regions as last sent (frames leave them out)
  inputSeq: 0, inputs: [],               // input events not yet shown: {seq, t, kind}
  latency: { rendered: [], events: [], settled: [] }, // ms from an input event to the picture showing it; from a
  //                                     release to the first converged picture after it
  solves: 0, errors: 0, ready: false, server: [], renderMs: [],
  certificates: [],                      // {state, ratio} of every answer shown
};
window.skelfemEditor = S;

// -- small helpers -------------------------------------------------------------------------------
function el(tag, attrs, parent) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}
const clone = (x) => JSON.parse(JSON.stringify(x));
const snap = (v) => Math.round(v * SNAP) / SNAP;
const fmt = (v, d = 2) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
function px(p) { const v = S.view; return [(p[0] - v.x0) * v.k, (v.y0 - p[1]) * v.k]; }
function pts(list) { return list.map((p) => px(p).map((c) => c.toFixed(1)).join(",")).join(" "); }
function toMM(evt) {
  const r = $("view").getBoundingClientRect(), v = S.view;
  return [(evt.clientX - r.left) / v.k + v.x0, v.y0 - (evt.clientY - r.top) / v.k];
}
function getPath(obj, path) { return path.reduce((o, k) => o[k], obj); }
function setPath(obj, path, value) { getPath(obj, path.slice(0, -1))[path[path.length - 1]] = value; }
function named(section) { return (S.design[section] || []); }
// HTML elements with text: names from a design are only ever text nodes (never markup: no innerHTML)
function html(tag, props, children) {
  const e = document.createElement(tag);
  Object.assign(e, props || {});
  for (const c of children || []) e.append(c);      // strings become text nodes
  return e;
}

// -- talking to the server ----------------------------------------------------------------------------
function connect() {
  const ws = new WebSocket(`ws://${location.host}/api/live`);
  ws.onopen = () => { S.ws = ws; S.inflight = null; if (S.queued || S.design) request({ kind: "solve" }); };
  ws.onmessage = (e) => onAnswer(unpackMesh(JSON.parse(e.data)));
  ws.onclose = () => { S.ws = null; setStatus("connection lost; retrying…", true); setTimeout(connect, 700); };
}

// The server packs the mesh's coordinates (the message's "packed"): {"f32": base64 float32, "shape": [n, d]}
// becomes the nested arrays the rest of the page reads (the known fields only: a JSON.parse reviver would be
// called for every value of the answer).
function unpackMesh(data) {
  const m = data && data.answer && data.answer.mesh;
  if (!m) return data;
  for (const k of ["x", "y"]) if (m[k]) m[k] = unpacked(m[k]);
  for (const c of m.cables || []) { c.via = unpacked(c.via); c.via_rest = unpacked(c.via_rest); }
  return data;
}
function unpacked(v) {
  if (!v || typeof v !== "object" || typeof v.f32 !== "string" || !Array.isArray(v.shape)) return v;
  const bin = atob(v.f32), bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  const f = new Float32Array(bytes.buffer), n = v.shape[0], d = v.shape.length > 1 ? v.shape[1] : 0;
  if (!d) return Array.from(f);
  const out = new Array(n);
  for (let i = 0; i < n; i++) {
    const row = new Array(d);
    for (let j = 0; j < d; j++) row[j] = f[i * d + j];
    out[i] = row;
  }
  return out;
}

// request(): the newest request replaces a waiting one (latest wins); at most one is in flight.
function request(req) {
  req.input = S.inputSeq;
  if (S.inflight || !S.ws) { S.queued = req; return; }
  send(req);
}
function send(req) {
  clearTimeout(S.goOnTimer);
  if (S.queued && S.queued.goOn) S.queued = null;       // any request goes on from the newest state
  const msg = { id: ++S.reqSeq, kind: req.kind, design: S.design, packed: true };
  if (req.kind === "solve") {
    // every solve is a frame: within the server's frame budget, asked again until converged; the mesh's
    // cells and regions are sent only when this page does not hold them, the fields only when drawn
    Object.assign(msg, { draft: !!req.draft, frame: true, have: S.topo ? S.topo.topology : null,
      fields: $("colour").value !== "region" });
  }
  if (req.kind === "ik") Object.assign(msg, { marker: req.marker, target: req.target, final: !!req.final });
  req.id = msg.id;
  req.input = S.inputSeq;                 // everything typed or dragged so far is in this design
  S.inflight = req;
  req.sent = performance.now();
  S.ws.send(JSON.stringify(msg));
}
function onAnswer(data) {
  const req = S.inflight;
  if (!req || data.id !== req.id) return;
  S.inflight = null;
  if (data.dropped) { /* a newer request replaced it on the server */ }
  else if (data.ok && (data.answer.converged || data.answer.status === "frame_budget") && data.answer.mesh &&
           !whole(data.answer)) {
    S.topo = null;                          // a frame on a mesh this page does not hold: ask for it whole
    if (!S.queued) S.queued = { kind: req.kind, draft: !!req.draft, input: req.input };
  }
  else if (data.ok && (data.answer.converged || data.answer.status === "frame_budget") && data.answer.mesh) {
    const a = data.answer;
    if (a.new_design && req.kind === "ik") adoptContractions(a.new_design);
    if (a.ik) S.ik.info = a.ik;
    S.answer = a; S.failed = null; S.solves += 1;
    S.server.push({ how: a.editor.how, draft: a.editor.draft, status: a.status, s: a.editor.seconds,
      rtt: performance.now() - req.sent });
    clearError();
    render();
    painted(req.input);
    // a frame stopped at its time budget: the same design again goes on from its state (unless newer input waits)
    if (a.status === "frame_budget" && !S.queued) {
      S.queued = { kind: "solve", draft: !!req.draft, input: req.input, goOn: true };
      // while a handle or slider moves, its next move comes within a frame (16 ms): wait for it rather than
      // make it wait for a "go on" in flight
      const wait = performance.now() - S.lastInput < MOVING ? GO_ON_WAIT : 0;
      if (wait) {
        const q = S.queued;
        S.goOnTimer = setTimeout(() => { if (S.queued === q && !S.inflight && S.ws) { S.queued = null; send(q); } }, wait);
        return;
      }
    }
  } else if (data.ok) {
    S.failed = `solve failed: ${data.answer.status} after ${data.answer.newton_iterations} Newton iterations; ` +
      "the last equilibrium stays on screen"; S.errors += 1;
    showError(S.failed, "");
    painted(req.input);
  } else {
    S.errors += 1;
    showError(data.error, data.key || "");
    painted(req.input);
  }
  if (S.queued && S.ws) { const q = S.queued; S.queued = null; send(q); }
}

// After the picture is on screen (the frame after this one), time every input it shows.
function painted(upto) {
  requestAnimationFrame(() => setTimeout(() => {
    const now = performance.now();
    performance.mark(`paint-${upto}`);
    for (const list of [S.latency.events, S.latency.rendered, S.server, S.renderMs])
      if (list.length > 20000) list.splice(0, list.length - 10000);     // a long session keeps the recent ones
    const shown = S.inputs.filter((i) => i.seq <= upto);
    S.inputs = S.inputs.filter((i) => i.seq > upto);
    for (const i of shown) S.latency.events.push({ kind: i.kind, ms: now - i.t });
    const s = S.settling, c = S.answer && S.answer.certificate;
    if (s && c && c.state === "converged") { S.latency.settled.push({ kind: s.kind, ms: now - s.t }); S.settling = null; }
    const own = shown.find((i) => i.seq === upto);
    if (own) {
      S.latency.rendered.push({ kind: own.kind, ms: now - own.t });
      try { performance.measure(`latency-${own.kind}-${upto}`, `input-${upto}`, `paint-${upto}`); } catch (e) { /* */ }
    }
  }, 0));
}
// The mesh of an answer made whole: a frame on the mesh this page holds leaves out its cells and regions.
// Returns false if it left them out for another mesh than the one held.
function whole(a) {
  const m = a.mesh;
  if (m.cells) {
    S.topo = { topology: m.topology, cells: m.cells, regions: m.regions, region_names: m.region_names,
      body_tag: m.body_tag, x: m.x };
    S.drawCache = null;
    return true;
  }
  if (!S.topo || S.topo.topology !== m.topology) return false;
  a.mesh = { ...S.topo, ...m };
  return true;
}
function input(kind) {
  S.inputSeq += 1;
  S.lastInput = performance.now();
  performance.mark(`input-${S.inputSeq}`);
  S.inputs.push({ seq: S.inputSeq, t: performance.now(), kind });
  if (kind.endsWith("release")) S.settling = { kind, t: performance.now() };
}

async function api(path, body) {
  const r = await fetch(path, body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  const data = await r.json();
  return { status: r.status, data };
}

// -- editing: every change goes through here ------------------------------------------------------------
function checkpoint() { S.undo.push(clone(S.design)); if (S.undo.length > 200) S.undo.shift(); S.redo = []; buttons(); }
function changed(kind, draft) {
  input(kind);
  drawSketch();
  if (!draft) { unsaved(); remember(); }
  request({ kind: "solve", draft: !!draft });
}
// -- unsaved changes, revert, and the history kept across reloads (per design file, in this browser) ------
function unsaved() {
  const dirty = JSON.stringify(S.design) !== S.savedText;
  $("file").textContent = S.file + (dirty ? " •" : "");
  $("file").title = dirty ? "unsaved changes" : "";
  $("revert").disabled = !dirty;
  document.title = `${dirty ? "• " : ""}${S.file} — skelfem`;
  return dirty;
}
function historyKey() { return `skelfem-history:${S.file}`; }
function remember(now) {
  // at most every 300 ms (a slider drag edits many times a second), and at once when asked (save)
  clearTimeout(S.rememberTimer);
  const write = () => {
    try {
      localStorage.setItem(historyKey(), JSON.stringify({ saved: S.savedText, design: S.design,
        undo: S.undo.slice(-50), redo: S.redo.slice(-50) }));
    } catch (e) { /* storage full or off: the history lives in this page only */ }
  };
  if (now) write(); else S.rememberTimer = setTimeout(write, 300);
}
function recall() {
  // the history of this file, if it was made on the same file content (else the file changed on disk)
  let h = null;
  try { h = JSON.parse(localStorage.getItem(historyKey()) || "null"); } catch (e) { h = null; }
  if (!h || h.saved !== S.savedText) return false;
  S.undo = h.undo || []; S.redo = h.redo || [];
  const edited = JSON.stringify(h.design) !== S.savedText;
  if (edited) S.design = h.design;
  return edited;
}
function newDesign() {
  if (S.readonly) return;
  if (unsaved() && !confirm("Start a new design? Your unsaved changes stay in the undo history.")) return;
  checkpoint();
  S.design = clone(TEMPLATE);
  S.file = "untitled.toml"; S.untitled = true; S.savedText = "";
  afterJump();
  fit();
}
function revert() {
  if (!unsaved()) return;
  checkpoint();
  S.design = JSON.parse(S.savedText);
  afterJump();
}
function undo() { if (!S.undo.length) return; S.redo.push(clone(S.design)); S.design = S.undo.pop(); afterJump(); }
function redo() { if (!S.redo.length) return; S.undo.push(clone(S.design)); S.design = S.redo.pop(); afterJump(); }
function afterJump() {
  const focused = document.activeElement && document.activeElement.dataset ? document.activeElement.dataset.key : null;
  buildPanel();
  if (focused) { const again = document.querySelector(`#panel [data-key="${CSS.escape(focused)}"]`); if (again) again.focus(); }
  changed("undo", false); buttons();
}
function buttons() { $("undo").disabled = !S.undo.length; $("redo").disabled = !S.redo.length; if (S.file) unsaved(); }
function adoptContractions(design) {
  for (const c of design.cables || []) {
    const mine = named("cables").find((m) => m.name === c.name);
    if (mine && c.kind === "tendon" && c.contraction !== undefined) mine.contraction = c.contraction;
  }
  syncSliders();
}

// -- the panel ------------------------------------------------------------------------------------------------
function buildPanel() {
  const d = S.design;
  $("file").textContent = S.file;
  const sliders = $("sliders"); sliders.textContent = "";
  for (const c of d.cables || []) {
    const key = c.kind === "tendon" ? "contraction" : "pretension";
    const L = c.path.slice(1).reduce((s, p, i) => s + Math.hypot(p[0] - c.path[i][0], p[1] - c.path[i][1]), 0);
    const max = Math.max(1, Math.ceil((c.kind === "tendon" ? 0.3 : 0.2) * L), Math.ceil(c[key] || 0));
    const box = document.createElement("div"); box.className = "slider";
    box.append(html("label", {}, [html("span", {}, [`${c.name} ${key} (mm)`]), html("output")]));
    const r = document.createElement("input");
    Object.assign(r, { type: "range", min: 0, max, step: 0.05, value: c[key] || 0 });
    r.dataset.cable = c.name; r.dataset.param = key; r.dataset.key = `cables.${c.name}.${key}`;
    r.addEventListener("pointerdown", () => { if (!r.dataset.live) { checkpoint(); r.dataset.live = "1"; } });
    r.addEventListener("keydown", (e) => {           // only keys that move the slider start an undo step
      if (e.ctrlKey || e.metaKey || e.altKey || !SLIDER_KEYS.has(e.key)) return;
      if (!r.dataset.live) { checkpoint(); r.dataset.live = "1"; }
    });
    r.addEventListener("input", () => {
      if (!r.dataset.live) { checkpoint(); r.dataset.live = "1"; }
      const m = named("cables").find((x) => x.name === c.name); m[key] = Number(r.value);
      box.querySelector("output").textContent = fmt(r.value);
      changed(c.kind === "tendon" ? "contraction" : "pretension", true);
    });
    // let go (or a key's step): the design is solved to the end, and becomes an undo step and unsaved
    r.addEventListener("change", () => { delete r.dataset.live; changed("slider-release", false); });
    box.querySelector("output").textContent = fmt(r.value);
    box.appendChild(r); sliders.appendChild(box);
  }
  const mats = $("materials"); mats.textContent = "";
  for (const [name, m] of Object.entries(d.materials || {})) {
    const row = document.createElement("div"); row.className = "material";
    row.append(html("span", { className: "material-name" }, [name]));
    for (const [p, step] of [["E", "any"], ["nu", "0.01"]]) {
      const label = document.createElement("label");
      label.className = "material-field";
      label.append(p === "E" ? "E (MPa) " : "ν ");
      const inp = document.createElement("input");
      Object.assign(inp, { type: "number", step, value: m[p], title: p === "E" ? "Young's modulus E (MPa)" : "Poisson's ratio ν" });
      inp.dataset.key = `materials.${name}.${p}`;
      inp.addEventListener("change", () => {
        const v = Number(inp.value); if (!Number.isFinite(v)) return;
        checkpoint(); d.materials[name][p] = v; changed("field", false);
      });
      label.appendChild(inp);
      row.appendChild(label);
    }
    mats.appendChild(row);
  }
  $("mesh-size").value = (d.mesh || {}).size ?? 2;
  $("mesh-degree").value = String((d.mesh || {}).degree ?? 1);
  const sel = $("ik-marker"); sel.textContent = "";
  for (const name of Object.keys(d.markers || {})) {
    const o = document.createElement("option"); o.textContent = name; sel.appendChild(o);
  }
  S.ik.marker = sel.value || null;
  $("ik-tools").disabled = !sel.value || !(d.cables || []).some((c) => c.kind === "tendon");
}
function syncSliders() {
  for (const r of document.querySelectorAll("#sliders input[type=range]")) {
    const c = named("cables").find((x) => x.name === r.dataset.cable);
    if (!c) continue;
    const v = c[r.dataset.param] || 0;
    if (Number(r.max) < v) r.max = Math.ceil(v);
    r.value = v; r.parentElement.querySelector("output").textContent = fmt(v);
  }
}
function meshField(id, key, parse) {
  $(id).addEventListener("change", () => {
    const v = parse($(id).value); if (!Number.isFinite(v)) return;
    checkpoint(); S.design.mesh = S.design.mesh || {}; S.design.mesh[key] = v; changed("field", false);
  });
}

function setStatus(text, failed) { $("status").textContent = text; $("status").classList.toggle("failed", !!failed); }
function showStatus() {
  const a = S.answer; if (!a) return;
  const e = a.editor || {};
  showCertificate(a.certificate);
  setStatus(`${a.design}: ${a.converged ? "converged" : a.status === "frame_budget" ? "preview" : a.status} in ` +
    `${a.newton_iterations} Newton iterations` +
    `\n${a.dofs} DOFs, ${a.cells} cells (h = ${fmt(e.mesh_size, 2)} mm${e.draft ? ", draft" : ""}), ` +
    `${e.how}, ${fmt(1000 * (e.seconds || 0), 0)} ms`, false);
  const rows = [];
  const row = (what, value) => rows.push(html("tr", {}, [html("td", {}, [what]), html("td", {}, [value])]));
  // a preview has no read-outs of its own (they are an equilibrium's): its markers come from its mesh
  const markers = a.markers || Object.fromEntries(Object.entries((a.mesh || {}).markers || {}).map(([n, p]) => [n, { position: p }]));
  for (const [n, m] of Object.entries(markers)) row(`marker ${n}`, `(${m.position.map((v) => fmt(v)).join(", ")}) mm`);
  for (const [n, c] of Object.entries(a.cables || {})) row(`${c.kind} ${n}`, c.tension > 0 ? fmt(c.tension, 3) + " N" : "slack");
  for (const [n, p] of Object.entries(a.pins || {})) row(`pin ${n}`, `(${p.reaction.map((v) => fmt(v, 3)).join(", ")}) N`);
  for (const [n, g] of Object.entries(a.grounds || {})) row(`ground ${n}`, `(${g.force.map((v) => fmt(v, 3)).join(", ")}) N`);
  $("readouts").replaceChildren(html("table", {}, rows));
}

// The certificate of the state on screen: "converged" only when the server measured its residual at or below
// the batch tolerance on the design's own mesh; "preview" otherwise (a draft, or a solve still short of it).
function showCertificate(c) {
  const box = $("certificate"); if (!box) return;
  const state = c ? c.state : "preview";
  const ratio = c && c.ratio !== null && c.ratio !== undefined ? `|R| = ${fmt(c.ratio, 2)} × batch tolerance` : "";
  box.textContent = [state, c && c.why ? c.why : "", ratio].filter((t) => t).join(" · ");
  box.dataset.state = state;
  box.classList.toggle("converged", state === "converged");
  S.certificates.push({ state, ratio: c ? c.ratio : null });
  if (S.certificates.length > 20000) S.certificates.splice(0, 10000);
}

// -- errors at their element ------------------------------------------------------------------------------
function keyMatches(elKey, key) {
  if (!key || !elKey) return false;
  return elKey === key || key.startsWith(elKey + ".") || key.startsWith(elKey + "[") || elKey.startsWith(key + ".")
    || elKey.startsWith(key + "[");
}
function showError(message, key) {
  S.error = { message, key };
  $("error").hidden = false;
  $("error").textContent = message;
  markError();
}
function clearError() { S.error = null; $("error").hidden = true; markError(); }
function markError() {
  const layer = $("layer-error"); layer.textContent = "";
  for (const e of document.querySelectorAll(".bad")) e.classList.remove("bad");
  if (!S.error || !S.error.key) return;
  let box = null;
  for (const e of document.querySelectorAll("[data-key]")) {
    if (!keyMatches(e.dataset.key, S.error.key)) continue;
    e.classList.add("bad");
    if (e instanceof SVGGraphicsElement && !e.classList.contains("hit")) {
      const b = e.getBBox();
      if (b.width || b.height) box = box || b;
    }
  }
  if (box) {
    const text = S.error.message.split(": ").slice(1).join(": ") || S.error.message;
    const svg = $("view"), W = svg.clientWidth || 800, H = svg.clientHeight || 600;
    const t = el("text", { x: 0, y: 0, class: "error-label", "data-error-for": S.error.key }, layer);
    // words into lines of at most ~40 % of the view's width (7 px a character), the whole message kept
    const perLine = Math.max(20, Math.floor(0.4 * W / 7)), lines = [];
    for (const word of text.split(" ")) {
      const last = lines.length ? lines[lines.length - 1] : null;
      if (last !== null && (last + " " + word).length <= perLine) lines[lines.length - 1] = last + " " + word;
      else lines.push(word);
    }
    lines.forEach((line, i) => { const span = el("tspan", { x: 0, dy: i ? 14 : 0 }, t); span.textContent = line; });
    const b = t.getBBox();
    let x = box.x + box.width + 6;                          // right of the element, else left of it, inside the view
    if (x + b.width > W - 4) x = Math.max(4, box.x - 6 - b.width);
    const y = Math.min(Math.max(box.y + 12, 14), H - b.height + 8);
    t.setAttribute("transform", `translate(${x.toFixed(1)} ${y.toFixed(1)})`);
  }
}

// -- drawing -------------------------------------------------------------------------------------------------
function fit() {
  const svg = $("view"), W = svg.clientWidth || 800, H = svg.clientHeight || 600;
  const all = [];
  const d = S.design;
  if (d.body && d.body.outline) all.push(...d.body.outline);
  for (const b of d.bodies || []) if (b.outline) all.push(...b.outline);
  if (S.answer && S.answer.mesh && S.answer.mesh.dim === 2) all.push(...S.answer.mesh.y);
  for (const p of Object.values(d.markers || {})) all.push(p);
  if (!all.length) all.push([0, 0], [1, 1]);
  const xs = all.map((p) => p[0]), ys = all.map((p) => p[1]);
  let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 0.12 * Math.max(x1 - x0, y1 - y0, 1);
  x0 -= pad; x1 += pad; y0 -= pad; y1 += pad;
  const k = Math.min(W / (x1 - x0), H / (y1 - y0));
  S.view = { k, x0: (x0 + x1) / 2 - W / 2 / k, y0: (y0 + y1) / 2 + H / 2 / k };
  S.size = { W, H };
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  drawSketch();
  render();
}

function render() {
  const t0 = performance.now();
  if (S.dim !== 2) { draw3d(); return; }
  // the sketch (the design's handles) is drawn when the design or the view changes, not with every answer
  drawMesh(); drawCables(); drawContacts(); drawMarkers(); drawIK(); showStatus(); markError();
  S.renderMs.push(performance.now() - t0);
}

// The mesh on a canvas under the drawing, rasterised here into the canvas's pixels: a canvas path of many
// triangles costs Chromium's software canvas far more (one path of finger.toml's 1,356 triangles: 13 ms to fill,
// of 18,696: 1.7 s; one fill per triangle 4.5 ms and 78 ms), an SVG path of them 5-10 ms an answer.
// Each triangle is filled by its edge functions at pixel centres; where cells are a few pixels across or
// more, pixels within half a pixel of a cell's edge are darkened (the cell edges).
function drawMesh() {
  const cv = $("mesh2d"), ctx = cv.getContext("2d");
  const dpr = window.devicePixelRatio || 1;
  // the view's size as fit() read it (reading it here would lay the page out again with every answer)
  const W = Math.max(1, Math.round(S.size.W * dpr)), H = Math.max(1, Math.round(S.size.H * dpr));
  if (cv.width !== W || cv.height !== H || !S.pixels) {
    cv.width = W; cv.height = H;
    const img = ctx.createImageData(W, H);
    S.pixels = { img, buf: new Uint32Array(img.data.buffer) };
  }
  const { img, buf } = S.pixels;
  buf.fill(0);                                             // transparent: the page's white shows through
  const a = S.answer;
  if (!a || !a.mesh || !a.mesh.cells) { ctx.putImageData(img, 0, 0); S.meshDrawn = { cells: 0, fills: [] }; return; }
  const m = a.mesh, v = S.view, n = m.y.length, P = new Float64Array(2 * n), k = v.k * dpr;
  for (let i = 0; i < n; i++) { P[2 * i] = (m.y[i][0] - v.x0) * k; P[2 * i + 1] = (v.y0 - m.y[i][1]) * k; }
  const { fills, index } = cellColours(m);
  const C = S.drawCache.cells, nc = index.length;
  const edges = nc > 0 && Math.sqrt(Math.abs(areaOf(P, C)) / nc) > 4 * dpr;
  const rgba = fills.map((c) => packed(c, 1)), edged = fills.map((c) => packed(c, 0.65));
  const used = new Uint8Array(fills.length);
  for (let i = 0; i < nc; i++) {
    const j = index[i];
    used[j] = 1;
    triangle(buf, W, H, P, 2 * C[3 * i], 2 * C[3 * i + 1], 2 * C[3 * i + 2], rgba[j], edges ? edged[j] : 0);
  }
  ctx.putImageData(img, 0, 0);
  const shown = fills.filter((_, j) => used[j]);
  S.meshDrawn = { cells: nc, fills: shown, edges };
  cv.dataset.fills = shown.join(" ");
}

// The colour of every cell (an index into fills): by region, or by the field drawn; sets the legend.
function cellColours(m) {
  if (!S.drawCache || S.drawCache.topology !== m.topology)       // the cells as one typed array, once per mesh
    S.drawCache = { topology: m.topology, index: null, cells: Int32Array.from(m.cells.flat()) };
  const mode = $("colour").value;
  const f = mode === "region" || !m.fields ? null : m.fields[mode];
  if (!f) {
    if (S.legend !== m.topology) {                                 // the legend, once per mesh
      const kinds = new Set(Object.values(m.region_names).map(regionKind));
      $("legend").className = "regions";
      $("legend").replaceChildren(...["body", "bone", "object"].filter((x) => kinds.has(x))
        .flatMap((x) => [html("span", { className: `swatch ${x}` }), html("span", {}, [REGION_LABEL[x]])]));
      S.legend = m.topology;
    }
    if (!S.drawCache.index) {                                      // the region colours, once per mesh
      const names = Object.keys(REGION_FILL), at = {};
      for (const [tag, name] of Object.entries(m.region_names)) at[tag] = names.indexOf(regionKind(name));
      S.drawCache.index = Int32Array.from(m.regions, (r) => at[r]);
    }
    return { fills: Object.values(REGION_FILL), index: S.drawCache.index };
  }
  const vals = f.filter((x) => x !== null && Number.isFinite(x)).sort((p, q) => p - q);
  const lo = mode === "stretch" ? 1 : 0;
  let hi = vals.length ? vals[Math.min(vals.length - 1, Math.floor(0.98 * vals.length))] : 1;
  if (!(hi > lo)) hi = lo + 1e-9;
  $("legend").className = "bar";
  $("legend").replaceChildren(html("span", {}, [fmt(lo, 3)]), html("span", {}, [mode === "stretch" ? "stretch" : "ψ (N·mm/mm³)"]),
    html("span", {}, [`≥ ${fmt(hi, 3)}`]));
  S.legend = null;
  const index = new Int32Array(f.length);
  for (let i = 0; i < index.length; i++) {
    const x = f[i] === null ? hi : f[i];
    index[i] = Math.max(0, Math.min(PALETTE.length - 1, Math.round((x - lo) / (hi - lo) * (PALETTE.length - 1))));
  }
  return { fills: PALETTE, index };
}

// "#rrggbb" darkened by `shade` (1: as is; the cell edges' #7a6a66 at 0.35) as a pixel (RGBA bytes, little-endian).
function packed(hex, shade) {
  const c = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));
  const e = [0x7a, 0x6a, 0x66];
  const [r, g, b] = c.map((x, i) => Math.round(shade * x + (1 - shade) * e[i]));
  return ((255 << 24) | (b << 16) | (g << 8) | r) >>> 0;
}

// Fill the triangle (P[a], P[b], P[c]) (device pixels) into buf (W x H pixels); with `edge` non-zero, the pixels
// within half a pixel of its sides get that colour instead.
function triangle(buf, W, H, P, a, b, c, fill, edge) {
  const x0 = P[a], y0 = P[a + 1];
  let x1 = P[b], y1 = P[b + 1], x2 = P[c], y2 = P[c + 1];
  if ((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0) < 0) { x1 = P[c]; y1 = P[c + 1]; x2 = P[b]; y2 = P[b + 1]; }
  const xa = Math.max(0, Math.floor(Math.min(x0, x1, x2))), xb = Math.min(W - 1, Math.ceil(Math.max(x0, x1, x2)));
  const ya = Math.max(0, Math.floor(Math.min(y0, y1, y2))), yb = Math.min(H - 1, Math.ceil(Math.max(y0, y1, y2)));
  if (xa > xb || ya > yb) return;
  // edge functions e_i(x, y) >= 0 inside (y down: the orientation above makes all three positive inside)
  const A0 = y1 - y2, B0 = x2 - x1, A1 = y2 - y0, B1 = x0 - x2, A2 = y0 - y1, B2 = x1 - x0;
  const L0 = 1 / (Math.sqrt(A0 * A0 + B0 * B0) || 1), L1 = 1 / (Math.sqrt(A1 * A1 + B1 * B1) || 1),
    L2 = 1 / (Math.sqrt(A2 * A2 + B2 * B2) || 1);
  const px0 = xa + 0.5, py0 = ya + 0.5;
  let r0 = A0 * (px0 - x1) + B0 * (py0 - y1), r1 = A1 * (px0 - x2) + B1 * (py0 - y2), r2 = A2 * (px0 - x0) + B2 * (py0 - y0);
  for (let y = ya; y <= yb; y++) {
    let e0 = r0, e1 = r1, e2 = r2, row = y * W + xa;
    for (let x = xa; x <= xb; x++, row++) {
      if (e0 >= 0 && e1 >= 0 && e2 >= 0) {
        buf[row] = edge && (e0 * L0 < 0.6 || e1 * L1 < 0.6 || e2 * L2 < 0.6) ? edge : fill;
      }
      e0 += A0; e1 += A1; e2 += A2;
    }
    r0 += B0; r1 += B1; r2 += B2;
  }
}

// The deformed mesh's area on screen: the sum of its cells' areas (device pixels^2).
function areaOf(P, C) {
  let A = 0;
  for (let c = 0; c < C.length; c += 3) {
    const a = 2 * C[c], b = 2 * C[c + 1], d = 2 * C[c + 2];
    A += (P[b] - P[a]) * (P[d + 1] - P[a + 1]) - (P[d] - P[a]) * (P[b + 1] - P[a + 1]);
  }
  return 0.5 * A;
}

function regionKind(name) {
  return !name || name === "body" || name.startsWith("body:") ? "body" : name.startsWith("object:") ? "object" : "bone";
}

function drawContacts() {
  // the forces the other pieces exert on each object's (and each body's but the first) boundary nodes
  const layer = $("layer-contacts"); layer.textContent = "";
  const a = S.answer; if (!a || !a.mesh || !a.mesh.objects || !a.mesh.objects.length) return;
  let fmax = 0;
  for (const o of a.mesh.objects) for (const f of [...o.normal, ...o.friction]) fmax = Math.max(fmax, Math.hypot(f[0], f[1]));
  if (!(fmax > 0)) return;
  const scale = 36 / fmax;                        // px per N: the largest nodal force is 36 px long
  for (const o of a.mesh.objects) {
    for (const [kind, forces] of [["normal", o.normal], ["friction", o.friction]]) {
      forces.forEach((f, i) => {
        const n = Math.hypot(f[0], f[1]); if (!(n > 0.02 * fmax)) return;
        const q = px(o.points[i]);
        el("line", { x1: q[0], y1: q[1], x2: q[0] + scale * f[0], y2: q[1] - scale * f[1],
          class: `contact-force ${kind}`, "marker-end": `url(#arrow-${kind})`, "data-object": o.name }, layer);
      });
    }
  }
  const t = el("text", { x: 8, y: 16, class: "contact-legend" }, layer);
  t.textContent = `contact forces: normal (blue), friction (green); largest ${fmt(fmax, 3)} N`;
}

function drawCables() {
  const layer = $("layer-cables"); layer.textContent = "";
  const a = S.answer; if (!a || !a.mesh) return;
  for (const c of a.mesh.cables) {
    const cls = `${c.kind}${c.slack ? " slack" : ""}`;
    el("polyline", { points: pts(c.via), class: `cable-line ${cls}`, "data-cable": c.name }, layer);
    // its via points: dots (zero-length strokes with round caps) of one path, not an element each (at 20k cells
    // a drag's frame drew some 500 circles)
    const dots = c.via.map((p) => { const q = px(p); return `M${q[0].toFixed(1)} ${q[1].toFixed(1)}h0`; }).join("");
    el("path", { d: dots, class: `via ${c.kind}`, "data-cable": c.name, "data-count": c.via.length }, layer);
  }
  placeCableLabels(layer, a.mesh.cables);
}

function placeCableLabels(layer, cables) {
  // tendons first, then taut ligaments, then slack ones; each at the first of several spots along its cable
  // (right, then left of a via point, from the middle outwards) that overlaps no label placed before; a
  // label with no free spot is hidden (its cable's tension is in the panel too)
  const rank = (c) => (c.kind === "tendon" ? 0 : c.slack ? 2 : 1);
  const order = [...cables].sort((p, q) => rank(p) - rank(q));
  const placed = [];
  const hits = (b) => placed.some((o) => b.x < o.x + o.width + 2 && o.x < b.x + b.width + 2 &&
                                         b.y < o.y + o.height + 1 && o.y < b.y + b.height + 1);
  for (const c of order) {
    const t = el("text", { x: 0, y: 0, class: `tension ${c.kind}`, "data-tension": c.name }, layer);
    t.textContent = c.slack ? `${c.name}: slack` : `${c.name}: ${fmt(c.tension, 2)} N`;
    const n = c.via.length, mid = Math.floor(n / 2), spots = [];
    for (let k = 0; k < n; k++) {
      const i = mid + (k % 2 ? -1 : 1) * Math.ceil(k / 2);
      if (i >= 0 && i < n) spots.push(i);
    }
    let done = false;
    const w = textWidth(t.textContent);        // measured once, without a layout of the page (getBBox forces one)
    for (const i of spots.slice(0, 12)) {
      const q = px(c.via[i]);
      for (const side of [1, -1]) {
        const x = side > 0 ? q[0] + 6 : q[0] - 6;
        const b = { x: side > 0 ? x : x - w, y: q[1] - 12, width: w, height: 16 };   // as its halo draws
        if (hits(b)) continue;
        t.setAttribute("x", x); t.setAttribute("y", q[1]);
        t.setAttribute("text-anchor", side > 0 ? "start" : "end");
        placed.push(b); done = true; break;
      }
      if (done) break;
    }
    if (!done) t.setAttribute("visibility", "hidden");
  }
}

// The width of a cable label (class "tension": 11 px) in px, from a canvas's text metrics.
function textWidth(text) {
  if (!S.measure) {
    S.measure = document.createElement("canvas").getContext("2d");
    S.measure.font = `11px ${getComputedStyle(document.body).fontFamily}`;
  }
  return S.measure.measureText(text).width;
}

function polygonItem(layer, points, cls, key, path, minCount) {
  el("polygon", { points: pts(points), class: `sketch ${cls}`, "data-key": key }, layer);
  const hit = el("polygon", { points: pts(points), class: "hit", "data-key": key }, layer);
  hit.addEventListener("dblclick", (e) => insertVertex(e, path, true));
  handles(layer, points, cls, key, path, minCount);
  return hit;
}
function handles(layer, points, cls, key, path, minCount) {
  points.forEach((p, i) => {
    const q = px(p);
    const h = el("circle", { cx: q[0], cy: q[1], r: 5, class: `handle ${cls}`, "data-key": key,
      "data-path": JSON.stringify([...path, i]) }, layer);
    h.addEventListener("pointerdown", (e) => {
      if (e.button === 2 || e.altKey) { e.preventDefault(); removeVertex(path, i, minCount); return; }
      startDrag(e, h, [...path, i], "vertex");
    });
    h.addEventListener("contextmenu", (e) => e.preventDefault());
  });
}
function drawSketch() {
  const layer = $("layer-sketch"); layer.textContent = "";
  const d = S.design; if (!d || S.dim !== 2) return;
  for (const [i, pin] of (d.pins || []).entries()) {
    const [a, b] = [px(pin.region[0]), px(pin.region[1])];
    const r = el("rect", { x: Math.min(a[0], b[0]), y: Math.min(a[1], b[1]), width: Math.max(3, Math.abs(b[0] - a[0])),
      height: Math.max(3, Math.abs(b[1] - a[1])), class: "pin", "data-key": `pins.${pin.name}.region`,
      "data-path": JSON.stringify(["pins", i, "region"]) }, layer);
    r.addEventListener("pointerdown", (e) => startDrag(e, r, ["pins", i, "region"], "box"));
  }
  for (const g of d.grounds || []) {
    const t = [-g.normal[1], g.normal[0]], n = Math.hypot(...t) || 1, L = 1e4;
    const a = px([g.point[0] - L * t[0] / n, g.point[1] - L * t[1] / n]), b = px([g.point[0] + L * t[0] / n, g.point[1] + L * t[1] / n]);
    el("line", { x1: a[0], y1: a[1], x2: b[0], y2: b[1], class: "ground", "data-key": `grounds.${g.name}.point` }, layer);
  }
  if (d.body && d.body.outline) {
    polygonItem(layer, d.body.outline, "body", "body.outline", ["body", "outline"], 3);
    (d.body.holes || []).forEach((h, k) => polygonItem(layer, h, "body", `body.holes[${k}]`, ["body", "holes", k], 3));
  }
  (d.bodies || []).forEach((b, k) => {            // [[bodies]]: each body's outline and holes
    if (!b.outline) return;
    polygonItem(layer, b.outline, "body", `bodies.${b.name}.outline`, ["bodies", k, "outline"], 3);
    (b.holes || []).forEach((h, j) => polygonItem(layer, h, "body", `bodies.${b.name}.holes[${j}]`, ["bodies", k, "holes", j], 3));
  });
  (d.bones || []).forEach((b, k) => { if (b.outline) polygonItem(layer, b.outline, "bone", `bones.${b.name}.outline`, ["bones", k, "outline"], 3); });
  (d.objects || []).forEach((o, k) => {          // a free object: drag a vertex, or drag inside it to move it whole
    if (!o.outline) return;
    const hit = polygonItem(layer, o.outline, "object", `objects.${o.name}.outline`, ["objects", k, "outline"], 3);
    hit.classList.add("movable");
    hit.setAttribute("data-object", o.name);
    hit.addEventListener("pointerdown", (e) => startDrag(e, hit, ["objects", k, "outline"], "box"));
  });
  (d.cables || []).forEach((c, k) => {
    const key = `cables.${c.name}.path`;
    el("polyline", { points: pts(c.path), class: `sketch cable ${c.kind}`, "data-key": key }, layer);
    const hit = el("polyline", { points: pts(c.path), class: "hit", "data-key": key }, layer);
    hit.addEventListener("dblclick", (e) => insertVertex(e, ["cables", k, "path"], false));
    handles(layer, c.path, `cable ${c.kind}`, key, ["cables", k, "path"], 2);
  });
  (d.loads || []).forEach((ld, k) => {
    const a = px(ld.at), f = ld.force, n = Math.hypot(f[0], f[1]) || 1;
    el("line", { x1: a[0], y1: a[1], x2: a[0] + 40 * f[0] / n, y2: a[1] - 40 * f[1] / n, class: "load" }, layer);
    const h = el("circle", { cx: a[0], cy: a[1], r: 5, class: "handle", "data-key": `loads.${ld.name}.at`,
      "data-path": JSON.stringify(["loads", k, "at"]) }, layer);
    h.addEventListener("pointerdown", (e) => startDrag(e, h, ["loads", k, "at"], "point"));
  });
  (d.grounds || []).forEach((g, k) => {
    const a = px(g.point);
    const h = el("circle", { cx: a[0], cy: a[1], r: 5, class: "handle", "data-key": `grounds.${g.name}.point`,
      "data-path": JSON.stringify(["grounds", k, "point"]) }, layer);
    h.addEventListener("pointerdown", (e) => startDrag(e, h, ["grounds", k, "point"], "point"));
  });
  for (const [name, p] of Object.entries(d.markers || {})) {
    const a = px(p);
    const h = el("rect", { x: a[0] - 7, y: a[1] - 7, width: 14, height: 14, class: "handle marker", "data-key": `markers.${name}`,
      "data-path": JSON.stringify(["markers", name]) }, layer);
    h.addEventListener("pointerdown", (e) => startDrag(e, h, ["markers", name], "point"));
  }
  // every handle above every line and outline: a vertex under a cable's (wide, invisible) click line stays grabbable
  // markers (larger squares) below the vertices: a vertex under a marker (the tip on the outline's top) is
  // grabbed at its centre, the marker around it
  for (const h of [...layer.querySelectorAll(".handle.marker")]) layer.appendChild(h);
  for (const h of [...layer.querySelectorAll(".handle:not(.marker)")]) layer.appendChild(h);
}

function drawMarkers() {
  const layer = $("layer-markers"); layer.textContent = "";
  const a = S.answer; if (!a || !a.mesh) return;
  for (const [name, p] of Object.entries(a.mesh.markers)) {
    const q = px(p);
    el("circle", { cx: q[0], cy: q[1], r: 4, class: "marker-now", "data-marker": name }, layer);
    const t = el("text", { x: q[0] + 7, y: q[1] - 6, class: "marker-label" }, layer);
    t.textContent = `${name} (${fmt(p[0], 1)}, ${fmt(p[1], 1)})`;
  }
}

function drawIK() {
  const layer = $("layer-ik"); layer.textContent = "";
  const t = S.ik.target; if (!t || !S.ik.on) { $("ik-status").textContent = ""; return; }
  const q = px(t);
  el("path", { d: `M${q[0] - 8} ${q[1] - 8}L${q[0] + 8} ${q[1] + 8}M${q[0] - 8} ${q[1] + 8}L${q[0] + 8} ${q[1] - 8}`, class: "target", id: "ik-target" }, layer);
  const info = S.ik.info, s = $("ik-status");
  if (info) {
    s.className = info.reached ? "reached" : "unreached";
    s.textContent = info.reached ? `reached: ${fmt(info.error, 3)} mm from the target`
      : `unreachable: ${fmt(info.error, 2)} mm from the target (${info.status}); closest pose shown`;
  }
}

// -- dragging ---------------------------------------------------------------------------------------------------
function startDrag(e, handle, path, what) {
  if (S.readonly || e.button !== 0) return;
  e.preventDefault(); e.stopPropagation();
  $("view").setPointerCapture(e.pointerId);
  checkpoint();
  const start = toMM(e);
  S.drag = { path, what, start, orig: clone(getPath(S.design, path)), pointer: e.pointerId,
    kind: what === "vertex" ? "vertex" : "move" };
}
function onMove(e) {
  const g = S.drag; if (!g || e.pointerId !== g.pointer) return;
  const p = toMM(e);
  if (g.what === "ik") { S.ik.target = [snap(p[0]), snap(p[1])]; input("ik"); drawIK(); requestIK(false); return; }
  const dx = p[0] - g.start[0], dy = p[1] - g.start[1];
  if (g.what === "box") setPath(S.design, g.path, g.orig.map((c) => [snap(c[0] + dx), snap(c[1] + dy)]));
  else setPath(S.design, g.path, [snap(g.orig[0] + dx), snap(g.orig[1] + dy)]);
  changed(g.kind, true);
}
function onUp(e) {
  const g = S.drag; if (!g || e.pointerId !== g.pointer) return;
  S.drag = null;
  if (g.what === "ik") { input("ik-release"); requestIK(true); return; }
  changed("release", false);
}
function insertVertex(e, path, closed) {
  if (S.readonly) return;
  e.preventDefault();
  const p = toMM(e), list = getPath(S.design, path);
  let best = 0, bestD = Infinity;
  const n = closed ? list.length : list.length - 1;
  for (let i = 0; i < n; i++) {
    const a = list[i], b = list[(i + 1) % list.length];
    const t = Math.max(0, Math.min(1, ((p[0] - a[0]) * (b[0] - a[0]) + (p[1] - a[1]) * (b[1] - a[1])) /
      ((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2 || 1)));
    const dd = Math.hypot(a[0] + t * (b[0] - a[0]) - p[0], a[1] + t * (b[1] - a[1]) - p[1]);
    if (dd < bestD) { bestD = dd; best = i; }
  }
  checkpoint();
  list.splice(best + 1, 0, [snap(p[0]), snap(p[1])]);
  changed("add-vertex", false);
}
function removeVertex(path, i, minCount) {
  if (S.readonly) return;
  const list = getPath(S.design, path);
  if (list.length <= minCount) { showError(`a ${minCount === 2 ? "cable" : "polygon"} needs at least ${minCount} points`, ""); return; }
  checkpoint();
  list.splice(i, 1);
  changed("remove-vertex", false);
}

// -- Soft IK ---------------------------------------------------------------------------------------------------------
function requestIK(final) {
  if (!S.ik.marker || !S.ik.target) return;
  request({ kind: "ik", marker: S.ik.marker, target: S.ik.target, final });
}
function startIK(e) {
  if (!S.ik.on || S.readonly || e.button !== 0) return;
  e.preventDefault();
  $("view").setPointerCapture(e.pointerId);
  checkpoint();
  const p = toMM(e);
  S.ik.target = [snap(p[0]), snap(p[1])]; S.ik.info = null;
  S.drag = { what: "ik", pointer: e.pointerId };
  input("ik"); drawIK(); requestIK(false);
}

// -- 3D: editor3d.js (setup3d, draw3d, fit3d), loaded before this file ----------------------------------------

// -- saving -------------------------------------------------------------------------------------------------------------
async function save(name) {
  const body = { design: S.design };
  if (name) body.name = name;
  let r = await api("/api/save", body);
  if (r.status === 409 && name && confirm(`${name} exists. Replace it?`)) r = await api("/api/save", { ...body, overwrite: true });
  if (r.status === 200) {
    S.file = r.data.file; S.untitled = false; S.savedText = JSON.stringify(S.design); unsaved(); remember(true);
    setStatusNote(`saved ${r.data.file}`); S.saved = r.data;
  }
  else showError(r.data.error, r.data.key || "");
  return r;
}
function setStatusNote(text) { const s = $("status"); s.textContent = s.textContent.split("\n— ")[0] + `\n— ${text}`; }

// -- start ------------------------------------------------------------------------------------------------------------------
async function main() {
  const { status, data } = await api("/api/design");
  if (status !== 200) { setStatus(`cannot load the design: ${data.error}`, true); return; }
  S.design = data.design; S.file = data.file; S.dim = data.dim; S.readonly = data.readonly;
  S.savedText = JSON.stringify(data.saved || data.design);      // the file as on disk: unsaved changes differ
  if (data.first) { S.answer = data.first; if (data.first.mesh) whole(data.first); }
  if (S.dim !== 2) { setup3d(); draw3d(); S.ready = true; window.addEventListener("resize", draw3d); return; }
  S.restored = recall();            // unsaved edits of this file from before a reload
  buildPanel(); buttons();
  const svg = $("view");
  svg.addEventListener("pointermove", onMove);
  svg.addEventListener("pointerup", onUp);
  svg.addEventListener("pointercancel", onUp);
  svg.addEventListener("pointerdown", startIK);
  svg.addEventListener("contextmenu", (e) => e.preventDefault());
  $("undo").onclick = undo; $("redo").onclick = redo; $("fit").onclick = fit; $("revert").onclick = revert;
  $("save").onclick = () => {                // a new design is saved under a name first
    if (!S.untitled) { save(null); return; }
    const n = prompt("Save the new design as (a .toml name in the same folder):", "untitled.toml"); if (n) save(n);
  };
  $("new").onclick = newDesign;
  $("saveas").onclick = () => { const n = prompt("Save as (a .toml name in the same folder):", S.file); if (n) save(n); };
  $("colour").onchange = () => {            // frames carry the fields only while a field is drawn
    if ($("colour").value !== "region" && S.answer && S.answer.mesh && !S.answer.mesh.fields) request({ kind: "solve" });
    else drawMesh();
  };
  $("ik-on").onchange = () => { S.ik.on = $("ik-on").checked; S.ik.info = null; drawIK(); };
  $("ik-marker").onchange = () => { S.ik.marker = $("ik-marker").value; };
  meshField("mesh-size", "size", Number);
  meshField("mesh-degree", "degree", (v) => parseInt(v, 10));
  document.addEventListener("keydown", (e) => {
    // shortcuts work wherever focus is, except in a text or number field (its own undo edits its text)
    const typing = e.target.tagName === "INPUT" && e.target.type !== "range" && e.target.type !== "checkbox";
    if (!(e.ctrlKey || e.metaKey) || typing) return;
    if (e.target.type === "range") delete e.target.dataset.live;      // a slider drag in progress ends here
    if (e.key === "z" && !e.shiftKey) { e.preventDefault(); undo(); }
    else if (e.key === "y" || (e.key === "Z" && e.shiftKey) || (e.key === "z" && e.shiftKey)) { e.preventDefault(); redo(); }
  });
  window.addEventListener("resize", fit);
  window.addEventListener("pagehide", () => { if (S.rememberTimer) remember(true); });   // a reload keeps the last edit
  fit();
  S.ready = true;
  connect();
}
main();
