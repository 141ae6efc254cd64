// The calibration desk page: plain ES modules, no build step (docs/page.md says which module holds which panel).
// It talks to the JSON API under /api and embeds the viser scene in an iframe (served by the same port under
// /scene). State lives on the server; the page only shows it and sends the operator's actions. This module
// starts the page: it asks for what the first view shows and wires each panel's controls.

import { api } from "./js/api.js";
import { activeCalibration, refreshActive, wireApply } from "./js/apply.js";
import { wireCalibrate } from "./js/calibrate.js";
import { showDrivable } from "./js/controls.js";
import { toast } from "./js/dom.js";
import { wireFrames } from "./js/frames.js";
import { wireHistory } from "./js/history.js";
import { wireLive } from "./js/live.js";
import { buildJoints, robotEvents, wireObserve } from "./js/observe.js";
import { followRunning, wireReplay } from "./js/replay.js";
import { wireReview } from "./js/review.js";
import { fillRobots, wireRobots } from "./js/robots.js";
import { showScene, watchServer, wireScene } from "./js/scene.js";
import { loadSessions, wireSessions } from "./js/sessions.js";
import { clearSplit, wireSplit } from "./js/split.js";
import { state } from "./js/state.js";
import { showTab, wireTabs } from "./js/tabs.js";

// What the first view shows is asked for at once (two waves: the active calibration and its history need the
// robot's name). The 3-D scene's client, a large script that runs on this page's main thread and draws on every
// animation frame, starts once the page has drawn the controls with their data (ready): started before, it
// held the answers up, and the page's first paint waited for its first frames.
async function init() {
  const [health, robots, status, sessions] = await Promise.all([
    api("GET", "/health"),
    api("GET", "/robots"),
    api("GET", "/robot").catch(() => null),  // none connected: a desk without a drivable robot
    api("GET", "/sessions"),
  ]);
  for (const r of robots) state.robots[r.name] = r;
  // The connected robot; a desk without a drivable robot has none: the first one is shown.
  state.robot = status ? status.robot : Object.keys(state.robots)[0];
  const active = activeCalibration();
  fillRobots();
  wire();
  await loadSessions(undefined, sessions);
  if (!state.session) clearSplit();  // the 2-D view says how to fill it
  robotEvents();
  buildJoints();
  showDrivable();
  await refreshActive(active);
  const replaying = await followRunning();  // a reload mid-replay: its controls given back
  showTab(replaying ? "replay" : state.robots[state.robot].drivable ? "observe" : "review");  // the papers' first step
  watchServer(health.instance);
  document.body.dataset.ready = "1";
  afterPaint(showScene);  // after requests with the token: off loopback, their answers set the cookie the scene needs
}

function wire() {
  wireTabs();
  wireRobots();
  wireSessions();
  wireObserve();
  wireLive();
  wireReplay();
  wireCalibrate();
  wireReview();
  wireFrames();
  wireSplit();
  wireScene();
  wireApply();
  wireHistory();
}

// Once the page has painted what it shows now (two animation frames), or after 250 ms (a tab in the background
// gets no animation frames).
function afterPaint(fn) {
  let done = false;
  const once = () => {
    if (!done) fn();
    done = true;
  };
  requestAnimationFrame(() => requestAnimationFrame(once));
  setTimeout(once, 250);
}

init().catch((err) => toast(`The page could not start: ${err.message}`));
