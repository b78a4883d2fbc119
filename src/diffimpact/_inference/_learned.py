"""State-dependent parameters: a physical parameter of an `Experiment` as a
function of the impact's state, learned through the solve.

A constant coefficient of restitution or friction is an average over the
states an experiment visits; measured impacts show both drifting with the
approach (the normal COR falls with the normal approach speed, Goldsmith's
*Impact*, 1960; Johnson, *Contact Mechanics*, 1985, ch. 11; the tangential
response changes with the ratio of tangential to normal approach speed,
Maw, Barber & Fawcett 1976).  `Learned` keeps the physics (the impact is
still `predict` of the experiment, so impulses stay in Coulomb's cone) and
lets one of its parameters vary with named
features of the state (a COR kept in (0, 1) under Stronge's energetic
restitution, which never gains energy, keeps every impact dissipative):

    ``p(x) = g(c + f(z(x)))``, ``z = (x - shift) / scale``,

``g`` the map of the parameter's domain (a logistic for a COR in (0, 1), a
tanh for a tangential COR in (-1, 1), a softplus for a friction
coefficient, an exponential for a positive constant), ``c`` the constant
the physics would fit, ``f`` a correction (a small MLP or a polynomial,
zero at the start) and ``z`` the features standardised on the training
rows.  Training penalises ``f`` on the
training rows (`penalty`), so that with few rows the function stays near
the constant: the physics is the prior, the data bend it.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array

from .._checks import require_type
from ..scenes._planar import AbstractPlanarScene
from ._corrections import Polynomial, _Network
from ._experiment import (
    Experiment,
    get_path,
    resolve_parameter,
    with_inputs,
    with_parameters,
)
from ._features import (
    available_features,
    feature_names,
    feature_values,
    feature_width,
)
from ._predict import predict
from ._residual import PLANAR_OUTPUTS, Residual

DOMAINS = {
    "unit": "(0, 1)",
    "symmetric": "(-1, 1)",
    "nonnegative": "[0, inf)",
    "positive": "(0, inf)",
}

# Parameters whose domain is not (0, inf), by the last part of their path;
# those in _NO_DEFAULT have a domain none of the three maps fits, and need
# domain= given.
_DOMAIN_OF = {
    "cor": "unit",
    "tangential_cor": "symmetric",
    "mu": "nonnegative",
    "mu_v": "nonnegative",
    "mu_s": "nonnegative",
}
_NO_DEFAULT = ("poisson_ratio",)
# A start on the edge of a domain the map reaches only in the limit (a COR
# of 1, a friction coefficient of 0) starts this far inside instead.
_EDGE = 1e-6


def _to_domain(domain: str, raw):
    if domain == "unit":
        return jax.nn.sigmoid(raw)
    if domain == "symmetric":
        return jnp.tanh(raw)
    if domain == "nonnegative":
        return jax.nn.softplus(raw)
    return jnp.exp(raw)


def _from_domain(domain: str, value: float) -> float:
    if domain == "unit":
        return math.log(value / (1.0 - value))
    if domain == "symmetric":
        return math.atanh(value)
    if domain == "nonnegative":
        return value + math.log(-math.expm1(-value))  # softplus^-1
    return math.log(value)


def _within(domain: str, value):
    """Traced: ``value`` lies in the closure a solve accepts (a logistic
    rounds to exactly 1 for a large argument: a COR of 1 is still valid)."""
    finite = jnp.isfinite(value)
    if domain == "unit":  # [0, 1]: a rigid law's COR may be exactly 0 or 1
        return finite & (value >= 0) & (value <= 1)
    if domain == "symmetric":
        return finite & (value >= -1) & (value <= 1)
    if domain == "nonnegative":
        return finite & (value >= 0)
    return finite & (value > 0)


def _inside(domain: str, value: float) -> bool:
    if domain == "unit":
        return 0.0 < value < 1.0
    if domain == "symmetric":
        return -1.0 < value < 1.0
    if domain == "nonnegative":
        return value > 0.0  # a start exactly at 0 has no finite raw value
    return value > 0.0


KINDS = ("mlp", "polynomial", "constant")


class Learned(eqx.Module):
    """A parameter of an `Experiment` as a function of the impact's state.

    **Arguments:** `features`: names of the state the parameter depends on
    (``available_features(scene)``: ``normal_speed``, ``slip_ratio``,
    ``orientation``, ...); `kind`: ``"mlp"`` (a tanh MLP of `width` and
    `depth`; the default with features), ``"polynomial"`` (every monomial
    up to `degree`) or ``"constant"`` (no dependence: the plain physics,
    trained the same way; the default without features); `start`: the
    constant to start from (None: the experiment's value); `domain`:
    ``"unit"`` (0, 1), ``"nonnegative"`` or ``"positive"`` (None: from the
    parameter, ``cor`` unit, ``mu`` nonnegative, others positive); `seed`:
    the MLP's initial weights.

    Put in a `Hybrid`, it is bound to its parameter: `domain`, the raw
    constant and the feature scaling are then set (`bind`, `with_scaling`).
    """

    features: tuple[str, ...] = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    domain: str | None = eqx.field(static=True)
    raw: Array | None
    correction: eqx.Module | None
    shift: Array
    scale: Array
    start: float | None = eqx.field(static=True)

    def __init__(
        self,
        features=(),
        kind: str | None = None,
        *,
        start: float | None = None,
        domain: str | None = None,
        width: int = 16,
        depth: int = 2,
        degree: int = 2,
        seed: int = 0,
    ):
        self.features = feature_names(features)
        if kind is None:
            kind = "mlp" if self.features else "constant"
        if kind not in KINDS:
            raise ValueError(f"Learned.kind={kind!r}: expected one of {KINDS}")
        if kind != "constant" and not self.features:
            raise ValueError(
                f"Learned(kind={kind!r}) needs at least one feature (e.g. "
                "features=('normal_speed', 'slip_ratio')); a parameter without "
                "features is kind='constant'"
            )
        if domain is not None and domain not in DOMAINS:
            raise ValueError(
                f"Learned.domain={domain!r}: expected one of {sorted(DOMAINS)}"
            )
        self.kind, self.domain, self.start = kind, domain, start
        k = feature_width(self.features)
        if kind == "mlp":
            if int(width) < 1 or int(depth) < 1:
                raise ValueError(
                    f"Learned: width and depth must be integers >= 1, got "
                    f"width={width}, depth={depth}"
                )
            self.correction = _Network(k, int(width), int(depth), jr.PRNGKey(seed))
        elif kind == "polynomial":
            if int(degree) < 1:
                raise ValueError(f"Learned.degree must be >= 1, got {degree}")
            self.correction = Polynomial(k, int(degree))
        else:
            self.correction = None
        self.raw = None
        self.shift = jnp.zeros(k)
        self.scale = jnp.ones(k)

    def bind(self, name: str, value) -> Learned:
        """This function bound to parameter ``name`` whose current value is
        ``value``: its domain set and its constant at `start` (or ``value``)."""
        last = name.rpartition(".")[2]
        if self.domain is None and last in _NO_DEFAULT:
            raise ValueError(
                f"learned parameter {name!r}: give its domain, e.g. "
                f"Learned(..., domain='positive'); none of {sorted(DOMAINS)} is "
                "implied for it"
            )
        domain = self.domain or _DOMAIN_OF.get(last, "positive")
        start = float(value) if self.start is None else float(self.start)
        if math.isnan(start):
            raise ValueError(
                f"learned parameter {name!r} is not set in the experiment; give "
                "Learned(start=...)"
            )
        if domain == "unit" and start in (0.0, 1.0):
            start = min(max(start, _EDGE), 1.0 - _EDGE)
        elif domain == "symmetric" and start in (-1.0, 1.0):
            start = min(max(start, -1.0 + _EDGE), 1.0 - _EDGE)
        elif domain == "nonnegative" and start == 0.0:
            start = _EDGE
        if not (math.isfinite(start) and _inside(domain, start)):
            raise ValueError(
                f"learned parameter {name!r}: start value {start:g} is outside "
                f"its domain {DOMAINS[domain]}; give Learned(start=...) inside it "
                "(or domain=...)"
            )
        # strongly typed: a weak type turns strong after the first optimiser
        # update, and a jitted training loop would compile twice
        raw = jnp.asarray(_from_domain(domain, start), jnp.result_type(float))
        new = eqx.tree_at(lambda m: m.raw, self, raw, is_leaf=lambda x: x is None)
        return _set_static(new, domain=domain)

    def with_scaling(self, x) -> Learned:
        """Standardise the features by the rows ``x`` (shape ``(n, k)``)."""
        shift = jnp.mean(x, axis=0)
        scale = jnp.std(x, axis=0)
        scale = jnp.where(scale > 0, scale, 1.0)
        return eqx.tree_at(lambda m: (m.shift, m.scale), self, (shift, scale))

    def deviation(self, x):
        """The correction ``f(z)`` in the unconstrained space (0 for a constant)."""
        if self.correction is None:
            return jnp.zeros(())
        z = (x - jax.lax.stop_gradient(self.shift)) / jax.lax.stop_gradient(self.scale)
        return self.correction(z)

    def __call__(self, x):
        """The parameter at features ``x``, inside its domain by construction."""
        return _to_domain(self.domain, self.raw + self.deviation(x))


def _set_static(module, **fields):
    """A copy of an equinox module with static fields replaced."""
    new = object.__new__(type(module))
    for f in module.__dataclass_fields__:
        object.__setattr__(new, f, fields.get(f, getattr(module, f)))
    return new


class Hybrid(eqx.Module):
    """An `Experiment` some of whose parameters are `Learned` functions of
    the impact's state: the physics with what it cannot explain learned
    through the solve.

    **Arguments:** `experiment`; `learned`: parameter name (as `fit` takes
    it: ``"cor"``, ``"mu"``, ``"yield_strength"``, a dotted path) ->
    `Learned`.  Each function is bound to its parameter (its domain and
    start value); a feature the scene does not offer is refused, naming
    the ones it does.  `residual`: None, or a `Residual` correction added
    to the predicted outputs (residual physics, for what no parameter of
    the law can express); `learned` may then be empty, the physics keeping
    the experiment's values.

    `predict` gives what `diffimpact.predict` gives, for one row of inputs;
    `jit`, `vmap` and `grad` compose with it.
    """

    experiment: Experiment
    learned: dict[str, Learned]
    residual: Residual | None

    def __init__(
        self, experiment: Experiment, learned: dict, residual: Residual | None = None
    ):
        require_type(experiment, Experiment, "Hybrid: expected an Experiment")
        require_type(
            residual,
            Residual,
            "Hybrid.residual: expected a diffimpact.Residual or None",
            optional=True,
        )
        learned = dict(learned or {})
        if not learned and residual is None:
            raise ValueError(
                "Hybrid: give at least one learned parameter or a residual"
            )
        offered = available_features(experiment.scene)
        paths = {}
        for name, fn in learned.items():
            if not isinstance(fn, Learned):
                raise TypeError(
                    f"learned parameter {name!r}: expected a diffimpact.Learned, "
                    f"got {type(fn).__name__}"
                )
            _check_features(f"learned parameter {name!r}", fn.features, offered,
                            experiment)  # fmt: skip
            path = resolve_parameter(experiment, name)
            twice = [n for n, p in paths.items() if p == path]
            if twice:
                raise ValueError(
                    f"learned parameters {twice[0]!r} and {name!r} are the same "
                    f"parameter ({path}); give it once"
                )
            paths[name] = path
        if residual is not None:
            _check_features("residual", residual.features, offered, experiment)
            if residual.outputs is None:
                if not isinstance(experiment.scene, AbstractPlanarScene):
                    raise ValueError(
                        f"residual: name the outputs it corrects for scene "
                        f"{type(experiment.scene).__name__} (Residual(features, "
                        "outputs=(...)), e.g. 'rebound_velocity')"
                    )
                residual = residual.bind(PLANAR_OUTPUTS)
        experiment = with_parameters(experiment, list(paths.values()))
        self.experiment = experiment
        self.learned = {
            paths[n]: fn
            if fn.raw is not None
            else fn.bind(paths[n], _value(experiment, paths[n]))
            for n, fn in learned.items()
        }
        self.residual = residual

    def features(self, inputs: dict) -> dict:
        """Each learned parameter's feature vector at one row's ``inputs``."""
        e = with_inputs(self.experiment, inputs)
        return {p: feature_values(e, fn.features) for p, fn in self.learned.items()}

    def parameters(self, inputs: dict) -> dict:
        """The learned parameters' values at one row's ``inputs`` (by path)."""
        x = self.features(inputs)
        return {p: fn(x[p]) for p, fn in self.learned.items()}

    def residual_features(self, inputs: dict):
        """The residual's feature vector at one row's ``inputs``."""
        e = with_inputs(self.experiment, inputs)
        return feature_values(e, self.residual.features)

    def correction(self, inputs: dict) -> dict:
        """The residual's correction of each output at one row's ``inputs``
        (quantity -> SI value; empty without a residual)."""
        if self.residual is None:
            return {}
        dy = self.residual(self.residual_features(inputs))
        return dict(zip(self.residual.outputs, dy, strict=True))

    def experiment_at(self, inputs: dict) -> Experiment:
        """The plain `Experiment` of one row: its inputs set and every learned
        parameter at its value there."""
        e = with_inputs(self.experiment, inputs)
        if not self.learned:
            return e
        x = {p: feature_values(e, fn.features) for p, fn in self.learned.items()}
        paths = list(self.learned)
        values = []
        for p in paths:
            fn = self.learned[p]
            value = fn(x[p])
            # Inside by construction for the built-in kinds; a function of
            # the user's (a subclass with its own __call__) is held to it.
            value = eqx.error_if(
                value,
                ~_within(fn.domain, value),
                f"learned parameter {p!r} returned a value outside its domain "
                f"{DOMAINS[fn.domain]} (or not finite)",
            )
            values.append(value)
        return eqx.tree_at(lambda m: [get_path(m, p) for p in paths], e, values)

    def predict(self, inputs: dict, *, throw: bool = True) -> dict:
        """`diffimpact.predict` of one row with the learned parameters, plus
        the residual's correction of its outputs (if any)."""
        out = predict(self.experiment_at(inputs), {}, throw=throw)
        if self.residual is None:
            return out
        missing = [q for q in self.residual.outputs if q not in out or q == "result"]
        if missing:
            raise ValueError(
                f"residual: output(s) {missing} are not predicted by the "
                f"experiment; expected any of {sorted(q for q in out if q != 'result')}"
            )
        out = dict(out)
        for q, dy in self.correction(inputs).items():
            out[q] = out[q] + dy
        return out

    def penalty(self, inputs: dict):
        """The sum of squared corrections at one row (what training keeps
        small so that the parameters stay near their constants and the
        residual near zero)."""
        x = self.features(inputs)
        total = sum(
            (fn.deviation(x[p]) ** 2 for p, fn in self.learned.items()), jnp.zeros(())
        )
        if self.residual is not None:
            f = self.residual.deviation(self.residual_features(inputs))
            total = total + jnp.sum(f**2)
        return total

    def with_scaling(self, rows: dict, outputs: dict | None = None) -> Hybrid:
        """Standardise every function's features on ``rows`` (a dict of
        input arrays); given the measured ``outputs`` of those rows
        (quantity -> array, NaN where not measured), scale the residual's
        correction of each by its spread."""
        xs = jax.vmap(self.features)(rows)
        new = {p: fn.with_scaling(xs[p]) for p, fn in self.learned.items()}
        out = eqx.tree_at(lambda h: h.learned, self, new)
        if self.residual is None:
            return out
        r = self.residual
        xr = jax.vmap(self.residual_features)(rows)
        y = None
        if outputs is not None and all(q in outputs for q in r.outputs):
            y = jnp.stack([jnp.asarray(outputs[q]) for q in r.outputs], axis=1)
        return eqx.tree_at(lambda h: h.residual, out, r.with_scaling(xr, y))


def _check_features(what, features, offered, experiment):
    unknown = [f for f in features if f not in offered]
    if unknown:
        raise ValueError(
            f"{what}: feature(s) {unknown} are not offered by scene "
            f"{type(experiment.scene).__name__}; expected any of {offered}"
        )


def _value(experiment, path):
    value = get_path(experiment, path)
    return float(value) if value is not None else math.nan
