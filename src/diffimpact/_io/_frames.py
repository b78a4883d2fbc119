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


def frame_columns(frame, name: str = "inputs") -> dict:
    """A DataFrame's columns as a dict of numpy arrays, keyed by the column
    names (the sweeps' rows); a column that is not numbers is refused."""
    import numpy as np

    out = {}
    for k in frame.columns:
        a = np.asarray(frame[k].to_numpy())
        if a.dtype.kind not in "biuf":
            raise ValueError(
                f"`{name}` column {k!r} holds {a.dtype} values, not numbers: a "
                "sweep's rows are arrays of numbers"
            )
        out[str(k)] = a
    return out


def to_frame(tree, index, purpose: str):
    """A pytree of arrays with a leading axis of rows as a DataFrame: one
    column per leaf, named by its key (``a.b`` in nested dicts); a leaf with
    more axes gives one column per entry (``name[j]``)."""
    import jax
    import numpy as np

    pd = optional("pandas", purpose)
    columns = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        name = ".".join(_key(k) for k in path) or "output"
        a = np.asarray(leaf)
        if a.ndim == 1:
            columns[name] = a
            continue
        flat = a.reshape(a.shape[0], -1)
        for j, at in enumerate(np.ndindex(*a.shape[1:])):
            columns[f"{name}[{','.join(map(str, at))}]"] = flat[:, j]
    return pd.DataFrame(columns, index=index)


def _key(k) -> str:
    for attr in ("key", "name", "idx"):
        if hasattr(k, attr):
            return str(getattr(k, attr))
    return str(k)


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
