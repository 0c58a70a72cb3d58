// The live page: one EventSource (SSE) stream of frames; the browser reconnects by itself after a drop.
"use strict";
const token = new URLSearchParams(location.search).get("token");
const Q = token ? "?token=" + encodeURIComponent(token) : "";
const $ = id => document.getElementById(id);
const hist = { t: [], rp: [], rs: [], tq: [] };  // the time plot's last 60 s (wall clock of the rig's host)
const SPAN_S = 60;
const TEST_STATES = ["warmup", "step", "settle", "measure"];
window.dynoLog = [];  // (for tests and curious people) what arrived when
let last = null, shownPoints = -1, es = null, ended = false;

function fmt(v, d, unit) {
  if (v === null || v === undefined || !isFinite(v)) return "—";
  let s = Number(v).toFixed(d); if (/^-0(\.0*)?$/.test(s)) s = s.slice(1);
  return s + (unit || "");
}
function dur(s) { s = Math.round(s); return s >= 60 ? Math.floor(s / 60) + ":" + String(s % 60).padStart(2, "0") : s + " s"; }

function render(f) {
  last = f;
  $("state").textContent = (f.state || "—").toUpperCase() + (f.paused ? " (paused)" : "");
  $("reason").textContent = f.reason || "";
  const testing = TEST_STATES.includes(f.state);  // an estimate means something only while the test runs
  $("progress").textContent = "point " + f.points_done + (testing && f.points_total_est ? "/~" + f.points_total_est : "");
  $("eta").textContent = testing && f.eta_s !== null && f.eta_s !== undefined ? "ETA " + dur(f.eta_s) : "";
  $("rundir").textContent = f.run_dir ? "run: " + f.run_dir : "";
  $("rpm-primary").textContent = fmt(f.rpm_primary, 0);
  $("rpm-secondary").textContent = fmt(f.rpm_secondary, 0);
  $("ratio").textContent = fmt(f.ratio, 3);
  $("torque").textContent = fmt(f.torque_secondary_nm, 2);
  $("rotor-temp").textContent = fmt(f.rotor_temp_c, 0) + (f.rotor_temp_limit_c ? " / " + fmt(f.rotor_temp_limit_c, 0) : "");
  $("run-enable").textContent = f.run_enable || "—";
  $("run-enable").dataset.off = String((f.run_enable || "").startsWith("off"));
  $("efficiency").textContent = fmt(f.efficiency === null ? null : f.efficiency * 100, 1, " %");
  $("eff-ci").textContent = f.efficiency_ci95 !== null && f.efficiency_ci95 !== undefined
    ? "CI95 ±" + fmt(f.efficiency_ci95 * 100, 1) + " pp · U95 ±" + fmt(f.efficiency_u95 * 100, 1) + " pp (½ interval95)"
      + (f.efficiency_interval95 ? " · interval95 " + interval(f.efficiency_interval95) + " %" : "") : "";
  const ban = $("banner");
  if (f.abort_cause) {
    ban.hidden = false;
    $("abort-cause").textContent = f.abort_cause;
    $("abort-detail").textContent = f.abort_detail || "";
    $("rig-safe").textContent = f.rig_safe === true ? "rig SAFE: throttle idle, engine killed, pads off the rotor"
      : f.rig_safe === false ? "rig NOT SAFE" + (f.rig_unsafe_because ? ": " + f.rig_unsafe_because : " (yet: the release stroke may still be under way)")
      : "safe state commanded (the outputs cannot report more)";
    $("rig-safe").dataset.safe = String(f.rig_safe);
  } else { ban.hidden = true; }
  $("stopcard").hidden = !f.web_stop;
  if (f.wall_unix_s) {
    hist.t.push(f.wall_unix_s); hist.rp.push(f.rpm_primary); hist.rs.push(f.rpm_secondary); hist.tq.push(f.torque_secondary_nm);
    while (hist.t.length && f.wall_unix_s - hist.t[0] > SPAN_S) for (const k in hist) hist[k].shift();
  }
  if ((f.points || []).length !== shownPoints) table(f.points || []);
  plots();
}

// an efficiency_interval95 [low, high] (fractions) as "low…high" in % (asymmetric where a term is)
function interval(iv) { return fmt(iv[0] * 100, 1) + "…" + fmt(iv[1] * 100, 1); }

function table(points) {
  shownPoints = points.length;
  $("n-points").textContent = String(points.length);
  const body = document.querySelector("#points tbody");
  body.textContent = "";
  for (const p of points.slice().reverse()) {  // newest first: on a phone it is the one in view
    const tr = document.createElement("tr");
    if (p.valid === false) tr.className = "invalid";
    for (const v of [p.index, fmt(p.rpm_primary, 0), fmt(p.rpm_secondary, 0), fmt(p.ratio, 3), fmt(p.torque_secondary_nm, 2),
                     fmt(p.power_out_w, 0), fmt(p.efficiency === null ? null : p.efficiency * 100, 1),
                     fmt(p.efficiency_ci95 === null ? null : p.efficiency_ci95 * 100, 1),
                     fmt(p.efficiency_u95 === null ? null : p.efficiency_u95 * 100, 1),
                     p.efficiency_interval95 ? interval(p.efficiency_interval95) : "—"]) {
      const td = document.createElement("td"); td.textContent = v; tr.appendChild(td);
    }
    body.appendChild(tr);
  }
}

function plots() {
  if (hist.t.length) {
    const t0 = hist.t[hist.t.length - 1];
    const x = hist.t.map(t => t - t0);
    DynoPlot.draw($("plot-time"), [
      { x, y: hist.rp, color: "#4fc3f7", label: "rpm primary" },
      { x, y: hist.rs, color: "#ffb74d", label: "rpm secondary" },
      { x, y: hist.tq, color: "#ce93d8", axis: "right", label: "torque N·m (right)" },
    ], { xRange: [-SPAN_S, 0], xFmt: v => v + " s" });
  }
  const pts = (last && last.points || []).filter(p => p.efficiency !== null && p.ratio !== null);
  const pct = v => v === null || v === undefined ? null : v * 100;
  // the axis fits the points and their CI; an interval95 bar wider than that is cut at the frame
  const lo = Math.min(...pts.map(p => pct(p.efficiency - (p.efficiency_ci95 || 0)))), hi = Math.max(...pts.map(p => pct(p.efficiency + (p.efficiency_ci95 || 0))));
  const yRange = pts.length ? [Math.max(0, lo - 5), Math.min(110, hi + 5)] : [0, 100];
  const series = [{ kind: "points", x: pts.map(p => p.ratio), y: pts.map(p => pct(p.efficiency)),
    err95: pts.map(p => pct(p.efficiency_ci95)),
    iv95: pts.map(p => p.efficiency_interval95 ? [pct(p.efficiency_interval95[0]), pct(p.efficiency_interval95[1])] : null),
    color: "#81c784", label: "points: eff % (thick: CI95, thin: interval95)" }];
  // the belt model at each point: the full model where solved (a line), the closed form's creep-only upper
  // bound (grey dots) where not yet
  const m = last && last.model, mp = (m && m.points || []).filter(p => p.ratio !== null && p.efficiency !== null);
  const full = mp.filter(p => p.tier === "full").sort((a, b) => a.ratio - b.ratio);
  const bound = mp.filter(p => p.tier !== "full");
  if (full.length) series.push({ x: full.map(p => p.ratio), y: full.map(p => pct(p.efficiency)), color: "#ffb74d", label: "model (full)" });
  if (bound.length) series.push({ kind: "points", x: bound.map(p => p.ratio), y: bound.map(p => pct(p.efficiency)), color: "#78909c", label: "model bound (closed form)" });
  $("model-status").textContent = !m ? "" : (m.error ? "belt model: " + m.error :
    `belt model: full at ${m.full}/${m.of} points` + (m.pending ? `, ${m.pending} solving` : "") +
    (m.no_steady_belt ? `, ${m.no_steady_belt} with no steady belt at the tune's clamp` : "") +
    " · grey: closed form, creep loss only, an upper bound");
  const ys = series.slice(1).flatMap(s => s.y).filter(v => v !== null);
  const yr = ys.length ? [Math.min(yRange[0], Math.min(...ys) - 2), Math.min(110, Math.max(yRange[1], Math.max(...ys) + 2))] : yRange;
  DynoPlot.draw($("plot-eff"), series, { yRange: yr });
}

function link(text, down) { const l = $("link"); l.textContent = text; l.className = "link" + (down ? " down" : ""); }

function connect() {
  es = new EventSource("/api/events" + Q);
  es.onopen = () => link("live", false);
  es.onmessage = ev => {
    const f = JSON.parse(ev.data);
    window.dynoLog.push({ recv_ms: Date.now(), wall_unix_s: f.wall_unix_s, t_sim_s: f.t_sim_s, state: f.state, abort_cause: f.abort_cause });
    if (window.dynoLog.length > 5000) window.dynoLog.splice(0, 1000);
    render(f);
  };
  es.addEventListener("bye", () => { ended = true; es.close(); link("the process has ended: last values shown", true); });
  es.onerror = () => {
    if (ended) return;
    link("connection lost: reconnecting…", true);
    if (es.readyState === EventSource.CLOSED) setTimeout(connect, 2000);  // (the browser gave up: start again)
  };
}

$("stop").addEventListener("click", async () => {
  if (!confirm("STOP the test? (software stop: throttle idle, engine killed, brake released)")) return;
  try { const r = await fetch("/api/stop" + Q, { method: "POST" }); link("STOP: " + (await r.json()).stop, false); }
  catch (e) { link("STOP not sent: " + e, true); }
});
window.addEventListener("resize", plots);
connect();
