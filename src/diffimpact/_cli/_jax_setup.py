"""The command line's own JAX setup, made before its first computation: the
persistent compilation cache's folder and XLA's faster-compiling CPU code
generator for the whole process.  A program of its own may choose these; the
library never sets them process-wide (it chooses the code generator for its
own programs only, `diffimpact._compile`)."""

from __future__ import annotations

import os

from .._compile import FAST_COMPILE_FLAG, fast_compile_wanted


def compilation_cache_dir() -> str | None:
    """Where the command line keeps compiled programs between runs:
    ``$DIFFIMPACT_CACHE_DIR``, else ``$XDG_CACHE_HOME/diffimpact/jax`` (by
    default ``~/.cache/diffimpact/jax``); None when ``DIFFIMPACT_NO_CACHE=1``."""
    if os.environ.get("DIFFIMPACT_NO_CACHE", "") not in ("", "0"):
        return None
    path = os.environ.get("DIFFIMPACT_CACHE_DIR")
    if not path:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(
            os.path.expanduser("~"), ".cache"
        )
        path = os.path.join(base, "diffimpact", "jax")
    return path


def use_compilation_cache() -> str | None:
    """Turn on JAX's persistent compilation cache at
    `compilation_cache_dir` (every program, however quick to compile:
    a cold run compiles dozens); returns the folder, or None."""
    import jax

    path = compilation_cache_dir()
    if path is None:
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


# XLA's CPU code generator by elemental emitters instead of its fusion
# emitters, for every program of the process (the library chooses it for its
# own programs only, `diffimpact._compile`): the same operations, rounded
# differently in the last bits at most, compiled faster and running no
# slower (benchmarks/RESULTS.md).


def use_fast_compile(environ=os.environ) -> bool:
    """Append `FAST_COMPILE_FLAG` to ``environ["XLA_FLAGS"]`` (call before
    JAX's first computation); True when it is there.  Not when
    ``DIFFIMPACT_XLA_DEFAULTS=1`` (any value other than empty or ``0``), when
    ``XLA_FLAGS`` sets the emitters already, nor on a jaxlib series other
    than those in `FAST_COMPILE_JAXLIB`."""
    flags = environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        return FAST_COMPILE_FLAG in flags.split()
    if not fast_compile_wanted(environ):
        return False
    environ["XLA_FLAGS"] = f"{flags} {FAST_COMPILE_FLAG}".strip()
    return True
