// What the page modules share: the server's last answers and the operator's selection (`state`), and the events
// through which the panels hear of each other (`on`, `emit`). State lives on the server; `state` only holds what
// the page shows. A module's own working variables stay in that module.
//
// A panel imports no other panel (tests/test_page_modules.py): it reads and writes `state`, says what it did or
// asks for work another panel owns with `emit`, and does its own part of what others say with `on`
// (docs/page.md lists the events, who emits each and who listens).

export const state = {
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
  job: null,           // {id, live} of the calibration whose progress is shown
  replaySnap: null,    // the last snapshot of the replay or dry run job shown (null: none running)
  sort: { key: "err_new", dir: -1 },
  moving: false,       // the robot moves (its last streamed state)
  capturing: false,    // a capture of this page is in flight
};

export const DEBUG = new URLSearchParams(location.search).has("debug");  // timings on the page (`?debug=1`)

// The unit the review's errors are shown in ("" without a review).
export const reviewUnit = () => (state.review && state.review.summary ? state.review.summary.unit : "");

// --- events ------------------------------------------------------------------------------------------------
// A name "thing:done" tells what happened (listeners do their part); "thing:do" asks the panel that owns the
// work to do it (one listener). Listeners subscribe in their panel's wireX(), so they run in app.js's wire order.
const listeners = new Map();  // event name -> [fn, ...]

export function on(event, fn) {
  if (!listeners.has(event)) listeners.set(event, []);
  listeners.get(event).push(fn);
}

// Each listener is called at once, in turn, with `args`: what it does before its first await is done when emit
// returns, as if the emitter had called it. The promise of them all: an emitter that needs the work done before
// it goes on (a review loaded, then its frame selected) awaits it; one that did not wait does not.
export function emit(event, ...args) {
  return Promise.all((listeners.get(event) || []).map((fn) => fn(...args)));
}
