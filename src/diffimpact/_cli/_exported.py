"""The demo's programs, traced once and kept (``jax.export``).

JAX's persistent compilation cache skips compiling a program on a second
run, not tracing it, and tracing a diffrax solve takes seconds.  The demo's
four programs (three solves and a gradient) are pure functions of the impact
speed, so they are exported once, serialised into the command line's cache
folder (`_jax_setup.compilation_cache_dir`, under ``exported/``), and a later run
deserialises and calls them: no Python tracing at all.  A blob is keyed by
the versions of diffimpact, JAX and jaxlib and the float width, so an
upgrade traces afresh; an unreadable blob is traced again and replaced.
Nothing outside that folder is written.
"""

from __future__ import annotations

import hashlib
import os
import tempfile

from ._files import versions


def _key(name: str) -> str:
    import jax

    v = versions()
    text = "|".join(
        [name, str(v.get("diffimpact")), str(v.get("jax")), str(v.get("jaxlib")),
         str(jax.config.jax_enable_x64)]
    )  # fmt: skip
    return f"{name}-{hashlib.sha256(text.encode()).hexdigest()[:16]}.bin"


def call(name: str, build, *args, folder: str | None):
    """``build()`` (a function of ``args``) called through its exported form:
    loaded from ``folder`` when a run has kept it, else traced, exported,
    kept (when ``folder`` is given) and called."""
    import jax

    path = None if folder is None else os.path.join(folder, "exported", _key(name))
    if path is not None and os.path.exists(path):
        program = _load(path)
        if program is not None:
            return program.call(*args)
    shapes = [jax.ShapeDtypeStruct(jax.numpy.shape(a), jax.numpy.result_type(a))
              for a in args]  # fmt: skip
    program = _export(jax.jit(build()), shapes)
    if path is not None:
        _keep(path, program.serialize())
    return program.call(*args)


def _load(path: str):
    """The exported program kept at ``path``, or None for a damaged or
    foreign blob (which the caller then traces afresh and replaces)."""
    from jax import export

    try:
        with open(path, "rb") as fh:
            return export.deserialize(bytearray(fh.read()))
    except Exception:  # any unreadable blob: never fatal, traced again
        return None


def _export(fn, shapes):
    """``jax.export`` of ``fn``, with the check for custom calls without a
    cross-version guarantee (LAPACK's QR in a root finder) waived for those
    named: a kept blob is only ever read by the same jaxlib (`_key`)."""
    import re

    from jax import export

    try:
        return export.export(fn)(*shapes)
    except ValueError as err:
        names = sorted(set(re.findall(r"@([A-Za-z0-9_]+)", str(err))))
        if "custom calls" not in str(err) or not names:
            raise
        checks = [export.DisabledSafetyCheck.custom_call(n) for n in names]
        return export.export(fn, disabled_checks=checks)(*shapes)


def _keep(path: str, blob: bytes) -> None:
    """Written whole or not at all (a temporary file renamed over)."""
    folder = os.path.dirname(path)
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            fh.write(blob)
        os.replace(tmp, path)
    except OSError:  # a read-only cache: the demo still runs, traced each time
        return
