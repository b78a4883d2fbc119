"""Prior densities of free parameters, for `posterior`.

A prior is a density on the parameter itself, in SI units (a yield strength in
Pa).  The sampler works on the same unconstrained coordinate ``u`` as `fit`
(`._transforms`), and adds ``log |dx/du|`` so that the prior stays the density
the user wrote, whatever the coordinate.  A prior with bounded support (a
`UniformPrior`, a `LogUniformPrior`) bounds the parameter: the transform maps
``u`` onto its support, so the sampler never proposes a value of zero density.
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def _number(value):
    """A prior's number as a 0-d float64 NumPy array: a leaf that ``jit``
    traces (one compiled sampler serves every prior of the same kind), and a
    number to Python (comparisons, ``math.log``, formatting)."""
    return np.asarray(float(value), dtype=np.float64)


def _positive(name: str, value) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return value


def _finite(name: str, value) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return value


class AbstractPrior(eqx.Module):
    """A prior density on one parameter (SI units)."""

    @property
    def support(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    @property
    @abc.abstractmethod
    def center(self) -> float:
        """A typical value (the median): the start of a parameter whose own
        start value lies outside the prior's support."""

    @abc.abstractmethod
    def log_prob(self, x):
        """Log density at ``x``, up to a constant."""

    @abc.abstractmethod
    def sample(self, key, shape) -> jax.Array:
        """Draws of the prior, of the given shape."""


class NormalPrior(AbstractPrior):
    """Normal prior with `mean` and standard deviation `sd` (the parameter's
    units); on a positive parameter it is truncated at zero."""

    mean: float = eqx.field(converter=_number)
    sd: float = eqx.field(converter=_number)

    def __check_init__(self):
        _finite("NormalPrior.mean", self.mean)
        _positive("NormalPrior.sd", self.sd)

    @property
    def center(self) -> float:
        return float(self.mean)

    def log_prob(self, x):
        return -0.5 * ((x - self.mean) / self.sd) ** 2

    def sample(self, key, shape):
        return self.mean + self.sd * jax.random.normal(key, shape)

    def __str__(self) -> str:
        return f"normal(mean={self.mean:.6g}, sd={self.sd:.6g})"


class LogNormalPrior(AbstractPrior):
    """Log-normal prior: ``log x`` is normal about ``log median`` with
    standard deviation `sigma` (``sigma = 1``: one standard deviation is a
    factor e = 2.72 either way)."""

    median: float = eqx.field(converter=_number)
    sigma: float = eqx.field(converter=_number)

    def __check_init__(self):
        for name in ("median", "sigma"):
            _positive(f"LogNormalPrior.{name}", getattr(self, name))

    @property
    def support(self):
        return (0.0, math.inf)

    @property
    def center(self) -> float:
        return float(self.median)

    def log_prob(self, x):
        z = jnp.log(x / self.median) / self.sigma
        return -0.5 * z**2 - jnp.log(x)

    def sample(self, key, shape):
        return self.median * jnp.exp(self.sigma * jax.random.normal(key, shape))

    def __str__(self) -> str:
        return f"lognormal(median={self.median:.6g}, sigma={self.sigma:.6g})"


class AbstractBoundedPrior(AbstractPrior):
    """A prior on ``(lower, upper)``, which bounds the parameter."""

    lower: float = eqx.field(converter=_number)
    upper: float = eqx.field(converter=_number)

    def _check_bounds(self, each, form: str) -> None:
        """``each(name, value)`` on both bounds, then ``lower < upper``
        (``form`` names the condition in the message)."""
        for name in ("lower", "upper"):
            each(f"{type(self).__name__}.{name}", getattr(self, name))
        if not self.lower < self.upper:
            raise ValueError(
                f"{type(self).__name__} needs {form}, got ({self.lower}, {self.upper})"
            )

    @property
    def support(self):
        return (float(self.lower), float(self.upper))


class UniformPrior(AbstractBoundedPrior):
    """Uniform prior on ``(lower, upper)``; bounds the parameter."""

    def __check_init__(self):
        self._check_bounds(_finite, "lower < upper")

    @property
    def center(self) -> float:
        return float(0.5 * (self.lower + self.upper))

    def log_prob(self, x):
        return jnp.zeros_like(x)

    def sample(self, key, shape):
        return jax.random.uniform(key, shape, minval=self.lower, maxval=self.upper)

    def __str__(self) -> str:
        return f"uniform({self.lower:.6g}, {self.upper:.6g})"


class LogUniformPrior(AbstractBoundedPrior):
    """Density ``1/x`` on ``(lower, upper)``, ``0 < lower``: every decade
    equally likely; bounds the parameter."""

    def __check_init__(self):
        self._check_bounds(_positive, "0 < lower < upper")

    @property
    def center(self) -> float:
        return float(np.sqrt(self.lower * self.upper))

    def log_prob(self, x):
        return -jnp.log(x)

    def sample(self, key, shape):
        lo, hi = jnp.log(self.lower), jnp.log(self.upper)
        return jnp.exp(jax.random.uniform(key, shape, minval=lo, maxval=hi))

    def __str__(self) -> str:
        return f"loguniform({self.lower:.6g}, {self.upper:.6g})"


_KINDS = {
    "normal": (NormalPrior, "MEAN:SD"),
    "lognormal": (LogNormalPrior, "MEDIAN:SIGMA"),
    "uniform": (UniformPrior, "LOWER:UPPER"),
    "loguniform": (LogUniformPrior, "LOWER:UPPER"),
}


def parse_prior(text: str) -> AbstractPrior:
    """A prior from its text form, e.g. ``"uniform:0:1"``,
    ``"lognormal:4e8:0.5"`` (the command line's ``--prior NAME=KIND:A:B``)."""
    kind, *numbers = [t.strip() for t in text.split(":")]
    expected = ", ".join(f"{k}:{form}" for k, (_, form) in _KINDS.items())
    if kind.lower() not in _KINDS or len(numbers) != 2:
        raise ValueError(f"prior {text!r}: expected one of {expected}")
    cls, form = _KINDS[kind.lower()]
    try:
        a, b = (float(n) for n in numbers)
    except ValueError:
        raise ValueError(
            f"prior {text!r}: {form} must be two numbers, e.g. {kind}:0.1:0.5"
        ) from None
    return cls(a, b)


def default_prior(transform) -> AbstractPrior:
    """The prior of a parameter the user gave none for, from its bounds:

    - ``(0, inf)`` (every physical parameter by default): log-normal about the
      start value with ``sigma = 1``, a weakly informative prior on the
      order of magnitude (95 % within a factor 7 either way);
    - ``(lower, upper)``, both finite (a COR, a Poisson ratio, given bounds):
      uniform between them;
    - otherwise: normal about the start value with the start's magnitude as
      its standard deviation (truncated at a finite bound).
    """
    lo, hi, x0 = transform.lower, transform.upper, transform.start
    if lo == 0.0 and hi == math.inf:
        return LogNormalPrior(x0, 1.0)
    if math.isfinite(lo) and math.isfinite(hi):
        return UniformPrior(lo, hi)
    return NormalPrior(x0, transform.scale)


def prior_draws_u(prior: AbstractPrior, transform, n: int, seed: int) -> np.ndarray:
    """``n`` draws of the prior mapped to the sampler's coordinate ``u``
    (the draws outside the transform's bounds, of a truncated prior, dropped):
    the prior's spread in the coordinate the posterior is compared in."""
    x = np.asarray(prior.sample(jax.random.key(seed), (n,)), dtype=float)
    lo, hi = transform.lower, transform.upper
    x = x[(x > lo) & (x < hi)]
    return np.array([transform.inverse(float(v)) for v in x])
