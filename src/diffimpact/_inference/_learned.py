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

import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array

from .._checks import as_float
from ..scenes._planar import AbstractPlanarScene
from ._experiment import (
    Experiment,
    get_path,
    resolve_parameter,
    with_inputs,
    with_parameters,
)
from ._predict import predict
from ._scenes import scene_spec

# Features of the state at first contact, from the contact-space
# quantities of a planar scene (contact-space page, CS-1): with the contact
# Jacobians J_n (into the flat), J_t and the mass matrix M, the approach
# speed s_0 = J_n q_dot, the slip v_0 = J_t q_dot, and the inverse effective masses
# a = J_n M^-1 J_n^T, b = J_n M^-1 J_t^T, c = J_t M^-1 J_t^T, made
# dimensionless by the body's mass.  They describe the impact independently
# of how the body is parametrised (an ellipse's orientation and a bar's
# tilt give the same features for the same contact).  With the contact
# radius they are what a compliant law's COR depends on besides the
# materials: the approach speed, the effective mass and the curvature
# (Johnson 1985, sec. 11.4; Jackson-Green loading and unloading, JG-5 to
# JG-10).
CONTACT_FEATURES = {
    "normal_speed": "approach speed of the contact point, J_n q_dot [m/s]",
    "tangential_speed": "slip of the contact point at first contact, J_t q_dot [m/s]",
    "slip_ratio": "tangential over normal approach speed, v_0 / s_0 [-]",
    "normal_mobility": "m J_n M^-1 J_n^T: mass over the effective normal mass [-]",
    "coupling": "m J_n M^-1 J_t^T: the normal-tangential coupling [-]",
    "tangential_mobility": "m J_t M^-1 J_t^T [-]",
    "contact_radius": "effective radius of curvature at the first contact (G-2) [m]",
}

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


def available_features(scene) -> list[str]:
    """The feature names a scene offers: the contact-space features of a
    planar scene, and every input its data rows may set (``orientation`` as
    its cosine and sine)."""
    names = list(CONTACT_FEATURES) if isinstance(scene, AbstractPlanarScene) else []
    if not isinstance(scene, AbstractPlanarScene) and hasattr(scene, "velocity"):
        names.append("normal_speed")
    return names + sorted(scene_spec(scene).inputs)


def feature_values(experiment: Experiment, names) -> Array:
    """The named features of ``experiment``'s scene, shape ``(k,)`` with
    ``orientation`` counted twice (cosine, sine)."""
    scene = experiment.scene
    out = []
    contact = None
    if not names:
        return jnp.zeros(0)
    for name in names:
        if name in CONTACT_FEATURES and isinstance(scene, AbstractPlanarScene):
            if contact is None:
                contact = _contact(scene)
            out.append(contact[name])
        elif name == "normal_speed":
            out.append(as_float(scene.velocity))
        else:
            value = getattr(scene, scene_spec(scene).inputs[name])
            if value is None:  # an optional input left unset (a height)
                raise ValueError(
                    f"feature {name!r}: the scene's {name} is not set (None); "
                    "give it in every row or choose another feature"
                )
            value = as_float(value)
            out.extend(
                [jnp.cos(value), jnp.sin(value)] if name == "orientation" else [value]
            )
    return jnp.stack(out)


def feature_width(names) -> int:
    return sum(2 if n == "orientation" else 1 for n in names)


def _contact(scene: AbstractPlanarScene) -> dict:
    scene = scene.at_first_contact()
    q0, q_dot0 = scene.initial_state()
    _, j_n, j_t = scene.kinematics(q0)
    m = scene.mass_diagonal()
    inv_m = 1.0 / m
    s0, v0 = j_n @ q_dot0, j_t @ q_dot0
    return {
        "contact_radius": scene.contact().effective_radius,
        "normal_speed": s0,
        "tangential_speed": v0,
        "slip_ratio": v0 / s0,
        "normal_mobility": m[0] * jnp.sum(j_n * inv_m * j_n),
        "coupling": m[0] * jnp.sum(j_n * inv_m * j_t),
        "tangential_mobility": m[0] * jnp.sum(j_t * inv_m * j_t),
    }


class Polynomial(eqx.Module):
    """All monomials of the standardised features up to `degree` (the
    constant excluded: it is `Learned`'s), with coefficients from zero."""

    coefficients: Array
    powers: tuple[tuple[int, ...], ...] = eqx.field(static=True)

    def __init__(self, width: int, degree: int):
        self.powers = tuple(
            p
            for d in range(1, degree + 1)
            for p in itertools.combinations_with_replacement(range(width), d)
        )
        self.coefficients = jnp.zeros(len(self.powers))

    def __call__(self, z):
        terms = jnp.stack([jnp.prod(z[jnp.asarray(p)]) for p in self.powers])
        return terms @ self.coefficients


class _Network(eqx.Module):
    """An MLP whose last layer starts at zero: the correction is zero, the
    parameter its constant, until training moves it."""

    mlp: eqx.nn.MLP

    def __init__(self, width_in: int, width: int, depth: int, key):
        mlp = eqx.nn.MLP(width_in, "scalar", width, depth, jax.nn.tanh, key=key)
        last = mlp.layers[-1]
        self.mlp = eqx.tree_at(
            lambda m: (m.layers[-1].weight, m.layers[-1].bias),
            mlp,
            (jnp.zeros_like(last.weight), jnp.zeros_like(last.bias)),
        )

    def __call__(self, z):
        return self.mlp(z)


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
        if isinstance(features, str):
            features = (features,)
        self.features = tuple(features)
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
    the ones it does.

    `predict` gives what `diffimpact.predict` gives, for one row of inputs;
    `jit`, `vmap` and `grad` compose with it.
    """

    experiment: Experiment
    learned: dict[str, Learned]

    def __init__(self, experiment: Experiment, learned: dict):
        if not isinstance(experiment, Experiment):
            raise TypeError(
                f"Hybrid: expected an Experiment, got {type(experiment).__name__}"
            )
        if not learned:
            raise ValueError("Hybrid: give at least one learned parameter")
        offered = available_features(experiment.scene)
        paths = {}
        for name, fn in learned.items():
            if not isinstance(fn, Learned):
                raise TypeError(
                    f"learned parameter {name!r}: expected a diffimpact.Learned, "
                    f"got {type(fn).__name__}"
                )
            unknown = [f for f in fn.features if f not in offered]
            if unknown:
                raise ValueError(
                    f"learned parameter {name!r}: feature(s) {unknown} are not "
                    f"offered by scene {type(experiment.scene).__name__}; expected "
                    f"any of {offered}"
                )
            path = resolve_parameter(experiment, name)
            twice = [n for n, p in paths.items() if p == path]
            if twice:
                raise ValueError(
                    f"learned parameters {twice[0]!r} and {name!r} are the same "
                    f"parameter ({path}); give it once"
                )
            paths[name] = path
        experiment = with_parameters(experiment, list(paths.values()))
        self.experiment = experiment
        self.learned = {
            paths[n]: fn
            if fn.raw is not None
            else fn.bind(paths[n], _value(experiment, paths[n]))
            for n, fn in learned.items()
        }

    def features(self, inputs: dict) -> dict:
        """Each learned parameter's feature vector at one row's ``inputs``."""
        e = with_inputs(self.experiment, inputs)
        return {p: feature_values(e, fn.features) for p, fn in self.learned.items()}

    def parameters(self, inputs: dict) -> dict:
        """The learned parameters' values at one row's ``inputs`` (by path)."""
        x = self.features(inputs)
        return {p: fn(x[p]) for p, fn in self.learned.items()}

    def experiment_at(self, inputs: dict) -> Experiment:
        """The plain `Experiment` of one row: its inputs set and every learned
        parameter at its value there."""
        e = with_inputs(self.experiment, inputs)
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
        """`diffimpact.predict` of one row with the learned parameters."""
        return predict(self.experiment_at(inputs), {}, throw=throw)

    def penalty(self, inputs: dict):
        """The sum of squared corrections at one row (what training keeps
        small so that the parameters stay near their constants)."""
        x = self.features(inputs)
        return sum(fn.deviation(x[p]) ** 2 for p, fn in self.learned.items())

    def with_scaling(self, rows: dict) -> Hybrid:
        """Standardise every function's features on ``rows`` (a dict of
        input arrays)."""
        xs = jax.vmap(self.features)(rows)
        new = {p: fn.with_scaling(xs[p]) for p, fn in self.learned.items()}
        return eqx.tree_at(lambda h: h.learned, self, new)


def _value(experiment, path):
    value = get_path(experiment, path)
    return float(value) if value is not None else math.nan
