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

// Images of a board, each with the flange pose the controller reported (POST /api/sessions/import-handeye): a
// session of a robot known by its flange pose, that robot added to the desk when its name is new (`robot:added`:
// the header offers it), then opened on step 3. The button is disabled while the desk reads the images (a double
// click imports once); what came of it, or the server's sentence, is said under the form (a refusal changes
// nothing: the form keeps what was chosen, to be corrected).
async function importHandeye(e) {
  e.preventDefault();
  const form = e.target;
  const said = $("#import-handeye-state");
  try {
    checkForm(form);
    const body = new FormData(form);
    // A folder holds the poses and camera files too, maybe more: only its images are sent, in their names' natural
    // order (2.png before 10.png; a folder lists them in no order), the order the answer's notes then follow.
    const folder = [...form.elements.folder.files].filter((f) => f.type.startsWith("image/"));
    const images = [...form.elements.images.files, ...folder]
      .sort((a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }));
    if (!images.length) throw new Error("Images: choose the images, a zip of them, or their folder");
    body.delete("images");
    body.delete("folder");
    for (const f of images) body.append("images", f, f.name);
    const mb = images.reduce((n, f) => n + f.size, 0) / 2 ** 20;
    say(said, "busy", `Importing ${images.length} file${images.length > 1 ? "s" : ""} (${mb.toFixed(1)} MB): ` +
      "the desk looks for the board in each image…");
    form.querySelector("button").disabled = true;
    const { id, robot, added, notes } = await api("POST", "/sessions/import-handeye", body);
    // New on the desk, or added from another tab since this one loaded: this tab learns of it.
    if (!state.robots[robot]) await emit("robot:added", (await api("GET", "/robots")).find((r) => r.name === robot));
    form.reset();
    await loadSessions(id);
    showTab("calibrate");
    const made = `Session ${state.session.name} of ${added ? "the new robot " : ""}${robot}: ` +
      `${state.session.measured} frames.`;
    say(said, notes.length ? "notes" : "done", notes.length ? `${made} Look: ${notes.join("; ")}.` : made);
    if (notes.length) toast(`Imported, but look: ${notes.join("; ")}`, "error");
    else toast("Imported: calibrate it.", "info");
  } catch (err) {
    say(said, "error", err.message);
    throw err;
  } finally {
    form.querySelector("button").disabled = false;
  }
}

function say(e, kind, text) {
  e.dataset.state = kind;
  e.textContent = text;
}

// The robots known by their flange pose (calib_core/model/flange_pose.py: its six joints are the reported pose),
// offered for another day's images; any other name is a new robot.
const FLANGE_JOINTS = "x,y,z,yaw,pitch,roll";
function offerFlangeRobots() {
  const flange = Object.values(state.robots).filter((r) => r.joints.map((j) => j.name).join() === FLANGE_JOINTS);
  $("#flange-robots").replaceChildren(...flange.map((r) => el("option", { value: r.name })));
}

export function wireSessions() {
  on("sessions:load", loadSessions);
  on("robot:turned", robotTurned);
  on("robot:added", offerFlangeRobots);
  offerFlangeRobots();
  $("#new-session").addEventListener("submit", (e) => act(() => newSession(e)));
  $("#import-session").addEventListener("submit", (e) => act(() => importSession(e)));
  $("#import-handeye").addEventListener("submit", (e) => act(() => importHandeye(e)));
}
