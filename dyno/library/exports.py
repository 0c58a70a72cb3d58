"""A run as one Parquet or ASAM MDF4 file: raw event streams and points, with units and metadata.

Both libraries are optional extras (``pip install 'dyno[export]'``): pyarrow for
Parquet, asammdf for MDF4.  :class:`MissingExtra` says which one is absent.

Parquet holds one table in long form (one file cannot hold several tables): a
``record`` column says what each row is — ``primary_edge``, ``secondary_edge``,
``adc`` or ``point`` — and the other columns are null where they do not apply.
Each field carries its unit in its metadata (``unit``); the file's metadata holds
the run's ``meta.json``, calibration and tune.

MDF4 holds one channel group per stream (``primary_edges``, ``secondary_edges``,
``adc``) and one for the points, each with its own master time in seconds on the
device's unwrapped timeline.  ``adc_code`` carries the run's calibration as a linear
conversion (raw counts -> secondary torque in N·m, ``T = (c - b) / a``), so an MDF
viewer shows torque while the raw counts stay readable.
"""

from __future__ import annotations

import json
import math

import numpy as np

#: point fields exported (numeric) and their units ("" = dimensionless)
POINT_UNITS = {
    "index": "", "throttle_frac": "", "t_start_us": "us", "t_end_us": "us", "duration_s": "s",
    "rpm_primary": "rpm", "rpm_primary_std": "rpm", "rpm_secondary": "rpm", "rpm_secondary_std": "rpm",
    "ratio": "", "torque_secondary_nm": "N·m", "torque_secondary_std_nm": "N·m", "torque_secondary_sem_nm": "N·m",
    "power_out_w": "W", "power_in_w": "W", "efficiency": "", "efficiency_sem": "",
    "n_primary_edges": "", "n_secondary_edges": "", "n_adc": "", "n_adc_error": "", "valid": "",
    "efficiency_true": "",
}
STREAM_UNITS = {"t_us": "us", "adc_code": "counts", "adc_status": "", "device_rpm": "rpm", "input_code": "counts",
                "input_status": ""}


class MissingExtra(Exception):
    """The optional library a format needs is not installed."""

    def __init__(self, fmt: str, module: str) -> None:
        self.fmt, self.module = fmt, module
        super().__init__(f"--format {fmt} needs {module}, which is not installed: pip install 'dyno[export]' "
                         f"(or pip install {module})")


def _point_value(p: dict, k: str) -> float:
    v = p.get(k)
    if isinstance(v, bool):
        return float(v)
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else math.nan


def stream_arrays(streams, protocol: str | None) -> dict:
    out = {"primary_edges": np.frombuffer(streams.edges[1], dtype=np.int64).copy(),
           "secondary_edges": np.frombuffer(streams.edges[2], dtype=np.int64).copy(),
           "adc_t_us": np.frombuffer(streams.adc_t, dtype=np.int64).copy(),
           "adc_code": np.frombuffer(streams.adc_code, dtype=np.uint16).copy(),
           "adc_status": np.frombuffer(streams.adc_status, dtype=np.uint8).copy()}
    if len(getattr(streams, "input_t", ())):  # the engine-side input torque converter, where the rig has one
        out["input_t_us"] = np.frombuffer(streams.input_t, dtype=np.int64).copy()
        out["input_code"] = np.frombuffer(streams.input_code, dtype=np.uint16).copy()
        out["input_status"] = np.frombuffer(streams.input_status, dtype=np.uint8).copy()
    if protocol == "v0":  # the v0 firmware reports its own rpm with each Hall edge
        out["primary_device_rpm"] = np.frombuffer(streams.edge_rpm[1], dtype=np.uint16).copy()
        out["secondary_device_rpm"] = np.frombuffer(streams.edge_rpm[2], dtype=np.uint16).copy()
    return out


def _metadata(run) -> dict:
    tune = run.path / "tune.toml"
    return {"dyno.format": "dyno-export/1", "dyno.meta": json.dumps(run.meta, sort_keys=True, default=str),
            "dyno.calibration": json.dumps(run.calibration, sort_keys=True),
            "dyno.tune": tune.read_text() if tune.is_file() else ""}


def write_parquet(run, points: list[dict], path) -> str:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise MissingExtra("parquet", "pyarrow") from None
    s = stream_arrays(run.streams, run.meta.get("protocol"))
    n1, n2, na, npt = len(s["primary_edges"]), len(s["secondary_edges"]), len(s["adc_t_us"]), len(points)
    ni = len(s.get("input_t_us", ()))
    n = n1 + n2 + na + ni + npt
    record = np.array(["primary_edge"] * n1 + ["secondary_edge"] * n2 + ["adc"] * na + ["input"] * ni
                      + ["point"] * npt, dtype=object)
    t_us = np.concatenate([s["primary_edges"], s["secondary_edges"], s["adc_t_us"],
                           s.get("input_t_us", np.zeros(0, dtype=np.int64)),
                           np.array([int(p["t_start_us"]) for p in points], dtype=np.int64)])
    nulls = np.ones(n, dtype=bool)

    def column(values, start, dtype):
        full = np.zeros(n, dtype=dtype)
        mask = nulls.copy()
        full[start:start + len(values)] = values
        mask[start:start + len(values)] = False
        return pa.array(full, mask=mask)

    cols = {"record": pa.array(record, pa.dictionary(pa.int8(), pa.string())), "t_us": pa.array(t_us)}
    cols["adc_code"] = column(s["adc_code"].astype(np.int32), n1 + n2, np.int32)
    cols["adc_status"] = column(s["adc_status"].astype(np.int16), n1 + n2, np.int16)
    if "primary_device_rpm" in s:
        cols["device_rpm"] = column(np.concatenate([s["primary_device_rpm"], s["secondary_device_rpm"]]).astype(np.int32),
                                    0, np.int32)
    if ni:  # the input converter's codes and status (rows "input")
        cols["input_code"] = column(s["input_code"].astype(np.int32), n1 + n2 + na, np.int32)
        cols["input_status"] = column(s["input_status"].astype(np.int16), n1 + n2 + na, np.int16)
    start = n1 + n2 + na + ni
    for k in POINT_UNITS:
        if k == "t_start_us":
            continue  # it is the point row's t_us
        vals = np.array([_point_value(p, k) for p in points], dtype=float)
        cols[f"point_{k}"] = column(vals, start, float)
    cols["point_settled_by"] = pa.array([None] * start + [p.get("settled_by") for p in points], pa.string())
    fields = []
    for name, arr in cols.items():
        unit = POINT_UNITS.get(name[6:], "") if name.startswith("point_") else STREAM_UNITS.get(name, "")
        fields.append(pa.field(name, arr.type, metadata={"unit": unit}))
    schema = pa.schema(fields, metadata=_metadata(run))
    pq.write_table(pa.Table.from_arrays(list(cols.values()), schema=schema), str(path))
    return str(path)


def read_parquet(path) -> dict:
    """The export back: streams, points (dicts) and units, as :func:`write_parquet` laid them out."""
    import pyarrow.parquet as pq

    table = pq.read_table(str(path))
    record = np.array(table.column("record").to_pylist(), dtype=object)
    cols = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}
    out = {"primary_edges": cols["t_us"][record == "primary_edge"],
           "secondary_edges": cols["t_us"][record == "secondary_edge"],
           "adc_t_us": cols["t_us"][record == "adc"], "adc_code": cols["adc_code"][record == "adc"],
           "adc_status": cols["adc_status"][record == "adc"], "units": units,
           "metadata": {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}}
    if "input_code" in cols:
        out.update(input_t_us=cols["t_us"][record == "input"], input_code=cols["input_code"][record == "input"],
                   input_status=cols["input_status"][record == "input"])
    is_pt = record == "point"
    pts = {k[6:]: cols[k][is_pt] for k in cols if k.startswith("point_")}
    pts["t_start_us"] = cols["t_us"][is_pt]
    out["points"] = [{k: v[i] for k, v in pts.items()} for i in range(int(is_pt.sum()))]
    return out


def write_mdf4(run, points: list[dict], path) -> str:
    """Write the MDF4 file; returns the path asammdf wrote (it may add its own suffix)."""
    try:
        from asammdf import MDF, Signal
    except ImportError:
        raise MissingExtra("mdf4", "asammdf") from None
    s = stream_arrays(run.streams, run.meta.get("protocol"))
    mdf = MDF(version="4.10")
    mdf.header.comment = json.dumps(_metadata(run), sort_keys=True)

    def group(name: str, t_us: np.ndarray, signals: list, comment: str) -> None:
        # MDF needs at least one sample per group to carry its master; an empty stream still gets its channels
        mdf.append([Signal(v, t_us / 1e6, **kw) for v, kw in signals], acq_name=name, comment=comment)

    for name, ch in (("primary_edges", "primary_edge_t_us"), ("secondary_edges", "secondary_edge_t_us")):
        sig = [(s[name], {"name": ch, "unit": "us", "comment": "Hall edge time, unwrapped device clock"})]
        key = name.split("_")[0] + "_device_rpm"
        if key in s:
            sig.append((s[key], {"name": key, "unit": "rpm", "comment": "v0 firmware's own rpm at the edge"}))
        group(name, s[name], sig, f"{name.replace('_', ' ')} (raw events)")
    cal = run.calibration or {}
    a, b = cal.get("slope_counts_per_nm"), cal.get("intercept_counts")
    conv = {"a": 1.0 / a, "b": -b / a} if a else None
    group("adc", s["adc_t_us"], [
        (s["adc_t_us"], {"name": "adc_t_us", "unit": "us", "comment": "conversion time, unwrapped device clock"}),
        (s["adc_code"], {"name": "adc_code", "unit": "N·m" if conv else "counts", "conversion": conv,
                         "comment": "AD7171 code; physical value: secondary torque T = (code - b)/a of the run's "
                                    "calibration" if conv else "AD7171 code"}),
        (s["adc_status"], {"name": "adc_status", "unit": "", "comment": "AD7171 status bits"}),
    ], "strain-gauge ADC (raw events)")
    if "input_t_us" in s:
        group("input", s["input_t_us"], [
            (s["input_t_us"], {"name": "input_t_us", "unit": "us", "comment": "conversion time, unwrapped device clock"}),
            (s["input_code"], {"name": "input_code", "unit": "counts",
                               "comment": "engine-side input torque converter (second AD7171) code; its calibration: "
                                          "the run's meta.json input_torque"}),
            (s["input_status"], {"name": "input_status", "unit": "", "comment": "AD7171 status bits"}),
        ], "engine-side input torque converter (raw events)")
    t0 = np.array([int(p["t_start_us"]) for p in points], dtype=np.int64)
    sigs = []
    for k, unit in POINT_UNITS.items():
        vals = np.array([_point_value(p, k) for p in points], dtype=float)
        sigs.append((vals, {"name": f"point_{k}", "unit": unit, "comment": f"steady point {k}"}))
    group("points", t0, sigs, "steady points (dyno.analysis.points.reduce_point)")
    written = mdf.save(str(path), overwrite=True)
    mdf.close()
    return str(written)


def read_mdf4(path) -> dict:
    from asammdf import MDF

    with MDF(str(path)) as mdf:
        def get(name, raw=True):
            return mdf.get(name, raw=raw)

        out = {"primary_edges": get("primary_edge_t_us").samples, "secondary_edges": get("secondary_edge_t_us").samples,
               "adc_t_us": get("adc_t_us").samples, "adc_code": get("adc_code").samples,
               "adc_status": get("adc_status").samples, "adc_torque_nm": get("adc_code", raw=False).samples,
               "units": {}, "metadata": json.loads(mdf.header.description or "{}")}
        pts = {}
        for k in POINT_UNITS:
            sig = get(f"point_{k}")
            pts[k] = sig.samples
            out["units"][f"point_{k}"] = sig.unit
        for name in ("primary_edge_t_us", "secondary_edge_t_us", "adc_t_us", "adc_code", "adc_status"):
            out["units"][name] = get(name).unit
        if "input_code" in mdf.channels_db:
            for name in ("input_t_us", "input_code", "input_status"):
                out[name] = get(name).samples
        out["points"] = [{k: v[i] for k, v in pts.items()} for i in range(len(pts["index"]))]
    return out
