// Step 1, Observe: what the camera sees now. The latest settled look's image with what the finder found (red
// rings, vision) and where the robot's active calibration puts the target (blue dots), fetched when the robot's
// stream names a new look and this step is on screen.

import { api } from "./api.js";
import { $, setText } from "./dom.js";
import { on, state } from "./state.js";

let shown = 0;         // the look on the canvas
let asking = false;    // a look is being fetched: the next stream message asks again if still newer

// Nothing looked at: not observing, or another robot.
function clearLive() {
  if (!shown) return;
  shown = 0;
  const canvas = $("#live-image");
  canvas.replaceWith(canvas.cloneNode(false));
  setText($("#live-caption"), "");
  $("#live").hidden = true;
}

// `look`: the number of the robot's latest look (the stream's observing.look), undefined when there is none.
async function showLook(look) {
  if (!look || look === shown || asking || $("#tab-observe").hidden) return;
  asking = true;
  try {
    const robot = state.robot;
    const l = await api("GET", `/robot/look?robot=${encodeURIComponent(robot)}`).catch(() => null);
    if (!l || robot !== state.robot || l.look <= shown) return;
    shown = l.look;
    $("#live").hidden = false;
    const img = l.image ? await decoded(l.image) : null;
    draw($("#live-image"), img, l);
    const found = l.measured ? l.measured.filter(Boolean).length : 0;
    setText($("#live-caption"), `look ${l.look}, ${l.sensor} on ${l.target}: ` +
      (l.status === "measured" ? `${found} points found` : `${l.status}${l.reason && l.reason !== l.status ? ` (${l.reason})` : ""}`) +
      (l.image ? "" : " · this sensor takes no image"));
  } finally {
    asking = false;
  }
}

export function wireLive() {
  // The robot's stream: what it observes (null: nothing, or the tab turned to another robot).
  on("robot:observing", (o) => (o ? showLook(o.look) : clearLive()));
}

function decoded(url) {
  const img = new Image();
  img.src = url;
  return img.decode().then(() => img);
}

function draw(canvas, img, l) {
  const w = l.width || 640;
  const h = l.height || 480;
  canvas.width = w;
  canvas.height = h;
  const ctx = canvas.getContext("2d");
  if (img) ctx.drawImage(img, 0, 0);
  const r = Math.max(2, w / 200);
  ctx.fillStyle = "#1d5bd8";
  for (const p of l.predicted || []) {
    if (!p) continue;
    ctx.beginPath();
    ctx.arc(p[0], p[1], r, 0, 2 * Math.PI);
    ctx.fill();
  }
  ctx.strokeStyle = "#ff2020";
  ctx.lineWidth = Math.max(1.5, w / 320);
  for (const p of l.measured || []) {
    if (!p) continue;
    ctx.beginPath();
    ctx.arc(p[0], p[1], 2.5 * r, 0, 2 * Math.PI);
    ctx.stroke();
  }
  canvas.dataset.look = l.look;
}
