"""The run library's record of tune advice: what ``dyno tune advise`` predicted for a tune file, kept
beside the runs (``<runs dir>/advice/<tune sha256>.json``) so a later run on that tune -- ``dyno run
--tune FILE`` records the file's sha256 -- shows "advised: predicted X ± u, measured Y".

Files, not a table of the index: the index is a cache rebuilt from the run directories at any time,
and advice is not derived from a run.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

FIGURE_KEYS = {"engagement": "engagement_rpm", "shift_out": "shift_out_rpm"}


def advice_dir(root) -> Path:
    return Path(root) / "advice"


def record(root, tune_text: str, entry: dict) -> Path:
    """Store one advised tune's prediction, keyed by the sha256 of its file's text (atomic write)."""
    sha = hashlib.sha256(tune_text.encode()).hexdigest()
    d = advice_dir(root)
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{sha}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"tune_sha256": sha, **entry}, indent=1))
    os.replace(tmp, path)
    return path


def lookup(root, tune_sha256: str | None) -> dict | None:
    if not tune_sha256:
        return None
    path = advice_dir(root) / f"{tune_sha256}.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def advised_for_run(root, run_dir) -> dict | None:
    """:func:`advised_vs_measured` for a run directory (its meta.json's ``tune_sha256``); None if none."""
    try:
        meta = json.loads((Path(run_dir) / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    sha = meta.get("tune_sha256") if isinstance(meta, dict) else None
    return advised_vs_measured(root, {"tune_sha256": sha, "path": str(run_dir)}) if sha else None


def measured_figures(run_dir) -> dict:
    """The engagement plan's light-load figures of a run (empty for another plan)."""
    path = Path(run_dir) / "documents.jsonl"
    out: dict = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return out
    for line in lines:
        try:
            d = json.loads(line)
        except ValueError:
            continue
        if isinstance(d, dict) and d.get("type") == "characterisation":
            for fig, key in FIGURE_KEYS.items():
                v = d.get(key)
                if isinstance(v, (int, float)) and math.isfinite(v):
                    out[fig] = float(v)
    return out


def advised_vs_measured(root, run: dict) -> dict | None:
    """For an index row (``tune_sha256``, ``path``): the advice on its tune and the run's measurement."""
    adv = lookup(root, run.get("tune_sha256"))
    if adv is None:
        return None
    measured = measured_figures(run["path"])
    figs = {}
    for fig, pred in (adv.get("predicted") or {}).items():
        row = {"predicted_rpm": pred.get("rpm"), "u_rpm": pred.get("u_rpm"), "u95_rpm": pred.get("u95_rpm"),
               "measured_rpm": measured.get(fig)}
        if row["measured_rpm"] is not None and isinstance(pred.get("rpm"), (int, float)):
            row["error_rpm"] = row["measured_rpm"] - pred["rpm"]
        figs[fig] = row
    return {"advice_file": adv.get("advice_file"), "targets": adv.get("targets"), "figures": figs}


def format_line(a: dict) -> str:
    parts = []
    for fig, r in a["figures"].items():
        if not isinstance(r.get("predicted_rpm"), (int, float)) or not math.isfinite(r["predicted_rpm"]):
            continue
        m = "not measured" if r.get("measured_rpm") is None else f"measured {r['measured_rpm']:.0f}"
        parts.append(f"{fig} predicted {r['predicted_rpm']:.0f} ± {r['u95_rpm']:.0f}, {m}")
    return "advised: " + "; ".join(parts) + " rpm (± U95)"
