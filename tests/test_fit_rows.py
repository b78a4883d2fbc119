"""Least squares over many rows (`diffimpact._inference._lsq`): row blocks on threads,
rows in solving order, the warm start on a subsample, and the central
differences that replace diverged forward-mode derivatives.  Normal impacts
on the quadrature path: exact and cheap, so every check is to rounding."""

import dataclasses

import diffrax
import numpy as np
import pytest

import diffimpact as di
from diffimpact._inference import _fit as _fit_module
from diffimpact._inference import _lsq, _row_blocks
from diffimpact._inference._fit_problem import prepare, with_adjoint
from diffimpact._inference._residuals import _predictions, _value_and_jacobian

VELOCITIES = np.linspace(0.2, 3.0, 24)


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    """24 normal impacts at S_y = 400 MPa, COR and contact time with 0.5 %
    seeded noise (so the optimum has non-zero residuals)."""
    exp = di.Experiment.default("normal_impact")
    rng = np.random.default_rng(3)
    cols = {"impact_velocity_m_s": VELOCITIES}
    out = [di.predict(exp, {"impact_velocity": v}) for v in VELOCITIES]
    for key, col, scale in (
        ("cor_normal", "cor_normal", 1.0),
        ("contact_time", "contact_time_us", 1e6),
    ):
        clean = np.array([float(o[key]) for o in out]) * scale
        cols[col] = clean * (1 + 0.005 * rng.standard_normal(len(clean)))
    path = tmp_path_factory.mktemp("rows") / "noisy.csv"
    di.write_experiments(path, cols, scene="normal_impact", provenance="test")
    return path, exp


def _problem(path, exp, chunk):
    data, problem, u0, _, _ = prepare(
        path, exp, ("yield_strength",), {"yield_strength": 300e6}, None, None, chunk
    )
    return data, with_adjoint(problem, diffrax.ForwardMode()), u0


def test_blocks_in_any_order_give_the_rows_predictions(noisy):
    """Three blocks of a shuffled order, one thread each, padded to equal
    length: every row's prediction, code and step count back in its place,
    identical to one program over the file (chunk composition does not enter
    a quadrature row)."""
    data, problem, u0 = _problem(*noisy, 4)
    order = np.random.default_rng(0).permutation(data.n)
    blocks = _row_blocks.RowBlocks(problem, order, 3)
    try:
        got = blocks.predictions(u0)
        r, jac = blocks.map(_row_blocks._block_values_and_jacobian, u0)
    finally:
        blocks.close()
    want = _predictions(problem, u0)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, np.asarray(w))
    jac_w, r_w = _value_and_jacobian(u0, problem)
    np.testing.assert_allclose(r.reshape(-1), np.asarray(r_w), rtol=0, atol=1e-14)
    np.testing.assert_allclose(jac.reshape(-1, 1), np.asarray(jac_w), rtol=1e-12)
    with pytest.raises(ValueError, match="permutation"):
        _row_blocks.RowBlocks(problem, order[:-1], 2)


def test_central_differences_replace_flagged_rows(noisy, monkeypatch):
    """Every row flagged (threshold below 1): the Jacobian from central
    differences of the predictions agrees with forward mode to 1e-6 (step
    1e-4 in log S_y: truncation ~1e-8, rounding of the quadrature ~1e-12 /
    1e-4), and the count of differenced rows says so."""
    data, problem, u0 = _problem(*noisy, 8)
    blocks = _row_blocks.RowBlocks(problem, np.arange(data.n), 2)
    try:
        exact = blocks.evaluate(u0)
        monkeypatch.setattr(_row_blocks, "_DIVERGED", 0.5)
        fd = blocks.evaluate(u0)
    finally:
        blocks.close()
    assert int(np.sum(exact.differenced)) == 0
    assert int(np.sum(fd.differenced)) > data.n // 2  # all rows above half the median
    np.testing.assert_array_equal(fd.residual, exact.residual)
    err = np.abs(np.asarray(fd.jacobian) - np.asarray(exact.jacobian))
    assert np.max(err / np.abs(np.asarray(exact.jacobian))) < 1e-6


def test_forward_differences_give_the_forward_mode_jacobian(noisy, monkeypatch):
    """``jacobian="differences"``: the residuals are forward mode's to
    rounding (another program), the Jacobian within 1e-4 of its RMS (step
    1e-5 in log S_y: truncation ~h/2 times the log-curvature, the
    quadrature's rounding ~1e-12 / 1e-5; measured 2.2e-5), and no row is counted as
    differenced (that count is of rows whose forward mode diverged).  A row
    predicted at the point but failing at the shifted one gets forward mode's
    derivatives (forced here for row 5)."""
    data, problem, u0 = _problem(*noisy, 4)
    exact_blocks = _row_blocks.RowBlocks(problem, np.arange(data.n), 3)
    blocks = _row_blocks.RowBlocks(
        problem, np.arange(data.n), 3, jacobian="differences"
    )
    try:
        exact = exact_blocks.evaluate(u0)
        fd = blocks.evaluate(u0)
        real = _row_blocks._predictions

        def failing_when_shifted(block, u):
            pred, codes, steps = real(block, u)
            if float(u[0]) != float(u0[0]):
                rows = np.asarray(block.inputs["impact_velocity"])
                codes = np.where(rows == VELOCITIES[5], 1, np.asarray(codes))
            return pred, codes, steps

        monkeypatch.setattr(_row_blocks, "_predictions", failing_when_shifted)
        fallback = blocks.evaluate(u0)
    finally:
        exact_blocks.close()
        blocks.close()
    np.testing.assert_allclose(fd.residual, exact.residual, rtol=0, atol=1e-14)
    assert int(np.sum(fd.differenced)) == 0
    want = np.asarray(exact.jacobian)
    err = np.abs(np.asarray(fd.jacobian) - want) / np.sqrt(np.mean(want**2))
    assert np.max(err) < 1e-4, np.max(err)
    k = np.asarray(problem.mask).shape[1]
    got = np.asarray(fallback.jacobian)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got[5 * k : 6 * k], want[5 * k : 6 * k], rtol=1e-12)
    assert np.max(np.abs(got[: 5 * k] - want[: 5 * k]) / np.abs(want[: 5 * k])) > 0


def test_one_flagged_row_is_differenced_alone(noisy, monkeypatch):
    """One row flagged, in one of three blocks: its 2 p perturbed solves run
    side by side with the other blocks skipped; that row's Jacobian agrees
    with forward mode to 1e-6 (as above) and every other row's is forward
    mode's own."""
    data, problem, u0 = _problem(*noisy, 4)
    blocks = _row_blocks.RowBlocks(problem, np.arange(data.n), 3)
    try:
        exact = blocks.evaluate(u0)
        monkeypatch.setattr(_row_blocks, "_diverged_rows", lambda *a: np.array([5]))
        fd = blocks.evaluate(u0)
    finally:
        blocks.close()
    assert int(np.sum(fd.differenced)) == 1
    k = np.asarray(problem.mask).shape[1]
    got, want = np.array(fd.jacobian), np.asarray(exact.jacobian)
    row = slice(5 * k, 6 * k)
    assert np.max(np.abs(got[row] - want[row]) / np.abs(want[row])) < 1e-6
    got[row] = want[row]
    np.testing.assert_array_equal(got, want)


def test_an_update_recomputes_the_rows_that_left_the_linear_model(noisy):
    """`RowBlocks.update` at a point near the base: residuals identical to a
    full evaluation there; the Jacobian recomputed (to forward mode's own
    value at the new point) exactly for the rows whose residuals departed from
    the base's linear model by more than `_REFRESH` times the median row,
    the base's for the others.  One row is made to depart (its base residual
    shifted by 1, far above the others' curvature over the step, ~1e-3); with
    more than a quarter of the rows departing, or one not finite, the full
    evaluation."""
    data, problem, u0 = _problem(*noisy, 4)
    blocks = _row_blocks.RowBlocks(problem, np.arange(data.n), 3)
    u1 = u0 + 0.02
    try:
        base, exact = blocks.evaluate(u0), blocks.evaluate(u1)
        k = np.asarray(problem.mask).shape[1]
        shifted = np.array(base.residual)
        shifted[5 * k] += 1.0
        moved = _row_blocks._Evaluated(shifted, base.jacobian, base.differenced)
        got = blocks.update(u1, u0, moved, (1.0, 1.0))  # no secant step
        many = np.array(base.residual)
        many[: 10 * k] += 1.0  # 10 of the 24 rows
        everything = _row_blocks._Evaluated(many, base.jacobian, base.differenced)
        full = blocks.update(u1, u0, everything, (1.0, 1.0))
        real = blocks.predictions

        def one_nan(u):  # a row whose prediction is NaN at the trial point
            pred, codes, steps = real(u)
            pred = np.array(pred)
            pred[7] = np.nan
            return pred, codes, steps

        blocks.predictions = one_nan
        fallback = blocks.update(u1, u0, base, (1.0, 1.0))
    finally:
        blocks.close()
    np.testing.assert_array_equal(fallback.jacobian, exact.jacobian)
    np.testing.assert_allclose(got.residual, exact.residual, rtol=0, atol=1e-15)
    jac, want, old = (np.array(x.jacobian) for x in (got, exact, base))
    row = slice(5 * k, 6 * k)
    np.testing.assert_allclose(jac[row], want[row], rtol=1e-12)
    assert np.max(np.abs(old[row] / want[row] - 1)) > 1e-3  # it did change
    jac[row] = old[row]
    np.testing.assert_array_equal(jac, old)
    np.testing.assert_array_equal(full.jacobian, exact.jacobian)


def test_the_secant_correction_brings_the_jacobian_to_the_new_point(noisy):
    """A step of 0.02 in log S_y, long in tolerances (1e-6): every row's
    updated derivative is Broyden's, taken to the step's end, exact for
    residuals quadratic over the step, so its error is third order in the
    step: measured <= 9.6e-3 of the change of the derivative over the step
    (the base's error is all of it), bound 2e-2; with the step counted short
    (tolerance 1), the base's."""
    data, problem, u0 = _problem(*noisy, 4)
    blocks = _row_blocks.RowBlocks(problem, np.arange(data.n), 2)
    u1 = u0 + 0.02
    try:
        base, exact = blocks.evaluate(u0), blocks.evaluate(u1)
        long = blocks.update(u1, u0, base, (1e-6, 1e-6))
        short = blocks.update(u1, u0, base, (1.0, 1.0))
    finally:
        blocks.close()
    old, want = np.asarray(base.jacobian), np.asarray(exact.jacobian)
    change = np.abs(want - old)
    assert np.min(change[np.asarray(problem.mask).ravel()]) > 1e-4
    err = np.abs(np.asarray(long.jacobian) - want)
    assert np.max(err / np.maximum(change, 1e-300)) < 2e-2
    np.testing.assert_array_equal(short.jacobian, base.jacobian)
    assert not np.any(np.asarray(long.differenced))


def test_diverged_rows_are_those_far_above_the_median():
    """Per parameter: a row flagged when its derivatives w.r.t. one
    parameter exceed 10 times the median row's, whatever the other column."""
    jac = np.ones((20, 2, 2))
    jac[:, :, 1] = 1e6  # the columns have their own scales
    jac[2] = 1e45  # the size seen in a planar fit
    jac[4, 0, 0] = np.nan
    jac[5, :, 0] = 9.0  # large, but within the spread of correct rows
    jac[6, 1, 0] = 16.0  # a diverged derivative seen: 16 times the median
    jac[7, 0, 1] = 9e6
    mask = np.ones((20, 2), bool)
    np.testing.assert_array_equal(_row_blocks._diverged_rows(jac, mask), [2, 4, 6])
    mask[2] = False  # a row not fitted is never flagged (nor differenced)
    np.testing.assert_array_equal(_row_blocks._diverged_rows(jac, mask), [4, 6])


def test_warm_start_reaches_the_same_optimum(noisy):
    """A warm start on 8 of 24 rows, then all rows: the same estimate and
    error as iterating on all rows from the start (each within 0.1 standard
    errors of the optimum), and the result says how it went.
    The standard errors come from the Jacobian at the last point evaluated,
    which the stopping rules allow a step of up to (1 - theta) / theta
    tolerances or 0.1 standard errors from the optimum: 1.4e-4 apart measured
    (forward mode or forward differences alike; 3.3e-5 before the rule in
    standard errors)."""
    path, exp = noisy
    kw = dict(free="yield_strength", start={"yield_strength": 250e6}, chunk_size=4)
    whole = di.fit(path, exp, subsample=None, **kw)
    warm = di.fit(path, exp, subsample=8, **kw)
    assert whole.subsample == (0, 0) and warm.subsample[0] == 8
    assert 1 <= warm.subsample[1] < warm.iterations
    assert warm.converged and whole.converged
    # each stops within 0.1 standard errors of the optimum (measured apart:
    # 2.2e-3 of one)
    assert abs(warm.values[0] - whole.values[0]) < 0.02 * whole.std_errors[0]
    assert abs(warm.std_errors[0] / whole.std_errors[0] - 1) < 5e-4
    assert "iterations on 8 rows" in warm.summary()
    assert warm.to_dict()["subsample"] == {"rows": 8, "iterations": warm.subsample[1]}
    # the truth lies within the noise: 0.5 % noise on 48 values
    assert abs(warm.values[0] / 400e6 - 1) < 4 * warm.std_errors[0] / 400e6


def test_a_rising_gauss_newton_step_hands_back_to_the_solver(noisy, monkeypatch):
    """After the warm start the fit takes Gauss-Newton steps on every row; a
    trial point whose cost rises hands back to Levenberg-Marquardt from the
    last point.  Forced here (every trial counts as rising): the same optimum
    as the unforced fit, to its tolerance (a few 1e-7 of the log parameter)."""
    path, exp = noisy
    kw = dict(free="yield_strength", start={"yield_strength": 250e6}, chunk_size=4)
    plain = di.fit(path, exp, subsample=8, **kw)
    calls = []
    real = _lsq.least_squares

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        calls.append((args[2], kwargs.get("stop_if_rising", False), out[4]))
        return out

    monkeypatch.setattr(_lsq, "_RISE", -1.0)
    # (without the stop in standard errors, which on these 24 rows stops the
    # Gauss-Newton steps before any trial)
    monkeypatch.setattr(_fit_module, "_WITHIN", 0.0)
    monkeypatch.setattr(_fit_module, "least_squares", spy)
    forced = di.fit(path, exp, subsample=8, **kw)
    assert [c[0] for c in calls] == [
        "levenberg-marquardt",
        "gauss-newton",
        "levenberg-marquardt",
    ]
    assert calls[1][1:] == (True, True)  # guarded, and it rose
    assert forced.converged
    assert abs(forced.values[0] / plain.values[0] - 1) < 1e-6


@pytest.mark.parametrize(
    ("sizes", "settled"),
    [
        ([5000.0, 70.0, 4.0], True),  # 2,000 planar impacts: lands at ~0.25
        ([5000.0, 70.0], False),  # one ratio is not enough
        ([100.0, 60.0, 1.5], False),  # slow contraction: 1.5 * 0.6 / 0.4
        ([100.0, 10.0, 8.0], False),  # the last ratio 0.8: not converging
        ([0.0, 10.0, 0.5], False),  # a zero step: no ratio
    ],
)
def test_the_linear_convergence_stopping_rule(sizes, settled):
    assert _lsq._settled(sizes) is settled


def test_the_step_left_in_standard_errors():
    """`_standard_errors_left` is the Gauss-Newton step's length in the
    covariance's metric: ``sqrt(step^T C^-1 step)`` with ``C = s^2 (J^T
    J)^-1``, ``s^2 = |r|^2 / dof`` (checked on a random linear problem whose
    rows are all fitted, and with a third of them masked out, where the dof
    counts only the fitted ones); exact data (r = 0) never stop it early."""
    rng = np.random.default_rng(5)
    n, k, p = 30, 2, 3
    jac = rng.standard_normal((n * k, p))
    r = rng.standard_normal(n * k)
    step = -np.linalg.lstsq(jac, r, rcond=None)[0]
    for masked in (0, 10):
        mask = np.ones((n, k), bool)
        mask[:masked] = False
        rr = np.where(mask.ravel(), r, 0.0)
        jj = np.where(mask.ravel()[:, None], jac, 0.0)
        st = -np.linalg.lstsq(jj, rr, rcond=None)[0]
        s2 = rr @ rr / (mask.sum() - p)
        cov = s2 * np.linalg.inv(jj.T @ jj)
        want = np.sqrt(st @ np.linalg.solve(cov, st))
        got = _lsq._standard_errors_left(jj, rr, st, mask)
        assert abs(got / want - 1) < 1e-12, (masked, got, want)
    zero = np.zeros(n * k)
    assert _lsq._standard_errors_left(jac, zero, step, np.ones((n, k), bool)) == np.inf


@pytest.mark.parametrize(
    ("errors", "lands"),
    [
        ([7.7, 0.055], True),  # 2,000 planar impacts: within 0.056
        ([0.055], False),  # a first step: its contraction is unknown
        ([0.2, 0.12], False),  # contraction 0.6: no bound on what is left
        ([0.2, 0.095], False),  # contraction 0.475: within 0.18
        ([1.0, 0.09], True),  # contraction 0.09: within 0.099
        ([0.0, 0.05], False),  # a zero step: no ratio
    ],
)
def test_the_stop_in_standard_errors(errors, lands):
    assert _lsq._lands_within(errors, 0.1) is lands


def test_auto_jacobian_needs_a_scale_for_the_step(noisy):
    """``jacobian="auto"`` differences rows in chunks on a CPU, but not where
    an unbounded parameter starts at 0 (its step would be 1e-5 of its unit)."""
    from diffimpact._inference._fit import _auto_jacobian
    from diffimpact._inference._transforms import make_transform

    _, problem, _ = _problem(*noisy, 4)
    assert _auto_jacobian(problem) == "differences"
    unbounded = make_transform("offset", 0.0, (-np.inf, np.inf))
    assert _auto_jacobian(dataclasses.replace(problem, transforms=(unbounded,))) == (
        "forward-mode"
    )
    started = make_transform("offset", 0.004, (-np.inf, np.inf))
    assert _auto_jacobian(dataclasses.replace(problem, transforms=(started,))) == (
        "differences"
    )
    assert _auto_jacobian(dataclasses.replace(problem, chunk_size=None)) == (
        "forward-mode"
    )


def test_a_bad_jacobian_option_is_named(noisy):
    with pytest.raises(ValueError, match="`jacobian` must be one of"):
        di.fit(noisy[0], noisy[1], "yield_strength", jacobian="reverse")


@pytest.mark.parametrize("bad", [1, 0, -3, 2.5, True, "half"])
def test_a_bad_subsample_is_named(noisy, bad):
    path, exp = noisy
    with pytest.raises(ValueError, match="subsample"):
        di.fit(path, exp, free="yield_strength", subsample=bad)


def test_the_fits_predictions_are_the_models_at_its_estimate(noisy):
    """With the default chunking (sorted rows, one block per core) the fit's
    predictions come back in the file's order and are the model's at the
    estimate.  They are the last evaluation moved by the last (untaken-solve)
    Gauss-Newton step to first order, off by its second-order term: the
    stopping rule (`_settled`) takes a last step of up to (1 - theta) / theta
    tolerances (~1e-5 of the log parameter), so ~1e-10 relative (2e-10
    measured), hence 1e-9."""
    path, exp = noisy
    r = di.fit(path, exp, free="yield_strength", start={"yield_strength": 250e6})
    assert _row_blocks.workers() >= 1 and r.converged
    direct = np.array(
        [
            float(di.predict(r.experiment, {"impact_velocity": v})["cor_normal"])
            for v in VELOCITIES
        ]
    )
    k = r.quantities.index("cor_normal")
    np.testing.assert_allclose(r.predicted[:, k], direct, rtol=1e-9)
    assert np.isfinite(r.std_errors[0])


class _Cliff:
    """Two rows with residuals ``u - 1`` whose solves fail (the sentinel
    residual) beyond ``u = 0.5``: the least-squares optimum lies where
    one row cannot be predicted."""

    mask = np.ones((2, 1), bool)

    def evaluate(self, u):
        import jax.numpy as jnp

        u = float(np.asarray(u)[0])
        r = np.array([u - 1.0, u - 1.0])
        if u > 0.5:
            r[1] = _lsq._FAILED_RESIDUAL
        return _row_blocks._Evaluated(jnp.asarray(r), jnp.ones((2, 1)), jnp.asarray(0))


@pytest.mark.parametrize("solver", ["levenberg-marquardt", "gauss-newton"])
def test_a_fit_stopped_by_failing_rows_has_not_converged(solver):
    """Every trial step past the edge is rejected: the fit stops near the
    edge (u <= 0.5) and reports the failing row, not convergence.  (It used
    to call the stalled cost converged: 8 noiseless rows of a low-inertia
    ellipse gave mu = 0.2602 for a truth of 0.25, 'converged'.)"""
    import jax.numpy as jnp

    u, steps, converged, final, _ = _lsq.least_squares(
        _Cliff(), jnp.asarray([0.0]), solver, 50, 1e-8, 1e-8, None
    )
    assert float(u[0]) <= 0.5 and not converged
    assert list(final[3]) == [1]
    # without the cliff the same solver converges to u = 1
    cliff_free = _Cliff()
    cliff_free.evaluate = lambda u: _row_blocks._Evaluated(
        jnp.asarray(np.full(2, float(np.asarray(u)[0]) - 1.0)),
        jnp.ones((2, 1)),
        jnp.asarray(0),
    )
    u, _, converged, final, _ = _lsq.least_squares(
        cliff_free, jnp.asarray([0.0]), solver, 50, 1e-8, 1e-8, None
    )
    assert converged and abs(float(u[0]) - 1.0) < 1e-8 and not len(final[3])


@pytest.mark.parametrize("solver", ["levenberg-marquardt", "gauss-newton"])
def test_the_optimistix_state_has_the_fields_least_squares_reads(solver):
    """`_lsq.least_squares` steps optimistix's solver by hand and reads
    ``state.y_eval`` (the next trial point) and
    ``state.num_steps_since_acceptance`` (0 when the last step was taken):
    fields of a private state.  pyproject pins optimistix below 0.2; this
    fails first if a release within the range changes the layout.  On a
    linear problem the trial points converge to the least-squares solution
    (Gauss-Newton in one step, damped Levenberg-Marquardt geometrically), so
    the trial point is checked for its value, not only its presence."""
    import jax
    import jax.numpy as jnp
    import optimistix as optx

    a = jnp.array([[2.0, 0.0], [0.0, 3.0], [1.0, 1.0]])
    b = jnp.array([2.0, 6.0, 3.0])

    def fn(u, args):
        return a @ u - b, None

    cls = (
        optx.LevenbergMarquardt if solver == "levenberg-marquardt" else optx.GaussNewton
    )
    s = cls(rtol=1e-10, atol=1e-10)
    u = jnp.zeros(2)
    f_struct, aux_struct = jax.eval_shape(lambda: fn(u, None))
    state = s.init(fn, u, None, {}, f_struct, aux_struct, frozenset())
    for _ in range(12):
        u, state, _ = s.step(fn, u, None, {}, state, frozenset())
    assert int(state.num_steps_since_acceptance) in (0, 1)
    x = np.linalg.lstsq(np.asarray(a), np.asarray(b), rcond=None)[0]
    np.testing.assert_allclose(np.asarray(state.y_eval), x, rtol=1e-8)
