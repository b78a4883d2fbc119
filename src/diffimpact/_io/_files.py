"""Output files: a user's file is never replaced unasked."""

from __future__ import annotations


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
