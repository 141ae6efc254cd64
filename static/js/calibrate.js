// Step 3, Calibrate: a calibration job of the session, its progress and cost curve, the session's calibrations.

import { api, follow } from "./api.js";
import { axes, ticks } from "./charts.js";
import { jobControls } from "./controls.js";
import { $, act, calibrationName, displayUnit, el, fmt, toast } from "./dom.js";
import { emit, on, state } from "./state.js";
import { showTab } from "./tabs.js";

// A session opened: its robot's modes, the first selected (the API lists `auto` first where the data have a choice
// to make), the job line of another session's calibration cleared, the session's calibrations listed.
async function sessionOpened(session) {
  const robot = state.robots[session.robot];
  const mode = $("#mode");
  mode.replaceChildren(...robot.modes.map((m) => el("option", { value: m.name, title: m.description }, m.name)));
  mode.value = robot.modes[0].name;
  if (!state.job || state.job.session !== session.id) clearJob();
  jobControls();
  await loadCalibrations();
}

// The session's calibrations, newest first as the API lists them: in this step's list and start-from choice, and
// the Review's choices.
async function loadCalibrations() {
  state.calibrations = await api("GET", `/sessions/${state.session.id}/calibrations`);
  const base = $("#base");
  base.replaceChildren(el("option", { value: "" }, "nominal model"), el("option", { value: "active" }, "robot's active calibration"));
  const oldSel = $("#review-old");
  const newSel = $("#review-new");
  oldSel.replaceChildren(el("option", { value: "active" }, "robot's active"), el("option", { value: "" }, "nominal model"));
  newSel.replaceChildren(el("option", { value: "" }, "(none)"));
  const ul = $("#calibrations");
  ul.replaceChildren();
  for (const c of state.calibrations) {
    const after = c.figures && c.figures.after ? shown(c.figures.after.mean, c.figures.after.unit) : "";
    const label = `${calibrationName(c)} · ${after}`;
    for (const s of [base, oldSel, newSel]) s.append(el("option", { value: c.id }, label));
    ul.append(el("li", { "data-calibration": c.id, onclick: () => act(() => emit("review:load", "active", c.id)) }, label));
  }
}

const shown = (v, unit) => {
  const [u, factor] = displayUnit(unit);
  return `${fmt(v * factor)} ${u}`;
};

async function startCalibration() {
  if (!state.session) throw new Error("select a session first");
  const baseValue = $("#base").value;
  const base = baseValue === "active" ? (await api("GET", `/robot/calibration?robot=${state.session.robot}`)).id : baseValue || null;
  const body = { mode: $("#mode").value, base, holdout: +$("#holdout").value };
  const sid = state.session.id;
  $("#job-warnings").replaceChildren();
  const { job } = await api("POST", `/sessions/${sid}/calibrations`, body);
  state.job = { id: job, live: true, session: sid };
  jobControls();
  const shown = () => state.session && state.session.id === sid;  // another session opened meanwhile: not its line
  const done = await follow(job, (j) => {
    if (state.job && state.job.id === job) state.job.live = ["queued", "running"].includes(j.state);
    jobControls();
    if (!shown()) return;
    $("#job-progress").value = j.progress;
    const loading = j.state === "queued" && j.detail && j.detail.phase === "loading" ? " · reading the session's frames" : "";
    $("#job-state").textContent = `${j.state}${j.error ? `: ${j.error}` : ""}${loading}` +
      (j.cost && j.cost.length ? ` · iteration ${j.cost.length - 1}, cost ${j.cost[j.cost.length - 1].toExponential(3)}` : "");
    drawCurve($("#cost-curve"), j.cost || []);
  });
  if (done.state === "done" && shown()) {
    const converged = done.detail.converged !== false;
    if (!converged) $("#job-state").textContent = `done, but the solver did not converge (${done.detail.solver_status})`;
    const warned = await showOutcome(done.result);
    await loadCalibrations();
    await emit("review:load", "active", done.result);
    showTab("review");
    if (!converged) toast(`The calibration did not converge (${done.detail.solver_status}): read the warnings before applying.`, "error");
    else if (warned) toast(`Calibration done with ${warned} warning${warned > 1 ? "s" : ""} (Calibrate and Review list them): read them before applying.`, "error");
    else toast("Calibration done: review it, then apply.", "info");
  }
}

// A calibration's warnings where its result is shown, and the richer mode its noise test names (residuals well
// above the sensor's noise: the mode cannot model what the data hold) one click away. The warnings' count.
async function showOutcome(calId) {
  const cal = await api("GET", `/calibrations/${calId}`);
  const warnings = cal.diagnostic_groups.filter((g) => g.severity === "warning" && g.code !== "not-converged");
  const box = $("#job-warnings");
  box.replaceChildren(...warnings.map((g) => el("p", { class: "warning", "data-code": g.code }, `⚠ ${g.title}`)));
  const richer = cal.diagnostics.find((d) => d.code === "noise-excess" && d.mode && d.mode !== cal.mode);
  if (richer && [...$("#mode").options].some((o) => o.value === richer.mode)) {
    const again = () => act(async () => {
      $("#mode").value = richer.mode;
      await startCalibration();
    });
    box.append(el("button", { id: "calibrate-richer", onclick: again }, `Calibrate again in mode '${richer.mode}'`));
  }
  return warnings.length;
}

// The job line and cost curve say nothing of another session's calibration.
function clearJob() {
  $("#job-state").textContent = "";
  $("#job-warnings").replaceChildren();
  $("#job-progress").value = 0;
  // A new canvas: under load Chromium sometimes kept showing a cleared canvas's old curve (read back too).
  const curve = $("#cost-curve");
  curve.replaceWith(curve.cloneNode(false));
}

// The solver's cost per iteration, on a log scale.
function drawCurve(canvas, ys) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (ys.length < 1) return;
  const ls = ys.map((y) => Math.log10(Math.max(y, 1e-300)));
  const lo = Math.floor(Math.min(...ls));
  const hi = Math.max(Math.ceil(Math.max(...ls)), lo + 1);
  const last = Math.max(1, ls.length - 1);
  const box = { left: 46, top: 8, right: canvas.width - 10, bottom: canvas.height - 30 };
  box.x = (i) => box.left + (i / last) * (box.right - box.left);
  box.y = (l) => box.bottom - ((l - lo) / (hi - lo)) * (box.bottom - box.top);
  ctx.strokeStyle = "#1d5bd8";
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ls.forEach((l, i) => (i ? ctx.lineTo(box.x(i), box.y(l)) : ctx.moveTo(box.x(i), box.y(l))));
  ctx.stroke();
  const xt = ticks(0, last, 4).filter((v) => Number.isInteger(v)).map((v) => [v, String(v)]);
  const yt = ticks(lo, hi, 3).filter((v) => Number.isInteger(v)).map((v) => [v, `1e${v}`]);
  axes(ctx, box, xt, yt, "iteration", "cost");
}

export function wireCalibrate() {
  on("session:opened", sessionOpened);
  on("session:closed", () => {
    $("#calibrations").replaceChildren();
    clearJob();
  });
  $("#holdout").addEventListener("input", () => ($("#holdout-out").textContent = `${Math.round($("#holdout").value * 100)}%`));
  $("#calibrate-start").addEventListener("click", () => act(async () => {
    const button = $("#calibrate-start");
    if (button.disabled) return;  // a double click: one calibration
    button.disabled = true;
    try {
      await startCalibration();
    } finally {
      jobControls();
    }
  }));
  $("#calibrate-cancel").addEventListener("click", () => state.job && act(() => api("POST", `/jobs/${state.job.id}/cancel`)));
}
