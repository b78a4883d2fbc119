"""A fit's progress on disk: its last accepted iterate, so that an interrupted
fit can restart from it (`diffimpact.fit`'s ``checkpoint`` and ``resume``,
``diffimpact fit --resume``).

The file is JSON, replaced atomically (written whole to a temporary file,
synced, renamed over the old one) at every accepted iterate, so it always
holds one whole iterate, whenever the fit is stopped::

    {"format": "diffimpact fit progress 1",
     "free": ["yield_strength"], "parameters": {"yield_strength": 3.9e8},
     "iteration": 4, "cost": 0.0123, "rows": 3, "solver": "levenberg-marquardt",
     "quantities": ["cor_normal", "contact_time"], "data_sha256": "..."}

``cost`` is half the sum of the squared weighted residuals of the ``rows``
fitted at that point (fewer than the file's during a warm start on a
subsample).  A restart begins at ``parameters``; it is refused if the free
parameters, the fitted quantities or the data differ.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from .._io._files import write_json_atomic

FORMAT = "diffimpact fit progress 1"


def free_names(free) -> tuple[str, ...]:
    """``free`` as `fit` reads it: a comma-separated string or names."""
    if isinstance(free, str):
        return tuple(f.strip() for f in free.split(",") if f.strip())
    return tuple(free)


def data_digest(problem) -> str:
    """SHA-256 of what a fit fits: the rows' inputs, measurements, sigmas."""
    h = hashlib.sha256()
    arrays = [(f"input {q}", v) for q, v in sorted(problem.inputs.items())]
    arrays += [("measured", problem.measured), ("sigma", problem.sigma),
               ("mask", problem.mask)]  # fmt: skip
    for name, value in arrays:
        a = np.ascontiguousarray(np.asarray(value))
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


class Checkpoint:
    """The progress file of one fit: `load` before it starts, `check` once
    the problem is built, `save` at every accepted iterate."""

    def __init__(self, path, resume: bool, callback=None):
        self.path = None if path is None else Path(path)
        self.resume, self.callback = resume, callback
        self.loaded = None  # the record a restart began from
        self.problem = self.digest = None

    def load(self, free) -> dict:
        """The start values of a restart (``{}`` for a fresh fit); refuses
        an existing file without ``resume`` and one of other parameters."""
        if self.path is None or not self.path.exists():
            return {}
        if not self.resume:
            raise FileExistsError(
                f"{self.path} already exists: pass resume=True to restart the fit "
                "from it, or remove it"
            )
        where = f"cannot restart from {self.path}"
        try:
            record = json.loads(self.path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise ValueError(f"{where}: it is not valid JSON") from None
        if not isinstance(record, dict) or record.get("format") != FORMAT:
            raise ValueError(f"{where}: it is not a fit's progress file")
        saved = tuple(record.get("free", ()))
        if saved != free_names(free):
            raise ValueError(
                f"{where}: it was saved by a fit of {', '.join(saved)}, not of "
                f"{', '.join(free_names(free))}"
            )
        self.loaded = record
        return {k: float(v) for k, v in record["parameters"].items()}

    def check(self, problem) -> None:
        """After the problem is built: the restart's data and quantities are
        the saved fit's."""
        self.problem = problem
        if self.path is None:
            return
        self.digest = data_digest(problem)
        if self.loaded is None:
            return
        where = f"cannot restart from {self.path}"
        saved = list(self.loaded.get("quantities", ()))
        if saved != list(problem.quantities):
            raise ValueError(
                f"{where}: it was saved by a fit of {', '.join(saved)}, not of "
                f"{', '.join(problem.quantities)}"
            )
        if self.loaded.get("data_sha256") != self.digest:
            raise ValueError(f"{where}: it was saved by a fit of other data")

    def on_accept(self, solver: str, rows: int):
        """The ``on_accept`` of the iterations: save and call back (None
        when there is neither a file nor a callback)."""
        if self.path is None and self.callback is None:
            return None

        def accept(u, step, cost):
            problem = self.problem
            values = np.asarray(u, float)
            parameters = {
                name: float(t.forward(values[i]))
                for i, (name, t) in enumerate(
                    zip(problem.names, problem.transforms, strict=True)
                )
            }
            if self.path is not None:
                self.save(parameters, step, cost, rows, solver)
            if self.callback is not None:
                self.callback(step, parameters, cost)

        return accept

    def save(self, parameters, step, cost, rows, solver) -> None:
        record = {
            "format": FORMAT,
            "free": list(self.problem.names),
            "parameters": parameters,
            "iteration": int(step),
            "cost": float(cost),
            "rows": int(rows),
            "solver": solver,
            "quantities": list(self.problem.quantities),
            "data_sha256": self.digest,
        }
        write_json_atomic(self.path, record)
