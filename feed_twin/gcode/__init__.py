"""G-code pipeline: lexer -> modal interpreter -> planner -> sampled trajectory.

`plan_program(path_or_text, config)` returns every sample; `plan_program_stream` yields chunks
with bounded look-ahead after validating the whole program. `load_nc_config(path)` reads the
`nc:` section of a config file.
"""

from feed_twin.gcode.config import NcAxis, NcConfig, WorkOffsets, load_nc_config
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.planner import plan_program, plan_program_stream, validate_program
from feed_twin.gcode.trajectory import NcEvent, SampledTrajectory

__all__ = [
    "GcodeError",
    "NcAxis",
    "NcConfig",
    "NcEvent",
    "SampledTrajectory",
    "WorkOffsets",
    "load_nc_config",
    "plan_program",
    "plan_program_stream",
    "validate_program",
]
