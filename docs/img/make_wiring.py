"""Draw docs/img/wiring.svg: the rig's safety wiring (hardware/README.md, "The wiring drawing").

    python docs/img/make_wiring.py [--out docs/img/wiring.svg] [--png PATH]

Plain matplotlib lines on a grid of 0.5 in cells; connections to the Pi and the Nano are net labels
(flags), so each block can be read on its own. The SVG is deterministic (no date, fixed hash salt).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Circle, FancyBboxPatch, Polygon, Rectangle  # noqa: E402

OUT = Path(__file__).resolve().parent / "wiring.svg"
LW = 1.1
FS = 7.0
PI_C, NANO_C, PWR_C, MAG_C, NOTE_C = "#1a7f37", "#0550ae", "#b3261e", "#b35c00", "#444444"

ax = None


def W(*pts, c="black", lw=LW, ls="-"):
    xs, ys = zip(*pts)
    ax.plot(xs, ys, color=c, lw=lw, ls=ls, solid_capstyle="round")


def dot(x, y):
    ax.add_patch(Circle((x, y), 0.07, color="black", zorder=5))


def T(x, y, s, ha="left", va="center", fs=FS, c="black", **kw):
    ax.text(x, y, s, ha=ha, va=va, fontsize=fs, color=c, **kw)


def _frame(p1, p2, length):
    """Unit vector along p1→p2, its normal, the midpoint, and the two ends of a body of ``length``."""
    (x1, y1), (x2, y2) = p1, p2
    d = math.hypot(x2 - x1, y2 - y1)
    u = ((x2 - x1) / d, (y2 - y1) / d)
    n = (-u[1], u[0])
    m = ((x1 + x2) / 2, (y1 + y2) / 2)
    a = (m[0] - u[0] * length / 2, m[1] - u[1] * length / 2)
    b = (m[0] + u[0] * length / 2, m[1] + u[1] * length / 2)
    return u, n, m, a, b


def _box(p1, p2, length, width, label, lx=0.0, ly=0.0, ha="left", fill="white", slash=False):
    u, n, m, a, b = _frame(p1, p2, length)
    W(p1, a)
    W(b, p2)
    hw = width / 2
    corners = [(a[0] + n[0] * s, a[1] + n[1] * s) for s in (hw, -hw)]
    corners += [(b[0] - n[0] * hw, b[1] - n[1] * hw), (b[0] + n[0] * hw, b[1] + n[1] * hw)]
    ax.add_patch(Polygon(corners, closed=True, fc=fill, ec="black", lw=LW, zorder=3))
    if slash:
        W(a, b)
    if label:
        T(m[0] + lx, m[1] + ly, label, ha=ha)


def res(p1, p2, label, **kw):
    _box(p1, p2, 0.8, 0.28, label, **kw)


def fuse(p1, p2, label, **kw):
    _box(p1, p2, 0.8, 0.28, label, slash=True, **kw)


def coil(p1, p2, label, **kw):
    _box(p1, p2, 0.9, 0.55, label, **kw)


def cap(p1, p2, label, lx=0.25, ly=0.0, ha="left"):
    u, n, m, a, b = _frame(p1, p2, 0.16)
    W(p1, a)
    W(b, p2)
    for q in (a, b):
        W((q[0] + n[0] * 0.3, q[1] + n[1] * 0.3), (q[0] - n[0] * 0.3, q[1] - n[1] * 0.3))
    T(m[0] + lx, m[1] + ly, label, ha=ha)


def diode(anode, cathode, label, lx=0.3, ly=0.0, ha="left", both=False):
    """A diode (or, ``both``, a bidirectional TVS) from ``anode`` to ``cathode``."""
    u, n, m, a, b = _frame(anode, cathode, 0.5 if both else 0.36)
    W(anode, a)
    W(b, cathode)
    s = 0.2

    def tri(base, tip):
        ax.add_patch(Polygon([(base[0] + n[0] * s, base[1] + n[1] * s), (base[0] - n[0] * s, base[1] - n[1] * s),
                              tip], closed=True, fc="black", ec="black", lw=0.8, zorder=3))

    if both:
        tri(a, m)
        tri(b, m)
    else:
        tri(a, b)
    bar = m if both else b
    W((bar[0] + n[0] * s, bar[1] + n[1] * s), (bar[0] - n[0] * s, bar[1] - n[1] * s))
    T(m[0] + lx, m[1] + ly, label, ha=ha)


def contact(p1, p2, kind, label, lx=0.0, ly=0.45, ha="center", flip=False):
    """A two-terminal contact: ``kind`` "NC" (closed at rest) or "NO" (open at rest)."""
    u, n, m, a, b = _frame(p1, p2, 0.9)
    if flip:
        n = (-n[0], -n[1])
    W(p1, a)
    W(b, p2)
    for q in (a, b):
        ax.add_patch(Circle(q, 0.06, fc="white", ec="black", lw=0.9, zorder=4))
    if kind == "NO":
        W(a, (b[0] + n[0] * 0.38, b[1] + n[1] * 0.38))
    else:
        W(b, (b[0] + n[0] * 0.32, b[1] + n[1] * 0.32))
        W(a, (b[0] + u[0] * 0.12 - n[0] * 0.18, b[1] + u[1] * 0.12 - n[1] * 0.18))
    T(m[0] + lx, m[1] + ly, label, ha=ha)


def changeover(com, nc, no, label, lx=0.0, ly=0.0, ha="center"):
    """An SPDT contact set at rest: the blade on NC."""
    for q in (com, nc, no):
        ax.add_patch(Circle(q, 0.06, fc="white", ec="black", lw=0.9, zorder=4))
    W(com, (nc[0] - 0.08 * (nc[0] - com[0]), nc[1] - 0.12 * (nc[1] - com[1])))
    s = 0.22 if nc[1] > no[1] else -0.22  # each label on its contact's outer side
    T(nc[0], nc[1] + s, "NC", ha="center", fs=5.5)
    T(no[0], no[1] - s, "NO", ha="center", fs=5.5)
    if label:
        T(com[0] + lx, com[1] + ly, label, ha=ha)


def npn(x, y, label, mirror=False, lx=0.65, ly=0.0):
    """NPN: collector at (x, y+0.8), emitter at (x, y-0.8), base lead end at (x∓1.0, y)."""
    s = -1 if mirror else 1
    bx = x - s * 0.28
    ax.add_patch(Circle((x - s * 0.08, y), 0.5, fc="none", ec="black", lw=0.9))
    W((bx, y - 0.26), (bx, y + 0.26), lw=1.8)
    W((x - s * 1.0, y), (bx, y))
    W((bx, y + 0.12), (x, y + 0.42), (x, y + 0.8))
    W((bx, y - 0.12), (x, y - 0.42), (x, y - 0.8))
    ax.annotate("", xy=(x, y - 0.42), xytext=(bx + s * 0.12, y - 0.2),
                arrowprops=dict(arrowstyle="-|>", color="black", lw=0.8, mutation_scale=7))
    T(x + s * lx, y + ly, label, ha="left" if s > 0 else "right")


def nmos(x, y, label, lx=0.6):
    """Logic-level N-MOSFET: drain (x, y+0.8), source (x, y-0.8), gate lead end (x-1.0, y)."""
    gx, cx = x - 0.38, x - 0.25
    W((x - 1.0, y), (gx, y))
    W((gx, y - 0.3), (gx, y + 0.3))
    for yy in (0.25, 0.0, -0.25):
        W((cx, y + yy - 0.09), (cx, y + yy + 0.09), lw=1.8)
    W((cx, y + 0.25), (x, y + 0.25), (x, y + 0.8))
    W((cx, y - 0.25), (x, y - 0.25), (x, y - 0.8))
    W((x, y), (x, y - 0.25))
    ax.annotate("", xy=(cx + 0.02, y), xytext=(x, y),
                arrowprops=dict(arrowstyle="-|>", color="black", lw=0.8, mutation_scale=7))
    T(x + lx, y, label)


def motor(x, y, label):
    ax.add_patch(Circle((x, y), 0.42, fc="white", ec="black", lw=LW, zorder=3))
    T(x, y, "M", ha="center", fs=9, zorder=4)
    T(x + 0.6, y, label)


def gnd(x, y, label=""):
    W((x, y), (x, y - 0.22))
    for i, hw in enumerate((0.26, 0.17, 0.08)):
        W((x - hw, y - 0.22 - i * 0.08), (x + hw, y - 0.22 - i * 0.08))
    if label:
        T(x + 0.35, y - 0.3, label, fs=6, c=NOTE_C)


def flag(x, y, text, color, side="left"):
    """A net label: the wire ends at (x, y); the flag points at the circuit."""
    w = 0.16 * len(text) * FS / 7 + 0.3
    h = 0.36
    if side == "left":  # flag to the left of the end point
        pts = [(x, y), (x - 0.2, y + h / 2), (x - w, y + h / 2), (x - w, y - h / 2), (x - 0.2, y - h / 2)]
        tx = x - 0.2 - (w - 0.2) / 2
    else:
        pts = [(x, y), (x + 0.2, y + h / 2), (x + w, y + h / 2), (x + w, y - h / 2), (x + 0.2, y - h / 2)]
        tx = x + 0.2 + (w - 0.2) / 2
    ax.add_patch(Polygon(pts, closed=True, fc="white", ec=color, lw=1.0, zorder=4))
    T(tx, y, text, ha="center", c=color, fs=6.5, zorder=5, fontweight="bold")


def panel(x0, y0, x1, y1, title, color="#888888"):
    ax.add_patch(FancyBboxPatch((x0, y0), x1 - x0, y1 - y0, boxstyle="round,pad=0.05,rounding_size=0.2",
                                fc="none", ec=color, lw=0.8, ls=(0, (4, 3))))
    T(x0 + 0.25, y1 - 0.3, title, fs=8, fontweight="bold", c=color)


def run_enable_chain():
    panel(0.3, 11.0, 15.2, 23.0, "1  Run-enable chain: the engine runs only while S1.1, Q1 and Q2 are all closed",
          PWR_C)
    y = 20.6
    flag(1.6, y, "+12 V", PWR_C, side="left")
    fuse((1.6, y), (3.2, y), "F1 1 A", lx=-0.4, ly=0.4)
    contact((3.2, y), (5.2, y), "NC", "S1.1 (E-stop, NC)", ly=-0.5)
    W((5.2, y), (11.0, y))
    # K1 and K3 coils in parallel, a flyback diode on each
    for xc, name, sub in ((6.4, "K1", "K1: kill relay"), (9.9, "K3", "K3: brake hold relay (DPDT)")):
        coil((xc, y), (xc, 17.2), "")
        T(xc, 18.9, name, ha="center", fs=6.5, zorder=4)
        T(xc - 0.2, y + 0.35, sub, fs=6.3)
        diode((xc + 1.1, 17.2), (xc + 1.1, y), f"D{name[1]}\n1N4007", lx=0.25)
        W((xc, 17.2), (xc + 1.1, 17.2))
        dot(xc, y)
        dot(xc + 1.1, 17.2)
    W((6.4, 17.2), (9.9, 17.2))
    dot(7.5, y)
    dot(9.9, 17.2)
    W((8.6, 17.2), (8.6, 16.5))
    dot(8.6, 17.2)
    npn(8.6, 15.7, "Q1  BC337\n(Pi enable)", lx=0.7)
    npn(8.6, 13.3, "Q2  BC337\n(Nano run-enable)", lx=0.7)
    W((8.6, 14.9), (8.6, 14.1))
    gnd(8.6, 12.5)
    for yb, pd, name, col in ((15.7, "100 kΩ", "Pi GPIO24", PI_C), (13.3, "10 kΩ", "Nano D7", NANO_C)):
        W((7.6, yb), (7.2, yb))
        res((7.2, yb), (5.4, yb), "1 kΩ", lx=0, ly=0.32, ha="center")
        W((5.4, yb), (2.6, yb))
        dot(3.6, yb)
        res((3.6, yb), (3.6, yb - 1.5), pd, lx=0.25)
        gnd(3.6, yb - 1.5)
        flag(2.6, yb, name, col)
    T(1.9, 12.65, "pull-down at the pin", fs=5.5, c=NANO_C, ha="center")
    # the E-stop monitor contact S1.3, on the same button
    ym = 21.7
    flag(2.3, ym, "Pi GPIO22", PI_C)
    W((2.3, ym), (3.2, ym))
    contact((3.2, ym), (5.2, ym), "NC", "S1.3 (E-stop, NC): monitor", ly=0.4)
    W((5.2, ym), (5.8, ym))
    gnd(5.8, ym)
    W((4.2, ym - 0.05), (4.2, y + 0.3), c=NOTE_C, lw=0.8, ls=(0, (2, 2)))
    T(11.5, 16.9, "Engine runs only while K1 is\nenergised: S1.1 closed AND\nQ1 on (GPIO24 high) AND\n"
      "Q2 on (D7 high, or pumped: 3).\nK3 drops with K1: the brake\nreleases by wiring (4).", fs=6.5, c=NOTE_C,
      va="top")
    T(11.5, 14.0, "Common ground: 12 V −, Pi GND,\nNano GND at one star point; the\nactuator's current returns on\n"
      "its own wire.", fs=6, c=NOTE_C, va="top")


def magneto_side():
    panel(15.6, 16.4, 31.7, 23.0, "2  Magneto side: contacts only, no electronics", MAG_C)
    y = 21.0
    flag(17.6, y, "magneto kill wire", MAG_C)
    W((17.6, y), (23.0, y))
    dot(19.6, y)
    contact((19.6, y), (19.6, 18.0), "NC", "K1 contact\n(NC: grounds\nwhile K1 is\nreleased)", lx=-0.5, ly=0,
            ha="right")
    gnd(19.6, 18.0, "engine ground")
    contact((23.0, y), (23.0, 18.0), "NO", "S1.2 (E-stop, NO):\ngrounds the kill wire\ndirectly when pressed",
            lx=0.5, ly=0, ha="left")
    gnd(23.0, 18.0, "engine ground")
    T(26.4, 21.6, "Ignition spikes (hundreds of volts) stay\non relay contacts and the button: no\n"
      "transistor, diode or Pi/Nano pin is\nconnected to the kill wire.\n\nTwo independent kills: the relay (any\n"
      "of S1.1, Q1, Q2 opening) and S1.2 on\nits own wire.\n\nS1: one latching mushroom button,\n"
      "three contact blocks (S1.1 NC, S1.2 NO,\nS1.3 NC).", fs=6.3, c=NOTE_C, va="top")


def charge_pump():
    panel(15.6, 11.0, 31.7, 16.0,
          "3  Variant: old-bootloader firmware (no watchdog): D7 pumps, a charge pump drives Q2",
          NANO_C)
    y = 13.6
    flag(17.6, y, "Nano D7", NANO_C)
    W((17.6, y), (18.2, y))
    dot(18.2, y)
    res((18.2, y), (18.2, 12.0), "10 kΩ", lx=-0.25, ha="right")
    gnd(18.2, 12.0)
    res((18.2, y), (20.0, y), "220 Ω", lx=0, ly=0.32, ha="center")
    cap((20.0, y), (21.6, y), "C1 1 µF", lx=0, ly=0.5, ha="center")
    dot(22.2, y)
    W((21.6, y), (22.2, y))
    diode((22.2, 12.0), (22.2, y), "1N4148", lx=0.2)
    gnd(22.2, 12.0)
    diode((22.2, y), (24.2, y), "1N4148", lx=0, ly=0.4, ha="center")
    dot(24.6, y)
    W((24.2, y), (24.6, y))
    cap((24.6, y), (24.6, 12.0), "C2 47 µF", lx=0.3)
    gnd(24.6, 12.0)
    W((24.6, y), (26.0, y))
    dot(26.0, y)
    res((26.0, y), (26.0, 12.0), "10 kΩ", lx=0.25)
    gnd(26.0, 12.0)
    res((26.0, y), (28.0, y), "1 kΩ", lx=0, ly=0.32, ha="center")
    W((28.0, y), (28.4, y))
    T(28.5, y, "→ Q2 base\n(instead of\nthe 1 kΩ in 1)", fs=6.3)
    T(16.0, 15.2, "A pulse train (the main loop toggles D7 every pass) charges C2 and holds Q2 on; a hung loop "
      "leaves D7 static, high or low:\nC1 passes no DC, C2 drains in ~50 ms and Q2 opens. The default (watchdog) "
      "build drives D7 static high: no pump.", fs=6.3, c=NOTE_C, va="top")


def actuator_power():
    panel(0.3, 0.3, 19.6, 10.75, "4  Brake actuator: K2 reverses, Q3 switches, K3 (coil in 1) releases by wiring",
          PWR_C)
    ys = 9.2
    flag(1.6, ys, "+12 V", PWR_C)
    W((1.6, ys), (2.2, ys))
    dot(2.2, ys)
    fuse((2.2, ys), (4.6, ys), "F2 5 A", lx=0, ly=0.35, ha="center")
    W((4.6, ys), (7.6, ys), (7.6, 8.4))
    dot(5.6, ys)
    # the freewheel diode: across the relay's input, whose polarity never reverses
    diode((5.6, 6.0), (5.6, ys), "D4 1N5408\nfreewheel", lx=-0.3, ha="right")
    # K2: two changeover contacts
    changeover((7.6, 8.4), (9.0, 8.8), (9.0, 8.0), "K2a", lx=-0.3, ly=0.0, ha="right")
    changeover((7.6, 6.0), (9.0, 6.4), (9.0, 5.6), "K2b", lx=0.0, ly=-0.4)
    T(8.3, 4.9, "K2 direction relay (DPDT)\nat rest: RELEASE", ha="center", fs=6.3)
    W((9.0, 8.8), (10.6, 8.8))               # K2a NC -> A
    W((10.6, 8.8), (10.6, 5.6), (9.0, 5.6))  # A <- K2b NO
    W((9.0, 8.0), (11.2, 8.0))               # K2a NO -> B (crosses A)
    W((9.0, 6.4), (11.2, 6.4))               # K2b NC -> B (crosses A)
    W((11.2, 8.0), (11.2, 6.4))
    dot(10.6, 8.8)
    dot(11.2, 6.4)
    T(10.45, 9.05, "A", fs=6, ha="center")
    T(11.35, 7.2, "B", fs=6)
    # Q3 low side, feeding K2b's common
    W((7.6, 6.0), (5.6, 6.0))
    dot(5.6, 6.0)
    W((5.6, 6.0), (5.6, 5.2))
    nmos(5.6, 4.4, "Q3 IRLZ44N", lx=0.3)
    gnd(5.6, 3.6)
    W((4.6, 4.4), (4.2, 4.4))
    res((4.2, 4.4), (2.9, 4.4), "100 Ω", lx=0, ly=0.32, ha="center")
    W((2.9, 4.4), (2.1, 4.4))
    dot(2.5, 4.4)
    res((2.5, 4.4), (2.5, 2.9), "100 kΩ", lx=0.25)
    gnd(2.5, 2.9)
    flag(2.1, 4.4, "Pi GPIO13", PI_C)
    # K3's contacts: NO = the software's path, NC = +12 V / GND in the release polarity
    changeover((14.0, 8.8), (12.6, 9.2), (12.6, 8.4), "K3a", lx=-0.1, ly=0.4)
    changeover((14.0, 6.0), (12.6, 5.6), (12.6, 6.4), "K3b", lx=-0.1, ly=-0.4)
    W((10.6, 8.8), (11.9, 8.8), (11.9, 8.4), (12.6, 8.4))  # A -> K3a NO
    W((11.2, 6.4), (12.6, 6.4))                             # B -> K3b NO
    W((12.6, 9.2), (12.2, 9.2), (12.2, 9.9))                # K3a NC -> F3 -> +12 V
    W((2.2, ys), (2.2, 9.9))
    fuse((2.2, 9.9), (12.2, 9.9), "F3 5 A: K3's direct path (from before F2)", lx=0, ly=-0.3, ha="center")
    W((12.6, 5.6), (12.2, 5.6), (12.2, 5.2))                # K3b NC -> GND
    gnd(12.2, 5.2)
    # the actuator
    W((14.0, 8.8), (15.2, 8.8), (15.2, 7.82))
    W((14.0, 6.0), (15.2, 6.0), (15.2, 6.98))
    motor(15.2, 7.4, "")
    T(14.95, 8.2, "M+", fs=6, ha="right")
    T(14.95, 6.6, "M−", fs=6, ha="right")
    W((15.2, 8.8), (16.4, 8.8))
    W((15.2, 6.0), (16.4, 6.0))
    dot(15.2, 8.8)
    dot(15.2, 6.0)
    diode((16.4, 6.0), (16.4, 8.8), "TVS\nSMBJ18CA", lx=0.3, both=True)
    T(15.0, 4.9, "linear actuator, 12 V, internal end stops\nM+ positive = retract (release)", ha="center", fs=6.3)
    T(0.6, 1.6, "K2 and K3 rest (de-energised) in the release polarity; K3's NC path never touches K2.\n"
      "D4 sits where the polarity never reverses: a diode across M itself would short\nthe supply in one "
      "direction. The TVS clamps the kick when K3 breaks the motor current.\nQ3 is off whenever K2 moves "
      "(actuator.relay_settle_s).", fs=6.3, c=NOTE_C)
    # K2's coil and driver
    yc = 3.85
    flag(12.9, yc, "+12 V", PWR_C)
    W((12.9, yc), (13.4, yc))
    coil((13.4, yc), (15.0, yc), "")
    T(14.2, yc + 0.45, "K2 coil", ha="center", fs=6.3)
    diode((15.0, yc - 0.8), (13.4, yc - 0.8), "")
    T(14.2, yc - 1.15, "D2 1N4007", ha="center", fs=6.3)
    W((13.4, yc), (13.4, yc - 0.8))
    W((15.0, yc), (15.0, yc - 0.8), (16.6, yc - 0.8))
    dot(13.4, yc)
    dot(15.0, yc - 0.8)
    npn(16.6, yc - 1.6, "Q4\nBC337", lx=0.6)
    gnd(16.6, yc - 2.4)
    W((15.6, yc - 1.6), (15.4, yc - 1.6))
    res((15.4, yc - 1.6), (13.9, yc - 1.6), "1 kΩ", lx=0, ly=-0.32, ha="center")
    W((13.9, yc - 1.6), (12.9, yc - 1.6))
    dot(13.3, yc - 1.6)
    res((13.3, yc - 1.6), (13.3, yc - 2.9), "", lx=0.25)
    T(13.55, yc - 2.55, "100 kΩ", fs=FS)
    gnd(13.3, yc - 2.9)
    flag(12.9, yc - 1.6, "Pi GPIO23", PI_C)


def pi_inputs():
    panel(20.0, 0.3, 31.7, 10.75, "5  Servo signal and end-of-travel switch", PI_C)
    y = 9.2
    flag(22.2, y, "Pi GPIO18", PI_C)
    res((22.2, y), (24.4, y), "470 Ω", lx=0, ly=0.32, ha="center")
    W((24.4, y), (25.4, y))
    T(25.5, y, "servo signal (its own 5–6 V supply,\ngrounds common)", fs=6.3)
    T(20.4, 8.3, "The resistor limits the current into GPIO18 if the servo's\nsupply reaches its signal "
      "wire, and damps the cable's ringing.", fs=6.0, c=NOTE_C)
    # the end switch: a separate dry contact
    ye = 6.6
    flag(22.2, ye, "Pi GPIO27", PI_C)
    T(21.3, ye - 0.4, "(Pi pull-up)", fs=5.5, c=PI_C, ha="center")
    W((22.2, ye), (23.4, ye))
    contact((23.4, ye), (25.4, ye), "NO", "S2 microswitch: its own dry\ncontact at the retracted stop", ly=0.5)
    W((25.4, ye), (26.0, ye))
    gnd(26.0, ye, "Pi GND")
    # or through an optocoupler
    yo = 3.6
    T(20.4, 5.2, "or, where the switch must sit in the 12 V circuit, through an optocoupler:", fs=6.3)
    flag(21.6, yo + 0.9, "+12 V", PWR_C)
    W((21.6, yo + 0.9), (22.4, yo + 0.9))
    contact((22.4, yo + 0.9), (23.4, yo + 0.9), "NO", "switch", ly=0.3)
    res((23.4, yo + 0.9), (24.6, yo + 0.9), "2.2 kΩ", lx=0, ly=0.32, ha="center")
    W((24.6, yo + 0.9), (25.2, yo + 0.9))
    ax.add_patch(Rectangle((24.85, yo - 1.05), 1.85, 2.2, fc="none", ec="black", lw=0.9))
    T(25.75, yo - 1.3, "PC817", ha="center", fs=6)
    diode((25.2, yo + 0.9), (25.2, yo - 0.7), "", lx=0)
    W((25.2, yo - 0.7), (24.4, yo - 0.7), (24.4, yo - 1.4))
    gnd(24.4, yo - 1.4, "12 V −")
    ax.annotate("", xy=(25.9, yo + 0.1), xytext=(25.4, yo + 0.1),
                arrowprops=dict(arrowstyle="-|>", color="black", lw=0.7, mutation_scale=6))
    bx = 26.0  # the phototransistor: collector to GPIO27 (pull-up), emitter to the Pi's ground
    W((bx, yo - 0.3), (bx, yo + 0.5), lw=1.8)
    W((bx, yo + 0.3), (26.4, yo + 0.6), (26.4, yo + 0.7), (27.6, yo + 0.7))
    W((bx, yo - 0.1), (26.4, yo - 0.4), (26.4, yo - 0.6), (26.9, yo - 0.6), (26.9, yo - 1.4))
    ax.annotate("", xy=(26.4, yo - 0.4), xytext=(bx + 0.1, yo - 0.175),
                arrowprops=dict(arrowstyle="-|>", color="black", lw=0.8, mutation_scale=6))
    gnd(26.9, yo - 1.4, "Pi GND")
    flag(27.6, yo + 0.7, "Pi GPIO27", PI_C, side="right")
    T(20.4, 0.8, "Never the actuator's internal limit contact that carries the motor current: it puts\n"
      "12 V on a 3.3 V pin.", fs=6.0, c=NOTE_C)


def draw(out: Path, png: Path | None = None) -> None:
    global ax
    plt.rcParams["svg.fonttype"] = "none"
    plt.rcParams["svg.hashsalt"] = "dyno-wiring"
    plt.rcParams["font.family"] = "DejaVu Sans"
    fig = plt.figure(figsize=(16, 11.65))
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, 32)
    ax.set_ylim(0, 23.3)
    ax.set_aspect("equal")
    ax.axis("off")
    run_enable_chain()
    magneto_side()
    charge_pump()
    actuator_power()
    pi_inputs()
    fig.savefig(out, format="svg", metadata={"Date": None})
    if png is not None:
        fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--png", type=Path, default=None, help="also a PNG preview here")
    a = ap.parse_args()
    draw(a.out, a.png)


if __name__ == "__main__":
    main()
