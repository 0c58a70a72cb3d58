"""``dyno doctor``'s data check: a few seconds of data frames, judged channel by channel.

A rig whose INFO frame answers can still have both Hall sensors and the torque converter unplugged.  This
polls the firmware as a run does (its poll rate, its reader, its MORE bursts) for :data:`SECONDS` and says,
one line a channel, what the frames show and which wire to check when they show nothing:

* each Hall channel has edges — the primary while the engine idles (or is turned over by hand), the
  secondary while its shaft turns (at idle the CVT is not engaged: turn the brake rotor by hand);
* the output torque converter (AD7171) converts at its rate (125 Hz ± 15 %) — not silent, not flooding
  (a floating DOUT reads "ready" on every pass), not repeating one code, not flagging errors;
* the link: failed transfers, rejected frames (CRC, sequence), resyncs and events lost over the polls,
  NACKs and CRC failures told apart (a NACK is an address or wiring matter, a CRC failure noise).

``operator`` (optional) is asked to turn a Hall channel that showed no edges, and the check repeats for that
channel: on the rig the terminal's prompt (the operator turns the shaft by hand, or revs the idling engine with
the brake released), in a simulation the simulated operator (nothing prompts).  Without one, a channel that
did not turn fails: never "rig OK" with a sensor that was not seen working.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

SECONDS = 3.0
#: reads a tick while the device says MORE (dyno.acquisition.poller.Poller's default)
MAX_BURST = 8
#: the AD7171's output data rate and the share of it a check accepts
ADC_RATE_HZ = 125.0
ADC_RATE_TOL = 0.15
#: a link with more failed or rejected transfers than this share of its polls is not fit to run
LINK_BAD_SHARE = 0.01

#: where each channel's wire is (hardware/README.md)
WIRES = {"primary": "the primary Hall sensor's cable (Nano D2)",
         "secondary": "the secondary Hall sensor's cable (Nano D3)",
         "adc": "the output torque converter's cable (AD7171: SCLK D4, DOUT D5)",
         "input": "the input torque converter's cable (second AD7171: DOUT D8, SCLK D9)"}
CH_INPUT = 4  # dyno.protocol.v2.CH_INPUT


@dataclass
class DataSample:
    polls: int = 0
    seconds: float = 0.0
    edges: dict = field(default_factory=lambda: {"primary": 0, "secondary": 0})
    conversions: int = 0
    codes: set = field(default_factory=set)
    conversion_errors: int = 0
    input_conversions: int = 0  # the engine-side converter's (rig.toml [input_torque]), v2 tag 4
    input_codes: set = field(default_factory=set)
    input_errors: int = 0
    events_lost: int = 0
    transport_errors: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    resyncs: int = 0


def sample(reader, clock, poll_hz: float, seconds: float = SECONDS) -> DataSample:
    """Poll ``reader`` at ``poll_hz`` for ``seconds`` of ``clock``'s time; count what the frames carry."""
    from dyno.protocol import v1

    s = DataSample()
    t0 = clock.now()
    period = 1.0 / poll_hz
    lost0 = reader.events_lost
    while clock.now() - t0 < seconds:
        s.polls += 1
        try:
            events = reader.poll(clock.now())
        except Exception:  # noqa: BLE001 - a failed poll is counted by the reader's stats; keep sampling
            events = []
        for _ in range(MAX_BURST - 1):  # as the run's poller: read again at once while the device says MORE
            if not getattr(reader, "more", False):
                break
            s.polls += 1
            try:
                events = events + reader.poll(clock.now())
            except Exception:  # noqa: BLE001 - (as above)
                break
        for ev in events:
            if ev.channel == v1.CH_PRIMARY:
                s.edges["primary"] += 1
            elif ev.channel == v1.CH_SECONDARY:
                s.edges["secondary"] += 1
            elif ev.channel == v1.CH_ADC:
                s.conversions += 1
                s.codes.add(ev.code)
                if ev.status:
                    s.conversion_errors += 1
            elif ev.channel == CH_INPUT:
                s.input_conversions += 1
                s.input_codes.add(ev.code)
                if ev.status:
                    s.input_errors += 1
        clock.sleep(period)
    s.seconds = clock.now() - t0
    st = reader.stats
    s.transport_errors = dict(st.transport_errors)
    s.rejected = dict(st.rejected)
    s.resyncs = st.resyncs
    s.events_lost = reader.events_lost - lost0
    return s


def check(reader, clock, poll_hz: float, operator=None, seconds: float = SECONDS,
          input_expected: bool = False) -> list[tuple[str, bool, str]]:
    """:func:`sample`, then for each Hall channel without edges the operator's turn and a second look;
    ``input_expected``: the rig declares the engine-side converter (judged as the output one)."""
    s = sample(reader, clock, poll_hz, seconds)
    for ch in ("primary", "secondary"):
        if s.edges[ch] or operator is None:
            continue
        with operator.turning(ch):
            again = sample(reader, clock, poll_hz, seconds)
        s.edges[ch] = again.edges[ch]
    out = judge(s)
    if input_expected:
        out.insert(3, _converter("adc (input torque)", "input", s.input_conversions, s.input_codes, s.input_errors,
                                 s.seconds))
    return out


def _converter(name: str, wire: str, n: int, codes: set, errors: int, seconds: float) -> tuple[str, bool, str]:
    """One AD7171: converting at its rate, not flooding, not stuck, not flagging errors."""
    rate = n / seconds if seconds > 0 else 0.0
    if n == 0:
        return name, False, f"no conversions in {seconds:.1f} s: check {WIRES[wire]} and the bridge supply"
    if abs(rate - ADC_RATE_HZ) > ADC_RATE_TOL * ADC_RATE_HZ:
        why = "flooding: a floating DOUT reads ready on every pass" if rate > ADC_RATE_HZ else "too slow"
        return name, False, f"{rate:.0f} conversions/s (expected {ADC_RATE_HZ:g}): {why}; check {WIRES[wire]}"
    if len(codes) <= 1:
        return name, False, (f"{n} conversions, every one code {min(codes):#08x}: stuck (an open bridge or a dead "
                             f"converter); check {WIRES[wire]}")
    if errors > ADC_RATE_TOL * n:
        return name, False, f"{errors} of {n} conversions flagged in error: check {WIRES[wire]} and the excitation"
    return name, True, f"{rate:.0f} conversions/s, {len(codes)} distinct codes"


def judge(s: DataSample) -> list[tuple[str, bool, str]]:
    """``(channel, ok, detail)`` for each channel: the Hall sensors, the converter, the link."""
    out = []
    for ch in ("primary", "secondary"):
        n = s.edges[ch]
        if n:
            out.append((f"hall {ch}", True, f"{n} edges in {s.seconds:.1f} s"))
        else:
            out.append((f"hall {ch}", False, f"no edges in {s.seconds:.1f} s while the shaft should turn: check "
                                            f"{WIRES[ch]}, the sensor's supply and its gap to the trigger"))
    out.append(_converter("adc (output torque)", "adc", s.conversions, s.codes, s.conversion_errors, s.seconds))
    nacks = sum(v for k, v in s.transport_errors.items() if k == "nack")
    other = sum(v for k, v in s.transport_errors.items() if k != "nack")
    crc = sum(v for k, v in s.rejected.items() if "crc" in str(k).lower())
    bad = nacks + other + sum(s.rejected.values())
    what = []
    if nacks:
        what.append(f"{nacks} NACKs (the Nano not answering: its address, SDA/SCL swapped or loose, the level shifter)")
    if other:
        what.append(f"{other} timeouts/errors ({', '.join(f'{k} {v}' for k, v in s.transport_errors.items() if k != 'nack')}"
                    "; a hung bus or clock stretching: docs/install-pi.md)")
    if crc:
        what.append(f"{crc} CRC failures (noise: cable length, pull-ups, a shared ground)")
    if sum(s.rejected.values()) - crc:
        what.append(f"{sum(s.rejected.values()) - crc} frames rejected ({', '.join(f'{k} {v}' for k, v in s.rejected.items())})")
    if s.events_lost:
        what.append(f"{s.events_lost} events lost (the Nano's ring overflowed between polls)")
    ok = bad <= LINK_BAD_SHARE * max(1, s.polls) and not s.events_lost
    detail = f"{s.polls} polls" + (f": {'; '.join(what)}" if what else ", no failure")
    out.append(("link", ok, detail))
    return out


class TerminalOperator:
    """The rig's operator at the doctor's terminal: asked to turn a shaft, given a few seconds to do it."""

    PROMPTS = {"primary": "turn the engine over by hand (pull the starter cord slowly), or start it",
               "secondary": "turn the brake rotor by hand (or rev the idling engine with the brake released)"}

    @contextmanager
    def turning(self, channel: str):
        import sys

        print(f"  ...  hall {channel}: no edges yet: {self.PROMPTS[channel]} now; watching "
              f"{SECONDS:g} s", flush=True, file=sys.stderr)
        yield
