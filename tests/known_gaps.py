"""Reasons for the tests that are known to fail today, each with what was measured.

A test marked `xfail(strict=True)` with one of these fails the suite as soon as it passes again,
so the mark cannot outlive the gap it names.
"""

VOLTAGE_BOUNDARY_LIMIT_CYCLE = (
    "open, found on branch i30jerk: with the full cascade in the controller node (boundary "
    "voltage: the current loop at 1 kHz, about 120 Hz, the velocity loop re-tuned above it to Kp "
    "174 A/(m/s), Ti 22 ms) the 10 mm F3000 move ends in a sustained oscillation of about 700 um "
    "peak to peak at about 14 Hz (the velocity loop's crossover), measured in-process for 1.5 s "
    "after the move at T = 50 ms (the jerk filter on main) and at T = 9 ms alike; the end-position "
    "check passed on main by the cycle's phase at the run's end (0.40998 m), at T = 9 ms it ends "
    "at 0.40959 m. The node set equals the in-process exchanges to 1e-9 m before that check. "
    "Cause not measured: the re-tune models the 1 kHz current loop as a 3 ms lag"
)
