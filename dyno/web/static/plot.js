// Hand-made canvas plots for the dyno pages (no library, nothing from a CDN).
"use strict";
const DynoPlot = (() => {
  function niceTicks(lo, hi, n) {
    if (!(hi > lo)) { hi = lo + 1; }
    const raw = (hi - lo) / Math.max(1, n), mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map(m => m * mag).find(s => s >= raw) || raw;
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) out.push(+v.toPrecision(12));
    return out;
  }
  function extent(vals, pad) {
    const f = vals.filter(v => v !== null && isFinite(v));
    if (!f.length) return [0, 1];
    let lo = Math.min(...f), hi = Math.max(...f);
    if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
    const p = (hi - lo) * (pad || 0.05);
    return [lo - p, hi + p];
  }
  // series: [{x:[], y:[], color, axis:'left'|'right', kind:'line'|'points', err95:[], iv95:[[lo, hi]], label}]
  // err95: a symmetric half-width (thick bar); iv95: an interval drawn as it is (thin bar; asymmetric where it is)
  function draw(canvas, series, o) {
    o = o || {};
    const dpr = window.devicePixelRatio || 1, cssW = canvas.clientWidth || 300, cssH = canvas.clientHeight || 220;
    if (canvas.width !== Math.round(cssW * dpr)) { canvas.width = Math.round(cssW * dpr); canvas.height = Math.round(cssH * dpr); }
    const g = canvas.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, cssW, cssH);
    const hasRight = series.some(s => s.axis === "right");
    const L = 46, R = hasRight ? 46 : 10, T = 18, B = 24, W = cssW - L - R, H = cssH - T - B;
    const xs = o.xRange || extent([].concat(...series.map(s => s.x)), 0.02);
    const yl = o.yRange || extent([].concat(...series.filter(s => s.axis !== "right").map(s => s.y.concat(
      (s.iv95 || []).map(iv => iv ? iv[0] : null), (s.iv95 || []).map(iv => iv ? iv[1] : null)))), 0.08);
    const yr = extent([].concat(...series.filter(s => s.axis === "right").map(s => s.y)), 0.08);
    const X = v => L + (v - xs[0]) / (xs[1] - xs[0]) * W;
    const Y = (v, ax) => { const r = ax === "right" ? yr : yl; return T + H - (v - r[0]) / (r[1] - r[0]) * H; };
    g.font = "11px DejaVu Sans, sans-serif"; g.strokeStyle = "#2f3742"; g.fillStyle = "#9aa4ae"; g.lineWidth = 1;
    g.textAlign = "right";
    for (const v of niceTicks(yl[0], yl[1], 4)) { const y = Y(v); g.beginPath(); g.moveTo(L, y); g.lineTo(L + W, y); g.stroke(); g.fillText(String(v), L - 4, y + 4); }
    if (hasRight) { g.textAlign = "left"; for (const v of niceTicks(yr[0], yr[1], 4)) g.fillText(String(v), L + W + 4, Y(v, "right") + 4); }
    g.textAlign = "center";
    for (const v of niceTicks(xs[0], xs[1], 5)) { const x = X(v); g.fillText(o.xFmt ? o.xFmt(v) : String(v), x, T + H + 15); }
    g.strokeRect(L, T, W, H);
    g.save(); g.beginPath(); g.rect(L, T, W, H); g.clip();  // nothing drawn outside the frame
    const labels = [];
    for (const s of series) {
      g.strokeStyle = g.fillStyle = s.color; g.lineWidth = 1.6;
      if (s.kind === "points") {
        s.x.forEach((xv, i) => {
          const yv = s.y[i]; if (xv === null || yv === null) return;
          const x = X(xv), y = Y(yv, s.axis);
          const iv = s.iv95 && s.iv95[i], e = s.err95 && s.err95[i];
          for (const [b, w] of [[iv ? iv : null, 1], [e === null || e === undefined ? null : [yv - e, yv + e], 3]]) {
            if (!b || b[0] === null || b[1] === null) continue;
            g.lineWidth = w; g.beginPath(); g.moveTo(x, Y(b[0], s.axis)); g.lineTo(x, Y(b[1], s.axis)); g.stroke();
          }
          g.beginPath(); g.arc(x, y, 3.2, 0, 2 * Math.PI); g.fill();
        });
      } else {
        g.beginPath(); let pen = false;
        s.x.forEach((xv, i) => {
          const yv = s.y[i]; if (xv === null || yv === null || !isFinite(yv)) { pen = false; return; }
          if (pen) g.lineTo(X(xv), Y(yv, s.axis)); else { g.moveTo(X(xv), Y(yv, s.axis)); pen = true; }
        });
        g.stroke();
      }
      if (s.label) labels.push(s);
    }
    g.restore();
    let lx = L + 4;
    g.textAlign = "left";
    for (const s of labels) { g.fillStyle = s.color; g.fillText(s.label, lx, 12); lx += g.measureText(s.label).width + 14; }
  }
  return { draw };
})();
