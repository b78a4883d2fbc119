"""Bayesian calibration (issue 18): priors, chain diagnostics, the posterior
against least squares, identifiability, bad input."""

import importlib.util
import math
import pathlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di
from diffimpact._inference._diagnostics import ess_bulk, split_rhat
from diffimpact._inference._priors import parse_prior
from diffimpact._inference._transforms import make_transform

DATA_BALL_PRISM = pathlib.Path(__file__).parent.parent / "data" / "ball_prism.csv"
# The normal impact on the quadrature path: a posterior in seconds.
_spec = importlib.util.spec_from_file_location(
    "make_synthetic", DATA_BALL_PRISM.parent / "make_synthetic.py"
)
make_synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_synthetic)
TRUTH = make_synthetic.NORMAL_TRUTH
# 2 chains of 500 draws after 300 warm-up steps
RUN = dict(free=list(TRUTH), num_samples=500, num_warmup=300, num_chains=2, seed=1)


def _noisy_file(path, seed=0):
    """Contact times and CORs of the default normal impact at 8 speeds, with
    1 % Gaussian noise and the sigma columns that say so."""
    return make_synthetic.noisy_normal_impacts(path, seed)


# --- priors and transforms -------------------------------------------------


def test_prior_densities_are_the_textbook_ones():
    """Differences of log densities (the constant drops out) against the
    closed forms."""
    x = np.array([0.3, 1.0, 2.5])
    ln = di.LogNormalPrior(1.2, 0.7)
    ref = -0.5 * (np.log(x / 1.2) / 0.7) ** 2 - np.log(x)
    got = np.asarray(ln.log_prob(jnp.asarray(x)))
    np.testing.assert_allclose(got - got[0], ref - ref[0], rtol=1e-12)
    nm = di.NormalPrior(1.0, 0.5)
    got = np.asarray(nm.log_prob(jnp.asarray(x)))
    np.testing.assert_allclose(got, -0.5 * ((x - 1.0) / 0.5) ** 2, rtol=1e-12)
    lu = di.LogUniformPrior(0.1, 10.0)
    np.testing.assert_allclose(np.asarray(lu.log_prob(jnp.asarray(x))), -np.log(x))
    assert di.UniformPrior(0.0, 1.0).support == (0.0, 1.0)
    # draws follow the density: log of a log-normal's draws is N(log m, s)
    d = np.log(np.asarray(ln.sample(jax.random.key(0), (20000,))))
    assert abs(d.mean() - math.log(1.2)) < 0.02 and abs(d.std() - 0.7) < 0.02


@pytest.mark.parametrize(
    "bounds",
    [None, (0.0, 1.0), (0.1, math.inf), (-math.inf, 2.0), (-math.inf, math.inf)],
)
def test_log_abs_det_is_the_derivative_of_the_transform(bounds):
    t = make_transform("p", 0.5, bounds)
    for u in (-1.3, 0.0, 0.8):
        d = jax.grad(t.forward)(u)
        assert abs(float(t.log_abs_det(u)) - math.log(abs(float(d)))) < 2e-15


def test_default_priors_follow_the_bounds():
    assert di.default_prior(make_transform("mu", 0.2, None)) == di.LogNormalPrior(
        0.2, 1.0
    )
    assert di.default_prior(make_transform("cor", 0.5, (0, 1))) == di.UniformPrior(
        0.0, 1.0
    )


@pytest.mark.parametrize(
    "text, match",
    [
        ("gamma:1:2", "expected one of normal:MEAN:SD"),
        ("uniform:0", "expected one of"),
        ("lognormal:a:1", "MEDIAN:SIGMA must be two numbers"),
        ("lognormal:-1:1", "LogNormalPrior.median must be a finite number > 0"),
        ("uniform:2:1", "lower < upper"),
        ("normal:0:nan", "NormalPrior.sd must be a finite number > 0"),
    ],
)
def test_bad_priors_are_named(text, match):
    with pytest.raises(ValueError, match=match):
        parse_prior(text)


# --- chain diagnostics -------------------------------------------------------


def test_split_rhat_and_ess_on_known_chains():
    """iid draws: R-hat ~ 1 and ESS ~ the number of draws; an AR(1) chain of
    coefficient 0.9: ESS = N (1 - 0.9) / (1 + 0.9); chains about different
    means, or one that drifts, are caught."""
    rng = np.random.default_rng(0)
    iid = rng.standard_normal((4, 2000))
    assert split_rhat(iid) < 1.005
    assert 0.85 < ess_bulk(iid) / iid.size < 1.15
    ar = np.zeros((4, 4000))
    for k in range(1, ar.shape[1]):
        ar[:, k] = 0.9 * ar[:, k - 1] + math.sqrt(1 - 0.81) * rng.standard_normal(4)
    assert 0.75 < ess_bulk(ar) / (ar.size * 0.1 / 1.9) < 1.3
    apart = iid + np.array([0.0, 0.0, 0.0, 0.5])[:, None]
    assert split_rhat(apart) > 1.02
    drift = iid + np.linspace(0.0, 1.5, 2000)[None, :]
    assert split_rhat(drift) > 1.05
    # same mean, different spreads: the folded R-hat sees it
    spread = iid * np.array([1.0, 1.0, 1.0, 3.0])[:, None]
    assert split_rhat(spread) > 1.02


# --- the posterior -----------------------------------------------------------


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    return _noisy_file(tmp_path_factory.mktemp("post") / "noisy.csv")


@pytest.fixture(scope="module")
def normal_posterior(noisy):
    with warnings.catch_warnings():
        warnings.simplefilter("error", di.ConvergenceWarning)
        return di.posterior(noisy, "normal_impact", **RUN)


def test_posterior_agrees_with_least_squares(normal_posterior):
    """1 % noise, 16 measurements, 2 parameters: the posterior is close to
    Gaussian and the priors (a factor e) are wide against it, so its sd equals
    the least-squares standard error; 20 % allows the Monte-Carlo error of an
    sd from ~1,000 effective draws (~2 %) and the curvature the linearised
    error ignores.  The mean sits on the least-squares optimum (within 0.25
    sd: the Monte-Carlo error of a mean from ~600 effective draws is 0.04 sd,
    the prior's pull ~1e-4 sd), and the truth within 3 sd of it (this data
    set's least-squares z-scores are -2.4 and -0.5; the coverage over many
    data sets is in benchmarks/RESULTS.md)."""
    r = normal_posterior
    assert r.converged and r.identifiable
    ratio = r.sd / r.fit.std_errors
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    for i, n in enumerate(r.names):
        assert abs(r.mean[i] - r.fit.values[i]) < 0.25 * r.sd[i], n
        assert abs(r.mean[i] - TRUTH[n]) < 3.0 * r.sd[i], (n, r.mean[i], r.sd[i])
    assert np.all(r.rhat < 1.01) and int(r.divergent.sum()) == 0
    # the data narrow every direction to a few % of its prior spread
    assert r.contraction[1] < 0.1
    # predictive: the replicated 90 % band holds most measurements
    pp = r.predictive
    m = pp["measured"]
    inside = (m >= pp["replicated"][0]) & (m <= pp["replicated"][2])
    assert inside.mean() > 0.7
    assert np.all(pp["model"][0] <= pp["model"][2])


def test_the_same_seed_gives_the_same_draws(noisy, normal_posterior):
    again = di.posterior(noisy, "normal_impact", **RUN)
    np.testing.assert_array_equal(again.samples, normal_posterior.samples)


def test_outputs_are_written_and_never_overwritten(normal_posterior, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    path = tmp_path / "draws.csv"
    normal_posterior.save(path)
    rows = np.genfromtxt(path, delimiter=",", names=True)
    assert rows.size == 2 * 500
    np.testing.assert_allclose(
        rows["yield_strength"], normal_posterior.samples[..., 0].ravel()
    )
    with pytest.raises(ValueError, match="already exists; pass --force"):
        normal_posterior.save(path)
    d = normal_posterior.to_dict()
    assert set(d["parameters"]) == set(TRUTH) and d["divergent"] == 0
    assert "R-hat" in normal_posterior.summary()
    assert len(normal_posterior.plot_corner(truths=list(TRUTH.values())).axes) == 4
    assert len(normal_posterior.plot_predictive().axes) == 2
    # pandas and ArviZ (tests/test_frames.py checks them on a made-up result)
    draws = normal_posterior.to_dataframe()
    np.testing.assert_array_equal(draws["yield_strength"], rows["yield_strength"])
    az = pytest.importorskip("arviz")
    data = normal_posterior.to_arviz()
    assert isinstance(data, az.InferenceData)
    np.testing.assert_array_equal(
        data.posterior["youngs_modulus"], normal_posterior.samples[..., 1]
    )
    stats = data.sample_stats
    assert stats["tree_depth"].shape == (2, 500) and stats["tree_depth"].min() >= 1
    assert np.all(stats["n_steps"] >= 1) and np.all(np.isfinite(stats["energy"]))
    np.testing.assert_array_equal(stats["diverging"], normal_posterior.divergent)
    # the file's units: contact times in us, rows by their line
    assert set(data.observed_data) == {"contact_time_us", "cor_normal"}
    pp = data.posterior_predictive["contact_time_us"]
    assert pp.dims == ("chain", "draw", "row") and pp.shape[0] == 2
    assert 30 < float(pp.median()) < 300  # microseconds


def test_an_unidentifiable_pair_is_reported(noisy):
    """The two moduli enter only through E* (G-1): along the ridge the data say
    nothing, and the diagnostics must say so rather than report the prior's
    spread as a measurement."""
    with pytest.warns(di.IdentifiabilityWarning, match="do not determine") as rec:
        r = di.posterior(
            noisy,
            "normal_impact",
            free=["youngs_modulus", "scene.body.youngs_modulus"],
            num_samples=200,
            num_warmup=200,
            num_chains=2,
            # Along the ridge NUTS trees reach the default depth 10 (1,023
            # gradients a draw); depth 6 still travels it, 16 times cheaper.
            max_tree_depth=6,
        )
    assert not r.identifiable and r.contraction[1] > 0.5
    msg = next(str(w.message) for w in rec if w.category is di.IdentifiabilityWarning)
    assert "log youngs_modulus" in msg and "log scene.body.youngs_modulus" in msg


def test_a_bounded_prior_bounds_the_draws(noisy):
    r = di.posterior(
        noisy,
        "normal_impact",
        free=["yield_strength"],
        priors={"yield_strength": "uniform:350e6:420e6"},
        num_samples=100,
        num_warmup=100,
        num_chains=1,
    )
    assert r.priors == ("uniform(3.5e+08, 4.2e+08)",)
    assert np.all((r.samples > 350e6) & (r.samples < 420e6))


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(num_samples=5), ValueError, "`num_samples` must be an integer >= 20"),
        (dict(num_chains=0), ValueError, "`num_chains` must be an integer >= 1"),
        (dict(target_acceptance=1.5), ValueError, "`target_acceptance` must lie"),
        (dict(priors={"mu": "uniform:0:1"}), ValueError, "not free: \\['mu'\\]"),
        (dict(priors={"yield_strength": 3.0}), TypeError, "must be a prior"),
        (
            dict(priors={"yield_strength": "uniform:-2:-1"}),
            ValueError,
            "lies outside its bounds",
        ),
    ],
)
def test_bad_arguments_are_named_before_any_solve(noisy, kwargs, error, match):
    with pytest.raises(error, match=match):
        di.posterior(noisy, "normal_impact", free=["yield_strength"], **kwargs)


# --- command line ------------------------------------------------------------


def test_cli_posterior_writes_its_files(noisy, tmp_path, capsys):
    from diffimpact._cli._main import main

    out = tmp_path / "out"
    argv = ["fit", str(noisy), "--free", "yield_strength", "--out", str(out)]
    post = ["--posterior", "--samples", "100", "--warmup", "100", "--chains", "2"]
    assert main(argv + post + ["--seed", "3", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "R-hat" in text and "posterior.csv" in text
    d = __import__("json").loads((out / "posterior.json").read_text())
    assert d["num_chains"] == 2 and d["seed"] == 3
    assert d["parameters"]["yield_strength"]["prior"].startswith("lognormal")
    for f in ("posterior.csv", "corner.png", "predictive.png", "fit.json"):
        assert (out / f).stat().st_size > 0
    # a second run refuses before any work, naming what it would overwrite
    assert main(argv + post) == 2
    assert "would overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--samples", "100"], "--samples: give with --posterior"),
        (["--posterior", "--chains", "0"], "--chains must be an integer >= 1"),
        (["--posterior", "--prior", "mu=uniform:0:1"], "'mu' is not free"),
        (["--posterior", "--prior", "yield_strength=beta:1:2"], "expected one of"),
        (["--posterior", "--holdout", "0.3"], "choose one"),
    ],
)
def test_cli_posterior_bad_options_are_named(noisy, tmp_path, capsys, extra, match):
    from diffimpact._cli._main import main

    argv = ["fit", str(noisy), "--free", "yield_strength", "--out", str(tmp_path)]
    assert main(argv + extra) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err


def test_the_sampler_never_evaluates_far_outside(noisy):
    """Beyond |u| = 12 (a factor e^12 from the start) the density drops past
    the divergence threshold, finitely, without a solve out there."""
    import equinox as eqx

    from diffimpact._inference._fit_problem import prepare
    from diffimpact._inference._posterior import PosteriorModel

    _, problem, u0, _, _ = prepare(
        noisy, "normal_impact", ["yield_strength"], None, None, None, None
    )
    prior = (di.LogNormalPrior(400e6, 1.0),)
    model = PosteriorModel(problem, jnp.zeros(problem.mask.size, bool), prior, 0)
    inside = float(model.log_density(jnp.asarray([11.9])))
    outside = float(model.log_density(jnp.asarray([13.0])))
    assert math.isfinite(outside) and inside - outside > 1e5
    g = eqx.filter_grad(lambda u: model.log_density(u))(jnp.asarray([13.0]))
    assert np.all(np.isfinite(np.asarray(g)))


def test_a_plain_number_set_by_tree_at_is_a_parameter(noisy):
    """`eqx.tree_at` bypasses the converters: a yield strength set as a plain
    float is still the parameter it names (it once read 'unknown parameter')."""
    import equinox as eqx

    e = di.Experiment.default("normal_impact")
    e = eqx.tree_at(lambda e: e.scene.flat.yield_strength, e, 380e6)
    r = di.fit(noisy, e, free=["yield_strength"])
    assert r.start[0] == 380e6 and abs(r.values[0] / 400e6 - 1.0) < 0.05


def test_a_prior_away_from_the_data_and_the_start(noisy):
    """The truth (400 MPa) and the start value lie outside a uniform prior on
    (450, 600) MPa: the start moves to the prior's middle, the least-squares
    optimum sits on the bound (a saturated sigmoid, once a division by zero),
    and every draw stays inside."""
    r = di.posterior(
        noisy,
        "normal_impact",
        free=["yield_strength"],
        priors={"yield_strength": di.UniformPrior(450e6, 600e6)},
        num_samples=50,
        num_warmup=50,
        num_chains=1,
    )
    assert r.fit.start[0] == 525e6 and r.fit.values[0] < 451e6
    assert np.all((r.samples > 450e6) & (r.samples < 600e6))
    # the data push against the lower bound: most draws sit near it
    assert np.median(r.samples) < 470e6


def test_an_improper_posterior_is_refused(tmp_path, capsys):
    """Three measurements without sigma and three free parameters: the noise
    integrated out leaves a density that is infinite where the data are
    fitted exactly; refused before any solve (the command line writes no
    file)."""
    from diffimpact._cli._main import main

    three = ["yield_strength", "youngs_modulus", "poisson_ratio"]
    with pytest.raises(ValueError, match="posterior is improper"):
        di.posterior(
            DATA_BALL_PRISM, "sphere_on_incline", free=three, outputs=["cor_normal"]
        )
    six = ",".join([*three, "mu", "radius", "mass"])
    argv = ["fit", str(DATA_BALL_PRISM), "--free", six, "--posterior"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert "posterior is improper" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
