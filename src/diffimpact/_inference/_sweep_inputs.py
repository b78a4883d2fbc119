"""Building the rows of a sweep: a grid (the Cartesian product of axes) or a
seeded random sample (uniform or log-uniform per column)."""

from __future__ import annotations

import math
import zlib

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import integer


def grid(**axes) -> dict[str, np.ndarray]:
    """Cartesian product of 1-D arrays, as flat columns.

    ``grid(velocity=[1, 2], yield_strength=[1e8, 2e8, 3e8])`` gives a dict of
    two arrays of 6 rows.  Rows are in C order: the *last* named axis varies
    fastest, so ``column.reshape(len(a0), len(a1), ...)`` recovers the grid
    (axis ``i`` along dimension ``i``).

    **Raises:** ``ValueError`` naming the axis if it is not 1-D or empty, or if
    no axis is given.
    """
    if not axes:
        raise ValueError("`grid` needs at least one axis, e.g. velocity=[1.0, 2.0]")
    arrays = {}
    for name, values in axes.items():
        a = np.asarray(values)
        if a.ndim != 1:
            raise ValueError(f"`{name}` must be a 1-D array of values, got {a.shape}")
        if a.size == 0:
            raise ValueError(f"`{name}` is empty: give at least one value")
        arrays[name] = a
    mesh = np.meshgrid(*arrays.values(), indexing="ij")
    return {name: m.ravel() for name, m in zip(arrays, mesh, strict=True)}


def sample(key, n: int, **ranges) -> dict[str, np.ndarray]:
    """``n`` random rows, each column drawn independently.

    **Arguments:**

    - `key`: a ``jax.random`` key, or an integer seed.
    - `n`: number of rows (> 0).
    - `ranges`: ``name=(low, high)`` draws uniformly in ``[low, high)``;
      ``name=(low, high, "log")`` draws *log-uniformly* (``log x`` uniform, the
      natural choice for quantities spanning decades such as speeds and yield
      strengths; needs ``0 < low``).

    Each column's stream is keyed by its name (``fold_in`` of a CRC of it), so
    adding or reordering columns does not change the others.

    **Returns:** a dict of float arrays (float64 under diffimpact's default),
    as numpy.
    """
    n = integer("n", n)
    if not ranges:
        raise ValueError("`sample` needs at least one range, e.g. velocity=(0.1, 10)")
    if isinstance(key, int | np.integer):
        key = jax.random.key(int(key))
    out = {}
    for name, spec in ranges.items():
        spec = tuple(spec)
        log = len(spec) == 3 and spec[2] == "log"
        if len(spec) not in (2, 3) or (
            len(spec) == 3 and spec[2] not in ("log", "lin")
        ):
            raise ValueError(
                f"`{name}` must be (low, high) or (low, high, 'log'), got {spec!r}"
            )
        lo, hi = float(spec[0]), float(spec[1])
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"`{name}` needs finite low <= high, got ({lo}, {hi})")
        if log and lo <= 0:
            raise ValueError(f"`{name}`: a log-uniform range needs low > 0, got {lo}")
        k = jax.random.fold_in(key, zlib.crc32(name.encode()) & 0x7FFFFFFF)
        a, b = (math.log(lo), math.log(hi)) if log else (lo, hi)
        u = jax.random.uniform(k, (n,), dtype=jnp.result_type(float))
        x = a + (b - a) * u
        out[name] = np.asarray(jnp.exp(x) if log else x)
    return out
