// The Review's 2-D split view: the frame's image at full size, both halves zoomed and panned together (wheel,
// drag, the buttons), measurements as red rings with their point numbers, predictions as dots in the side's
// colour, residuals as lines, optionally magnified (said on the view). With the Overlay, one image: a ring per
// measurement and both predictions, each in its own colour. It shows the reviewed sensor's image; a session of
// several sensors offers those that take one.

import { api } from "./api.js";
import { $, el } from "./dom.js";
import { on, state } from "./state.js";

const split = { marks: null, img: null, zoom: 1, cx: null, cy: null, drag: null };

// Each frame's marks and decoded image, of the review shown (emptied when one is loaded), for the last
// MARKS_KEPT frames used: the frames a step goes to next are fetched ahead, so a step draws at once.
const MARKS_KEPT = 24;
const PREFETCH = [1, -1, 2];  // the frames fetched ahead, in the stepping order from the one shown
const marksCache = new Map();  // frame index -> Promise<{m, img}>, least recently used first

// An image loaded and decoded (off the main thread) before it is drawn; null if it cannot be.
function loadImage(url) {
  const img = new Image();
  img.src = url;
  return img.decode().then(() => img, () => null);
}

function frameMarks(index) {
  let got = marksCache.get(index);
  if (got) marksCache.delete(index);
  else {
    got = api("GET", `/review/marks/${index}`).then(async (m) => ({ m, img: m.image ? await loadImage(m.image) : null }));
    got.catch(() => marksCache.get(index) === got && marksCache.delete(index));  // asked again next time
  }
  marksCache.set(index, got);
  while (marksCache.size > MARKS_KEPT) marksCache.delete(marksCache.keys().next().value);
  return got;
}

const OLD_BLUE = "#0050ff";
const NEW_GREEN = "#00b000";
const VISION_RED = "#ff2020";

// Whether the reviewed sensor takes an image (a laser tracker does not: nothing to mark in 2-D).
const imaged = () => Boolean(state.review && state.review.images.includes(state.review.sensor));

// The 2-D view of a review: its sensor's image, and a choice of the session's sensors that take one when there
// is a choice (or the sensor reviewed takes none). Choosing one reviews that sensor.
function showSplitFor(review) {
  const sel = $("#split-sensor");
  const names = review.images.includes(review.sensor) ? review.images : ["", ...review.images];
  sel.replaceChildren(...names.map((s) => el("option", { value: s }, s || `— (${review.sensor}: no image)`)));
  sel.value = review.images.includes(review.sensor) ? review.sensor : "";
  $("#split-sensor-label").hidden = names.length < 2;
  $("#split").hidden = !review.images.length;
  $("#split-view").hidden = !imaged();
}

async function drawSplit(index) {
  if (!imaged()) return;
  const { m, img } = await frameMarks(index);
  if (!split.marks || split.marks.width !== m.width || split.marks.height !== m.height) fitSplit(m);
  else if (split.marks.index !== m.index) keepInView(m);
  Object.assign(split, { marks: m, img });
  redrawSplit();
  const k = state.frameOrder.indexOf(index);
  for (const d of PREFETCH) {
    const next = state.frameOrder[k + d];
    if (k >= 0 && next !== undefined) frameMarks(next).catch(() => {});
  }
}

function fitSplit(m) {
  Object.assign(split, { zoom: 1, cx: (m.width || 640) / 2, cy: (m.height || 480) / 2 });
}

// The image box [u0, v0, u1, v1] px around a frame's measurements (its predictions where nothing was measured);
// null: none.
function marksBox(m) {
  const points = (sides) => sides.flatMap((side) => side || []).filter((p) => p);
  const measured = points([m.measured]);
  const ps = measured.length ? measured : points([m.old, m.new]);
  if (!ps.length) return null;
  const us = ps.map((p) => p[0]);
  const vs = ps.map((p) => p[1]);
  return [Math.min(...us), Math.min(...vs), Math.max(...us), Math.max(...vs)];
}

// The image box [u0, v0, u1, v1] px the view shows.
function viewBox(canvas, m) {
  const { s, x0, y0 } = splitTransform(canvas, m);
  return [-x0 / s, -y0 / s, (canvas.clientWidth - x0) / s, (canvas.clientHeight - y0) / s];
}

const MARGIN = 0.1;  // of the view, kept free around the marks

// Another frame's marks in view: the zoom kept unless they need more room, centred on them if any is out.
function keepInView(m) {
  const box = marksBox(m);
  if (!box || split.zoom <= 1) return;
  const canvas = $("#split-new");
  const [u0, v0, u1, v1] = viewBox(canvas, m);
  const room = Math.min((u1 - u0) / (box[2] - box[0] || 1), (v1 - v0) / (box[3] - box[1] || 1)) * (1 - 2 * MARGIN);
  if (room < 1) split.zoom = Math.max(1, split.zoom * room);
  if (room < 1 || box[0] < u0 || box[1] < v0 || box[2] > u1 || box[3] > v1) centreOn(box);
}

function centreOn(box) {
  Object.assign(split, { cx: (box[0] + box[2]) / 2, cy: (box[1] + box[3]) / 2 });
}

function redrawSplit() {
  const m = split.marks;
  if (!m) return;
  const found = (m.measured || []).some((p) => p);
  const overlaid = $("#overlay").checked;
  $("#split").classList.toggle("overlaid", overlaid);
  const sides = overlaid ? [["#split-new", [[m.old, OLD_BLUE], [m.new, NEW_GREEN]]]]
    : [["#split-old", [[m.old, OLD_BLUE]]], ["#split-new", [[m.new, NEW_GREEN]]]];
  for (const [id, predictions] of sides) drawMarks($(id), split.img, m, predictions, found);
  for (const canvas of [$("#split-old"), $("#split-new")]) {
    canvas.dataset.frame = m.index;
    canvas.dataset.status = found ? "measured" : "not found";
  }
  $("#zoom-level").textContent = `zoom ${split.zoom.toFixed(split.zoom < 10 ? 1 : 0)}x`;
}

// Image px -> canvas (CSS px) transform: the image fitted to the canvas, times the zoom, about (cx, cy).
function splitTransform(canvas, m) {
  const w = m.width || 640;
  const h = m.height || 480;
  const s = Math.min(canvas.clientWidth / w, canvas.clientHeight / h) * split.zoom;
  return { s, x0: canvas.clientWidth / 2 - split.cx * s, y0: canvas.clientHeight / 2 - split.cy * s, w, h };
}

// Points are [u, v] px or null (not measured; a prediction behind the camera): nulls are not drawn.
// `predictions`: [points or null (no calibration on that side), colour] each.
function drawMarks(canvas, img, m, predictions, found) {
  const dpr = window.devicePixelRatio || 1;
  const cw = canvas.clientWidth;
  const ch = canvas.clientHeight;
  if (canvas.width !== Math.round(cw * dpr) || canvas.height !== Math.round(ch * dpr)) {
    canvas.width = Math.round(cw * dpr);
    canvas.height = Math.round(ch * dpr);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#222";
  ctx.fillRect(0, 0, cw, ch);
  const { s, x0, y0, w, h } = splitTransform(canvas, m);
  const at = (p) => [x0 + p[0] * s, y0 + p[1] * s];
  ctx.imageSmoothingEnabled = split.zoom < 4;  // zoomed in: the pixels as they are
  if (img) ctx.drawImage(img, x0, y0, w * s, h * s);
  else {
    ctx.strokeStyle = "#555";
    ctx.strokeRect(x0, y0, w * s, h * s);
  }
  const measured = m.measured || [];
  const mag = +$("#magnify").value || 1;
  for (const [predicted, colour] of predictions) {
    if (!predicted) continue;
    ctx.strokeStyle = colour;
    ctx.lineWidth = 1.5;
    predicted.forEach((p, i) => {
      const q = measured[i];
      if (!p || !q) return;
      const [mx, my] = at(q);
      ctx.beginPath();
      ctx.moveTo(mx, my);
      ctx.lineTo(mx + (p[0] - q[0]) * mag * s, my + (p[1] - q[1]) * mag * s);
      ctx.stroke();
    });
    ctx.fillStyle = colour;
    for (const p of predicted) {
      if (!p) continue;
      const [x, y] = at(p);
      ctx.beginPath();
      ctx.arc(x, y, 2.5, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
  ctx.strokeStyle = VISION_RED;
  ctx.lineWidth = 2;
  for (const p of measured) {
    if (!p) continue;
    const [x, y] = at(p);
    ctx.beginPath();
    ctx.arc(x, y, 6, 0, 2 * Math.PI);
    ctx.stroke();
  }
  if ($("#indices").checked && spaced(measured, s)) {
    ctx.font = "10px sans-serif";
    ctx.lineWidth = 3;
    ctx.strokeStyle = "rgba(0,0,0,0.8)";
    ctx.fillStyle = "#fff";
    measured.forEach((p, i) => {
      if (!p) return;
      const [x, y] = at(p);
      ctx.strokeText(String(i), x + 6, y - 6);
      ctx.fillText(String(i), x + 6, y - 6);
    });
  }
  ctx.font = "12px sans-serif";
  ctx.fillStyle = "#eee";
  const notes = [];
  const drawn = predictions.some(([predicted]) => predicted);
  if (!drawn) notes.push("no calibration on this side");
  if (!found) notes.push("not found: the detector found no fixture in this frame");
  if (!img) notes.push("no image kept with this frame: its marks on a blank frame of the camera's size");
  notes.forEach((t, k) => ctx.fillText(t, 8, 16 + 16 * k));
  if (mag > 1 && drawn) {
    ctx.fillStyle = "#ffd24a";
    ctx.font = "bold 13px sans-serif";
    const label = `residuals x${mag}`;
    ctx.fillText(label, cw - ctx.measureText(label).width - 8, 18);
  }
}

// Point numbers only where they do not cover each other: the closest two measurements at least 14 px apart.
function spaced(points, s) {
  const ps = points.filter((p) => p);
  if (ps.length < 2) return ps.length === 1;
  let closest = Infinity;
  for (let i = 0; i < ps.length; i++) {
    for (let j = i + 1; j < ps.length; j++) closest = Math.min(closest, Math.hypot(ps[i][0] - ps[j][0], ps[i][1] - ps[j][1]));
  }
  return closest * s >= 14;
}

// About the cursor (the wheel): the image point under it stays there.
function zoomSplit(factor, canvas, cssX, cssY) {
  const m = split.marks;
  if (!m) return;
  const before = splitTransform(canvas, m);
  const u = (cssX - before.x0) / before.s;
  const v = (cssY - before.y0) / before.s;
  split.zoom = Math.min(Math.max(split.zoom * factor, 1), 64);
  const after = splitTransform(canvas, m);
  split.cx += (u - (cssX - after.x0) / after.s);
  split.cy += (v - (cssY - after.y0) / after.s);
  redrawSplit();
}

// The buttons: about the frame's marks, centred on them (about the view's centre without marks).
function zoomOnMarks(factor) {
  const m = split.marks;
  if (!m) return;
  split.zoom = Math.min(Math.max(split.zoom * factor, 1), 64);
  const box = marksBox(m);
  if (box) centreOn(box);
  redrawSplit();
}

// Another review shown: the server's marks are of it from now on (none kept of the last), its sensors offered.
function showReview(review) {
  marksCache.clear();
  showSplitFor(review);
}

// No session: nothing drawn, nothing kept.
export function clearSplit() {
  $("#split").hidden = !state.robots[state.robot].sensor.image;  // a laser tracker has no image to mark
  $("#split-view").hidden = false;
  $("#split-sensor-label").hidden = true;
  for (const sel of ["#split-old", "#split-new"]) {
    const canvas = $(sel);
    const dpr = window.devicePixelRatio || 1;
    canvas.width = Math.round(canvas.clientWidth * dpr);  // resets it: blank, at the panel's resolution
    canvas.height = Math.round(canvas.clientHeight * dpr);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.font = "12px sans-serif";
    ctx.fillStyle = "#eee";
    ctx.fillText("no frame to show: open a session (Sessions, left) to review its frames", 8, 16);
    delete canvas.dataset.frame;
    canvas.dataset.status = "no frame";
  }
  split.marks = null;
  marksCache.clear();
}

export function wireSplit() {
  on("review:shown", showReview);
  on("frame:shown", drawSplit);
  on("session:closed", clearSplit);
  $("#zoom-in").addEventListener("click", () => zoomOnMarks(2));
  $("#zoom-out").addEventListener("click", () => zoomOnMarks(0.5));
  $("#zoom-fit").addEventListener("click", () => {
    if (split.marks) fitSplit(split.marks);
    redrawSplit();
  });
  $("#magnify").addEventListener("change", redrawSplit);
  $("#indices").addEventListener("change", redrawSplit);
  for (const canvas of [$("#split-old"), $("#split-new")]) {
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      const r = canvas.getBoundingClientRect();
      zoomSplit(e.deltaY < 0 ? 1.25 : 0.8, canvas, e.clientX - r.left, e.clientY - r.top);
    }, { passive: false });
    canvas.addEventListener("pointerdown", (e) => {
      split.drag = { x: e.clientX, y: e.clientY };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", (e) => {
      if (!split.drag || !split.marks) return;
      const { s } = splitTransform(canvas, split.marks);
      split.cx -= (e.clientX - split.drag.x) / s;
      split.cy -= (e.clientY - split.drag.y) / s;
      split.drag = { x: e.clientX, y: e.clientY };
      redrawSplit();
    });
    canvas.addEventListener("pointerup", () => (split.drag = null));
  }
  window.addEventListener("resize", redrawSplit);
}
