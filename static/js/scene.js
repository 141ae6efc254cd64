// The Review's 3-D scene: this tab's own viser scene in the iframe, opened again after a server restart.

import { api, VIEWER } from "./api.js";
import { $, act } from "./dom.js";
import { selectFrame } from "./frames.js";
import { loadReview } from "./review.js";
import { state } from "./state.js";

export function showScene() {
  $("#scene").src = `/scene/${VIEWER}/`;
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
  if (!state.session || !state.reviewAsked) return;
  const frame = state.frame;
  await loadReview(...state.reviewAsked);
  if (frame !== null && state.frameOrder.includes(frame)) await selectFrame(frame);
}
