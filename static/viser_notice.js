// In the 3-D scene's page (viser's client, served by app/web/scene_proxy.py): viser's "Software WebGL rendering
// detected" notice covers a corner of the view until it is closed, on every machine without a GPU (most laptops
// beside a robot, every screenshot of a headless browser). It is hidden here and the scene tells the desk's page,
// which says it in a line of its own under the view (static/js/scene.js). viser's other notices stay.
(() => {
  const TITLE = "Software WebGL rendering detected";
  let told = false;

  function quiet() {
    for (const title of document.querySelectorAll("[class*='Notification-title']")) {
      if (title.textContent.trim() !== TITLE) continue;
      const root = title.closest("[class*='Notification-root']");
      if (root && root.style.display !== "none") root.style.display = "none";  // hidden, left to React to remove
      if (!told && window.parent !== window) {
        told = true;
        window.parent.postMessage({ scene: "software-webgl" }, window.location.origin);
      }
    }
  }

  new MutationObserver(quiet).observe(document.documentElement, { childList: true, subtree: true });
})();
