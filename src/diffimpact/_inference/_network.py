"""The physics-free baseline: an MLP from a row's inputs to its measured
outputs, trained and judged exactly as a `Hybrid` is.

Learned models of impact (Fazeli et al., CoRL 2017; Ajay et al., IROS 2018)
are compared with such a network: with many rows it fits what a constant-
parameter law cannot, with few it has nothing to fall back on.  A hybrid
is worth its physics where it beats both.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array

from ..scenes._planar import AbstractPlanarScene
from ._experiment import Experiment, si_inputs
from ._scenes import scene_spec


class VelocityNetwork(eqx.Module):
    """A plain MLP from the pre-impact inputs of a row to its outputs.

    **Arguments:** `experiment` (only its scene's input names are used:
    the network knows no physics); `inputs`: the input quantities it reads
    (``orientation`` enters as its cosine and sine); `outputs`: the
    quantities it predicts; `width`, `depth` (tanh hidden layers), `seed`.
    Inputs and outputs are standardised on the training rows
    (`with_scaling`).
    """

    mlp: eqx.nn.MLP
    inputs: tuple[str, ...] = eqx.field(static=True)
    outputs: tuple[str, ...] = eqx.field(static=True)
    in_shift: Array
    in_scale: Array
    out_shift: Array
    out_scale: Array
    # The scene's mass-matrix diagonal, for the kinetic-norm error only
    # (`relative_errors`); the network itself never reads it.
    mass_diagonal: tuple[float, ...] | None = eqx.field(static=True)

    def __init__(
        self,
        experiment: Experiment,
        inputs,
        outputs,
        *,
        width: int = 32,
        depth: int = 2,
        seed: int = 0,
    ):
        spec = scene_spec(experiment.scene)
        spec.refuse_unknown(inputs, "VelocityNetwork: input(s)")
        if not outputs:
            raise ValueError("VelocityNetwork: give at least one output quantity")
        self.inputs, self.outputs = tuple(inputs), tuple(outputs)
        scene = experiment.scene
        self.mass_diagonal = (
            tuple(float(m) for m in scene.mass_diagonal())
            if isinstance(scene, AbstractPlanarScene)
            else None
        )
        k = sum(2 if q == "orientation" else 1 for q in self.inputs)
        self.mlp = eqx.nn.MLP(
            k,
            len(self.outputs),
            int(width),
            int(depth),
            jax.nn.tanh,
            key=jr.PRNGKey(seed),
        )
        self.in_shift, self.in_scale = jnp.zeros(k), jnp.ones(k)
        self.out_shift = jnp.zeros(len(self.outputs))
        self.out_scale = jnp.ones(len(self.outputs))

    def _x(self, inputs: dict):
        parts = []
        for q in self.inputs:
            v = jnp.asarray(inputs[q], float)
            parts.extend([jnp.cos(v), jnp.sin(v)] if q == "orientation" else [v])
        return jnp.stack(parts)

    def predict(self, inputs: dict, *, throw: bool = True) -> dict:
        """The predicted outputs of one row (a dict keyed by quantity, SI)."""
        del throw  # a network never fails
        x = self._x(inputs)
        z = (x - jax.lax.stop_gradient(self.in_shift)) / jax.lax.stop_gradient(
            self.in_scale
        )
        y = self.mlp(z) * jax.lax.stop_gradient(self.out_scale) + jax.lax.stop_gradient(
            self.out_shift
        )
        return dict(zip(self.outputs, y, strict=True))

    def penalty(self, inputs: dict):
        del inputs
        return jnp.zeros(())

    def with_scaling(self, rows: dict, outputs: dict | None = None) -> VelocityNetwork:
        """Standardise the inputs on ``rows`` and the outputs on ``outputs``
        (quantity -> array, NaN where not measured)."""
        x = jax.vmap(self._x)(rows)
        shift, scale = jnp.mean(x, axis=0), jnp.std(x, axis=0)
        new = eqx.tree_at(
            lambda m: (m.in_shift, m.in_scale),
            self,
            (shift, jnp.where(scale > 0, scale, 1.0)),
        )
        if outputs is not None:
            y = jnp.stack([jnp.asarray(outputs[q]) for q in self.outputs], axis=1)
            o_shift, o_scale = jnp.nanmean(y, axis=0), jnp.nanstd(y, axis=0)
            new = eqx.tree_at(
                lambda m: (m.out_shift, m.out_scale),
                new,
                (o_shift, jnp.where(o_scale > 0, o_scale, 1.0)),
            )
        return new


def network_inputs(experiment: Experiment, data_inputs) -> tuple[str, ...]:
    """The inputs a `VelocityNetwork` reads from a file: those it gives."""
    return tuple(si_inputs(experiment, {q: 0.0 for q in data_inputs}))
