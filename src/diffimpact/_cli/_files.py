"""The command line's files and flag values: never replace a user's file unasked,
never read a number that is not written as one."""

from __future__ import annotations

import os
import tempfile
from importlib.metadata import PackageNotFoundError, version

from .._io._files import open_new as open_new
from .._io._units import parse_integer, parse_number


def number(text: str) -> float:
    """argparse type of a number flag: plain decimal digits only (``float``
    would read ``0_5`` as 5); argparse names the flag in its message."""
    return parse_number(text)


def integer(text: str) -> int:
    """argparse type of an integer flag (``int`` would read ``1_0`` as 10)."""
    return parse_integer(text)


def writable_folder(out) -> bool:
    """Make the output folder ``out`` if needed and check that a file can be
    written in it, before any long computation; ValueError naming ``--out``
    otherwise.  Returns whether the folder was made here."""
    created = not os.path.isdir(out)
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as err:
        raise ValueError(f"--out {out}: cannot be created ({err.strerror})") from None
    try:
        tempfile.TemporaryFile(dir=out).close()  # made, then removed on close
    except OSError as err:
        if created:
            os.rmdir(out)
        raise ValueError(
            f"--out {out}: no file can be written there ({err.strerror})"
        ) from None
    return created


# The libraries behind a result's numbers, as `--version` and the result
# files' provenance name them.
LIBRARIES = ("diffimpact", "jax", "jaxlib", "diffrax", "equinox", "optimistix",
             "blackjax")  # fmt: skip


def versions() -> dict[str, str | None]:
    """Installed version of each of `LIBRARIES` (None: not installed), read
    from the package metadata: nothing is imported."""
    out = {}
    for name in LIBRARIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out
