"""Range checks for the `__post_init__` of frozen parameter dataclasses.

Each raises `ValueError` naming the field and the value, e.g. `m = -3.0: must be > 0`;
feed_twin.core.config.from_mapping prefixes that with the file and the dotted field path.
"""

from __future__ import annotations

import math


def require_finite(name: str, value: float) -> None:
    # the annotation is the contract; the check is for what a YAML file or a caller hands in
    wrong_type = not isinstance(value, int | float)  # pyright: ignore[reportUnnecessaryIsInstance]
    if wrong_type or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{name} = {value!r}: must be a finite number")


def require_positive(name: str, value: float) -> None:
    require_finite(name, value)
    if value <= 0.0:
        raise ValueError(f"{name} = {value!r}: must be > 0")


def require_nonnegative(name: str, value: float) -> None:
    require_finite(name, value)
    if value < 0.0:
        raise ValueError(f"{name} = {value!r}: must be >= 0")


def require_range(name: str, value: float, low: float, high: float) -> None:
    require_finite(name, value)
    if not low <= value <= high:
        raise ValueError(f"{name} = {value!r}: must lie in [{low}, {high}]")


def require_integer_multiple(name: str, value: float, base: float, base_name: str) -> int:
    """Return value/base when it is a whole number (to 1e-9 relative), else raise."""
    require_positive(name, value)
    ratio = value / base
    whole = round(ratio)
    if whole < 1 or abs(ratio - whole) > 1e-9 * max(1.0, ratio):
        raise ValueError(
            f"{name} = {value!r}: must be an integer multiple of {base_name} = {base!r}"
        )
    return whole
