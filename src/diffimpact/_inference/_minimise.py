"""The optax minimisers of a fit (``"adam"``, ``"lbfgs"``): half the sum of
squares of the residuals, minimised step by step on the host."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import optax

from .._compile import filter_jit


def _loss(u, problem):
    r = problem.residuals(u)
    return 0.5 * jnp.sum(r**2)


@functools.cache
def _optimiser(name: str, learning_rate: float) -> optax.GradientTransformation:
    """One optimiser object per (name, learning rate): the step below is
    compiled once for it, not once per fit."""
    return optax.adam(learning_rate) if name == "adam" else optax.lbfgs()


@filter_jit
def _step(problem, opt, name, u, state):
    loss = functools.partial(_loss, problem=problem)
    if name == "adam":
        value, grad = jax.value_and_grad(loss)(u)
    else:
        value, grad = optax.value_and_grad_from_state(loss)(u, state=state)
    updates, state = opt.update(grad, state, u, value=value, grad=grad, value_fn=loss)
    return optax.apply_updates(u, updates), state, value, grad


def minimise(problem, u0, name, max_steps, rtol, atol, learning_rate, bar,
             on_accept=None):  # fmt: skip
    """``(u, steps, converged)``: steps until the gradient is below ``atol``
    or both the step and the change of the cost are within tolerances.
    ``on_accept``: None, or called as ``on_accept(u, step, cost)`` at each
    point whose cost a step has evaluated (the point before the step)."""
    opt = _optimiser(name, float(learning_rate))
    state = opt.init(u0)
    u, steps, converged, last = u0, 0, False, math.inf
    while steps < max_steps:
        u_new, state, value, grad = _step(problem, opt, name, u, state)
        steps += 1
        value = float(value)
        if on_accept is not None:
            on_accept(u, steps - 1, value)
        if bar:
            bar.update(steps, f"cost {value:.4g}")
        small_step = float(jnp.max(jnp.abs(u_new - u))) < rtol + atol
        small_change = abs(last - value) <= rtol * abs(value) + atol
        u, last = u_new, value
        if float(jnp.max(jnp.abs(grad))) <= atol or (small_step and small_change):
            converged = True
            break
    return u, steps, converged
