"""Feed-forward symmetrization: the NC's position and velocity, delayed to meet the feedback.

A position loop with velocity and acceleration feed-forward drives the axis by the
feed-forward alone when the model is right; the loops then see no error only if the setpoint
they compare with the feedback is the one the feed-forward has produced by the time that
feedback was latched. In the controller node the acceleration feed-forward reaches the motor
late (one exchange of transport, half an exchange of hold, the closed current loop's lag) and
the velocity estimate lags the table (half a sample for the difference quotient and the FIR's
group delay). Without the delay, every acceleration of the NC shows up as a velocity error of
a D_v and a following error of v D_x, which the PI loop integrates into a speed overshoot after
each ramp (18 % on a 10 mm F3000 move at the T = 9 ms jerk filter, docs/planner.md).
Sinumerik does the same ("Vorsteuerungssymmetrierung": MD32810 $MA_EQUIV_SPEEDCTRL_TIME delays
the position setpoint of the position controller by the equivalent time of the speed loop
when feed-forward is on).

`DelayedReference.update(x, v, a)` takes the reference once per sample period and returns
(x(t - D_x), v(t - D_v), a(t)): the acceleration (the feed-forward) undelayed. Between samples
the delayed values come from the cubic Hermite spline through the samples' positions and
velocities (feed_twin.control.cascade.hermite: its position and its slope). Before the first
sample the reference is taken at rest where it starts.
"""

from __future__ import annotations

import collections
import math

from feed_twin.control.cascade import hermite

_EXACT = 1e-9  # a delay within this many periods of a whole number of samples is taken as one


class DelayedReference:
    """(x, v, a) -> (x(t - position_delay_s), v(t - velocity_delay_s), a(t)) at a fixed period."""

    def __init__(self, *, period_s: float, position_delay_s: float, velocity_delay_s: float):
        if not period_s > 0.0:
            raise ValueError(f"period_s = {period_s!r}: must be > 0")
        for name, value in (
            ("position_delay_s", position_delay_s),
            ("velocity_delay_s", velocity_delay_s),
        ):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} = {value!r}: must lie in [0, 1] s")
        self.period_s = period_s
        self.position_delay_s = position_delay_s
        self.velocity_delay_s = velocity_delay_s
        longest = max(position_delay_s, velocity_delay_s) / period_s
        self._history: collections.deque[tuple[float, float, float]] = collections.deque(
            maxlen=math.floor(longest + _EXACT) + 2
        )

    def reset(self) -> None:
        self._history.clear()

    def update(self, x: float, v: float, a: float) -> tuple[float, float, float]:
        history = self._history
        if not history:
            history.extend([(x, 0.0, 0.0)] * (history.maxlen or 1))
        history.append((x, v, a))
        x_d = self._at(self.position_delay_s)[0]
        v_d = self._at(self.velocity_delay_s)[1]
        return x_d, v_d, a

    def _at(self, delay_s: float) -> tuple[float, float, float]:
        """The spline's (x, dx/dt, d2x/dt2) delay_s before the newest sample."""
        ages = delay_s / self.period_s
        whole = math.floor(ages + _EXACT)
        if abs(ages - whole) <= _EXACT:
            return self._history[-1 - whole]
        cur = self._history[-1 - whole]
        prev = self._history[-2 - whole]
        return hermite(whole + 1.0 - ages, self.period_s, prev, cur)
