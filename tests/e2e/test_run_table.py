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
    header, row = capsys.readouterr().out.splitlines()
    assert "eff %" in header and "±CI95" in header and "±U95" in header and "interval95 %" in header
    assert header.split()[-5:] == ["%", "±CI95", "±U95", "interval95", "%"]  # (the efficiency's column is "eff %")
    assert " ± " not in header and not any(w == "±" for w in header.split())  # no bare "±"
    assert row.split()[-4:] == ["87.0", "0.7", "5.1", "82.4..95.1"]  # the CI, not the standard error (0.3)
    assert len(header) == len(row)  # right-aligned under their labels
