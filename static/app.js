// The calibration desk page: plain ES module, talks to the JSON API under /api and embeds the viser
// scene in an iframe (served by the same port under /scene). State lives on the server; this file only
// shows it and sends the operator's actions.

const $ = (sel) => document.querySelector(sel);
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
    const given = window.prompt("This desk is reachable from the network: its access token, please " +
      "(calib serve printed it at its first start).");
    if (given) {
      sessionStorage.setItem(TOKEN_KEY, given.trim());
      return api(method, path, body, true);
    }
  }
  if (!res.ok) {
    const err = new Error((data && data.detail) || `${res.status} ${res.statusText}`);
    err.status = res.status;
    err.data = data;
    throw err;
  }
  return data;
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

// --- start-up --------------------------------------------------------------------------------
async function init() {
  const health = await api("GET", "/health");
  for (const r of await api("GET", "/robots")) state.robots[r.name] = r;
  showScene();  // after a request with the token: off loopback, its answer set the cookie the scene needs
  const sel = $("#robot-select");
  for (const r of Object.values(state.robots)) addRobotOption(r);
  // The connected robot; a desk without a drivable robot has none: the first one is shown.
  const status = await api("GET", "/robot").catch(() => null);
  state.robot = status ? status.robot : Object.keys(state.robots)[0];
  sel.value = state.robot;
  sel.addEventListener("change", () => act(() => connect(sel.value)));
  wire();
  await loadSessions();
  if (Object.values(state.robots).some((r) => r.drivable)) robotEvents();
  buildJoints();
  showDrivable();
  await refreshActive();
  showTab(state.robots[state.robot].drivable ? "observe" : "review");  // the papers' first step
  watchServer(health.instance);
  document.body.dataset.ready = "1";
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
  $("#frame-label").textContent = "frame —";
  $("#frame-slider").max = 0;
  $("#split").hidden = !state.robots[state.robot].sensor.image;  // a laser tracker has no image to mark
  renderApply();
  jobControls();
}

const MOTION_CONTROLS = ["#capture", "#observe-on", "#autocapture", "#wander", "#dry-run", "#replay-start",
  "#goto", "#new-session button"];

// Pause while it runs, resume while paused, abort until it ends; no second replay meanwhile, none without a
// session to replay into.
function replayControls(job) {
  state.replaySnap = job;
  const live = Boolean(job) && ["queued", "running"].includes(job.state);
  const drivable = state.robots[state.robot].drivable;
  $("#replay-pause").disabled = !live || job.paused;
  $("#replay-resume").disabled = !live || !job.paused;
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
  $("#goto").addEventListener("click", () => act(async () => {
    if (!state.session || state.frame === null) throw new Error("select a frame first");
    await api("POST", `/sessions/${state.session.id}/frames/${state.frame}/goto`);
    toast(`Driving to frame ${state.frame}'s configuration.`, "info");
  }));
  $("#capture").addEventListener("click", () => act(captureNow));
  $("#observe-on").addEventListener("change", () => act(setObserve));
  $("#autocapture").addEventListener("change", () => act(setObserve));
  $("#wander").addEventListener("change", () => act(() => api("POST", "/robot/wander", { on: $("#wander").checked })));
  $("#dry-run").addEventListener("click", () => act(() => replay(true)));
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
async function loadSessions(selectId) {
  state.sessions = (await api("GET", "/sessions")).sort((a, b) => b.created.localeCompare(a.created));
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

// A robot added to the running desk: a profile file (with its URDF when it says `urdf: ...`) or a built-in
// profile's name (another NAO), and a driver or none (real data only).
async function addRobot(e) {
  e.preventDefault();
  const form = new FormData(e.target);
  for (const key of ["profile_file", "urdf_file"]) if (!form.get(key) || !form.get(key).size) form.delete(key);
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
      if (!["queued", "running", "paused"].includes(job.state)) {
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
  state.reviewAsked = [old, neu, sensor];
  state.newCal = state.review.new;
  $("#review-old").value = old || "";
  $("#review-new").value = neu || "";
  const sensors = $("#review-sensor");
  const names = [...new Set([state.review.sensor, ...state.review.sensors])];
  sensors.replaceChildren(...names.map((s) => el("option", { value: s }, s)));
  sensors.value = state.review.sensor;
  $("#review-sensor-label").hidden = state.review.sensors.length < 2;
  const rows = state.review.table;
  state.sort = { key: state.newCal ? "err_new" : "err_old", dir: -1 };
  state.frameOrder = rows.map((r) => r.index);
  const slider = $("#frame-slider");
  slider.max = Math.max(0, rows.length - 1);
  renderFrames();
  renderSummary();
  await renderParameters();
  renderApply();
  const worst = sortedRows()[0];
  if (worst) await selectFrame(worst.index);
}

function sortedRows() {
  const { key, dir } = state.sort;
  const v = (r) => (r[key] === null || r[key] === undefined ? -Infinity : r[key]);
  // dir -1: largest first (worst first for errors); frames without an error go last either way.
  return [...state.review.table].sort((a, b) => {
    const va = v(a);
    const vb = v(b);
    if (va === vb) return a.index - b.index;
    if (typeof va === "string" || typeof vb === "string") return dir * String(vb).localeCompare(String(va));
    if (va === -Infinity) return 1;
    if (vb === -Infinity) return -1;
    return dir < 0 ? vb - va : va - vb;
  });
}

function renderFrames() {
  const t = $("#frames");
  const u = unit();
  const cols = [["index", "frame"], ["status", "status"], ["err_old", `old ${u}`], ["err_new", `new ${u}`]];
  t.replaceChildren(el("tr", {}, ...cols.map(([k, label]) => el("th", {
    onclick: () => {
      state.sort = { key: k, dir: state.sort.key === k ? -state.sort.dir : -1 };
      renderFrames();
    },
  }, label + (state.sort.key === k ? (state.sort.dir < 0 ? " ▼" : " ▲") : "")))));
  for (const r of sortedRows()) {
    t.append(el("tr", {
      "data-frame": r.index,
      class: `${r.index === state.frame ? "selected" : ""} ${r.heldout ? "heldout" : ""}`,
      onclick: () => selectFrame(r.index),
    }, el("td", {}, r.index + (r.heldout ? "*" : "")), el("td", {}, r.status), el("td", {}, fmt(r.err_old)),
    el("td", {}, fmt(r.err_new))));
  }
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
  for (const tr of document.querySelectorAll("#frames tr[data-frame]")) tr.classList.toggle("selected", +tr.dataset.frame === index);
  if (selecting) {
    pending = index;
    return;
  }
  selecting = true;
  try {
    const r = await api("POST", "/review/frame", { index, all: $("#all-frames").checked, overlay: $("#overlay").checked });
    $("#scene-ms").textContent = `scene ${r.server_ms.toFixed(1)} ms`;
    await drawSplit(index);
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

const images = new Map();
function loadImage(url) {
  if (!images.has(url)) {
    images.set(url, new Promise((resolve) => {
      const img = new Image();
      img.onload = () => resolve(img);
      img.onerror = () => resolve(null);
      img.src = url;
    }));
  }
  return images.get(url);
}

async function drawSplit(index) {
  const robot = state.review && state.robots[state.review.robot];
  $("#split").hidden = Boolean(robot && !robot.sensor.image);  // a laser tracker has no image to mark
  if ($("#split").hidden) return;
  const m = await api("GET", `/review/marks/${index}`);
  const img = m.image ? await loadImage(m.image) : null;
  const found = (m.measured || []).some((p) => p);
  for (const [id, predicted, colour] of [["#split-old", m.old, "#0050ff"], ["#split-new", m.new, "#00b000"]]) {
    const canvas = $(id);
    drawMarks(canvas, img, m, predicted, colour, found);
    canvas.dataset.frame = index;
    canvas.dataset.status = found ? "measured" : "not found";
  }
}

// Points are [u, v] px or null (not measured; a prediction behind the camera): nulls are not drawn.
function drawMarks(canvas, img, m, predicted, colour, found) {
  const ctx = canvas.getContext("2d");
  const w = m.width || 640;
  const h = m.height || 480;
  const s = Math.min(canvas.width / w, canvas.height / h);
  ctx.fillStyle = "#222";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  if (img) ctx.drawImage(img, 0, 0, w * s, h * s);
  const dot = (p, c, r) => {
    ctx.beginPath();
    ctx.arc(p[0] * s, p[1] * s, r, 0, 2 * Math.PI);
    ctx.fillStyle = c;
    ctx.fill();
  };
  const measured = m.measured || [];
  if (predicted) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = 1;
    predicted.forEach((p, i) => {
      if (!p || !measured[i]) return;
      ctx.beginPath();
      ctx.moveTo(p[0] * s, p[1] * s);
      ctx.lineTo(measured[i][0] * s, measured[i][1] * s);
      ctx.stroke();
    });
    for (const p of predicted) if (p) dot(p, colour, 3);
  }
  for (const p of measured) if (p) dot(p, "#ff0000", 3);
  ctx.fillStyle = "#ccc";
  if (!predicted) ctx.fillText("no calibration on this side", 8, 16);
  if (!found) ctx.fillText("not found: the detector found no fixture in this frame", 8, predicted ? 16 : 32);
}

function renderSummary() {
  const s = state.review.summary;
  const u = s.unit;
  const cols = [["old", "old"], ["new", "new"], ["heldout_old", "held-out old"], ["heldout_new", "held-out new"]]
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
  t.append(el("tr", {}, ...["parameter", "old", "new", "change", "std", "unit"].map((h) => el("th", {}, h))));
  for (const p of cal.parameters) {
    if (!p.estimated && Math.abs(p.value - p.base) < 1e-12) continue;
    t.append(el("tr", { class: p.estimated ? "" : "fixed", title: p.note || "" },
      el("td", {}, p.label), el("td", {}, fmt(p.base, 4)), el("td", {}, fmt(p.value, 4)),
      el("td", {}, fmt(p.value - p.base, 4)), el("td", {}, p.std === null ? "held" : fmt(p.std, 4)), el("td", {}, p.unit)));
  }
}

function drawHistogram(canvas, hist) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!hist || !hist.edges || hist.edges.length < 2) return;
  const n = hist.edges.length - 1;
  const series = [["old", "#0050ff"], ["new", "#00b000"]].filter(([k]) => hist[k]);
  const top = Math.max(1, ...series.flatMap(([k]) => hist[k]));
  const bw = (canvas.width - 20) / n;
  series.forEach(([k, c], si) => {
    ctx.fillStyle = c;
    hist[k].forEach((v, i) => {
      const bh = (v / top) * (canvas.height - 20);
      ctx.fillRect(10 + i * bw + (si * bw) / series.length, canvas.height - 12 - bh, bw / series.length - 1, bh);
    });
  });
  ctx.fillStyle = "#444";
  ctx.font = "10px sans-serif";
  ctx.fillText(`${fmt(hist.edges[0], 2)}`, 4, canvas.height - 1);
  ctx.fillText(`${fmt(hist.edges[n], 2)} ${unit()}`, canvas.width - 60, canvas.height - 1);
}

function drawCurve(canvas, ys) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (ys.length < 1) return;
  const ls = ys.map((y) => Math.log10(Math.max(y, 1e-300)));
  const lo = Math.min(...ls);
  const hi = Math.max(...ls);
  ctx.strokeStyle = "#333";
  ctx.beginPath();
  ls.forEach((l, i) => {
    const x = 10 + (i / Math.max(1, ls.length - 1)) * (canvas.width - 20);
    const y = 10 + (hi === lo ? 0.5 : (hi - l) / (hi - lo)) * (canvas.height - 20);
    if (i) ctx.lineTo(x, y);
    else ctx.moveTo(x, y);
  });
  ctx.stroke();
  ctx.fillStyle = "#444";
  ctx.fillText("log cost", 12, 12);
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

async function refreshActive() {
  const a = await api("GET", `/robot/calibration?robot=${state.robot}`);
  $("#active-cal").textContent = a.id ? `${a.id} (${a.mode})` : "nominal model";
  $("#active-cal").dataset.id = a.id || "";
  const t = $("#history");
  t.replaceChildren(el("tr", {}, ...["applied", "calibration", "mode", "session", "after", ""].map((h) => el("th", {}, h))));
  for (const h of await api("GET", `/robot/history?robot=${state.robot}`)) {
    t.append(el("tr", {}, el("td", {}, h.time.replace("T", " ").slice(0, 19)), el("td", {}, h.calibration),
      el("td", {}, h.mode || ""), el("td", {}, h.session || ""),
      el("td", {}, h.figures && h.figures.after ? fmt(h.figures.after.mean) : ""),
      el("td", {}, el("button", { onclick: () => act(async () => {
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
    if (slider && deg !== null && (all || document.activeElement !== slider)) slider.value = deg;
  }
}

// The connected robot's state, streamed while the desk has a robot to drive.
function robotEvents() {
  state.events = true;
  const es = new EventSource("/api/robot/events");
  es.onmessage = (ev) => {
    const r = JSON.parse(ev.data);
    if (r.robot !== state.robot) return;
    $("#robot-state").textContent = `${r.robot}: ${r.connected ? (r.moving ? "moving" : "still") : "disconnected"}`;
    $("#robot-state").className = `pill ${r.moving ? "moving" : ""}`;
    if (Boolean(state.moving) !== r.moving) {
      state.moving = r.moving;
      jobControls();
    }
    state.readings = r.joints;
    for (const [name, deg] of Object.entries(r.joints)) {
      const cell = document.querySelector(`[data-reading="${name}"]`);
      if (cell) cell.textContent = deg === null ? "—" : `${deg.toFixed(1)}°`;
    }
    const d = state.driving;
    if (d && !r.moving && performance.now() - d.since > SLIDERS_FOLLOW_AFTER_MS) state.driving = null;
    if (!state.driving) slidersToReadings();
    const o = r.observing;
    if (o && state.session && o.session === state.session.id && o.captured > (state.autoCaptured || 0)) showNewFrames(o.session);
    state.autoCaptured = o ? o.captured : 0;
    $("#observe-state").textContent = o ? `live: ${o.detection || "…"}${o.reason && o.reason !== "ok" ? ` (${o.reason})` : ""} · ${o.captured} auto-captured` : "";
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
  if (source === "count") {
    // New poses each replay, the same ones for a dry run and the replay that follows it.
    state.replaySeed ??= crypto.getRandomValues(new Uint32Array(1))[0];
    Object.assign(body, { count: +$("#replay-count").value, seed: state.replaySeed });
  }
  if ($("#replay-continue").checked) body.resume = true;
  const r = await api("POST", `/sessions/${state.session.id}/replay`, body);
  if (dry) {
    const bad = r.configurations.filter((c) => !c.ok);
    const moved = r.configurations.filter((c) => c.ok && c.note);
    const box = $("#dry-run-result");
    box.replaceChildren(el("p", {}, `${r.configurations.length} configurations, ${bad.length} with a problem` +
      (moved.length ? `, ${moved.length} moved out of the safety margin` : "")));
    for (const c of bad) box.append(el("p", { class: "warning" }, `#${c.index}: ${c.problem}`));
    for (const c of moved) box.append(el("p", { class: "note" }, `#${c.index}: ${c.note}`));
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
    const planning = j.state === "running" && d.phase === "planning" ? " · planning the configurations" : "";
    const shown = j.paused && j.state === "running" ? "paused" : j.state;
    $("#replay-state").textContent = `${shown}${j.error ? `: ${j.error}` : ""}${planning}${d.frame ? ` · frame ${d.frame}: ${d.status}` : ""}`;
  });
  replayControls(null);
  if (!watching()) await act(() => api("POST", `/sessions/${sid}/observe`, { on: false }));
  await loadSessions(state.session.id);
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
      state.frameOrder = state.review.table.map((row) => row.index);
      $("#frame-slider").max = Math.max(0, state.frameOrder.length - 1);
      renderFrames();
    } while (refreshing.again);
  } catch (err) {
    toast(err.message);
  } finally {
    refreshing = null;
  }
}

init().catch((err) => toast(`The page could not start: ${err.message}`));
