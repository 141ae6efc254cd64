// Step 1, Observe: the joint sliders and readings, the robot's streamed state, watching live, capturing.

import { api } from "./api.js";
import { jobControls } from "./controls.js";
import { $, act, el, setText, toast } from "./dom.js";
import { emit, on, state } from "./state.js";

let driving = null;    // {since}: the sliders show the page's move target until the robot stopped after it
let readings = {};     // joint name -> degrees, the robot's last streamed readings
let autoCaptured = 0;  // frames auto-captured so far by the session's observation

// The joint sliders show the configuration the operator asks for, within the joint limits less the driver's
// safety margin (the server refuses a move closer to a limit). Moving one sends the whole configuration the
// sliders show: a joint still on its way keeps its target, not the reading it had when another slider moved.
export function buildJoints() {
  const t = $("#joints");
  t.replaceChildren();
  const robot = state.robots[state.robot];
  driving = null;
  for (const j of robot.joints) {
    const revolute = j.lower_deg !== null;
    const m = revolute ? Math.min(robot.margin_deg || 0, (j.upper_deg - j.lower_deg) / 2) : 0;
    const slider = el("input", { type: "range", min: j.lower_deg + m, max: j.upper_deg - m, step: 0.1, "data-joint": j.name });
    slider.disabled = !robot.drivable || !revolute;
    slider.addEventListener("change", moveToSliders);
    t.append(el("tr", {}, el("td", {}, j.name), el("td", {}, slider), el("td", { "data-reading": j.name }, "—")));
  }
}

const SLIDERS_FOLLOW_AFTER_MS = 300;  // a move's answer comes before its first "moving" state: wait that long

async function moveToSliders() {
  const joints = {};
  for (const s of document.querySelectorAll("input[data-joint]")) if (!s.disabled) joints[s.dataset.joint] = +s.value;
  driving = { since: Infinity };  // the sliders show the target, not the readings, until the robot stops
  try {
    await api("POST", "/robot/move", { joints, robot: state.robot });
    driving = { since: performance.now() };
  } catch (err) {
    driving = null;
    slidersToReadings(true);
    toast(`Move refused: ${err.message}`);
  }
}

// The sliders follow the robot's readings while the page is not driving it (a wander, a replay, another tab);
// `all`: the slider in the operator's hand too.
function slidersToReadings(all = false) {
  for (const [name, deg] of Object.entries(readings)) {
    const slider = document.querySelector(`input[data-joint="${name}"]`);
    if (!slider || deg === null || (!all && document.activeElement === slider)) continue;
    if (Math.abs(+slider.value - deg) > 0.06) slider.value = deg;  // a step is 0.1 deg: the same position unwritten
  }
}

// This tab's robot's state, streamed while it has a driver (another tab's robot has its own stream there);
// opened again for the robot the tab turns to. The page's pill, readings and motion controls follow it; what the
// robot observes goes to the camera's view (`robot:observing`, null: nothing), the frames it auto-captured into
// the session shown to the frame list (`frames:captured`).
let stream = null;

// Why a robot is not connected, in a word the pill has room for (its title holds the driver's sentence).
function notConnected(message) {
  if (message.startsWith("not responding")) return "not responding";
  if (message.startsWith("faulty readings")) return "faulty readings";
  return "disconnected";
}

export function robotEvents() {
  if (stream) stream.close();
  stream = null;
  emit("robot:observing", null);
  state.moving = false;
  if (!state.robots[state.robot].drivable) return;
  const robot = state.robot;
  const es = new EventSource(`/api/robot/events?robot=${encodeURIComponent(robot)}`);
  stream = es;
  es.onmessage = (ev) => {
    const r = JSON.parse(ev.data);
    if (r.robot !== state.robot) return;
    // At each change (the server looks ten times a second; a robot at rest is sent once a second): the page is
    // written only where something changed (a repaint of an unchanged page costs a software-rendered browser as
    // much as a changed one, and slows the 3-D view of every tab).
    setText($("#robot-state"), `${r.robot}: ${r.connected ? (r.moving ? "moving" : "still") : notConnected(r.message)}`);
    if ($("#robot-state").title !== r.message) $("#robot-state").title = r.message;  // the whole sentence
    $("#robot-state").classList.toggle("moving", r.moving);
    if (Boolean(state.moving) !== r.moving) {
      state.moving = r.moving;
      jobControls();
    }
    readings = r.joints;
    for (const [name, deg] of Object.entries(r.joints)) {
      const cell = document.querySelector(`[data-reading="${name}"]`);
      if (cell) setText(cell, deg === null ? "—" : `${deg.toFixed(1)}°`);
    }
    if (driving && !r.moving && performance.now() - driving.since > SLIDERS_FOLLOW_AFTER_MS) driving = null;
    if (!driving) slidersToReadings();
    const o = r.observing;
    if (o && state.session && o.session === state.session.id && o.captured > autoCaptured) emit("frames:captured", o.session);
    autoCaptured = o ? o.captured : 0;
    emit("robot:observing", o || null);
    setText($("#observe-state"), o ? `live: ${o.detection || "…"}${o.reason && o.reason !== "ok" && o.reason !== o.detection ? ` (${o.reason})` : ""} · ${o.captured} auto-captured` : "");
  };
  es.onerror = () => {
    es.close();
    if (stream !== es) return;  // the tab turned to another robot meanwhile
    $("#robot-state").textContent = "server unreachable";
    setTimeout(() => stream === es && robotEvents(), 2000);
  };
}

async function setObserve() {
  if (!state.session) throw new Error("select or create a session first");
  await api("POST", `/sessions/${state.session.id}/observe`, { on: $("#observe-on").checked || $("#autocapture").checked, autocapture: $("#autocapture").checked });
}

async function captureNow() {
  if (!state.session) throw new Error("select or create a session first");
  if (state.capturing) return;  // a double click: one frame
  state.capturing = true;
  jobControls();
  let frame;
  try {
    ({ frame } = await api("POST", `/sessions/${state.session.id}/capture`));
  } finally {
    state.capturing = false;
    jobControls();
  }
  toast(`Frame ${frame.index}: ${frame.status}${frame.reason && frame.reason !== "ok" && frame.reason !== frame.status ? ` (${frame.reason})` : ""}`, "info");
  await emit("sessions:load", state.session.id);
}

export function wireObserve() {
  on("robot:turned", () => {
    buildJoints();
    robotEvents();
  });
  $("#capture").addEventListener("click", () => act(captureNow));
  $("#observe-on").addEventListener("change", () => act(setObserve));
  $("#autocapture").addEventListener("change", () => act(setObserve));
  $("#wander").addEventListener("change", () => act(() => api("POST", "/robot/wander", { on: $("#wander").checked, robot: state.robot })));
}
