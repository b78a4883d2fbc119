"""Modified Jackson-Green three-phase law (JG-1 .. JG-10).

Source: Wang & Fu, Mech. Sci. 10 (2019), eqs. (25)-(31), following Ghaednia,
Marghitu and Jackson.  Every number of the fit is a field with the paper's
value as default, so any of them can be fitted like a material parameter.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, finite, positive
from .._materials import MAX_DEPTH, ContactProperties
from .._smooth import safe_div, safe_pow, safe_powers, safe_sqrt, step
from ._base import AbstractBoundLaw, AbstractNormalLaw

_f = eqx.field

_JG_FIELDS = (
    "c_a", "c_b", "elastic_limit", "ep_decay", "ep_decay_exponent",
    "hardness_scale", "hardness_exponent", "ep_exponent", "hg_a", "hg_b", "b_a",
    "b_b", "dr_a", "dr_b", "dr_c", "dr_exponent", "unloading_exponent",
)  # fmt: skip
_JG_POSITIVE = (
    "c_a", "elastic_limit", "hardness_scale", "hardness_exponent", "ep_exponent",
    "hg_a", "b_a", "dr_c", "unloading_exponent",
)  # fmt: skip


class JacksonGreen(AbstractNormalLaw):
    """Elastic (Hertz) loading, elasto-plastic loading beyond ``d* = 1.9``, and
    Hertzian restitution about the permanent deformation ``d_r``.

    **Arguments** (defaults: JG-1..JG-10, docs/physics/contact.md):

    - `c_a`, `c_b`: ``C = c_a exp(c_b nu)`` (JG-1); 1.295, 0.736.
    - `elastic_limit`: ``d*`` where elasto-plastic loading starts (JG-4/5); 1.9.
    - `ep_decay`, `ep_decay_exponent`: ``exp(-0.17 d*^(5/12))`` in JG-5.
    - `hardness_scale`, `hardness_exponent`, `ep_exponent`: 78, ``5/9``,
      ``1.1`` in the second term of JG-5, ``1 - exp(-d*^(5/9) / 78)`` and ``d*^1.1``.
    - `hg_a`, `hg_b`: ``H_G/S_y = 2.84 - 0.92 (1 - cos(pi a/R))`` (JG-6).
    - `b_a`, `b_b`: ``B = 0.14 exp(23 S_y / E*)`` (JG-6).
    - `dr_a`, `dr_b`, `dr_c`, `dr_exponent`: ``d_r = d_m 0.8 (1 - ((d_m/d_y + 5.5)
      / 6.5)^-2)`` (JG-8).
    - `unloading_exponent`: 3/2 in JG-10.
    - `yield_onset` (static): ``"elastic_limit"`` (default, ``d_y = 1.9 d_c`` as both
      source papers do) or ``"critical"`` (``d_y = d_c``, Jackson-Green's onset of
      sub-surface yield); see JG-8 in docs/physics/contact.md.
    - `continuous` (static): scale JG-5 so it meets Hertz at ``d* = 1.9``.  By
      default (False) the force drops by about 10 % there, as in the source.
    """

    c_a: Array = _f(converter=as_float, default=1.295)
    c_b: Array = _f(converter=as_float, default=0.736)
    elastic_limit: Array = _f(converter=as_float, default=1.9)
    ep_decay: Array = _f(converter=as_float, default=0.17)
    ep_decay_exponent: Array = _f(converter=as_float, default=5.0 / 12.0)
    hardness_scale: Array = _f(converter=as_float, default=78.0)
    hardness_exponent: Array = _f(converter=as_float, default=5.0 / 9.0)
    ep_exponent: Array = _f(converter=as_float, default=1.1)
    hg_a: Array = _f(converter=as_float, default=2.84)
    hg_b: Array = _f(converter=as_float, default=0.92)
    b_a: Array = _f(converter=as_float, default=0.14)
    b_b: Array = _f(converter=as_float, default=23.0)
    dr_a: Array = _f(converter=as_float, default=0.8)
    dr_b: Array = _f(converter=as_float, default=5.5)
    dr_c: Array = _f(converter=as_float, default=6.5)
    dr_exponent: Array = _f(converter=as_float, default=2.0)
    unloading_exponent: Array = _f(converter=as_float, default=1.5)
    yield_onset: Literal["elastic_limit", "critical"] = _f(
        static=True, default="elastic_limit"
    )
    continuous: bool = _f(static=True, default=False)

    def _checks(self):
        # Every constant of the fit is finite; the scales, exponents and the
        # elastic limit must be > 0 for the formulas to mean anything, and
        # d_r = dr_a (...) d_m < d_m needs 0 <= dr_a < 1 (JG-8).
        out = [finite(getattr(self, n), f"JacksonGreen.{n}") for n in _JG_FIELDS]
        out += [positive(getattr(self, n), f"JacksonGreen.{n}") for n in _JG_POSITIVE]
        out.append(
            check(
                self.dr_a,
                (self.dr_a >= 0) & (self.dr_a < 1),
                "`JacksonGreen.dr_a` must lie in [0, 1) (d_r < d_m, JG-8)",
            )
        )
        # JG-5's exponential is a decay; JG-8's base (d_m/d_y + dr_b)/dr_c
        # stays positive for every plastic impact (d_m >= d_y) with dr_b > -1,
        # and its power is a decay with dr_exponent > 0.
        out += [
            check(
                self.ep_decay,
                self.ep_decay >= 0,
                "`JacksonGreen.ep_decay` must be >= 0 (a decay, JG-5)",
            ),
            check(self.dr_b, self.dr_b > -1, "`JacksonGreen.dr_b` must be > -1 (JG-8)"),
            positive(self.dr_exponent, "JacksonGreen.dr_exponent"),
        ]
        return out

    def __check_init__(self):
        if self.yield_onset not in ("elastic_limit", "critical"):
            raise ValueError(
                "`JacksonGreen.yield_onset` must be 'elastic_limit' or 'critical', "
                f"got {self.yield_onset!r}"
            )

    def bind(self, contact: ContactProperties, approach_velocity):
        e_star = contact.effective_modulus
        radius = contact.effective_radius
        # A yield strength above E* is never reached (d_c would exceed the
        # radius); clamping keeps S_y = inf ("never yields") finite in every
        # branch, so gradients stay finite too.
        c = self.c_a * jnp.exp(self.c_b * contact.poisson_ratio)  # JG-1
        # A yield strength so high that the elasto-plastic switch lies deeper
        # than MAX_DEPTH * R is never reached by an impact the model accepts
        # (simulate rejects deeper ones): clamp it there.  That keeps S_y = inf
        # ("never yields") finite in every branch, and keeps the unused
        # elasto-plastic branch inside the range of its formulas, so gradients
        # through the branch select stay finite (a looser cap, S_y <= E*, puts
        # the switch ~12 R deep, where the unused branch has NaN gradients).
        s_cap = 2.0 * e_star / (jnp.pi * c) * jnp.sqrt(MAX_DEPTH / self.elastic_limit)
        s_y = jnp.minimum(contact.yield_strength, s_cap)
        d_c = (jnp.pi * c * s_y / (2.0 * e_star)) ** 2 * radius  # JG-2
        f_c = 4.0 / 3.0 * (radius / e_star) ** 2 * (jnp.pi * c * s_y / 2.0) ** 3
        b = self.b_a * jnp.exp(self.b_b * s_y / e_star)  # JG-6
        bound = BoundJacksonGreen(
            law=self,
            stiffness=contact.hertz_stiffness,
            radius=radius,
            c=c,
            d_c=d_c,
            f_c=f_c,
            b=b,
            ep_scale=jnp.ones_like(d_c),
        )
        if self.continuous:
            ds = bound.switch_deflection()
            scale = bound.loading_force(ds, 0.0, 0) / bound.loading_force(ds, 0.0, 1)
            bound = eqx.tree_at(lambda x: x.ep_scale, bound, scale)
        return bound


class BoundJacksonGreen(AbstractBoundLaw):
    law: JacksonGreen
    stiffness: Array  # K = (4/3) E* sqrt(R)  (H-1, JG-4)
    radius: Array
    c: Array  # JG-1
    d_c: Array  # JG-2
    f_c: Array  # JG-3
    b: Array  # JG-6
    ep_scale: Array  # 1, or the continuity factor of the `continuous` variant
    hysteretic: ClassVar[bool] = True
    rate_dependent: ClassVar[bool] = False
    n_loading_phases: ClassVar[int] = 2

    def scale(self):
        return self.stiffness, jnp.asarray(1.5)

    def switch_deflection(self):
        return self.law.elastic_limit * self.d_c

    def yield_deflection(self):
        """``d_y`` of JG-8."""
        if self.law.yield_onset == "critical":
            return self.d_c
        return self.switch_deflection()

    def _hertz(self, d):
        return self.stiffness * safe_pow(d, 1.5)  # (JG-4) = (H-1)

    def _elasto_plastic(self, d):
        """JG-5 with JG-6: force [N] at interference ``d`` [m]."""
        p = self.law
        ds = d / self.d_c
        # Four powers of d* share one logarithm (the hot path of the ODE).
        # (d*/1.9)^B keeps its own: B reaches 1e9 for a never-yielding pair,
        # and d*^B / 1.9^B would then be inf * 0.
        pw_decay, pw_hertz, pw_hard, pw_ep = safe_powers(
            ds, p.ep_decay_exponent, 1.5, p.hardness_exponent, p.ep_exponent
        )
        first = jnp.exp(-p.ep_decay * pw_decay) * pw_hertz
        a = safe_sqrt(self.radius * self.d_c * safe_pow(ds / p.elastic_limit, self.b))
        hg_over_sy = p.hg_a - p.hg_b * (1.0 - jnp.cos(jnp.pi * a / self.radius))
        hardening = 1.0 - jnp.exp(-pw_hard / p.hardness_scale)
        second = 4.0 * hg_over_sy / self.c * hardening * pw_ep
        return self.ep_scale * self.f_c * (first + second)

    def loading_force(self, d, v, phase: int):
        return self._hertz(d) if phase == 0 else self._elasto_plastic(d)

    def loading_force_smooth(self, d, v, phase_width):
        # Blend JG-4 into JG-5 across d* = elastic_limit (docs/physics/contact.md).
        s = step(d / self.d_c - self.law.elastic_limit, phase_width)
        return (1.0 - s) * self._hertz(d) + s * self._elasto_plastic(d)

    def residual_deflection(self, d_m):
        """Permanent deformation ``d_r`` (JG-8); 0 for ``d_m <= d_y``."""
        p = self.law
        x = jnp.maximum(d_m / self.yield_deflection(), 1.0)
        return d_m * p.dr_a * (1.0 - ((x + p.dr_b) / p.dr_c) ** (-p.dr_exponent))

    def unloading_force(self, d, v, d_m, f_m):
        """JG-10 with the restitution radius of JG-9, written as
        ``F = F_m ((d - d_r)/(d_m - d_r))^(3/2)``, so unloading starts at ``F_m``."""
        d_r = self.residual_deflection(d_m)
        # Below 1e-12 of d_c there is no dent to unload from.  (A bound near
        # the underflow limit let the derivative -num/den^2 overflow where a
        # span solve carries a vanishing d_m between impacts: inf * 0 = NaN.)
        ratio = safe_div(d - d_r, d_m - d_r, 1e-12 * self.d_c)
        return f_m * safe_pow(ratio, self.law.unloading_exponent)

    def restitution_radius(self, d_m, f_m):
        """``R_r = (3 F_m / (4 E*))^2 / (d_m - d_r)^3`` (JG-9) [m]."""
        e_star = 0.75 * self.stiffness / jnp.sqrt(self.radius)
        d_r = self.residual_deflection(d_m)
        return (0.75 * f_m / e_star) ** 2 / (d_m - d_r) ** 3

    def peak_force(self, d_m):
        d_s = self.switch_deflection()
        plastic = d_m > d_s
        # The source's force drops ~10 % at the switch, so just past it the
        # largest force is the Hertz force at d_s, not F(d_m).
        return jnp.where(
            plastic,
            jnp.maximum(self._elasto_plastic(d_m), self._hertz(jnp.minimum(d_s, d_m))),
            self._hertz(d_m),
        )

    def elastic_work(self, d):
        return self.stiffness * safe_pow(d, 2.5) / 2.5

    def unloading_exponent(self):
        return self.law.unloading_exponent
