"""`python -m feed_twin.truth RUN.csv [--hidden EFFECT ...] [--seed N] [trace options]`: write a
truth-machine record and its column map (RUN_map.yaml), and print the hidden effects' values."""

from __future__ import annotations

import argparse
import json
import sys

from feed_twin.truth.effects import EFFECTS, draw_all
from feed_twin.truth.record import PROGRAM, VALIDATION_PROGRAM, make_record
from feed_twin.truth.trace import Trace


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m feed_twin.truth", description=__doc__)
    ap.add_argument("csv", help="the record to write (its map goes next to it)")
    ap.add_argument("--hidden", nargs="*", default=[], choices=sorted(EFFECTS), metavar="EFFECT")
    ap.add_argument("--seed", type=int, default=0, help="draws the effect sizes and the noise")
    ap.add_argument("--validation", action="store_true", help="the second program")
    ap.add_argument("--period-ms", type=float, default=1.0, help="record sample period")
    ap.add_argument("--average", action="store_true", help="mean over each sample period")
    ap.add_argument("--effort-delay-ms", type=float, default=0.0)
    ap.add_argument("--position-delay-ms", type=float, default=0.0)
    ap.add_argument("--resolution-mm", type=float, default=1e-5, help="position rounding")
    args = ap.parse_args(argv)
    trace = Trace(
        period_s=args.period_ms * 1e-3,
        average=args.average,
        delay_effort_s=args.effort_delay_ms * 1e-3,
        delay_position_s=args.position_delay_ms * 1e-3,
        position_resolution_m=args.resolution_mm * 1e-3,
    )
    hidden = draw_all(args.hidden, args.seed)
    program = VALIDATION_PROGRAM if args.validation else PROGRAM
    rec = make_record(args.csv, hidden=hidden, trace=trace, program=program, seed=args.seed)
    print(json.dumps({"csv": str(rec.csv), "map": str(rec.map), "hidden": hidden}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
