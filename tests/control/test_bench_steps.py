"""`bench/bench_test_time.py`'s step part as a real process: several seeds, a row per seed and a distribution
per step whose figures are those of the rows (one seed's figures were once reported as the hold's)."""

import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_step_part_prints_per_seed_rows_and_their_distribution(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_test_time.py"), "--step-seeds", "3",
                           "--step-seed-start", "4", "--seeds", "0", "--thesis-seeds", "0"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    seeds = [line.split("|") for line in out.splitlines() if re.match(r"\| \d+ \| \d", line)]
    assert [int(r[1]) for r in seeds] == [4, 5, 6]
    times = [[float(c.split("/")[0]) for c in r[2:7]] for r in seeds]  # within +-0.5 % after s, per step
    dist = [line.split("|") for line in out.splitlines() if re.match(r"\| \d+ -> \d+ \| \d", line)]
    assert len(dist) == 5
    for i, row in enumerate(dist):
        col = [t[i] for t in times]
        assert float(row[2]) == round(statistics.median(col), 2) and float(row[3]) == max(col)
        assert row[4].strip() == f"{sum(t > 2.0 for t in col)} of 3"
    m = re.search(r"5 % steps: (\d+) of 12 long.*pulses/s while holding ([\d.]+) \(reversals/s ([\d.]+)\)", out)
    assert m and int(m.group(1)) == sum(t > 2.0 for r in times for t in r[:4])
    assert 0 < float(m.group(2)) < 20 and float(m.group(3)) <= float(m.group(2))
