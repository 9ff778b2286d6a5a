"""G- and M-codes the interpreter knows, by name ("G90.1"), with their modal groups."""

from __future__ import annotations

MM = 1e-3  # [m] per millimetre
INCH = 25.4e-3  # [m] per inch

# Modal groups, named as the error messages show them. A block holds at most one code of each
# modal group; non-modal codes act on their own block only.
MOTION = "motion"
PLANE = "plane"
UNITS = "units"
DISTANCE = "distance"
ARC_DISTANCE = "arc distance"
FEED_MODE = "feed mode"
PATH_CONTROL = "path control"
WORK_OFFSET = "work offset"
CUTTER_COMPENSATION = "cutter compensation"
TOOL_LENGTH_OFFSET = "tool length offset"
NON_MODAL = "non-modal"

GROUP_OF: dict[str, str] = {
    **dict.fromkeys(("G0", "G1", "G2", "G3", "G80"), MOTION),
    **dict.fromkeys(("G17", "G18", "G19"), PLANE),
    **dict.fromkeys(("G20", "G21", "G70", "G71", "G700", "G710"), UNITS),
    **dict.fromkeys(("G90", "G91"), DISTANCE),
    **dict.fromkeys(("G90.1", "G91.1"), ARC_DISTANCE),
    "G94": FEED_MODE,
    # exact stop G60 (Sinumerik; Fanuc's one-direction positioning G60 is not modelled),
    # G61 and G61.1 (LinuxCNC's exact path and exact stop, both a stop here); G64 blends
    **dict.fromkeys(("G60", "G61", "G61.1", "G64"), PATH_CONTROL),
    **dict.fromkeys(("G54", "G55", "G56", "G57", "G58", "G59"), WORK_OFFSET),
    **dict.fromkeys(("G4", "G9", "G53", "G92", "G92.1", "G92.2"), NON_MODAL),
    "G40": CUTTER_COMPENSATION,
    **dict.fromkeys(("G43", "G49"), TOOL_LENGTH_OFFSET),
}
UNSUPPORTED_G = {
    "G93": "unsupported mode (inverse-time feed)",
    "G95": "unsupported mode (feed per revolution)",
    "G96": "unsupported mode (constant surface speed)",
    "G41": "unsupported mode (cutter radius compensation)",
    "G42": "unsupported mode (cutter radius compensation)",
    "G28": "unsupported (return to reference point)",
    "G30": "unsupported (return to reference point)",
    "G10": "unsupported (setting offsets from the program)",
    "G5": "unsupported (spline motion)",
    "G5.1": "unsupported (spline motion)",
    "G92.3": "unsupported (restoring G92 offsets)",
    **dict.fromkeys(
        ("G73", "G74", "G81", "G82", "G83", "G84", "G85", "G86", "G87", "G88", "G89"),
        "unsupported (canned cycle)",
    ),
    **dict.fromkeys(("G38.2", "G38.3", "G38.4", "G38.5"), "unsupported (probing)"),
    **dict.fromkeys(("G33", "G33.1", "G76"), "unsupported (spindle-synchronised motion)"),
}
# Units: (length unit, feed unit; None keeps the feed unit: Sinumerik's G70/G71 scale geometry)
UNIT_CODES: dict[str, tuple[float, float | None]] = {
    "G20": (INCH, INCH),
    "G21": (MM, MM),
    "G70": (INCH, None),
    "G71": (MM, None),
    "G700": (INCH, INCH),
    "G710": (MM, MM),
}
LINE_MOTIONS = ("G0", "G1")
ARC_MOTIONS = ("G2", "G3")

# M-codes: those that only mark the recording (kind; the value is the M number), and those
# that stop the program
M_KNOWN = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30}
M_SPINDLE = {3: "spindle_cw", 4: "spindle_ccw"}
M_COOLANT = {7: "coolant_on", 8: "coolant_on", 9: "coolant_off"}
M_PAUSES = {0: "pause", 1: "optional_pause"}
CENTRE_LETTERS = ("I", "J", "K")
OTHER_LETTERS = frozenset("FSTIJKRPQ")
# Plane -> (first axis, second axis, normal axis, first centre letter, second centre letter)
PLANE_AXES = {
    "G17": ("X", "Y", "Z", "I", "J"),
    "G18": ("Z", "X", "Y", "K", "I"),
    "G19": ("Y", "Z", "X", "J", "K"),
}
PLANE_NAMES = {"G17": "G17 (XY)", "G18": "G18 (ZX)", "G19": "G19 (YZ)"}


def g_code_name(value: float) -> str | None:
    """The canonical name of a G word's number ("G90.1" for 90.1); None if not in tenths."""
    tenths = round(value * 10)
    if abs(value * 10 - tenths) > 1e-6:
        return None
    whole, tenth = divmod(tenths, 10)
    return f"G{whole}" if tenth == 0 else f"G{whole}.{tenth}"
