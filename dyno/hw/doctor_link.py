"""``dyno doctor``'s view of the firmware link's budget (:mod:`dyno.transports.budget`): the busiest second the
rig file allows, planned (and the rate a run derates to), and the busiest second of the data check's polls,
measured as the transfers took it."""

from __future__ import annotations

from dyno.hw.doctor_report import FAIL, OK, WARN, Report


def check_link_budget(report: Report, cfg):
    """The busiest second the rig file allows against the link's clock (dyno.transports.budget): every transfer
    counted, planned; returns the rig as a run would run it (derated to fit, ``derate = true``), or ``cfg``."""
    from dyno.errors import ConfigError
    from dyno.transports.budget import MAX_BUSY, check_budget, clock_hz, planned_busy, planned_by_kind, poll_s

    by_kind = planned_by_kind(cfg)
    busy = sum(by_kind.values())
    kinds = ", ".join(f"{kind} {100 * share:.1f}" for kind, share in by_kind.items())
    head = (f"planned {100 * busy:.0f} % of the busiest second ({kinds} %) at {cfg.poll_hz:g} polls/s x "
            f"{poll_s(cfg) * 1e3:.2f} ms on {cfg.transport} at {clock_hz(cfg)} "
            f"{'Bd' if cfg.transport == 'serial' else 'Hz'} (limit {100 * MAX_BUSY:.0f} %)")
    try:
        run_cfg = check_budget(cfg, say=lambda line: None)
    except ConfigError as exc:
        report.add("link budget", FAIL, f"{head}: a run is refused ({exc.args[0] if exc.args else exc})")
        return cfg
    if run_cfg is cfg:
        report.add("link budget", OK, head)
    else:
        report.add("link budget", WARN, f"{head}: a run derates poll_hz to {run_cfg.poll_hz:g} Hz (derate = true; "
                   f"planned {100 * planned_busy(run_cfg):.0f} % there)", essential=False)
    return run_cfg


def check_link_measured(report: Report, cfg, meter) -> None:
    """The busiest full second of the data check's polls, as the transfers took it (dyno.transports.budget):
    above 60 % a warning, ``link_busy``."""
    from dyno.transports.budget import MAX_BUSY, planned_busy

    if meter is None or meter.transactions == 0:
        return
    measured = meter.worst_frac()
    above = measured > MAX_BUSY
    report.add("link measured", WARN if above else OK,
               f"busiest second {100 * measured:.0f} % of the link over {meter.transactions} transfers at "
               f"{cfg.poll_hz:g} Hz (planned {100 * planned_busy(cfg):.0f} %, limit {100 * MAX_BUSY:.0f} %)"
               + (": link_busy, a run will say so (link.warnings)" if above else ""), essential=False)


def check_data(report: Report, cfg, transport, clock, operator, *, simulated: bool = False) -> None:
    """A few seconds of data frames: edges on each Hall channel, the converter's conversions, the link's
    counters (:mod:`dyno.hw.doctor_data`); one line a channel, naming the wire to check.  The link's busiest
    second measured meanwhile: each transfer timed as it happens, or on a ``simulated`` link charged at the
    rig file's clock (:func:`check_link_measured`)."""
    from dyno.acquisition.reader import make_reader
    from dyno.hw import doctor_data
    from dyno.clock import MonotonicClock
    from dyno.transports.budget import ChargedTransport, LinkMeter

    clock = clock or MonotonicClock()
    meter = LinkMeter(clock.now)
    if simulated:
        link = ChargedTransport(transport, meter, cfg)
    else:  # each attempt timed inside the transport, as a run's (dyno.transports.budget.metered_rig_link)
        link = transport
        transport.meter_with(meter, clock.now)
    input_expected = getattr(cfg, "input_torque", None) is not None and cfg.protocol == "v2"
    # the engine-side converter asked for, as a run asks at boot
    reader = make_reader(cfg.protocol, link, want_input=input_expected)
    try:
        for name, ok, detail in doctor_data.check(reader, clock, cfg.poll_hz, operator,
                                                  input_expected=input_expected):
            report.add(name, OK if ok else FAIL, detail)
    finally:
        if not simulated:
            transport.meter_with(None, None)
    check_link_measured(report, cfg, meter)
