"""Reference integration: the same generated plant functions, un-jitted, under scipy solve_ivp.

The loop mirrors feed_twin.sim.kernel.advance tick by tick (sensor sampling with delays, the
controller, recording) but integrates each base period with an adaptive scipy method at tight
tolerances instead of fixed-step RK4. It shares no equations with the fast path except the
generated ones, so agreement tests the loop, the integrator and the code generation together.
Averaged inverter only (the switching model's piecewise integration is the kernel's own).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from feed_twin.core import signals
from feed_twin.sim.engine import Engine, SimResult
from feed_twin.sim.kernel import RING


def reference_run(
    engine: Engine,
    n_ticks: int,
    *,
    ref: np.ndarray | None = None,
    drive: np.ndarray | None = None,
    ext: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    method: str = "DOP853",
    rtol: float = 1e-11,
    atol: float = 1e-13,
) -> SimResult:
    """Run `engine`'s plant and controller from tick 0 with solve_ivp; same recording."""
    model = engine.model
    if model.switching_inverter:
        raise ValueError("reference_run: the switching inverter is integrated by the kernel only")
    ns = model.namespace()
    rhs, outputs, sense, draw_noise = ns["rhs"], ns["outputs"], ns["sense"], ns["draw_noise"]
    angles = ns["angles"]
    p = engine.p
    x = model.initial_state() if x0 is None else np.array(x0, dtype=float)
    ref = np.zeros((n_ticks, signals.REF_SIZE)) if ref is None else ref
    drive = np.zeros((n_ticks, signals.OUT_SIZE)) if drive is None else drive
    ext = np.zeros((n_ticks, engine.n_ext)) if ext is None else ext
    from feed_twin.control.cascade import cascade_tick

    cs = np.array(engine.controller.initial_state()) if engine.controller is not None else None
    out = np.zeros(signals.OUT_SIZE)
    sw = np.zeros(3)
    ring = np.zeros((RING, signals.MEAS_SIZE))
    mraw, mdelay, meas = (np.zeros(signals.MEAS_SIZE) for _ in range(3))
    aux = np.zeros(len(model.aux_names))
    dx = np.zeros(len(x))
    rows, times = [], []
    h = engine.h
    for k in range(n_ticks):
        t = k * h
        noise = draw_noise(p, engine.seed, k)
        sense(t, x, p, out, ext[k], sw, angles(t, x, p), noise, mraw, mdelay)
        ring[k % RING] = mraw
        for m in range(signals.MEAS_SIZE):
            meas[m] = ring[(k - min(int(mdelay[m]), k)) % RING, m]
        if cs is not None:
            cascade_tick(engine.cp, cs, k, ref[k], meas, out)
        else:
            out[:] = drive[k]
        if k % engine.dec == 0:
            outputs(t, x, p, out, ext[k], sw, aux)
            ctrl = cs if cs is not None else np.zeros(0)
            row = np.concatenate([x, aux, meas, out, ctrl])
            rows.append(row[engine.sel])
            times.append(t)
        ext_k = ext[k]

        def f(tau, y, ext_k=ext_k):
            rhs(tau, y, p, out, ext_k, sw, dx)
            return dx.copy()

        sol = solve_ivp(f, (t, t + h), x, method=method, rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"reference_run: solve_ivp failed at t = {t!r} s: {sol.message}")
        x = sol.y[:, -1].copy()
    return SimResult(t=np.array(times), names=engine.record_names, data=np.array(rows))
