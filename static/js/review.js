// Step 4, Review: an old and a new calibration over the session's frames; the error summary, the histogram,
// the new calibration's warnings and parameters.

import { api } from "./api.js";
import { axes, ticks } from "./charts.js";
import { $, act, displayUnit, el, fmt } from "./dom.js";
import { emit, on, reviewUnit, state } from "./state.js";

// A review's table and summary (POST /review, /review/table) in the unit errors are shown in, in place.
function inDisplayUnit(answer) {
  const [shown, factor] = displayUnit(answer.summary.unit);
  const scale = (v) => (v === null || v === undefined ? v : v * factor);
  for (const r of answer.table) Object.assign(r, { err_old: scale(r.err_old), err_new: scale(r.err_new), band: scale(r.band) });
  const s = answer.summary;
  for (const k of ["old", "new", "heldout_old", "heldout_new"]) {
    if (s[k]) Object.assign(s[k], { mean: scale(s[k].mean), rms: scale(s[k].rms), max: scale(s[k].max) });
  }
  if (s.histogram.edges) s.histogram.edges = s.histogram.edges.map(scale);
  s.band.median = scale(s.band.median);
  s.unit = shown;
  return answer;
}

const reviewBody = (old, neu, sensor) => ({ session: state.session.id, old: old || null, new: neu || null, sensor });

// `sensor`: whose observations (a session of several sensors); null: the data format's sensor. `keep`: the
// selected frame stays selected (a review asked again: the robot's active calibration changed). Once the review
// is shown, its frame is selected (`frame:select`), as the scene shows the review's frame only.
async function loadReview(old, neu, sensor = null, keep = false) {
  const kept = keep ? state.frame : null;
  state.review = inDisplayUnit(await api("POST", "/review", reviewBody(old, neu, sensor)));
  state.reviewAsked = [old, neu, sensor];
  state.newCal = state.review.new;
  $("#review-old").value = old || "";
  $("#review-new").value = neu || "";
  emit("calibration:chosen");  // with the review's choice, before anything awaited: Apply never names the one before
  const sensors = $("#review-sensor");
  const names = [...new Set([state.review.sensor, ...state.review.sensors])];
  sensors.replaceChildren(...names.map((s) => el("option", { value: s }, s)));
  sensors.value = state.review.sensor;
  $("#review-sensor-label").hidden = state.review.sensors.length < 2;
  // What the scene could not show as asked (a URDF robot's mesh that cannot be read): said once per review.
  $("#review-warnings").replaceChildren(...(state.review.warnings || []).map((w) => el("p", { class: "warning" }, w)));
  emit("review:shown", state.review);  // its frames listed, its 2-D view made ready: still before anything awaited
  renderBand();
  renderSummary();
  await renderParameters();
  if (state.frameOrder.includes(kept)) await emit("frame:select", kept);
  else if (state.frameOrder.length) await emit("frame:select", state.frameOrder[0]);
}

// The review's figures again, its scene untouched (frames captured meanwhile: a live view keeps running); the
// frame list follows them (`review:refreshed`).
async function refreshFigures() {
  const [old, neu, sensor] = state.reviewAsked;
  const sid = state.session.id;
  const fresh = inDisplayUnit(await api("POST", "/review/table", reviewBody(old, neu, sensor)));
  if (!state.review || state.review.session !== sid || state.reviewAsked[1] !== neu) return;
  Object.assign(state.review, fresh);
  renderSummary();
  emit("review:refreshed");
}

// A review whose old side is the robot's active calibration shows the one just applied (its frame kept).
function reviewApplied() {
  if (state.reviewAsked && state.reviewAsked[0] === "active") return loadReview(...state.reviewAsked, true);
}

// What "same", "better" and "worse" in the frame list mean (app/scene/review.py's band).
function renderBand() {
  const b = state.review.summary.band;
  const p = $("#change-band");
  p.dataset.of = b.of.join(" ");
  if (!state.review.new) {
    p.textContent = "";
    return;
  }
  if (!b.of.length) {
    p.textContent = "new−old is not coloured: neither calibration has a covariance (the nominal model, or a file written before covariances were kept).";
    return;
  }
  const whose = b.of.length === 2 ? "the old and the new calibration's" : `the ${b.of[0]} calibration's`;
  const other = b.of[0] === "new" ? "old" : "new";
  const without = b.of.length === 2 ? "" : ` (the ${other} calibration has none: the nominal model, or a file written before covariances were kept)`;
  p.textContent = `better / worse: new−old beyond ${b.k}× the frame's band, same within it. The band: how far ${whose} own uncertainty moves the frame's predicted points (RMS over its points; median ${fmt(b.median)} ${reviewUnit()})${without}.`;
}

function renderSummary() {
  const s = state.review.summary;
  const u = s.unit;
  const cols = [["old", "old calibration"], ["new", "new calibration"], ["heldout_old", "held-out, old"],
    ["heldout_new", "held-out, new"]]
    .filter(([k]) => s[k]);
  const t = $("#summary");
  t.replaceChildren(el("tr", {}, el("th", {}, `error (${u})`), ...cols.map(([, l]) => el("th", {}, l))));
  for (const k of ["mean", "rms", "max", "n"]) {
    t.append(el("tr", { "data-figure": k }, el("td", {}, k === "rms" ? "RMS" : k),
      ...cols.map(([c]) => el("td", { "data-col": c }, k === "n" ? s[c][k] : fmt(s[c][k])))));
  }
  drawHistogram($("#histogram"), s.histogram);
}

// The notes shown after the warnings, each a line in the words `calib solve` prints (in the server's order): what
// mode `auto` chose and why (every candidate's cross-validated error); a fit within a fifth of the declared noise.
const NOTES = ["model-choice", "noise-scatter"];

async function renderParameters() {
  const t = $("#parameters");
  const w = $("#warnings");
  t.replaceChildren();
  w.replaceChildren();
  if (!state.newCal) return;
  const cal = await api("GET", `/calibrations/${state.newCal}`);
  if (!cal.converged) {
    w.append(el("p", { class: "warning", "data-code": "not-converged" },
      `⚠ Did not converge: ${cal.solver.message} after ${cal.solver.iterations} iterations.`));
  }
  // One line per kind, those that change whether to apply first; a kind of several lists each on demand.
  for (const g of cal.diagnostic_groups.filter((g) => g.severity === "warning" && g.code !== "not-converged")) {
    if (g.messages.length === 1) {
      w.append(el("p", { class: "warning", "data-code": g.code }, `⚠ ${g.title}`));
      continue;
    }
    w.append(el("details", { class: "warning", "data-code": g.code },
      el("summary", {}, `⚠ ${g.title}`), el("ul", {}, ...g.messages.map((m) => el("li", {}, m)))));
  }
  for (const g of cal.diagnostic_groups.filter((g) => NOTES.includes(g.code))) {
    w.append(el("p", { "data-code": g.code }, g.title));
  }
  if (cal.outliers.length) {
    const shown = (o) => {
      const [u, factor] = displayUnit(o.unit);
      return `frame ${o.frame} (${fmt(o.error * factor, 2)} ${u})`;
    };
    w.append(el("p", {}, `Outliers left out: ${cal.outliers.map(shown).join(", ")}`));
  }
  // "start": where the solver started (the nominal model or the calibration it was based on), not the review's
  // old calibration.
  t.append(el("tr", {}, ...[["parameter", ""], ["start", "the value the calibration started from"],
    ["calibrated", "the value it found"], ["change", "calibrated − start"], ["std", ""], ["unit", ""]]
    .map(([h, title]) => el("th", { title }, h))));
  for (const p of cal.parameters) {
    if (!p.estimated && Math.abs(p.value - p.base) < 1e-12) continue;
    t.append(el("tr", { class: p.estimated ? "" : "fixed", title: p.note || "" },
      el("td", {}, p.label), el("td", {}, fmt(p.base, 4)), el("td", {}, fmt(p.value, 4)),
      el("td", {}, fmt(p.value - p.base, 4)), el("td", {}, p.std === null ? "held" : fmt(p.std, 4)), el("td", {}, p.unit)));
  }
}

function drawHistogram(canvas, hist) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!hist || !hist.edges || hist.edges.length < 2) return;
  const n = hist.edges.length - 1;
  const series = [["old", "#0050ff"], ["new", "#00b000"]].filter(([k]) => hist[k]);
  const top = Math.max(1, ...series.flatMap(([k]) => hist[k]));
  const lo = hist.edges[0];
  const hi = hist.edges[n];
  const box = { left: 46, top: 8, right: canvas.width - 10, bottom: canvas.height - 30 };
  box.x = (v) => box.left + ((v - lo) / (hi - lo)) * (box.right - box.left);
  box.y = (v) => box.bottom - (v / top) * (box.bottom - box.top);
  const bw = (box.right - box.left) / n;
  series.forEach(([k, c], si) => {
    ctx.fillStyle = c;
    hist[k].forEach((v, i) => {
      const bh = box.bottom - box.y(v);
      ctx.fillRect(box.left + i * bw + (si * bw) / series.length, box.bottom - bh, bw / series.length - 1, bh);
    });
  });
  const yt = ticks(0, top, 3).filter((v) => Number.isInteger(v)).map((v) => [v, String(v)]);
  axes(ctx, box, ticks(lo, hi, 5).map((v) => [v, fmt(v, 2)]), yt, `error (${reviewUnit()})`, "observations");
}

// No session: no figures.
function clearReview() {
  for (const sel of ["#summary", "#parameters", "#warnings"]) $(sel).replaceChildren();
  const histogram = $("#histogram");
  histogram.getContext("2d").clearRect(0, 0, histogram.width, histogram.height);
}

export function wireReview() {
  on("session:closed", clearReview);
  on("review:load", loadReview);
  on("review:refresh", refreshFigures);
  on("calibration:applied", reviewApplied);
  const reviewAgain = () => act(() => loadReview($("#review-old").value, $("#review-new").value, $("#review-sensor").value || null));
  $("#review-load").addEventListener("click", reviewAgain);
  $("#review-sensor").addEventListener("change", reviewAgain);
  $("#split-sensor").addEventListener("change", () => {
    const sensor = $("#split-sensor").value;
    if (sensor) act(() => loadReview($("#review-old").value, $("#review-new").value, sensor));
  });
}
