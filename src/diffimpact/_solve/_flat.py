"""What every solve hands to ``diffrax.diffeqsolve`` and takes back from it.

The code reads and writes states as pytrees (`NormalState`, `PlanarState`,
`SpanState`); diffrax is given one flat vector.  The two integrate the same
numbers, but a pytree of scalar leaves makes XLA emit every Runge-Kutta
combination once per leaf, and on a CPU those small kernels dominate a small
state's step: measured side by side, a 1-DOF impact took 1.8x (events 2.2x)
and a slider-crank span 2.7x the time of the flat vector, for the same steps
and the same outputs.  Ravelled at the boundary, the solves run at the flat
vector's speed and the code keeps its names.
"""

from __future__ import annotations

import diffrax
import jax
from jax.flatten_util import ravel_pytree

from .._result import RESULTS


class Flat:
    """A state pytree's flat form: ``flat`` (the vector diffrax integrates)
    and the wrappers that let pytree-valued functions see it."""

    def __init__(self, y0):
        self.flat, self.unravel = ravel_pytree(y0)

    def field(self, field):
        """``field(t, y, args) -> pytree`` as a function of the flat state."""

        def flat_field(t, y, args):
            return ravel_pytree(field(t, self.unravel(y), args))[0]

        return flat_field

    def function(self, fn):
        """``fn(t, y, args, **kw)`` (an event condition, a tracked extremum)
        as a function of the flat state; None stays None."""
        if fn is None:
            return None

        def flat_fn(t, y, args, **kw):
            return fn(t, self.unravel(y), args, **kw)

        return flat_fn

    def saved(self, ys):
        """Saved flat states (a leading axis of save times) as pytrees."""
        return jax.vmap(self.unravel)(ys)


def solve_result(r) -> RESULTS:
    """diffrax's result code in our terms (its messages would not say which
    setting to change); an event that ended the solve is a success."""
    ended = (r == diffrax.RESULTS.successful) | (r == diffrax.RESULTS.event_occurred)
    return RESULTS.where(
        r == diffrax.RESULTS.max_steps_reached,
        RESULTS.max_steps_reached,
        RESULTS.where(ended, RESULTS.successful, RESULTS.solver_failed),
    )
