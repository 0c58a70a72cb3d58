"""``dyno flash``: the Nano's firmware through avrdude, then its version checked over the link (dyno.hw.flash).

Exit 0 flashed and answering as stamped; 1 avrdude failed or the firmware did not answer; 2 bad input (no
prebuilt firmware, no port found, the port held by another process: stop the service first).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_arguments(parser) -> None:
    parser.add_argument("--hex", type=Path, default=None, metavar="FILE",
                        help="flash this Intel HEX file (default: the prebuilt firmware shipped in the package)")
    parser.add_argument("--port", default=None, metavar="PORT",
                        help="the Nano's serial port (default: the rig file's [serial] port if present, else the "
                             "one of /dev/dyno-nano, /dev/ttyUSB*, /dev/ttyACM*)")
    parser.add_argument("--json", action="store_true", help="print one JSON document")


def run(args) -> int:
    from dyno.hw import flash as fl
    from dyno.rig.config import load_rig

    image = fl.custom_image(args.hex) if args.hex else fl.shipped_image()
    rig_cfg = load_rig(getattr(args, "rig", None))  # (only its [serial] port, baud and boot wait are used)
    port = fl.find_port(args.port, rig_cfg)
    result = fl.flash(port, image, rig_cfg)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(f"dyno flash: {port}: {result['hex']} written at {result['baud']} Bd ({result['bootloader']}); the "
              f"firmware answers {result['version']} ({result['protocol']})", file=sys.stderr)
    return 0
