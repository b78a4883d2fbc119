"""pandas and ArviZ, optional: recognised without importing them, imported
only where a DataFrame or an InferenceData is made, with a message naming
the ``pip install`` that is missing."""

from __future__ import annotations

import importlib
import sys

_INSTALL = {"pandas": "pandas", "arviz": "arviz"}


def optional(module: str, purpose: str):
    """Import an optional dependency; an ImportError that says how to get it."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        package = _INSTALL.get(module, module)
        raise ImportError(
            f"{purpose} needs {package}, an optional dependency of diffimpact: "
            f"pip install {package}  (or pip install 'diffimpact[{package}]')"
        ) from err


def is_dataframe(obj) -> bool:
    """Whether ``obj`` is a pandas DataFrame (without importing pandas: a
    program that made one has imported it)."""
    pd = sys.modules.get("pandas")
    return pd is not None and isinstance(obj, pd.DataFrame)


def frame_columns(frame) -> dict:
    """A DataFrame's columns as a dict of numpy arrays (for the sweeps)."""
    import numpy as np

    return {str(k): np.asarray(frame[k].to_numpy()) for k in frame.columns}


# The unit suffix of each dimension's SI unit in column names (as the
# command line's sweep.csv writes them).
_SI_SUFFIX = {
    "length": "m",
    "time": "s",
    "velocity": "m_s",
    "angle": "rad",
    "angular_velocity": "rad_s",
    "mass": "kg",
    "force": "N",
    "stress": "Pa",
}


def si_suffix(dimension: str) -> str:
    """``_m`` for a length, ``_m_s`` for a velocity, "" if dimensionless."""
    return f"_{_SI_SUFFIX[dimension]}" if dimension in _SI_SUFFIX else ""
