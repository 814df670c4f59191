// skelfem editor, 3D designs: the deformed surfaces on a canvas, the design (at rest) drawn over them with handles.
// Loaded before editor.js, whose state (S), requests, undo and saving it shares; plain JavaScript, no build step.
//
// Handles (drawn on the canvas; S.handles3d lists them with their pixel positions):
//   bone centre (square)        drag: move the bone in the view's plane          -> bones[k].move
//   bone arrows x / y / z       drag: move the bone along that axis               -> bones[k].move
//   bone rings x / y / z (dots) drag round the centre: turn the bone about that axis through its centre
//                                                                                  -> bones[k].rotate
//   markers, cable sketch points, load points: drag in the view's plane
//   pins (their box's centre), objects (their solids' centre): drag to move the whole box / object
// Anywhere else: drag to turn the view; the wheel zooms.
"use strict";

const V3 = { yaw: 0.6, pitch: -0.5, zoom: 1, frame: null, drag: null, M: null, k: 1, W: 0, H: 0 };
const AXES3 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
const AXIS_COLOUR = ["#c0392b", "#2e8b3e", "#1f5fbf"];
const HANDLE_PX = 9;                       // a press this close to a handle grabs it
const ANGLE_SNAP = 100;                    // angles are rounded to 0.01 degree, axes to 1e-4

// -- small 3-vector helpers --------------------------------------------------------------------------------------
const add3 = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub3 = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const mul3 = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
function matVec(R, v) { return [dot3(R[0], v), dot3(R[1], v), dot3(R[2], v)]; }
function matMul(A, B) { return A.map((row) => [0, 1, 2].map((j) => row[0] * B[0][j] + row[1] * B[1][j] + row[2] * B[2][j])); }
function rotation3(axis, degrees) {          // Rodrigues, as skelfem.design.pose.rotation
  const n = Math.hypot(...axis) || 1, a = axis.map((v) => v / n), t = degrees * Math.PI / 180;
  const c = Math.cos(t), s = Math.sin(t), C = 1 - c, [x, y, z] = a;
  return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
    [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
    [z * x * C - y * s, z * y * C + x * s, c + z * z * C]];
}
function axisAngle(R) {                      // [axis, degrees] of a rotation matrix
  const cos = Math.max(-1, Math.min(1, (R[0][0] + R[1][1] + R[2][2] - 1) / 2));
  const angle = Math.acos(cos) * 180 / Math.PI;
  let axis = [R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1]];
  const n = Math.hypot(...axis);
  if (n < 1e-9) {                            // 0 or 180 degrees: the axis from R + I's largest column
    if (angle < 90) return [[0, 0, 1], 0];
    const col = [0, 1, 2].map((j) => [R[0][j] + (j === 0), R[1][j] + (j === 1), R[2][j] + (j === 2)]);
    axis = col.reduce((p, q) => (Math.hypot(...q) > Math.hypot(...p) ? q : p));
  }
  const m = Math.hypot(...axis);
  return [axis.map((v) => v / m), angle];
}
const snapA = (v) => Math.round(v * ANGLE_SNAP) / ANGLE_SNAP;
const snapAxis = (v) => Math.round(v * 1e4) / 1e4;

// -- the view: a turntable projection, fitted once to the rest mesh (handles do not jump while dragging) ---------
function viewMatrix() {
  const cy = Math.cos(V3.yaw), sy = Math.sin(V3.yaw), cp = Math.cos(V3.pitch), sp = Math.sin(V3.pitch);
  return [[cy, 0, sy], [sp * sy, cp, -sp * cy], [-cp * sy, sp, cp * cy]];     // rows: screen x, screen y, depth
}
function frame3d() {
  const a = S.answer; if (!a || !a.mesh) return null;
  if (!V3.frame) {
    const x = a.mesh.x, lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (const p of x) for (let j = 0; j < 3; j++) { lo[j] = Math.min(lo[j], p[j]); hi[j] = Math.max(hi[j], p[j]); }
    V3.frame = { c: lo.map((v, j) => (v + hi[j]) / 2), size: Math.max(...hi.map((v, j) => v - lo[j])) };
  }
  return V3.frame;
}
function proj3(p) {                          // [screen x, screen y, depth] of a point in mm
  const f = V3.frame, M = V3.M, d = sub3(p, f.c);
  return [V3.W / 2 + V3.k * dot3(M[0], d), V3.H / 2 - V3.k * dot3(M[1], d), dot3(M[2], d)];
}
function screenToWorld(dx, dy) {             // a pixel move on screen as a move in mm in the view's plane
  const M = V3.M, vx = dx / V3.k, vy = -dy / V3.k;
  return [M[0][0] * vx + M[1][0] * vy, M[0][1] * vx + M[1][1] * vy, M[0][2] * vx + M[1][2] * vy];
}
function fit3d() { V3.frame = null; V3.zoom = 1; draw3d(); }

// -- the design's pieces at rest ------------------------------------------------------------------------------------
function primPoints(prim) {                  // corners of a primitive as written
  const [kind, p] = Object.entries(prim)[0];
  if (kind === "box") {
    const out = [];
    for (const x of [p.min[0], p.max[0]]) for (const y of [p.min[1], p.max[1]]) for (const z of [p.min[2], p.max[2]]) out.push([x, y, z]);
    return out;
  }
  if (kind === "cylinder") return [p.from, p.to];
  if (kind === "sphere") return [p.center.map((v) => v - p.radius), p.center.map((v) => v + p.radius)];
  return p.outline.flatMap(([x, y]) => [[x, y, p.z[0]], [x, y, p.z[1]]]);
}
function primEdges(prim) {                   // line segments drawing a primitive as written
  const [kind, p] = Object.entries(prim)[0];
  if (kind === "box") {
    const c = primPoints(prim), E = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
    return E.map(([i, j]) => [c[i], c[j]]);
  }
  if (kind === "cylinder") return [[p.from, p.to]];
  if (kind === "sphere") {
    const out = [];
    for (let i = 0; i < 24; i++) {
      const t0 = i * Math.PI / 12, t1 = (i + 1) * Math.PI / 12, r = p.radius, c = p.center;
      out.push([add3(c, [r * Math.cos(t0), r * Math.sin(t0), 0]), add3(c, [r * Math.cos(t1), r * Math.sin(t1), 0])]);
    }
    return out;
  }
  const n = p.outline.length, out = [];
  for (let i = 0; i < n; i++) {
    const a = p.outline[i], b = p.outline[(i + 1) % n];
    for (const z of p.z) out.push([[a[0], a[1], z], [b[0], b[1], z]]);
    out.push([[a[0], a[1], p.z[0]], [a[0], a[1], p.z[1]]]);
  }
  return out;
}
function boxCentre(points) {
  const lo = [0, 1, 2].map((j) => Math.min(...points.map((q) => q[j]))), hi = [0, 1, 2].map((j) => Math.max(...points.map((q) => q[j])));
  return lo.map((v, j) => snap((v + hi[j]) / 2));
}
function bonePose(b) {                       // {R, c, m}: x = c + m + R (X - c)
  const rot = b.rotate || null;
  const c = rot && rot.centre ? rot.centre : boxCentre((b.solids || []).flatMap(primPoints));
  return { R: rot ? rotation3(rot.axis || [0, 0, 1], rot.angle || 0) : rotation3([0, 0, 1], 0), c, m: b.move || [0, 0, 0] };
}
function placeBy(pose, X) { return add3(add3(pose.c, pose.m), matVec(pose.R, sub3(X, pose.c))); }

// -- drawing ---------------------------------------------------------------------------------------------------------
function draw3d() {
  const t0 = performance.now();
  const cv = $("view3d"), a = S.answer;
  const W = cv.clientWidth, H = cv.clientHeight;
  if (cv.width !== W || cv.height !== H) { cv.width = W; cv.height = H; }
  const ctx = cv.getContext("2d");
  ctx.clearRect(0, 0, W, H);
  showStatus();
  S.handles3d = [];
  const f = frame3d(); if (!f) return;
  V3.M = viewMatrix(); V3.W = W; V3.H = H; V3.k = V3.zoom * 0.8 * Math.min(W, H) / (f.size || 1);
  if (!drawSurfacesGL(ctx, a.mesh, W, H)) drawSurfaces(ctx, a.mesh);
  drawCables3d(ctx, a.mesh);
  if (!S.readonly) drawHandles3d(ctx, S.design);
  S.renderMs.push(performance.now() - t0);
}
function drawSurfaces(ctx, m) {
  const n = m.y.length, P = new Float64Array(3 * n);
  for (let i = 0; i < n; i++) { const q = proj3(m.y[i]); P[3 * i] = q[0]; P[3 * i + 1] = q[1]; P[3 * i + 2] = q[2]; }
  // no depth sort: only the faces towards the viewer are drawn, the opaque bones first and the translucent
  // body over them (a sort of 40k faces took a third of a 50k-DOF frame's drawing)
  const cells = m.cells;
  const groups = new Map();                  // fill colour -> path: one fill call per colour
  for (let i = 0; i < cells.length; i++) {
    const c = cells[i], x0 = P[3 * c[0]], y0 = P[3 * c[0] + 1], x1 = P[3 * c[1]], y1 = P[3 * c[1] + 1];
    const x2 = P[3 * c[2]], y2 = P[3 * c[2] + 1];
    const cross = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0);
    if (cross >= 0) continue;                // faces outward-ordered by the server: this one faces away
    const norm = Math.hypot(x1 - x0, y1 - y0) * Math.hypot(x2 - x0, y2 - y0) || 1;
    const shade = Math.round(10 * (0.55 + 0.45 * Math.min(1, Math.abs(cross) / norm))) / 10;
    const bone = m.regions[i] !== m.body_tag, kind = bone ? regionKind(m.region_names[m.regions[i]]) : "body";
    const key = `${kind}${shade}`;
    if (!groups.has(key)) groups.set(key, { bone, kind, shade, tris: [] });
    groups.get(key).tris.push(x0, y0, x1, y1, x2, y2);
  }
  // the opaque bones first, then the translucent body over them
  for (const g of [...groups.values()].sort((p, q) => q.bone - p.bone)) {
    const rgb = g.kind === "object" ? [185, 203, 228] : [232, 228, 216];    // objects in their colour, as in 2D
    ctx.fillStyle = g.bone ? `rgb(${Math.round(rgb[0] * g.shade)},${Math.round(rgb[1] * g.shade)},${Math.round(rgb[2] * g.shade)})`
      : `rgba(${Math.round(244 * g.shade)},${Math.round(182 * g.shade)},${Math.round(166 * g.shade)},0.35)`;
    ctx.beginPath();
    const t = g.tris;
    for (let i = 0; i < t.length; i += 6) { ctx.moveTo(t[i], t[i + 1]); ctx.lineTo(t[i + 2], t[i + 3]); ctx.lineTo(t[i + 4], t[i + 5]); ctx.closePath(); }
    ctx.fill();
  }
}
// -- the surfaces with WebGL where the browser has it (a GPU, or Chromium's software one): the page's canvas
// path filled 41k faces in 100-120 ms at 49k DOFs. The GL canvas is not in the page: each picture is copied onto
// the view's canvas, and the handles drawn over it. Cells and regions go to the GPU once per mesh, the deformed
// nodes (the surfaces' only) with every frame, into the same typed array.
const GL3 = { gl: null, failed: false, cells: null, groups: null, pos: null, n: 0 };
const GL3_VS = `#version 300 es
in vec3 p; uniform mat3 M; uniform vec3 c; uniform vec2 s; uniform float depth; out vec3 v;
void main() { v = M * (p - c); gl_Position = vec4(s.x * v.x, s.y * v.y, -v.z / depth, 1.0); }`;
const GL3_FS = `#version 300 es
precision highp float; in vec3 v; uniform vec4 colour; out vec4 o;
void main() { vec3 n = normalize(cross(dFdx(v), dFdy(v))); float shade = 0.55 + 0.45 * abs(n.z);
  o = vec4(colour.rgb * shade, colour.a); }`;
function gl3Init() {
  const cv = document.createElement("canvas");
  const gl = cv.getContext("webgl2", { antialias: false, stencil: true, depth: true, premultipliedAlpha: false,
    preserveDrawingBuffer: false });
  if (!gl) return null;
  const shader = (kind, src) => { const sh = gl.createShader(kind); gl.shaderSource(sh, src); gl.compileShader(sh); return sh; };
  const prog = gl.createProgram();
  gl.attachShader(prog, shader(gl.VERTEX_SHADER, GL3_VS)); gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, GL3_FS));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) return null;
  gl.useProgram(prog);
  const u = (n) => gl.getUniformLocation(prog, n);
  GL3.uni = { M: u("M"), c: u("c"), s: u("s"), depth: u("depth"), colour: u("colour") };
  GL3.buf = gl.createBuffer(); GL3.vao = gl.createVertexArray();
  gl.bindVertexArray(GL3.vao); gl.bindBuffer(gl.ARRAY_BUFFER, GL3.buf);
  const at = gl.getAttribLocation(prog, "p"); gl.enableVertexAttribArray(at); gl.vertexAttribPointer(at, 3, gl.FLOAT, false, 0, 0);
  gl.enable(gl.CULL_FACE); gl.cullFace(gl.BACK);            // outward-ordered faces: only those towards the viewer
  GL3.canvas = cv;
  return gl;
}
function gl3Mesh(gl, m) {                    // once per mesh: one index buffer per kind (bones, objects, body)
  for (const g of GL3.groups || []) gl.deleteBuffer(g.buf);
  const by = { bone: [], object: [], body: [] };
  for (let i = 0; i < m.cells.length; i++) {
    const kind = m.regions[i] === m.body_tag ? "body" : regionKind(m.region_names[m.regions[i]]) === "object" ? "object" : "bone";
    const c = m.cells[i]; by[kind].push(c[0], c[1], c[2]);
  }
  GL3.groups = Object.entries(by).filter(([, v]) => v.length).map(([kind, v]) => {
    const buf = gl.createBuffer(); gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, buf);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, Uint32Array.from(v), gl.STATIC_DRAW);
    return { kind, buf, count: v.length };
  });
  GL3.cells = m.cells; GL3.n = m.y.length; GL3.pos = new Float32Array(3 * GL3.n);
  gl.bindBuffer(gl.ARRAY_BUFFER, GL3.buf); gl.bufferData(gl.ARRAY_BUFFER, GL3.pos.byteLength, gl.DYNAMIC_DRAW);
}
function drawSurfacesGL(ctx, m, W, H) {      // false where WebGL is missing or lost: the canvas path draws
  if (GL3.failed) return false;
  let gl = GL3.gl;
  if (!gl || gl.isContextLost()) { gl = GL3.gl = gl3Init(); GL3.cells = null; if (!gl) { GL3.failed = true; return false; } }
  const cv = GL3.canvas;
  if (cv.width !== W || cv.height !== H) { cv.width = W; cv.height = H; }
  if (GL3.cells !== m.cells || GL3.n !== m.y.length) gl3Mesh(gl, m);
  const pos = GL3.pos, y = m.y;
  for (let i = 0, j = 0; i < y.length; i++, j += 3) { const q = y[i]; pos[j] = q[0]; pos[j + 1] = q[1]; pos[j + 2] = q[2]; }
  gl.bindBuffer(gl.ARRAY_BUFFER, GL3.buf); gl.bufferSubData(gl.ARRAY_BUFFER, 0, pos);
  gl.viewport(0, 0, W, H);
  gl.clearColor(1, 1, 1, 1); gl.clearStencil(0);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT | gl.STENCIL_BUFFER_BIT);
  const M = V3.M, f = V3.frame;                // GLSL's mat3 is column-major: the view's rows as its columns
  gl.uniformMatrix3fv(GL3.uni.M, false, [M[0][0], M[1][0], M[2][0], M[0][1], M[1][1], M[2][1], M[0][2], M[1][2], M[2][2]]);
  gl.uniform3fv(GL3.uni.c, f.c); gl.uniform2f(GL3.uni.s, 2 * V3.k / W, 2 * V3.k / H); gl.uniform1f(GL3.uni.depth, 2 * (f.size || 1));
  for (const g of GL3.groups) {              // the opaque bones and objects first, then the translucent body once
    const body = g.kind === "body";            // over each pixel (as the canvas fills one path per colour)
    if (body) {
      gl.disable(gl.DEPTH_TEST); gl.enable(gl.BLEND);
      gl.blendFuncSeparate(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA, gl.ZERO, gl.ONE);
      gl.enable(gl.STENCIL_TEST); gl.stencilFunc(gl.EQUAL, 0, 0xff); gl.stencilOp(gl.KEEP, gl.KEEP, gl.INCR);
      gl.uniform4f(GL3.uni.colour, 244 / 255, 182 / 255, 166 / 255, 0.35);
    } else {
      gl.enable(gl.DEPTH_TEST); gl.disable(gl.BLEND); gl.disable(gl.STENCIL_TEST);
      const rgb = g.kind === "object" ? [185, 203, 228] : [232, 228, 216];
      gl.uniform4f(GL3.uni.colour, rgb[0] / 255, rgb[1] / 255, rgb[2] / 255, 1);
    }
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, g.buf);
    gl.drawElements(gl.TRIANGLES, g.count, gl.UNSIGNED_INT, 0);
  }
  ctx.drawImage(cv, 0, 0);
  return true;
}
function drawCables3d(ctx, m) {
  for (const cb of m.cables) {
    ctx.strokeStyle = cb.kind === "tendon" ? "#1f5fbf" : "#d9822b"; ctx.lineWidth = cb.slack ? 1.5 : 3;
    ctx.setLineDash(cb.slack ? [3, 3] : []);
    ctx.beginPath(); cb.via.forEach((p, i) => { const q = proj3(p); if (i) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); }); ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.fillStyle = "#222"; ctx.font = "12px sans-serif";
  for (const [n, p] of Object.entries(m.markers)) { const q = proj3(p); ctx.beginPath(); ctx.arc(q[0], q[1], 4, 0, 7); ctx.fill(); ctx.fillText(n, q[0] + 6, q[1] - 6); }
}
function handle3d(ctx, h, shape, colour) {
  S.handles3d.push(h);
  ctx.fillStyle = colour; ctx.strokeStyle = "#222"; ctx.lineWidth = 1;
  ctx.beginPath();
  if (shape === "square") ctx.rect(h.x - 6, h.y - 6, 12, 12); else ctx.arc(h.x, h.y, 5, 0, 7);
  ctx.fill(); ctx.stroke();
}
function line3d(ctx, a, b, colour, width, dash) {
  const p = proj3(a), q = proj3(b);
  ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.setLineDash(dash || []);
  ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke(); ctx.setLineDash([]);
}
function drawHandles3d(ctx, d) {
  const L = 0.12 * V3.frame.size;
  (d.bones || []).forEach((b, k) => {
    if (!b.solids) return;
    const pose = bonePose(b), P = add3(pose.c, pose.m);
    for (const prim of b.solids) for (const [u, v] of primEdges(prim)) line3d(ctx, placeBy(pose, u), placeBy(pose, v), "#6b5e3c", 1.2);
    const at = proj3(P);
    handle3d(ctx, { kind: "bone-move", bone: k, name: b.name, x: at[0], y: at[1] }, "square", "#e8e4d8");
    AXES3.forEach((e, i) => {
      const tip = add3(P, mul3(e, L)), q = proj3(tip);
      line3d(ctx, P, tip, AXIS_COLOUR[i], 2);
      handle3d(ctx, { kind: "bone-axis", bone: k, name: b.name, axis: i, x: q[0], y: q[1] }, "dot", AXIS_COLOUR[i]);
      // the ring of turns about axis i: a dot on it, a quarter turn from the arrows
      const ring = add3(P, mul3(AXES3[(i + 1) % 3], 0.75 * L)), r = proj3(ring);
      ctx.strokeStyle = AXIS_COLOUR[i]; ctx.lineWidth = 1; ctx.setLineDash([2, 2]);
      ctx.beginPath();
      for (let s = 0; s <= 32; s++) {
        const t = s * Math.PI / 16, u = AXES3[(i + 1) % 3], v = AXES3[(i + 2) % 3];
        const p = proj3(add3(P, add3(mul3(u, 0.75 * L * Math.cos(t)), mul3(v, 0.75 * L * Math.sin(t)))));
        if (s) ctx.lineTo(p[0], p[1]); else ctx.moveTo(p[0], p[1]);
      }
      ctx.stroke(); ctx.setLineDash([]);
      handle3d(ctx, { kind: "bone-turn", bone: k, name: b.name, axis: i, x: r[0], y: r[1] }, "dot", "#fff");
    });
  });
  (d.cables || []).forEach((c, k) => {
    c.path.forEach((p, i) => { if (i) line3d(ctx, c.path[i - 1], p, c.kind === "tendon" ? "#1f5fbf" : "#d9822b", 1, [4, 3]); });
    c.path.forEach((p, i) => { const q = proj3(p); handle3d(ctx, { kind: "point", path: ["cables", k, "path", i], x: q[0], y: q[1] }, "dot", "#fff"); });
  });
  (d.pins || []).forEach((pin, k) => {
    const q = proj3(pin.region[0].map((v, j) => (v + pin.region[1][j]) / 2));
    handle3d(ctx, { kind: "pin", path: ["pins", k, "region"], x: q[0], y: q[1] }, "square", "#bbb");
  });
  (d.objects || []).forEach((o, k) => {
    if (!o.solids) return;
    const q = proj3(boxCentre(o.solids.flatMap(primPoints)));
    handle3d(ctx, { kind: "object", path: ["objects", k, "solids"], x: q[0], y: q[1] }, "square", "#b9cbe4");
  });
  (d.loads || []).forEach((ld, k) => { const q = proj3(ld.at); handle3d(ctx, { kind: "point", path: ["loads", k, "at"], x: q[0], y: q[1] }, "dot", "#8b1a1a"); });
  for (const name of Object.keys(d.markers || {})) {
    const q = proj3(d.markers[name]);
    handle3d(ctx, { kind: "point", path: ["markers", name], x: q[0], y: q[1] }, "square", "#fff");
  }
}

// -- dragging ---------------------------------------------------------------------------------------------------------
function pick3d(x, y) {
  let best = null, bestD = HANDLE_PX;
  for (const h of S.handles3d || []) { const dd = Math.hypot(h.x - x, h.y - y); if (dd <= bestD) { best = h; bestD = dd; } }
  return best;
}
function movePrim(prim, d) {                 // a primitive moved by d (mm)
  const [kind, p] = Object.entries(prim)[0], q = clone(p), mv = (v) => add3(v, d).map(snap);
  if (kind === "box") { q.min = mv(p.min); q.max = mv(p.max); }
  else if (kind === "cylinder") { q.from = mv(p.from); q.to = mv(p.to); }
  else if (kind === "sphere") q.center = mv(p.center);
  else { q.outline = p.outline.map(([x, y]) => [snap(x + d[0]), snap(y + d[1])]); q.z = p.z.map((z) => snap(z + d[2])); }
  return { [kind]: q };
}
function start3dDrag(e, h) {
  checkpoint();
  const g = { h, x0: e.offsetX, y0: e.offsetY, pointer: e.pointerId };
  if (h.kind.startsWith("bone")) {
    const b = S.design.bones[h.bone], pose = bonePose(b);
    g.pose = pose; g.P = proj3(add3(pose.c, pose.m));
    g.kind = h.kind === "bone-turn" ? "bone-turn" : "bone-move";
  } else {
    g.orig = clone(getPath(S.design, h.path)); g.kind = h.kind === "point" ? "point-move" : `${h.kind}-move`;
  }
  V3.drag = g;
}
function on3dMove(e) {
  const g = V3.drag; if (!g || e.pointerId !== g.pointer) return;
  const dx = e.offsetX - g.x0, dy = e.offsetY - g.y0;
  if (g.view) { V3.yaw = g.yaw + dx * 0.01; V3.pitch = g.pitch + dy * 0.01; draw3d(); return; }
  const h = g.h;
  if (g.kind === "bone-move" || g.kind === "bone-turn") {
    const b = S.design.bones[h.bone];
    if (g.kind === "bone-turn") {
      const a0 = Math.atan2(-(g.y0 - g.P[1]), g.x0 - g.P[0]), a1 = Math.atan2(-(e.offsetY - g.P[1]), e.offsetX - g.P[0]);
      const facing = Math.sign(dot3(V3.M[2], AXES3[h.axis])) || 1;
      const turn = rotation3(AXES3[h.axis], (a1 - a0) * 180 / Math.PI * facing);
      const [axis, angle] = axisAngle(matMul(turn, g.pose.R));
      b.rotate = { angle: snapA(angle), axis: axis.map(snapAxis), centre: g.pose.c };
      if (!b.move) b.move = [0, 0, 0];
    } else {
      let d;
      if (h.kind === "bone-axis") {           // along the arrow: the pointer's move projected on the arrow's screen direction
        const e3 = AXES3[h.axis], s = sub3(proj3(add3(g.pose.c, e3)), proj3(g.pose.c)), n2 = s[0] * s[0] + s[1] * s[1];
        d = n2 > 1e-9 ? mul3(e3, (dx * s[0] + dy * s[1]) / n2) : [0, 0, 0];
      } else d = screenToWorld(dx, dy);
      b.move = add3(g.pose.m, d).map(snap);
      if (!b.rotate) b.rotate = { angle: 0, axis: [0, 0, 1], centre: g.pose.c };
    }
    changed(g.kind === "bone-turn" ? "bone-turn" : "bone-move", true);
    return;
  }
  const d = screenToWorld(dx, dy);
  if (h.kind === "point") setPath(S.design, h.path, add3(g.orig, d).map(snap));
  else if (h.kind === "pin") setPath(S.design, h.path, g.orig.map((c) => add3(c, d).map(snap)));
  else if (h.kind === "object") setPath(S.design, h.path, g.orig.map((prim) => movePrim(prim, d)));
  changed(g.kind, true);
}
function on3dUp(e) {
  const g = V3.drag; if (!g || e.pointerId !== g.pointer) return;
  V3.drag = null;
  if (!g.view) changed("release", false);
}
// main() (editor.js) calls this for a 3D design, then draws: the page's panel, buttons and keys as in 2D, the canvas
function setup3d() {
  $("view").hidden = true; const cv = $("view3d"); cv.hidden = false;
  if ($("mesh2d")) $("mesh2d").hidden = true;
  $("new").hidden = true;                  // the template is a 2D design
  S.restored = recall();                   // unsaved edits of this file from before a reload
  buildPanel(); buttons();
  $("undo").onclick = undo; $("redo").onclick = redo; $("fit").onclick = fit3d; $("revert").onclick = revert;
  $("save").onclick = () => save(null);
  $("saveas").onclick = () => { const n = prompt("Save as (a .toml name in the same folder):", S.file); if (n) save(n); };
  meshField("mesh-size", "size", Number);
  meshField("mesh-degree", "degree", (v) => parseInt(v, 10));
  document.addEventListener("keydown", (e) => {     // as in 2D: Ctrl+Z / Ctrl+Y outside a text or number field
    const typing = e.target.tagName === "INPUT" && e.target.type !== "range" && e.target.type !== "checkbox";
    if (!(e.ctrlKey || e.metaKey) || typing) return;
    if (e.target.type === "range") delete e.target.dataset.live;
    if (e.key === "z" && !e.shiftKey) { e.preventDefault(); undo(); }
    else if (e.key === "y" || (e.key === "Z" && e.shiftKey) || (e.key === "z" && e.shiftKey)) { e.preventDefault(); redo(); }
  });
  window.addEventListener("pagehide", () => { if (S.rememberTimer) remember(true); });
  for (const id of ["colour", "legend", "ik-tools"]) { const x = $(id); if (x) (x.closest("label") || x).style.display = "none"; }
  const help = $("help"); if (help) help.querySelector("ul").replaceChildren(
    html("li", {}, ["Bones: drag the square to move a bone in the view's plane, an arrow's dot to move it along that axis, a ring's white dot to turn it about that axis through its centre."]),
    html("li", {}, ["Markers, cable sketch points and load points: drag them in the view's plane; pins and objects: drag their square to move them whole."]),
    html("li", {}, ["Elsewhere: drag to turn the view, the wheel zooms; Fit resets it. While you drag, the mesh's nodes follow the bone; a new mesh follows when you let go."]));
  cv.addEventListener("pointerdown", (e) => {
    if (e.button !== 0) return;
    cv.setPointerCapture(e.pointerId);
    const h = S.readonly ? null : pick3d(e.offsetX, e.offsetY);
    if (h) { e.preventDefault(); start3dDrag(e, h); return; }
    V3.drag = { view: true, x0: e.offsetX, y0: e.offsetY, yaw: V3.yaw, pitch: V3.pitch, pointer: e.pointerId };
  });
  cv.addEventListener("pointermove", on3dMove);
  cv.addEventListener("pointerup", on3dUp);
  cv.addEventListener("pointercancel", on3dUp);
  cv.addEventListener("wheel", (e) => { e.preventDefault(); V3.zoom *= Math.exp(-0.001 * e.deltaY); draw3d(); }, { passive: false });
  connect();
}
