"""Running extrema of a solution, taken from the accepted steps.

A diagnostic such as the peak contact force or the least slip of the contact
point never feeds back into the motion.  Integrated as an ODE state it needs a
steep switch ("at the running maximum"), its own error weight, and it stops an
implicit solver's stage equations from converging.  Here it is not a state:
`TrackExtrema` wraps the user's solver and, after each step, refines the
extremum of a scalar function of the state inside the step on the solver's own
dense interpolant (samples, then a parabola through the best three), keeping the
running maximum and minimum in the solver state.  diffrax keeps the solver
state of accepted steps only, and returns the final one with
``SaveAt(solver_state=True)``.
"""

from __future__ import annotations

from collections.abc import Callable

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

# Samples per step (end points included), then the vertex of the parabola
# through the best sample and its neighbours (`_refine`).  No derivatives of the tracked
# function are taken, so tracking adds one vmapped evaluation per step to the
# compiled program: Newton on the interpolant's time derivative (nested
# `jax.grad`) measured the same accuracy but doubled the compile time of a
# planar solve's gradient.
_SAMPLES = 17


def _refine(fn, lo, hi, sign):
    """Extremum of ``sign * fn`` (maximum) on ``[lo, hi]``: the best sample,
    moved to the vertex of the parabola through it and its neighbours, where
    ``fn`` is evaluated again.  The location does not carry derivatives: at an
    extremum the value's derivative is the function's derivative at a fixed
    location (the envelope theorem), and the vertex's own derivative divides
    by the parabola's curvature, which makes forward and reverse mode differ
    by rounding amplified 1e4-fold where the extremum is flat."""
    u = jnp.linspace(0.0, 1.0, _SAMPLES, dtype=lo.dtype)
    ts = lo + (hi - lo) * u
    values = jax.vmap(fn)(ts) * sign
    i = jnp.clip(jnp.argmax(values), 1, _SAMPLES - 2)
    left, mid, right = values[i - 1], values[i], values[i + 1]
    curv = left - 2.0 * mid + right
    ok = curv < 0  # a maximum between the neighbours
    offset = jnp.clip(
        jnp.where(ok, 0.5 * (left - right) / jnp.where(ok, curv, -1.0), 0.0),
        -1.0,
        1.0,
    )
    t_vertex = jax.lax.stop_gradient(ts[i] + offset * (ts[1] - ts[0]))
    return jnp.maximum(jnp.max(values), sign * fn(t_vertex)) * sign


_MIRRORED = ("root_finder", "scan_kind")


class TrackExtrema(diffrax.AbstractWrappedSolver):
    """``solver`` plus the running maximum of ``peak(t, y, args)`` and the
    running minimum of ``least(t, y, args)`` (either None) over the accepted
    steps, in ``sol.solver_state[1]`` as ``(maximum, minimum)``."""

    solver: diffrax.AbstractSolver
    peak: Callable | None = eqx.field(static=True, default=None)
    least: Callable | None = eqx.field(static=True, default=None)
    # Fields that diffrax rewrites on the solver it is given (isinstance checks
    # see through the wrapper): an implicit solver's root finder gets the
    # step-size controller's tolerances, a Runge-Kutta solver's `scan_kind` is
    # set for forward-mode differentiation.  Mirrored here; `_inner` hands them
    # back to the wrapped solver.
    root_finder: object = None
    scan_kind: object = None

    def __init__(self, solver, peak=None, least=None):
        self.solver = solver
        self.peak = peak
        self.least = least
        self.root_finder = getattr(solver, "root_finder", None)
        self.scan_kind = getattr(solver, "scan_kind", None)

    def _inner(self):
        solver = self.solver
        for name in _MIRRORED:
            if hasattr(solver, name) and getattr(self, name) is not getattr(
                solver, name
            ):
                solver = eqx.tree_at(
                    lambda s, n=name: getattr(s, n),
                    solver,
                    getattr(self, name),
                    is_leaf=lambda x: x is None,
                )
        return solver

    @property
    def term_structure(self):
        return self.solver.term_structure

    @property
    def interpolation_cls(self):  # pyright: ignore
        return self.solver.interpolation_cls

    @property
    def term_compatible_contr_kwargs(self):
        return self.solver.term_compatible_contr_kwargs

    def order(self, terms):
        return self.solver.order(terms)

    def strong_order(self, terms):
        return self.solver.strong_order(terms)

    def error_order(self, terms):
        return self.solver.error_order(terms)

    def func(self, terms, t0, y0, args):
        return self._inner().func(terms, t0, y0, args)

    def _extrema(self, t0, y0, args):
        out = []
        for fn in (self.peak, self.least):
            out.append(None if fn is None else fn(t0, y0, args))
        return tuple(out)

    def init(self, terms, t0, t1, y0, args):
        inner = self._inner().init(terms, t0, t1, y0, args)
        return inner, self._extrema(t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        inner, (top, bottom) = solver_state
        y1, y_error, dense_info, inner, result = self._inner().step(
            terms, t0, t1, y0, args, inner, made_jump
        )
        interp = self.solver.interpolation_cls(t0=t0, t1=t1, **dense_info)
        lo, hi = jnp.asarray(t0), jnp.asarray(t1)
        if self.peak is not None:
            here = _refine(lambda t: self.peak(t, interp.evaluate(t), args), lo, hi, 1)
            top = jnp.maximum(top, here)
        if self.least is not None:
            here = _refine(
                lambda t: self.least(t, interp.evaluate(t), args), lo, hi, -1
            )
            bottom = jnp.minimum(bottom, here)
        return y1, y_error, dense_info, (inner, (top, bottom)), result


def track_extrema(solver, peak=None, least=None):
    """``solver`` wrapped to track the extrema, or ``solver`` itself when there
    is nothing to track."""
    if peak is None and least is None:
        return solver
    return TrackExtrema(solver, peak, least)
