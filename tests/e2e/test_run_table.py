"""`dyno run`'s text table labels each column by what it is: the point's 95 % CI, its U95 and the interval the
truth lies in at 95 %, not a bare "±" that was the standard error (k = 1, less than half the CI)."""

import pytest

from dyno.cli.run_cmd import _print_points

pytestmark = pytest.mark.quick


def test_the_table_shows_the_ci95_and_the_u95_with_their_names(capsys):
    _print_points([{"index": 0, "rpm_primary": 3000.0, "rpm_secondary": 3100.0, "torque_secondary_nm": 15.0,
                    "power_out_w": 4870.0, "power_in_w": 5600.0, "efficiency": 0.8696, "efficiency_sem": 0.0031,
                    "efficiency_ci95": 0.0072, "efficiency_u95": 0.0512,
                    "efficiency_interval95": [0.8243, 0.9512]}])
    header, row = capsys.readouterr().out.splitlines()[:2]
    assert "eff %" in header and "±CI95" in header and "±U95" in header and "interval95 %" in header
    assert header.split()[-5:] == ["%", "±CI95", "±U95", "interval95", "%"]  # (the efficiency's column is "eff %")
    assert " ± " not in header and not any(w == "±" for w in header.split())  # no bare "±"
    assert row.split()[-4:] == ["87.0", "0.7", "5.1", "82.4..95.1"]  # the CI, not the standard error (0.3)
    assert len(header) == len(row)  # right-aligned under their labels


def _point(index, **kw):
    p = {"index": index, "rpm_primary": 3000.0, "rpm_secondary": 3100.0, "ratio": 0.968, "torque_secondary_nm": 15.0,
         "power_out_w": 4870.0, "power_in_w": 5600.0, "efficiency": 0.8696, "efficiency_ci95": 0.0072,
         "efficiency_u95": 0.0512, "efficiency_interval95": [0.8243, 0.9512],
         "efficiency_u95_terms": {"statistical": 0.0072, "calibration": 0.010, "engine_map": 0.0495, "air": 0.004,
                                  "driveline": 0.0}}
    p.update(kw)
    return p


def test_the_table_shows_the_ratio_where_p_in_comes_from_and_the_largest_term(capsys):
    measured = _point(1, efficiency_source="input_torque",
                      efficiency_u95_terms={"statistical": 0.03, "calibration": 0.01, "calibration_input": 0.02})
    _print_points([_point(0), measured])
    lines = capsys.readouterr().out.splitlines()
    header, row_map, row_meas = lines[:3]
    cols = header.split()
    assert cols[3] == "ratio" and "from" in cols
    assert row_map.split()[3] == "0.97" and row_meas.split()[3] == "0.97"
    src = cols.index("from") - 3  # (the header's "T_s N·m", "P_out W" and "P_in W" are two words each)
    assert row_map.split()[src] == "map" and row_meas.split()[src] == "meas"
    footer = "\n".join(lines[3:])
    assert "map: the engine map" in footer and "meas: the input torque channel" in footer
    assert "±U95: half the width of interval95, the point's one 95 % statement" in footer  # not a second one
    # the term that dominates: the map's (rms over the two points: 3.5 pp against the statistical 2.1 pp)
    assert "largest U95 term: engine_map (±3.5 pp of" in footer, footer
    assert "`dyno compare` cancels what two runs share" in footer
    assert all(len(x) == len(header) for x in (row_map, row_meas))


def test_the_footer_says_to_measure_the_engine_when_an_unmeasured_map_dominates(capsys):
    terms = [{"term": "engine_map", "u_rel": 0.10, "basis": "…", "measured": False}]
    _print_points([_point(0)], terms)
    assert "to narrow: the engine map is not measured on this engine" in capsys.readouterr().out
    _print_points([_point(0)], [{**terms[0], "measured": True}])  # a map measured on this engine: nothing to add
    assert "to narrow" not in capsys.readouterr().out
    _print_points([_point(0)])  # a run from before the terms said it
    assert "to narrow" not in capsys.readouterr().out
