// Axes of the page's charts (the Calibrate step's cost curve, the Review's histogram): round ticks, labels.

// Round tick values covering [lo, hi]: about n of them, steps of 1, 2 or 5 times a power of ten.
export function ticks(lo, hi, n = 4) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const p = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((k) => k * p).find((k) => k >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) out.push(+v.toPrecision(12));
  return out;
}

// Axes of a chart in the box (left, top) .. (right, bottom): tick values and a label on each axis.
export function axes(ctx, box, xt, yt, xLabel, yLabel) {
  const { left, top, right, bottom, x, y } = box;
  ctx.strokeStyle = "#888";
  ctx.fillStyle = "#444";
  ctx.lineWidth = 1;
  ctx.font = "10px sans-serif";
  ctx.beginPath();
  ctx.moveTo(left, top);
  ctx.lineTo(left, bottom);
  ctx.lineTo(right, bottom);
  ctx.stroke();
  ctx.textAlign = "center";
  for (const [v, text] of xt) {
    ctx.beginPath();
    ctx.moveTo(x(v), bottom);
    ctx.lineTo(x(v), bottom + 3);
    ctx.stroke();
    ctx.fillText(text, x(v), bottom + 13);
  }
  ctx.fillText(xLabel, (left + right) / 2, bottom + 25);
  ctx.textAlign = "right";
  for (const [v, text] of yt) {
    ctx.beginPath();
    ctx.moveTo(left - 3, y(v));
    ctx.lineTo(left, y(v));
    ctx.stroke();
    ctx.fillText(text, left - 5, y(v) + 3);
  }
  ctx.save();
  ctx.translate(10, (top + bottom) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.textAlign = "center";
  ctx.fillText(yLabel, 0, 0);
  ctx.restore();
  ctx.textAlign = "left";
}
