"""Declarations in an experiment file's preamble: the body of a planar-body
file, given once per file.

A file of impacts of one rigid body (a tracked drop, say) declares the body
in ``#`` lines above the header, each ``key: item, item, ...``:

    # body: mass_g=50, inertia_kg_m2=1.4e-5, com_x_mm=5
    # shape: ellipse, a_mm=30, b_mm=15
    # body_material: youngs_modulus_gpa=200, poisson_ratio=0.3
    # flat_material: youngs_modulus_gpa=205, poisson_ratio=0.29, yield_strength_mpa=400

An item is ``<quantity>_<unit>=<number>`` with the units of the data columns
(`UNITS`); a dimensionless quantity takes no unit.  The shape's first item
is its kind; a rounded polygon's vertices are ``x y`` pairs separated by
semicolons (``vertices_mm=0 0; 30 0; 15 20``).  Everything is read into SI
units here, with messages that name the file, the line and the item; the
scene itself is made from it by `diffimpact.Experiment.from_file`.
"""

from __future__ import annotations

import dataclasses
import math

from ._units import UNITS, DataError, parse_number, units_of

_MATERIAL = {
    "youngs_modulus": "stress",
    "poisson_ratio": "dimensionless",
    "yield_strength": "stress",
    "density": "density",
}

# key -> (quantity -> dimension, the quantities it must give)
_KEYS: dict[str, tuple[dict[str, str], tuple[str, ...]]] = {
    "body": (
        {
            "mass": "mass",
            "inertia": "inertia",
            "com_x": "length",
            "com_y": "length",
            "incline": "angle",
            "gravity": "acceleration",
        },
        ("mass", "inertia"),
    ),
    "body_material": (_MATERIAL, ("youngs_modulus", "poisson_ratio")),
    "flat_material": (_MATERIAL, ("youngs_modulus", "poisson_ratio")),
}

# shape kind -> its quantities (all lengths), every one required
SHAPES: dict[str, tuple[str, ...]] = {
    "disk": ("radius",),
    "ellipse": ("a", "b"),
    "capsule": ("half_length", "radius"),
    "rounded_polygon": ("vertices", "radius"),
}

KEYS = (*_KEYS, "shape")


@dataclasses.dataclass(frozen=True)
class Declarations:
    """A planar-body file's declarations, in SI units.

    - `body`: ``mass``, ``inertia`` and any of ``com_x``, ``com_y``,
      ``incline``, ``gravity``;
    - `shape`: ``(kind, {quantity: value})``; a rounded polygon's
      ``vertices`` is a tuple of ``(x, y)`` pairs;
    - `body_material`, `flat_material`: ``youngs_modulus``,
      ``poisson_ratio`` and any of ``yield_strength``, ``density``;
    - `lines`: the file line of each declaration, by key.
    """

    body: dict
    shape: tuple
    body_material: dict
    flat_material: dict
    lines: dict

    def where(self, path: str, keys=()) -> str:
        """``path, line n ('key:')``: where the declarations of ``keys`` are
        (all four when none is given)."""
        keys = keys or tuple(self.lines)
        at = sorted((self.lines[k], k) for k in keys)
        if len(at) == 1:
            return f"{path}, line {at[0][0]} ('{at[0][1]}:')"
        named = ", ".join(f"{n} ('{k}:')" for n, k in at)
        return f"{path}, lines {named}"


def _key(text: str) -> str:
    return text.strip().lower().replace(" ", "_").replace("-", "_")


def declaration_key(line: str) -> str | None:
    """The declaration a provenance line (without ``#``) starts, as its key
    (``"body"``, ``"shape"``, ...), or None for a line that is a note."""
    key, sep, _ = line.partition(":")
    key = _key(key)
    return key if sep and key in KEYS else None


def read_declarations(preamble, path: str) -> Declarations | None:
    """The declarations among ``preamble`` (pairs ``(line number, text)`` of
    the ``#`` lines above the header, without the ``#``); None when the file
    declares nothing.  A file that declares some of the body must declare
    all of it: ``body``, ``shape``, ``body_material`` and ``flat_material``."""
    found, lines = {}, {}
    for lineno, text in preamble:
        key = declaration_key(text)
        if key is None:
            continue
        value = text.partition(":")[2]
        where = f"{path}, line {lineno} ('{key}:')"
        if key in found:
            raise DataError(
                f"{where}: declared twice (first on line {lines[key]}); give "
                "each declaration once"
            )
        items = [i.strip() for i in value.split(",")]
        try:
            if key == "shape":
                found[key] = _shape(items, where)
            else:
                quantities, required = _KEYS[key]
                found[key] = _items(items, quantities, required, where)
        except DataError as err:
            raise DataError(
                f"{err} (a '#' line above the header that starts with "
                f"'{text.partition(':')[0].strip()}:' declares a planar body; if "
                "it is a note, reword it, e.g. with ' - ' for the colon)"
            ) from None
        lines[key] = lineno
    if not found:
        return None
    if missing := [k for k in KEYS if k not in found]:
        raise DataError(
            f"{path}: the file declares {', '.join(sorted(found))} but not "
            f"{', '.join(missing)}; a planar body is declared by four lines, e.g. "
            "'# body: mass_kg=0.05, inertia_kg_m2=1.4e-5', '# shape: ellipse, "
            "a_mm=30, b_mm=15', '# body_material: youngs_modulus_gpa=200, "
            "poisson_ratio=0.3', '# flat_material: youngs_modulus_gpa=205, "
            "poisson_ratio=0.29, yield_strength_mpa=400'"
        )
    return Declarations(lines=lines, **found)


def _items(items, quantities: dict, required, where: str) -> dict:
    out = {}
    for item in items:
        name, value = _split(item, where, quantities)
        quantity, factor = _quantity(name, quantities, where)
        if quantity in out:
            raise DataError(f"{where}: {quantity!r} is given twice")
        if quantity == "vertices":
            out[quantity] = _vertices(value, factor, where, name)
        else:
            out[quantity] = _value(value, quantity, factor, where, name)
    missing = [q for q in required if q not in out]
    if missing:
        raise DataError(
            f"{where}: {', '.join(repr(q) for q in missing)} missing; expected "
            f"{', '.join(_form(q, quantities) for q in required)}"
        )
    return out


def _shape(items, where: str) -> tuple:
    kind = _key(items[0])
    if kind not in SHAPES:
        raise DataError(
            f"{where}: unknown shape {items[0]!r}; the first item is the shape's "
            f"kind, one of {', '.join(SHAPES)} (e.g. '# shape: ellipse, "
            "a_mm=30, b_mm=15')"
        )
    names = SHAPES[kind]
    quantities = {q: "length" for q in names}
    return kind, _items(items[1:], quantities, names, f"{where}, {kind}")


def _split(item: str, where: str, quantities: dict) -> tuple[str, str]:
    name, sep, value = item.partition("=")
    if not sep and _is_number(item):
        raise DataError(
            f"{where}: {item!r} is not an item '<quantity>_<unit>=<number>': a "
            "decimal comma? numbers take a point (50.5), items are separated by "
            "commas"
        )
    if not sep or not name.strip():
        raise DataError(
            f"{where}: {item!r} is not an item '<quantity>_<unit>=<number>'; "
            f"expected items of {', '.join(_form(q, quantities) for q in quantities)}"
        )
    return name.strip(), value.strip()


def _is_number(text: str) -> bool:
    try:
        parse_number(text)
    except ValueError:
        return False
    return True


def _form(quantity: str, quantities: dict) -> str:
    dim = quantities[quantity]
    return quantity if dim == "dimensionless" else f"{quantity}_<{dim} unit>"


def _quantity(name: str, quantities: dict, where: str) -> tuple[str, float]:
    """The quantity and the factor to SI of an item's name."""
    if name in quantities:
        if quantities[name] == "dimensionless":
            return name, 1.0
        dim = quantities[name]
        raise DataError(
            f"{where}: {name!r} has no unit: write '{name}_<unit>' with a {dim} "
            f"unit ({units_of(dim)})"
        )
    for q in sorted(quantities, key=len, reverse=True):
        if name.startswith(q + "_"):
            unit, dim = name[len(q) + 1 :].lower(), quantities[q]
            if dim == "dimensionless":
                raise DataError(
                    f"{where}: {q!r} is dimensionless and takes no unit suffix"
                )
            if unit not in UNITS or UNITS[unit][0] != dim:
                raise DataError(
                    f"{where}: unit {unit!r} does not fit {q!r} (dimension: "
                    f"{dim}); expected one of {units_of(dim)}"
                )
            return q, UNITS[unit][1]
    raise DataError(
        f"{where}: unknown item {name!r}; expected "
        f"{', '.join(_form(q, quantities) for q in quantities)}"
    )


def _value(text: str, quantity: str, factor: float, where: str, name: str) -> float:
    try:
        x = parse_number(text)
    except ValueError:
        raise DataError(f"{where}, {name}: {text!r} is not a number") from None
    # Only a material that never yields has an infinite value.
    if math.isnan(x) or (
        math.isinf(x) and not (quantity == "yield_strength" and x > 0)
    ):
        raise DataError(f"{where}, {name}: {text!r} is not a finite number")
    return x * factor


def _vertices(text: str, factor: float, where: str, name: str) -> tuple:
    pairs = []
    for point in text.split(";"):
        xy = point.split()
        if len(xy) != 2:
            raise DataError(
                f"{where}, {name}: {point.strip()!r} is not a point 'x y'; give "
                "the vertices as 'x y' pairs separated by semicolons, e.g. "
                f"'{name}=0 0; 30 0; 15 20'"
            )
        pairs.append(tuple(_value(v, "vertices", factor, where, name) for v in xy))
    return tuple(pairs)


def _floats(pairs):
    return [(float(x), float(y)) for x, y in pairs]


# The unit each quantity is written in by `format_declarations`.
_WRITE_UNIT = {
    "mass": "g",
    "inertia": "kg_m2",
    "length": "mm",
    "angle": "deg",
    "acceleration": "m_s2",
    "density": "kg_m3",
    "youngs_modulus": "gpa",
    "yield_strength": "mpa",
}


def _item(quantity: str, dim: str, value) -> str:
    """``quantity_unit=value`` in the unit of `_WRITE_UNIT` (15 digits: read
    back to within a unit in the last place)."""
    if dim == "dimensionless":
        return f"{quantity}={float(value):.15g}"
    unit = _WRITE_UNIT.get(quantity, _WRITE_UNIT.get(dim))
    return f"{quantity}_{unit}={float(value) / UNITS[unit][1]:.15g}"


def format_declarations(scene) -> str:
    """The declaration lines (without ``#``) of a `PlanarBody` ``scene``: the
    provenance that `write_experiments(..., body=scene)` writes."""
    if not all(hasattr(scene, f) for f in ("shape", "mass", "inertia", "body", "flat")):
        raise TypeError(
            f"`body` must be a diffimpact.scenes.PlanarBody, got "
            f"{type(scene).__name__} (an experiment's body is `experiment.scene`)"
        )
    shape = scene.shape
    kind = {
        "Disk": "disk",
        "Ellipse": "ellipse",
        "Capsule": "capsule",
        "RoundedPolygon": "rounded_polygon",
    }.get(type(shape).__name__)
    if kind is None:
        raise TypeError(
            f"{type(shape).__name__}: a file can declare only the built-in shapes "
            f"({', '.join(SHAPES)})"
        )

    def items(obj, quantities):
        given = [q for q in quantities if hasattr(obj, q)]
        return ", ".join(_item(q, quantities[q], getattr(obj, q)) for q in given)

    shape_items = []
    for q in SHAPES[kind]:
        v = getattr(shape, q)
        if q == "vertices":
            mm = UNITS["mm"][1]
            points = "; ".join(f"{x / mm:.15g} {y / mm:.15g}" for x, y in _floats(v))
            shape_items.append(f"vertices_mm={points}")
        else:
            shape_items.append(_item(q, "length", v))
    return "\n".join(
        [
            f"body: {items(scene, _KEYS['body'][0])}",
            f"shape: {', '.join([kind, *shape_items])}",
            f"body_material: {items(scene.body, _MATERIAL)}",
            f"flat_material: {items(scene.flat, _MATERIAL)}",
        ]
    )
