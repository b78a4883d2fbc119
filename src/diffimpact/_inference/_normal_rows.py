"""The common row of a sweep: a sphere hitting a flat (`normal_impact`,
public as ``diffimpact.normal_impact_row``), its inputs with their defaults
and its outputs."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax.numpy as jnp
import numpy as np

from .._checks import as_float, is_traced
from .._compile import filter_jit
from .._laws._jackson_green import JacksonGreen
from .._materials import Material
from .._solve._settings import SolverSettings
from .._solve._simulate import simulate
from ..scenes import NormalImpact

# Inputs of `normal_impact` and their defaults (SI): the reference impact
# of the tests and benchmarks, a 5 mm steel sphere on a flat of the same steel.
NORMAL_DEFAULTS: dict[str, float] = {
    "velocity": 1.0,  # approach speed at first contact [m/s]
    "yield_strength": 300e6,  # [Pa]
    "youngs_modulus": 210e9,  # [Pa]
    "poisson_ratio": 0.3,  # [-]
    "radius": 5e-3,  # sphere radius [m]
    "density": 7850.0,  # [kg/m^3], gives the mass when `mass` is not given
}
# `mass` [kg] has no fixed default: 4/3 pi radius^3 density.
_NORMAL_COLUMNS = (*NORMAL_DEFAULTS, "mass")
_ALIASES = {"E": "youngs_modulus", "nu": "poisson_ratio"}

# Outputs of `normal_impact` (ImpactResult fields), SI units.
NORMAL_OUTPUTS = (
    "contact_time",  # [s]
    "cor_newton",  # [-]
    "max_force",  # [N]
    "max_deflection",  # [m]
    "permanent_deformation",  # [m]
    "rebound_velocity",  # [m/s]
)


def _normal_params(params: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for name, value in params.items():
        canon = _ALIASES.get(name, name)
        if canon not in _NORMAL_COLUMNS:
            raise ValueError(
                f"unknown sweep column `{name}`; normal_impact takes "
                f"{', '.join(_NORMAL_COLUMNS)} (aliases E, nu)"
            )
        if canon in out:
            raise ValueError(f"`{name}` is given twice (as `{canon}` and its alias)")
        out[canon] = value
    return out


def _normal_scene(params: Mapping[str, Any]):
    p = {**NORMAL_DEFAULTS, **_normal_params(params)}
    if "mass" not in p:
        p["mass"] = 4.0 / 3.0 * jnp.pi * p["radius"] ** 3 * p["density"]
    mat = Material(
        p["youngs_modulus"], p["poisson_ratio"], p["yield_strength"], p["density"]
    )
    return NormalImpact(
        mass=p["mass"], radius=p["radius"], body=mat, flat=mat, velocity=p["velocity"]
    )


def check_normal_inputs(columns: Mapping[str, Any]) -> None:
    """Check the columns of a `normal_impact` sweep before running it.

    Inside a sweep the inputs are traced, so a bad row (say a zero velocity)
    is only found at run time: with ``throw=False`` (the default of
    `normal_impact`) it gets the code ``invalid_input`` and NaN outputs.
    This builds the scene once from the whole (concrete) columns, so that a
    bad value raises ``ValueError`` naming the field (e.g.
    ``NormalImpact.velocity``) before anything is compiled.
    """
    _normal_scene({k: np.asarray(v) for k, v in columns.items()})


def normal_impact(
    params: Mapping[str, Any],
    *,
    law=None,
    method="quadrature",
    settings=None,
    throw: bool = False,
) -> dict:
    """One row of a normal-impact sweep: a sphere hitting a flat head-on.

    Builds `diffimpact.scenes.NormalImpact` from the named columns of
    ``params`` (any subset of `NORMAL_DEFAULTS` and ``mass``; the rest
    take their defaults) and simulates it.  Sphere and flat are the same material
    (``youngs_modulus``, ``poisson_ratio``, ``yield_strength``), as in the
    Jackson-Green validation grid; ``mass`` defaults to
    ``4/3 pi radius^3 density``.  ``E`` and ``nu`` are accepted as aliases.

    **Arguments:**

    - `params`: mapping of column name to a scalar (one row).
    - `law`: the contact law (default `diffimpact.JacksonGreen`).
    - `method`: default ``"quadrature"``, the ODE-free energy solution: exact
      to about 1e-11 and the fastest path (Hertz and Jackson-Green only).
    - `settings`: `diffimpact.SolverSettings` (default settings).
    - `throw`: default False: a row whose impact fails (outside the contact
      model, say) or whose input lies outside its domain (``invalid_input``)
      gets NaN outputs and its code, and the sweep goes on, also when the
      row is called eagerly; True stops the whole sweep at the first failure
      or bad value.

    **Returns:** dict of `NORMAL_OUTPUTS` (SI: s, -, N, m, m, m/s) and
    ``"result"``, the integer `diffimpact.RESULTS` code of each row
    (0: successful; `diffimpact.result_name` names the others).

    Use with `sweep` (``sweep(normal_impact, grid(velocity=...))``) or,
    for other laws, ``functools.partial(normal_impact, law=di.Hertz())``;
    `check_normal_inputs` validates the columns first.
    """
    if not throw and not is_traced(params):
        # Eagerly the constructors would refuse a bad value at once; compiled,
        # the row gets its code, as in a sweep (a loop and a sweep agree).
        _normal_params(params)  # an unknown column: still an error
        rows = {k: as_float(v) for k, v in params.items()}
        return _compiled_row(rows, law, method, settings)
    scene = _normal_scene(params)
    res = simulate(
        scene,
        JacksonGreen() if law is None else law,
        method,
        settings=SolverSettings() if settings is None else settings,
        throw=throw,
    )
    # Only these outputs: XLA then drops the work nothing reads.
    out = {name: getattr(res, name) for name in NORMAL_OUTPUTS}
    out["result"] = res.result._value
    return out


@filter_jit
def _compiled_row(params, law, method, settings):
    return normal_impact(params, law=law, method=method, settings=settings)


# The public name (``diffimpact.normal_impact_row``): one row of a sweep.
normal_impact_row = normal_impact
