// The Sessions list: a session opened, made, imported or closed.

import { api } from "./api.js";
import { renderApply } from "./apply.js";
import { clearJob, loadCalibrations } from "./calibrate.js";
import { jobControls } from "./controls.js";
import { $, act, checkForm, el, toast } from "./dom.js";
import { fillReplaySources, setUntilUnit } from "./replay.js";
import { connect } from "./robots.js";
import { clearSplit } from "./split.js";
import { emit, state } from "./state.js";
import { showTab } from "./tabs.js";

// Newest first: a session just made or imported is at the top of the list.
export async function loadSessions(selectId, sessions = null) {
  state.sessions = (sessions || (await api("GET", "/sessions"))).sort((a, b) => b.created.localeCompare(a.created));
  const ul = $("#sessions");
  ul.replaceChildren();
  for (const s of state.sessions) {
    const li = el("li", { "data-session": s.id, onclick: () => act(() => openSession(s.id)) },
      el("b", {}, s.name), el("small", {}, ` ${s.robot} · ${s.measured}/${s.frames} frames measured`));
    ul.append(li);
  }
  fillReplaySources();
  if (selectId) await openSession(selectId);
}

async function openSession(id) {
  state.session = await api("GET", `/sessions/${id}`);
  state.newCal = null;  // Apply names nothing of the session before while this one's review loads
  renderApply();
  for (const li of document.querySelectorAll("#sessions li")) li.classList.toggle("selected", li.dataset.session === id);
  if (state.session.robot !== state.robot) {
    await connect(state.session.robot);
    $("#robot-select").value = state.robot;
  }
  const robot = state.robots[state.session.robot];
  const mode = $("#mode");
  mode.replaceChildren(...robot.modes.map((m) => el("option", { value: m.name, title: m.description }, m.name)));
  mode.value = robot.modes.some((m) => m.name === "full") ? "full" : robot.modes[0].name;
  setUntilUnit(robot);
  if (!state.job || state.job.session !== id) clearJob();
  jobControls();
  await loadCalibrations();
  await emit("review:load", "active", state.calibrations.length ? state.calibrations[0].id : "");
}

export function closeSession() {
  Object.assign(state, { session: null, review: null, reviewAsked: null, newCal: null, frame: null, frameOrder: [],
    calibrations: [] });
  for (const li of document.querySelectorAll("#sessions li")) li.classList.remove("selected");
  for (const sel of ["#frames", "#summary", "#parameters", "#warnings", "#calibrations"]) $(sel).replaceChildren();
  const histogram = $("#histogram");
  histogram.getContext("2d").clearRect(0, 0, histogram.width, histogram.height);
  clearSplit();
  $("#frame-summary").replaceChildren();
  $("#frame-label").textContent = "frame —";
  $("#frame-slider").max = 0;
  renderApply();
  clearJob();
  jobControls();
}

async function newSession(e) {
  e.preventDefault();
  checkForm(e.target);
  const name = new FormData(e.target).get("name");
  const { id } = await api("POST", "/sessions", { robot: state.robot, name });
  e.target.reset();
  await loadSessions(id);
  showTab("observe");
}

async function importSession(e) {
  e.preventDefault();
  checkForm(e.target);
  const form = new FormData(e.target);
  form.append("robot", state.robot);
  const { id, notes } = await api("POST", "/sessions/import", form);
  e.target.reset();
  await loadSessions(id);
  if (notes.length) toast(`Imported, but look: ${notes.join("; ")}`, "error");
  else toast("Imported.", "info");
}

export function wireSessions() {
  $("#new-session").addEventListener("submit", (e) => act(() => newSession(e)));
  $("#import-session").addEventListener("submit", (e) => act(() => importSession(e)));
}
