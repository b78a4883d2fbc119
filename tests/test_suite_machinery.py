"""The test suite's own machinery (tests/conftest.py): what it relies on in
JAX's private caches still holds."""

import jax
import jax.numpy as jnp
from conftest import _release_programs
from jax._src import pjit
from jax._src.interpreters import pxla


def test_releasing_programs_drops_the_executables_and_keeps_the_trace():
    """`_release_programs` (after every test module) must drop the compiled
    programs, which hold the memory maps a long run exhausts, and keep the
    traced jaxprs, which a later module reuses.  Checked on one jitted
    function: after the release its dispatch cache and the caches of lowered
    and compiled programs are empty, and calling it again compiles it
    without tracing it again (the Python body runs once in all)."""
    traced = []

    @jax.jit
    def f(x):
        traced.append(1)
        return jnp.sin(x) * 2.0

    x = jnp.arange(3.0)
    first = f(x)
    assert f._cache_size() == 1
    assert pxla._cached_compilation.cache_info().currsize > 0
    _release_programs()
    assert f._cache_size() == 0
    assert pjit._pjit_lower.cache_info().currsize == 0
    assert pxla._cached_compilation.cache_info().currsize == 0
    assert (f(x) == first).all() and f._cache_size() == 1
    assert len(traced) == 1
