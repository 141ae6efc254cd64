// Off loopback the desk wants its access token: from `?token=` in the address calib serve printed (kept
// for this tab, then removed from the address bar), or asked once when the server answers 401.

const TOKEN_KEY = "calib-access-token";

(function takeToken() {
  const url = new URL(location.href);
  const token = url.searchParams.get("token");
  if (!token) return;
  sessionStorage.setItem(TOKEN_KEY, token);
  url.searchParams.delete("token");
  history.replaceState(null, "", url);
})();

export const token = () => sessionStorage.getItem(TOKEN_KEY);

// Asked once however many requests the server refused at once (the page starts with several in parallel).
let asking = null;
export function askToken() {
  asking ??= new Promise((resolve) => setTimeout(() => {
    const given = window.prompt("This desk is reachable from the network: its access token, please " +
      "(calib serve printed it at its first start).");
    if (given) sessionStorage.setItem(TOKEN_KEY, given.trim());
    asking = null;
    resolve(Boolean(given));
  }));
  return asking;
}
