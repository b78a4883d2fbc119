"""Units of the experiment files, their error type, and how a number is read."""

from __future__ import annotations

import math
import re

# unit suffix -> (dimension, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "um": ("length", 1e-6),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "m_s": ("velocity", 1.0),
    "mm_s": ("velocity", 1e-3),
    "deg": ("angle", math.pi / 180.0),
    "rad": ("angle", 1.0),
    "rad_s": ("angular_velocity", 1.0),
    "deg_s": ("angular_velocity", math.pi / 180.0),
    "rpm": ("angular_velocity", 2.0 * math.pi / 60.0),
    "kg": ("mass", 1.0),
    "g": ("mass", 1e-3),
    "n": ("force", 1.0),
    "kn": ("force", 1e3),
    "pa": ("stress", 1.0),
    "mpa": ("stress", 1e6),
    "gpa": ("stress", 1e9),
    # used by the body declarations of a planar-body file, not by columns
    "kg_m2": ("inertia", 1.0),
    "g_mm2": ("inertia", 1e-9),
    "g_cm2": ("inertia", 1e-7),
    "kg_m3": ("density", 1.0),
    "g_cm3": ("density", 1e3),
    "m_s2": ("acceleration", 1.0),
    # US customary units, by their exact SI definitions (international yard
    # and pound, 1959; standard gravity for the pound-force)
    "in": ("length", 0.0254),
    "ft": ("length", 0.3048),
    "in_s": ("velocity", 0.0254),
    "ft_s": ("velocity", 0.3048),
    "lb": ("mass", 0.45359237),
    "lbf": ("force", 0.45359237 * 9.80665),
    "psi": ("stress", 0.45359237 * 9.80665 / 0.0254**2),
    "ksi": ("stress", 1e3 * 0.45359237 * 9.80665 / 0.0254**2),
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
