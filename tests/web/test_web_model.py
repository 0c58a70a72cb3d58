"""The belt model beside the live page's points (issue 26: "efficiency against speed ratio with the points and
the model overlay"): a real `dyno run --sim --web` in headless chromium, and the curve's own logic."""

from __future__ import annotations

import json
import time

from dyno.web.model_curve import ModelCurve
from tests.web.conftest import DynoProcess, http_status, needs_browser


@needs_browser
def test_page_shows_the_model_at_each_point_marked_by_tier(browser, tmp_path):
    run_dir = tmp_path / "run"
    p = DynoProcess(["run", "--sim", "--headless", "--json", "--out", run_dir, "--speed", "4", "--plan",
                     "engine-hold", "--web", "127.0.0.1:0"], cwd=tmp_path)
    try:
        url = p.wait_url()
        page = browser.new_page()
        page.goto(url)
        page.wait_for_function("document.querySelectorAll('#points tbody tr').length >= 2", timeout=90_000)
        page.wait_for_function("document.getElementById('model-status').textContent.startsWith('belt model:')",
                               timeout=30_000)
        status = page.evaluate("document.getElementById('model-status').textContent")
        assert p.wait(300) == 0, "".join(p.stderr_lines)
    finally:
        p.stop()
    assert "upper bound" in status and "full at " in status, status
    n_model = int(status.split("full at ")[1].split(" ")[0].split("/")[1])  # "full at K/N points"
    result = json.loads(p.stdout)
    # the model's values, as the page had them at the end (the last frame), against an independent computation
    # of the same operating points: the closed form's creep-only bound at each point with a steady belt
    from dyno.model.overlay import predict_overlay
    from dyno.model.overlay_inputs import overlay_inputs

    pts = [q for q in result["points"] if q.get("valid", True) and q.get("efficiency") is not None]
    pairs = overlay_inputs(pts, run_dir / "tune.toml")
    bound = [r["efficiency"]["overall"] for r in predict_overlay([op for _, op in pairs], tier="closed_form")]
    assert 1 <= n_model <= len(pairs)  # (the status was read while the run still took points)
    for (rs, _), b, q in zip(pairs, bound, [q for q in pts if any(abs(q["rpm_secondary"] - x) < 1e-9 for x, _ in pairs)]):
        # an upper bound on the belt's efficiency, above the measured one (the rig loses more than creep)
        assert b >= q["efficiency"] - 0.02 and b <= 1.0


class FakeService:
    """Stands in for the solver process: results appear when the test says so."""

    def __init__(self):
        self.submitted, self.results, self.closed = [], {}, False

    def submit(self, op):
        self.submitted.append(op)
        return f"k{len(self.submitted)}"

    def get(self, key):
        return self.results.get(key)

    @property
    def pending(self):
        return len(self.submitted) - len(self.results)

    def close(self):
        self.closed = True


def _row(i, rpm_p, rpm_s, p_in, eff=0.85):
    return {"index": i, "rpm_primary": rpm_p, "rpm_secondary": rpm_s, "ratio": rpm_p / rpm_s, "power_in_w": p_in,
            "efficiency": eff, "valid": True}


def test_curve_shows_the_bound_until_the_full_model_and_starts_afresh_on_a_new_run():
    svc = FakeService()
    curve = ModelCurve(service_factory=lambda: svc)
    rows = [_row(0, 3400, 2500, 3400 * 0.10472 * 15.0), _row(1, 3400, 3000, 3400 * 0.10472 * 15.0)]
    m = curve.update({"run_dir": None, "points": rows[:1]})
    assert len(svc.submitted) == 1 and m["of"] == 1 and m["full"] == 0 and m["points"][0]["tier"] == "closed_form"
    assert 0.95 < m["points"][0]["efficiency"] <= 1.0  # the creep-only bound
    m = curve.update({"run_dir": None, "points": rows})  # only the new point is submitted
    assert len(svc.submitted) == 2 and m["of"] == 2
    v0 = curve.version
    svc.results["k1"] = {"converged": True, "efficiency": {"overall": 0.9123}}
    assert curve.version != v0  # (the page is sent the frame again)
    m = curve.frame()
    assert m["full"] == 1 and [q["tier"] for q in m["points"]] == ["full", "closed_form"]
    assert m["points"][0]["efficiency"] == 0.9123
    m = curve.update({"run_dir": "/runs/next", "points": rows[:1]})  # a re-armed session's new run
    assert m["of"] == 1 and len(svc.submitted) == 3
    curve.close()
    assert svc.closed and curve.update({"run_dir": "/runs/next", "points": rows})["of"] == 1  # closed: no more
