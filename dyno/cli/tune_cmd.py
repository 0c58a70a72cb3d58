"""``dyno tune advise RUN [RUN...]``: which parts to fit to reach target engagement / shift-out rpm."""

from __future__ import annotations

import datetime as _dt
import json
import math
import sys
from pathlib import Path

from dyno.cli import number_in

from dyno.resources import resource
FIGURES = ("engagement", "shift_out", "full_load")


def add_arguments(p) -> None:
    p.add_argument("action", choices=("advise",), metavar="advise",
                   help="rank catalogue tunes against targets: dyno tune advise RUN [RUN...] --target FIGURE=RPM")
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help="engagement-plan runs (dyno run --plan engagement), oldest first; the last one's tune "
                        "is the one to change")
    p.add_argument("--target", action="append", default=[], metavar="FIGURE=RPM",
                   help="engagement=RPM, shift_out=RPM (the engagement plan's light-load figures), "
                        "full_load=RPM (the engine speed held in a full-load upshift); repeatable")
    p.add_argument("--catalogue", type=Path, default=resource("calibration/parts"), metavar="DIR",
                   help="parts catalogue directory (default calibration/parts)")
    p.add_argument("--max-changes", type=number_in(0, 4, integer=True), default=2, metavar="N",
                   help="change at most N parts (default 2)")
    p.add_argument("--tolerance", type=number_in(1.0, 1000.0), default=50.0, metavar="RPM",
                   help="a target is met within +-RPM (default 50)")
    p.add_argument("--top", type=number_in(1, 50, integer=True), default=5, help="tunes to print and write (default 5)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="where the advised tune files, advice.json and advice.html go (default advice/<UTC time>)")
    p.add_argument("--jobs", type=number_in(1, 256, integer=True), default=None, metavar="N",
                   help="refine the best tunes in a local pool of N processes (default: the machine's cores; "
                        "1: in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="refine them on a running dask.distributed scheduler instead (pip install 'dyno[cluster]')")
    p.add_argument("--json", action="store_true", help="print one JSON document")


def parse_targets(items: list[str]) -> dict[str, float]:
    from dyno.errors import ConfigError

    out: dict[str, float] = {}
    for it in items:
        name, sep, val = it.partition("=")
        if not sep or name not in FIGURES:
            raise ConfigError("<arguments>", "--target", f"FIGURE=RPM with FIGURE one of {', '.join(FIGURES)}, "
                                                         f"got {it!r}")
        try:
            rpm = float(val)
        except ValueError:
            rpm = math.nan
        if not (500.0 <= rpm <= 8000.0):
            raise ConfigError("<arguments>", f"--target {name}", f"an engine speed 500..8000 rpm, got {val!r}")
        if name in out:
            raise ConfigError("<arguments>", f"--target {name}", f"one target per figure, got {out[name]:g} and "
                                                               f"{rpm:g}")
        out[name] = rpm
    if not out:
        raise ConfigError("<arguments>", "--target", "at least one target (e.g. --target engagement=2100 "
                                                     "--target shift_out=2700)")
    return out


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.tuning.advisor import advise
    from dyno.tuning.advisor_model import load_run_data
    from dyno.tuning.parts import load_catalogue

    targets = parse_targets(args.target)
    catalogue = load_catalogue(args.catalogue)
    runs = []
    for r in args.runs:
        if not Path(r).is_dir():
            raise ConfigError(r, "RUN", "a run directory")
        runs.append(load_run_data(r))
    out = args.out or Path("advice") / _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    if out.exists() and any(out.glob("tune-*.toml")):
        raise ConfigError(out, "--out", "a new or empty directory (advice is never overwritten)")
    from dyno.model.executor import make_executor

    with make_executor(args.jobs, args.scheduler) as executor:
        result = advise(runs, catalogue, targets, max_changes=args.max_changes, tolerance_rpm=args.tolerance,
                        top=args.top, executor=executor)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(out, "--out", f"a directory dyno can create ({exc.strerror})") from None
    advice = _write(result, out, runs, targets)
    if args.json:
        print(json.dumps(advice, indent=1, default=_plain))
    else:
        _print(advice)
    return 0


def _plain(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return str(x)


def _write(result: dict, out: Path, runs, targets) -> dict:
    """Tune files, advice.json, advice.html; the run library's record of each advised tune."""
    from dyno.library import advice as lib_advice
    from dyno.library.index import runs_dir
    from dyno.tuning import advice_html
    from dyno.tuning.advisor import curve_for, tolerance_lookup
    from dyno.tuning.tune import dumps_tune, load_tune

    base = runs[-1].tune
    tunes = []
    curves = []
    tol_of = tolerance_lookup([], [])  # (the curve needs only the calibrated parts; new parts at their label)
    for k, (row, cand) in enumerate(zip(result["ranked"], result["_candidates"]), 1):
        ids = "+".join(p.id for p in cand.changes) or "unchanged"
        tune = cand.tune.with_changes(name=f"{base.name}+{ids}"[:120],
                                      notes=f"dyno tune advise #{k}: {base.name} with " + (
                                          ", ".join(f"{p.kind} {p.id} ({p.label})" for p in cand.changes)
                                          or "no change"))
        text = dumps_tune(tune)
        path = out / f"tune-{k}.toml"
        path.write_text(text)
        load_tune(path)  # what `dyno run --tune` will read
        tunes.append({"rank": k, "tune_file": str(path), **row})
        lib_advice.record(runs_dir(), text, {"advice_file": str(out / "advice.json"), "tune_file": str(path),
                                             "targets": result["targets"], "predicted": row["predicted"],
                                             "changes": row["changes"]})
        if runs[-1].engine is not None and k <= 5:
            try:
                curves.append((f"#{k} {ids}", curve_for(result["_calibration"], cand.tune, runs[-1].engine, tol_of)))
            except Exception:  # noqa: BLE001  a curve that cannot be solved is left off the page, the advice stands
                curves.append((f"#{k} {ids}", None))
    advice = {k: v for k, v in result.items() if not k.startswith("_") and k != "ranked"}
    advice["tunes"] = tunes
    # what the calibration had to go on: a speed-hold run has no engagement figure, only steady points
    advice["calibrated_on"] = [{"run": r.name, "engagement_figures": sum(f.figure == "engagement" for f in r.figures),
                                "shift_out_figures": sum(f.figure == "shift_out" for f in r.figures),
                                "steady_points": len(r.steady)} for r in runs]
    advice["verdict"] = verdict(advice)
    advice["html"] = str(out / "advice.html")
    svg = advice_html.curves_figure(curves, result["targets"]) if curves else None
    (out / "advice.html").write_text(advice_html.render(advice, svg))
    (out / "advice.json").write_text(json.dumps(advice, indent=1, default=_plain))
    return advice


#: below this chance of meeting every target within two trips the advice says the targets are out of reach
LIKELY_P = 0.5


def verdict(advice: dict) -> str:
    """One sentence: whether the catalogue, with at most --max-changes parts, is likely to reach the targets."""
    n = advice["max_changes"]
    if not advice["tunes"]:
        return (f"no tune to advise: with at most {n} parts changed the catalogue offers nothing but the measured "
                "tune (never advised); raise --max-changes or add parts")
    best = max(t.get("p_within_two_trips", t["p_within_tolerance"]) for t in advice["tunes"])
    if best >= LIKELY_P:
        return f"reachable: the best tune meets every target within two trips with P {best:.2f}"
    return (f"out of reach: no tune with at most {n} parts changed from this catalogue is likely to meet every "
            f"target within ±{advice['tolerance_rpm']:.0f} rpm (best P {best:.2f} within two trips); the nearest "
            "are listed: raise --max-changes, add parts to the catalogue or revisit the targets")


def _print(advice: dict) -> None:
    t = ", ".join(f"{k} {v:.0f}" for k, v in advice["targets"].items())
    print(f"targets: {t} rpm (±{advice['tolerance_rpm']:.0f}); {advice['searched']} tunes searched "
          f"(≤ {advice['max_changes']} parts changed), from {advice['base_tune']}")
    print("calibrated on: " + "; ".join(
        f"{c['run']} (" + ", ".join(f"{n} {what}" for n, what in (
            (c["engagement_figures"], "engagement"), (c["shift_out_figures"], "shift-out"),
            (c["steady_points"], "steady points")) if n) + ")" for c in advice.get("calibrated_on", [])))
    cur = advice["current"]["predicted"]
    print("current tune, calibrated: " + ", ".join(f"{f} {v['rpm']:.0f} ± {v['u95_rpm']:.0f}" for f, v in cur.items()))
    for row in advice["tunes"]:
        ch = "; ".join(f"{c['kind']} -> {c['label']}" for c in row["changes"]) or "no change"
        pr = ", ".join(f"{f} {v['rpm']:.0f} ± {v['u95_rpm']:.0f}" for f, v in row["predicted"].items())
        print(f"#{row['rank']} P(met) {row['p_within_tolerance']:.2f}, within two trips "
              f"{row.get('p_within_two_trips', row['p_within_tolerance']):.2f}  {ch}\n    predicted (± U95): {pr} rpm\n"
              f"    {row['tune_file']}")
    print(advice["verdict"])
    print(f"curves and calibration: {advice['html']}")
