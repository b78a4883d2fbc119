"""Experiment CSV files: the schema, units and a validating loader.

One row per impact.  A column name is a quantity followed by its unit,
``<quantity>_<unit>`` (``contact_time_us``, ``drop_height_m``, ``angle_deg``);
dimensionless quantities carry no unit (``cor_normal``).  Lines starting with
``#`` before the header are the provenance note (paper, table, how the numbers
were made) and are kept with the data.  Columns:

- ``scene`` (optional): the scene every row uses (one scene per file), e.g.
  ``sphere_on_incline``;
- inputs: what was set for each impact (drop height, impact speed, angle, ...);
- measured outputs: what was measured (contact time, rebound velocities,
  CORs, ...); an empty cell means "not measured in this row";
- uncertainties (optional): ``sigma_<quantity>_<unit>``, one standard deviation
  of a measured output, in any unit of its dimension.

`QUANTITIES` lists every quantity with its dimension, and `UNITS`
every unit with its factor to SI.  The loader converts everything to SI.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import sys

import numpy as np

from ._declarations import (
    Declarations,
    read_declarations,
)
from ._frames import is_dataframe, si_suffix
from ._units import (
    SI,
    UNITS,
    DataError,
    parse_number,
    units_of,
)


@dataclasses.dataclass(frozen=True)
class Quantity:
    name: str
    dimension: str
    role: str  # "input", "output" or "check" (compared with the model, not used)
    nonnegative: bool
    doc: str
    maximum: float = math.inf  # largest physically possible value (SI)
    magnitude: bool = False  # the maximum bounds |value|, not value


# name | dimension | role | sign (">= 0" or "any") | what it is.  A normal COR
# above 1 would be a rebound with more energy than the approach: no passive
# impact does that (the ``max 1`` column).  Nor can friction on a flat, which
# only opposes the slip, leave a ball dropped without spin with more
# tangential speed than it came with: |e_t| <= 1 (``abs 1``).
_TABLE = """
drop_height           | length           | input  | >= 0 | height of the drop
impact_velocity       | velocity         | input  | >= 0 | normal approach speed
angle                 | angle            | input  | >= 0 | incline / impact angle
release_angle         | angle            | input  | >= 0 | release angle of a link
link_length           | length           | input  | >= 0 | length of a rotating link
mass                  | mass             | input  | >= 0 | mass of the moving body
radius                | length           | input  | >= 0 | radius of the sphere or tip
orientation           | angle            | input  | any  | a planar body's angle at first contact (counter-clockwise)
velocity_x            | velocity         | input  | any  | centre-of-mass velocity along the flat at first contact
velocity_y            | velocity         | input  | any  | centre-of-mass velocity normal to the flat at first contact (< 0: falling)
angular_velocity_before | angular_velocity | input  | any  | angular velocity at first contact (counter-clockwise)
height                | length           | input  | >= 0 | height of a planar body's centre of mass above the flat at the given state (omitted: the state is at first contact)
contact_time          | time             | output | >= 0 | first contact to separation
rebound_velocity      | velocity         | output | >= 0 | normal rebound speed of the contact point
tangential_velocity   | velocity         | output | any  | tangential velocity of the centre of mass after the impact
angular_velocity      | angular_velocity | output | any  | spin after
velocity_x_after      | velocity         | output | any  | centre-of-mass velocity along the flat after the impact
velocity_y_after      | velocity         | output | any  | centre-of-mass velocity normal to the flat after the impact
cor_normal            | dimensionless    | output | >= 0 | Newton's COR e_n | max 1
cor_tangential        | dimensionless    | output | any  | tangential COR e_t of the centre of mass | abs 1
max_force             | force            | output | >= 0 | peak normal contact force
max_deflection        | length           | output | >= 0 | maximum interference d_m
permanent_deformation | length           | output | >= 0 | residual interference d_r
jacobian_normal_x     | dimensionless    | check  | any  | contact Jacobian, normal row: d(normal velocity of the contact point, away from the flat)/d(velocity_x)
jacobian_normal_y     | dimensionless    | check  | any  | contact Jacobian, normal row: d(normal velocity of the contact point)/d(velocity_y)
jacobian_normal_angular | length         | check  | any  | contact Jacobian, normal row: d(normal velocity of the contact point)/d(angular velocity)
jacobian_tangent_x    | dimensionless    | check  | any  | contact Jacobian, tangent row: d(velocity of the contact point along the flat)/d(velocity_x)
jacobian_tangent_y    | dimensionless    | check  | any  | contact Jacobian, tangent row: d(velocity of the contact point along the flat)/d(velocity_y)
jacobian_tangent_angular | length        | check  | any  | contact Jacobian, tangent row: d(velocity of the contact point along the flat)/d(angular velocity)
"""  # noqa: E501


def _quantity(row: str) -> Quantity:
    name, dimension, role, sign, doc, *limit = (c.strip() for c in row.split("|"))
    maximum = math.inf
    magnitude = False
    if limit:
        kind, _, value = limit[0].partition(" ")
        maximum, magnitude = float(value), kind == "abs"
    return Quantity(name, dimension, role, sign == ">= 0", doc, maximum, magnitude)


QUANTITIES: dict[str, Quantity] = {
    q.name: q for q in map(_quantity, _TABLE.strip().splitlines())
}


@dataclasses.dataclass(frozen=True)
class Column:
    """How a CSV column maps to a quantity (``factor`` converts to SI)."""

    header: str
    quantity: str
    unit: str
    factor: float
    is_sigma: bool


def parse_column(header: str, where: str = "") -> Column:
    """Split a column name into quantity and unit; raise naming the column."""
    name = header.strip()
    is_sigma = name.startswith("sigma_")
    base = name[len("sigma_") :] if is_sigma else name
    if base in QUANTITIES:
        quantity, unit = base, ""
    else:
        quantity, unit = None, None
        # The longest quantity name that prefixes the column wins, so that
        # "rebound_velocity_m_s" is (rebound_velocity, m_s).
        for q in sorted(QUANTITIES, key=len, reverse=True):
            if base.startswith(q + "_"):
                quantity, unit = q, base[len(q) + 1 :].lower()
                break
        if quantity is None:
            known = ", ".join(sorted(QUANTITIES))
            raise DataError(
                f"{where}unknown column {header!r}: expected 'scene', a quantity "
                f"with its unit ('<quantity>_<unit>', quantities: {known}) or "
                "'sigma_' followed by a measured column"
            )
    dim = QUANTITIES[quantity].dimension
    if dim == "dimensionless":
        if unit:
            raise DataError(
                f"{where}column {header!r}: {quantity!r} is dimensionless and "
                "takes no unit suffix"
            )
        return Column(header, quantity, "", 1.0, is_sigma)
    if not unit:
        raise DataError(
            f"{where}column {header!r} has no unit: write it as "
            f"'{quantity}_<unit>' with a {dim} unit ({units_of(dim)})"
        )
    if unit not in UNITS or UNITS[unit][0] != dim:
        raise DataError(
            f"{where}column {header!r}: unit {unit!r} does not fit {quantity!r} "
            f"(dimension: {dim}); expected one of {units_of(dim)}"
        )
    return Column(header, quantity, unit, UNITS[unit][1], is_sigma)


def column_of(quantity: str, columns: dict | None = None) -> Column:
    """The column that gives ``quantity``: the file's own (from
    `ExperimentData.columns`, its unit the file's) where it has one, else
    the quantity in SI units (``max_force_N``, ``angle_rad``, ``cor_normal``).
    Output files and DataFrames name their columns by it, and divide an SI
    value by its ``factor`` to write it in that unit."""
    for col in (columns or {}).values():
        if col.quantity == quantity and not col.is_sigma:
            return col
    dim = QUANTITIES[quantity].dimension
    suffix = si_suffix(dim)
    return Column(quantity + suffix, quantity, suffix[1:].lower(), 1.0, False)


def unit_label(quantity: str) -> str:
    """`` [SI unit]`` of a quantity for a figure's axis ("" if dimensionless)."""
    dim = QUANTITIES[quantity].dimension if quantity in QUANTITIES else ""
    return "" if dim in ("", "dimensionless") else f" [{SI[dim]}]"


@dataclasses.dataclass(frozen=True)
class ExperimentData:
    """A validated experiment file, in SI units.

    - `scene`: the scene name from the ``scene`` column (None if absent);
    - `inputs`: quantity -> array of shape ``(n,)``;
    - `outputs`: quantity -> array ``(n,)``, NaN where a row did not measure it;
    - `sigmas`: quantity -> array ``(n,)`` (only where uncertainty columns exist);
    - `checks`: quantity -> array ``(n,)``, NaN where empty: columns the model
      is checked against before a fit (a planar body's contact Jacobian rows),
      never used as inputs;
    - `declarations`: the body a planar-body file declares above its header
      (`Declarations`, in SI units), or None;
    - `provenance`: the ``#`` lines before the header; `path`: the file
      (``"DataFrame"`` for a DataFrame).
    - `lines`: the line number in the file of each row, shape ``(n,)``: every
      message, residual file and plot names a row by it (None for a
      DataFrame: rows are named ``row N``, from 1).
    """

    scene: str | None
    inputs: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]
    sigmas: dict[str, np.ndarray]
    provenance: str
    path: str
    columns: dict[str, Column]
    lines: np.ndarray | None = None
    checks: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    declarations: Declarations | None = None

    @property
    def n(self) -> int:
        arrays = list(self.inputs.values()) + list(self.outputs.values())
        return len(arrays[0]) if arrays else 0


# Quantities whose sign is a sense of rotation: a file that declares
# clockwise-positive angles has them negated on reading.
_SIGNED_ANGLES = (
    "orientation",
    "angular_velocity_before",
    "angular_velocity",
    # d(velocity)/d(angular velocity): the sign of the angular velocity's
    "jacobian_normal_angular",
    "jacobian_tangent_angular",
)


def _clockwise(provenance: list[str], path: str) -> bool:
    """Whether a provenance line ``angles: clockwise`` declares the file's
    angles clockwise-positive (``angles: counter-clockwise``, the default,
    may be written too); anything else after ``angles:`` is refused."""
    found = None
    for line in provenance:
        key, sep, value = line.partition(":")
        if not sep or key.strip().lower() != "angles":
            continue
        value = value.strip().lower().replace("_", "-")
        if value not in ("clockwise", "counter-clockwise", "counterclockwise"):
            raise DataError(
                f"{path}: '# {line}': the angle convention must be 'clockwise' "
                "or 'counter-clockwise'"
            )
        if found is not None and found != (value == "clockwise"):
            raise DataError(f"{path}: two different 'angles:' declarations")
        found = value == "clockwise"
    return bool(found)


def load_experiments(path) -> ExperimentData:
    """Read and validate an experiment CSV (schema in this module's docstring),
    or a pandas DataFrame with the same column names and units.

    Raises `DataError` (a ``ValueError``) naming the file, the row (the
    line number in the file) and the column for: an empty file, no header or no
    rows, an unknown column or unit, a missing required value, a non-number, a
    negative value of a quantity that cannot be negative, a physically
    impossible value (a normal COR above 1, a rebound faster than the impact),
    an output column with no value, a sigma column without its measured column
    or with a value <= 0, a file mixing scenes, a file that is not UTF-8 text
    (a byte-order mark is fine), a semicolon- or tab-delimited file, and a
    directory.  Rows are named by the line of the file they start on.  ``#``
    lines above the header are the provenance; a ``#`` line among the rows is
    a commented-out row and is skipped.  Scene names are read as the scene
    registry reads them (``Sphere-On-Incline`` is ``sphere_on_incline``).
    A provenance line ``angles: clockwise`` declares clockwise-positive
    angles: ``orientation``, ``angular_velocity_before`` and
    ``angular_velocity`` are negated to the counter-clockwise convention of
    the scenes.  Lines ``body:``, ``shape:``, ``body_material:`` and
    ``flat_material:`` declare a planar body (`read_declarations`), read
    and checked here.

    A pandas DataFrame goes through the same checks, cell by cell as the
    file's text (a float as its shortest round-trip text; NaN, None or ""
    as an empty cell): the same numbers to the bit and the same messages,
    with ``DataFrame, row N`` (from 1, in the frame's order; the index is
    not read) for the file and line; ``path`` is then ``"DataFrame"`` and
    ``lines`` None.  ``frame.attrs["provenance"]`` (one note a line) stands
    for the ``#`` lines above a file's header.
    """
    if is_dataframe(path):
        return read_frame(path)
    path = os.fspath(path)
    lines = _read_lines(path)
    provenance, preamble, body_start = [], [], 0
    for i, line in enumerate(lines):
        if line.startswith("#"):
            provenance.append(line.lstrip("#").strip())
            preamble.append((i + 1, provenance[-1]))
        elif line.strip():
            body_start = i
            break
    else:
        raise DataError(f"{path}: the file is empty (no header and no rows)")
    reader = csv.reader(lines[body_start:])
    header = [h.strip() for h in next(reader)]
    for sep, name in ((";", "semicolons"), ("\t", "tabs")):
        if len(header) == 1 and sep in header[0]:
            raise DataError(
                f"{path}, line {body_start + 1}: the header has no commas but "
                f"{name}; the experiment format is comma-separated (save the "
                "file as CSV with ',' as the delimiter and '.' as the decimal "
                "point)"
            )
    # Rows by the file line they start on (a quoted field may span lines);
    # a line starting with '#' among the rows is a commented-out row, skipped.
    rows, consumed, ends = [], reader.line_num, {}
    for r in reader:
        first, consumed = body_start + consumed + 1, reader.line_num
        ends[first] = body_start + consumed  # the line the row ends on
        if any(r) and not r[0].lstrip().startswith("#"):
            rows.append((first, r))
    source = _Source(path, "line", f"{path}, line {body_start + 1}")

    def fields(lineno, row):
        if len(row) != len(header):
            # a row read across lines with too few fields: a quote left open
            # (a quoted field may span lines, but then the count holds)
            last = ends[lineno]
            runs_on = (
                f'; it runs on to line {last}: is a quote (") left open?'
                if last > lineno
                else '; a quote (") is left open'
                if lines[lineno - 1].count('"') % 2
                else ""
            )
            raise DataError(
                f"{path}, line {lineno}: {len(row)} fields, expected {len(header)} "
                f"({', '.join(header)}){runs_on}"
            )

    return _parse(source, header, rows, provenance, preamble, fields)


@dataclasses.dataclass(frozen=True)
class _Source:
    """How messages name the data and its rows: a file by its path and the
    line a row starts on, a DataFrame as ``DataFrame`` and its row number."""

    path: str
    row: str  # "line" or "row"
    header: str  # where the header is
    numbered: bool = True  # keep the row numbers as `ExperimentData.lines`

    def at(self, number: int) -> str:
        return f"{self.path}, {self.row} {number}"


def read_frame(frame, *, require_output: bool = True) -> ExperimentData:
    """A pandas DataFrame with the experiment file's column names (and units)
    read as `load_experiments` reads the file: each cell is given to the
    same checks as the file's text (a float as its shortest round-trip
    text, NaN, None or an empty string as an empty cell), so the numbers are
    the file's to the bit and a bad column or value gets the same message,
    with ``DataFrame, row N`` (N from 1, in the frame's order; the index is
    not read) in place of the file and line.  ``frame.attrs["provenance"]``
    (a string, one line per note) stands for the ``#`` lines above a file's
    header: the notes, ``angles: clockwise`` and a planar body's
    declarations.  `require_output`: False for rows to predict (no measured
    column needed)."""
    isna = sys.modules["pandas"].isna  # (a DataFrame: pandas is imported)
    header = [str(h).strip() for h in frame.columns]
    rows = [
        (i + 1, [_text(v, isna) for v in values])
        for i, values in enumerate(frame.itertuples(index=False, name=None))
    ]
    notes = frame.attrs.get("provenance", "") if hasattr(frame, "attrs") else ""
    provenance = [line.lstrip("#").strip() for line in str(notes).splitlines()]
    provenance = [line for line in provenance if line]
    preamble = list(enumerate(provenance, start=1))
    source = _Source("DataFrame", "row", "DataFrame", numbered=False)
    return _parse(source, header, rows, provenance, preamble, None, require_output)


def _text(value, isna) -> str:
    """A DataFrame cell as the text a CSV file would hold."""
    if isinstance(value, str):
        return value
    if value is None or isna(value) is True:  # NaN, None, pd.NA, NaT
        return ""
    if isinstance(value, bool | np.bool_):
        return str(value)  # refused as not a number, as in a file
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "" if math.isnan(x) else repr(x)


def _parse(
    source: _Source,
    header: list[str],
    rows: list,
    provenance: list[str],
    preamble: list,
    fields=None,
    require_output: bool = True,
) -> ExperimentData:
    """The checks and conversions of `load_experiments` after the text is
    split: ``rows`` are ``(number, cells)``; `fields` checks a row's length."""
    path = source.path
    if not rows:
        raise DataError(f"{path}: header but no rows of data")
    unnamed = [j + 1 for j, h in enumerate(header) if not h]
    if unnamed:
        raise DataError(
            f"{source.header}: column(s) {unnamed} of the header have "
            "no name (a stray or trailing comma?); every column needs a name"
        )
    if len(set(header)) != len(header):
        raise DataError(f"{path}: duplicate column names in {header}")
    columns, scene_idx = {}, None
    for j, h in enumerate(header):
        if h.strip() == "scene":
            scene_idx = j
            continue
        columns[j] = parse_column(h, f"{path}: ")
    # One column per quantity (two units of one quantity would be ambiguous).
    seen = {}
    for col in columns.values():
        key = (col.quantity, col.is_sigma)
        if key in seen:
            raise DataError(
                f"{path}: columns {seen[key]!r} and {col.header!r} both give "
                f"{'sigma of ' if col.is_sigma else ''}{col.quantity!r}"
            )
        seen[key] = col.header
    measured = {c.quantity for c in columns.values() if not c.is_sigma}
    for col in columns.values():
        if col.is_sigma and (
            col.quantity not in measured or QUANTITIES[col.quantity].role != "output"
        ):
            raise DataError(
                f"{path}: column {col.header!r} gives an uncertainty for "
                f"{col.quantity!r}, but the file has no measured {col.quantity!r} "
                "column"
            )
    if require_output and not any(
        QUANTITIES[c.quantity].role == "output" and not c.is_sigma
        for c in columns.values()
    ):
        raise DataError(
            f"{path}: no measured output column (e.g. contact_time_s, cor_normal)"
        )
    scenes = set()
    values = {j: [] for j in columns}
    for lineno, row in rows:
        if fields is not None:
            fields(lineno, row)
        if scene_idx is not None:
            s = row[scene_idx].strip()
            if not s:
                raise DataError(f"{source.at(lineno)}, column 'scene': empty")
            scenes.add(s.lower().replace("-", "_"))  # as scene names are read
        for j, col in columns.items():
            values[j].append(_cell(row[j], col, source.at(lineno)))
    if len(scenes) > 1:
        raise DataError(
            f"{path}, column 'scene': one scene per file, found {sorted(scenes)}; "
            "split the file by scene"
        )
    inputs, outputs, sigmas, checks = {}, {}, {}, {}
    for j, col in columns.items():
        arr = np.asarray(values[j], dtype=np.float64) * col.factor
        role = QUANTITIES[col.quantity].role
        if col.is_sigma:
            sigmas[col.quantity] = arr
        else:
            {"input": inputs, "output": outputs, "check": checks}[role][
                col.quantity
            ] = arr
    # A scene column naming another scene makes such lines notes; a file
    # that declares a body cannot also give its mass row by row.
    other = bool(scenes) and scenes != {"planar_body"}
    declarations = None if other else read_declarations(preamble, path)
    if declarations is not None and "mass" in inputs:
        raise DataError(
            f"{declarations.where(path, ('body',))}: the body's mass is declared, "
            f"and column {seen[('mass', False)]!r} gives it row by row; keep one"
        )
    if _clockwise(provenance, path):
        for q in _SIGNED_ANGLES:
            for group in (inputs, outputs, checks):
                if q in group:
                    group[q] = -group[q]
    line_numbers = np.asarray([lineno for lineno, _ in rows])
    if not source.numbered:
        line_numbers = None
    for q, a in outputs.items():
        if require_output and not np.isfinite(a).any():
            raise DataError(
                f"{path}, column {seen[(q, False)]!r}: no row has a value; fill "
                "it in or remove the column"
            )
    for q, s in sigmas.items():
        bad = np.isfinite(outputs[q]) & ~(s > 0)
        if bad.any():
            k = int(np.argmax(bad))
            raise DataError(
                f"{source.at(rows[k][0])}, column {seen[(q, True)]!r}: an "
                "uncertainty must be a number > 0 where the output is measured"
            )
    if "rebound_velocity" in outputs and "impact_velocity" in inputs:
        faster = outputs["rebound_velocity"] > inputs["impact_velocity"]
        if faster.any():
            k = int(np.argmax(faster))
            raise DataError(
                f"{source.at(rows[k][0])}: the rebound velocity exceeds the "
                "impact velocity (a normal COR above 1, more energy out than in); "
                "check the columns' units"
            )
    return ExperimentData(
        scene=scenes.pop() if scenes else None,
        inputs=inputs,
        outputs=outputs,
        sigmas=sigmas,
        provenance="\n".join(provenance),
        path=path,
        columns={c.header: c for c in columns.values()},
        lines=line_numbers,
        checks=checks,
        declarations=declarations,
    )


def _read_lines(path: str) -> list[str]:
    """The file's lines, decoded as UTF-8 (a byte-order mark, as spreadsheet
    programs write, is dropped); a clear `DataError` otherwise."""
    if os.path.isdir(path):
        raise DataError(f"{path}: is a directory; give the path of a CSV file")
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as err:
        raise DataError(f"{path}: cannot be read ({err.strerror})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise DataError(
            f"{path}, line {line}: byte 0x{raw[err.start]:02x} is not UTF-8 "
            "text; save the file as UTF-8 (CSV UTF-8 in spreadsheet programs)"
        ) from None
    return text.splitlines()


def finite_number(text: str, where: str) -> float:
    """``text`` as a finite float, or a `DataError` that starts with ``where``."""
    try:
        x = parse_number(text)
    except ValueError:
        raise DataError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(x):
        raise DataError(f"{where}: {text!r} is not a finite number")
    return x


def _cell(text: str, col: Column, row: str) -> float:
    where = f"{row}, column {col.header!r}"
    text = text.strip()
    q = QUANTITIES[col.quantity]
    if not text:
        if q.role != "input":
            return math.nan  # not measured (or not checked) in this row
        raise DataError(f"{where}: empty, but an input needs a value in every row")
    x = finite_number(text, where)
    if q.nonnegative and x < 0:
        raise DataError(
            f"{where}: {text} is negative; {q.name} ({q.doc}) must be >= 0 "
            f"in {col.unit or SI[q.dimension]}"
        )
    size = abs(x) if q.magnitude else x
    if not col.is_sigma and size * col.factor > q.maximum:
        what = f"|{q.name}|" if q.magnitude else q.name
        raise DataError(
            f"{where}: {text} exceeds {q.maximum:g}, the largest physically "
            f"possible {what} ({q.doc})"
        )
    return x
