"""Partial slip in a compliant circular contact (Mindlin & Deresiewicz), by
the method of dimensionality reduction (F-16 .. F-18).

The contact of a sphere (effective radius ``R``) under varying normal and
tangential load is mapped, exactly for Hertz contacts of similar materials
(Heß 2011; Popov & Heß 2015; the equivalence used by Willert & Popov 2016
to recompute Maw, Barber & Fawcett's oblique impact), onto a row of
independent springs on the line ``x >= 0``: the spring at ``x`` touches once
the interference ``d`` passes ``x^2 / R``, carries the normal load ``E* (d -
x^2 / R)`` per unit length and a tangential one ``G_1 u(x)``, ``G_1 = 4 G*``
(``G*`` Mindlin's effective shear modulus), and obeys Coulomb's law on its
own: ``|G_1 u(x)| <= mu E* (d - x^2 / R)``.  A spring that enters the contact
starts unstressed, sticks (``du/dt = v_t``, the slip velocity of the contact
point) while below its cap and slides on it otherwise; the tangential force
is ``-2 G_1 int_0^a u dx``.  The stick region's stiffness is Mindlin's ``8 G*
a``; the springs at the edge, whose caps are smallest, slide first, which is
the annulus of micro-slip of Cattaneo and Mindlin, and the loading history
(which spring slid when, and how far) is what Mindlin & Deresiewicz's
incremental rules track.

Here ``int_0^a`` is the midpoint rule on ``n`` springs (``Friction.annuli``),
spaced ``Delta x`` over ``[0, sqrt(R d_cover)]``, ``d_cover = reach d_ref``
(``Friction.reach``).  The caps are rescaled so that they sum to ``mu F_n``
exactly (``F_n`` the normal law's force), so gross slip is Coulomb's force
for every ``n`` and every normal law (for Hertz, once many springs touch, the
rescaling corrects the rule's error in ``mu F_n``, ``O(Delta x^2)``; while one
or two touch, at first touch and separation, it is a correction of order one:
a single spring then carries all of ``mu F_n``).

The projection onto the cap (the sliding spring follows it) is smoothed for
the ODE: see `strip_rates`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# Sharpness of the stick/slide switch of a spring: the switch is spread over
# this fraction of ``mu d_ref`` in displacement.  Measured on a steel ball at
# 5 deg, mu 0.3, e_t against the hard-switched solve: 3.1e-4, 4.3e-5, 5.5e-6,
# 6.5e-7 at 1e-5 .. 1e-8, at 5,474, 5,413, 5,702, 6,013 steps (the error is
# the lag of the smoothed switch, the steps are the springs' switches).
_SWITCH = 1e-8
# Least coefficient the switch width is scaled with (so mu = 0 is not a
# division by zero; below it the switch is merely wider than the caps).
_MU_FLOOR = 1e-3
# Rate (per impact time unit ``d_ref / v0``) at which a spring beyond its cap,
# left there where the cap falls faster than the smoothed projection follows,
# is pulled back onto it.
_RELAX = 20.0


def annulus_depths(n: int, cover, dtype=None):
    """Interference ``x_i^2 / R`` at which each spring touches [m], for the
    midpoint rule on ``n`` springs over ``[0, sqrt(R cover)]``:
    ``cover (i - 1/2)^2 / n^2``."""
    i = jnp.arange(n, dtype=dtype) + 0.5
    return cover * (i / n) ** 2


def strip_stiffness(shear_modulus, radius, cover, n: int):
    """Tangential stiffness of one spring pair (``+-x``) [N/m]: ``2 G_1 Delta x``
    ``= 8 G* sqrt(R cover) / n``; the stuck contact's stiffness is this times
    the number of springs in contact, ``8 G* a`` to the rule's accuracy."""
    return 8.0 * shear_modulus * jnp.sqrt(radius * cover) / n


def caps(d, capacity, depths, stiffness):
    """Each spring's cap on its displacement [m]: ``mu E* (d - x_i^2/R) / G_1``
    rescaled so that ``stiffness * sum(caps) = capacity = mu F_n`` [N]; 0 out
    of contact (and everywhere before the first spring touches)."""
    load = jnp.maximum(d - depths, 0.0)
    total = jnp.sum(load)
    ok = total > 0
    scale = jnp.where(ok, capacity / (stiffness * jnp.where(ok, total, 1.0)), 0.0)
    return load * scale


def strip_force(displacement, cap, stiffness):
    """The contact's tangential force on the body [N]: ``-stiffness sum
    clip(u_i, -c_i, c_i)`` (a spring beyond its cap carries the cap)."""
    return -stiffness * jnp.sum(jnp.clip(displacement, -cap, cap))


def strip_rates(displacement, cap, cap_rate, slip_velocity, width, time_unit):
    """``du_i/dt`` [m/s] of every spring: the sweeping process

        ``du/dt = v_t``                     inside the cap,
        ``du/dt = min(v_t, dc/dt)``         on the upper cap (``u = c``),
        ``du/dt = max(v_t, -dc/dt)``        on the lower cap (``u = -c``),

    with the switch onto a cap a logistic of ``(|u| - c) / width`` and a pull
    back at ``_RELAX / time_unit`` of what lies beyond the cap (a spring left
    there while the smoothed switch lags a falling cap; zero below it)."""
    u, c = displacement, cap
    upper = jax.nn.sigmoid((u - c) / width)
    lower = jax.nn.sigmoid((-u - c) / width)
    rate = (
        slip_velocity
        - upper * jnp.maximum(slip_velocity - cap_rate, 0.0)
        + lower * jnp.maximum(-slip_velocity - cap_rate, 0.0)
    )
    beyond = jnp.maximum(u - c, 0.0) - jnp.maximum(-u - c, 0.0)
    return rate - _RELAX / time_unit * beyond


def switch_width(mu, length):
    """The stick/slide switch's width [m] (``_SWITCH``)."""
    return _SWITCH * jnp.maximum(mu, _MU_FLOOR) * length
