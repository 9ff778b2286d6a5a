"""An independent truth machine: a feed axis simulated from its own equations, for testing the
discrepancy workflow on a machine it did not build.

It shares no code with the twin (feed_twin.plant, .control, .sim, .analysis): its only
feed_twin import is the G-code planner, for the commanded trajectory
(tests/test_truth_machine.py enforces this). Its nominal machine is the one
`config/truth_nominal.yaml` describes to the twin, with other numerics, rates and laws
(feed_twin.truth.machine says which).

Making a record (CSV + column map, exactly what `feed-twin diagnose` takes):

    from feed_twin.truth import Trace, draw_all, make_record
    hidden = draw_all(["coulomb_friction", "constant_force"], seed=7)  # sizes 0.5x-2x typical
    # or by hand: hidden = {"coulomb_friction": {"F_c_N": 150.0}}
    rec = make_record(
        "run.csv",                  # the map is written next to it: run_map.yaml
        hidden=hidden,              # effect name -> the values the workflow reports for it
        machine=NOMINAL,            # the machine before the effects (truth.machine.Machine)
        trace=Trace(period_s=1e-3, average=True, delay_effort_s=2e-3),  # how the trace exports
        program=PROGRAM,            # G-code (PROGRAM, VALIDATION_PROGRAM, long_program(5), ...)
        seed=0,                     # the measurement noise
    )
    # rec.csv, rec.map, rec.machine (the truth with its effects), rec.hidden
    # feed-twin diagnose rec.csv --map rec.map --config config/truth_nominal.yaml

Effects and their size ranges: feed_twin.truth.effects. Trace settings: feed_twin.truth.trace.
"""

from feed_twin.truth.effects import EFFECTS, SIZE_RANGE, draw, draw_all, machine_with
from feed_twin.truth.machine import NOMINAL, Machine
from feed_twin.truth.record import (
    NC_CONFIG,
    PROGRAM,
    VALIDATION_PROGRAM,
    Record,
    command,
    long_program,
    make_record,
    simulate,
)
from feed_twin.truth.trace import Trace

__all__ = [
    "EFFECTS",
    "NC_CONFIG",
    "NOMINAL",
    "PROGRAM",
    "SIZE_RANGE",
    "VALIDATION_PROGRAM",
    "Machine",
    "Record",
    "Trace",
    "command",
    "draw",
    "draw_all",
    "long_program",
    "machine_with",
    "make_record",
    "simulate",
]
