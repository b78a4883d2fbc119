"""The forms of a learned correction: a polynomial of the standardised
features and a small MLP, both zero until trained."""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array


class Polynomial(eqx.Module):
    """All monomials of the standardised features up to `degree` (the
    constant excluded: it is `Learned`'s), with coefficients from zero; one
    column of coefficients per output (``outputs`` None: a scalar)."""

    coefficients: Array
    powers: tuple[tuple[int, ...], ...] = eqx.field(static=True)

    def __init__(self, width: int, degree: int, outputs: int | None = None):
        self.powers = tuple(
            p
            for d in range(1, degree + 1)
            for p in itertools.combinations_with_replacement(range(width), d)
        )
        shape = (len(self.powers),) if outputs is None else (len(self.powers), outputs)
        self.coefficients = jnp.zeros(shape)

    def __call__(self, z):
        terms = jnp.stack([jnp.prod(z[jnp.asarray(p)]) for p in self.powers])
        return terms @ self.coefficients


class _Network(eqx.Module):
    """An MLP whose last layer starts at zero: the correction is zero, the
    parameter its constant, until training moves it (``outputs`` None: a
    scalar; else a vector of that many)."""

    mlp: eqx.nn.MLP

    def __init__(self, width_in: int, width: int, depth: int, key, outputs=None):
        out = "scalar" if outputs is None else outputs
        mlp = eqx.nn.MLP(width_in, out, width, depth, jax.nn.tanh, key=key)
        last = mlp.layers[-1]
        self.mlp = eqx.tree_at(
            lambda m: (m.layers[-1].weight, m.layers[-1].bias),
            mlp,
            (jnp.zeros_like(last.weight), jnp.zeros_like(last.bias)),
        )

    def __call__(self, z):
        return self.mlp(z)
