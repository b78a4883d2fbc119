"""Shared fixtures.  The physics is tested in float64: diffimpact leaves JAX's
configuration to its host program, so the test suite (the host here) enables
it before any array exists."""

import math
import os
import pathlib

# One persistent compilation cache for the whole run: the two xdist workers
# and every subprocess (notebooks, CLI runs) load a program another has
# compiled instead of compiling it again (the same ball-prism fit, say, is
# compiled by four tests).  It lives in the ignored .pytest_cache, so a fresh
# clone starts cold; set JAX_COMPILATION_CACHE_DIR to put it elsewhere.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    str(pathlib.Path(__file__).parent.parent / ".pytest_cache" / "jax"),
)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
# The command line's own cache (diffimpact._cli._jax_setup.use_compilation_cache): the
# same folder, never the user's home.
os.environ.setdefault("DIFFIMPACT_CACHE_DIR", os.environ["JAX_COMPILATION_CACHE_DIR"])
# XLA's faster-compiling CPU code generator, as the command line uses it
# (diffimpact._cli._jax_setup.use_fast_compile): the suite's time is mostly
# compiling, 8:45 against 12:21 under XLA's defaults (measured 2026-11-29,
# jaxlib 0.10.2).  Every bound holds under either; DIFFIMPACT_XLA_DEFAULTS=1
# runs the suite with XLA's defaults.  Subprocesses (the CLI, notebooks)
# inherit the flags.  Importing diffimpact computes nothing, so XLA reads them.
from diffimpact._cli._jax_setup import use_fast_compile  # noqa: E402

use_fast_compile()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import diffimpact as di  # noqa: E402

# Tight event solve: the exact phase-switching reference of the smooth method.
TIGHT = di.SolverSettings(rtol=1e-13, atol=1e-15)

# Steel sphere, R = 5 mm (the reference impact).
RADIUS = 5e-3
MASS = 4.0 / 3.0 * math.pi * RADIUS**3 * 7850.0


# The ball-prism ball of Alaci et al. (19 mm bearing ball dropped 0.29 m on a
# hard prism), the ball of the sharp stick/slip reference's tests.
BALL = di.Material(208e9, 0.3, 2e9)
PRISM = di.Material(205e9, 0.29, 2e9)
BALL_RADIUS = 9.5e-3
BALL_MASS = 4.0 / 3.0 * math.pi * BALL_RADIUS**3 * 7850.0
DROP_HEIGHT = 0.29


def steel(yield_strength=300e6, youngs_modulus=210e9, poisson_ratio=0.3):
    return di.Material(youngs_modulus, poisson_ratio, yield_strength, 7850.0)


def sphere(velocity=1.0, yield_strength=300e6, **kw):
    """Steel sphere on a steel flat of the same material (JG tests)."""
    mat = steel(yield_strength)
    return di.scenes.NormalImpact(
        mass=kw.get("mass", MASS),
        radius=kw.get("radius", RADIUS),
        body=mat,
        flat=mat,
        velocity=velocity,
        gravity=kw.get("gravity", 0.0),
    )


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.abs(a - b) / np.abs(b)


def grad_and_central_difference(f, x, h, differenced=None):
    """``(df/dx, central difference)`` at the scalar ``x``, step ``h``: the
    gradient by ``jax.grad`` of ``f``, the difference of ``differenced``
    (default ``f``; e.g. the same quantity from a tighter solve).  Both
    jitted, the two differenced solves in one vmapped program: run eagerly,
    every operation around a solve is dispatched (and its pieces compiled)
    one by one."""
    g = float(jax.jit(jax.grad(f))(x))
    up, down = jax.jit(jax.vmap(differenced or f))(jnp.array([x + h, x - h]))
    return g, float(up - down) / (2 * h)


def assert_grad_matches_fd(f, p0, reference, tol=1e-5, step=1e-4):
    """``jax.grad(f)(p0)`` (default settings) against central differences of
    ``f(p, reference)`` (reference settings), relative step ``step`` each.
    Both jitted, the differences' solves in one vmapped program: run eagerly,
    every operation around the solves is dispatched one by one."""
    g = np.asarray(jax.jit(jax.grad(f))(p0))
    assert np.all(np.isfinite(g))
    h = step * np.abs(np.asarray(p0))
    points = jnp.concatenate([p0 + np.diag(h), p0 - np.diag(h)])
    out = np.asarray(jax.jit(jax.vmap(lambda p: f(p, reference)))(points))
    n = p0.shape[0]
    for k in range(n):
        fd = float(out[k] - out[n + k]) / (2 * h[k])
        assert rel(g[k], fd) < tol, (k, g[k], fd)


@pytest.fixture(autouse=True, scope="session")
def _x64():
    assert jax.config.jax_enable_x64, "the test suite runs in float64"


def sharp_reference():
    """``benchmarks/sharp_stickslip.py``, the event-based stick/slip reference
    (scipy), loaded once per process."""
    import importlib.util
    import sys

    name = "sharp_stickslip"
    if name not in sys.modules:
        path = pathlib.Path(__file__).parents[1] / "benchmarks" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module, keep its traces.
    A worker compiles thousands of programs (eager operations included),
    each XLA CPU executable holds a few memory maps (4 for a tiny one,
    measured), and a process near the kernel's limit (vm.max_map_count,
    65,530 by default) crashes inside the compiler: seen three times as a
    segfault in backend_compile late in a quiet fresh-clone run.  What a
    later module runs again is loaded from the persistent cache.  Keeping
    the programs until a worker held 20,000 maps (tried 2026-11-29) made the
    default tier slower, 13:19 against 12:11: the tests of many eager
    operations ran 40-60 % longer beside the larger caches.  The traced
    jaxprs (no memory maps) stay: a library function a later module calls
    with the same signature (`simulate`'s, `fit`'s programs) is not traced
    again, only lowered and loaded.  Against `jax.clear_caches()` after each
    module: 9:54 against 10:22 on clean clones of the default tier, 1,150 s
    against 1,211 s of test time (2026-12-06).  These are JAX's private
    caches (jax 0.10): if one moves, tests/test_suite_machinery.py fails and
    `jax.clear_caches()` is the fallback."""
    yield
    _release_programs()


def _release_programs():
    from jax._src import dispatch, pjit
    from jax._src.interpreters import pxla
    from jax._src.lib import _jax

    pjit._pjit_lower.cache_clear()  # lowered computations, with their executables
    pxla._cached_compilation.cache_clear()
    dispatch.xla_primitive_callable.cache_clear()  # eager operations
    pjit._cpp_pjit_cache_fun_only.clear()  # the C++ dispatch caches
    pjit._cpp_pjit_cache_explicit_attributes.clear()
    _jax.PjitFunctionCache.clear_all()


_EXTENDED = pathlib.Path(__file__).with_name("extended.txt")
TIERS = pytest.StashKey[tuple]()


def _tier(item) -> str:
    for tier in ("extended", "stress"):
        if item.get_closest_marker(tier):
            return tier
    return "default"


# Seconds each test file took in the default tier (a full run on 2 cores,
# 2026-11-29, `--durations=0`; the files of tests moved in from the long tier
# since, by those tests' own times), to order the files: `--dist loadfile`
# hands whole files to the two workers as they free up, and with the longest
# first (and `--no-loadscope-reorder`, which would order them by their number
# of tests) the workers finish together; ordered by number of tests, one
# idled its last 40 s.  A file not listed goes first, as if long.
_FILE_SECONDS = {
    "test_multi": 180, "test_docs": 81, "test_body": 75, "test_learned": 58,
    "test_fit": 70, "test_slip": 51, "test_flexible_bar": 60,
    "test_contact_space": 44, "test_partial_slip": 44,
    "test_reliability_io": 39, "test_layer": 35, "test_reliability": 35,
    "test_tangential": 33, "test_references": 32, "test_jackson_green": 31,
    "test_extending": 28, "test_docs_cli": 26, "test_cli_learn": 26,
    "test_resume": 26, "test_sweep": 24, "test_line_contact": 23,
    "test_incline": 22, "test_fit_rows": 21, "test_rigid": 21,
    "test_collinear": 19, "test_stress": 19, "test_bar": 19, "test_link": 18,
    "test_posterior": 18, "test_gradients": 18, "test_cli_fit": 12,
    "test_body_data": 11, "test_hertz": 10, "test_energy": 10,
    "test_compliance": 9, "test_api": 8, "test_invalid_input": 6,
    "test_newcomer": 5, "test_validation": 4, "test_frames": 4,
    "test_suite_machinery": 1,
}  # fmt: skip


def _file_seconds(item) -> float:
    return _FILE_SECONDS.get(pathlib.Path(item.nodeid.split("::")[0]).stem, 1e3)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Mark the tests listed in tests/extended.txt ``extended`` (before
    ``-m`` selects), and refuse a line that names no test: of any file when
    every test file was collected, else of the files collected whole (not
    with node ids on the command line, nor only last run's failures)."""
    listed = {
        line.strip()
        for line in _EXTENDED.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    }
    found = set()
    for item in items:
        if item.nodeid in listed:
            item.add_marker(pytest.mark.extended)
            found.add(item.nodeid)
    files = {item.nodeid.split("::")[0] for item in items}
    every = {f"tests/{p.name}" for p in _EXTENDED.parent.glob("test_*.py")}
    # The tier of every collected test, before -m deselects any, for
    # tests/test_docs_validation.py (which needs the whole suite's).
    config.stash[TIERS] = (
        every <= files,
        {item.nodeid: _tier(item) for item in items},
    )
    if os.environ.get("DIFFIMPACT_TIERS_JSON"):
        import json

        pathlib.Path(os.environ["DIFFIMPACT_TIERS_JSON"]).write_text(
            json.dumps(config.stash[TIERS][1])
        )
    if every <= files:
        missing = listed - found
    elif config.getoption("lf", default=False) or any("::" in a for a in config.args):
        missing = set()
    else:
        missing = {n for n in listed - found if n.split("::")[0] in files}
    if missing:
        raise pytest.UsageError(
            f"tests/extended.txt names tests that do not exist: {sorted(missing)}"
        )
    # longest files first (a stable sort: each file's tests stay together and
    # in order)
    items.sort(key=lambda item: -_file_seconds(item))
