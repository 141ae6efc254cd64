// Step 6, History: the robot's applied calibrations read together (what drifts, with its rate a day; what changed
// beyond both calibrations' uncertainty; a small plot per parameter that moved, most moved first) and the robots of
// its model side by side (the odd one out, which calibration each runs and how old it is). It reads the server's
// analysis (GET /api/robot/drift, /api/team) and imports no other panel: it reloads when its tab is opened and,
// while it is open, when the robot's active calibration is shown anew (the event `active:shown`: another robot
// chosen, a calibration applied).

import { api } from "./api.js";
import { $, act, el, fmt } from "./dom.js";
import { on, state } from "./state.js";

const SVG = "http://www.w3.org/2000/svg";
let asked = 0;  // the newest load: an older answer arriving late is dropped

function svg(tag, attrs = {}) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
}

const shown = () => !$("#tab-history").hidden;

export async function loadHistory() {
  const robot = state.robot;
  const mine = ++asked;
  const [drift, team] = await Promise.all([
    api("GET", `/robot/drift?robot=${encodeURIComponent(robot)}`),
    api("GET", `/team?robot=${encodeURIComponent(robot)}`),
  ]);
  if (mine !== asked) return;
  renderDrift(drift);
  renderTeam(team, robot);
  $("#tab-history").dataset.robot = robot;
}

function renderDrift(d) {
  const n = d.calibrations.length;
  const head = $("#drift-summary");
  $("#drift-csv").href = `/api/robot/drift.csv?robot=${encodeURIComponent(d.robot)}`;
  if (n < 2) {
    head.replaceChildren(el("p", { class: "hint" }, n === 0
      ? `No calibration applied to ${d.robot} yet: its history starts with the first one applied (step 5).`
      : `One calibration applied to ${d.robot} (${d.calibrations[0]}): a second one is needed to compare.`));
    $("#drift-plots").replaceChildren();
    return;
  }
  const flagged = d.steps.filter((s) => s.flagged);
  const times = d.series.flatMap((s) => s.points.map((p) => p.measured)).sort();
  const span = times.length ? `, measured from ${day(times[0])} to ${day(times.at(-1))}` : "";
  const lines = [
    el("p", {}, `${n} calibrations applied${span}; each change tested against both calibrations' uncertainty `
      + `(a history where nothing moved shows a flag ${fmt(100 * d.level, 0)}% of the time).`),
  ];
  for (const t of d.trends) lines.push(el("p", { class: "trend" }, el("b", {}, "Drifts: "), t.sentence));
  for (const s of flagged) lines.push(el("p", { class: "flag" }, el("b", {}, "Changed: "), s.sentence));
  if (!d.trends.length && !flagged.length) {
    lines.push(el("p", { class: "steady" }, "Nothing moved beyond what the calibrations' uncertainty explains."));
  }
  for (const note of d.notes) lines.push(el("p", { class: "hint" }, note));
  head.replaceChildren(...lines);
  drawSeries(d);
}

function drawSeries(d) {
  const every = $("#drift-all").checked;
  const series = d.series.filter((s) => every || s.moved);
  const plots = series.map((s) => plot(s, d));
  if (!every && series.length < d.series.length) {
    plots.push(el("p", { class: "hint" }, `${d.series.length - series.length} parameters moved less than 3 sd: `
      + "tick \"every parameter\" to see them."));
  }
  $("#drift-plots").replaceChildren(...plots);
}

const day = (iso) => iso.slice(0, 10);

// One parameter: each calibration's value as its fit gave it (grey, +-2 sd), and held with the other parameters at
// what the history fits for them (blue dot, +-2 sd band: the precision a single parameter's move is read with),
// the trend's line if it drifts. x: days since the first calibration.
function plot(s, d) {
  const W = 330, H = 96, L = 52, R = 8, T = 6, B = 18;
  const t0 = Date.parse(s.points[0].measured);
  const x = (p) => (Date.parse(p.measured) - t0) / 86400000;
  const xs = s.points.map(x);
  const held = s.points.every((p) => p.held !== null);
  const ys = s.points.flatMap((p) => (held ? [p.held - 2 * p.held_sd, p.held + 2 * p.held_sd] : [p.value - 2 * p.sd, p.value + 2 * p.sd]));
  let lo = Math.min(...ys), hi = Math.max(...ys);
  if (!(hi > lo)) [lo, hi] = [lo - 1, hi + 1];
  const span = Math.max(...xs) || 1;
  const X = (v) => L + ((W - L - R) * v) / span;
  const Y = (v) => T + ((H - T - B) * (hi - v)) / (hi - lo);
  const g = svg("svg", { width: W, height: H, viewBox: `0 0 ${W} ${H}`, class: "drift-plot", "data-parameter": s.parameter });
  g.append(svg("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "#888" }),
    svg("line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "#888" }));
  for (const [v, anchor] of [[hi, "hanging"], [lo, "auto"]]) {
    const label = svg("text", { x: L - 4, y: Y(v), "text-anchor": "end", "dominant-baseline": anchor, "font-size": 9 });
    label.textContent = fmt(v, 3);
    g.append(label);
  }
  const xl = svg("text", { x: W - R, y: H - 4, "text-anchor": "end", "font-size": 9 });
  xl.textContent = `${fmt(span, 1)} days`;
  g.append(xl);
  if (held) {
    const upper = s.points.map((p, i) => `${X(xs[i])},${Y(p.held + 2 * p.held_sd)}`);
    const lower = s.points.map((p, i) => `${X(xs[i])},${Y(p.held - 2 * p.held_sd)}`).reverse();
    g.append(svg("polygon", { points: [...upper, ...lower].join(" "), fill: "rgba(0,0,255,0.12)", stroke: "none" }));
  }
  s.points.forEach((p, i) => {
    const lo2 = Math.max(Y(p.value + 2 * p.sd), T), hi2 = Math.min(Y(p.value - 2 * p.sd), H - B);
    if (!held) g.append(svg("line", { x1: X(xs[i]), x2: X(xs[i]), y1: lo2, y2: hi2, stroke: "#999" }));
    const dot = svg("circle", { cx: X(xs[i]), cy: Y(held ? p.held : p.value), r: 2.5, fill: held ? "#00f" : "#555" });
    const tip = svg("title");
    tip.textContent = `${p.calibration} · ${day(p.measured)}: ${fmt(p.value, 4)} ± ${fmt(p.sd, 3)} ${s.unit} as fitted`
      + (held ? `; ${fmt(p.held, 4)} ± ${fmt(p.held_sd, 3)} with the others held` : "");
    dot.append(tip);
    g.append(dot);
  });
  if (s.trend) {
    const mid = xs.reduce((a, b) => a + b, 0) / xs.length;
    const at = s.points.reduce((a, p) => a + p.held, 0) / xs.length;
    const f = (v) => at + s.trend.rate_per_day * (v - mid);
    g.append(svg("line", { x1: X(0), y1: Y(f(0)), x2: X(span), y2: Y(f(span)), stroke: "#c00", "stroke-dasharray": "4 2" }));
  }
  const rate = s.trend ? ` · ${s.trend.rate_per_day > 0 ? "+" : ""}${fmt(s.trend.rate_per_day, 4)} ${s.unit} a day` : "";
  return el("figure", { class: "drift" }, el("figcaption", {}, el("b", {}, s.parameter), ` (${s.unit}) · moved `
    + `${fmt(s.moved_sd, 1)} sd${rate}`), g);
}

function renderTeam(t, robot) {
  const table = $("#team");
  const members = t.members;
  $("#team-block").hidden = members.length < 2;
  if (members.length < 2) return;
  $("#team-title").textContent = `Robots of model ${t.model}`;
  table.replaceChildren(el("tr", {}, ...["robot", "active calibration", "age"].map((h) => el("th", {}, h))));
  for (const m of members) {
    const odd = t.odd.filter((o) => o.robot === m.robot);
    table.append(el("tr", { "data-robot": m.robot, class: `${m.robot === robot ? "me" : ""} ${odd.length ? "odd" : ""}` },
      el("td", {}, m.robot), el("td", {}, m.calibration ? `${m.calibration} (${m.mode})` : "nominal model"),
      el("td", {}, m.age_days === null ? "—" : `${fmt(m.age_days, m.age_days < 10 ? 1 : 0)} d`)));
  }
  const lines = t.odd.map((o) => el("p", { class: "flag" }, el("b", {}, "Odd one out: "), o.sentence));
  const compared = members.filter((m) => m.calibration).length;
  if (!t.odd.length) {
    lines.push(el("p", { class: "hint" }, compared < 3
      ? "Three robots or more with an applied calibration are compared parameter by parameter."
      : `No robot is far from the others (${compared} compared, each parameter against the others' spread).`));
  }
  $("#team-odd").replaceChildren(...lines);
  // Each parameter across the robots compared, the most off first (every one with "every parameter").
  const cols = t.parameters.length ? t.parameters[0].robots.map((s) => s.robot) : [];
  const rows = $("#drift-all").checked ? t.parameters : t.parameters.slice(0, 6);
  $("#team-parameters").replaceChildren(...(rows.length ? [
    el("tr", {}, el("th", {}, "parameter"), ...cols.map((r) => el("th", {}, r))),
    ...rows.map((c) => el("tr", { "data-parameter": c.parameter }, el("td", {}, `${c.parameter} (${c.unit})`),
      ...cols.map((r) => {
        const s = c.robots.find((x) => x.robot === r);
        if (!s) return el("td", {}, "—");
        return el("td", { class: c.odd === r ? "odd" : "", title: `${fmt(s.value, 4)} ± ${fmt(s.sd, 3)} ${c.unit}: `
          + `${fmt(s.z, 1)} sd from the others' mean` }, fmt(s.value, 3));
      }))),
  ] : []));
}

export function wireHistory() {
  const reload = () => shown() && act(loadHistory);
  $("#tabs button[data-tab='history']").addEventListener("click", () => act(loadHistory));
  on("active:shown", reload);
  $("#drift-all").addEventListener("change", reload);
}
