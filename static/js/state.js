// What the page modules share: the server's last answers and the operator's selection. State lives on the
// server; this object only holds what the page shows. A module's own working variables stay in that module.

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
