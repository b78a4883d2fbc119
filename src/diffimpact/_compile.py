"""How the library compiles its own programs: ``equinox.filter_jit`` with
XLA's faster-compiling CPU code generator, chosen per program.

XLA's CPU backend generates code by *fusion emitters* by default (since jax
0.5); its older *elemental emitters* compile the same operations faster and
run them no slower here (the model's programs are long chains of small
element-wise operations and loops; measured in benchmarks/RESULTS.md).  A
library must not set ``XLA_FLAGS`` (it is a layer in other people's
programs), but the choice can be made per compiled program, through
``jax.jit``'s ``compiler_options``: it then applies to the programs this
library compiles at its own entry points (`simulate`, `fit`, `predict` of a
file, a posterior's sampler, ...) and to nothing else.  Under the caller's
own ``jax.jit`` these are inlined into the caller's program, which the
caller's options govern.

Not used (the programs compile with XLA's defaults) on a backend other than
the CPU, on a jaxlib series where it was not measured (XLA refuses an option
it does not know, and is retiring this one), when ``XLA_FLAGS`` sets the
emitters itself, or when ``DIFFIMPACT_XLA_DEFAULTS`` is set to anything but
empty or ``0``."""

from __future__ import annotations

import functools
import os

import equinox as eqx
import jax

# The process-wide form of the option, as the command line sets it for itself.
FAST_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"
FAST_COMPILE_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
# the jaxlib series on which the option was measured
FAST_COMPILE_JAXLIB = ("0.10",)


@functools.cache
def jaxlib_series() -> str | None:
    """``"0.10"`` for jaxlib 0.10.x; None when jaxlib's version is unknown."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return ".".join(version("jaxlib").split(".")[:2])
    except PackageNotFoundError:
        return None


def fast_compile_wanted(environ=os.environ) -> bool:
    """Whether this process may use the elemental emitters (see the module's
    docstring): not chosen by ``XLA_FLAGS`` already, not turned off by
    ``DIFFIMPACT_XLA_DEFAULTS``, and a jaxlib series where it was measured."""
    if "xla_cpu_use_fusion_emitters" in environ.get("XLA_FLAGS", ""):
        return False
    if environ.get("DIFFIMPACT_XLA_DEFAULTS", "") not in ("", "0"):
        return False
    return jaxlib_series() in FAST_COMPILE_JAXLIB


def compiler_options(environ=os.environ) -> dict:
    """The ``compiler_options`` of the library's programs now: the fast-
    compiling emitters on the CPU where `fast_compile_wanted`, else none."""
    if jax.default_backend() == "cpu" and fast_compile_wanted(environ):
        return dict(FAST_COMPILE_OPTIONS)
    return {}


def _top_level() -> bool:
    """Whether no JAX transformation is tracing this call: JAX takes
    ``compiler_options`` only on a top-level ``jit`` (a nested one is inlined
    into its caller's program).  Read through JAX's internal
    ``trace_state_clean``; where that is gone, False (XLA's defaults)."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:
        return False
    return bool(trace_state_clean())


def filter_jit(fun):
    """``equinox.filter_jit(fun)``, compiled with `compiler_options` as they
    are at each top-level call (one compiled wrapper per set of options, so a
    process whose backend or environment changes recompiles rather than
    reusing a program compiled for the other); under a transformation
    (``jit``, ``vmap``, ``grad``, ``eval_shape``) without options."""
    jitted: dict = {}

    @functools.wraps(fun)
    def call(*args, **kwargs):
        options = compiler_options() if _top_level() else {}
        key = tuple(sorted(options.items()))
        if key not in jitted:
            jitted[key] = eqx.filter_jit(fun, compiler_options=options or None)
        return jitted[key](*args, **kwargs)

    return call
