"""A sweep's rows in a CSV file, appended as each chunk finishes, and resumed.

The file is the header line and one line per row, in row order.  Beside it,
``<file>.json`` (`settings_path`) holds the sweep's settings: the rows, the
chunk size, the devices, the columns, the SHA-256 of the inputs, the versions
of diffimpact and JAX, and whatever the caller adds (the command line's
flags).  A resumed sweep must have the same settings, so that the rows still
to come are computed by the same program on the same chunks: the finished
file is then the same, bit for bit, as an uninterrupted run's.

Each chunk's lines are written whole by one ``write`` call on an unbuffered
file and synced to the disk (``fsync``) at most every `SYNC_EVERY`
seconds and at the end: a killed process loses no line the operating system
has been given; a machine that loses power, at most that last second.  On
resume a partial last line (a write cut short) is dropped, and so are the
rows of an incomplete last chunk, so that the sweep goes on from a chunk
boundary.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import jax
import numpy as np

from .._io._files import write_json_atomic

# The format of the settings file; a later format may not resume this one.
FORMAT = "diffimpact sweep rows 1"
# Least seconds between two syncs of the file to the disk (an fsync took 5 ms
# here: after each chunk of 512 rows, 20 % of the sweep's time).
SYNC_EVERY = 1.0


def settings_path(path) -> Path:
    """Where the settings of the rows in ``path`` are kept: ``<path>.json``."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def inputs_digest(names, leaves) -> str:
    """SHA-256 of the inputs: each column's name, dtype, shape and bytes."""
    h = hashlib.sha256()
    for name, leaf in zip(names, leaves, strict=True):
        a = np.ascontiguousarray(leaf)
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def library_versions() -> dict[str, str | None]:
    """The versions whose programs compute the rows: a resumed sweep with
    others could give other bits."""
    out = {}
    for name in ("diffimpact", "jax", "jaxlib"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def _shown(value) -> str:
    text = "(not given)" if value is None else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _differences(old: dict, new: dict) -> list[str]:
    """``"KEY OLD there, NEW here"`` for each setting that differs."""
    out = []
    for key in dict.fromkeys([*new, *old]):
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if key == "inputs_sha256":
            out.append("the inputs differ (their SHA-256)")
        else:
            out.append(f"{key} {_shown(a)} there, {_shown(b)} here")
    return out


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _sync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # (not on every system)
        return
    try:
        with contextlib.suppress(OSError):  # (a folder cannot always be synced)
            os.fsync(fd)
    finally:
        os.close(fd)


class RowFile:
    """The CSV file of a sweep, opened for appending whole chunks of rows.

    ``mode``: ``"new"`` (an existing file, or its settings file, is refused
    with ``FileExistsError``), ``"force"`` (replaced) or ``"resume"`` (the rows
    it holds are kept, after its settings are compared with ``settings``;
    a missing file starts the sweep)."""

    def __init__(self, path, header: str, settings: dict, n: int, chunk: int,
                 mode: str = "new", exists_hint: str = ""):  # fmt: skip
        if mode not in ("new", "force", "resume"):
            raise ValueError(f"mode must be new, force or resume, got {mode!r}")
        self.path = Path(path)
        self.sidecar = settings_path(self.path)
        self.header = (header + "\n").encode()
        self.settings = {"format": FORMAT, **settings}
        self.n, self.chunk, self.mode = n, chunk, mode
        self.exists_hint = exists_hint
        self.fd = None
        self.kept = 0  # rows found in the file when it was opened
        self.written = 0  # rows in the file now
        self.made = False  # whether this call created the file
        self._synced = time.monotonic()

    # -- opening -----------------------------------------------------------

    def open(self) -> bytes:
        """Open the file; returns the lines of the rows it already holds
        (``self.kept`` of them: whole chunks, or every row)."""
        if self.mode == "resume" and self.path.exists():
            return self._resume()
        if self.mode == "new":
            for p in (self.path, self.sidecar):
                if p.exists():
                    raise FileExistsError(f"{p} already exists{self.exists_hint}")
        self._write_settings()
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND
        flags |= os.O_EXCL if self.mode == "new" else os.O_TRUNC
        self.fd = os.open(self.path, flags, 0o666)
        self.made = True
        _write_all(self.fd, self.header)
        os.fsync(self.fd)
        _sync_dir(self.path.parent)
        return b""

    def _write_settings(self) -> None:
        """The settings file, replaced atomically (written whole, synced,
        then renamed over the old one)."""
        record = {**self.settings, "versions": library_versions()}
        write_json_atomic(self.sidecar, record)

    def read_only(self) -> bytes:
        """`open` for a process that does not write (under
        ``jax.distributed``): where the sweep resumes, the file unchanged."""
        if self.mode != "resume" or not self.path.exists():
            return b""
        return self._resume(write=False)

    def _resume(self, write: bool = True) -> bytes:
        where = f"cannot resume {self.path}"
        try:
            with open(self.sidecar) as fh:
                old = json.load(fh)
        except FileNotFoundError:
            raise ValueError(
                f"{where}: its settings file {self.sidecar.name} is missing (a "
                "sweep's file without it cannot be checked; remove the file to "
                "start again)"
            ) from None
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise ValueError(f"{where}: {self.sidecar} is not valid JSON") from None
        if not isinstance(old, dict) or old.get("format") != FORMAT:
            raise ValueError(f"{where}: {self.sidecar} is not a sweep's settings")
        new = {**self.settings, "versions": library_versions()}
        diffs = _differences(old, new)
        if diffs:
            raise ValueError(
                f"{where}: it was started with other settings: {'; '.join(diffs)}"
            )
        raw = self.path.read_bytes()
        if raw.startswith(self.header):
            body = raw[len(self.header) :]
        elif self.header.startswith(raw):  # (killed while writing the header)
            body = b""
        else:
            raise ValueError(f"{where}: its first line is not this sweep's header")
        # whole lines only: a last line without its newline was cut short
        lines = body[: body.rfind(b"\n") + 1].splitlines(keepends=True)
        if len(lines) > self.n:
            raise ValueError(
                f"{where}: it holds {len(lines):,} rows, more than the sweep's "
                f"{self.n:,}"
            )
        # from a chunk boundary, so that every chunk is the program's own
        keep = len(lines)
        if keep < self.n:
            keep = keep // self.chunk * self.chunk
        kept = b"".join(lines[:keep])
        self.kept = self.written = keep
        if not write:
            return kept
        self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        if not raw.startswith(self.header):
            os.ftruncate(self.fd, 0)
            _write_all(self.fd, self.header)
            os.fsync(self.fd)
        elif len(raw) != len(self.header) + len(kept):
            os.ftruncate(self.fd, len(self.header) + len(kept))
            os.fsync(self.fd)
        return kept

    # -- appending ---------------------------------------------------------

    def append(self, text: str, rows: int) -> None:
        """Append the lines of ``rows`` rows, whole, in one write."""
        _write_all(self.fd, text.encode())
        self.written += rows
        now = time.monotonic()
        if self.written == self.n or now - self._synced >= SYNC_EVERY:
            os.fsync(self.fd)
            self._synced = now

    def close(self) -> None:
        if self.fd is not None:
            os.fsync(self.fd)
            os.close(self.fd)
            self.fd = None

    def abandon(self) -> None:
        """After a failure or an interruption: close the file, and remove it
        and its settings where this call made them and wrote no row (an
        interrupted sweep with rows stays, to be resumed)."""
        self.close()
        if self.made and self.written == 0:
            for p in (self.path, self.sidecar):
                p.unlink(missing_ok=True)


def _key_name(path) -> str:
    """``a.b.0`` for the key path of a leaf (dict keys, indices, fields)."""
    parts = []
    for k in path:
        for attr in ("key", "idx", "name"):
            if hasattr(k, attr):
                parts.append(str(getattr(k, attr)))
                break
        else:
            parts.append(str(k))
    return ".".join(parts)


def _columns(name: str, shape) -> list[str]:
    """The CSV columns of a leaf whose rows have ``shape``."""
    if not shape:
        return [name]
    return [f"{name}[{','.join(map(str, i))}]" for i in np.ndindex(*shape)]


def _cell_format(dtype, where: str) -> str:
    """The ``%`` format of a column that reads back to the same bits: the
    shortest decimal of a float that does (Python's ``repr``)."""
    dtype = np.dtype(dtype)
    if dtype.kind in "biu":
        return "%d"
    if dtype.kind == "f":
        return "%r"
    raise ValueError(
        f"`{where}` has dtype {dtype}: a sweep file holds real numbers, integers "
        "and booleans only"
    )


def _function_name(fn) -> str:
    while isinstance(fn, functools.partial):
        fn = fn.func
    name = getattr(fn, "__qualname__", type(fn).__qualname__)
    return f"{getattr(fn, '__module__', None) or ''}.{name}".lstrip(".")


class Table:
    """`sweep`'s file: the columns of the inputs and outputs, each written
    with the digits that read back to its bits (``engine``: the sweep's
    chunks, `diffimpact._inference._sweep.plan`)."""

    def __init__(self, engine):
        self.engine = engine
        tree = jax.tree_util.tree_unflatten(engine.treedef, engine.host)
        flat, _ = jax.tree_util.tree_flatten_with_path(tree)
        inputs = [_key_name(p) or "input" for p, _ in flat]
        self.in_names = inputs
        struct = engine.structure()
        out_flat, self.out_def = jax.tree_util.tree_flatten_with_path(struct)
        names, formats, widths = [], [], []
        for name, leaf in zip(inputs, engine.host, strict=True):
            cols = _columns(name, leaf.shape[1:])
            names += cols
            formats += [_cell_format(leaf.dtype, name)] * len(cols)
        self.shapes, self.dtypes = [], []
        for path, leaf in out_flat:
            name = _key_name(path) or "output"
            if name in inputs:
                name = "output." + name
            cols = _columns(name, leaf.shape[1:])
            names += cols
            formats += [_cell_format(leaf.dtype, name)] * len(cols)
            widths.append(len(cols))
            self.shapes.append(leaf.shape[1:])
            self.dtypes.append(leaf.dtype)
        twice = sorted({c for c in names if names.count(c) > 1})
        if twice:
            raise ValueError(f"sweep columns named twice: {', '.join(twice)}")
        self.names, self.widths = names, widths
        self.n_inputs = len(names) - sum(widths)
        self.header = ",".join(names)
        self.row = ",".join(formats) + "\n"

    def settings(self) -> dict:
        e = self.engine
        return {
            "rows": e.n,
            "chunk_size": e.chunk,
            "devices": f"{len(e.devices)} {e.devices[0].platform}",
            "processes": jax.process_count(),
            "function": _function_name(e.fn),
            "columns": self.names,
            "inputs_sha256": inputs_digest(self.in_names, e.host),
        }

    def format_rows(self, start: int, stop: int, out) -> str:
        cols = []
        for leaf in self.engine.host:
            block = leaf[start:stop].reshape(stop - start, -1)
            cols += [c.tolist() for c in block.T]
        for leaf in jax.tree_util.tree_leaves(out):
            block = np.asarray(leaf).reshape(stop - start, -1)
            cols += [c.tolist() for c in block.T]
        row = self.row
        return "".join(row % cells for cells in zip(*cols, strict=True))

    def parse_rows(self, lines: bytes, struct):
        cells = np.array(
            [line.split(",") for line in lines.decode().splitlines()], dtype=str
        )
        if cells.ndim != 2 or cells.shape[1] != len(self.names):
            raise ValueError("a row of the sweep's file has the wrong number of cells")
        leaves, j = [], self.n_inputs
        for width, shape, dtype in zip(self.widths, self.shapes, self.dtypes,
                                       strict=True):  # fmt: skip
            block = cells[:, j : j + width]
            j += width
            kind = np.dtype(dtype).kind
            values = block.astype(np.float64 if kind == "f" else np.int64)
            leaves.append(values.astype(dtype).reshape((len(cells), *shape)))
        return jax.tree_util.tree_unflatten(self.out_def, leaves)
