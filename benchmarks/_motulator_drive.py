"""The drive of config/axis_default.yaml in motulator, for benchmarks/model_speed.py.

Runs under the Python 3.12 venv that model_speed.py creates (motulator needs Python >= 3.12):
the same PMSM (p = 4, R_s = 0.35 ohm, L = 4 mH, psi = 0.3167 V s) with current-vector control
and a speed controller sampled at 62.5 us, two-mass mechanics (motor 3.2e-3 kg m^2 and the screw
and table reflected to the motor, the coupling's torsional stiffness), 560 V DC bus, a speed
step and a load step, simulated for 1 s. Prints the wall time of `simulate` [s] as its last line.
Written against motulator's current API (motulator.drive.model / control.sm); an older or newer
API makes this script fail, and model_speed.py reports the ratio as null with the error.
"""

import math
import time

# motulator runs in its own Python 3.12 venv (model_speed.py), not in .venv that pyright reads
import motulator.drive.control.sm as control  # pyright: ignore[reportMissingImports]
from motulator.drive import model  # pyright: ignore[reportMissingImports]

T_S = 62.5e-6
T_STOP = 1.0

par = model.SynchronousMachinePars(n_p=4, R_s=0.35, L_d=4.0e-3, L_q=4.0e-3, psi_f=0.3167)
machine = model.SynchronousMachine(par)
mechanics = model.TwoMassMechanicalSystem(J_M=3.2e-3, J_L=2.6e-3, K_S=3.0e4, C_S=2.0)
converter = model.VoltageSourceConverter(u_dc=560.0)
mdl = model.Drive(machine, mechanics, converter)

cfg = control.CurrentVectorControllerCfg(i_s_max=30.0, sensorless=False, T_s=T_S, J=5.8e-3)
vector_ctrl = control.CurrentVectorController(par, cfg)
speed_ctrl = control.SpeedController(J=5.8e-3, alpha_s=2.0 * math.pi * 50.0)
ctrl = control.VectorControlSystem(vector_ctrl, speed_ctrl)
ctrl.set_speed_ref(lambda t: (t > 0.05) * 2.0 * math.pi * 10.0)
mdl.mechanics.set_external_load_torque(lambda t: (t > 0.5) * 5.0)

sim = model.Simulation(mdl, ctrl)
t0 = time.perf_counter()
sim.simulate(t_stop=T_STOP)
print(time.perf_counter() - t0)
