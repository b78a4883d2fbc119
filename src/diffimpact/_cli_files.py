"""Output files of the command line: never replace a user's file unasked."""

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


def number(text: str) -> float:
    """argparse type of a number flag: plain decimal digits only (``float``
    would read ``0_5`` as 5); argparse names the flag in its message."""
    from ._data import parse_number

    return parse_number(text)


def integer(text: str) -> int:
    """argparse type of an integer flag (``int`` would read ``1_0`` as 10)."""
    from ._data import parse_integer

    return parse_integer(text)
