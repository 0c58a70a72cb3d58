"""dyno compare: runs side by side — curves, point-wise differences with their uncertainty, tune diff."""

from __future__ import annotations

import json
from pathlib import Path

from dyno.cli import number_in


def add_arguments(p) -> None:
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help="two or more run directories (or run names in the runs directory); the first is the reference")
    p.add_argument("--grid-rpm", type=number_in(10.0, 2000.0), default=200.0,
                   help="spacing of the common secondary-rpm grid (default 200)")
    p.add_argument("--html", type=Path, default=None,
                   help="the HTML report (default: compare-<first>-vs-<last>.html in the runs directory)")
    p.add_argument("--no-html", action="store_true", help="terminal view only")
    p.add_argument("--json", action="store_true", help="print the comparison as one JSON document")


def resolve_run(text: str) -> Path:
    """A run directory given by path, or by name inside the runs directory."""
    from dyno.errors import ConfigError
    from dyno.library.index import runs_dir

    for cand in (Path(text), runs_dir() / text):
        if (cand / "meta.json").is_file():
            return cand
    raise ConfigError(text, "RUN", "a run directory (with meta.json) or the name of one in the runs directory")


def load_for_compare(run_dir: Path) -> dict:
    from dyno.library.index import key
    from dyno.library.summary import read_run_files, run_row

    files = read_run_files(run_dir)
    return {"name": run_dir.name, "row": run_row(files, key(run_dir)),
            "points": [d for d in files["documents"] if d.get("type") == "point"],
            "tune": files["tune"]["data"] if files["tune"] else None, "meta": files["meta"]}


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.library.compare import compare

    if len(args.runs) < 2:
        raise ConfigError("command line", "RUN", "two or more runs to compare")
    dirs = [resolve_run(r) for r in args.runs]
    runs = [load_for_compare(d) for d in dirs]
    names = [r["name"] for r in runs]
    for i, n in enumerate(names):  # same directory names from different places: tell them apart
        if names.count(n) > 1:
            runs[i]["name"] = f"{n} ({dirs[i].parent.name})"
    html_path = None
    if not args.no_html:
        from dyno.library.index import runs_dir

        html_path = args.html or runs_dir() / f"compare-{dirs[0].name}-vs-{dirs[-1].name}.html"
        if not html_path.parent.is_dir():
            raise ConfigError(html_path, "--html", "a file in an existing directory")
    try:
        result = compare(runs, step_rpm=args.grid_rpm)
    except ValueError as exc:
        raise ConfigError(" ".join(str(d) for d in dirs), "points", f"runs that can be compared ({exc})") from None
    if html_path is not None:
        from dyno.fileio import write_atomic
        from dyno.library.compare_html import render

        write_atomic(html_path, render(result))
        result["html"] = str(html_path)
    if args.json:
        print(json.dumps(result, indent=1, allow_nan=False))
    else:
        print_view(result)
    return 0


def _pm(v, s, sig, k=1.0, fmt="{:+.2f}") -> str:
    if v is None or s is None:
        return "-"
    return f"{fmt.format(v * k)}±{s * k:.2f}{'*' if sig else ' '}"


def print_view(result: dict) -> None:
    print(result["atmosphere"])
    ref = result["curves"][0]
    for d, cur in zip(result["differences"], result["curves"][1:]):
        print(f"\n{d['name']} against {d['reference']}")
        if d["tune_diff"]:
            print("  tune diff:")
            for t in d["tune_diff"]:
                print(f"    {t['key']}: {t['from']!r} -> {t['to']!r}")
        else:
            print("  tune: the same")
        for t in d["setup_diff"]:
            if t["key"] not in ("tune_name", "tune_sha256"):
                print(f"  setup: {t['key']}: {t['from']!r} -> {t['to']!r}")
        q = d["quantities"]
        if d.get("terms"):  # what cancels in the efficiency difference, and what is left (U95 column)
            print("  efficiency difference, its 95 % uncertainty U95 by term:")
            for k, t in d["terms"].items():
                top = "-" if t["max_u95"] is None else f"≤{100 * t['max_u95']:.2f} pts"
                print(f"    {k}: {t['status']} ({top}): {t['reason']}")
        u95 = q["efficiency"].get("difference_u95")
        print(f"  {'rpm_s':>6} {'eff A %':>7} {'eff B %':>7} {'Δeff %':>13} {'U95 %':>6} {'ΔT N·m':>13} "
              f"{'ΔP W':>15} {'Δrpm_p':>15}")
        for i, g in enumerate(result["grid_rpm_secondary"]):
            ea, eb = ref["efficiency"]["value"][i], cur["efficiency"]["value"][i]
            qe = q["efficiency"]
            de = _pm(qe["difference"][i], qe["sem"][i], qe["significant"][i], 100.0)
            ud = None if u95 is None or u95[i] is None else f"{100 * u95[i]:.2f}"
            print(f"  {g:>6.0f} {'-' if ea is None else f'{100 * ea:.1f}':>7} {'-' if eb is None else f'{100 * eb:.1f}':>7} "
                  + f"{de:>13} {ud or '-':>6} "
                  + " ".join(f"{_pm(q[n]['difference'][i], q[n]['sem'][i], q[n]['significant'][i], k, fmt):>{w}}"
                             for n, k, fmt, w in (("torque_secondary_nm", 1.0, "{:+.2f}", 13),
                                                  ("power_out_w", 1.0, "{:+.0f}", 15),
                                                  ("rpm_primary", 1.0, "{:+.0f}", 15))))
        n_sig = sum(bool(s) for s in q["efficiency"]["significant"])
        print(f"  efficiency: {n_sig} of {len(result['grid_rpm_secondary'])} grid speeds differ significantly "
              "(* = |Δ| > 1.96 s.e., 95 %)")
        if u95 is not None:
            n_u = sum(bool(s) for s in q["efficiency"].get("significant_u95") or ())
            print(f"  efficiency: {n_u} of {len(result['grid_rpm_secondary'])} grid speeds differ by more than U95 "
                  "(all terms that do not cancel)")
    if result.get("html"):
        print(f"\nreport: {result['html']}")
