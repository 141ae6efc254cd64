// The header's robot: which one this page drives, a robot added to the running desk, STOP.

import { api } from "./api.js";
import { showDrivable } from "./controls.js";
import { $, act, checkForm, el, toast } from "./dom.js";
import { emit, on, state } from "./state.js";

export function fillRobots() {
  for (const r of Object.values(state.robots)) addRobotOption(r);
  $("#robot-select").value = state.robot;
}

function addRobotOption(r) {
  $("#robot-select").append(el("option", { value: r.name }, r.drivable ? r.name : `${r.name} (real data only)`));
}

// A robot added to the desk (this form, or an import of images and poses that made one): offered in the header.
function robotAdded(r) {
  state.robots[r.name] = r;
  addRobotOption(r);
}

// A robot with real data only (no driver) has sessions imported from CSV, calibrations and reviews,
// but nothing to connect to or move: its capture and motion controls are disabled.
// This tab's 3-D scene shows the connected robot: a session and review of another robot are closed
// (`robot:turned`, which every panel that follows the robot hears; Apply asks for its active calibration).
async function connect(robot) {
  if (state.robots[robot].drivable) await api("POST", "/robot/connect", { robot });
  state.robot = robot;
  $("#robot-select").value = robot;
  const followed = emit("robot:turned", robot);  // each panel follows it at once; Apply's answer awaited below
  showDrivable();
  await followed;
}

// A robot added to the running desk: a profile file (with its URDF when it says `urdf: ...`, and a zip of
// that URDF's meshes) or a built-in profile's name (another NAO), and a driver or none (real data only).
async function addRobot(e) {
  e.preventDefault();
  checkForm(e.target);
  const form = new FormData(e.target);
  for (const key of ["profile_file", "urdf_file", "meshes_zip"]) if (!form.get(key) || !form.get(key).size) form.delete(key);
  for (const key of ["profile", "driver"]) if (!form.get(key)) form.delete(key);
  const robot = await api("POST", "/robots", form);
  await emit("robot:added", robot);
  e.target.reset();
  $("#robot-select").value = robot.name;
  await connect(robot.name);
  toast(`Robot ${robot.name} (${robot.model}) is on the desk.`, "info");
}

// STOP answers within about 150 ms whatever the robots do: a robot that did not take the stop is named, with
// what to do (its own emergency stop), instead of "Stopped."
async function stopAll() {
  $("#wander").checked = false;
  const answer = await act(() => api("POST", "/robot/stop"));
  const unconfirmed = (answer?.stops || []).filter((s) => !s.confirmed).map((s) => s.message);
  if (unconfirmed.length) toast(unconfirmed.join(" "), "error");
  else if (answer !== null) toast("Stopped.", "info");
}

export function wireRobots() {
  on("robot:connect", connect);  // a session of another robot opened
  on("robot:added", robotAdded);
  const sel = $("#robot-select");
  sel.addEventListener("change", () => act(() => connect(sel.value)));
  $("#stop").addEventListener("click", stopAll);
  document.addEventListener("keydown", (e) => {
    if (e.key === "Escape") stopAll();
  });
  $("#add-robot").addEventListener("submit", (e) => act(() => addRobot(e)));
}
