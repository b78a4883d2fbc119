"""Units of the experiment files, their error type, and how a number is read."""

from __future__ import annotations

import math
import re

# Factors to SI by dimension.  US customary units by their exact SI
# definitions (international yard and pound, 1959; standard gravity for the
# pound-force).  Inertia, density and acceleration serve the body
# declarations of a planar-body file, not columns.
_INCH, _POUND, _G0 = 0.0254, 0.45359237, 9.80665
_FACTORS: dict[str, dict[str, float]] = {
    "length": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "in": _INCH, "ft": 0.3048},
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6},
    "velocity": {"m_s": 1.0, "mm_s": 1e-3, "in_s": _INCH, "ft_s": 0.3048},
    "angle": {"deg": math.pi / 180.0, "rad": 1.0},
    "angular_velocity": {
        "rad_s": 1.0,
        "deg_s": math.pi / 180.0,
        "rpm": 2.0 * math.pi / 60.0,
    },
    "mass": {"kg": 1.0, "g": 1e-3, "lb": _POUND},
    "force": {"n": 1.0, "kn": 1e3, "lbf": _POUND * _G0},
    "stress": {
        "pa": 1.0,
        "mpa": 1e6,
        "gpa": 1e9,
        "psi": _POUND * _G0 / _INCH**2,
        "ksi": 1e3 * _POUND * _G0 / _INCH**2,
    },
    "inertia": {"kg_m2": 1.0, "g_mm2": 1e-9, "g_cm2": 1e-7},
    "density": {"kg_m3": 1.0, "g_cm3": 1e3},
    "acceleration": {"m_s2": 1.0},
}
# unit suffix -> (dimension, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    unit: (dimension, factor)
    for dimension, units in _FACTORS.items()
    for unit, factor in units.items()
}

SI = {
    "length": "m",
    "time": "s",
    "velocity": "m/s",
    "angle": "rad",
    "angular_velocity": "rad/s",
    "mass": "kg",
    "force": "N",
    "stress": "Pa",
    "inertia": "kg m^2",
    "density": "kg/m^3",
    "acceleration": "m/s^2",
    "dimensionless": "-",
}


class DataError(ValueError):
    """A problem with an experiment file, naming the file, row and column."""


def units_of(dim: str) -> str:
    return ", ".join(u for u, (d, _) in UNITS.items() if d == dim)


# A plain decimal number, or inf / nan spelled out (reported as not finite
# where a finite number is needed).  Python's float() also reads "1_000" and
# non-ASCII digits: "0_290" in a cell would be read as 290, a silent wrong value.
_NUMBER = re.compile(
    r"\s*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf(?:inity)?|nan)\s*",
    re.IGNORECASE,
)


def parse_number(text: str) -> float:
    """``text`` as a float if it is written as a plain decimal number (digits,
    one point, an exponent; ``inf`` or ``nan`` spelled out); ValueError
    otherwise."""
    if not isinstance(text, str) or not _NUMBER.fullmatch(text):
        raise ValueError(f"{text!r} is not a number")
    return float(text)


def parse_integer(text: str) -> int:
    """``text`` as an int if it is written as plain digits; ValueError
    otherwise (``int`` also reads ``"1_0"`` as 10)."""
    if not isinstance(text, str) or not re.fullmatch(r"\s*[+-]?[0-9]+\s*", text):
        raise ValueError(f"{text!r} is not an integer")
    return int(text)
