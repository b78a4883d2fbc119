"""Residual physics: a learned correction added to what the solve predicts.

A learned parameter (`Learned`) can only move the impact within what its
law can express: a coefficient of restitution, a friction coefficient or a
tangential restitution changes the contact impulse, never the geometry the
solve assumes, the tracking of the measured body, or a mechanism the law
lacks.  Where the physics misses such a mechanism, a plain network trained
on enough rows predicts better than any parameter can make the physics
predict.  Residual physics keeps the solve and learns only its error
(Ajay et al., IROS 2018; Zeng et al., RSS 2019; on planar impacts Fazeli
et al., CoRL 2017, whose data-reinforced models correct a rigid contact
model by a learned term):

    ``y_q(x) = y_q^phys(x) + s_q f_q(z(x))``,  ``z = (x - shift) / scale``,

``y^phys`` the `Hybrid`'s physics (its learned parameters included), ``s_q``
the spread of quantity ``q`` over the training rows, ``f`` a small MLP or a
polynomial of the standardised features, zero at the start.  Training
penalises ``|f|^2`` on the training rows as it penalises a learned
parameter's correction, so with few rows the correction stays near zero and
the physics predicts; with many it takes up what the physics misses.

What it gives up: the correction is not an impulse, so the physics'
guarantees (impulses in Coulomb's cone, no energy gained) hold for
``y^phys`` only.  Use it where held-out error matters more than those, and
compare with the parameters alone (`learning_curve`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array

from ._corrections import Polynomial, _Network
from ._features import feature_names, feature_width

KINDS = ("mlp", "polynomial")

# The corrected quantities of a planar scene when none are named: the body's
# velocities after the impact, what tracked impacts measure.
PLANAR_OUTPUTS = ("velocity_x_after", "velocity_y_after", "angular_velocity")


class Residual(eqx.Module):
    """A learned correction of a `Hybrid`'s predicted outputs (residual
    physics).

    **Arguments:** `features`: names of the state it reads (as `Learned`'s:
    ``available_features(scene)``); `outputs`: the predicted quantities it
    corrects (None: a planar scene's velocities after the impact,
    ``velocity_x_after``, ``velocity_y_after``, ``angular_velocity``);
    `kind`: ``"mlp"`` (tanh, `width` x `depth`; the default) or
    ``"polynomial"`` (every monomial up to `degree`); `seed`: the MLP's
    initial weights.  The correction is zero until trained.

    Put in a `Hybrid` (``Hybrid(experiment, learned, residual=...)``), its
    features and outputs are checked against the scene, and `train` sets
    its scaling on the training rows (`with_scaling`).
    """

    features: tuple[str, ...] = eqx.field(static=True)
    outputs: tuple[str, ...] | None = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    correction: eqx.Module | None
    shift: Array
    scale: Array
    out_scale: Array | None
    settings: tuple[int, int, int, int] = eqx.field(static=True)

    def __init__(
        self,
        features,
        outputs=None,
        kind: str = "mlp",
        *,
        width: int = 16,
        depth: int = 2,
        degree: int = 2,
        seed: int = 0,
    ):
        self.features = feature_names(features)
        if not self.features:
            raise ValueError(
                "Residual needs at least one feature (e.g. features=("
                "'normal_speed', 'slip_ratio', 'orientation'))"
            )
        if isinstance(outputs, str):
            outputs = (outputs,)
        self.outputs = None if outputs is None else tuple(outputs)
        if self.outputs is not None and not self.outputs:
            raise ValueError("Residual.outputs: give at least one quantity, or None")
        if kind not in KINDS:
            raise ValueError(f"Residual.kind={kind!r}: expected one of {KINDS}")
        for name, value in (("width", width), ("depth", depth), ("degree", degree)):
            if isinstance(value, bool) or int(value) != value or int(value) < 1:
                raise ValueError(
                    f"Residual.{name} must be an integer >= 1, got {value}"
                )
        self.kind = kind
        self.settings = (int(width), int(depth), int(degree), int(seed))
        k = feature_width(self.features)
        self.shift, self.scale = jnp.zeros(k), jnp.ones(k)
        self.correction = None
        self.out_scale = None
        if self.outputs is not None:
            self.correction, self.out_scale = self._fresh(len(self.outputs))

    def _fresh(self, n_out: int):
        width, depth, degree, seed = self.settings
        k = feature_width(self.features)
        if self.kind == "mlp":
            net = _Network(k, width, depth, jr.PRNGKey(seed), outputs=n_out)
        else:
            net = Polynomial(k, degree, outputs=n_out)
        return net, jnp.ones(n_out)

    def bind(self, outputs) -> Residual:
        """This correction with its `outputs` set (where they were None)."""
        if self.outputs is not None:
            return self
        new = _with_outputs(self, tuple(outputs))
        correction, out_scale = new._fresh(len(new.outputs))
        return eqx.tree_at(
            lambda r: (r.correction, r.out_scale),
            new,
            (correction, out_scale),
            is_leaf=lambda x: x is None,
        )

    def with_scaling(self, x, y=None) -> Residual:
        """Standardise the features by the rows ``x`` (shape ``(n, k)``) and,
        given the measured outputs ``y`` (shape ``(n, len(outputs))``, NaN
        where not measured), scale each correction by its quantity's spread."""
        shift, scale = jnp.mean(x, axis=0), jnp.std(x, axis=0)
        scale = jnp.where(scale > 0, scale, 1.0)
        new = eqx.tree_at(lambda r: (r.shift, r.scale), self, (shift, scale))
        if y is not None:
            spread = jnp.nanstd(y, axis=0)
            spread = jnp.where(jnp.isfinite(spread) & (spread > 0), spread, 1.0)
            new = eqx.tree_at(lambda r: r.out_scale, new, spread)
        return new

    def deviation(self, x):
        """``f(z)``: the correction in units of each quantity's spread."""
        z = (x - jax.lax.stop_gradient(self.shift)) / jax.lax.stop_gradient(self.scale)
        return self.correction(z)

    def __call__(self, x):
        """The correction of each output [SI], at features ``x``."""
        return jax.lax.stop_gradient(self.out_scale) * self.deviation(x)


def _with_outputs(residual: Residual, outputs) -> Residual:
    new = object.__new__(Residual)
    for f in residual.__dataclass_fields__:
        object.__setattr__(new, f, getattr(residual, f))
    object.__setattr__(new, "outputs", outputs)
    return new
