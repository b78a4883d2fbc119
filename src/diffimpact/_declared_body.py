"""The `PlanarBody` a planar-body file declares (`read_declarations`)."""

from __future__ import annotations

import math

from ._declarations import Declarations
from ._materials import Material
from ._units import DataError
from .scenes._body import PlanarBody
from .scenes._shapes import Capsule, Disk, Ellipse, RoundedPolygon

_SHAPE_TYPES = {
    "disk": Disk,
    "ellipse": Ellipse,
    "capsule": Capsule,
    "rounded_polygon": RoundedPolygon,
}

# The state a template body takes where the file has no column for it.
_STATE = {
    "orientation": ("angle", 0.0),
    "velocity_x": ("velocity_x", 0.0),
    "velocity_y": ("velocity_y", -1.0),
    "angular_velocity_before": ("angular_velocity", 0.0),
}


def declared_body(declarations: Declarations, inputs: dict, path: str) -> PlanarBody:
    """The declared body, in the state of the file's first row (every row
    replaces it by its own and is checked on its own before any fit).  The
    body's checks (the centre of mass inside the shape, an inertia the mass
    and shape can have, a convex polygon) name the declarations' lines."""
    where = declarations.where(path)
    kind, dims = declarations.shape
    try:
        shape = _SHAPE_TYPES[kind](**dims)
        body = Material(**declarations.body_material)
        flat = Material(**declarations.flat_material)
        state = {
            field: float(inputs[q][0]) if q in inputs else default
            for q, (field, default) in _STATE.items()
        }
        height = inputs.get("height")
        return PlanarBody(
            shape=shape,
            body=body,
            flat=flat,
            height=None if height is None else float(height[0]),
            **declarations.body,
            **state,
        )
    except ValueError as err:
        raise DataError(f"{where}: {err}") from None


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
            f"{declarations.where(path)}: the file declares a {kind} shape, but "
            f"the experiment's body is a {type(scene.shape).__name__}"
        )
    pairs = [(q, getattr(scene, q), v) for q, v in declarations.body.items()]
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
            raise DataError(
                f"{declarations.where(path)}: the file declares {name} = "
                f"{declared!r} (SI), the experiment's body has {given!r}; use "
                "Experiment.from_file, or give the body the file declares"
            )
