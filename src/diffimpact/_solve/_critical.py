"""Critical impact angles: where a contact switches between sliding and sticking.

The switch is located on the smooth solve's slip diagnostics
(``result.extras["min_slip_ratio"]`` / ``["final_slip_ratio"]``, see
``_planar.py``) with a differentiable root search: Brent's method on
forward solves finds each root, and a custom_jvp supplies the implicit
derivative ``d angle / d theta = -(dg/dtheta) / (dg/d angle)`` (the rule of
``_root.newton_root``), so ``jax.grad`` of a critical angle with respect to any
parameter of the law, the friction or the scene works.

``newton_root`` itself is not called: its ``lax.while_loop`` compiles a solve
(~20 s) even for a root already known to 1e-9 rad, and its JVP rule runs the
loop again.  Here the primal costs forward solves only, and the derivative one
reverse-mode gradient at each root (compiled once, cached).  optimistix has
no Brent solver, and its bisection needs 27 forward solves to shrink a
0.1 rad bracket to 1e-9 rad, where Brent's method converges superlinearly.
"""

from __future__ import annotations

import math
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from .._laws._friction import Friction
from ._settings import SolverSettings
from ._simulate import simulate

_SETTINGS = SolverSettings()

# Level (in slip widths) at which a contact *with* tangential approach is taken
# to switch: the exact-hold law ends at 1/e widths when the sharp law ends at
# zero slip (docstring of `critical_angles`; the law's corner rounding and dead
# zone move it to 0.368058, 1.8e-4 widths: ~3e-8 rad on the ball, 1 % of the
# measured distance to the sharp law's angle).
_LEVEL_SLIDING = math.exp(-1.0)
# The coefficient of the contact held throughout (``criterion="impulse"``).
# The held tangential force stays finite as the normal force falls to 0 at
# separation (a vibrating tip's the most), so any coefficient lets the contact
# slip over a last, short tail, and the impulse ratio depends on it a little:
# between 1e3, 1e4 and 1e5 it changed by at most 3e-4 and 4e-4 relative
# (flexible bars, 3 + 3 modes, 5 to 70 deg), about 0.02 deg of a critical
# angle; 1e4 costs 1.5 times the steps.
_HOLDING = 1e3


def held_impulse_ratio(scene, law, *, settings: SolverSettings = _SETTINGS):
    """``|P_t| / P_n``: the ratio of the tangential to the normal impulse of
    `scene`'s contact held throughout (smooth solve with the friction
    coefficient `_HOLDING`), the static coefficient it needs not to slide
    (Wang & Fu 2019, eq. 22; ``critical_angles(..., criterion="impulse")``
    finds where it equals ``mu_s``).  Jittable and differentiable."""
    r = simulate(scene, law, "smooth", friction=Friction(_HOLDING), settings=settings)
    ex = r.extras
    p_t = ex["tangential_impulse_compression"] + ex["tangential_impulse_restitution"]
    return jnp.abs(p_t) / (r.impulse_compression + r.impulse_restitution)


def _indicator(angle, dyn, static, settings, level, criterion="slip"):
    """Signed stick/slip indicator at ``angle``, in slip widths: > 0 slides
    (`critical_angles`; with ``criterion="impulse"`` the impulse ratio of the
    held contact less the static coefficient)."""
    make, law, friction = eqx.combine(dyn, static)
    if criterion == "impulse":
        coefficient = friction.mu if friction.mu_s is None else friction.mu_s
        return held_impulse_ratio(make(angle), law, settings=settings) - coefficient
    # The smooth solve's slip diagnostics, also for a sphere (whose default is
    # the closed form, where a stuck contact's least slip is exactly 0 and the
    # indicator has no sign change).
    r = simulate(make(angle), law, "smooth", friction=friction, settings=settings)
    ex = r.extras
    approach = ex["tangential_velocity_contact_before"] != 0
    ratio = jnp.where(approach, ex["min_slip_ratio"], ex["final_slip_ratio"])
    if level is None:
        lev = jnp.where(approach, _LEVEL_SLIDING, friction.stick_band)
    else:
        lev = level
    return ratio / settings.slip_width - lev


_indicator_jit = eqx.filter_jit(_indicator)


def _concrete(tree):
    """The values of ``tree`` with derivatives cut; refuses tracers (jit)."""
    tree = jax.lax.stop_gradient(tree)
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree)):
        raise ValueError(
            "critical_angles cannot run under jax.jit / jax.vmap: how many critical "
            "angles there are depends on the values.  Call it outside jit; "
            "jax.grad and jax.jacfwd of its result work."
        )
    return tree


def _brent(f, xa, xb, fa, fb, xtol, max_iter):
    """Root of ``f`` in ``[xa, xb]`` (``fa fb < 0``) by Brent's method (scipy's
    ``brentq``: inverse quadratic interpolation with a bisection safeguard,
    which matters here: the indicator is flat on its stick side)."""
    xpre, xcur, fpre, fcur = xa, xb, fa, fb
    xblk = fblk = spre = scur = 0.0
    rtol = 4.0 * np.finfo(float).eps
    for _ in range(max_iter):
        if fpre != 0.0 and fcur != 0.0 and (fpre < 0.0) != (fcur < 0.0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = 0.5 * (xtol + rtol * abs(xcur))
        sbis = 0.5 * (xblk - xcur)
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:  # secant
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:  # inverse quadratic interpolation
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = (
                    -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
                )
            if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):
                spre, scur = scur, stry
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0 else -delta)
        fcur = f(xcur)
    return xcur


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _implicit_root(grad_fn, x, args):
    """``x``, a root of ``g(x, args) = 0`` found outside JAX, with the implicit
    derivative ``dx = -(dg/dargs . dargs) / (dg/dx)`` (the rule of
    `diffimpact._solve._root.newton_root`, linear in the tangents, so it
    transposes for reverse mode).  ``grad_fn(x, varied, fixed)`` returns
    ``(dg/dx, dg/dvaried)``; only the leaves of ``args`` with a nonzero tangent
    are differentiated (e.g. for ``d angle / d mu`` the law's calibration solve
    is not)."""
    return x


def _implicit_root_jvp(grad_fn, primals, tangents):
    x, args = primals
    _, args_dot = tangents
    is_zero = lambda t: isinstance(t, SymbolicZero)  # noqa: E731
    varied = jax.tree.map(lambda t: not is_zero(t), args_dot, is_leaf=is_zero)
    if not any(jax.tree.leaves(varied)):
        return x, jnp.zeros_like(x)
    var, fixed = eqx.partition(args, varied)
    var_dot, _ = eqx.partition(args_dot, varied, is_leaf=is_zero)
    dgdx, dgdv = grad_fn(x, var, fixed)
    terms = jax.tree.leaves(jax.tree.map(lambda g, t: jnp.sum(g * t), dgdv, var_dot))
    return x, -sum(terms) / dgdx


_implicit_root.defjvp(_implicit_root_jvp, symbolic_zeros=True)


def _split_indicator(x, var, fixed, static, settings, level, criterion):
    return _indicator(x, eqx.combine(var, fixed), static, settings, level, criterion)


_indicator_grad = eqx.filter_jit(jax.grad(_split_indicator, argnums=(0, 1)))


def critical_angles(
    make_scene,
    law,
    friction,
    angles,
    *,
    settings: SolverSettings = _SETTINGS,
    level: float | None = None,
    criterion: str = "slip",
    xtol: float = 1e-9,
    max_iter: int = 60,
):
    """Impact angles [rad] at which a frictional contact switches between
    sliding and sticking (smooth method).

    **Arguments:**

    - `make_scene`: a callable ``angle -> scene`` (a planar scene, e.g.
      ``lambda a: scenes.SphereOnIncline(m, r, ball, flat, a, h)`` or
      ``lambda a: scenes.FreeBar(m, bar, flat, height=h, tilt=a)``).  It may close
      over traced values (it is closure-converted), so derivatives with respect
      to a scene parameter flow too.
    - `law`, `friction`: the normal law and the `Friction`.
    - `angles`: a 1-D increasing grid of angles [rad] (concrete).  Each
      interval where the indicator changes sign holds one reported root; the
      grid must be fine enough to separate neighbouring roots.
    - `settings`: `SolverSettings` (default: the defaults).
    - `level`: the switching level in slip widths (default: see below).
    - `criterion`: ``"slip"`` (default): the contact's slip during the solve
      with `friction`, below; ``"impulse"``: Wang & Fu's (2019, eq. 22)
      ``Delta = |P_t| - mu_s |P_n|`` on the impulses of the contact held
      throughout, as the ratio ``g = |P_t| / P_n - mu_s`` (``mu_s`` the
      static coefficient of `friction`, else its ``mu``; its other fields and
      `level` are unused).  The held contact is solved with the coefficient
      1e3 (the held force stays finite as the normal force vanishes at
      separation, so it lets go over a short tail; the ratio is within 4e-4
      of its limit, ~0.02 deg of an angle).  For a contact that starts stuck
      (``v_t0 = 0``, a bar dropped without spin) this is the source's
      criterion; with a tangential approach the held solve first stops the
      slip.  For a rigid bar the two criteria agree to about 1e-3 rad; for a
      vibrating one (`scenes.FlexibleBar`) the final slip carries the tip's
      vibration at release, and the impulse criterion is the one that
      separates held from sliding contacts.
    - `xtol`, `max_iter`: stopping rule of the bracketing search [rad] (the
      indicator is noisy at ~3e-5 slip widths, ~5e-9 rad for the ball: a
      tighter `xtol` buys nothing).

    **Returns:** a 1-D array of the critical angles in increasing order (empty
    if the indicator changes sign nowhere on the grid).

    **Indicator.** In slip widths ``w = SolverSettings.slip_width``:
    ``g = s / w - level``, positive when the contact slides:

    - with a tangential approach (``v_t0 != 0``, e.g. a ball on an incline),
      ``s = min_slip_ratio``, how close the contact point came to stopping.
      On a ball the regularised law never lets it reverse (it approaches stick
      exponentially), so ``s`` stays >= 0 and the switch is taken at a level
      inside the band: for a contact whose tangential motion decouples from the
      normal one (``J_t M^-1 J_n^T = 0``, the ball), the exact-hold law of
      `Friction` is full Coulomb down to ``|v_t| = eps`` and linear
      below, ``dv_t/dP = -mu v_t / (m_t eps)`` per unit normal impulse
      (``m_t`` the tangential effective mass), so where the
      sharp law ends at zero slip the smooth one ends at ``exp(-1)`` widths.
      Default level: 0.368 (gravity and coupling leave an O(eps) bias).
    - with no tangential approach (``v_t0 = 0``, e.g. a bar dropped without
      spin, which starts stuck), ``s = final_slip_ratio``: a held contact ends
      at rest (exact hold), one that slides ends at ``O(v_ref)``.  Default
      level: ``friction.stick_band`` (5 widths).

    **Differentiation.** Each root is differentiated implicitly (one
    reverse-mode gradient of the solve at the root):
    ``jax.grad(lambda mu: critical_angles(make, law, Friction(mu), grid)[0])``
    works.  Not jittable (the number of roots depends on the values).
    """
    if criterion not in ("slip", "impulse"):
        raise ValueError(f"criterion={criterion!r}: expected 'slip' or 'impulse'")
    grid = np.asarray(angles, dtype=float)
    if grid.ndim != 1 or grid.size < 2 or not np.all(np.diff(grid) > 0):
        raise ValueError("`angles` must be a 1-D increasing grid of >= 2 angles")
    example = jnp.asarray(grid[0])
    # Closure-convert only a make_scene that closes over tracers (so their
    # derivatives flow); a plain function stays static, which lets the
    # compiled solve be reused across calls with the same function.
    make = eqx.filter_closure_convert(make_scene, example)
    if not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(make)):
        make = make_scene
    dyn, static = eqx.partition((make, law, friction), eqx.is_inexact_array)
    dyn_c = _concrete(dyn)

    def f(x):
        g = _indicator_jit(jnp.asarray(x), dyn_c, static, settings, level, criterion)
        return float(g)

    values = [f(a) for a in grid]
    roots = [a for a, v in zip(grid, values, strict=True) if v == 0.0]
    for i in range(grid.size - 1):
        fa, fb = values[i], values[i + 1]
        if fa * fb < 0.0:
            roots.append(_brent(f, grid[i], grid[i + 1], fa, fb, xtol, max_iter))
    if not roots:
        return jnp.zeros((0,), example.dtype)

    def grad_fn(x, var, fixed):
        return _indicator_grad(x, var, fixed, static, settings, level, criterion)

    return jnp.stack(
        [
            _implicit_root(grad_fn, jnp.asarray(x, example.dtype), dyn)
            for x in sorted(roots)
        ]
    )
