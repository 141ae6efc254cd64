// The calibration desk page: plain ES module, talks to the JSON API under /api and embeds the viser
// scene in an iframe (served by the same port under /scene). State lives on the server; this file only
// shows it and sends the operator's actions.

const $ = (sel) => document.querySelector(sel);
const DEBUG = new URLSearchParams(location.search).has("debug");  // timings on the page (`?debug=1`)
const state = {
  robots: {},          // name -> /api/robots entry
  robot: null,         // the selected robot: the connected one, or one with real data only (not drivable)
  sessions: [],        // /api/sessions, newest first
  session: null,       // the selected session (full /api/sessions/{id} answer)
  calibrations: [],    // of the selected session
  review: null,        // the last /api/review answer
  reviewAsked: null,   // [old, new, sensor] as that review was asked for (shown again after a server restart)
  frameOrder: [],      // frame indices in slider order
  frame: null,         // the selected frame index
  newCal: null,        // the calibration under review (id)
  job: null,           // {id, source} of the job whose progress is shown
  sort: { key: "err_new", dir: -1 },
  events: false,       // the robot's state is streamed (robotEvents)
  replaySeed: null,    // the seed of the N new configurations a dry run checked (null: a new one next)
};

// --- HTTP ------------------------------------------------------------------------------------
// Off loopback the desk wants its access token: from `?token=` in the address calib serve printed (kept
// for this tab, then removed from the address bar), or asked once when the server answers 401.
const TOKEN_KEY = "calib-access-token";
(function takeToken() {
  const url = new URL(location.href);
  const token = url.searchParams.get("token");
  if (!token) return;
  sessionStorage.setItem(TOKEN_KEY, token);
  url.searchParams.delete("token");
  history.replaceState(null, "", url);
})();

// This tab's viewer: its own review and 3-D scene on the server, so another tab never moves them. A new one
// per page load (a duplicated tab gets its own); every request names it, and the scene's iframe is its own.
// crypto.getRandomValues, not randomUUID: the desk may be served over plain http off loopback.
const VIEWER = Array.from(crypto.getRandomValues(new Uint8Array(16)), (b) => b.toString(16).padStart(2, "0")).join("");

async function api(method, path, body, retried = false) {
  const opts = { method, headers: { "X-Viewer": VIEWER } };
  const token = sessionStorage.getItem(TOKEN_KEY);
  if (token) opts.headers.Authorization = `Bearer ${token}`;
  if (body instanceof FormData) opts.body = body;
  else if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const res = await fetch(`/api${path}`, opts);
  const text = await res.text();
  const data = text ? JSON.parse(text) : null;
  if (res.status === 401 && !retried) {
    // Another request may have asked for the token meanwhile: retried with it without asking again.
    const now = sessionStorage.getItem(TOKEN_KEY);
    if ((now && now !== token) || (await askToken())) return api(method, path, body, true);
  }
  if (!res.ok) {
    const err = new Error((data && data.detail) || `${res.status} ${res.statusText}`);
    err.status = res.status;
    err.data = data;
    throw err;
  }
  return data;
}

// Asked once however many requests the server refused at once (the page starts with several in parallel).
let asking = null;
function askToken() {
  asking ??= new Promise((resolve) => setTimeout(() => {
    const given = window.prompt("This desk is reachable from the network: its access token, please " +
      "(calib serve printed it at its first start).");
    if (given) sessionStorage.setItem(TOKEN_KEY, given.trim());
    asking = null;
    resolve(Boolean(given));
  }));
  return asking;
}

function toast(message, kind = "error") {
  const t = $("#toast");
  t.textContent = message;
  t.className = kind;
  t.hidden = false;
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => (t.hidden = true), 6000);
}

async function act(fn) {
  try {
    return await fn();
  } catch (err) {
    toast(err.message);
    return null;
  }
}

// d decimals; a small figure (a laser tracker's errors in metres) keeps d significant digits instead of 0.000.
const fmt = (v, d = 3) => {
  if (v === null || v === undefined || Number.isNaN(v)) return "—";
  const x = Number(v);
  return x !== 0 && Math.abs(x) < 0.01 ? x.toPrecision(d) : x.toFixed(d);
};
// Text written only when it changes (no layout or repaint for the same words).
const setText = (e, text) => {
  if (e.textContent !== text) e.textContent = text;
};
const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "onclick") e.addEventListener("click", v);
    else if (k === "class") e.className = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return e;
};

// --- start-up ---------------------------------------------------------------------------------
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
  const sel = $("#robot-select");
  for (const r of Object.values(state.robots)) addRobotOption(r);
  sel.value = state.robot;
  sel.addEventListener("change", () => act(() => connect(sel.value)));
  wire();
  await loadSessions(undefined, sessions);
  if (Object.values(state.robots).some((r) => r.drivable)) robotEvents();
  buildJoints();
  showDrivable();
  await refreshActive(active);
  showTab(state.robots[state.robot].drivable ? "observe" : "review");  // the papers' first step
  watchServer(health.instance);
  document.body.dataset.ready = "1";
  afterPaint(showScene);  // after requests with the token: off loopback, their answers set the cookie the scene needs
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

function showScene() {
  $("#scene").src = `/scene/${VIEWER}/`;
}

// A restarted server knows nothing of this tab's viewer, and viser's client in an iframe does not reconnect
// until it gets focus: when /api/health names another server instance, reload the scene and show the review
// (and frame) this tab showed.
function watchServer(instance) {
  setInterval(async () => {
    const health = await api("GET", "/health").catch(() => null);
    if (!health || health.instance === instance) return;
    instance = health.instance;
    await act(reopenScene);
  }, 2000);
}

async function reopenScene() {
  await api("GET", "/robots");  // a new read cookie (off loopback): the old server's is no longer valid
  showScene();
  if (!state.session || !state.reviewAsked) return;
  const frame = state.frame;
  await loadReview(...state.reviewAsked);
  if (frame !== null && state.frameOrder.includes(frame)) await selectFrame(frame);
}

function addRobotOption(r) {
  $("#robot-select").append(el("option", { value: r.name }, r.drivable ? r.name : `${r.name} (real data only)`));
}

// A robot with real data only (no driver) has sessions imported from CSV, calibrations and reviews,
// but nothing to connect to or move: its capture and motion controls are disabled.
// This tab's 3-D scene shows the connected robot: a session and review of another robot are closed.
async function connect(robot) {
  if (state.robots[robot].drivable) await api("POST", "/robot/connect", { robot });
  state.robot = robot;
  if (state.session && state.session.robot !== robot) closeSession();
  fillReplaySources();
  buildJoints();
  showDrivable();
  await refreshActive();
}

function closeSession() {
  Object.assign(state, { session: null, review: null, reviewAsked: null, newCal: null, frame: null, frameOrder: [],
    calibrations: [] });
  for (const li of document.querySelectorAll("#sessions li")) li.classList.remove("selected");
  for (const sel of ["#frames", "#summary", "#parameters", "#warnings", "#calibrations"]) $(sel).replaceChildren();
  for (const sel of ["#split-old", "#split-new", "#histogram"]) {
    const canvas = $(sel);
    canvas.getContext("2d").clearRect(0, 0, canvas.width, canvas.height);
  }
  split.marks = null;
  marksCache.clear();
  $("#frame-summary").replaceChildren();
  $("#frame-label").textContent = "frame —";
  $("#frame-slider").max = 0;
  $("#split").hidden = !state.robots[state.robot].sensor.image;  // a laser tracker has no image to mark
  renderApply();
  jobControls();
}

const MOTION_CONTROLS = ["#capture", "#observe-on", "#autocapture", "#wander", "#dry-run", "#replay-start",
  "#goto", "#new-session button"];

// Pause while it runs, resume while paused, abort until it ends; no second replay or dry run meanwhile, none
// without a session to replay into. A dry run's job moves nothing: abort it, there is nothing to pause.
function replayControls(job) {
  state.replaySnap = job;
  const live = Boolean(job) && ["queued", "running"].includes(job.state);
  const pausable = live && job.kind !== "dry_run";
  const drivable = state.robots[state.robot].drivable;
  $("#replay-pause").disabled = !pausable || job.paused;
  $("#replay-resume").disabled = !pausable || !job.paused;
  $("#replay-abort").disabled = !live;
  for (const sel of ["#replay-start", "#dry-run"]) $(sel).disabled = live || !drivable || !state.session;
}

// The other buttons that start or stop work are enabled only when they can act: Calibrate with a session of
// measured frames and no calibration of the page running, Cancel while one runs, Capture with a session and a
// robot standing still (no capture in flight), Stop while the desk has a robot to stop.
function jobControls() {
  const drivable = state.robots[state.robot].drivable;
  const calibrating = Boolean(state.job && state.job.live);
  $("#calibrate-start").disabled = !state.session || !state.session.measured || calibrating;
  $("#calibrate-cancel").disabled = !calibrating;
  $("#capture").disabled = !drivable || !state.session || Boolean(state.moving) || Boolean(state.capturing);
  $("#stop").disabled = !Object.values(state.robots).some((r) => r.drivable);
  replayControls(state.replaySnap);
}

function showDrivable() {
  const drivable = state.robots[state.robot].drivable;
  for (const sel of MOTION_CONTROLS) $(sel).disabled = !drivable;
  jobControls();
  document.body.dataset.drivable = drivable ? "1" : "0";
  if (!drivable) {
    $("#robot-state").textContent = `${state.robot}: real data only (no robot to drive; import its sessions)`;
    $("#robot-state").className = "pill";
  }
}

function wire() {
  for (const b of document.querySelectorAll("#tabs button")) b.addEventListener("click", () => showTab(b.dataset.tab));
  $("#stop").addEventListener("click", stopAll);
  document.addEventListener("keydown", (e) => {
    if (e.key === "Escape") stopAll();
  });
  $("#new-session").addEventListener("submit", (e) => act(() => newSession(e)));
  $("#import-session").addEventListener("submit", (e) => act(() => importSession(e)));
  $("#add-robot").addEventListener("submit", (e) => act(() => addRobot(e)));
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
  const reviewAgain = () => act(() => loadReview($("#review-old").value, $("#review-new").value, $("#review-sensor").value || null));
  $("#review-load").addEventListener("click", reviewAgain);
  $("#review-sensor").addEventListener("change", reviewAgain);
  $("#frame-slider").addEventListener("input", () => selectFrame(state.frameOrder[+$("#frame-slider").value]));
  $("#step-back").addEventListener("click", () => step(-1));
  $("#step-fwd").addEventListener("click", () => step(+1));
  $("#play").addEventListener("click", togglePlay);
  $("#overlay").addEventListener("change", () => selectFrame(state.frame));
  $("#all-frames").addEventListener("change", () => selectFrame(state.frame));
  $("#apply").addEventListener("click", () => act(applyNew));
  wireSplit();
  $("#goto").addEventListener("click", () => act(async () => {
    if (!state.session || state.frame === null) throw new Error("select a frame first");
    await api("POST", `/sessions/${state.session.id}/frames/${state.frame}/goto`);
    toast(`Driving to frame ${state.frame}'s configuration.`, "info");
  }));
  $("#capture").addEventListener("click", () => act(captureNow));
  $("#observe-on").addEventListener("change", () => act(setObserve));
  $("#autocapture").addEventListener("change", () => act(setObserve));
  $("#wander").addEventListener("change", () => act(() => api("POST", "/robot/wander", { on: $("#wander").checked })));
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
      state.replayJob && act(() => api("POST", `/jobs/${state.replayJob}/${a === "abort" ? "cancel" : a}`)));
  }
}

function showTab(name) {
  for (const b of document.querySelectorAll("#tabs button")) b.classList.toggle("active", b.dataset.tab === name);
  for (const s of document.querySelectorAll(".tab")) s.hidden = s.id !== `tab-${name}`;
}

async function stopAll() {
  $("#wander").checked = false;
  await act(() => api("POST", "/robot/stop"));
  toast("Stopped.", "info");
}

// --- sessions --------------------------------------------------------------------------------
// Newest first: a session just made or imported is at the top of the list.
async function loadSessions(selectId, sessions = null) {
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

// A replay drives the robot in view through configurations of its own sessions only.
function fillReplaySources() {
  const mine = state.sessions.filter((s) => s.robot === state.robot);
  $("#replay-from").replaceChildren(...mine.map((s) => el("option", { value: s.id }, `${s.name} (${s.frames})`)));
}

async function openSession(id) {
  state.session = await api("GET", `/sessions/${id}`);
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
  jobControls();
  await loadCalibrations();
  await loadReview("active", state.calibrations.length ? state.calibrations[0].id : "");
}

async function loadCalibrations() {
  state.calibrations = (await api("GET", `/sessions/${state.session.id}/calibrations`)).reverse();
  const base = $("#base");
  base.replaceChildren(el("option", { value: "" }, "nominal model"), el("option", { value: "active" }, "robot's active calibration"));
  const oldSel = $("#review-old");
  const newSel = $("#review-new");
  oldSel.replaceChildren(el("option", { value: "active" }, "robot's active"), el("option", { value: "" }, "nominal model"));
  newSel.replaceChildren(el("option", { value: "" }, "(none)"));
  const ul = $("#calibrations");
  ul.replaceChildren();
  for (const c of state.calibrations) {
    const after = c.figures && c.figures.after ? `${fmt(c.figures.after.mean)} ${unit()}` : "";
    const label = `${c.mode} · ${c.created.replace("T", " ").slice(0, 19)} · ${after}`;
    for (const s of [base, oldSel, newSel]) s.append(el("option", { value: c.id }, label));
    ul.append(el("li", { "data-calibration": c.id, onclick: () => act(() => loadReview("active", c.id)) }, label));
  }
}

const unit = () => (state.review && state.review.summary ? state.review.summary.unit : "");

// A robot added to the running desk: a profile file (with its URDF when it says `urdf: ...`, and a zip of
// that URDF's meshes) or a built-in profile's name (another NAO), and a driver or none (real data only).
async function addRobot(e) {
  e.preventDefault();
  const form = new FormData(e.target);
  for (const key of ["profile_file", "urdf_file", "meshes_zip"]) if (!form.get(key) || !form.get(key).size) form.delete(key);
  for (const key of ["profile", "driver"]) if (!form.get(key)) form.delete(key);
  const robot = await api("POST", "/robots", form);
  state.robots[robot.name] = robot;
  addRobotOption(robot);
  e.target.reset();
  $("#robot-select").value = robot.name;
  await connect(robot.name);
  if (robot.drivable && !state.events) robotEvents();
  toast(`Robot ${robot.name} (${robot.model}) is on the desk.`, "info");
}

async function newSession(e) {
  e.preventDefault();
  const name = new FormData(e.target).get("name");
  const { id } = await api("POST", "/sessions", { robot: state.robot, name });
  e.target.reset();
  await loadSessions(id);
  showTab("observe");
}

async function importSession(e) {
  e.preventDefault();
  const form = new FormData(e.target);
  form.append("robot", state.robot);
  const { id, notes } = await api("POST", "/sessions/import", form);
  e.target.reset();
  await loadSessions(id);
  if (notes.length) toast(`Imported, but look: ${notes.join("; ")}`, "error");
  else toast("Imported.", "info");
}

// --- jobs: progress by server-sent events ------------------------------------------------------
function follow(jobId, onUpdate) {
  return new Promise((resolve) => {
    const es = new EventSource(`/api/jobs/${jobId}/events`);
    es.onmessage = (ev) => {
      const job = JSON.parse(ev.data);
      onUpdate(job);
      if (!["queued", "running"].includes(job.state)) {
        es.close();
        resolve(job);
      }
    };
    es.onerror = () => {
      es.close();
      api("GET", `/jobs/${jobId}`).then((job) => {
        onUpdate(job);
        resolve(job);
      });
    };
  });
}

async function startCalibration() {
  if (!state.session) throw new Error("select a session first");
  const baseValue = $("#base").value;
  const base = baseValue === "active" ? (await api("GET", `/robot/calibration?robot=${state.session.robot}`)).id : baseValue || null;
  const body = { mode: $("#mode").value, base, holdout: +$("#holdout").value };
  const { job } = await api("POST", `/sessions/${state.session.id}/calibrations`, body);
  state.job = { id: job, live: true };
  jobControls();
  const done = await follow(job, (j) => {
    state.job.live = ["queued", "running"].includes(j.state);
    jobControls();
    $("#job-progress").value = j.progress;
    const loading = j.state === "queued" && j.detail && j.detail.phase === "loading" ? " · reading the session's frames" : "";
    $("#job-state").textContent = `${j.state}${j.error ? `: ${j.error}` : ""}${loading}` +
      (j.cost && j.cost.length ? ` · iteration ${j.cost.length - 1}, cost ${j.cost[j.cost.length - 1].toExponential(3)}` : "");
    drawCurve($("#cost-curve"), j.cost || []);
  });
  if (done.state === "done") {
    const converged = done.detail.converged !== false;
    if (!converged) $("#job-state").textContent = `done, but the solver did not converge (${done.detail.solver_status})`;
    await loadCalibrations();
    await loadReview("active", done.result);
    showTab("review");
    if (converged) toast("Calibration done: review it, then apply.", "info");
    else toast(`The calibration did not converge (${done.detail.solver_status}): read the warnings before applying.`, "error");
  }
}

// --- review ----------------------------------------------------------------------------------
// `sensor`: whose observations (a session of several sensors); null: the data format's sensor.
async function loadReview(old, neu, sensor = null) {
  const body = { session: state.session.id, old: old || null, new: neu || null, sensor };
  state.review = await api("POST", "/review", body);
  marksCache.clear();  // the server's marks are of this review from now on
  state.reviewAsked = [old, neu, sensor];
  state.newCal = state.review.new;
  $("#review-old").value = old || "";
  $("#review-new").value = neu || "";
  const sensors = $("#review-sensor");
  const names = [...new Set([state.review.sensor, ...state.review.sensors])];
  sensors.replaceChildren(...names.map((s) => el("option", { value: s }, s)));
  sensors.value = state.review.sensor;
  $("#review-sensor-label").hidden = state.review.sensors.length < 2;
  // What the scene could not show as asked (a URDF robot's mesh that cannot be read): said once per review.
  $("#review-warnings").replaceChildren(...(state.review.warnings || []).map((w) => el("p", { class: "warning" }, w)));
  const rows = state.review.table;
  state.sort = { key: state.newCal ? "err_new" : "err_old", dir: -1 };
  const slider = $("#frame-slider");
  slider.max = Math.max(0, rows.length - 1);
  renderFrames();
  renderSummary();
  await renderParameters();
  renderApply();
  if (state.frameOrder.length) await selectFrame(state.frameOrder[0]);
}

function sortedRows(rows = state.review.table) {
  const { key, dir } = state.sort;
  const v = (r) => (r[key] === null || r[key] === undefined ? -Infinity : r[key]);
  // dir -1: largest first (worst first for errors); frames without an error go last either way.
  return [...rows].sort((a, b) => {
    const va = v(a);
    const vb = v(b);
    if (va === vb) return a.index - b.index;
    if (typeof va === "string" || typeof vb === "string") return dir * String(vb).localeCompare(String(va));
    if (va === -Infinity) return 1;
    if (vb === -Infinity) return -1;
    return dir < 0 ? vb - va : va - vb;
  });
}

// A frame's new-minus-old error (null without both) and its word: better (the new calibration's error is
// smaller), worse, or same (within 1% of the old error).
const change = (r) => (r.err_old === null || r.err_new === null || r.err_new === undefined ? null : r.err_new - r.err_old);
const verdict = (r) => {
  const d = change(r);
  if (d === null) return "";
  return Math.abs(d) <= 0.01 * Math.abs(r.err_old) ? "same" : d < 0 ? "better" : "worse";
};

// The frame list, sorted; stepping (◀ ▶|, the slider, play) follows its order.
function renderFrames() {
  const t = $("#frames");
  const u = unit();
  const cols = [["index", "frame"], ["status", "status"], ["err_old", `old ${u}`], ["err_new", `new ${u}`],
    ["change", `new−old ${u}`]];
  const withChange = state.review.table.map((r) => ({ ...r, change: change(r) }));
  t.replaceChildren(el("tr", {}, ...cols.map(([k, label]) => el("th", {
    "data-sort": k,
    onclick: () => {
      state.sort = { key: k, dir: state.sort.key === k ? -state.sort.dir : -1 };
      renderFrames();
      if (state.frame !== null) $("#frame-slider").value = state.frameOrder.indexOf(state.frame);
    },
  }, label + (state.sort.key === k ? (state.sort.dir < 0 ? " ▼" : " ▲") : "")))));
  const rows = sortedRows(withChange);
  state.frameOrder = rows.map((r) => r.index);
  for (const r of rows) {
    const v = verdict(r);
    t.append(el("tr", {
      "data-frame": r.index,
      class: `${r.index === state.frame ? "selected" : ""} ${r.heldout ? "heldout" : ""}`,
      onclick: () => selectFrame(r.index),
    }, el("td", {}, r.index + (r.heldout ? "*" : "")), el("td", {}, r.status), el("td", {}, fmt(r.err_old)),
    el("td", {}, fmt(r.err_new)), el("td", { class: v, "data-verdict": v }, r.change === null ? "—" : signed(r.change))));
  }
}

const signed = (v) => (v > 0 ? "+" : v < 0 ? "−" : "±") + fmt(Math.abs(v));

// The selected frame's figures: old and new error, their difference, better or worse.
function renderFrameSummary(index) {
  const r = state.review && state.review.table.find((x) => x.index === index);
  const box = $("#frame-summary");
  if (!r) {
    box.replaceChildren();
    return;
  }
  const u = unit();
  const v = verdict(r);
  const parts = [el("b", {}, `Frame ${index}${r.heldout ? " (held out)" : ""}`), ` ${r.status} · old calibration `,
    el("span", { class: "blue" }, `${fmt(r.err_old)} ${u}`)];
  if (state.review.new) {
    parts.push(" · new calibration ", el("span", { class: "green" }, `${fmt(r.err_new)} ${u}`));
    if (v) parts.push(" · ", el("span", { class: v, "data-verdict": v }, `${signed(change(r))} ${u} (${v})`));
  }
  box.replaceChildren(...parts);
  box.dataset.frame = index;
}

// Latest wins: while a scene update is in flight only the newest request waits behind it.
let selecting = false;
let pending = null;
async function selectFrame(index) {
  if (index === undefined || index === null) return;
  if (state.reviewStale) {  // frames captured since the review was loaded: the server's review is made anew
    state.reviewStale = false;
    await act(() => loadReview(...state.reviewAsked));
  }
  state.frame = index;
  $("#frame-slider").value = state.frameOrder.indexOf(index);
  $("#frame-label").textContent = `frame ${index} (${state.frameOrder.indexOf(index) + 1}/${state.frameOrder.length})`;
  // Only the rows that change (a session may have thousands).
  for (const tr of document.querySelectorAll("#frames tr.selected")) if (+tr.dataset.frame !== index) tr.classList.remove("selected");
  const row = document.querySelector(`#frames tr[data-frame="${index}"]`);
  if (row) {
    row.classList.add("selected");
    row.scrollIntoView({ block: "nearest" });
  }
  renderFrameSummary(index);
  if (selecting) {
    pending = index;
    return;
  }
  selecting = true;
  try {
    // The scene and the 2-D view at once: neither waits for the other.
    const [r] = await Promise.all([
      api("POST", "/review/frame", { index, all: $("#all-frames").checked, overlay: $("#overlay").checked }),
      drawSplit(index),
    ]);
    if (DEBUG) $("#scene-ms").textContent = `scene ${r.server_ms.toFixed(1)} ms`;
  } catch (err) {
    toast(err.message);
  } finally {
    selecting = false;
  }
  if (pending !== null && pending !== index) {
    const next = pending;
    pending = null;
    await selectFrame(next);
  } else pending = null;
}

function step(d) {
  const i = Math.min(Math.max(state.frameOrder.indexOf(state.frame) + d, 0), state.frameOrder.length - 1);
  return selectFrame(state.frameOrder[i]);
}

let playTimer = null;
function togglePlay() {
  if (playTimer) {
    clearInterval(playTimer);
    playTimer = null;
    $("#play").textContent = "▶";
    return;
  }
  $("#play").textContent = "❚❚";
  playTimer = setInterval(() => {
    const i = state.frameOrder.indexOf(state.frame);
    if (i >= state.frameOrder.length - 1) togglePlay();
    else step(1);
  }, 400);
}

// An image loaded and decoded (off the main thread) before it is drawn; null if it cannot be.
function loadImage(url) {
  const img = new Image();
  img.src = url;
  return img.decode().then(() => img, () => null);
}

// The 2-D split view: the frame's image at full size, both halves zoomed and panned together (wheel, drag,
// the buttons), measurements as red rings with their point numbers, predictions as dots in the side's colour,
// residuals as lines, optionally magnified (said on the view).
const split = { marks: null, img: null, zoom: 1, cx: null, cy: null, drag: null };

// Each frame's marks and decoded image, of the review shown (emptied when one is loaded), for the last
// MARKS_KEPT frames used: the frames a step goes to next are fetched ahead, so a step draws at once.
const MARKS_KEPT = 24;
const PREFETCH = [1, -1, 2];  // the frames fetched ahead, in the stepping order from the one shown
const marksCache = new Map();  // frame index -> Promise<{m, img}>, least recently used first

function frameMarks(index) {
  let got = marksCache.get(index);
  if (got) marksCache.delete(index);
  else {
    got = api("GET", `/review/marks/${index}`).then(async (m) => ({ m, img: m.image ? await loadImage(m.image) : null }));
    got.catch(() => marksCache.get(index) === got && marksCache.delete(index));  // asked again next time
  }
  marksCache.set(index, got);
  while (marksCache.size > MARKS_KEPT) marksCache.delete(marksCache.keys().next().value);
  return got;
}

async function drawSplit(index) {
  const robot = state.review && state.robots[state.review.robot];
  $("#split").hidden = Boolean(robot && !robot.sensor.image);  // a laser tracker has no image to mark
  if ($("#split").hidden) return;
  const { m, img } = await frameMarks(index);
  if (!split.marks || split.marks.width !== m.width || split.marks.height !== m.height) fitSplit(m);
  Object.assign(split, { marks: m, img });
  redrawSplit();
  const k = state.frameOrder.indexOf(index);
  for (const d of PREFETCH) {
    const next = state.frameOrder[k + d];
    if (k >= 0 && next !== undefined) frameMarks(next).catch(() => {});
  }
}

function fitSplit(m) {
  Object.assign(split, { zoom: 1, cx: (m.width || 640) / 2, cy: (m.height || 480) / 2 });
}

function redrawSplit() {
  const m = split.marks;
  if (!m) return;
  const found = (m.measured || []).some((p) => p);
  for (const [id, predicted, colour] of [["#split-old", m.old, "#0050ff"], ["#split-new", m.new, "#00b000"]]) {
    const canvas = $(id);
    drawMarks(canvas, split.img, m, predicted, colour, found);
    canvas.dataset.frame = m.index;
    canvas.dataset.status = found ? "measured" : "not found";
  }
  $("#zoom-level").textContent = `zoom ${split.zoom.toFixed(split.zoom < 10 ? 1 : 0)}x`;
}

// Image px -> canvas (CSS px) transform: the image fitted to the canvas, times the zoom, about (cx, cy).
function splitTransform(canvas, m) {
  const w = m.width || 640;
  const h = m.height || 480;
  const s = Math.min(canvas.clientWidth / w, canvas.clientHeight / h) * split.zoom;
  return { s, x0: canvas.clientWidth / 2 - split.cx * s, y0: canvas.clientHeight / 2 - split.cy * s, w, h };
}

// Points are [u, v] px or null (not measured; a prediction behind the camera): nulls are not drawn.
function drawMarks(canvas, img, m, predicted, colour, found) {
  const dpr = window.devicePixelRatio || 1;
  const cw = canvas.clientWidth;
  const ch = canvas.clientHeight;
  if (canvas.width !== Math.round(cw * dpr) || canvas.height !== Math.round(ch * dpr)) {
    canvas.width = Math.round(cw * dpr);
    canvas.height = Math.round(ch * dpr);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#222";
  ctx.fillRect(0, 0, cw, ch);
  const { s, x0, y0, w, h } = splitTransform(canvas, m);
  const at = (p) => [x0 + p[0] * s, y0 + p[1] * s];
  ctx.imageSmoothingEnabled = split.zoom < 4;  // zoomed in: the pixels as they are
  if (img) ctx.drawImage(img, x0, y0, w * s, h * s);
  else {
    ctx.strokeStyle = "#555";
    ctx.strokeRect(x0, y0, w * s, h * s);
  }
  const measured = m.measured || [];
  const mag = +$("#magnify").value || 1;
  if (predicted) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = 1.5;
    predicted.forEach((p, i) => {
      const q = measured[i];
      if (!p || !q) return;
      const [mx, my] = at(q);
      ctx.beginPath();
      ctx.moveTo(mx, my);
      ctx.lineTo(mx + (p[0] - q[0]) * mag * s, my + (p[1] - q[1]) * mag * s);
      ctx.stroke();
    });
    ctx.fillStyle = colour;
    for (const p of predicted) {
      if (!p) continue;
      const [x, y] = at(p);
      ctx.beginPath();
      ctx.arc(x, y, 2.5, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
  ctx.strokeStyle = "#ff2020";
  ctx.lineWidth = 2;
  for (const p of measured) {
    if (!p) continue;
    const [x, y] = at(p);
    ctx.beginPath();
    ctx.arc(x, y, 6, 0, 2 * Math.PI);
    ctx.stroke();
  }
  if ($("#indices").checked && spaced(measured, s)) {
    ctx.font = "10px sans-serif";
    ctx.lineWidth = 3;
    ctx.strokeStyle = "rgba(0,0,0,0.8)";
    ctx.fillStyle = "#fff";
    measured.forEach((p, i) => {
      if (!p) return;
      const [x, y] = at(p);
      ctx.strokeText(String(i), x + 6, y - 6);
      ctx.fillText(String(i), x + 6, y - 6);
    });
  }
  ctx.font = "12px sans-serif";
  ctx.fillStyle = "#eee";
  const notes = [];
  if (!predicted) notes.push("no calibration on this side");
  if (!found) notes.push("not found: the detector found no fixture in this frame");
  notes.forEach((t, k) => ctx.fillText(t, 8, 16 + 16 * k));
  if (mag > 1 && predicted) {
    ctx.fillStyle = "#ffd24a";
    ctx.font = "bold 13px sans-serif";
    const label = `residuals x${mag}`;
    ctx.fillText(label, cw - ctx.measureText(label).width - 8, 18);
  }
}

// Point numbers only where they do not cover each other: the closest two measurements at least 14 px apart.
function spaced(points, s) {
  const ps = points.filter((p) => p);
  if (ps.length < 2) return ps.length === 1;
  let closest = Infinity;
  for (let i = 0; i < ps.length; i++) {
    for (let j = i + 1; j < ps.length; j++) closest = Math.min(closest, Math.hypot(ps[i][0] - ps[j][0], ps[i][1] - ps[j][1]));
  }
  return closest * s >= 14;
}

function zoomSplit(factor, canvas = $("#split-old"), cssX = null, cssY = null) {
  const m = split.marks;
  if (!m) return;
  const before = splitTransform(canvas, m);
  const x = cssX ?? canvas.clientWidth / 2;
  const y = cssY ?? canvas.clientHeight / 2;
  const u = (x - before.x0) / before.s;  // the image point under the cursor stays there
  const v = (y - before.y0) / before.s;
  split.zoom = Math.min(Math.max(split.zoom * factor, 1), 64);
  const after = splitTransform(canvas, m);
  split.cx += (u - (x - after.x0) / after.s);
  split.cy += (v - (y - after.y0) / after.s);
  redrawSplit();
}

function wireSplit() {
  $("#zoom-in").addEventListener("click", () => zoomSplit(2));
  $("#zoom-out").addEventListener("click", () => zoomSplit(0.5));
  $("#zoom-fit").addEventListener("click", () => {
    if (split.marks) fitSplit(split.marks);
    redrawSplit();
  });
  $("#magnify").addEventListener("change", redrawSplit);
  $("#indices").addEventListener("change", redrawSplit);
  for (const canvas of [$("#split-old"), $("#split-new")]) {
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      const r = canvas.getBoundingClientRect();
      zoomSplit(e.deltaY < 0 ? 1.25 : 0.8, canvas, e.clientX - r.left, e.clientY - r.top);
    }, { passive: false });
    canvas.addEventListener("pointerdown", (e) => {
      split.drag = { x: e.clientX, y: e.clientY };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", (e) => {
      if (!split.drag || !split.marks) return;
      const { s } = splitTransform(canvas, split.marks);
      split.cx -= (e.clientX - split.drag.x) / s;
      split.cy -= (e.clientY - split.drag.y) / s;
      split.drag = { x: e.clientX, y: e.clientY };
      redrawSplit();
    });
    canvas.addEventListener("pointerup", () => (split.drag = null));
  }
  window.addEventListener("resize", redrawSplit);
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

async function renderParameters() {
  const t = $("#parameters");
  const w = $("#warnings");
  t.replaceChildren();
  w.replaceChildren();
  if (!state.newCal) return;
  const cal = await api("GET", `/calibrations/${state.newCal}`);
  state.newCalibration = cal;
  if (!cal.converged) {
    w.append(el("p", { class: "warning", "data-code": "not-converged" },
      `⚠ Did not converge: ${cal.solver.message} after ${cal.solver.iterations} iterations.`));
  }
  for (const d of cal.diagnostics.filter((d) => d.severity === "warning" && d.code !== "not-converged")) {
    w.append(el("p", { class: "warning", "data-code": d.code }, `⚠ ${d.message}`));
  }
  if (cal.outliers.length) {
    w.append(el("p", {}, `Outliers left out: ${cal.outliers.map((o) => `frame ${o.frame} (${fmt(o.error, 2)} ${o.unit})`).join(", ")}`));
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

// Round tick values covering [lo, hi]: about n of them, steps of 1, 2 or 5 times a power of ten.
function ticks(lo, hi, n = 4) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const p = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((k) => k * p).find((k) => k >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) out.push(+v.toPrecision(12));
  return out;
}

// Axes of a chart in the box (left, top) .. (right, bottom): tick values and a label on each axis.
function axes(ctx, box, xt, yt, xLabel, yLabel) {
  const { left, top, right, bottom, x, y } = box;
  ctx.strokeStyle = "#888";
  ctx.fillStyle = "#444";
  ctx.lineWidth = 1;
  ctx.font = "10px sans-serif";
  ctx.beginPath();
  ctx.moveTo(left, top);
  ctx.lineTo(left, bottom);
  ctx.lineTo(right, bottom);
  ctx.stroke();
  ctx.textAlign = "center";
  for (const [v, text] of xt) {
    ctx.beginPath();
    ctx.moveTo(x(v), bottom);
    ctx.lineTo(x(v), bottom + 3);
    ctx.stroke();
    ctx.fillText(text, x(v), bottom + 13);
  }
  ctx.fillText(xLabel, (left + right) / 2, bottom + 25);
  ctx.textAlign = "right";
  for (const [v, text] of yt) {
    ctx.beginPath();
    ctx.moveTo(left - 3, y(v));
    ctx.lineTo(left, y(v));
    ctx.stroke();
    ctx.fillText(text, left - 5, y(v) + 3);
  }
  ctx.save();
  ctx.translate(10, (top + bottom) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.textAlign = "center";
  ctx.fillText(yLabel, 0, 0);
  ctx.restore();
  ctx.textAlign = "left";
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
  axes(ctx, box, ticks(lo, hi, 5).map((v) => [v, fmt(v, 2)]), yt, `error (${unit()})`, "observations");
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

// --- apply -----------------------------------------------------------------------------------
function renderApply() {
  const id = state.newCal;
  $("#apply-what").textContent = id ? `${id}` : "— (run or pick a calibration)";
  $("#apply").disabled = !id;
  for (const f of ["json", "yaml", "urdf"]) {
    const a = $(`#export-${f}`);
    if (id) a.href = `/api/calibrations/${id}/export?format=${f}`;
    else a.removeAttribute("href");
  }
}

// A calibration worse than the active one, or moving a parameter beyond its sane bound, is applied only
// when the operator confirms the server's reasons (409); null when not applied.
async function applyCalibration(id, note) {
  try {
    return await api("POST", `/calibrations/${id}/apply`, { note });
  } catch (err) {
    if (err.status !== 409 || !err.data || !err.data.reasons) throw err;
    const ask = `${err.data.detail}\n\n- ${err.data.reasons.join("\n- ")}\n\nApply it anyway?`;
    if (!window.confirm(ask)) {
      toast("Not applied.", "info");
      return null;
    }
    return api("POST", `/calibrations/${id}/apply`, { note, confirm: true });
  }
}

async function applyNew() {
  if (state.applying) return;  // a double click: one apply
  state.applying = true;
  $("#apply").disabled = true;
  try {
    const r = await applyCalibration(state.newCal, "");
    if (r) await applied(r);
  } finally {
    state.applying = false;
    renderApply();
  }
}

async function applied(r) {
  await refreshActive();
  $("#apply-state").textContent = r.recorded ? `Active: ${r.active} (previous: ${r.previous || "nominal model"})`
    : `Active: ${r.active} (it already was: sent to the robot again, history unchanged)`;
  toast(r.recorded ? "Applied to the robot." : "Already the active calibration: sent to the robot again.", "info");
}

// The header and the Apply panel both say which calibration the robot runs; the history says for each apply
// when, which mode, and the mean error before and after (held out too) on the calibration's own session.
function activeCalibration() {
  return Promise.all([api("GET", `/robot/calibration?robot=${state.robot}`), api("GET", `/robot/history?robot=${state.robot}`)]);
}

// `asked`: activeCalibration() already under way (none: asked now).
async function refreshActive(asked = null) {
  const [a, history] = await (asked || activeCalibration());
  const active = a.id ? `${a.id} (${a.mode})` : "nominal model";
  $("#active-cal").textContent = active;
  $("#active-cal").dataset.id = a.id || "";
  $("#apply-active").textContent = active;
  $("#apply-active").dataset.id = a.id || "";
  const t = $("#history");
  t.replaceChildren(el("tr", {}, ...["applied", "calibration and its mean error", ""].map((h) => el("th", {}, h))));
  for (const [k, h] of history.entries()) {
    const f = h.figures || {};
    const u = (f.after && f.after.unit) || "";
    const errors = [f.before && `before ${fmt(f.before.mean)}`, f.after && `after ${fmt(f.after.mean)}`,
      f.holdout_after && `held out ${fmt(f.holdout_after.mean)}`].filter(Boolean).join(" → ");
    const current = k === 0 && h.calibration === a.id;  // the newest apply: what the robot runs
    t.append(el("tr", { "data-calibration": h.calibration, title: h.note || "" },
      el("td", {}, h.time.replace("T", " ").slice(0, 16)),
      el("td", {}, el("b", {}, h.mode || "—"), ` ${errors}${u ? ` ${u}` : ""}`, el("br", {}),
        el("small", {}, `${h.calibration}${h.session ? ` · ${h.session}` : ""}`)),
      el("td", {}, current ? el("small", {}, "active") : el("button", { class: "small", onclick: () => act(async () => {
        const r = await applyCalibration(h.calibration, "re-applied from history");
        if (r) await applied(r);
      }) }, "re-apply"))));
  }
}

// --- observe and replay ----------------------------------------------------------------------
// The joint sliders show the configuration the operator asks for, within the joint limits less the driver's
// safety margin (the server refuses a move closer to a limit). Moving one sends the whole configuration the
// sliders show: a joint still on its way keeps its target, not the reading it had when another slider moved.
function buildJoints() {
  const t = $("#joints");
  t.replaceChildren();
  const robot = state.robots[state.robot];
  state.driving = null;
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
  state.driving = { since: Infinity };  // the sliders show the target, not the readings, until the robot stops
  try {
    await api("POST", "/robot/move", { joints });
    state.driving = { since: performance.now() };
  } catch (err) {
    state.driving = null;
    slidersToReadings(true);
    toast(`Move refused: ${err.message}`);
  }
}

// The sliders follow the robot's readings while the page is not driving it (a wander, a replay, another tab);
// `all`: the slider in the operator's hand too.
function slidersToReadings(all = false) {
  for (const [name, deg] of Object.entries(state.readings || {})) {
    const slider = document.querySelector(`input[data-joint="${name}"]`);
    if (!slider || deg === null || (!all && document.activeElement === slider)) continue;
    if (Math.abs(+slider.value - deg) > 0.06) slider.value = deg;  // a step is 0.1 deg: the same position unwritten
  }
}

// The connected robot's state, streamed while the desk has a robot to drive.
function robotEvents() {
  state.events = true;
  const es = new EventSource("/api/robot/events");
  es.onmessage = (ev) => {
    const r = JSON.parse(ev.data);
    if (r.robot !== state.robot) return;
    // Ten times a second: the page is written only where something changed (a repaint of an unchanged page
    // costs a software-rendered browser as much as a changed one, and slows the 3-D view of every tab).
    setText($("#robot-state"), `${r.robot}: ${r.connected ? (r.moving ? "moving" : "still") : "disconnected"}`);
    $("#robot-state").classList.toggle("moving", r.moving);
    if (Boolean(state.moving) !== r.moving) {
      state.moving = r.moving;
      jobControls();
    }
    state.readings = r.joints;
    for (const [name, deg] of Object.entries(r.joints)) {
      const cell = document.querySelector(`[data-reading="${name}"]`);
      if (cell) setText(cell, deg === null ? "—" : `${deg.toFixed(1)}°`);
    }
    const d = state.driving;
    if (d && !r.moving && performance.now() - d.since > SLIDERS_FOLLOW_AFTER_MS) state.driving = null;
    if (!state.driving) slidersToReadings();
    const o = r.observing;
    if (o && state.session && o.session === state.session.id && o.captured > (state.autoCaptured || 0)) showNewFrames(o.session);
    state.autoCaptured = o ? o.captured : 0;
    setText($("#observe-state"), o ? `live: ${o.detection || "…"}${o.reason && o.reason !== "ok" ? ` (${o.reason})` : ""} · ${o.captured} auto-captured` : "");
  };
  es.onerror = () => {
    $("#robot-state").textContent = "server unreachable";
    es.close();
    setTimeout(robotEvents, 2000);
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
  toast(`Frame ${frame.index}: ${frame.status}${frame.reason && frame.reason !== "ok" ? ` (${frame.reason})` : ""}`, "info");
  await loadSessions(state.session.id);
}

async function replay(dry) {
  if (!state.session) throw new Error("select a session first");
  const source = document.querySelector("input[name=replay-source]:checked").value;
  const body = { dry_run: dry, remeasure: source === "remeasure" };
  if (source === "from") body.from_session = $("#replay-from").value;
  if (source === "count" || source === "until") {
    // New poses each replay, the same ones for a dry run and the replay that follows it.
    state.replaySeed ??= crypto.getRandomValues(new Uint32Array(1))[0];
    Object.assign(body, { seed: state.replaySeed }, replayPlanning(source));
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
  state.replayJob = r.job;
  state.replaySeed = null;
  const sid = state.session.id;
  const watching = () => $("#observe-on").checked || $("#autocapture").checked;
  // The 3-D robot follows the robot while the replay drives it (the live view), whether or not "Watch live" is on.
  if (!watching()) await act(() => api("POST", `/sessions/${sid}/observe`, { on: true, autocapture: false }));
  let done = 0;
  await follow(r.job, (j) => {
    $("#replay-progress").value = j.progress;
    replayControls(j);
    const d = j.detail || {};
    if ((d.done || 0) > done) {
      done = d.done;
      showNewFrames(sid);
    }
    const planning = j.state === "running" && d.phase === "planning" ? ` · ${planningText(d)}` : "";
    const shown = j.paused && j.state === "running" ? "paused" : j.state;
    $("#replay-state").textContent = `${shown}${j.error ? `: ${j.error}` : ""}${planning}${d.frame ? ` · frame ${d.frame}: ${d.status}` : ""}`;
    if (d.curve) showUntilProgress(d);
  });
  replayControls(null);
  if (!watching()) await act(() => api("POST", `/sessions/${sid}/observe`, { on: false }));
  await loadSessions(state.session.id);
}

// A dry run's job: its progress (planning, checking, predicting) in the Replay step; Abort or Esc cancels it.
// Its result (null: it did not finish) once done.
async function followDryRun(jobId) {
  state.replayJob = jobId;
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
    el("p", { class: "predicted" }, `Predicted after a ${mode} calibration from the ${p.n} configurations captured: ` +
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

// Frames captured while the page looks on (a replay, auto-capture) join the frame list at once: fetched with
// the session, shown without errors (none computed yet) until the review is next loaded. Latest wins.
let refreshing = null;
async function showNewFrames(sid) {
  if (refreshing) {
    refreshing.again = true;
    return;
  }
  refreshing = { again: false };
  try {
    do {
      refreshing.again = false;
      if (!state.session || state.session.id !== sid) return;
      const s = await api("GET", `/sessions/${sid}`);
      if (!state.session || state.session.id !== sid) return;
      state.session = s;
      const li = document.querySelector(`#sessions li[data-session="${sid}"] small`);
      if (li) li.textContent = ` ${s.robot} · ${s.measured}/${s.frames.length} frames measured`;
      if (!state.review || state.review.session !== sid) continue;
      const rows = new Map(state.review.table.map((row) => [row.index, row]));
      let changed = false;
      for (const f of s.frames) {
        const row = rows.get(f.index);
        if (row && row.status === f.status) continue;
        if (row) Object.assign(row, { status: f.status, err_old: null, err_new: null });
        else state.review.table.push({ index: f.index, status: f.status, err_old: null, err_new: null, heldout: false });
        changed = true;
      }
      if (!changed) continue;
      state.reviewStale = true;  // the server's review lacks them: selecting one loads the review again
      renderFrames();  // the frame list's order is the stepping order
      $("#frame-slider").max = Math.max(0, state.frameOrder.length - 1);
    } while (refreshing.again);
  } catch (err) {
    toast(err.message);
  } finally {
    refreshing = null;
  }
}

init().catch((err) => toast(`The page could not start: ${err.message}`));
