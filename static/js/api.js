// The JSON API under /api and a job's progress by server-sent events.

import { askToken, token } from "./token.js";

// This tab's viewer: its own review and 3-D scene on the server, so another tab never moves them. A new one
// per page load (a duplicated tab gets its own); every request names it, and the scene's iframe is its own.
// crypto.getRandomValues, not randomUUID: the desk may be served over plain http off loopback.
export const VIEWER = Array.from(crypto.getRandomValues(new Uint8Array(16)), (b) => b.toString(16).padStart(2, "0")).join("");

export async function api(method, path, body, retried = false) {
  const opts = { method, headers: { "X-Viewer": VIEWER } };
  const sent = token();
  if (sent) opts.headers.Authorization = `Bearer ${sent}`;
  if (body instanceof FormData) opts.body = body;
  else if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const res = await fetch(`/api${path}`, opts);
  const text = await res.text();
  const data = text ? JSON.parse(text) : null;
  if (res.status === 401 && !retried) {
    // Another request may have asked for the token meanwhile: retried with it without asking again.
    const now = token();
    if ((now && now !== sent) || (await askToken())) return api(method, path, body, true);
  }
  if (!res.ok) {
    const err = new Error((data && data.detail) || `${res.status} ${res.statusText}`);
    err.status = res.status;
    err.data = data;
    throw err;
  }
  return data;
}

// A job's snapshots, each to onUpdate, until it ends; its last snapshot.
export function follow(jobId, onUpdate) {
  return new Promise((resolve) => {
    const es = new EventSource(`/api/jobs/${jobId}/events`);
    es.onmessage = (ev) => {
      const job = JSON.parse(ev.data);
      onUpdate(job);
      if (!["queued", "running"].includes(job.state)) {
        es.close();
        resolve(job);
      }
    };
    es.onerror = () => {
      es.close();
      api("GET", `/jobs/${jobId}`).then((job) => {
        onUpdate(job);
        resolve(job);
      });
    };
  });
}
