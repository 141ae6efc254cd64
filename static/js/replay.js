// Step 2, Replay: drive the robot through a session's configurations or planned ones; the dry run first.

import { api, follow } from "./api.js";
import { replayControls } from "./controls.js";
import { $, act, el, setText } from "./dom.js";
import { emit, on, state } from "./state.js";

let replayJob = null;   // the replay or dry run job the Pause, Resume and Abort buttons act on
let replaySeed = null;  // the seed of the N new configurations a dry run checked (null: a new one next)

// A replay drives the robot in view through configurations of its own sessions only.
function fillReplaySources() {
  const mine = state.sessions.filter((s) => s.robot === state.robot);
  $("#replay-from").replaceChildren(...mine.map((s) => el("option", { value: s.id }, `${s.name} (${s.frames})`)));
}

async function replay(dry) {
  if (!state.session) throw new Error("select a session first");
  const source = document.querySelector("input[name=replay-source]:checked").value;
  const body = { dry_run: dry, remeasure: source === "remeasure" };
  if (source === "from") body.from_session = $("#replay-from").value;
  if (source === "count" || source === "until") {
    // New poses each replay, the same ones for a dry run and the replay that follows it.
    replaySeed ??= crypto.getRandomValues(new Uint32Array(1))[0];
    Object.assign(body, { seed: replaySeed }, replayPlanning(source));
  }
  if ($("#replay-continue").checked) body.resume = true;
  if (dry) {
    $("#dry-run-result").replaceChildren();
    showPredicted(null);
  }
  const r = await api("POST", `/sessions/${state.session.id}/replay`, body);
  if (dry) {
    // A dry run of frames answers at once; one of new configurations plans them in a job first.
    showDryRun(r.job ? await followDryRun(r.job) : r);
    return;
  }
  replaySeed = null;
  await followReplay(r.job, state.session.id);
}

// A replay job followed to its end (one this page started, or found running when it loaded): its progress, its
// controls, each frame joining the list as it is captured, and the 3-D robot live meanwhile.
async function followReplay(jobId, sid) {
  replayJob = jobId;
  const watching = () => $("#observe-on").checked || $("#autocapture").checked;
  // The 3-D robot follows the robot while the replay drives it (the live view), whether or not "Watch live" is on.
  if (!watching()) await act(() => api("POST", `/sessions/${sid}/observe`, { on: true, autocapture: false }));
  let done = 0;
  await follow(jobId, (j) => {
    $("#replay-progress").value = j.progress;
    replayControls(j);
    const d = j.detail || {};
    if ((d.done || 0) > done) {
      done = d.done;
      emit("frames:captured", sid);
    }
    const planning = j.state === "running" && d.phase === "planning" ? ` · ${planningText(d)}` : "";
    const shown = j.paused && j.state === "running" ? "paused" : j.state;
    $("#replay-state").textContent = `${shown}${j.error ? `: ${j.error}` : ""}${planning}${d.frame ? ` · frame ${d.frame}: ${d.status}` : ""}`;
    if (d.curve) showUntilProgress(d);
  });
  replayControls(null);
  if (!watching()) await act(() => api("POST", `/sessions/${sid}/observe`, { on: false }));
  if (state.session && state.session.id === sid) await emit("sessions:load", sid);
}

// A page that loads (a reload mid-replay) finds the replay or dry run of its robot still running: its session
// opened, its controls given back and followed to its end. Whether it found one.
export async function followRunning() {
  const robotOf = (j) => (j.detail && j.detail.robot) || (state.sessions.find((s) => s.id === j.session) || {}).robot;
  const jobs = await api("GET", "/jobs");
  const job = jobs.find((j) => ["replay", "dry_run"].includes(j.kind) && ["queued", "running"].includes(j.state) &&
    robotOf(j) === state.robot);
  if (!job) return false;
  if (job.session && (!state.session || state.session.id !== job.session)) await emit("sessions:load", job.session);
  replayControls(job);
  if (job.kind === "dry_run") act(async () => showDryRun(await followDryRun(job.id)));
  else act(() => followReplay(job.id, job.session));
  return true;
}

// A dry run's job: its progress (planning, checking, predicting) in the Replay step; Abort or Esc cancels it.
// Its result (null: it did not finish) once done.
async function followDryRun(jobId) {
  replayJob = jobId;
  const done = await follow(jobId, (j) => {
    $("#replay-progress").value = j.progress;
    replayControls(j);
    const d = j.detail || {};
    const doing = {
      planning: planningText(d),
      checking: `checking ${d.checked} of ${d.total} configurations`,
      predicting: "predicting the accuracy",
    }[d.phase];
    const live = ["queued", "running"].includes(j.state);
    setText($("#replay-state"), `dry run ${j.state}${j.error ? `: ${j.error}` : ""}${live && doing ? ` · ${doing}` : ""}`);
  });
  replayControls(null);
  return done.state === "done" ? api("GET", `/jobs/${jobId}/dry-run`) : null;
}

// Where the planning of new configurations is (a replay's or a dry run's job): its stage and steps.
function planningText(d) {
  return "planning the configurations" + ({
    choosing: `: ${d.step} of ${d.steps} chosen`,
    exchanging: `: improving the plan (${d.step} of ${d.steps})`,
    refining: `: refining the plan (${d.step} of ${d.steps})`,
  }[d.stage] || "");
}

function showDryRun(r) {
  if (!r) return;
  const bad = r.configurations.filter((c) => !c.ok);
  const moved = r.configurations.filter((c) => c.ok && c.note);
  const box = $("#dry-run-result");
  box.replaceChildren(el("p", {}, `${r.configurations.length} configurations, ${bad.length} with a problem` +
    (moved.length ? `, ${moved.length} moved out of the safety margin` : "")));
  for (const c of bad) box.append(el("p", { class: "warning" }, `#${c.index}: ${c.problem}`));
  for (const c of moved) box.append(el("p", { class: "note" }, `#${c.index}: ${c.note}`));
  showPredicted(r.predicted, r.mode);
}

// --- planned configurations: predicted accuracy, capture until good enough -------------------------
// What a replay of new configurations asks for: N planned for the mode of step 3, or until good enough.
function replayPlanning(source) {
  const mode = $("#mode").value || undefined;
  if (source === "until") {
    return { mode, until: { error: +$("#replay-until-error").value, max: +$("#replay-until-max").value } };
  }
  return { mode, count: +$("#replay-count").value };
}

// The target of "capture until" is in the robot's measurement unit; a first value of its scale when the
// unit changes (the operator's own value stays while it does not).
function setUntilUnit(robot) {
  if ($("#replay-until-unit").textContent === robot.sensor.unit) return;
  $("#replay-until-unit").textContent = robot.sensor.unit;
  $("#replay-until-error").value = { m: 0.0001, mm: 1 }[robot.sensor.unit] ?? 0.1;
}

const fmtError = (v, unit) => (v === null || v === undefined ? "not determined yet" : `${v.toPrecision(3)} ${unit}`);

// The dry run's prediction: the error a calibration from these configurations would leave over the workspace.
function showPredicted(p, mode) {
  const box = $("#replay-predicted");
  if (!p) { box.replaceChildren(); return; }
  const worst = [...p.parameters].sort((a, b) => (b.std ?? Infinity) - (a.std ?? Infinity)).slice(0, 3);
  box.replaceChildren(
    el("p", { class: "predicted" }, `Predicted after ${/^[aeiou]/i.test(mode) ? "an" : "a"} ${mode} calibration from the ${p.n} configurations captured: ` +
      `error over the workspace mean ${fmtError(p.mean, p.unit)}, max ${fmtError(p.max, p.unit)}`),
    el("p", { class: "note" }, "largest predicted standard deviations: " +
      worst.map((w) => `${w.name} ${w.std === null ? "-" : w.std.toPrecision(2)} ${w.unit}`).join(", ") +
      (p.held.length ? ` · not identifiable, held: ${p.held.join(", ")}` : "")),
  );
}

// Capture until good enough: the predicted error after each frame, falling towards the target.
function showUntilProgress(d) {
  const values = d.curve.filter((v) => v !== null);
  const W = 240, H = 60;
  const top = Math.max(...values, d.target_error) * 1.05 || 1;
  const y = (v) => (H - 4 - (v / top) * (H - 8)).toFixed(1);
  const x = (k) => (4 + (k / Math.max(d.curve.length - 1, 1)) * (W - 8)).toFixed(1);
  const pts = d.curve.map((v, k) => (v === null ? null : `${x(k)},${y(v)}`)).filter(Boolean).join(" ");
  const svg = `<svg width="${W}" height="${H}" role="img" aria-label="predicted error after each frame">` +
    `<line x1="4" x2="${W - 4}" y1="${y(d.target_error)}" y2="${y(d.target_error)}" stroke="#2a2" stroke-dasharray="4 3"/>` +
    `<polyline fill="none" stroke="#c33" stroke-width="2" points="${pts}"/></svg>`;
  const box = $("#replay-predicted");
  box.replaceChildren(el("p", { class: "predicted" }, `Predicted error ${fmtError(d.predicted, d.unit)} ` +
    `(target ${d.target_error} ${d.unit}) after ${d.done} of at most ${d.total} configurations` +
    (d.stopped ? ` · ${d.stopped}` : "")));
  const chart = el("div", { class: "until-chart" });
  chart.innerHTML = svg;
  box.append(chart);
}

export function wireReplay() {
  on("robot:turned", fillReplaySources);
  on("sessions:listed", fillReplaySources);
  on("session:opened", (session) => setUntilUnit(state.robots[session.robot]));
  $("#dry-run").addEventListener("click", () => act(async () => {
    const button = $("#dry-run");
    if (button.disabled) return;  // a double click: one dry run
    button.disabled = true;
    try {
      await replay(true);
    } finally {
      replayControls(state.replaySnap);
    }
  }));
  $("#replay-start").addEventListener("click", () => act(() => replay(false)));
  for (const a of ["pause", "resume", "abort"]) {
    $(`#replay-${a}`).addEventListener("click", () =>
      replayJob && act(() => api("POST", `/jobs/${replayJob}/${a === "abort" ? "cancel" : a}`)));
  }
}
