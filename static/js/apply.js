// Step 5, Apply: the calibration under review sent to the robot, its exports, the history of applies; the
// header's active calibration.

import { api } from "./api.js";
import { $, act, calibrationName, displayUnit, el, fmt, toast } from "./dom.js";
import { emit, on, state } from "./state.js";

let applying = false;  // an apply of this page is in flight

// What Apply applies is the calibration under review, named as the Review shows it (its id in data-id).
function renderApply() {
  const id = state.newCal;
  const c = state.calibrations.find((x) => x.id === id);
  $("#apply-what").textContent = id ? `${id}${c ? ` (${calibrationName(c)})` : ""}` : "— (run or pick a calibration)";
  $("#apply-what").dataset.id = id || "";
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
  if (applying) return;  // a double click: one apply
  applying = true;
  $("#apply").disabled = true;
  try {
    const r = await applyCalibration(state.newCal, "");
    if (r) await applied(r);
  } finally {
    applying = false;
    renderApply();
  }
}

async function applied(r) {
  await refreshActive();
  await emit("calibration:applied");  // the Review shows it where its old side is the robot's active calibration
  const sent = r.deployed ? ` On the robot: ${r.deployed}.` : "";  // what the driver did with it (ROS 2, NAOqi)
  $("#apply-state").textContent = (r.recorded ? `Active: ${r.active} (previous: ${r.previous || "nominal model"})`
    : `Active: ${r.active} (it already was: sent to the robot again, history unchanged)`) + sent;
  toast((r.recorded ? "Applied to the robot." : "Already the active calibration: sent to the robot again.") + sent, "info");
}

// The header and the Apply panel both say which calibration the robot runs; the history says for each apply
// when, which mode, and the mean error before and after (held out too) on the calibration's own session.
export function activeCalibration() {
  return Promise.all([api("GET", `/robot/calibration?robot=${state.robot}`), api("GET", `/robot/history?robot=${state.robot}`)]);
}

// `asked`: activeCalibration() already under way (none: asked now).
export async function refreshActive(asked = null) {
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
    const [u, factor] = displayUnit((f.after && f.after.unit) || "");
    // Means over the calibration's own session: the observations it was fitted on, then those it held out.
    const v = (x) => `${fmt(x.mean * factor)}${u ? ` ${u}` : ""}`;
    const fitted = [f.before && `before ${v(f.before)}`, f.after && `after ${v(f.after)}`].filter(Boolean).join(" → ");
    const errors = [fitted && `${fitted}${f.after ? ` (mean over the ${f.after.n} fitted)` : ""}`,
      f.holdout_after && `held out ${v(f.holdout_after)} (${f.holdout_after.n})`].filter(Boolean).join(" · ");
    const session = h.session && ((state.sessions || []).find((x) => x.id === h.session) || { name: h.session }).name;
    const current = k === 0 && h.calibration === a.id;  // the newest apply: what the robot runs
    t.append(el("tr", { "data-calibration": h.calibration, title: h.note || "" },
      el("td", {}, h.time.replace("T", " ").slice(0, 16)),
      el("td", {}, el("b", {}, h.mode || "—"), ` ${errors}`, el("br", {}),
        el("small", {}, `${h.calibration}${session ? ` · ${session}` : ""}`)),
      el("td", {}, current ? el("small", {}, "active") : el("button", { class: "small", onclick: () => act(async () => {
        const r = await applyCalibration(h.calibration, "re-applied from history");
        if (r) await applied(r);
      }) }, "re-apply"))));
  }
  emit("active:shown");  // the History panel reads it again if open
}

export function wireApply() {
  on("calibration:chosen", renderApply);
  on("robot:turned", () => refreshActive());
  $("#apply").addEventListener("click", () => act(applyNew));
}
