"""The `PlanarBody` a planar-body file declares (`read_declarations`)."""

from __future__ import annotations

import math

from .._materials import Material
from ..scenes._body import PlanarBody
from ..scenes._shapes import Capsule, Disk, Ellipse, RoundedPolygon
from ._declarations import Declarations
from ._units import DataError

# The body's defaults (`PlanarBody`) of the items a declaration may omit.
_BODY_DEFAULTS = {"com_x": 0.0, "com_y": 0.0, "incline": 0.0, "gravity": 9.81}

_SHAPE_TYPES = {
    "disk": Disk,
    "ellipse": Ellipse,
    "capsule": Capsule,
    "rounded_polygon": RoundedPolygon,
}

# The state a template body takes where the file has no column for it.
_STATE = {
    "orientation": ("orientation", 0.0),
    "velocity_x": ("velocity_x", 0.0),
    "velocity_y": ("velocity_y", -1.0),
    "angular_velocity_before": ("angular_velocity", 0.0),
}


def declared_body(declarations: Declarations, inputs: dict, path: str) -> PlanarBody:
    """The declared body, in the state of the file's first row (every row
    replaces it by its own and is checked on its own before any fit).  A
    problem of the declarations is named by its line: a shape that is not
    convex, a material out of its domain, a centre of mass outside the
    shape or an inertia the mass and shape cannot have (the ``body:`` and
    ``shape:`` lines).  A first row the body cannot start from is left to
    the rows' own check, which names that row."""
    kind, dims = declarations.shape
    shape = _built(lambda: _SHAPE_TYPES[kind](**dims), declarations, path, "shape")
    body = _built(
        lambda: Material(**declarations.body_material), declarations, path,
        "body_material",
    )  # fmt: skip
    flat = _built(
        lambda: Material(**declarations.flat_material), declarations, path,
        "flat_material",
    )  # fmt: skip
    parts = dict(shape=shape, body=body, flat=flat, **declarations.body)
    first = {
        field: float(inputs[q][0]) if q in inputs else default
        for q, (field, default) in _STATE.items()
    }
    if "height" in inputs:
        first["height"] = float(inputs["height"][0])
    at_first = _or_none(lambda: PlanarBody(**parts, **first))
    if at_first is not None:
        return at_first
    # the body at a plain state: what fails there is the declarations'
    return _built(
        lambda: PlanarBody(**parts, **_PLAIN), declarations, path, "body", "shape"
    )


# A state any convex body can start from: falling, with no flat side of a
# polygon or capsule facing the flat (0.1234 rad is no multiple of any
# regular polygon's symmetry).
_PLAIN = {"orientation": 0.1234, "velocity_x": 0.0, "velocity_y": -1.0}


def _or_none(make):
    """``make()``, or None where its checks refuse it (a first row the body
    cannot start from: the rows' own check names that row)."""
    try:
        return make()
    except ValueError:
        return None


def _built(make, declarations: Declarations, path: str, *keys):
    """``make()``, or a `DataError` naming the lines of ``keys``."""
    try:
        return make()
    except ValueError as err:
        raise DataError(f"{declarations.where(path, keys)}: {err}") from None


def check_declared(declarations: Declarations, scene, path: str) -> None:
    """A `PlanarBody` given in Python must be the body the file declares:
    mass, inertia, centre of mass and shape (to 1e-9 relative), else a
    `DataError` naming the quantity and both values.  The materials are not
    compared: they are the start of a fit (the flat's yield strength, say)."""
    if not isinstance(scene, PlanarBody):
        raise DataError(
            f"{declarations.where(path)}: the file declares a planar body, but "
            f"the experiment's scene is a {type(scene).__name__}"
        )
    kind, dims = declarations.shape
    if type(scene.shape) is not _SHAPE_TYPES[kind]:
        raise DataError(
            f"{declarations.where(path)}: the file declares {_article(kind)} "
            f"{kind.replace('_', ' ')} shape, but "
            f"the experiment's body is a {type(scene.shape).__name__}"
        )
    # an item the file leaves out is its default, and is compared as such
    body = {**_BODY_DEFAULTS, **declarations.body}
    pairs = [(q, getattr(scene, q), v) for q, v in body.items()]
    for q, v in dims.items():
        given = getattr(scene.shape, q)
        if q == "vertices":
            if len(given) != len(v):
                raise DataError(
                    f"{declarations.where(path)}: the file declares "
                    f"{len(v)} vertices, the experiment's body has {len(given)}"
                )
            pairs += [
                (f"shape.vertices[{i}]", g, d)
                for i, (gp, dp) in enumerate(zip(given, v, strict=True))
                for g, d in zip(gp, dp, strict=True)
            ]
        else:
            pairs.append((f"shape.{q}", given, v))
    # a length may be zero (the centre of mass on an axis): compared to the
    # body's size; the mass, inertia and gravity are positive
    size = float(scene.largest_lever())
    for name, given, declared in pairs:
        given = float(given)
        length = name.startswith(("shape.", "com_"))
        atol = 1e-9 * size if length else 1e-12 if name == "incline" else 0.0
        if not math.isclose(given, declared, rel_tol=1e-9, abs_tol=atol):
            key = "shape" if name.startswith("shape.") else "body"
            raise DataError(
                f"{declarations.where(path, (key,))}: the file declares {name} = "
                f"{declared!r} (SI), the experiment's body has {given!r}; the "
                "body is the file's (change its declaration, or fit the "
                "quantity with --free / `free`; a --set or a Python body that "
                "differs is refused)"
            )


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"
