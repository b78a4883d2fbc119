"""Writing an experiment CSV: the schema `_data` reads, a planar body's
declarations above the header, and every column checked before the file
exists (a user's file is never replaced)."""

from __future__ import annotations

import csv
import math
import os

import numpy as np

from ._data import parse_column
from ._declarations import declaration_key, format_declarations


def write_experiments(
    path,
    columns: dict[str, np.ndarray],
    *,
    provenance: str = "",
    scene=None,
    body=None,
):
    """Write an experiment CSV in the schema `load_experiments` reads (refuses
    to overwrite).

    `columns` maps column names (with units, as in the schema) to arrays in
    the units of the name; `provenance` is written as ``#`` lines above the
    header and `scene` as a ``scene`` column.  `body`: a
    `diffimpact.scenes.PlanarBody` whose declarations (shape, mass, inertia,
    centre of mass, materials; in SI units) are written above the header,
    so that the file can be fitted on its own (`Experiment.from_file`,
    ``diffimpact fit``); its state is not written (the rows give it).
    """
    path = os.fspath(path)
    if body is not None:
        if scene is not None and scene.strip().lower().replace("-", "_") != (
            "planar_body"
        ):
            raise ValueError(
                f"{path}: `scene` is {scene!r}, but a declared `body` is a planar "
                "body's; give scene='planar_body' or none"
            )
        noted = [line for line in provenance.splitlines() if declaration_key(line)]
        if noted:
            raise ValueError(
                f"{path}: the provenance line {noted[0]!r} would be read as a "
                "body declaration; reword it (e.g. with ' - ' for the colon)"
            )
        provenance = "\n".join(filter(None, [provenance, format_declarations(body)]))
    if os.path.exists(path):
        raise FileExistsError(f"{path} exists; remove it first or choose another name")
    if not columns:
        raise ValueError(f"{path}: `columns` is empty; give at least one column")
    for h in columns:
        parse_column(h, f"{path}: ")
    # Every column checked before the file exists: a shorter column would
    # fail half-way through the rows, a longer one lose its tail silently.
    lengths = {h: np.shape(np.asarray(v)) for h, v in columns.items()}
    bad = {h: s for h, s in lengths.items() if len(s) != 1}
    if bad:
        raise ValueError(f"{path}: every column must be 1-D, got shapes {bad}")
    n = next(iter(lengths.values()))[0]
    if any(s[0] != n for s in lengths.values()):
        rows = {h: s[0] for h, s in lengths.items()}
        raise ValueError(f"{path}: the columns differ in length: {rows}")
    with open(path, "x", newline="", encoding="utf-8") as fh:
        for line in provenance.splitlines():
            fh.write(f"# {line}\n")
        w = csv.writer(fh)
        header = (["scene"] if scene else []) + list(columns)
        w.writerow(header)
        for i in range(n):
            row = [scene] if scene else []
            row += [_fmt(columns[h][i]) for h in columns]
            w.writerow(row)


def _fmt(x) -> str:
    x = float(x)
    return "" if math.isnan(x) else repr(x)
