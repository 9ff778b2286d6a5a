"""The drive's current loop behind a torque source: a PI on the motor's R-L windings.

A drive's torque is not its velocity loop's current setpoint times K_t at once: its current loop
drives the windings' voltage, and the motor's back-EMF is a disturbance that a loop without a
back-EMF feed-forward only rejects through its integrator. With the setpoint i* [A] held over a
tick, the q-axis current i [A] and the PI's integral z [V] obey (i_d held at zero by its own
loop, so no cross coupling acts on q):
    e = i* - i,    u = clip(Kp e + z, -u_max, u_max)   (0 while the drive is disabled),
    dz/dt = (Kp / Ti) e      (held while |Kp e + z| >= u_max: clamping anti-windup),
    L di/dt = u - R i - k_e omega,    k_e = emf_ratio * K_t,    tau = K_t i,
emf_ratio = k_e / K_t: 1 for a DC motor, 2/3 for a PMSM in amplitude-invariant d/q
(K_t = 1.5 p psi_pm, k_e = p psi_pm); the windings then take u i / emf_ratio [W] (1.5 u_q i_q),
lose R i^2 / emf_ratio and store L i^2 / (2 emf_ratio), and the rotor gets K_t i omega.
Closed loop, unsaturated:
    i(s) = [(Kp s + Kp/Ti) i*(s) - k_e s omega(s)] / (L s^2 + (R + Kp) s + Kp/Ti),
so on a steady ramp the current lags its setpoint by (Ti/Kp) (R di*/dt + k_e domega/dt): the
integrator must ramp the voltage by what the resistance and the rising back-EMF take. That lag
follows the acceleration, and an ideal source cannot show it (a heavier table mimics it).
The drive's loop is sampled (8 kHz on the truth machine's data sheet) and acts one period late;
a ramp's lag is the same for it (its integrator ramps the voltage alike), its answer to faster
changes is not: this continuous loop is the sampled one's low-frequency model.
"""

from __future__ import annotations

from numba import njit


@njit(error_model="numpy", forceinline=True)
def current_loop(
    i_ref: float,
    enabled: float,
    i: float,
    z: float,
    omega: float,
    gain: float,
    R: float,
    L: float,
    Kp: float,
    Ti: float,
    emf_ratio: float,
    u_max: float,
) -> tuple[float, float, float]:
    """(di/dt [A/s], dz/dt [V/s], winding voltage u [V]) of the loop's equations above;
    while the drive is disabled (enabled < 0.5) the bridge is off (u = 0: the current decays
    through the windings) and the integral holds."""
    if enabled < 0.5:
        return (-R * i - emf_ratio * gain * omega) / L, 0.0, 0.0
    e = i_ref - i
    raw = Kp * e + z
    u = min(max(raw, -u_max), u_max)
    dz = Kp / Ti * e if abs(raw) < u_max else 0.0
    return (u - R * i - emf_ratio * gain * omega) / L, dz, u


def loop_poles(R: float, L: float, Kp: float, Ti: float) -> tuple[complex, complex]:
    """[1/s] The closed loop's poles, the roots of L s^2 + (R + Kp) s + Kp/Ti (back-EMF and
    limit aside)."""
    b = (R + Kp) / L
    c = Kp / (Ti * L)
    root = complex(b * b - 4.0 * c) ** 0.5
    return (-b - root) / 2.0, (-b + root) / 2.0


def fastest_rate(R: float, L: float, Kp: float, Ti: float) -> float:
    """[1/s] The largest pole magnitude, which sets explicit RK4's step: h |s| < 2.5."""
    return max(abs(s) for s in loop_poles(R, L, Kp, Ti))
