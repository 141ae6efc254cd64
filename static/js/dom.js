// The page's small helpers: a selector, an element builder, text written only when it changes, figures and
// calibrations named, and the toast that says what went wrong.

export const $ = (sel) => document.querySelector(sel);

// d decimals; a small figure (a laser tracker's errors in metres) keeps d significant digits instead of 0.000.
export const fmt = (v, d = 3) => {
  if (v === null || v === undefined || Number.isNaN(v)) return "—";
  const x = Number(v);
  return x !== 0 && Math.abs(x) < 0.01 ? x.toPrecision(d) : x.toFixed(d);
};

// The unit errors are shown in and the factor to it: a length in metres reads better in millimetres (a tracker's
// 0.0000716 m is 0.0716 mm); cm, mm and px as they are.
export const displayUnit = (unit) => (unit === "m" ? ["mm", 1000] : [unit, 1]);

// A calibration as the page names it (Calibrate's list, the Review's choices, Apply): its mode and when it was made.
export const calibrationName = (c) => `${c.mode} · ${c.created.replace("T", " ").slice(0, 19)}`;

// Text written only when it changes (no layout or repaint for the same words).
export const setText = (e, text) => {
  if (e.textContent !== text) e.textContent = text;
};

export const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "onclick") e.addEventListener("click", v);
    else if (k === "class") e.className = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return e;
};

let toastTimer = null;
export function toast(message, kind = "error") {
  const t = $("#toast");
  t.textContent = message;
  t.className = kind;
  t.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => (t.hidden = true), 6000);
}

// An operator's action: its error said in the toast (null returned).
export async function act(fn) {
  try {
    return await fn();
  } catch (err) {
    toast(err.message);
    return null;
  }
}

// A form's own check before it is sent. The forms are `novalidate`: the browser's check of a control inside a
// closed <details> cannot show where it is and only logs "An invalid form control ... is not focusable". Here
// its <details> opens, the first invalid control takes the focus, and the toast names it.
export function checkForm(form) {
  const bad = form.querySelector(":invalid");
  if (!bad) return;
  const details = form.closest("details");
  if (details) details.open = true;
  bad.focus();
  const label = bad.closest("label");
  throw new Error(`${label ? label.firstChild.textContent.trim() : bad.name}: ${bad.validationMessage}`);
}
