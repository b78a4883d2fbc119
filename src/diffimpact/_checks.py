"""Input validation that holds eagerly and under ``jit``, ``vmap`` and ``grad``.

A module whose numbers have a domain (a modulus > 0, a Poisson ratio in
(-1, 0.5), ...) derives from `AbstractValidated` and lists its checks
in ``_checks()``.  They run twice, with the same message:

- at construction, when the values are concrete: ``ValueError`` naming the
  field and the expected form, before anything is traced or solved;
- at the entry of every solve (`guard`), which threads the whole input
  pytree through one ``equinox.branched_error_if``.  The solve then reads the
  guarded values, so the check cannot be removed as dead code (an
  ``equinox.error_if`` whose return value is unused is dropped by JAX), and
  XLA runs it before anything that depends on the inputs: a traced bad value
  raises the same message as an ``EquinoxRuntimeError`` instead of reaching
  the solver.  This is how diffrax guards ``dt0``.  The traced message names
  the offending value and, under ``vmap``, its row: only when a check fails,
  a host callback reads them (`_detail`).

With ``throw=False`` (`guard(..., throw=False)`) no value check raises: the
guard returns whether each row is invalid, and the solve reports it as
``RESULTS.invalid_input`` with NaN outputs.

Where diffimpact runs the computation itself (an eager call, an eager
``vmap``, `diffimpact.sweep`), a traced check's error reaches the user as
`InvalidInputError` (a ``ValueError``).  Inside a user's ``jit`` only JAX
and equinox see the error: ``equinox.filter_jit`` raises
``equinox.EquinoxRuntimeError`` with the message; plain ``jax.jit`` raises
JAX's ``JaxRuntimeError`` (a ``ValueError`` once the compiled function has
run: JAX GitHub issue 34083) whose text ends with the message.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import os
import types
import typing
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from equinox.internal import unvmap_any


class InvalidInputError(ValueError):
    """An input outside its domain (a negative modulus, a Poisson ratio of
    0.9, a NaN speed), with ``throw=True``: the message names the field and
    the value, and under ``vmap`` the row.  A ``ValueError``.  ``result`` is
    ``RESULTS.invalid_input`` where a result code was at hand, else None."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class Check(NamedTuple):
    """One domain check: ``ok`` (a boolean array) must hold for ``value``."""

    value: object
    ok: object
    message: str


def as_float(x):
    """Convert a real number or array to a floating JAX array (ints become
    floats); anything else (None, text, a complex number) is a ``TypeError``."""
    try:
        a = jnp.asarray(x)
    except (TypeError, ValueError):
        raise TypeError(
            f"expected a real number (or array of them), got {x!r} ({type(x).__name__})"
        ) from None
    if jnp.issubdtype(a.dtype, jnp.complexfloating) or a.dtype == jnp.bool_:
        raise TypeError(f"expected a real number, got {x!r} ({a.dtype})")
    if not jnp.issubdtype(a.dtype, jnp.inexact):
        a = a.astype(jnp.result_type(float))
    return a


def require_scalars(tree, what: str) -> None:
    """Every floating-point number of ``tree`` is a scalar: a solve is one
    impact (batches go through ``jax.vmap``, whose tracers are scalars here).
    Raises ``ValueError`` naming the field and its shape."""
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        if eqx.is_inexact_array(leaf) and leaf.ndim != 0:
            name = what + jax.tree_util.keystr(path)
            raise ValueError(
                f"`{name}` has shape {tuple(leaf.shape)}; one solve is one "
                "impact: give scalars, and use jax.vmap for a batch"
            )


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def is_traced(tree) -> bool:
    """Whether any leaf of ``tree`` is a JAX tracer (inside jit/vmap/grad)."""
    return any(_is_traced(x) for x in jax.tree.leaves(tree))


def _unit(unit: str) -> str:
    return f" in {unit}" if unit else ""


def check(value, ok, message: str) -> Check:
    return Check(value, ok, message)


def finite(x, name: str) -> Check:
    return Check(x, jnp.isfinite(x), f"`{name}` must be finite")


def positive(x, name: str, unit: str = "") -> Check:
    return Check(
        x,
        jnp.isfinite(x) & (x > 0),
        f"`{name}` must be a finite number > 0{_unit(unit)}",
    )


def positive_fields(module, units: dict[str, str]) -> list[Check]:
    """`positive` for each field of ``module`` named in ``units`` (field ->
    unit), each check named ``Type.field``."""
    owner = type(module).__name__
    return [positive(getattr(module, f), f"{owner}.{f}", u) for f, u in units.items()]


def nonnegative(x, name: str, unit: str = "") -> Check:
    return Check(
        x,
        jnp.isfinite(x) & (x >= 0),
        f"`{name}` must be a finite number >= 0{_unit(unit)}",
    )


def raise_failed(checks: Iterable[Check]) -> None:
    """Raise ``ValueError`` for the first check that fails whose outcome is
    concrete (traced ones are skipped: `guard` handles them).  The outcome
    decides, not the value: under ``jax.grad`` a comparison of a
    differentiated value is concrete (booleans carry no tangent), and
    skipping it would let a later check on a dependent field (the inertia,
    for a negative mass) speak first."""
    for c in checks:
        if _is_traced(c.ok):
            continue
        if not bool(np.all(np.asarray(c.ok))):
            shown = _show(c.value)
            raise InvalidInputError(c.message + (f" (got {shown})" if shown else ""))


def _show(value) -> str:
    """The value for a message; "" when it is traced with no concrete value
    at hand."""
    while _is_traced(value):
        # a differentiated value carries its concrete primal
        value = getattr(value, "primal", None)
        if value is None:
            return ""
    a = np.asarray(value)
    if a.ndim == 0:
        return repr(a.item())
    # one line: a message is shown whole on one line (the command line's)
    return " ".join(np.array2string(a, threshold=8).split())


class AbstractValidated(eqx.Module):
    """A module with domain checks on its fields (module docstring)."""

    def _checks(self) -> list[Check]:
        return []

    def __check_init__(self):
        # A field declared as another validated module (a scene's `body:
        # Material`, say) must hold one: a string or None there would otherwise
        # surface as an AttributeError deep inside a solve.
        for name, classes, optional in _module_fields(type(self)):
            value = getattr(self, name)
            if not (isinstance(value, classes) or (value is None and optional)):
                want = " or ".join(c.__name__ for c in classes)
                raise TypeError(
                    f"`{type(self).__name__}.{name}` must be a diffimpact.{want}"
                    f"{' or None' if optional else ''}, got {type(value).__name__}"
                )
        raise_failed(self._checks())


@functools.cache
def _module_fields(cls) -> tuple:
    """``(name, classes, optional)`` of the fields of ``cls`` annotated with
    `AbstractValidated` subclasses (``Material``, ``Material | None``)."""
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # an annotation that does not resolve: nothing to check
        return ()
    out = []
    for field in dataclasses.fields(cls):
        hint = hints.get(field.name)
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)
        options = typing.get_args(hint) if union else (hint,)
        classes = tuple(
            o
            for o in options
            if isinstance(o, type) and issubclass(o, AbstractValidated)
        )
        if classes:
            out.append((field.name, classes, type(None) in options))
    return tuple(out)


def collect_checks(tree) -> list[Check]:
    """Every check of every `AbstractValidated` module inside ``tree``, each
    module's parts before the module itself: the order in which they are
    built, and so checked eagerly.  A whole's checks may depend on its parts
    (a body's centre of mass inside its shape), and a bad part (a disk of
    negative radius) must be named, not that symptom."""
    out: list[Check] = []

    def visit(node):
        children = jax.tree.leaves(
            node,
            is_leaf=lambda x: x is not node and isinstance(x, AbstractValidated),
        )
        for child in children:
            if isinstance(child, AbstractValidated):
                visit(child)
        if isinstance(node, AbstractValidated):
            out.extend(node._checks())

    visit(tree)
    return out


def guard(tree, extra: Iterable[Check] = (), *, throw: bool = True):
    """Return ``tree`` with every check of its modules (and ``extra``) applied.

    Concrete failures raise `InvalidInputError` at once.  Traced checks become
    one ``equinox.branched_error_if`` on the whole of ``tree`` (the first
    failing check's message is raised, with the value and the row: `_detail`);
    use the returned tree, never the argument, so the check stays in the
    computation.

    With ``throw=False`` nothing raises: the result is ``(tree, invalid)``,
    ``invalid`` a boolean array (per row under ``vmap``) that is True where a
    check fails, for the solve to report as ``RESULTS.invalid_input``."""
    checks = [*collect_checks(tree), *extra]
    if not throw:
        return tree, invalid(checks)
    raise_failed(checks)
    traced = [c for c in checks if _is_traced(c.ok)]
    if not traced or not any(eqx.is_array(x) for x in jax.tree.leaves(tree)):
        return tree
    bad = jnp.stack([jnp.any(jnp.logical_not(c.ok)) for c in traced])
    index = jnp.argmax(bad)
    # The value and the row are read by a host callback, and only where
    # equinox raises: with EQX_ON_ERROR=nan (a graph to export) or breakpoint
    # the program holds no callback of ours.
    if os.environ.get("EQX_ON_ERROR", "raise") == "raise":
        index = _detail(traced, bad, index)
    messages = _Messages(tuple(c.message for c in traced))
    try:
        return eqx.branched_error_if(tree, jnp.any(bad), index, messages)
    except eqx.EquinoxRuntimeError:
        # Run here (an eager vmap or grad): the documented class.
        if _last.text is None:
            raise
        raise InvalidInputError(_last.text) from None


def invalid(checks: Iterable[Check]):
    """A boolean array, True where any of ``checks`` fails (per row under
    ``vmap``); never raises."""
    flags = [jnp.any(jnp.logical_not(jnp.asarray(c.ok))) for c in checks]
    return jnp.any(jnp.stack(flags)) if flags else jnp.asarray(False)


# --------------------------------------------------------------------------
# A traced check's message: the value and the row, read only on failure
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Messages(Sequence):
    """The messages of one `guard`, handed to ``equinox.branched_error_if``
    (a static, hashable argument).  equinox takes the failing check's message
    by its index on the host, when it raises; this returns the one `_record`
    wrote for that check, with the value and the row."""

    messages: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.messages)

    def __getitem__(self, i):
        text = _details.pop((self.messages, i), None) or self.messages[i]
        _last.text = text
        return text


class _Last:
    """The last message handed to equinox, and its parts (for `guard`'s
    eager re-raise, `raise_as_invalid` and the log filter)."""

    text: str | None = None
    row: tuple | None = None
    batch: tuple | None = None
    value: tuple | None = None  # (the check's message, the value shown)


_last = _Last()
_details: dict = {}


def raise_as_invalid(err: BaseException, first_row: int | None, rows: int) -> None:
    """Raise `InvalidInputError` for ``err`` (a JAX or equinox runtime error
    from a jitted ``vmap`` over rows ``first_row``, ... of a sweep of
    ``rows``; None: rows not known) if it reports a traced input check,
    naming the sweep's row; return otherwise."""
    text = _last.text
    if text is None or _last.value is None or text not in str(err):
        return
    message, shown = _last.value
    batch, row = _last.batch or (), _last.row or ()
    known = len(batch) == 1 and first_row is not None
    where = f", row {first_row + row[0]} of {rows}" if known else ""
    raise InvalidInputError(f"{message} (got {shown}{where})") from None


def _detail(checks: list[Check], bad, index):
    """``index`` (the failing check), after a host callback has written the
    check's message with its value and row, only when a check fails: the
    callback sits in a ``lax.cond`` on the whole batch's failure, so a valid
    input runs none.  The check's index is returned through the callback, so
    equinox's error waits for it."""
    values = [jax.lax.stop_gradient(jnp.asarray(c.value)) for c in checks]
    ndims = tuple(jnp.ndim(v) for v in values)
    messages = tuple(c.message for c in checks)
    out = jax.ShapeDtypeStruct(jnp.shape(index), index.dtype)
    record = functools.partial(_record, messages, ndims, index.dtype)

    def failed(bad, index, values):
        del index
        return jax.pure_callback(record, out, bad, *values, vmap_method="broadcast_all")

    fails = unvmap_any(jnp.any(bad))
    return jax.lax.cond(fails, failed, lambda b, i, v: i, bad, index, values)


def _record(messages, ndims, dtype, bad, *values):
    """On the host, when a check fails: write the failing check's message with
    its value and row (the first failing row, in C order) and return the
    check's index for every row."""
    bad = np.asarray(bad)
    batch = bad.shape[:-1]
    rows = bad.reshape(-1, bad.shape[-1])
    first = int(np.argmax(rows.any(axis=1)))
    i = int(np.argmax(rows[first]))
    try:
        row = tuple(int(k) for k in np.unravel_index(first, batch)) if batch else ()
        value = np.asarray(values[i])
        lead = min(max(value.ndim - ndims[i], 0), len(row))
        at = row[len(row) - lead :]
        at = tuple(k if value.shape[j] > 1 else 0 for j, k in enumerate(at))
        shown = _show(value[at])
        if len(batch) == 1:
            where = f", row {row[0]} of {batch[0]}"
        elif batch:
            where = f", batch element {row} of shape {batch}"
        else:
            where = ""
        _details[(messages, i)] = f"{messages[i]} (got {shown}{where})"
        _last.row, _last.batch, _last.value = row, batch, (messages[i], shown)
    except Exception:  # the check's own message, never a formatting error
        _last.row = _last.batch = _last.value = None
    return np.full(batch, i, dtype)


class _QuietCallback(logging.Filter):
    """JAX logs every exception raised in a host callback with its traceback
    (``jax.pure_callback failed``) before it raises it to the caller; for
    diffimpact's own errors (an input check, a failed solve's code) the
    exception carries the whole message, so the log is dropped."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() != "jax.pure_callback failed" or not record.exc_info:
            return True
        text = str(record.exc_info[1])
        ours = text.startswith("diffimpact: ") or (
            _last.text is not None and text.startswith(_last.text)
        )
        return not ours


logging.getLogger("jax._src.callback").addFilter(_QuietCallback())


_skip_requires = 0


@contextlib.contextmanager
def inputs_guarded():
    """Inside a solve whose entry checked its inputs (`guard`): `require`
    adds no second check.  With ``throw=False`` a bad row reaches the solve
    (its outputs are NaN afterwards), and must not raise there."""
    global _skip_requires
    _skip_requires += 1
    try:
        yield
    finally:
        _skip_requires -= 1


def require_type(value, classes, what: str, *, optional: bool = False) -> None:
    """``TypeError`` "``what``, got TYPE" unless ``value`` is an instance of
    ``classes`` (or None, with ``optional``)."""
    if not (isinstance(value, classes) or (optional and value is None)):
        raise TypeError(f"{what}, got {type(value).__name__}")


def require(x, ok, message: str):
    """Return ``x`` after checking the boolean array ``ok`` (eagerly:
    ``ValueError``; traced: an ``equinox.error_if`` guard on ``x``, so use the
    returned value).  Nothing inside `inputs_guarded`."""
    if _skip_requires:
        return x
    if _is_traced(x) or _is_traced(ok):
        return eqx.error_if(x, jnp.logical_not(ok), message)
    raise_failed([Check(x, ok, message)])
    return x


def require_finite(x, name: str):
    return require(*finite(x, name))


def require_positive(x, name: str, unit: str = ""):
    return require(*positive(x, name, unit))


def require_nonnegative(x, name: str, unit: str = ""):
    return require(*nonnegative(x, name, unit))


def static_positive(owner: str, name: str, value, allow_none=False) -> None:
    """A static (Python) setting: a finite number > 0."""
    if value is None and allow_none:
        return
    ok = (
        isinstance(value, int | float | np.integer | np.floating)
        and not isinstance(value, bool | np.bool_)
        and math.isfinite(value)
    )
    if not (ok and value > 0):
        raise ValueError(f"`{owner}.{name}` must be a finite number > 0, got {value!r}")


def integer(name: str, value, minimum: int = 1) -> int:
    """A Python or NumPy integer (not a bool) >= ``minimum``, as an ``int``;
    ValueError naming ``name`` otherwise.  The one integer check of the
    package: settings, sampler counts, sweep chunks."""
    is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
    if not (is_int and value >= minimum):
        raise ValueError(f"`{name}` must be an integer >= {minimum}, got {value!r}")
    return int(value)


def static_count(owner: str, name: str, value, minimum: int = 1) -> None:
    """A static (Python) integer setting >= ``minimum``."""
    integer(f"{owner}.{name}", value, minimum)


def optional_float(x):
    """``as_float`` that keeps ``None`` (an optional numeric field)."""
    return None if x is None else as_float(x)


def plain_number(value):
    """A NumPy scalar as the Python number it holds (static settings must be
    hashable plain numbers: ``np.float32(1e-6)`` is accepted as ``1e-6``);
    anything else unchanged, for the settings' checks to judge."""
    if isinstance(value, np.integer | np.floating) and not isinstance(value, bool):
        return value.item()
    return value
