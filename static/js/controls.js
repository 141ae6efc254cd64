// The buttons that start or stop work, enabled only when they can act: a widget the panels share (it reads
// `state` and sets the buttons of several steps), not a panel.

import { $ } from "./dom.js";
import { state } from "./state.js";

const MOTION_CONTROLS = ["#capture", "#observe-on", "#autocapture", "#wander", "#dry-run", "#replay-start",
  "#goto", "#new-session button"];

// Calibrate with a session of measured frames and no calibration of the page running, Cancel while one runs,
// Capture with a session and a robot standing still (no capture in flight), Stop while the desk has a robot to
// stop; the Replay step's buttons as replayControls says.
export function jobControls() {
  const drivable = state.robots[state.robot].drivable;
  const calibrating = Boolean(state.job && state.job.live);
  $("#calibrate-start").disabled = !state.session || !state.session.measured || calibrating;
  $("#calibrate-cancel").disabled = !calibrating;
  $("#capture").disabled = !drivable || !state.session || Boolean(state.moving) || Boolean(state.capturing);
  $("#stop").disabled = !Object.values(state.robots).some((r) => r.drivable);
  replayControls(state.replaySnap);
}

// Pause while it runs, resume while paused, abort until it ends; no second replay or dry run meanwhile, none
// without a session to replay into. A dry run's job moves nothing: abort it, there is nothing to pause.
// `job`: the replay's or dry run's last snapshot (null: none running), kept for jobControls.
export function replayControls(job) {
  state.replaySnap = job;
  const live = Boolean(job) && ["queued", "running"].includes(job.state);
  const pausable = live && job.kind !== "dry_run";
  const drivable = state.robots[state.robot].drivable;
  $("#replay-pause").disabled = !pausable || job.paused;
  $("#replay-resume").disabled = !pausable || !job.paused;
  $("#replay-abort").disabled = !live;
  for (const sel of ["#replay-start", "#dry-run"]) $(sel).disabled = live || !drivable || !state.session;
}

export function showDrivable() {
  const drivable = state.robots[state.robot].drivable;
  for (const sel of MOTION_CONTROLS) $(sel).disabled = !drivable;
  jobControls();
  document.body.dataset.drivable = drivable ? "1" : "0";
  if (!drivable) {
    $("#robot-state").textContent = `${state.robot}: real data only (no robot to drive; import its sessions)`;
    $("#robot-state").className = "pill";
  }
}
