"""The component types a plant YAML may name, by their `type:`, and the effects they carry.

A new component (a friction law) is its own file plus one line here; the effects it declares
(`EFFECTS`) then belong to the discrepancy workflow's library.
"""

from __future__ import annotations

import dataclasses

from feed_twin.plant.axial_compliance import AxialCompliance
from feed_twin.plant.backlash import Backlash
from feed_twin.plant.ball_screw import BallScrew
from feed_twin.plant.cogging_torque import CoggingTorque
from feed_twin.plant.component import Component
from feed_twin.plant.coupling import Coupling
from feed_twin.plant.dc_bus import DcBus
from feed_twin.plant.dc_motor import DcMotor
from feed_twin.plant.effect_api import Effect
from feed_twin.plant.effort_source import EffortSource
from feed_twin.plant.elastoplastic_friction import ElastoPlasticFriction
from feed_twin.plant.external_force import ConstantForce, ExternalForce
from feed_twin.plant.gas_spring import GasSpring
from feed_twin.plant.gravity import Gravity
from feed_twin.plant.guide_friction import GuideFriction
from feed_twin.plant.inertia import Inertia
from feed_twin.plant.inverter import Inverter
from feed_twin.plant.mass import Mass
from feed_twin.plant.pmsm import Pmsm
from feed_twin.plant.screw_shaft import ScrewShaft
from feed_twin.plant.sensors import CurrentSensor, Encoder, LinearScale
from feed_twin.plant.stiction_friction import StictionFriction
from feed_twin.plant.thermal_growth import ThermalGrowth

COMPONENT_TYPES: dict[str, type[Component]] = {
    cls.TYPE: cls
    for cls in (
        AxialCompliance,
        Backlash,
        BallScrew,
        CoggingTorque,
        ConstantForce,
        Coupling,
        CurrentSensor,
        DcBus,
        DcMotor,
        EffortSource,
        ElastoPlasticFriction,
        Encoder,
        ExternalForce,
        GasSpring,
        Gravity,
        GuideFriction,
        Inertia,
        Inverter,
        LinearScale,
        Mass,
        Pmsm,
        ScrewShaft,
        StictionFriction,
        ThermalGrowth,
    )
}
# the effects the discrepancy workflow may add, each with the component type that carries it
EFFECTS: tuple[Effect, ...] = tuple(
    dataclasses.replace(effect, owner=cls.TYPE)
    for cls in COMPONENT_TYPES.values()
    for effect in cls.EFFECTS
)
