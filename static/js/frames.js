// The Review's frames: the sortable list, the selected frame and its figures, stepping and playing through
// them, frames captured meanwhile. A selected frame is shown in the 3-D scene and the 2-D view at once.

import { api } from "./api.js";
import { $, act, el, fmt, toast } from "./dom.js";
import { DEBUG, emit, on, reviewUnit, state } from "./state.js";

let reviewStale = false;  // frames captured since the review was loaded: the server's review lacks them

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

// A frame's new-minus-old error (null without both) and the server's word for it: better or worse beyond k
// bands (how far the calibrations' own uncertainty moves the frame's predictions), same within; none
// without a band (no calibration with a covariance), so the change is not coloured.
const change = (r) => (r.err_old === null || r.err_new === null || r.err_new === undefined ? null : r.err_new - r.err_old);
const verdict = (r) => (change(r) === null ? "" : r.verdict || "");

const signed = (v) => (v > 0 ? "+" : v < 0 ? "−" : "±") + fmt(Math.abs(v));

// A review loaded: its frames listed worst first (by the new calibration's error, the old one's without a new).
function listReview(review) {
  state.sort = { key: state.newCal ? "err_new" : "err_old", dir: -1 };
  $("#frame-slider").max = Math.max(0, review.table.length - 1);
  renderFrames();
}

// The frame list, sorted; stepping (◀ ▶|, the slider, play) follows its order.
function renderFrames() {
  const t = $("#frames");
  const u = reviewUnit();
  const cols = [["index", "frame"], ["status", "status"], ["err_old", `old ${u}`], ["err_new", `new ${u}`],
    ["change", `new−old ${u}`]];
  const withChange = state.review.table.map((r) => ({ ...r, change: change(r) }));
  t.replaceChildren(el("tr", {}, ...cols.map(([k, label]) => el("th", {
    "data-sort": k,
    onclick: () => {
      state.sort = { key: k, dir: state.sort.key === k ? -state.sort.dir : -1 };
      renderFrames();
      showPosition();
      revealSelected();
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

// The selected frame's row in view: out of it, centred below the list's sticky header; then the panel scrolled to
// it if need be. Nothing while the list is hidden.
function revealSelected() {
  const row = document.querySelector("#frames tr.selected");
  if (!row || !row.offsetParent) return;
  const list = row.closest(".scroll");
  const box = list.getBoundingClientRect();
  const top = box.top + $("#frames tr").getBoundingClientRect().height;
  const r = row.getBoundingClientRect();
  if (r.top < top || r.bottom > box.bottom) list.scrollTop += r.top - (top + box.bottom - r.height) / 2;
  row.scrollIntoView({ block: "nearest" });
}

// The selected frame's figures: old and new error, their difference, better or worse.
function renderFrameSummary(index) {
  const r = state.review && state.review.table.find((x) => x.index === index);
  const box = $("#frame-summary");
  if (!r) {
    box.replaceChildren();
    return;
  }
  const u = reviewUnit();
  const v = verdict(r);
  const title = el("b", {}, `Frame ${index}${r.heldout ? " (held out)" : ""}`);
  if (r.err_old === null || r.err_old === undefined) {  // nothing measured: no error to give, only why
    box.replaceChildren(title, ` ${r.status}: no error to show`);  // the 2-D view says why
    box.dataset.frame = index;
    return;
  }
  const parts = [title, ` ${r.status} · old calibration `, el("span", { class: "blue" }, `${fmt(r.err_old)} ${u}`)];
  if (state.review.new) {
    parts.push(" · new calibration ", el("span", { class: "green" }, `${fmt(r.err_new)} ${u}`));
    if (change(r) !== null) {
      const band = r.band === null || r.band === undefined ? "" : `, band ${fmt(r.band)} ${u}`;
      parts.push(" · ", el("span", { class: v, "data-verdict": v }, `${signed(change(r))} ${u} (${v || "no band"}${band})`));
    }
  }
  box.replaceChildren(...parts);
  box.dataset.frame = index;
}

// The slider and its label at the selected frame's place in the frame list's order.
function showPosition() {
  const slider = $("#frame-slider");
  slider.max = Math.max(0, state.frameOrder.length - 1);
  slider.value = state.frameOrder.indexOf(state.frame);
  $("#frame-label").textContent = state.frame === null ? "frame —"
    : `frame ${state.frame} (${state.frameOrder.indexOf(state.frame) + 1}/${state.frameOrder.length})`;
}

// Latest wins: while a scene update is in flight only the newest request waits behind it.
let selecting = false;
let pending = null;
async function selectFrame(index) {
  if (index === undefined || index === null) return;
  if (reviewStale) {  // the server's review is made anew
    reviewStale = false;
    await act(() => emit("review:load", ...state.reviewAsked));
  }
  state.frame = index;
  showPosition();
  // Only the rows that change (a session may have thousands).
  for (const tr of document.querySelectorAll("#frames tr.selected")) if (+tr.dataset.frame !== index) tr.classList.remove("selected");
  const row = document.querySelector(`#frames tr[data-frame="${index}"]`);
  if (row) row.classList.add("selected");
  revealSelected();
  renderFrameSummary(index);
  if (selecting) {
    pending = index;
    return;
  }
  selecting = true;
  try {
    // The scene and the 2-D view (`frame:shown`) at once: neither waits for the other.
    const [r] = await Promise.all([
      api("POST", "/review/frame", { index, all: $("#all-frames").checked, overlay: $("#overlay").checked }),
      emit("frame:shown", index),
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

// Frames captured while the page looks on (a replay, auto-capture) join the frame list at once: fetched with
// the session, then their errors (the review's figures asked again, `review:refresh`, its scene untouched:
// selecting a new frame loads the review again). Latest wins.
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
      reviewStale = true;  // selecting one loads the review again
      renderFrames();  // the frame list's order is the stepping order
      showPosition();
      await emit("review:refresh");  // their errors: `review:refreshed` lists them
    } while (refreshing.again);
  } catch (err) {
    toast(err.message);
  } finally {
    refreshing = null;
  }
}

// The review's figures asked again: the list, the slider and the selected frame's figures with them.
function refreshed() {
  renderFrames();
  showPosition();
  renderFrameSummary(state.frame);
}

// No session: no frames, none selected.
function clearFrames() {
  $("#frames").replaceChildren();
  $("#frame-summary").replaceChildren();
  $("#frame-label").textContent = "frame —";
  $("#frame-slider").max = 0;
}

export function wireFrames() {
  on("frames:captured", showNewFrames);
  on("session:closed", clearFrames);
  on("review:shown", listReview);
  on("review:refreshed", refreshed);
  on("frame:select", selectFrame);
  // A review loaded while its tab was hidden (a calibration's end) selected its frame unseen: shown, the list
  // goes to it.
  new ResizeObserver(revealSelected).observe($("#frames").parentElement);
  $("#frame-slider").addEventListener("input", () => selectFrame(state.frameOrder[+$("#frame-slider").value]));
  $("#step-back").addEventListener("click", () => step(-1));
  $("#step-fwd").addEventListener("click", () => step(+1));
  $("#play").addEventListener("click", togglePlay);
  $("#overlay").addEventListener("change", () => selectFrame(state.frame));
  $("#all-frames").addEventListener("change", () => selectFrame(state.frame));
  $("#goto").addEventListener("click", () => act(async () => {
    if (!state.session || state.frame === null) throw new Error("select a frame first");
    await api("POST", `/sessions/${state.session.id}/frames/${state.frame}/goto`);
    toast(`Driving to frame ${state.frame}'s configuration.`, "info");
  }));
}
