"""Parameter sweeps: evaluate one function over many parameter rows.

Two ways to run a sweep, one contract: ``inputs`` is a pytree of arrays sharing
a leading axis of length ``N`` (one row per parameter combination), and ``fn``
maps one *unbatched* row (the same pytree with the leading axis removed) to an
output pytree.

- `sweep`: for large sweeps (10^6 rows and more).  ``jax.vmap(fn)`` runs
  over chunks of ``chunk_size`` rows; each chunk is sharded along its rows over
  a 1-D `jax.sharding.Mesh` of every device given (all that JAX sees by
  default, across all processes under ``jax.distributed``) and its outputs are
  copied to host numpy arrays, so device memory is bounded by the chunk,
  whatever ``N``.  The result is numpy: it is *not* differentiable.
- `sweep_map`: for small sweeps that must be differentiated.  It is
  ``jax.vmap(fn)``, or ``jax.lax.map(fn, inputs, batch_size=...)`` over
  batches, with no host transfer, so
  ``jax.jit``/``jax.grad``/``jax.vmap`` compose with it (e.g. the gradient of a
  mean rebound velocity over a batch).

Helpers build ``inputs`` (`._sweep_inputs`: `grid`, the Cartesian product,
and `sample`, uniform or log-uniform random rows); `._normal_rows` holds
`normal_impact`, the row function of the common case (a sphere on a flat
under Jackson-Green contact, solved by the ODE-free quadrature); the rows
on disk are `._sweep_file`'s.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._checks import integer, raise_as_invalid
from .._io._frames import frame_columns, is_dataframe, to_frame
from ._progress import Progress
from ._sweep_file import RowFile, Table

# Rows per device in a chunk by default.  On CPU a small chunk keeps the
# quadrature's per-row temporaries (32 x 16 Gauss nodes, ~25 kB a row) in
# cache and bounds the peak memory; larger chunks gain little or no
# throughput for more memory (benchmarks/RESULTS.md, "Sweeps").  On
# accelerators larger batches keep the device busy; 65536 rows (~1.6 GB a
# chunk) is a guess, not measured.
ROWS_PER_DEVICE = {"cpu": 512}
ROWS_PER_DEVICE_ACCELERATOR = 65536

_AXIS = "batch"  # name of the mesh axis the rows are sharded along


# --------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------


def _rows(inputs, name: str = "inputs") -> tuple[int, list, Any]:
    """Leaves (as arrays), common leading length and treedef of ``inputs``.

    Raises ``ValueError`` naming the offending leaf for a missing leading axis,
    mismatched leading axes or an empty sweep.  Only shapes are read, so this
    works on tracers too (``sweep_map`` under ``jit``)."""
    flat, treedef = jax.tree_util.tree_flatten_with_path(inputs)
    if not flat:
        raise ValueError(f"`{name}` is empty: give at least one array of rows")
    leaves, n = [], None
    first = None
    for path, leaf in flat:
        where = f"{name}{jax.tree_util.keystr(path)}"
        if not isinstance(leaf, jax.Array | np.ndarray):
            leaf = np.asarray(leaf)
        if leaf.ndim == 0:
            raise ValueError(
                f"`{where}` is a scalar; every input needs a leading axis of "
                "rows (broadcast fixed values, or close over them in `fn`)"
            )
        if n is None:
            n, first = leaf.shape[0], where
        elif leaf.shape[0] != n:
            raise ValueError(
                f"`{where}` has {leaf.shape[0]} rows but `{first}` has {n}: all "
                "inputs must share the leading axis"
            )
        leaves.append(leaf)
    if n == 0:
        raise ValueError(f"`{name}` has 0 rows: the sweep is empty")
    return n, leaves, treedef


# --------------------------------------------------------------------------
# Sweeps
# --------------------------------------------------------------------------


def _to_host(out):
    """Copy a pytree of (sharded) arrays to host numpy arrays."""
    leaves = jax.tree_util.tree_leaves(out)
    if all(x.is_fully_addressable for x in leaves):
        return jax.tree.map(np.asarray, out)
    # Under jax.distributed the chunk's rows live on several processes: every
    # process gathers all of them, in one collective for the whole pytree
    # (so every process must call it).
    from jax.experimental import multihost_utils

    return jax.tree.map(np.asarray, multihost_utils.process_allgather(out, tiled=True))


def default_chunk_size(devices: Sequence[jax.Device] | None = None) -> int:
    """Default rows per chunk for ``devices`` (default ``jax.devices()``): 512
    per CPU device, 65536 per accelerator (see ``ROWS_PER_DEVICE``)."""
    devices = list(jax.devices() if devices is None else devices)
    per = ROWS_PER_DEVICE.get(devices[0].platform, ROWS_PER_DEVICE_ACCELERATOR)
    return per * len(devices)


@functools.lru_cache(maxsize=16)
def _cached_batched(fn):
    return jax.jit(jax.vmap(fn))


def _batched(fn):
    """``jax.jit(jax.vmap(fn))``, the same object for the same ``fn``, so a
    second sweep of the same function reuses the compiled programs."""
    try:
        return _cached_batched(fn)
    except TypeError:  # unhashable callable (e.g. a Module holding arrays)
        return jax.jit(jax.vmap(fn))


def sweep(
    fn: Callable,
    inputs,
    *,
    chunk_size: int | None = None,
    devices: Sequence[jax.Device] | None = None,
    progress: bool = False,
    out=None,
    resume: bool = False,
    on_chunk: Callable[[int, int], Any] | None = None,
):
    """Evaluate ``fn`` on every row of ``inputs``, in vmapped, sharded chunks.

    **Arguments:**

    - `fn`: maps one row (``inputs`` with the leading axis removed) to a pytree
      of arrays.  It must be traceable by ``jax.vmap``/``jax.jit``.
    - `inputs`: pytree of arrays (numpy or JAX) with a common leading axis of
      ``N >= 1`` rows.  Kept on the host; each chunk is copied to the devices
      in turn.
    - `chunk_size`: rows per chunk, split evenly over the devices (default:
      `default_chunk_size`, 512 rows per CPU device).  Rounded up to a
      multiple of the number of devices, and down to ``N`` (rounded up) for
      small sweeps.  The last chunk is padded by
      repeating the last row, so every chunk has the same shape and ``fn`` is
      compiled once (per device); the padding is dropped.  Device memory is
      that of two chunks (one computing while the previous one is copied
      back), whatever ``N``; host memory holds ``inputs`` and the outputs.
    - `devices`: devices to shard each chunk over, as a 1-D
      `jax.sharding.Mesh` (default ``jax.devices()``: all of them, on
      every process under ``jax.distributed``).  Each gets
      ``chunk_size / len(devices)`` consecutive rows of every chunk.
    - `progress`: draw a text progress bar on stderr (process 0 only).
    - `out`: a path: also write the rows to this CSV file as each chunk
      finishes (**The file** below), so that an interrupted sweep
      loses nothing.  An existing file is never replaced: ``FileExistsError``.
    - `resume`: with `out`: continue the sweep that file holds (or start it,
      if there is none).  Its rows are kept, not computed again, and the
      finished file is the same, bit for bit, as an uninterrupted run's.  Its
      settings must be this call's: ``ValueError`` naming what differs.
    - `on_chunk`: called as ``on_chunk(rows_done, rows_total)`` after each
      chunk (written, with `out`); an exception it raises stops the sweep
      (a ``KeyboardInterrupt`` too), and what is written stays.

    **Returns:** the output pytree of ``fn`` with every leaf stacked to a numpy
    array of leading length ``N`` (row ``i`` is ``fn`` of row ``i``); with
    `resume`, the rows of the file included (read back exactly).

    **The file** (`out`): a header line, then one line per row, in row
    order: the columns of ``inputs``, then those of the outputs, named by
    their keys (``a.b`` for nested ones, ``name[i]`` for the entries of a
    leaf with more than one value a row; an output named like an input is
    ``output.name``), floats with the digits that read back to the same
    bits (Python's ``repr``), integers and booleans as integers.  Beside it,
    ``<out>.json`` holds the settings a resumed sweep must share: the rows,
    the chunk size, the devices, the columns, the SHA-256 of the inputs, the
    function's name (not what it closes over: the caller keeps that the
    same) and the versions of diffimpact and JAX.  Lines are written whole,
    one write a chunk, and synced to the disk at most every second; a
    resumed sweep drops a partial last line and an incomplete last chunk and
    goes on from there.  Under ``jax.distributed`` process 0 writes the
    file, and every process must see it to resume.

    **Several processes** (``jax.distributed.initialize()`` first, on every
    machine): every process calls ``sweep`` with the same ``inputs`` (a
    `grid`, or a `sample` with the same key), computes the rows of
    its own devices, and gets all ``N`` rows back (gathered by a collective
    after each chunk, so every process must take part).

    **Reproducibility:** every device runs the same single-device program
    ``jax.vmap(fn)`` on its own rows (no SPMD partitioning), so sharding
    changes no bit: ``K`` devices with chunks of ``K c`` rows give exactly
    the results of one device with chunks of ``c``, and so do several
    processes (the tests check this against one jitted ``jax.vmap(fn)`` over
    all rows).  XLA may compile different batch sizes per device to
    differently vectorised code: on the development CPU, 8 to 2048 rows per
    device gave one set of bits and 4096 or more another: 3 % of 10^6 random
    impacts differed, by at most 4e-15 relative (7.7e-14 on a permanent
    deformation 200 times smaller than the maximum deflection it is the
    difference of).  Fewer than 8 rows and 64 rows differed likewise.  Keep
    the rows per device fixed when results must match bit for bit.

    The result is numpy, so ``sweep`` cannot be differentiated; use
    `sweep_map` for gradients through a (small) sweep.

    **A pandas DataFrame** as `inputs`: its columns are the row's entries
    (``fn`` gets ``{column name: value}``), and the result is a DataFrame
    with the frame's index, one column per output leaf (named by its key).

    **Raises:** ``ValueError`` naming the field for mismatched leading axes, an
    empty sweep, or ``chunk_size <= 0``; `diffimpact.InvalidInputError`
    naming the field, the value and the row for a row outside a scene's
    domain, when ``fn`` simulates with ``throw=True`` (`normal_impact`'s
    default ``throw=False`` gives that row the code ``invalid_input`` and
    NaN outputs instead).
    """
    if is_dataframe(inputs):
        result = sweep(
            fn,
            frame_columns(inputs),
            chunk_size=chunk_size,
            devices=devices,
            progress=progress,
            out=out,
            resume=resume,
            on_chunk=on_chunk,
        )
        return to_frame(result, inputs.index, "a sweep over a DataFrame")
    if resume and out is None:
        raise ValueError("`resume=True` needs `out`, the file of the sweep to go on")
    engine = plan(fn, inputs, chunk_size=chunk_size, devices=devices)
    if out is None:
        return run_sweep(engine, progress=progress, on_chunk=on_chunk)
    table = Table(engine)
    rows = RowFile(
        out,
        table.header,
        table.settings(),
        engine.n,
        engine.chunk,
        "resume" if resume else "new",
        exists_hint=": pass resume=True to go on with its sweep, or remove it",
    )
    return run_sweep(
        engine,
        progress=progress,
        on_chunk=on_chunk,
        rows=rows,
        format_rows=table.format_rows,
        parse_rows=table.parse_rows,
    )


def plan(fn, inputs, *, chunk_size=None, devices=None) -> _Chunks:
    """The chunks of `sweep` (its arguments checked): ``inputs`` on the host,
    split into chunks of equal shape over ``devices``."""
    n, leaves, treedef = _rows(inputs)
    devices = list(jax.devices() if devices is None else devices)
    if not devices:
        raise ValueError("`devices` is empty: give at least one device")
    if chunk_size is None:
        chunk_size = default_chunk_size(devices)
    chunk_size = integer("chunk_size", chunk_size)
    n_dev = len(devices)
    # Never compute more padding than one device's share, and keep every
    # device's share equal (NamedSharding needs divisibility).
    chunk = min(chunk_size, n)
    chunk = -(-chunk // n_dev) * n_dev
    host = [np.asarray(leaf) for leaf in leaves]
    return _Chunks(fn, host, treedef, n, chunk, devices)


class _Chunks:
    """The chunks of a sweep, computed on the devices and copied back."""

    def __init__(self, fn, host, treedef, n, chunk, devices):
        self.fn, self.host, self.treedef = fn, host, treedef
        self.n, self.chunk, self.devices = n, chunk, devices
        self.n_chunks = -(-n // chunk)
        mesh = Mesh(np.asarray(devices), (_AXIS,))
        self.sharding = NamedSharding(mesh, PartitionSpec(_AXIS))
        # Which rows of a chunk each of this process's devices holds (under
        # jax.distributed, only the local devices are listed).
        self.local = self.sharding.addressable_devices_indices_map((chunk,))
        # Every device runs the same single-device program `vmap(fn)` on its
        # own rows, dispatched asynchronously (so all devices work at once),
        # and the pieces are assembled into one array sharded by `rows`.
        # Rows are independent, so nothing needs to communicate, and each
        # device leaves its loops (Newton, adaptive steps) when its own rows
        # converge.  (An SPMD program -- jit with in_shardings, or shard_map
        # -- is compiled through XLA's partitioning pipeline, which rewrites
        # some arithmetic: its results differed from the unsharded ones by a
        # few ulps, up to 6e-15.)
        self.batched = _batched(fn)
        self._structure = None

    def structure(self):
        """The outputs of one chunk, as ``jax.ShapeDtypeStruct`` (traced,
        not run)."""
        if self._structure is not None:
            return self._structure
        one = [
            jax.ShapeDtypeStruct(
                (self.chunk // len(self.devices),) + x.shape[1:], x.dtype
            )  # fmt: skip
            for x in self.host
        ]
        self._structure = jax.eval_shape(
            self.batched, jax.tree_util.tree_unflatten(self.treedef, one)
        )
        return self._structure

    def _run(self, k: int):
        chunk, rows = self.chunk, self.sharding
        # Rows past the end repeat the last row: a valid input, so runtime
        # checks inside `fn` (e.g. velocity > 0) are not tripped by padding.
        idx = np.minimum(np.arange(k * chunk, (k + 1) * chunk), self.n - 1)
        blocks = [leaf[idx] for leaf in self.host]
        pieces = []
        for device, index in self.local.items():
            x = [jax.device_put(b[index], device) for b in blocks]
            pieces.append(self.batched(jax.tree_util.tree_unflatten(self.treedef, x)))
        flat = [jax.tree_util.tree_leaves(p) for p in pieces]
        tdef = jax.tree_util.tree_structure(pieces[0])
        out = [
            jax.make_array_from_single_device_arrays(
                (chunk,) + parts[0].shape[1:], rows, list(parts)
            )
            for parts in zip(*flat, strict=True)
        ]
        return jax.tree_util.tree_unflatten(tdef, out)

    def __call__(self, first: int = 0):
        """``(start, stop, outputs)`` for each chunk from row ``first`` (a
        chunk boundary), the outputs as host numpy arrays of ``stop - start``
        rows."""
        # JAX dispatches asynchronously: chunk k+1 is queued before chunk k
        # is copied back, so the devices are not idle during the transfer.
        pending = None
        start = self.n_chunks if first >= self.n else first // self.chunk
        for k in range(start, self.n_chunks):
            out = self._checked(self._run, k)
            if pending is not None:
                yield self._checked(self._collect, *pending)
            pending = (k, out)
        if pending is not None:
            yield self._checked(self._collect, *pending)

    def _checked(self, call, k: int, *args):
        """``call(k, *args)``; a traced input check that fails inside `fn`
        (under jit: JAX's runtime error) is raised as InvalidInputError naming
        the sweep's row (exact on one device, whose program holds the whole
        chunk)."""
        try:
            return call(k, *args)
        except (jax.errors.JaxRuntimeError, ValueError) as err:
            one = len(self.devices) == 1
            raise_as_invalid(err, k * self.chunk if one else None, self.n)
            raise

    def _collect(self, k, out):
        start = k * self.chunk
        stop = min(start + self.chunk, self.n)
        host = jax.tree.map(lambda x: x[: stop - start], _to_host(out))
        return start, stop, host


def run_sweep(engine: _Chunks, *, progress=False, on_chunk=None, rows=None,
              format_rows=None, parse_rows=None):  # fmt: skip
    """The sweep's loop: every chunk of ``engine`` into one output pytree of
    numpy arrays; with ``rows`` (a `RowFile`), each chunk's lines
    (``format_rows(start, stop, outputs)``) appended to it, and the rows it
    held already read back (``parse_rows(lines, structure)``) instead of
    computed."""
    n = engine.n
    writer = rows is not None and jax.process_index() == 0
    out_leaves = out_def = None
    first = 0
    if rows is not None:
        struct = engine.structure()
        out_def = jax.tree_util.tree_structure(struct)
        out_leaves = [
            np.empty((n,) + x.shape[1:], x.dtype)
            for x in jax.tree_util.tree_leaves(struct)
        ]
        if writer:
            kept = rows.open()
        else:  # every process starts where process 0 does (a shared file)
            kept = rows.read_only()
        first = rows.kept
        if first:
            done = jax.tree_util.tree_leaves(parse_rows(kept, struct))
            for dst, src in zip(out_leaves, done, strict=True):
                dst[:first] = src
    bar = (
        Progress(n, rate=True, every=0.2, start=first)
        if progress and jax.process_index() == 0
        else None
    )
    if bar is not None:
        bar.update(first, final=first == n)  # shown during the first compilation
    try:
        for start, stop, out in engine(first):
            flat, tdef = jax.tree_util.tree_flatten(out)
            if out_leaves is None:
                out_def = tdef
                out_leaves = [np.empty((n,) + x.shape[1:], x.dtype) for x in flat]
            for dst, src in zip(out_leaves, flat, strict=True):
                dst[start:stop] = src
            if writer:
                rows.append(format_rows(start, stop, out), stop - start)
            if bar is not None:
                bar.update(stop, final=stop == n)
            if on_chunk is not None:
                on_chunk(stop, n)
    except BaseException:
        if writer:
            rows.abandon()
        raise
    if writer:
        rows.close()
    return jax.tree_util.tree_unflatten(out_def, out_leaves)


def sweep_map(fn: Callable, inputs, *, batch_size: int | None = None):
    """Differentiable sweep: ``fn`` on every row of ``inputs``, all in JAX.

    ``jax.lax.map(fn, inputs, batch_size=batch_size)``: rows are processed
    ``batch_size`` at a time by ``jax.vmap(fn)`` inside a ``lax.scan`` (the
    remainder by one more vmap), so the working memory of the forward pass is
    that of one batch.  With ``batch_size=None`` (default) all rows go through
    one ``jax.vmap(fn)``, the fastest for the small sweeps this is meant for.
    Reverse-mode gradients store the residuals of every row either way.

    Nothing leaves the device, so ``jax.jit``, ``jax.grad`` and ``jax.vmap``
    compose with it, e.g. ``jax.grad(lambda s: sweep_map(f, rows(s))[...].mean())``.
    It runs on the default device; to shard it, ``jax.jit`` the caller with
    ``in_shardings`` on the rows (and ``batch_size=None``).

    **Arguments:** `fn` and `inputs` as in `sweep`; `batch_size`: rows
    per vmapped step (integer > 0) or None.

    **Returns:** the output pytree of ``fn``, leaves stacked to JAX arrays of
    leading length ``N``; for a pandas DataFrame of rows, a DataFrame (as
    in `sweep`).
    """
    if is_dataframe(inputs):
        out = sweep_map(fn, frame_columns(inputs), batch_size=batch_size)
        return to_frame(out, inputs.index, "a sweep over a DataFrame")
    n, _, _ = _rows(inputs)
    if batch_size is None:
        return jax.vmap(fn)(inputs)
    batch_size = integer("batch_size", batch_size)
    return jax.lax.map(fn, inputs, batch_size=min(batch_size, n))
