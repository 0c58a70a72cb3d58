"""What the run library records of one run: a pure function of the run's files.

:func:`read_run_files` reads only the small files of a run directory (``meta.json``,
``documents.jsonl``, ``tune.toml``, ``calibration.json``; never ``events.bin``, so
indexing hundreds of runs stays fast) and :func:`run_row` / :func:`point_rows` turn
them into the index's rows.  Everything here is derived from the files alone, so an
index rebuilt from the directories equals one filled run by run.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import tomllib
from pathlib import Path

from dyno.errors import ConfigError

#: the run row's columns, in table order (name, SQL type)
RUN_COLUMNS = (
    ("path", "TEXT PRIMARY KEY"), ("name", "TEXT"), ("created_utc", "TEXT"), ("date", "TEXT"),
    ("mode", "TEXT"), ("seed", "INTEGER"), ("rig_config", "TEXT"), ("rig_sha256", "TEXT"),
    ("plan_sha256", "TEXT"), ("settle_mode", "TEXT"), ("plan_json", "TEXT"),
    ("tune_name", "TEXT"), ("tune_sha256", "TEXT"), ("tune_source", "TEXT"),
    ("calibration_source", "TEXT"), ("calibration_date", "TEXT"), ("calibration_slope_counts_per_nm", "REAL"),
    ("engine_map_sha256", "TEXT"),
    ("atm_pressure_kpa", "REAL"), ("atm_temperature_c", "REAL"), ("atm_humidity_pct", "REAL"),
    ("firmware_version", "TEXT"), ("protocol", "TEXT"), ("software_version", "TEXT"),
    ("state", "TEXT"), ("exit_status", "TEXT"), ("reason", "TEXT"), ("abort_cause", "TEXT"),
    ("n_points", "INTEGER"), ("n_valid_points", "INTEGER"),
    ("peak_efficiency", "REAL"), ("peak_efficiency_sem", "REAL"), ("peak_efficiency_rpm_secondary", "REAL"),
    ("rpm_secondary_min", "REAL"), ("rpm_secondary_max", "REAL"), ("max_power_out_w", "REAL"),
    ("files_sig", "TEXT"),
)

#: the point row's columns (name, SQL type); ``run_path`` refers to the run row
POINT_COLUMNS = (
    ("run_path", "TEXT"), ("idx", "INTEGER"), ("rpm_primary", "REAL"), ("rpm_secondary", "REAL"),
    ("ratio", "REAL"), ("torque_secondary_nm", "REAL"), ("torque_secondary_sem_nm", "REAL"),
    ("power_out_w", "REAL"), ("power_in_w", "REAL"), ("efficiency", "REAL"), ("efficiency_sem", "REAL"),
    ("duration_s", "REAL"), ("valid", "INTEGER"),
)


def _num(x):
    """A finite float or None (NaN is not a value the index can compare)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def files_signature(run_dir: Path) -> str:
    """Size and mtime of the files a row is built from: a changed run is re-indexed."""
    parts = []
    for name in ("meta.json", "documents.jsonl", "tune.toml", "calibration.json"):
        try:
            st = (run_dir / name).stat()
            parts.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
        except OSError:
            parts.append(f"{name}:-")
    return ";".join(parts)


def read_run_files(run_dir) -> dict:
    """The small files of a run directory, parsed; ConfigError names a file that is not a run's."""
    run_dir = Path(run_dir)
    meta_path = run_dir / "meta.json"
    try:
        meta = json.loads(meta_path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(run_dir, "meta.json", "a run directory written by dyno (meta.json missing)") from None
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ConfigError(meta_path, "file", "UTF-8 JSON text") from None
    if not isinstance(meta, dict):
        raise ConfigError(meta_path, "top level", "a JSON object")
    docs = []
    try:
        text = (run_dir / "documents.jsonl").read_bytes().decode("utf-8", errors="replace")
    except FileNotFoundError:
        text = ""
    for line in text.split("\n"):
        if line.strip():
            try:
                d = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line torn by a kill: the reader drops it too
            if isinstance(d, dict):
                docs.append(d)
    tune = None
    tune_path = run_dir / "tune.toml"
    if tune_path.is_file():
        raw = tune_path.read_bytes()
        try:
            tune = {"data": tomllib.loads(raw.decode("utf-8")), "sha256": hashlib.sha256(raw).hexdigest()}
        except (UnicodeDecodeError, tomllib.TOMLDecodeError):
            tune = {"data": {}, "sha256": hashlib.sha256(raw).hexdigest()}
    calibration = None
    cal_path = run_dir / "calibration.json"
    if cal_path.is_file():
        try:
            calibration = json.loads(cal_path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            calibration = None
    return {"path": run_dir, "meta": meta, "documents": docs, "tune": tune, "calibration": calibration}


def _sha(obj) -> str | None:
    if obj is None:
        return None
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def run_state(docs: list) -> tuple[str, str | None, str | None]:
    """(state, exit_status, reason): the last controller state of a closed run, else ``incomplete``."""
    stops = [d for d in docs if d.get("type") == "stop"]
    if not stops:
        return "incomplete", None, "no stop record (the run was killed or is still running)"
    stop = stops[-1]
    states = [d.get("state") for d in docs if d.get("type") == "state" and d.get("state")]
    status = stop.get("exit_status")
    state = states[-1] if states else {"success": "done", "abort": "aborted"}.get(status, status or "unknown")
    return str(state), status, stop.get("reason")


def run_row(files: dict, path_key: str, signature: str = "") -> dict:
    """The run's row (see RUN_COLUMNS) from :func:`read_run_files` output."""
    meta, docs = files["meta"], files["documents"]
    created = _num(meta.get("created_unix_s"))
    stamp = (_dt.datetime.fromtimestamp(created, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
             if created is not None else None)
    tune = files["tune"]
    tune_data = tune["data"] if tune else {}
    tune_name = tune_data.get("name") if isinstance(tune_data.get("name"), str) else None
    if tune and not tune_name and meta.get("tune_source"):
        tune_name = Path(str(meta["tune_source"])).stem
    cal = files["calibration"] if isinstance(files["calibration"], dict) else {}
    atm = meta.get("ambient") if isinstance(meta.get("ambient"), dict) else {}  # the run's air (dyno.session.ambient)
    state, status, reason = run_state(docs)
    aborts = [d for d in docs if d.get("type") == "abort"]
    points = [d for d in docs if d.get("type") == "point"]
    valid = [p for p in points if p.get("valid") and _num(p.get("efficiency")) is not None]
    best = max(valid, key=lambda p: p["efficiency"]) if valid else {}
    rpm_s = [v for v in (_num(p.get("rpm_secondary")) for p in valid) if v is not None]
    p_out = [v for v in (_num(p.get("power_out_w")) for p in valid) if v is not None]
    plan = meta.get("plan") if isinstance(meta.get("plan"), dict) else None
    device = next((d for d in docs if d.get("type") == "device"), {})
    return {
        "path": path_key, "name": Path(path_key).name, "created_utc": stamp, "date": stamp[:10] if stamp else None,
        "mode": meta.get("mode"), "seed": meta.get("seed") if isinstance(meta.get("seed"), int) else None,
        "rig_config": None if meta.get("rig_config") is None else str(meta.get("rig_config")),
        "rig_sha256": _sha(meta.get("rig")),
        "plan_sha256": _sha(plan), "settle_mode": (plan or {}).get("settle_mode"),
        "plan_json": json.dumps(plan, sort_keys=True) if plan is not None else None,
        "tune_name": tune_name, "tune_sha256": meta.get("tune_sha256") or (tune["sha256"] if tune else None),
        "tune_source": meta.get("tune_source"),
        "calibration_source": meta.get("calibration_source"), "calibration_date": cal.get("date"),
        "calibration_slope_counts_per_nm": _num(cal.get("slope_counts_per_nm")),
        "engine_map_sha256": meta.get("engine_map_sha256"),
        "atm_pressure_kpa": _num(atm.get("pressure_kpa")), "atm_temperature_c": _num(atm.get("temp_c")),
        "atm_humidity_pct": _num(atm.get("rh_pct")),
        "firmware_version": meta.get("firmware_version") or device.get("fw_version"),
        "protocol": meta.get("protocol"), "software_version": meta.get("software_version"),
        "state": state, "exit_status": status, "reason": reason,
        "abort_cause": aborts[0].get("cause") if aborts else None,
        "n_points": len(points), "n_valid_points": len(valid),
        "peak_efficiency": _num(best.get("efficiency")), "peak_efficiency_sem": _num(best.get("efficiency_sem")),
        "peak_efficiency_rpm_secondary": _num(best.get("rpm_secondary")),
        "rpm_secondary_min": min(rpm_s) if rpm_s else None, "rpm_secondary_max": max(rpm_s) if rpm_s else None,
        "max_power_out_w": max(p_out) if p_out else None,
        "files_sig": signature,
    }


def point_rows(files: dict, path_key: str) -> list[dict]:
    rows = []
    for i, p in enumerate(d for d in files["documents"] if d.get("type") == "point"):
        idx = p.get("index")
        rows.append({
            "run_path": path_key, "idx": idx if isinstance(idx, int) else i,
            **{k: _num(p.get(k)) for k in ("rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm",
                                             "torque_secondary_sem_nm", "power_out_w", "power_in_w",
                                             "efficiency", "efficiency_sem", "duration_s")},
            "valid": 1 if p.get("valid") else 0,
        })
    return rows
