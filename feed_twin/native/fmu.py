"""FMU export: the axis as an FMI 2.0 co-simulation FMU with the C kernel compiled inside.

    feed-twin fmu --config config/axis_default.yaml --out axis.fmu

The FMU holds `modelDescription.xml`, `binaries/linux64/feed_twin_axis.so` (the C kernel of
feed_twin.native.emit and the FMI glue of feed_twin.native.fmi2, compiled with the system cc
against the FMI headers FMPy ships) and `sources/` (the same C files, to rebuild elsewhere:
`python -m fmpy compile axis.fmu`).

Variables (SI; every parameter with its unit and physical range, feed_twin.plant.slot_specs:
the range is in the modelDescription (min/max, description) and fmi2SetReal refuses a value
outside it with a message; signals take their units from their names):
- parameters (fixed, set before initialisation): every plant slot `<component>.<slot>`, the
  controller's slots `controller.<slot>` (its structure slots are compiled in and refused),
  `start.<body>` (the start position of the load coordinate; the others follow at rest) and
  `max_step` (the longest communication step accepted);
- inputs: at the configured boundary (CiA 402 mode) `ref.pos_ref_m`, `ref.vel_ref_m_s`,
  `ref.acc_ref_m_s2` (position), `ref.vel_ext_m_s` (velocity) or `ref.i_q_ext_A` (torque),
  plus `ref.effort_add` and `F_ext.<component>` [N] for each external force;
- outputs, at the communication point: every state, every sensor sample `meas.*` and controller
  output `out.*` (with the following error `out.following_error_m`) as the next tick computes
  them from the inputs set.

Checked against simulate_program to the bit by two importers, FMPy and libcosim
(tests/test_native_fmu.py); the sources compile clean as C99 under -Wall -Wextra -pedantic.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from feed_twin.core import signals
from feed_twin.native.build import FLAGS, find_cc, portable_flags, run_cc
from feed_twin.native.emit import CKernel, c_kernel
from feed_twin.native.fmi2 import GLUE_C
from feed_twin.plant.component import SlotSpec
from feed_twin.plant.slot_specs import describe, slot_specs

MODEL_IDENTIFIER = "feed_twin_axis"
# the sources are C99, so any importer's compiler builds them (python -m fmpy compile)
C99_FLAGS = (*(f for f in FLAGS if not f.startswith("-std=")), "-std=c99", "-Wall", "-Wextra")
MAX_STEP_S = 1.0  # [s] default longest communication step (the inputs are held over a step)
_MODE_INPUTS = {
    "position": ("pos_ref_m", "vel_ref_m_s", "acc_ref_m_s2"),
    "velocity": ("vel_ext_m_s",),
    "torque": ("i_q_ext_A",),
}
_SUFFIX_UNITS = (
    ("_m_s2", "m/s2"),
    ("_m_s", "m/s"),
    ("_1_s", "1/s"),
    ("_period_s", "s"),
    ("_m", "m"),
    ("_rad", "rad"),
    ("_A", "A"),
    ("_V", "V"),
    ("_Vs", "V s"),
    ("_H", "H"),
)
K_PARAM, K_CTRL_PARAM, K_REF, K_EXT, K_START, K_MAX_STEP, K_STATE, K_MEAS, K_OUT = range(9)


@dataclass(frozen=True)
class Variable:
    name: str
    kind: int
    index: int
    causality: str  # parameter, input, output
    start: float | None
    unit: str
    spec: SlotSpec | None = None  # the range fmi2SetReal checks (None: finite inputs only)


def signal_unit(name: str) -> str:
    """The unit a signal's or controller slot's name states in its suffix (pos_ref_m -> m,
    Kv_1_s -> 1/s), "" for none."""
    ratio = re.fullmatch(r"(m|rad)_per_(m|rad)", name)
    if ratio:
        return f"{ratio.group(1)}/{ratio.group(2)}"
    return next((unit for suffix, unit in _SUFFIX_UNITS if name.endswith(suffix)), "")


def controller_unit(name: str, effort: str) -> str:
    """The unit of a controller slot or output; `effort` is the velocity loop's output unit
    (A with a current loop, else the drive's input unit, "1")."""
    per = {"vel_Kp": " s/m", "vel_Ki_T": " s/m", "acc_ff_gain": " s2/m"}
    if name in per:
        return f"{effort}{per[name]}" if effort != "1" else per[name].strip()
    if name in ("effort_limit", "effort_cmd", "effort_add"):
        return effort
    if name in ("Kp_d", "Ki_T_d", "Kp_q", "Ki_T_q"):
        return "V/A"
    return signal_unit(name) or "1"


def variables(axis, kernel: CKernel) -> list[Variable]:
    model = axis.plant
    out: list[Variable] = []
    p0 = model.nominal_params()
    for name, comp in model.components.items():
        for slot, spec in slot_specs(comp).items():
            full = f"{name}.{slot}"
            i = model.param_index[full]
            out.append(Variable(full, K_PARAM, i, "parameter", float(p0[i]), spec.unit, spec))
    effort = "1"
    if axis.controller is not None:
        from feed_twin.control.layout import (
            LOOP_PRESENT,
            P_HAS_CURRENT,
            STRUCTURE_SLOTS,
            build_cascade,
        )

        cascade = build_cascade(axis.controller)
        effort = "A" if cascade.params[P_HAS_CURRENT] == LOOP_PRESENT else "1"
        for i, name in enumerate(cascade.param_names):
            if i not in STRUCTURE_SLOTS:
                value = float(cascade.params[i])
                unit = controller_unit(name, effort)
                out.append(
                    Variable(f"controller.{name}", K_CTRL_PARAM, i, "parameter", value, unit)
                )
        mode = axis.controller.mode
        inputs = _MODE_INPUTS[mode] + ("effort_add",)
    else:
        inputs = ()
    load = model.coordinates[-1]
    finite = SlotSpec(
        unit=_coord_unit(load), low=-math.inf, low_open=True, high=math.inf, high_open=True
    )
    out.append(Variable(f"start.{load.name}", K_START, 0, "parameter", 0.0, finite.unit, finite))
    step = SlotSpec(unit="s", low=0.0, low_open=True, high=math.inf, high_open=True)
    out.append(Variable("max_step", K_MAX_STEP, 0, "parameter", MAX_STEP_S, "s", step))
    for name in inputs:
        i = signals.REF_NAMES.index(name)
        out.append(Variable(f"ref.{name}", K_REF, i, "input", 0.0, controller_unit(name, effort)))
    for i, name in enumerate(model.ext_names):
        out.append(Variable(f"F_ext.{name}", K_EXT, i, "input", 0.0, "N"))
    for i, (name, unit) in enumerate(zip(model.state_names, model.state_units, strict=True)):
        out.append(Variable(name, K_STATE, i, "output", None, unit))
    for i, name in enumerate(signals.MEAS_NAMES):
        out.append(Variable(f"meas.{name}", K_MEAS, i, "output", None, signal_unit(name)))
    for i, name in enumerate(signals.OUT_NAMES):
        unit = controller_unit(name, effort)
        out.append(Variable(f"out.{name}", K_OUT, i, "output", None, unit))
    return out


def _coord_unit(coord) -> str:
    return "rad" if coord.kind == "rotational" else "m"


def model_description(axis, kernel: CKernel, variables_: list[Variable], guid: str) -> str:
    units = sorted({v.unit for v in variables_ if v.unit})
    rows = []
    for vr, v in enumerate(variables_):
        variability = "fixed" if v.causality == "parameter" else "continuous"
        real = "<Real"
        if v.unit:
            real += f" unit={quoteattr(v.unit)}"
        if v.spec is not None and math.isfinite(v.spec.low) and not v.spec.low_open:
            real += f' min="{_xs_double(v.spec.low)}"'
        if v.spec is not None and math.isfinite(v.spec.high) and not v.spec.high_open:
            real += f' max="{_xs_double(v.spec.high)}"'
        if v.start is not None:
            real += f' start="{_xs_double(v.start)}"'
        described = "" if v.spec is None else f" description={quoteattr(describe(v.spec))}"
        rows.append(
            f'    <ScalarVariable name={quoteattr(v.name)} valueReference="{vr}" '
            f'causality="{v.causality}" variability="{variability}"{described}>{real}/>'
            "</ScalarVariable>"
        )
    outputs = [i + 1 for i, v in enumerate(variables_) if v.causality == "output"]
    unknowns = "\n".join(f'      <Unknown index="{i}"/>' for i in outputs)
    sources = "".join(f'<File name="{n}"/>' for n in ("feed_twin_axis.c", "fmu_glue.c"))
    return "\n".join(
        [
            '<?xml version="1.0" encoding="UTF-8"?>',
            f'<fmiModelDescription fmiVersion="2.0" modelName={quoteattr(MODEL_IDENTIFIER)} '
            f'guid="{guid}" description={quoteattr(f"feed_twin axis twin of {axis.source}")} '
            'generationTool="feed_twin" variableNamingConvention="flat" '
            'numberOfEventIndicators="0">',
            f'  <CoSimulation modelIdentifier="{MODEL_IDENTIFIER}" '
            'canHandleVariableCommunicationStepSize="true" canNotUseMemoryManagementFunctions='
            f'"true"><SourceFiles>{sources}</SourceFiles></CoSimulation>',
            "  <UnitDefinitions>",
            *(f"    <Unit name={quoteattr(u)}/>" for u in units),
            "  </UnitDefinitions>",
            '  <LogCategories><Category name="logStatusError"/></LogCategories>',
            f'  <DefaultExperiment startTime="0.0" stepSize="{kernel.base_period_s!r}"/>',
            "  <ModelVariables>",
            *rows,
            "  </ModelVariables>",
            "  <ModelStructure>",
            "    <Outputs>",
            unknowns,
            "    </Outputs>",
            "    <InitialUnknowns>",
            unknowns,
            "    </InitialUnknowns>",
            "  </ModelStructure>",
            "</fmiModelDescription>",
            "",
        ]
    )


def _xs_double(value: float) -> str:
    """A float as XML Schema writes a double (INF, -INF, NaN)."""
    if np.isnan(value):
        return "NaN"
    if np.isinf(value):
        return "INF" if value > 0 else "-INF"
    return repr(float(value))


def _c_list(items) -> str:
    return ", ".join(items) or "0"


def _c_double(value: float) -> str:
    if math.isinf(value):
        return "INFINITY" if value > 0 else "-INFINITY"
    return float(value).hex()


def _range_flags(spec: SlotSpec | None) -> int:
    """Bits of the glue's RANGE_* flags."""
    if spec is None:
        return 0
    return (spec.low_open << 0) | (spec.high_open << 1) | (spec.integer << 2)


def glue_source(axis, kernel: CKernel, variables_: list[Variable], guid: str) -> str:
    model = axis.plant
    load = model.coordinates[-1]
    start = []
    for state, chain in model.position_chains(load.name).items():
        ops = "".join(f" * {_c_double(m)} / {_c_double(d)}" for m, d in chain)
        start.append(f"    x[{model.state_index[state]}] = c->start{ops};")
    return GLUE_C.format(
        source=axis.source,
        kinds=_c_list(str(v.kind) for v in variables_),
        indices=_c_list(str(v.index) for v in variables_),
        names=_c_list(f'"{v.name}"' for v in variables_),
        low=_c_list(_c_double(-math.inf if v.spec is None else v.spec.low) for v in variables_),
        high=_c_list(_c_double(math.inf if v.spec is None else v.spec.high) for v in variables_),
        flags=_c_list(str(_range_flags(v.spec)) for v in variables_),
        ranges=_c_list('""' if v.spec is None else f'"{describe(v.spec)}"' for v in variables_),
        n_vr=len(variables_),
        start_state="\n".join(start),
        guid=guid,
        max_step=repr(MAX_STEP_S),
        start=0.0,
    )


def fmi_headers() -> Path:
    """The FMI headers FMPy ships (fmpy/c-code)."""
    try:
        import fmpy
    except ImportError:
        raise RuntimeError(
            "FMU export needs the FMI headers of FMPy: pip install fmpy (requirements.txt)"
        ) from None
    return Path(fmpy.__file__).resolve().parent / "c-code"


def build_fmu(axis, out: Path, *, cc: str = "cc") -> Path:
    """Write the FMU of `axis` (feed_twin.sim.config.AxisConfig) to `out`; returns `out`."""
    compiler = find_cc(cc)
    controller = None
    if axis.controller is not None:
        from feed_twin.control.layout import build_cascade

        controller = build_cascade(axis.controller)
    kernel = c_kernel(
        axis.plant,
        base_period_s=axis.engine.base_period_s,
        controller=controller,
        substeps=axis.engine.substeps,
        seed=axis.engine.seed,
    )
    vars_ = variables(axis, kernel)
    digest = hashlib.sha256(kernel.source.encode() + repr(vars_).encode()).hexdigest()
    guid = "{" + str(uuid.UUID(digest[:32])) + "}"
    glue = glue_source(axis, kernel, vars_, guid)
    # Built beside `out` and moved in place at the end: a failure (a full disk, a compiler
    # error) leaves neither the build directory nor a partial FMU behind.
    build = out.parent / f".{out.name}.build"
    build.mkdir(parents=True, exist_ok=True)
    try:
        files = {"feed_twin_axis.c": kernel.source, "feed_twin_axis.h": kernel.header}
        files["fmu_glue.c"] = glue
        for name, text in files.items():
            (build / name).write_text(text)
        library = build / f"{MODEL_IDENTIFIER}.so"
        run_cc(
            compiler,
            [*C99_FLAGS, *portable_flags(), "-I", str(fmi_headers()), "-I", str(build), "-shared"],
            [build / "feed_twin_axis.c", build / "fmu_glue.c"],
            library,
        )
        packed = build / out.name
        with zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", model_description(axis, kernel, vars_, guid))
            z.write(library, f"binaries/linux64/{MODEL_IDENTIFIER}.so")
            for name, text in files.items():
                z.writestr(f"sources/{name}", text)
        os.replace(packed, out)
    finally:
        shutil.rmtree(build, ignore_errors=True)
    return out
