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
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import as_float
from .._io._data import (
    QUANTITIES,
    DataError,
    ExperimentData,
    load_experiments,
    parse_column,
)
from .._io._declared_body import declared_body
from .._laws._base import AbstractNormalLaw
from .._laws._friction import Friction
from .._laws._jackson_green import JacksonGreen
from .._materials import Material
from .._solve._rigid import RigidContact
from .._solve._settings import SolverSettings
from .._solve._simulate import simulate
from ..scenes._bar import FreeBar
from ..scenes._base import AbstractScene
from ..scenes._body import PlanarBody
from ..scenes._link import RotatingLink
from ..scenes._normal import NormalImpact
from ..scenes._planar import SphereOnIncline


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
        return scene_spec(scene).default()

    @staticmethod
    def from_file(data) -> Experiment:
        """The experiment an experiment file names: for a planar-body file,
        the body it declares above its header (shape, mass, inertia, centre
        of mass, materials; docs: Data formats), in the state of its first
        row, with the Jackson-Green law and friction ``mu = 0.2`` as start;
        for any other file, its scene's built-in experiment (`default`).

        **Arguments:** `data`: a path or an `ExperimentData`."""
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
        return scene_spec(data.scene).default()


# The short names every scene with friction accepts; anything else by its
# dotted path (``scene.radius``) or as a field of the law.
_FRICTION_NAMES = {"mu": "friction.mu", "mu_v": "friction.mu_v"}


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """How a scene meets the data: its name, its built-in experiment, the
    short names of its parameters (each a dotted path in the `Experiment`);
    which inputs set which fields is declared by the scene class itself
    (`AbstractScene.data_inputs`, `data_required`)."""

    name: str
    cls: type
    default: Callable[[], Experiment] | None = None
    parameters: dict[str, str] = dataclasses.field(
        default_factory=lambda: dict(_FRICTION_NAMES)
    )
    tangential_before: Callable | None = None  # CM tangential velocity before

    @property
    def inputs(self) -> dict[str, str]:
        """Input quantity -> scene field."""
        return dict(self.cls.data_inputs)

    @property
    def required(self) -> tuple[str, ...]:
        """The inputs every row must give."""
        return tuple(self.cls.data_required)


# Ball-prism defaults (Alaci, Filote & Ciornei): bearing-steel ball, 19 mm diameter, on
# an as-delivered OLC-45 (C45) prism.  The paper gives no material data: E, nu of both
# from that paper's ranges; S_y of the prism a mid-range start value.
_BALL_RADIUS = 9.5e-3
_STEEL_DENSITY = 7850.0
_BALL_MASS = 4.0 / 3.0 * math.pi * _BALL_RADIUS**3 * _STEEL_DENSITY


def _ball_and_prism():
    # Made on call, not at import: creating arrays at import would start JAX's
    # backend before a user can call jax.distributed.initialize().
    ball = Material(208e9, 0.3, math.inf, _STEEL_DENSITY)
    prism = Material(207e9, 0.29, 400e6, _STEEL_DENSITY)
    return ball, prism


def _sphere_on_incline() -> Experiment:
    scene = SphereOnIncline(
        _BALL_MASS, _BALL_RADIUS, *_ball_and_prism(), math.radians(30.0), 0.29
    )
    return Experiment(scene, JacksonGreen(), Friction(0.2))


def _normal_impact() -> Experiment:
    scene = NormalImpact(_BALL_MASS, _BALL_RADIUS, *_ball_and_prism(), 1.0)
    return Experiment(scene, JacksonGreen(), None, method="quadrature")


def _rotating_link() -> Experiment:
    # The rotating-link paper (Math. Probl. Eng. 2020): a steel link and a steel flat of
    # the same material, released from rest in a horizontal position.  The paper's
    # dimensions are not in the text we have: a 0.2 m long, 10 mm diameter rod striking
    # at 30 deg. Both bodies have the same yield strength; the contact uses the lower
    # one (G-3), so the link is given S_y = inf and `yield_strength` names the flat's,
    # which is then the pair's.
    diameter, length = 0.01, 0.2
    mass = _STEEL_DENSITY * math.pi * diameter**2 / 4.0 * length
    steel = Material(207e9, 0.3, math.inf, _STEEL_DENSITY)
    flat = Material(207e9, 0.3, 400e6, _STEEL_DENSITY)
    scene = RotatingLink(mass, length, diameter, steel, flat, math.radians(30.0))
    return Experiment(scene, JacksonGreen(), Friction(0.2))


def _free_bar() -> Experiment:
    # Wang & Fu (2019), xi = 1/8: the Babbitt/steel bar (the body that yields) on an
    # AISI 1045 flat, 45 deg, dropped 0.3 m.
    bar = Material(200.83e9, 0.3, 230.63e6, 7850.0)
    flat = Material(205e9, 0.29, 355e6, 7850.0)
    scene = FreeBar(0.04718, bar, flat, 0.3)
    return Experiment(scene, JacksonGreen(), Friction(0.2))


_PLATE = {
    "yield_strength": "scene.flat.yield_strength",
    "youngs_modulus": "scene.flat.youngs_modulus",
    "poisson_ratio": "scene.flat.poisson_ratio",
    "mu": "friction.mu",
    "mu_v": "friction.mu_v",
    "mass": "scene.mass",
    "radius": "scene.radius",
}
_PLATE_NO_RADIUS = {k: v for k, v in _PLATE.items() if k != "radius"}


# The free bar is the body that yields (230.63 MPa against 355 MPa).
_BAR = {k: v.replace("scene.flat.", "scene.body.") for k, v in _PLATE_NO_RADIUS.items()}
_NORMAL = {k: v for k, v in _PLATE.items() if not k.startswith("mu")}
_LINK = {**_PLATE_NO_RADIUS, "length": "scene.length"}


def _planar_body() -> Experiment:
    raise ValueError(
        "scene 'planar_body' has no built-in body: declare the body above the "
        "file's header ('# body: ...', '# shape: ...', '# body_material: ...', "
        "'# flat_material: ...'; docs: Data formats) and use "
        "Experiment.from_file, or give a diffimpact.scenes.PlanarBody in an "
        "Experiment"
    )


# A planar body and a flat may both yield; the contact takes the lower
# strength (G-3).  `yield_strength` names the flat's, the common case of a
# hard body on a softer flat; `body_yield_strength` the body's.
_PLANAR_BODY = {
    **_PLATE_NO_RADIUS,
    "body_yield_strength": "scene.body.yield_strength",
    "body_youngs_modulus": "scene.body.youngs_modulus",
    "inertia": "scene.inertia",
    "com_x": "scene.com_x",
    "com_y": "scene.com_y",
}


def _sphere_tangential_before(scene):
    return scene.impact_speed * jnp.sin(scene.angle)


SCENES: dict[str, SceneSpec] = {
    spec.name: spec
    for spec in (
        SceneSpec(
            "sphere_on_incline",
            SphereOnIncline,
            _sphere_on_incline,
            _PLATE,
            _sphere_tangential_before,
        ),
        SceneSpec("normal_impact", NormalImpact, _normal_impact, _NORMAL),
        SceneSpec("rotating_link", RotatingLink, _rotating_link, _LINK),
        SceneSpec("free_bar", FreeBar, _free_bar, _BAR),
        SceneSpec("planar_body", PlanarBody, _planar_body, _PLANAR_BODY),
    )
}


def scene_spec(scene) -> SceneSpec:
    """The registry entry for a scene name or a scene instance; for a scene
    type of the user's, the mapping its `data_inputs` declares."""
    if isinstance(scene, str):
        key = scene.strip().lower().replace("-", "_")
        if key not in SCENES:
            raise ValueError(
                f"unknown scene {scene!r}: expected one of {sorted(SCENES)}"
            )
        return SCENES[key]
    for spec in SCENES.values():
        if type(scene) is spec.cls:
            return spec
    return _declared_spec(type(scene))


def _declared_spec(cls: type) -> SceneSpec:
    name = cls.__name__
    inputs = dict(getattr(cls, "data_inputs", {}))
    if not inputs:
        raise ValueError(
            f"scene type {name} has no data mapping: declare one as a class "
            "variable, e.g. `data_inputs: ClassVar = {'angle': 'angle'}` "
            "(input quantity -> field), or use a built-in scene "
            f"{sorted(SCENES)}"
        )
    fields = {f.name for f in dataclasses.fields(cls)}
    for quantity, field in inputs.items():
        if QUANTITIES.get(quantity) is None or QUANTITIES[quantity].role != "input":
            known = sorted(q for q, v in QUANTITIES.items() if v.role == "input")
            raise ValueError(
                f"{name}.data_inputs: {quantity!r} is not an input quantity; "
                f"expected one of {known}"
            )
        if field not in fields:
            raise ValueError(
                f"{name}.data_inputs[{quantity!r}]: {field!r} is not a field of "
                f"{name} (its fields: {sorted(fields)})"
            )
    stray = [q for q in cls.data_required if q not in inputs]
    if stray:
        raise ValueError(f"{name}.data_required: {stray} are not in data_inputs")
    return SceneSpec(name, cls)


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


def check_rows(
    experiment: Experiment,
    inputs: dict,
    path: str = "data",
    lines=None,
    checks=None,
    columns=None,
) -> None:
    """Validate every row's scene eagerly (before any solve) with the scene's own
    checks; raise a ValueError naming the row and the scene's message.
    ``checks``: a file's check columns (`ExperimentData.checks`), compared with
    the model row by row (`check_jacobian_rows`).  ``columns`` (the file's
    `ExperimentData.columns`): the message also gives the row's inputs as
    the file writes them (the scene's checks speak SI: radians for a column
    in degrees)."""
    spec = scene_spec(experiment.scene)
    unknown = [q for q in inputs if q not in spec.inputs]
    if unknown:
        raise ValueError(
            f"{path}: input column(s) {unknown} do not apply to scene "
            f"{spec.name!r} (its inputs: {sorted(spec.inputs)})"
        )
    missing = [q for q in spec.required if q not in inputs]
    if missing:
        raise ValueError(
            f"{path}: scene {spec.name!r} needs input column(s) {missing} "
            "(with units, e.g. 'drop_height_m', 'angle_deg')"
        )
    n = len(next(iter(inputs.values())))

    def row_scene(i):
        fields = {spec.inputs[q]: float(v[i]) for q, v in inputs.items()}
        try:
            return dataclasses.replace(experiment.scene, **fields)
        except ValueError as err:
            raise ValueError(
                f"{path}, {row_label(lines, i)}: {err}{_as_written(columns, inputs, i)}"
            ) from None

    if checks:
        scenes = [row_scene(i) for i in range(n)]
        check_jacobian_rows(scenes, checks, path, lines)
        return
    # Building each row's scene runs its checks op by op: 2,000 planar bodies
    # took 17 s (8 ms a row).  The same checks, vmapped over the rows and
    # compiled once (about a second), find the failing rows; each of those is
    # then rebuilt eagerly, which raises the scene's own message.
    suspects = None
    if n > _EAGER_ROWS:
        suspects = _failing_rows(experiment, inputs)
    for i in range(n) if suspects is None else suspects:
        row_scene(i)


def _as_written(columns, inputs: dict, i: int) -> str:
    """``; the row gives angle_deg = 95, ...``: a row's inputs in the units of
    the file's columns ("" without them, or where all are in SI already)."""
    if not columns:
        return ""
    shown = [
        (c.header, float(inputs[c.quantity][i]) / c.factor)
        for c in columns.values()
        if not c.is_sigma and c.quantity in inputs
    ]
    if all(columns[h].factor == 1.0 for h, _ in shown):
        return ""
    return "; the row gives " + ", ".join(f"{h} = {v:.6g}" for h, v in shown)


# Up to this many rows, checking each eagerly is quicker than compiling.
_EAGER_ROWS = 64


def _failing_rows(experiment: Experiment, inputs: dict):
    """Rows whose scene fails one of its own checks (`_checks`), found in one
    vmapped, compiled pass of `with_inputs`; None where the checks cannot be
    traced (every row is then checked eagerly)."""

    def oks(row):
        scene = with_inputs(experiment, row).scene
        return jnp.stack([jnp.all(jnp.asarray(c.ok)) for c in scene._checks()])

    rows = {q: jnp.asarray(np.asarray(v, dtype=float)) for q, v in inputs.items()}
    try:
        ok = np.asarray(jax.jit(jax.vmap(oks))(rows))
    except Exception:  # a check written for concrete values only
        return None
    return np.nonzero(~ok.all(axis=1))[0]


# A file's contact Jacobian agrees with the shape's when every component is
# within 1 % (the angular ones relative to the body's largest lever arm):
# tracking data derive their Jacobians from tracked poses, good to about
# that; a wrong sign convention, centre of mass or shape is off by far more.
JACOBIAN_TOLERANCE = 1e-2
_JACOBIAN = {
    "jacobian_normal_x": (0, 0),
    "jacobian_normal_y": (0, 1),
    "jacobian_normal_angular": (0, 2),
    "jacobian_tangent_x": (1, 0),
    "jacobian_tangent_y": (1, 1),
    "jacobian_tangent_angular": (1, 2),
}


def check_jacobian_rows(scenes, checks: dict, path: str, lines) -> None:
    """Compare a file's contact-Jacobian rows with the ones the scene's shape
    gives at each row's state; a disagreement is a `DataError` naming the rows
    (never used in place of the shape's)."""
    if not all(hasattr(scenes[0], m) for m in ("contact_jacobian", "largest_lever")):
        raise DataError(
            f"{path}: contact Jacobian columns {sorted(checks)} apply to a scene "
            "with contact_jacobian() and largest_lever(), as PlanarBody; "
            f"{type(scenes[0]).__name__} has not"
        )
    bad = []
    for i, scene in enumerate(scenes):
        rows = np.asarray(jnp.stack(scene.contact_jacobian()))
        lever = float(scene.largest_lever())
        for q, values in checks.items():
            given = values[i]
            if not np.isfinite(given):
                continue
            model = rows[_JACOBIAN[q]]
            scale = lever if q.endswith("angular") else 1.0
            if abs(given - model) > JACOBIAN_TOLERANCE * scale:
                bad.append((i, q, given, model))
    if bad:
        listed = "; ".join(
            f"{row_label(lines, i)}: {q} = {g:.6g}, the shape gives {m:.6g}"
            for i, q, g, m in bad[:5]
        )
        more = f" (and {len(bad) - 5} more)" if len(bad) > 5 else ""
        raise DataError(
            f"{path}: the file's contact Jacobian disagrees with the body's shape "
            f"at the given states: {listed}{more}. Check the angle convention "
            "('# angles: clockwise'), the centre of mass and the shape; the "
            "normal row is the contact point's velocity away from the flat"
        )


def row_label(lines, i: int) -> str:
    """How every message, file and plot names row ``i`` of a data file: its
    line number in the file (``lines[i]``), or ``row i+1`` without a file."""
    if lines is None:
        return f"row {i + 1}"
    return f"line {int(lines[i])}"


def predict(
    experiment: Experiment,
    inputs: dict | None = None,
    *,
    throw: bool = True,
    _guarded: bool = True,
    _steps: bool = False,
) -> dict:
    """Simulate one impact and return every measurable quantity it gives (SI).

    **Arguments:** `experiment`; `inputs`: the row's inputs, by quantity in SI
    (``{"drop_height": 0.3, "angle": 0.52}``) or by column name with its unit
    (``{"drop_height_m": 0.3, "angle_deg": 30}``); an unknown name is an error
    listing the valid ones, and a value outside the scene's range (an angle
    in degrees given as radians, say) is refused by the scene's checks.
    `throw`: as in `simulate`; with False the dict also holds
    ``"result"``, the `RESULTS` code, and failed outputs are NaN.

    Keys follow the experiment CSV quantities (``contact_time``,
    ``cor_normal``, ...); ``cor_tangential`` is the centre-of-mass tangential
    velocity after over before.  (`_guarded`: as in `simulate`; `_steps`: add
    ``"num_steps"``, the solver's step count, 0 without an ODE, which `fit`
    uses to group impacts of similar cost.)
    """
    e = with_inputs(experiment, inputs or {})
    if isinstance(e.law, RigidContact):
        out = _predict_rigid(e, throw)
        if _steps:
            out["num_steps"] = jnp.zeros((), jnp.int32)
        return out
    r = simulate(
        e.scene,
        e.law,
        e.method,
        friction=e.friction,
        settings=e.settings,
        throw=throw,
        _guarded=_guarded,
    )
    out = {
        "contact_time": r.contact_time,
        "rebound_velocity": r.rebound_velocity,
        "cor_normal": r.cor_newton,
        "max_force": r.max_force,
        "max_deflection": r.max_deflection,
        "permanent_deformation": r.permanent_deformation,
    }
    for key in ("velocity_x_after", "velocity_y_after"):
        if key in r.extras:
            out[key] = r.extras[key]
    if "tangential_velocity_after" in r.extras:
        out["tangential_velocity"] = r.extras["tangential_velocity_after"]
    if "angular_velocity_after" in r.extras:
        out["angular_velocity"] = r.extras["angular_velocity_after"]
    _add_cor_tangential(e.scene, out)
    if not throw:
        out["result"] = r.result
    if _steps:
        out["num_steps"] = jnp.asarray(r.num_steps, jnp.int32)
    return out


def _predict_rigid(e: Experiment, throw: bool) -> dict:
    """What a rigid contact predicts: velocities after, no durations or
    deformations (they are not defined for a rigid impact)."""
    o = e.law.impact(e.scene, e.friction, throw=throw)
    out = {"cor_normal": o["cor_newton"]}
    for key in ("velocity_x_after", "velocity_y_after"):
        if key in o:
            out[key] = o[key]
    if "tangential_velocity_after" in o:
        out["tangential_velocity"] = o["tangential_velocity_after"]
    if "angular_velocity_after" in o:
        out["angular_velocity"] = o["angular_velocity_after"]
    _add_cor_tangential(e.scene, out)
    if not throw:
        out["result"] = o["result"]
    return out


def _add_cor_tangential(scene, out: dict) -> None:
    """``cor_tangential``: the tangential velocity after over before, for a
    scene that says what it was before."""
    spec = scene_spec(scene)
    if spec.tangential_before is not None and "tangential_velocity" in out:
        out["cor_tangential"] = out["tangential_velocity"] / spec.tangential_before(
            scene
        )
