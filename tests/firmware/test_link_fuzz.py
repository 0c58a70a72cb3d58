"""The link's integrity check under bit errors: 10^6 frames per bit-error rate from 1e-4 to
1e-2 through a bit-error channel to a session expecting each one -> no corrupted v2 frame
accepted, and the expectation computed in docs/protocol.md is the one the code computes.
(bench/bench_firmware.py prints the same table with v1's measured rate beside it.)"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

REPO = Path(__file__).resolve().parents[2]


def _bench_host():
    spec = importlib.util.spec_from_file_location("bench_host", REPO / "bench" / "bench_host.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def frames():
    # 10^5 distinct frames as the device builds them, sent 10 times each (fresh flips every
    # time): 10^6 deliveries per rate in ~20 s rather than a minute of frame building.
    return _bench_host().realistic_frames(100_000, seed=1, version=2) * 10


@pytest.mark.parametrize("ber,seed", [(1e-4, 100), (1e-3, 101), (1e-2, 103)])
def test_v2_accepts_no_corrupted_frame_in_a_million(frames, ber, seed):
    bh = _bench_host()
    r = bh.false_accepts(frames, ber, seed=seed, version=2)
    assert r["frames"] == 1_000_000
    # The channel really corrupted frames: 1 - (1-p)^256 of them (all 32 bytes of a read are
    # exposed; flips in the padding after a short frame are corruption too).
    assert r["corrupted"] == pytest.approx(1e6 * (1 - (1 - ber) ** 256), rel=0.05)
    assert r["false_accepts"] == 0, r
    assert bh.expected_false_accepts_v2(frames, ber) < 1e-4  # << 1 over the million


def test_protocol_doc_states_the_computed_expectation():
    """docs/protocol.md's bound for a full 32-byte frame at BER 1e-2 over 10^6 frames is what the
    formula gives (>= 6 flips or a hit length byte, times 2^-32)."""
    from math import comb

    p, n = 1e-2, 256
    ge6 = 1 - sum(comb(n, k) * p**k * (1 - p) ** (n - k) for k in range(6))
    length_hit = 1 - (1 - p) ** 8
    per_million = 1e6 * (ge6 + length_hit) * 2.0**-32
    doc = (REPO / "docs" / "protocol.md").read_text()
    m = re.search(r"expected over 10⁶ frames\s+≤ ([\d.]+) · 10⁻([⁰¹²³⁴⁵⁶⁷⁸⁹]+)", doc)
    assert m, "docs/protocol.md: the expected-count line"
    exponent = int(m.group(2).translate(str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹", "0123456789")))
    stated = float(m.group(1)) * 10.0**-exponent
    assert stated == pytest.approx(per_million, rel=0.05)
    assert f"{ge6:.4f}" in doc and f"{length_hit:.4f}" in doc
