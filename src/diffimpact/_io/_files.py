"""Output files: a user's file is never replaced unasked."""

from __future__ import annotations

import json
import os
from pathlib import Path


def open_new(path, force: bool, binary: bool = False):
    """Open ``path`` for writing; without ``force`` refuse (atomically, mode
    ``"x"``) to replace an existing file."""
    mode = ("w" if force else "x") + ("b" if binary else "")
    try:
        return open(path, mode, **({} if binary else {"newline": ""}))
    except FileExistsError:
        raise ValueError(
            f"{path} already exists; pass --force to overwrite it"
        ) from None


def write_json_atomic(path, record: dict) -> None:
    """Replace ``path`` by ``record`` as JSON atomically: written whole to a
    temporary file beside it, synced, then renamed over it, so that a kill
    leaves either the old file or the new one (a checkpoint, a sweep's
    settings), never half of one."""
    path = Path(path)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    with open(tmp, "w") as fh:
        json.dump(record, fh, indent=2)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
