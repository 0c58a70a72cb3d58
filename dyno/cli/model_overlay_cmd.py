"""``dyno model overlay RUN``: the belt model's prediction at every point of a run, in the run's order.

Each point: the slip-consistent inverse (the geometric ratio and the tune's clamp that reproduce the
measured speed ratio, :mod:`dyno.model.inverse`) at the chosen tier, then the model at that operating
point (:func:`dyno.model.overlay.predict_overlay`): its efficiency and its balances (force, moment, power
residuals), or ``efficiency: null`` and the ``reason`` (a point with no speeds or input power, gross slip
at the tune's clamp, a solve that did not converge).
"""

from __future__ import annotations

import json


def _model_point(res, pred, tier: str) -> dict:
    if not res.ok:
        return {"efficiency": None, "state": res.state, "reason": res.reason or res.state}
    eff = (pred.get("efficiency") or {}).get("overall")
    out = {"state": "steady" if pred.get("converged") else pred.get("state", "failed"),
           "geometric_ratio": res.geometric_ratio, "slip": res.slip,
           "primary_axial_force_n": res.primary_axial_force_n,
           "efficiency": eff if pred.get("converged") else None}
    if pred.get("balance") is not None:
        out["balance"] = pred["balance"]
    if not pred.get("converged"):
        out["reason"] = pred.get("error") or "the model did not converge"
    return out


def run_overlay(args) -> int:
    from dyno.model.inverse import invert_points, invertible
    from dyno.runlog.reader import load_run
    from dyno.tuning.tune import model_params_for
    from dyno.tuning.tune import load_tune

    run = load_run(args.run_dir, with_events=False)
    tune_path = args.tune if args.tune is not None else args.run_dir / "tune.toml"
    tune = load_tune(tune_path) if args.tune is not None or tune_path.is_file() else None
    params = model_params_for(tune) if tune is not None else None
    from dyno.model.overlay import predict_overlay

    usable = [p for p in run.points if p.get("valid", True) and invertible(p)]
    inverted = invert_points(usable, tune, tier=args.tier)
    # All the run's points in one batch: each solve warm-starts from its nearest solved neighbour, and a
    # first point that failed from nothing is tried again from the points solved after it.
    ops = [res.operating_point() for _, res in inverted if res.ok]
    preds = iter(predict_overlay(ops, params if params is not None else _table_6_1(), tier=args.tier))
    inverted = iter(inverted)
    rows = []
    for k, p in enumerate(run.points):
        row = {"index": p.get("index", k), "rpm_primary": p.get("rpm_primary"), "rpm_secondary": p.get("rpm_secondary"),
               "efficiency_measured": p.get("efficiency")}
        if not p.get("valid", True):
            row.update(efficiency=None, state="invalid", reason="the point is not valid (its faults: see the report)")
        elif not invertible(p):
            row.update(efficiency=None, state="no_input", reason="no finite speeds, speed ratio or input power")
        else:
            _, res = next(inverted)
            row.update(_model_point(res, next(preds) if res.ok else None, args.tier))
        rows.append(row)
    level = f"tune {tune.name!r}" if tune is not None else "no tune: Table 6.1 drive at 100 N slack"
    if args.json:
        print(json.dumps({"run": str(args.run_dir), "tier": args.tier, "clamp": level, "points": rows}, default=float))
        return 0
    n_ok = sum(r["efficiency"] is not None for r in rows)
    print(f"{args.run_dir}: {len(rows)} points, model ({args.tier}) at {n_ok}; clamp from {level}")
    print("  #   rpm_p  eta meas  eta model  force_rel  power_rel  state")
    for r in rows:
        bal = r.get("balance") or {}
        em = r.get("efficiency_measured")
        print(f"{r['index']:>3} {r['rpm_primary'] or float('nan'):7.0f} {em if em is not None else float('nan'):9.4f} "
              f"{r['efficiency'] if r['efficiency'] is not None else float('nan'):10.4f} "
              f"{bal.get('force_rel', float('nan')):10.2e} {bal.get('power_rel', float('nan')):10.2e}  {r['state']}"
              f"{'  ' + r['reason'][:70] if r.get('reason') else ''}")
    return 0


def _table_6_1():
    from dyno.model.params import TABLE_6_1

    return TABLE_6_1
