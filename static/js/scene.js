// The Review's 3-D scene: this tab's own viser scene in the iframe, opened again after a server restart.

import { api, VIEWER } from "./api.js";
import { $, act } from "./dom.js";
import { emit, state } from "./state.js";

export function showScene() {
  $("#scene").src = `/scene/${VIEWER}/`;
}

// The 3-D residuals' magnification, sent to this tab's scene and said over it (the scene's labels say it too).
async function magnify() {
  const factor = +$("#scene-magnify-select").value || 1;
  await api("POST", "/review/magnify", { factor });
  const said = $("#scene-magnify");
  said.hidden = factor === 1;
  said.textContent = `residuals x${factor}`;
}

export function wireScene() {
  $("#frame-marks").addEventListener("click", () => act(() => api("POST", "/review/frame-marks")));
  // viser's own notice of software WebGL covers part of the view: the scene hides it and tells us (viser_notice.js).
  window.addEventListener("message", (e) => {
    if (e.origin === window.location.origin && e.data && e.data.scene === "software-webgl") $("#scene-software").hidden = false;
  });
  $("#scene-magnify-select").addEventListener("change", () => act(magnify));
}

// A restarted server knows nothing of this tab's viewer, and viser's client in an iframe does not reconnect
// until it gets focus: when /api/health names another server instance, reload the scene and show the review
// (and frame) this tab showed.
export function watchServer(instance) {
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
  await magnify();  // the new server's viewer draws at x1
  if (!state.session || !state.reviewAsked) return;
  const frame = state.frame;
  await emit("review:load", ...state.reviewAsked);
  if (frame !== null && state.frameOrder.includes(frame)) await emit("frame:select", frame);
}
