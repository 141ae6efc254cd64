// The Sessions list: a session opened, made, imported or closed.

import { api } from "./api.js";
import { jobControls } from "./controls.js";
import { $, act, checkForm, el, toast } from "./dom.js";
import { emit, on, state } from "./state.js";
import { showTab } from "./tabs.js";

// Newest first: a session just made or imported is at the top of the list. `selectId`: the session then opened
// (`sessions:load` asks for it: frames captured, a replay's end).
export async function loadSessions(selectId, sessions = null) {
  state.sessions = (sessions || (await api("GET", "/sessions"))).sort((a, b) => b.created.localeCompare(a.created));
  const ul = $("#sessions");
  ul.replaceChildren();
  for (const s of state.sessions) {
    const li = el("li", { "data-session": s.id, onclick: () => act(() => openSession(s.id)) },
      el("b", {}, s.name), el("small", {}, ` ${s.robot} · ${s.measured}/${s.frames} frames measured`));
    ul.append(li);
  }
  emit("sessions:listed");
  if (selectId) await openSession(selectId);
}

// A session of another robot turns this tab to that robot first (`robot:connect`); the session's steps made
// ready for it (`session:opened`: its calibrations listed), then its review of the newest calibration loaded.
async function openSession(id) {
  state.session = await api("GET", `/sessions/${id}`);
  state.newCal = null;
  emit("calibration:chosen");  // Apply names nothing of the session before while this one's review loads
  for (const li of document.querySelectorAll("#sessions li")) li.classList.toggle("selected", li.dataset.session === id);
  if (state.session.robot !== state.robot) await emit("robot:connect", state.session.robot);
  await emit("session:opened", state.session);
  await emit("review:load", "active", state.calibrations.length ? state.calibrations[0].id : "");
}

// The tab turned to another robot: a session of the robot before is closed (this tab's scene shows its robot).
function robotTurned(robot) {
  if (state.session && state.session.robot !== robot) closeSession();
}

// Each panel clears what it showed of the session (`session:closed`).
function closeSession() {
  Object.assign(state, { session: null, review: null, reviewAsked: null, newCal: null, frame: null, frameOrder: [],
    calibrations: [] });
  for (const li of document.querySelectorAll("#sessions li")) li.classList.remove("selected");
  emit("session:closed");
  emit("calibration:chosen");
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
  on("sessions:load", loadSessions);
  on("robot:turned", robotTurned);
  $("#new-session").addEventListener("submit", (e) => act(() => newSession(e)));
  $("#import-session").addEventListener("submit", (e) => act(() => importSession(e)));
}
