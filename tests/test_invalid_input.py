"""Bad values of the Python API, a table of them under every way of calling
(the newcomer trial): ``equinox.filter_jit`` and plain ``jax.jit`` raise with the
field and the value, a jitted ``vmap`` names the row too, an eager ``vmap``
and `sweep` raise `InvalidInputError` (a ``ValueError``), and with
``throw=False`` nothing raises: the bad row gets ``invalid_input`` and NaN
outputs, the other rows keep their bits.

One function solves both scenes of the table (a sphere on a flat head-on,
and obliquely with Coulomb friction, both by quadrature: no ODE), so the
whole table costs one compilation per way of calling.
"""

import functools
import logging
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

M, R = 4.0 / 3.0 * math.pi * 5e-3**3 * 7850.0, 5e-3
GOOD = dict(
    b_E=208e9, b_nu=0.3, b_sy=math.inf, b_rho=7850.0,
    f_E=205e9, f_nu=0.29, f_sy=355e6, f_rho=7850.0,
    mass=M, radius=R, velocity=1.0,
    angle=0.5, height=0.29, mu=0.2,
)  # fmt: skip
KEYS = list(GOOD)
BASE = np.asarray(list(GOOD.values()))

# (field, bad value, the check's message)
BAD = [
    ("f_nu", 0.9, "`Material.poisson_ratio"),
    ("f_nu", 0.5, "`Material.poisson_ratio"),
    ("b_nu", -2.0, "`Material.poisson_ratio"),
    ("b_E", -1.0, "`Material.youngs_modulus"),
    ("b_E", math.nan, "`Material.youngs_modulus"),
    ("f_E", 0.0, "`Material.youngs_modulus"),
    ("f_sy", -1.0, "`Material.yield_strength"),
    ("f_sy", math.nan, "`Material.yield_strength"),
    ("f_rho", 0.0, "`Material.density"),
    ("mass", -1.0, "`NormalImpact.mass"),
    ("mass", math.nan, "`NormalImpact.mass"),
    ("radius", -R, "`NormalImpact.radius"),
    ("radius", math.inf, "`NormalImpact.radius"),
    ("velocity", math.nan, "`NormalImpact.velocity"),
    ("velocity", -1.0, "`NormalImpact.velocity"),
    ("velocity", 0.0, "`NormalImpact.velocity"),
    ("angle", 1.6, "`SphereOnIncline.incline"),
    ("angle", -0.1, "`SphereOnIncline.incline"),
    ("angle", math.nan, "`SphereOnIncline.incline"),
    ("height", -0.1, "`SphereOnIncline.height"),
    ("height", 0.0, "`SphereOnIncline.height"),
    ("mu", -0.1, "`Friction.mu"),
    ("mu", math.nan, "`Friction.mu"),
    ("mu", math.inf, "`Friction.mu"),
    ("f_nu", math.nan, "`Material.poisson_ratio"),
    ("b_rho", -1.0, "`Material.density"),
]
INVALID = int(di.RESULTS.invalid_input._value)


def _row(field, value):
    x = BASE.copy()
    x[KEYS.index(field)] = value
    return x


def _expected(field, value, message, row=""):
    """The message's start: the check, then the value (and the row)."""
    import re

    return re.escape(f"{message}") + r".* \(got " + re.escape(f"{value!r}{row})")


def run(x, throw=True):
    """(contact time head-on, tangential COR obliquely, result codes)."""
    p = dict(zip(KEYS, x, strict=True))
    body = di.Material(p["b_E"], p["b_nu"], p["b_sy"], p["b_rho"])
    flat = di.Material(p["f_E"], p["f_nu"], p["f_sy"], p["f_rho"])
    law = di.Hertz()  # (the cheapest to compile; laws' checks: test_reliability)
    head_on = di.scenes.NormalImpact(
        p["mass"], p["radius"], body, flat, velocity=p["velocity"]
    )
    oblique = di.scenes.SphereOnIncline(
        M, R, body, flat, incline=p["angle"], height=p["height"]
    )
    a = di.simulate(head_on, law, "quadrature", throw=throw)
    b = di.simulate(
        oblique, law, "quadrature", friction=di.Friction(p["mu"]), throw=throw
    )
    return a.contact_time, b.extras["cor_tangential"], jnp.stack([a.code, b.code])


@pytest.fixture(autouse=True)
def _no_callback_log(caplog):
    """No traceback of JAX's ("jax.pure_callback failed") reaches the log
    for a diffimpact error: the exception carries the message."""
    with caplog.at_level(logging.ERROR, logger="jax._src.callback"):
        yield
    logged = [r for r in caplog.records if "pure_callback" in r.getMessage()]
    assert not logged


def _raises(f, x, expected, pattern):
    with pytest.raises(expected, match=pattern) as info:
        jax.block_until_ready(f(jnp.asarray(x)))
    return info.value


def test_table_under_jit():
    """Each bad value under plain jax.jit: JAX's own runtime error
    (JaxRuntimeError, or ValueError once the compiled function has run: JAX
    GitHub issue 34083), whose text ends with the check's message, the field and
    the value."""
    f = jax.jit(run)
    assert np.all(np.isfinite(np.asarray(f(jnp.asarray(BASE))[:2])))
    errors = (jax.errors.JaxRuntimeError, ValueError)
    for field, value, message in BAD:
        _raises(f, _row(field, value), errors, _expected(field, value, message))


def test_table_under_filter_jit_and_vmap_names_the_row():
    """Under equinox.filter_jit: EquinoxRuntimeError, and in a batch the
    row is named; an eager vmap, where diffimpact runs the program itself,
    raises InvalidInputError (a ValueError)."""
    batched = eqx.filter_jit(jax.vmap(run))

    def f(x):
        return batched(jnp.stack([BASE, x, BASE]))

    for field, value, message in BAD:
        pattern = _expected(field, value, message, ", row 1 of 3")
        _raises(f, _row(field, value), eqx.EquinoxRuntimeError, pattern)

    head_on = functools.partial(_head_on, throw=True)
    with pytest.raises(di.InvalidInputError, match=r"got 0\.9, row 1 of 3\)"):
        jax.vmap(head_on)(jnp.array([0.3, 0.9, 0.2]))


def _head_on(nu, throw):
    plate = di.Material(205e9, nu)
    scene = di.scenes.NormalImpact(M, R, di.Material(208e9, 0.3), plate, velocity=1)
    r = di.simulate(scene, di.Hertz(), "quadrature", throw=throw)
    return r.cor_newton, r.code


def test_table_with_throw_false():
    """The whole table in one batch with throw=False: nothing raises, each
    bad row has the code invalid_input and NaN outputs, and the good rows
    between them have the bits they have in a batch without bad rows."""
    batched = jax.jit(jax.vmap(functools.partial(run, throw=False)))
    good = [_row("velocity", 0.5 + 0.1 * k) for k in range(len(BAD))]
    rows, clean = [], []
    for k, (field, value, _) in enumerate(BAD):
        rows += [good[k], _row(field, value)]
        clean += [good[k], BASE]
    t, cor_t, codes = map(np.asarray, batched(jnp.asarray(np.stack(rows))))
    t0, cor_t0, codes0 = map(np.asarray, batched(jnp.asarray(np.stack(clean))))
    bad = np.arange(1, len(rows), 2)
    names = {di.result_name(c) for c in codes[bad].max(axis=1)}
    assert names == {"invalid_input"}, names
    assert np.all(np.isnan(t[bad]) | (codes[bad, 0] != INVALID))
    assert np.all(np.isnan(cor_t[bad]) | (codes[bad, 1] != INVALID))
    # each bad field is seen by the solve that uses it
    for k, (field, _, _) in enumerate(BAD):
        where = {"angle", "height", "mu"}
        used = [field not in where, field not in {"mass", "radius", "velocity"}]
        assert list(codes[bad[k]] == INVALID) == used, field
    assert np.all(codes0 == 0) and np.all(codes[::2] == 0)
    for a, b in [(t, t0), (cor_t, cor_t0)]:
        assert np.array_equal(a[::2], b[::2])  # bit for bit

    # the scans: a Poisson ratio and an angle
    cor, codes = jax.vmap(functools.partial(_head_on, throw=False))(
        jnp.array([0.3, 0.9, 0.2])
    )
    assert [di.result_name(c) for c in codes] == [
        "successful",
        "invalid_input",
        "successful",
    ]
    assert np.isnan(cor[1]) and np.all(np.isfinite(cor[::2]))


def test_a_failure_known_when_compiling_still_raises_its_message():
    """A bad value known when the program is compiled (Python floats under
    filter_jit, a constant closed over by jax.jit) must still raise its own
    message, not return NaN or another failure's message: a check placed
    where constant folding can remove it (after the outputs are masked to a
    constant NaN, say) would pass the rest of the table and fail here."""
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"poisson_ratio.*got 0\.6\)"):
        eqx.filter_jit(_head_on)(0.6, True)
    scene = di.scenes.NormalImpact(
        M, R, di.Material(208e9, 0.3), di.Material(205e9, 0.3), velocity=1.0
    )
    bad = eqx.tree_at(lambda s: s.flat.poisson_ratio, scene, jnp.asarray(0.9))
    closed_over = jax.jit(lambda: di.simulate(bad, di.Hertz(), "quadrature").cor_newton)
    with pytest.raises(
        (jax.errors.JaxRuntimeError, ValueError), match=r"poisson_ratio.*got 0\.9\)"
    ):
        jax.block_until_ready(closed_over())


def test_throw_false_eagerly_gives_the_code():
    """Eagerly, a value check made by the solve (here on a scene built by
    eqx.tree_at, which skips the constructor) is a code with throw=False,
    as in a batch; the constructor itself raises InvalidInputError, a
    ValueError, since it has no result to carry a code."""
    with pytest.raises(di.InvalidInputError, match=r"poisson_ratio.*got 0\.9\)"):
        di.Material(205e9, 0.9)
    assert issubclass(di.InvalidInputError, ValueError)
    scene = di.scenes.NormalImpact(
        M, R, di.Material(208e9, 0.3), di.Material(205e9, 0.3), velocity=1.0
    )
    bad = eqx.tree_at(lambda s: s.flat.poisson_ratio, scene, jnp.asarray(0.9))
    r = di.simulate(bad, di.Hertz(), "quadrature", throw=False)
    assert di.result_name(r.code) == "invalid_input"
    assert np.isnan(r.cor_newton) and np.isnan(r.contact_time)
    with pytest.raises(di.InvalidInputError, match=r"got 0\.9\)"):
        di.simulate(bad, di.Hertz(), "quadrature")
    # rigid impacts likewise
    oblique = di.scenes.SphereOnIncline(
        M, R, di.Material(208e9, 0.3), di.Material(205e9, 0.3), incline=0.5,
        height=0.3,
    )  # fmt: skip
    out = di.rigid_impact(oblique, -0.1, 0.8, throw=False)
    assert di.result_name(out["result"]._value) == "invalid_input"
    assert np.isnan(out["cor_newton"])
    with pytest.raises(di.InvalidInputError, match=r"`mu`.*got -0\.1\)"):
        di.rigid_impact(oblique, -0.1, 0.8)


def test_sweep_names_the_row():
    """di.sweep: with throw=True a bad row raises InvalidInputError naming
    the sweep's row; normal_impact's default throw=False gives it a code."""
    columns = {"poisson_ratio": np.array([0.3, 0.3, 0.9, 0.2])}
    strict = functools.partial(di.normal_impact_row, law=di.Hertz(), throw=True)
    with pytest.raises(di.InvalidInputError, match=r"got 0\.9, row 2 of 4\)"):
        di.sweep(strict, columns, chunk_size=2)
    out = di.sweep(functools.partial(di.normal_impact_row, law=di.Hertz()), columns)
    assert [di.result_name(c) for c in out["result"]] == [
        "successful",
        "successful",
        "invalid_input",
        "successful",
    ]
    assert np.isnan(out["max_force"][2]) and np.all(np.isfinite(out["max_force"][:2]))
    # a row called eagerly, as in a Python loop: the same code
    row = di.normal_impact_row({"poisson_ratio": 0.9}, law=di.Hertz())
    assert di.result_name(row["result"]) == "invalid_input"
