"""From a simulated impact to what an experimenter measures.

An `Experiment` is the model behind one experiment file: a template
scene (its fields are the defaults; each CSV row replaces the inputs it gives),
a normal law, optional friction, and how to solve.  `predict` maps one
row of inputs to the measured quantities of `diffimpact._io._data.QUANTITIES`.

The scene registry says, per scene, which CSV inputs set which scene fields,
which inputs every row must give, and the short parameter names a user fits
(``yield_strength``, ``mu``, ...), each a path into the `Experiment`.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp

from .._checks import as_float
from .._io._data import (
    DataError,
    ExperimentData,
    load_experiments,
    parse_column,
)
from .._io._declared_body import declared_body
from .._laws._base import AbstractNormalLaw
from .._laws._friction import Friction
from .._laws._jackson_green import JacksonGreen
from .._solve._rigid import RigidContact
from .._solve._settings import SolverSettings
from ..scenes._base import AbstractScene
from ._scenes import SCENES, scene_spec


class Experiment(eqx.Module):
    """The model of an experiment: scene template, law, friction, solver.

    **Arguments:** `scene` (its numbers are defaults, replaced row by row by the
    inputs of a data file), `law`, `friction` (None = frictionless), `method`
    and `settings` for `diffimpact.simulate`.
    """

    scene: AbstractScene
    law: AbstractNormalLaw | RigidContact
    friction: Friction | None = None
    method: str = eqx.field(static=True, default="auto")
    settings: SolverSettings = eqx.field(
        static=True, default=SolverSettings(max_steps=16384)
    )

    @staticmethod
    def default(scene: str) -> Experiment:
        """The built-in experiment of a scene name (e.g. ``"sphere_on_incline"``:
        the ball and prism of Alaci, Filote & Ciornei, Jackson-Green law,
        friction ``mu = 0.2``)."""
        return Experiment(**scene_spec(scene).default())

    @staticmethod
    def from_file(data) -> Experiment:
        """The experiment an experiment file names: for a planar-body file,
        the body it declares above its header (shape, mass, inertia, centre
        of mass, materials; docs: Data formats), in the state of its first
        row, with the Jackson-Green law and friction ``mu = 0.2`` as start;
        for any other file, its scene's built-in experiment (`default`).

        **Arguments:** `data`: a path, an `ExperimentData` or a pandas
        DataFrame (`load_experiments`)."""
        if not isinstance(data, ExperimentData):
            data = load_experiments(data)
        if data.declarations is not None:  # (none in a file of another scene)
            scene = declared_body(data.declarations, data.inputs, data.path)
            return Experiment(scene, JacksonGreen(), Friction(0.2))
        if data.scene is None:
            raise DataError(
                f"{data.path}: no 'scene' column and no body declared; add a "
                f"'scene' column naming one of {sorted(SCENES)}, or declare the "
                "planar body above the header"
            )
        return Experiment(**scene_spec(data.scene).default())


def resolve_parameter(experiment: Experiment, name: str) -> str:
    """The dotted path of a free-parameter name, or a ValueError listing names.

    Accepted: the scene's short names (``yield_strength`` = the flat's, the
    body that yields; ``mu``, ``mu_v``, ...), any numeric field of the law by
    its name (``ep_exponent``, ``dr_a``, ...), or a dotted path from the
    experiment (``scene.body.youngs_modulus``, ``law.c_a``, ``friction.mu``).
    """
    spec = scene_spec(experiment.scene)
    if name in spec.parameters:
        path = spec.parameters[name]
    elif name in _array_fields(experiment.law):
        path = f"law.{name}"
    else:
        path = name
    try:
        value = get_path(experiment, path)
    except AttributeError:
        value = None
    if value is None and path == "friction.mu_v" and experiment.friction is not None:
        return path  # no viscous term yet: `with_parameters` adds one at 0
    # a plain number is a parameter too (set by `eqx.tree_at`, which bypasses
    # the modules' converters); `with_parameters` makes it an array
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if value is None or not (eqx.is_inexact_array(value) or number):
        names = spec.parameters
        if isinstance(experiment.law, RigidContact):  # Coulomb friction only
            names = {k: v for k, v in names.items() if k != "mu_v"}
        known = sorted(names) + sorted(_array_fields(experiment.law))
        extra = (
            " (the experiment has no friction)" if path.startswith("friction") else ""
        )
        raise ValueError(
            f"unknown parameter {name!r}{extra}: expected one of {known}, or a "
            "dotted path such as 'scene.body.youngs_modulus'"
        )
    return path


def with_parameters(experiment: Experiment, paths) -> Experiment:
    """``experiment`` with every path of ``paths`` present as an array: a
    friction without a viscous term (``mu_v=None``) gets ``mu_v = 0`` when
    ``friction.mu_v`` is set or fitted."""
    if "friction.mu_v" in paths and experiment.friction.mu_v is None:
        experiment = eqx.tree_at(
            lambda e: e.friction.mu_v,
            experiment,
            as_float(0.0),
            is_leaf=lambda x: x is None,
        )
    plain = [p for p in paths if isinstance(get_path(experiment, p), int | float)]
    if plain:
        experiment = eqx.tree_at(
            lambda e: [get_path(e, p) for p in plain],
            experiment,
            [as_float(get_path(experiment, p)) for p in plain],
        )
    return experiment


def set_parameters(experiment: Experiment, values: dict) -> Experiment:
    """Return ``experiment`` with parameters set by name (names as in
    `resolve_parameter`); values in SI units."""
    if not values:
        return experiment
    paths = [resolve_parameter(experiment, n) for n in values]
    experiment = with_parameters(experiment, paths)
    new = eqx.tree_at(
        lambda e: [get_path(e, p) for p in paths],
        experiment,
        [
            jnp.asarray(v, dtype=get_path(experiment, p).dtype)
            for p, v in zip(paths, values.values(), strict=True)
        ],
    )
    # tree_at skips the modules' checks: run them on the concrete values.
    for p in paths:
        owner = get_path(new, p.rpartition(".")[0]) if "." in p else new
        try:
            dataclasses.replace(owner)
        except ValueError as err:
            raise ValueError(f"parameter {p!r}: {err}") from None
    return new


def _array_fields(module) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(module)
        if eqx.is_inexact_array(getattr(module, f.name))
    ]


def get_path(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def getter(path: str):
    return lambda obj: get_path(obj, path)


def si_inputs(experiment: Experiment, inputs: dict) -> dict:
    """``inputs`` keyed by quantity in SI units.

    A key is a quantity in SI (``"angle"`` in rad, ``"drop_height"`` in m) or a
    column name with its unit as in the CSV format (``"angle_deg"``,
    ``"drop_height_mm"``), converted to SI.  A name the scene does not take is
    a ``ValueError`` listing the ones it does (never silently ignored)."""
    spec = scene_spec(experiment.scene)
    out = {}
    for key, value in inputs.items():
        if key in spec.inputs:
            quantity, factor = key, 1.0
        else:
            try:
                col = parse_column(key)
            except DataError:
                col = None
            if col is None or col.is_sigma or col.quantity not in spec.inputs:
                names = sorted(spec.inputs)
                raise ValueError(
                    f"unknown input {key!r} for scene {spec.name!r}: give one of "
                    f"{names} in SI units, or a column name with its unit as in "
                    "the CSV format (e.g. 'angle_deg', 'drop_height_mm')"
                )
            quantity, factor = col.quantity, col.factor
        if quantity in out:
            raise ValueError(f"input {quantity!r} is given twice (as {key!r})")
        out[quantity] = value if factor == 1.0 else value * factor
    return out


def with_inputs(experiment: Experiment, inputs: dict) -> Experiment:
    """Replace the scene fields that one row's ``inputs`` give (keys as in
    `si_inputs`).

    ``eqx.tree_at`` does not re-run the scene's checks; `simulate` runs
    them on the scene it is given (and `check_rows` validates whole
    files before any solve)."""
    inputs = si_inputs(experiment, inputs)
    spec = scene_spec(experiment.scene)
    names = list(inputs)
    if not names:
        return experiment
    where = [getter("scene." + spec.inputs[q]) for q in names]
    return eqx.tree_at(
        lambda e: [w(e) for w in where],
        experiment,
        [as_float(inputs[q]) for q in names],
        # an optional field left at None (a planar body's height) is set too
        is_leaf=lambda x: x is None,
    )
