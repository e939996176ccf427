// coartic view: plays the face (.glb, morph-target weights animation) with its WAV and the channels.
// A minimal WebGL2 renderer written for this one mesh: no library, nothing fetched from the network.
// Data come from the page: window.COARTIC = {glb: base64, channels: {...}, segments: [...], audio, fps, name}.
"use strict";

function decodeBase64(b64) {
  const bin = atob(b64);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out.buffer;
}

// --- glTF 2.0 binary: the parts of the format this face uses -------------------------------------
const TYPES = {SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4};
const ARRAYS = {5121: Uint8Array, 5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array};

function parseGlb(buffer) {
  const dv = new DataView(buffer);
  if (dv.getUint32(0, true) !== 0x46546c67 || dv.getUint32(4, true) !== 2) throw new Error("not a glTF 2.0 binary");
  const jsonLen = dv.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 20, jsonLen)));
  const binStart = 20 + jsonLen + 8;
  const binLen = dv.getUint32(20 + jsonLen, true);
  const bin = buffer.slice(binStart, binStart + binLen);
  function accessor(i) {
    const a = json.accessors[i];
    const nc = TYPES[a.type];
    const Arr = ARRAYS[a.componentType];
    let out;
    if (a.bufferView === undefined) out = new Arr(a.count * nc);  // glTF: no bufferView means zeros
    else {
      const v = json.bufferViews[a.bufferView];
      out = new Arr(bin, (v.byteOffset || 0) + (a.byteOffset || 0), a.count * nc);
    }
    if (a.sparse) {  // the morph targets are sparse: only the vertices they move
      const s = a.sparse, iv = json.bufferViews[s.indices.bufferView], vv = json.bufferViews[s.values.bufferView];
      const idx = new ARRAYS[s.indices.componentType](bin, (iv.byteOffset || 0) + (s.indices.byteOffset || 0), s.count);
      const vals = new Arr(bin, (vv.byteOffset || 0) + (s.values.byteOffset || 0), s.count * nc);
      out = Arr.from(out);
      for (let j = 0; j < s.count; j++) for (let c = 0; c < nc; c++) out[idx[j] * nc + c] = vals[j * nc + c];
    }
    return out;
  }
  return {json, accessor};
}

// One vertex array for all primitives (parts) of every mesh, base positions, colours, triangles,
// morph targets, and the weights animation. The FAP and ARKit morph sets are one mesh; the set for
// three.js up to r132 (--gltf-morphs eight) is several, each with at most 8 targets of its own
// vertices and its own weights channel: a target is kept with where its mesh's vertices start.
function loadFace(buffer) {
  const {json, accessor} = parseGlb(buffer);
  const anim = (json.animations || [])[0];
  let nVerts = 0;
  for (const mesh of json.meshes) for (const p of mesh.primitives) nVerts += json.accessors[p.attributes.POSITION].count;
  const base = new Float32Array(nVerts * 3);
  const color = new Float32Array(nVerts * 3).fill(0.8);
  const targets = [], starts = [], names = [], channels = [];
  const indices = [];
  const same = new Map();  // a face vertex -> its copies in several meshes (the skin's seam)
  let offset = 0;
  json.nodes.forEach((node, n) => {
    if (node.mesh === undefined) return;
    const mesh = json.meshes[node.mesh];
    const nt = mesh.primitives[0].targets ? mesh.primitives[0].targets.length : 0;
    let meshVerts = 0;
    for (const p of mesh.primitives) meshVerts += json.accessors[p.attributes.POSITION].count;
    const own = [];
    for (let k = 0; k < nt; k++) own.push(new Float32Array(meshVerts * 3));
    const first = offset;
    for (const p of mesh.primitives) {
      const pos = accessor(p.attributes.POSITION);
      base.set(pos, offset * 3);
      if (p.attributes.COLOR_0 !== undefined) {
        const c = accessor(p.attributes.COLOR_0);
        const nc = TYPES[json.accessors[p.attributes.COLOR_0].type];
        for (let i = 0; i < pos.length / 3; i++) for (let j = 0; j < 3; j++) color[(offset + i) * 3 + j] = c[i * nc + j];
      }
      for (let k = 0; k < nt; k++) own[k].set(accessor(p.targets[k].POSITION), (offset - first) * 3);
      if (p.attributes._VERTEX !== undefined) {  // the face's vertex numbers (the eight-target set)
        const ids = accessor(p.attributes._VERTEX);
        for (let i = 0; i < ids.length; i++) {
          const copies = same.get(ids[i]) || [];
          copies.push(offset + i);
          same.set(ids[i], copies);
        }
      }
      const idx = accessor(p.indices);
      for (let i = 0; i < idx.length; i++) indices.push(idx[i] + offset);
      offset += pos.length / 3;
    }
    if (nt === 0) return;
    const ch = anim && anim.channels.find(c => c.target.path === "weights" && c.target.node === n);
    if (!ch) return;  // targets that nothing animates stay at rest
    const sampler = anim.samplers[ch.sampler];
    channels.push({times: accessor(sampler.input), weights: accessor(sampler.output), nt, first: targets.length});
    for (let k = 0; k < nt; k++) { targets.push(own[k]); starts.push(first * 3); }
    const meshNames = (mesh.extras && mesh.extras.targetNames) || [];
    for (let k = 0; k < nt; k++) names.push(meshNames[k] || `${mesh.name || node.mesh}.${k}`);
  });
  // one weights table (keys x all targets): coartic writes every channel at the same key times
  const nTargets = targets.length;
  const times = channels.length ? channels[0].times : new Float32Array([0]);
  for (const c of channels) {
    if (c.times.length !== times.length || c.times.some((t, i) => t !== times[i])) {
      throw new Error("the weights channels of this glTF have different key times");
    }
  }
  const weights = new Float32Array(times.length * nTargets);
  for (const c of channels) {
    for (let i = 0; i < times.length; i++) for (let k = 0; k < c.nt; k++) weights[i * nTargets + c.first + k] = c.weights[i * c.nt + k];
  }
  const welds = [...same.values()].filter(c => c.length > 1);
  return {base, color, targets, starts, indices: new Uint32Array(indices), times, weights, nTargets,
          names, welds, extras: json.asset.extras || {}};
}

// Weights at time t: linear between keys, held outside (glTF LINEAR sampler).
function weightsAt(face, t) {
  const {times, weights, nTargets} = face;
  const n = times.length;
  const w = new Float32Array(nTargets);
  let i = 0;
  if (t <= times[0]) i = 0;
  else if (t >= times[n - 1]) i = n - 1;
  else {
    let lo = 0, hi = n - 1;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (times[mid] <= t) lo = mid; else hi = mid; }
    const f = (t - times[lo]) / (times[hi] - times[lo]);
    for (let k = 0; k < nTargets; k++) w[k] = (1 - f) * weights[lo * nTargets + k] + f * weights[hi * nTargets + k];
    return w;
  }
  for (let k = 0; k < nTargets; k++) w[k] = weights[i * nTargets + k];
  return w;
}

// --- rendering -------------------------------------------------------------------------------------
const VS = `#version 300 es
in vec3 position; in vec3 color; in vec3 normal;
uniform mat4 mvp; out vec3 vPos; out vec3 vColor; out vec3 vNormal;
void main() { vPos = position; vColor = color; vNormal = normal; gl_Position = mvp * vec4(position, 1.0); }`;
// Smooth shading: vertex normals of the morphed face (recomputed every frame), turned towards the
// eye where a surface is seen from behind (the mouth's inside).
const FS = `#version 300 es
precision highp float;
in vec3 vPos; in vec3 vColor; in vec3 vNormal; uniform vec3 eye; uniform float section; out vec4 outColor;
void main() {
  if (section > 0.0 && vPos.x > 0.0) discard;  // the midsagittal section: the face's left half cut away
  vec3 n = normalize(vNormal);
  vec3 flat_n = normalize(cross(dFdx(vPos), dFdy(vPos)));
  if (dot(flat_n, eye - vPos) < 0.0) flat_n = -flat_n;
  if (dot(n, flat_n) < 0.0) n = -n;
  vec3 key = normalize(vec3(0.55, 0.65, 0.75)), fill = normalize(vec3(-0.7, 0.0, 0.5));
  float light = 0.22 + 0.78 * max(dot(n, key), 0.0) + 0.2 * max(dot(n, fill), 0.0);
  outColor = vec4(pow(vColor * light, vec3(1.0 / 2.2)), 1.0);
}`;

function compile(gl, type, src) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}

function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function lookAt(eye, at, up) {
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const norm = a => { const l = Math.hypot(a[0], a[1], a[2]); return [a[0] / l, a[1] / l, a[2] / l]; };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = norm(sub(eye, at)), x = norm(cross(up, z)), y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
}
function multiply(a, b) {  // column-major 4x4: a * b
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
  return o;
}

// Area-weighted vertex normals of the triangles as they are now (out: zeroed and filled); the
// mesh's triangles are wound alike (coartic.face.mesh.orient), so the normals agree.
function vertexNormals(p, indices, out) {
  out.fill(0);
  for (let t = 0; t < indices.length; t += 3) {
    const a = 3 * indices[t], b = 3 * indices[t + 1], c = 3 * indices[t + 2];
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    for (const i of [a, b, c]) { out[i] += nx; out[i + 1] += ny; out[i + 2] += nz; }
  }
}

class FaceView {
  constructor(canvas, face) {
    this.canvas = canvas;
    this.face = face;
    const gl = canvas.getContext("webgl2", {antialias: true, preserveDrawingBuffer: true});
    if (!gl) throw new Error("this browser has no WebGL2");
    this.gl = gl;
    const prog = gl.createProgram();
    gl.attachShader(prog, compile(gl, gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, compile(gl, gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
    this.prog = prog;
    this.positions = new Float32Array(face.base);
    this.posBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.posBuf);
    gl.bufferData(gl.ARRAY_BUFFER, this.positions, gl.DYNAMIC_DRAW);
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    const locPos = gl.getAttribLocation(prog, "position");
    gl.enableVertexAttribArray(locPos);
    gl.vertexAttribPointer(locPos, 3, gl.FLOAT, false, 0, 0);
    const colBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, colBuf);
    gl.bufferData(gl.ARRAY_BUFFER, face.color, gl.STATIC_DRAW);
    const locCol = gl.getAttribLocation(prog, "color");
    gl.enableVertexAttribArray(locCol);
    gl.vertexAttribPointer(locCol, 3, gl.FLOAT, false, 0, 0);
    this.normals = new Float32Array(face.base.length);
    this.normBuf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.normBuf);
    gl.bufferData(gl.ARRAY_BUFFER, this.normals, gl.DYNAMIC_DRAW);
    const locNorm = gl.getAttribLocation(prog, "normal");
    gl.enableVertexAttribArray(locNorm);
    gl.vertexAttribPointer(locNorm, 3, gl.FLOAT, false, 0, 0);
    const idxBuf = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, idxBuf);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, face.indices, gl.STATIC_DRAW);
    this.yaw = 0.0;
    this.pitch = 0.08;
    this.zoom = 1.0;
    this.section = false;
  }
  draw(t) {
    const {gl, face} = this;
    const w = weightsAt(face, t);
    const p = this.positions;
    p.set(face.base);
    for (let k = 0; k < face.nTargets; k++) {
      const wk = w[k];
      if (wk === 0) continue;
      const d = face.targets[k], s = face.starts[k];
      for (let i = 0; i < d.length; i++) p[s + i] += wk * d[i];
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, this.posBuf);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, p);
    vertexNormals(p, face.indices, this.normals);
    // a vertex that two meshes share is one point of the surface: the sum of both fans' normals
    for (const copies of face.welds) {
      for (let j = 0; j < 3; j++) {
        let sum = 0;
        for (const v of copies) sum += this.normals[3 * v + j];
        for (const v of copies) this.normals[3 * v + j] = sum;
      }
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, this.normBuf);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, this.normals);
    const width = this.canvas.width, height = this.canvas.height;
    gl.viewport(0, 0, width, height);
    gl.clearColor(0.93, 0.94, 0.96, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.prog);
    const dist = 0.5 / this.zoom, at = [0, 0.0, 0.07];
    const eye = [at[0] + dist * Math.sin(this.yaw) * Math.cos(this.pitch), at[1] + dist * Math.sin(this.pitch),
                 at[2] + dist * Math.cos(this.yaw) * Math.cos(this.pitch)];
    const mvp = multiply(perspective(0.52, width / height, 0.05, 2.0), lookAt(eye, at, [0, 1, 0]));
    gl.uniformMatrix4fv(gl.getUniformLocation(this.prog, "mvp"), false, mvp);
    gl.uniform3fv(gl.getUniformLocation(this.prog, "eye"), eye);
    gl.uniform1f(gl.getUniformLocation(this.prog, "section"), this.section ? 1.0 : 0.0);
    gl.bindVertexArray(this.vao);
    gl.drawElements(gl.TRIANGLES, face.indices.length, gl.UNSIGNED_INT, 0);
  }
}

// --- the channels plot -----------------------------------------------------------------------------
const CH_COLORS = {ULO: "#1f77b4", LLO: "#2ca02c", ULP: "#9467bd", LLP: "#8c564b", LR: "#e377c2", JO: "#7f7f7f",
                   TTH: "#d62728", TTA: "#ff7f0e", TBH: "#17becf", TBA: "#bcbd22"};
const PLOT = {left: 44, right: 8, top: 8, bottom: 34};
// Fewer pixels a second than this and the phoneme labels of ordinary speech (~12 a second) crowd
// into a band: a longer utterance scrolls under a fixed window instead.
const MIN_PX_PER_S = 110;

// Where the phoneme labels go: in two staggered rows, each label where it does not overlap the one
// before it in its row, else left out (its boundary line stays). `width(text)` measures a label.
function layoutLabels(segments, X, width) {
  const ends = [-Infinity, -Infinity], placed = [];
  let omitted = 0;
  for (const seg of segments) {
    if (seg[2] === "#") continue;
    const w = width(seg[2]), x = X((seg[0] + seg[1]) / 2) - w / 2;
    const row = ends[0] <= ends[1] ? 0 : 1;
    const use = x >= ends[row] + 2 ? row : (x >= ends[1 - row] + 2 ? 1 - row : -1);
    if (use < 0) { omitted++; continue; }
    ends[use] = x + w;
    placed.push({text: seg[2], x, w, row: use});
  }
  return {placed, omitted};
}

// The plot's time axis: the whole utterance if it fits at MIN_PX_PER_S, else a window that scrolls.
function plotScale(W, duration) {
  const inner = W - PLOT.left - PLOT.right;
  const pxPerS = Math.max(inner / duration, MIN_PX_PER_S);
  return {pxPerS, window: inner / pxPerS, scrolls: inner / duration < MIN_PX_PER_S};
}

// The curves and labels are drawn once into a hidden canvas as wide as the utterance needs; each
// frame copies the part around the cursor and adds the cursor, so playing stays cheap.
let plotCache = null;

function plotStart(scale, duration, t) {  // first second shown: the cursor a third of the way in
  return scale.scrolls ? Math.max(0, Math.min(duration - scale.window, t - scale.window / 3)) : 0;
}

function drawPlot(canvas, data, t) {
  const W = canvas.width, H = canvas.height;
  const scale = plotScale(W, data.duration);
  if (!plotCache || plotCache.key !== `${W}x${H}`) {
    const c = document.createElement("canvas");
    c.width = Math.min(32000, Math.ceil(PLOT.left + data.duration * scale.pxPerS + PLOT.right));
    c.height = H;
    const info = drawCurves(c, data, scale.pxPerS);
    plotCache = {canvas: c, key: `${W}x${H}`, info};
    // what was drawn where, for the tests: [x, width, row] of each label, and how many were left out
    document.body.dataset.labels = JSON.stringify(info.placed.map(l => [Math.round(l.x * 10) / 10, Math.round(l.w * 10) / 10, l.row]));
    document.body.dataset.labelsOmitted = String(info.omitted);
  }
  const t0 = plotStart(scale, data.duration, t);
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = "#ffffff";
  ctx.fillRect(0, 0, W, H);
  const sx = Math.round(t0 * scale.pxPerS);
  ctx.drawImage(plotCache.canvas, PLOT.left + sx, 0, W - PLOT.left, H, PLOT.left, 0, W - PLOT.left, H);
  ctx.drawImage(plotCache.canvas, 0, 0, PLOT.left, H, 0, 0, PLOT.left, H);  // the channel names
  const x = PLOT.left + t * scale.pxPerS - sx;  // where the cache drew time t, shifted like the copy
  ctx.strokeStyle = "#d62728";  // cursor
  ctx.lineWidth = 2;
  ctx.beginPath(); ctx.moveTo(x, PLOT.top); ctx.lineTo(x, H - PLOT.bottom + 6); ctx.stroke();
}

function drawCurves(canvas, data, pxPerS) {
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height;
  ctx.fillStyle = "#ffffff";
  ctx.fillRect(0, 0, W, H);
  const times = data.times, names = Object.keys(data.channels);
  const band = (H - PLOT.top - PLOT.bottom) / names.length;
  const X = s => PLOT.left + pxPerS * s;
  ctx.font = "11px sans-serif";
  ctx.strokeStyle = "#dddddd";
  for (const seg of data.segments) {  // phoneme boundaries
    ctx.beginPath(); ctx.moveTo(X(seg[0]), PLOT.top); ctx.lineTo(X(seg[0]), H - PLOT.bottom + 6); ctx.stroke();
  }
  const labels = layoutLabels(data.segments, X, text => ctx.measureText(text).width);
  for (const l of labels.placed) {
    ctx.fillStyle = ["p", "b", "m"].includes(l.text) ? "#b00020" : "#333333";
    ctx.fillText(l.text, l.x, H - PLOT.bottom + 18 + 13 * l.row);
  }
  names.forEach((name, j) => {
    const y = data.channels[name];
    let lo = Infinity, hi = -Infinity;
    for (const v of y) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (hi - lo < 1e-6) { hi += 0.5; lo -= 0.5; }
    const y0 = PLOT.top + j * band, Y = v => y0 + band - 3 - (band - 6) * (v - lo) / (hi - lo);
    ctx.strokeStyle = CH_COLORS[name] || "#000";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    y.forEach((v, i) => (i ? ctx.lineTo(X(times[i]), Y(v)) : ctx.moveTo(X(times[i]), Y(v))));
    ctx.stroke();
  });
  ctx.fillStyle = "#ffffff";
  ctx.fillRect(0, 0, PLOT.left - 1, H);
  names.forEach((name, j) => {
    ctx.fillStyle = CH_COLORS[name] || "#000";
    ctx.fillText(name, 4, PLOT.top + j * band + band / 2 + 4);
  });
  return labels;
}

// --- the page ----------------------------------------------------------------------------------------
function start() {
  const data = window.COARTIC;
  const face = loadFace(decodeBase64(data.glb));
  const fps = data.fps;
  const nFrames = face.times.length;
  const params = new URLSearchParams(window.location.search);
  // ?face=N: only the face, on an N x N canvas at the page's top left (screenshots, tests)
  const faceOnly = params.has("face");
  const canvas = document.getElementById("face");
  const plot = document.getElementById("plot");
  if (faceOnly) {
    document.body.classList.add("face-only");
    const n = Math.max(64, Math.min(4096, Number(params.get("face")) || 400));
    canvas.width = canvas.height = n;
    canvas.style.width = canvas.style.height = `${n}px`;
  }
  const view = new FaceView(canvas, face);
  const audio = document.getElementById("audio");
  const slider = document.getElementById("frame");
  const label = document.getElementById("time");
  const button = document.getElementById("play");
  slider.max = String(nFrames - 1);
  let playing = false, clockStart = 0, t = 0;
  function show(time) {
    t = Math.max(0, Math.min(time, (nFrames - 1) / fps));
    view.draw(t);
    if (!faceOnly) drawPlot(plot, data, t);
    const k = Math.round(t * fps);
    slider.value = String(k);
    label.textContent = `${t.toFixed(3)} s  frame ${k} / ${nFrames - 1}`;
    document.body.dataset.frame = String(k);
  }
  function tick() {
    if (!playing) return;
    // the sound is the clock: the face follows audio.currentTime, so picture and voice stay together
    const now = data.audio ? audio.currentTime : (performance.now() - clockStart) / 1000;
    document.body.dataset.clock = String(now);  // what the frame was chosen from, in full (tests read it)
    show(now);
    if (now >= (nFrames - 1) / fps || (data.audio && audio.ended)) { stop(); return; }
    requestAnimationFrame(tick);
  }
  function play() {
    if (t >= (nFrames - 1) / fps - 1e-9) t = 0;
    playing = true;
    button.textContent = "pause";
    if (data.audio) { audio.currentTime = t; audio.play().catch(() => stop()); }
    else clockStart = performance.now() - t * 1000;
    requestAnimationFrame(tick);
  }
  function stop() { playing = false; button.textContent = "play"; if (data.audio) audio.pause(); }
  button.addEventListener("click", () => (playing ? stop() : play()));
  slider.addEventListener("input", () => { stop(); show(Number(slider.value) / fps); if (data.audio) audio.currentTime = t; });
  document.getElementById("prev").addEventListener("click", () => { stop(); show((Math.round(t * fps) - 1) / fps); });
  document.getElementById("next").addEventListener("click", () => { stop(); show((Math.round(t * fps) + 1) / fps); });
  let drag = null;
  canvas.addEventListener("pointerdown", e => { drag = [e.clientX, e.clientY, view.yaw, view.pitch]; });
  window.addEventListener("pointerup", () => { drag = null; });
  window.addEventListener("pointermove", e => {
    if (!drag) return;
    view.yaw = drag[2] - (e.clientX - drag[0]) * 0.01;  // a whole head: all the way round
    view.pitch = Math.max(-1.2, Math.min(1.2, drag[3] + (e.clientY - drag[1]) * 0.01));
    show(t);
  });
  plot.addEventListener("click", e => {
    const r = plot.getBoundingClientRect();
    const scale = plotScale(plot.width, data.duration);
    const s = plotStart(scale, data.duration, t) + (e.clientX - r.left - PLOT.left) / scale.pxPerS;
    stop(); show(s);
  });
  if (params.has("yaw")) view.yaw = Number(params.get("yaw"));
  if (params.get("section") === "1") view.section = true;  // ?section=1: cut along the midline
  if (params.has("zoom")) view.zoom = Math.max(0.2, Math.min(10, Number(params.get("zoom")) || 1));
  if (params.has("frame")) {
    const k = Number(params.get("frame"));
    // a frame the animation does not have is said so, not shown as the nearest one
    if (!(Number.isInteger(k) && k >= 0 && k < nFrames)) throw new Error(`frame ${params.get("frame")} is outside 0..${nFrames - 1}`);
  }
  show(params.has("frame") ? Number(params.get("frame")) / fps : params.has("t") ? Number(params.get("t")) : 0);
  window.coarticView = {show, play, stop, nFrames, fps};
  if (params.get("render") === "1") {
    // ?render=1: every frame drawn in turn, each as a PNG data URL on its own line of a "frames" pre element,
    // for a headless Chromium's --dump-dom (coartic.face.viewer.render_frames: the perceptual tests' videos)
    const out = [];
    for (let k = 0; k < nFrames; k++) { view.draw(k / fps); out.push(canvas.toDataURL("image/png")); }
    const pre = document.createElement("pre");
    pre.id = "frames";
    pre.textContent = out.join("\n");
    document.body.appendChild(pre);
  }
  if (params.get("play") === "1") play();  // ?play=1 starts at once (a browser may ask for a click first)
  document.title = `${data.name} - coartic view`;
}

if (typeof module !== "undefined") module.exports = {layoutLabels, plotScale, weightsAt};  // node: the tests
else window.addEventListener("load", () => {
  try { start(); } catch (err) {
    document.getElementById("error").textContent = "coartic view: " + err.message;
    throw err;
  }
});
