"""The scene registry of experiment files: per scene, its default experiment,
which CSV inputs set which scene fields, which inputs every row must give,
and the short parameter names a user fits, each a path into the
`Experiment`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax.numpy as jnp

from .._io._data import (
    QUANTITIES,
)
from .._laws._friction import Friction
from .._laws._jackson_green import JacksonGreen
from .._materials import Material
from ..scenes._bar import FreeBar
from ..scenes._body import PlanarBody
from ..scenes._link import RotatingLink
from ..scenes._normal import NormalImpact
from ..scenes._planar import SphereOnIncline

# The short names every scene with friction accepts; anything else by its
# dotted path (``scene.radius``) or as a field of the law.
FRICTION_NAMES = {"mu": "friction.mu", "mu_v": "friction.mu_v"}


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """How a scene meets the data: its name, its built-in experiment, the
    short names of its parameters (each a dotted path in the `Experiment`);
    which inputs set which fields is declared by the scene class itself
    (`AbstractScene.data_inputs`, `data_required`)."""

    name: str
    cls: type
    default: Callable[[], dict] | None = None  # the built-in Experiment's fields
    parameters: dict[str, str] = dataclasses.field(
        default_factory=lambda: dict(FRICTION_NAMES)
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

    def refuse_unknown(self, names, where: str) -> None:
        """``ValueError`` naming those of ``names`` that are not inputs of
        the scene, after ``where`` (a file, a model)."""
        unknown = [q for q in names if q not in self.inputs]
        if unknown:
            raise ValueError(
                f"{where} {unknown} do not apply to scene {self.name!r} (its "
                f"inputs: {sorted(self.inputs)})"
            )


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


def _sphere_on_incline() -> dict:
    scene = SphereOnIncline(
        _BALL_MASS,
        _BALL_RADIUS,
        *_ball_and_prism(),
        incline=math.radians(30.0),
        height=0.29,
    )
    return dict(scene=scene, law=JacksonGreen(), friction=Friction(0.2))


def _normal_impact() -> dict:
    scene = NormalImpact(_BALL_MASS, _BALL_RADIUS, *_ball_and_prism(), velocity=1.0)
    return dict(scene=scene, law=JacksonGreen(), method="quadrature")


def _rotating_link() -> dict:
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
    scene = RotatingLink(
        mass, length, diameter, steel, flat, impact_angle=math.radians(30.0)
    )
    return dict(scene=scene, law=JacksonGreen(), friction=Friction(0.2))


def _free_bar() -> dict:
    # Wang & Fu (2019), xi = 1/8: the Babbitt/steel bar (the body that yields) on an
    # AISI 1045 flat, 45 deg, dropped 0.3 m.
    bar = Material(200.83e9, 0.3, 230.63e6, 7850.0)
    flat = Material(205e9, 0.29, 355e6, 7850.0)
    scene = FreeBar(0.04718, bar, flat, height=0.3)
    return dict(scene=scene, law=JacksonGreen(), friction=Friction(0.2))


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


def _planar_body() -> dict:
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
    return scene.impact_speed * jnp.sin(scene.incline)


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
