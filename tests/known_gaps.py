"""Reasons for the tests that are known to fail today, each with what was measured.

A test marked `xfail(strict=True)` with one of these fails the suite as soon as it passes again,
so the mark cannot outlive the gap it names.
"""

PLANNER_MOTION = (
    "issue #27, open: the #30 jerk profile (a box filter over an acceleration-limited plan) "
    "changed the synthetic records' motion (reversals spend 320 ms below 5 mm/s instead of "
    "252 ms); the synthetic truth's unmodelled current-loop lag and 3 % softer coupling then "
    "leave a residual that a ~1 N Stribeck hump fits (or that hides the small effect the test "
    "hides); on the old planner's records the same workflow passes (measured: 18 of 18)"
)

CROSS_COUPLING_FIT = (
    "open: on the #30 jerk profile's motion the least-squares fit of u_d_ref against "
    "-omega_e i_q over the node-set run gives L_q = 4.32 mH for the configured 4.0 mH (8 % off, "
    "the test allows 5 %); not explained yet (a guess: the regression leaves out the d-axis "
    "current loop's own dynamics, which the new motion excites more); the back-EMF constant "
    "still fits within 5 %"
)
