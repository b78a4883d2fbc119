"""The command line's own JAX setup, made before its first computation: the
persistent compilation cache's folder and XLA's faster-compiling CPU code
generator.  A program of its own may choose these; the library never does."""

from __future__ import annotations

import os


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
# emitters (the default since jax 0.5): the same operations, rounded
# differently in the last bits at most, compiled faster (measured with jaxlib
# 0.10.2 on 2 cores: a gradient through the planar ODE 14.7 -> 8.9 s of XLA
# compilation, the 2,000-row contact-space fit 11.1 -> 9.4 s in all, the demo
# 9.1 -> 7.7 s) and running no slower.  Only on the jaxlib series where this
# was measured: XLA refuses a flag it does not know, and is retiring this one.
FAST_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"
_FAST_COMPILE_JAXLIB = ("0.10",)


def use_fast_compile(environ=os.environ) -> bool:
    """Append `FAST_COMPILE_FLAG` to ``environ["XLA_FLAGS"]`` (call before
    JAX's first computation); True when it is there.  Not when
    ``DIFFIMPACT_XLA_DEFAULTS=1`` (any value other than empty or ``0``), when
    ``XLA_FLAGS`` sets the emitters already, nor on a jaxlib series other
    than those in `_FAST_COMPILE_JAXLIB`."""
    from importlib.metadata import PackageNotFoundError, version

    flags = environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        return FAST_COMPILE_FLAG in flags.split()
    if environ.get("DIFFIMPACT_XLA_DEFAULTS", "") not in ("", "0"):
        return False
    try:
        series = ".".join(version("jaxlib").split(".")[:2])
    except PackageNotFoundError:
        return False
    if series not in _FAST_COMPILE_JAXLIB:
        return False
    environ["XLA_FLAGS"] = f"{flags} {FAST_COMPILE_FLAG}".strip()
    return True
