"""Legacy protocol v0 at BER 1e-3: corrupted frames that pass its 16-bit sum never end a test early.

(bench/bench_v0.py runs 20 seeds; this is one seed whose faulty run, before the
plausibility check, aborted on a false over-speed from a corrupted time slot.)
"""

from dyno.session.root import RunSpec, run_test
from dyno.sim.bus import BusFaults

from .conftest import IDEAL  # perfect knowledge: this test checks the statistics alone


def test_v0_bit_errors_never_end_the_test_early(tmp_path):
    r = run_test(RunSpec(sim=True, seed=3, protocol="v0", faults=BusFaults(bit_error_rate=1e-3), sim_params=IDEAL,
                            out_dir=tmp_path / "run"))
    assert r["state"] == "done" and r["reason"].startswith("secondary below"), (r["reason"], r["aborts"])
    fr = r["frames"]
    assert sum(v for k, v in fr["rejected"].items() if k.startswith("implausible")) > 0  # the check worked
    assert isinstance(fr["corrupted_accepted"], int)  # the audit runs for v0 as for v1
    assert len(r["points"]) >= 15
    # the points stay honest: within their uncertainty of the sim's truth (4 sigma + 0.3 pp)
    for p in r["points"]:
        assert abs(p["efficiency"] - p["efficiency_true"]) <= 4 * p["efficiency_sem"] + 0.003, p
