// In the 3-D scene's page (viser's client, served by app/web/scene_proxy.py): the review's marks drawn over the robot's
// bodies, so a hand in front of its board, or the overlay's translucent copy, never hides a measurement. viser's
// API has no depth test for point clouds and line segments: this reads the three.js object of each marks node
// from viser's client (window.__viserMutable.nodeRefFromName, the hook viser keeps for its own browser tests;
// app/scene/viser_private.py lists every such use, tests/test_browser_scene.py checks it on the pinned viser) and turns
// their materials' depth test off, drawing them last: the old side's, then the new side's over them (as
// app/scene/review_scene/marks.py lifts the new side nearer); on each side the residual lines, the rings, then the prediction dots.
(() => {
  const MARKS = /^\/(review\/(old|new)|live)\/base\/(frame|all)\/(lines|measured|predicted)$/;
  const ORDER = 9000;  // after every body (viser's are at 0), before viser's labels (10 001 and on)
  const SIDE = { old: 0, new: 10, undefined: 0 };
  const PART = { lines: 0, measured: 1, predicted: 2 };

  function overBodies(object, order) {
    object.traverse((o) => {
      if (!o.material) return;
      o.renderOrder = order;
      for (const m of Array.isArray(o.material) ? o.material : [o.material]) {
        if (m.depthTest === false && m.transparent) continue;
        m.depthTest = false;
        m.depthWrite = false;
        m.transparent = true;  // drawn with the translucent bodies, after them (renderOrder)
        m.needsUpdate = true;
      }
    });
  }

  function marksOverBodies() {
    const nodes = window.__viserMutable && window.__viserMutable.nodeRefFromName;
    if (!nodes) return;
    for (const [name, object] of Object.entries(nodes)) {
      const m = object && MARKS.exec(name);
      if (m) overBodies(object, ORDER + SIDE[m[2]] + PART[m[4]]);
    }
  }

  // Before each frame viser draws (it draws on demand), not in a loop of our own: an idle scene then costs
  // nothing (a loop per animation frame kept a software-rendered browser busy at 60 Hz). The scene exists once
  // the client has connected: looked for four times a second, in case the client makes another.
  let hooked = null;
  function hook() {
    const scene = window.__viserMutable && window.__viserMutable.scene;
    if (!scene || scene === hooked) return;
    const before = scene.onBeforeRender;
    scene.onBeforeRender = function (...args) {
      marksOverBodies();
      return before.apply(this, args);
    };
    hooked = scene;
  }
  hook();
  setInterval(hook, 250);
})();
