"""The ``--drill`` option's help, made from the drills' own table (:data:`dyno.session.drills.DRILLS`): a drill
added there is listed in ``dyno run --help``, ``dyno ui --help`` and docs/cli.md (regenerated)."""

from __future__ import annotations

#: a numeric argument's name in the help and the errors (a drill not named here takes its listed arguments)
ARG_FORMS = {"estop-held": "SECONDS", "loop-stall": "MS", "pi-freeze": "S", "loop-freeze": "S"}


def drill_form(name: str) -> str:
    """``hall-dead:primary|secondary|both``, ``loop-stall:MS``, ``pi-freeze[:S]``, ``adc-error[:input]``, ``bus-lost``."""
    from dyno.session.drills import DRILLS

    needs_arg, allowed, _ = DRILLS[name]
    arg = "|".join(allowed) if allowed else ARG_FORMS.get(name)
    if arg is None:
        return name
    return f"{name}:{arg}" if needs_arg else f"{name}[:{arg}]"


def drill_help(names=None) -> str:
    """The ``--drill`` help: the forms of WHEN and every drill (from :data:`DRILLS`: a drill added there is listed)."""
    from dyno.session.drills import DRILLS, PHASES
    from dyno.session.drills_wiring import WIRING_DRILLS

    names = list(DRILLS if names is None else names)
    wiring = [n for n in names if n in WIRING_DRILLS]
    plain = [n for n in names if n not in WIRING_DRILLS]
    when = ("fault drill NAME[:ARG]@WHEN (repeatable; --sim only; docs/safety.md). WHEN: T, simulated seconds "
            "from the first frame (@12); PHASE, its first poll (@loaded); PHASE+S, S seconds after it (@loaded+2, "
            f"@after+1). PHASE: {', '.join(PHASES)} (loaded: the pads first bite; after: the test has ended). ")
    text = when + "NAME: " + ", ".join(drill_form(n) for n in plain)
    if wiring:
        text += "; through the wiring twin (--mock-pins): " + ", ".join(drill_form(n) for n in wiring)
    return text.replace("%", "%%")
