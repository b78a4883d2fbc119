"""Exact normal impact without an ODE (docs/physics/contact.md).

For one normal degree of freedom every output follows from energy integrals:

- ``d_m`` from ``W(d_m) - m g d_m = m v0^2 / 2`` (Newton, implicit derivative);
- the loading time ``int_0^{d_m} dd / v(d)`` with ``d = d_m (1 - s^2)``, which
  removes the end-point singularity, split at the phase switch ``d_s`` so that
  each Gauss-Legendre piece has a smooth integrand (the switch is a kink of
  ``v(d)``, which would spoil Gauss convergence across it);
- restitution is Hertzian about ``d_r``: the rebound speed in closed form and
  the unloading time by the same substitution about ``d_r``.

The elasto-plastic work ``int F dd`` is integrated in ``log d``: ``F`` is a sum of
powers of ``d*`` (and exponentials of powers), entire functions of ``log d*``,
so Gauss-Legendre converges geometrically however wide ``[d_s, d_m]`` is.
Differences of potentials are formed without cancellation (``expm1``/``log1p``
and direct integrals over ``[d, d_m]``), so the integrand stays accurate next
to the turning point.  The direct integrals over ``[d, d_m]`` at every node of
the plastic loading time come from one Chebyshev interpolant of the force in
``log d``, integrated spectrally (Clenshaw-Curtis), rather than one Gauss rule
per node.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._result import RESULTS
from .._smooth import safe_sqrt
from ._root import newton_root

# Chebyshev samples of the plastic force for its cumulative work from d to
# d_m (see `solve_quadrature`).  Against a nested Gauss rule (order x 16
# force evaluations per impact, itself 4e-11 from a tight event solve on the
# loading time) on 8,192 random impacts: 24 samples agree to 5e-13, 16 to
# 1.6e-8.
_CHEB_ORDER = 24


def _gauss01(order: int):
    x, w = np.polynomial.legendre.leggauss(order)
    return 0.5 * (x + 1.0), 0.5 * w


def _log_work(force, a, log_ratio, order):
    """``int_a^{a e^L} force(x) dx`` by Gauss-Legendre in ``log x``."""
    s, w = _gauss01(order)
    dt = jnp.result_type(a, log_ratio)  # nodes in the impact's dtype (float32 stays)
    x = a * jnp.exp(jnp.asarray(s, dt) * log_ratio)
    return log_ratio * jnp.sum(jnp.asarray(w, dt) * force(x) * x)


@functools.lru_cache(maxsize=8)
def _cheb_cumulative(order: int):
    """Chebyshev nodes ``tau_i`` on ``[0, 1]`` (first kind) and the matrix
    that maps samples ``g(tau_i)`` to the Chebyshev coefficients (on ``x = 2
    tau - 1``) of ``G(tau) = int_0^tau g``.  Spectral integration of an
    interpolant (Clenshaw-Curtis): one set of ``order`` samples gives the
    cumulative integral everywhere in ``[0, 1]``."""
    x = np.cos(np.pi * (np.arange(order) + 0.5) / order)[::-1]
    to_coef = np.linalg.inv(np.polynomial.chebyshev.chebvander(x, order - 1))
    integrate = np.polynomial.chebyshev.chebint(to_coef, lbnd=-1.0, axis=0)
    return 0.5 * (x + 1.0), 0.5 * integrate  # d tau = dx / 2


def _cheb_eval(coef, tau):
    """Chebyshev series ``sum_k coef_k T_k(2 tau - 1)`` at ``tau``."""
    theta = jnp.arccos(jnp.clip(2.0 * tau - 1.0, -1.0, 1.0))
    k = jnp.arange(coef.shape[0], dtype=theta.dtype)
    return jnp.cos(theta[..., None] * k) @ coef


def _travel_time(delta, potential_drop, m, order, s_lo=0.0, s_hi=1.0):
    """Time to travel ``d = d_end - delta s^2`` for ``s`` in ``[s_lo, s_hi]``,
    ``int dd / v = int 2 delta s / v(s) ds``, where ``v = sqrt(2 drop(s) / m)``
    and ``potential_drop(s) = U(d_end) - U(d)``.  With ``d_end`` a turning point
    the integrand is smooth at ``s = 0`` (``drop ~ s^2``)."""
    sigma, w = _gauss01(order)
    dt = jnp.result_type(delta, m)
    s = s_lo + (s_hi - s_lo) * jnp.asarray(sigma, dt)
    v = jnp.sqrt(2.0 * jax.vmap(potential_drop)(s) / m)
    return (s_hi - s_lo) * jnp.sum(jnp.asarray(w, dt) * 2.0 * delta * s / v)


def normal_timeline(problem, bound, settings) -> Timeline:
    """The normal impact solved by energy integrals (module docstring), as a
    `Timeline`: its totals, and the state at any point of the contact."""
    if bound.rate_dependent:
        raise ValueError(
            "method='quadrature' needs a law whose loading force depends on the "
            "interference only (Hertz, JacksonGreen); this law depends on the "
            "interference rate: use method='smooth' or 'events'"
        )
    if not bound.power_law:
        raise ValueError(
            "method='quadrature' needs a power law K d^n (Hertz, JacksonGreen, "
            "AdamsImpact); use method='smooth' or 'events' for "
            f"{type(bound).__name__}"
        )
    order = settings.quadrature_order
    m, g, v0 = problem.mass, problem.gravity, problem.velocity
    energy = 0.5 * m * v0**2
    k, n = bound.scale()
    two_phase = bound.n_loading_phases == 2

    def f_el(d):
        return bound.loading_force(d, 0.0, 0)

    def w_el(d):
        return k * d ** (n + 1.0) / (n + 1.0)

    # --- maximum compression (JG-7) -------------------------------------------
    def h_el(d, args):
        k, n, m, g, energy = args
        return k * d ** (n + 1.0) / (n + 1.0) - m * g * d - energy

    d_free = ((n + 1.0) * energy / k) ** (1.0 / (n + 1.0))
    d_static = (2.0 * jnp.abs(m * g) / k) ** (1.0 / n)

    def dh_el(d, args):
        k, n, m, g, _ = args
        return k * d**n - m * g

    d_el = newton_root(h_el, d_free + d_static, (k, n, m, g, energy), fprime=dh_el)

    if two_phase:
        d_s = bound.switch_deflection()

        def f_pl(d):
            return bound.loading_force(d, 0.0, 1)

        u_s = w_el(d_s) - m * g * d_s
        plastic = energy > u_s
        # The unused branch is solved for a benign energy so that it stays
        # finite (a NaN there would poison gradients through the select).
        e_pl = jnp.where(plastic, energy, 2.0 * u_s)

        # Newton in y = log(d / d_s): the work grows like a power of d, so
        # h(d_s e^y) is convex and nearly exponential in y and Newton converges
        # in a few steps from the power-law estimate below (exponent 1.25,
        # between the 1.1 and 1.5 of JG-5), however deep the impact.
        def h_pl(y, args):
            bound_, d_s, u_s, m, g, e = args
            f = lambda x: bound_.loading_force(x, 0.0, 1)  # noqa: E731
            d = d_s * jnp.exp(y)
            return u_s + _log_work(f, d_s, y, order) - m * g * (d - d_s) - e

        def dh_pl(y, args):
            bound_, d_s, _, m, g, _ = args
            d = d_s * jnp.exp(y)
            return (bound_.loading_force(d, 0.0, 1) - m * g) * d

        f_s = f_pl(d_s)
        y0 = jnp.log1p(2.25 * jnp.maximum(e_pl - u_s, 0.0) / (f_s * d_s)) / 2.25
        y_pl = newton_root(h_pl, y0, (bound, d_s, u_s, m, g, e_pl), fprime=dh_pl)
        d_pl = d_s * jnp.exp(y_pl)
        d_m = jnp.where(plastic, d_pl, d_el)
    else:
        plastic = False
        d_m = d_el

    # --- loading time -----------------------------------------------------------
    if two_phase:
        d_m_pl = jnp.where(plastic, d_pl, 1.5 * d_s)  # benign when unused
        s_s = jnp.sqrt(1.0 - d_s / d_m_pl)
        w_pl_total = _log_work(f_pl, d_s, jnp.log(d_m_pl / d_s), order)

        # Work of the plastic force from d up to d_m, needed at every node of
        # the travel-time quadrature: one spectral cumulative integral in
        # tau = log(d_m / d) / log(d_m / d_s) (the force is a smooth power law
        # in log d) instead of a Gauss rule per node (order x 16 force
        # evaluations; measured 4e-11 on the loading time, the same here).
        dt = jnp.result_type(d_m_pl, m)
        tau_nodes, cumulative = _cheb_cumulative(_CHEB_ORDER)
        log_span = jnp.log(d_m_pl / d_s)
        x = d_m_pl * jnp.exp(-jnp.asarray(tau_nodes, dt) * log_span)
        coef = jnp.asarray(cumulative, dt) @ (f_pl(x) * x * log_span)

        def drop_pl(s):  # d = d_m (1 - s^2) in [d_s, d_m]
            tau = -jnp.log1p(-(s * s)) / log_span
            return _cheb_eval(coef, tau) - m * g * d_m_pl * s * s

        t_pl = _travel_time(d_m_pl, drop_pl, m, order, 0.0, s_s)
        t_pl = jnp.where(plastic, t_pl, 0.0)
        a = jnp.where(plastic, d_s, d_m)
        s_lo = jnp.where(plastic, s_s, 0.0)
        w_top = jnp.where(plastic, w_pl_total, 0.0)
    else:
        t_pl, a, s_lo, w_top = 0.0, d_m, 0.0, 0.0

    def drop_el(s):  # s in [s_lo, 1], d = d_m (1 - s^2) in [0, a]
        rel = d_m * (s_lo * s_lo - s * s) / a  # (d - a) / a, exact
        w_diff = -k / (n + 1.0) * a ** (n + 1.0) * jnp.expm1((n + 1.0) * jnp.log1p(rel))
        return w_top + w_diff - m * g * d_m * s * s

    t_el = _travel_time(d_m, drop_el, m, order, s_lo, 1.0)
    t_load = t_pl + t_el

    # --- restitution (JG-8..JG-10) -----------------------------------------------
    if two_phase:
        f_m = jnp.where(plastic, f_pl(d_m_pl), f_el(d_m))
    else:
        f_m = f_el(d_m)
    d_r = bound.residual_deflection(d_m)
    stroke = d_m - d_r
    p = bound.unloading_exponent()
    elastic_energy = f_m * stroke / (p + 1.0)
    rebound_sq = 2.0 * (elastic_energy - m * g * stroke) / m
    # Gravity may hold back more than the stored elastic energy: then the
    # bodies never separate (the result code says so; the numbers are NaN).
    separates = rebound_sq > 0
    rebound_sq = jnp.where(separates, rebound_sq, 1.0)
    v_out = jnp.sqrt(rebound_sq)

    def drop_un(s):
        return (
            -elastic_energy * jnp.expm1((p + 1.0) * jnp.log1p(-(s * s)))
            - m * g * stroke * s * s
        )

    t_un = _travel_time(stroke, drop_un, m, order)
    return Timeline(
        mass=m,
        max_deflection=d_m,
        residual_deflection=d_r,
        peak_force=f_m,
        unloading_exponent=p,
        compression_time=t_load,
        restitution_time=t_un,
        rebound_velocity=v_out,
        separates=separates,
        order=order,
        drop_unloading=drop_un,
    )


class Timeline:
    """A normal impact solved by `normal_timeline`, and its state along
    the way (built and used inside one trace; not a pytree).

    Restitution is parametrised by ``r`` in ``[0, 1]``, ``d = d_m - (d_m -
    d_r) r^2`` (0 at maximum compression, 1 at separation); the normal
    velocity ``v_n`` is positive while approaching."""

    def __init__(self, **fields):
        self.__dict__.update(fields)

    @property
    def contact_time(self):
        return self.compression_time + self.restitution_time

    @property
    def stroke(self):
        return self.max_deflection - self.residual_deflection

    def restitution_travel(self, lo, hi=1.0):
        """Time to travel the restitution points ``[lo, hi]`` (0 for an empty
        span, evaluated on a benign one so that gradients stay finite)."""
        ok = hi - lo > 1e-12
        t = _travel_time(
            self.stroke,
            self.drop_unloading,
            self.mass,
            self.order,
            jnp.where(ok, lo, 0.0),
            jnp.where(ok, hi, 1.0),
        )
        return jnp.where(ok, t, 0.0)

    def restitution_velocity(self, r):
        """``v_n`` (< 0: receding) at the restitution point ``r`` (at ``r = 1``
        exactly ``-v_out``, where the potential's log form has no derivative)."""
        end = r > 1.0 - 1e-12
        drop = self.drop_unloading(jnp.where(end, 0.5, r))
        return jnp.where(
            end, -self.rebound_velocity, -safe_sqrt(2.0 * drop / self.mass)
        )

    def restitution_force(self, r):
        """``F = F_m ((d - d_r) / (d_m - d_r))^p = F_m (1 - r^2)^p`` [N] (JG-9)."""
        return self.peak_force * (1.0 - r * r) ** self.unloading_exponent

    def outputs(self) -> dict:
        return dict(
            contact_time=self.contact_time,
            compression_time=self.compression_time,
            rebound_velocity=self.rebound_velocity,
            max_deflection=self.max_deflection,
            num_steps=jnp.zeros((), jnp.int32),
            result=RESULTS.where(
                self.separates, RESULTS.successful, RESULTS.never_separates
            ),
        )


def solve_quadrature(problem, bound, settings) -> dict:
    """The outputs of `normal_timeline` (the ``"quadrature"`` method)."""
    return normal_timeline(problem, bound, settings).outputs()
