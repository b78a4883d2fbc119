"""Materials and effective contact properties (G-1, G-2, G-3)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from ._checks import AbstractValidated, as_float, check, positive

# Deepest interference, as a fraction of the effective radius, that the contact
# laws are used for: Hertz and the JG fits describe a contact small against the
# radius ((JG-6) has cos(pi a / R)).  simulate rejects impacts whose Hertz
# estimate goes deeper.
MAX_DEPTH = 0.5


class Material(AbstractValidated):
    """An isotropic, elastic-perfectly-plastic material (SI units).

    **Arguments:**

    - `youngs_modulus`: Young's modulus ``E`` [Pa], > 0.
    - `poisson_ratio`: Poisson's ratio ``nu``, in (-1, 0.5).
    - `yield_strength`: yield strength ``S_y`` [Pa], > 0; ``inf`` for a body that
      never yields.
    - `density`: density [kg/m^3], > 0 (used by scenes that derive masses).

    Every field is an array, so a material can be differentiated, vmapped or
    fitted like any other parameter.
    """

    youngs_modulus: Array = eqx.field(converter=as_float)
    poisson_ratio: Array = eqx.field(converter=as_float)
    yield_strength: Array = eqx.field(converter=as_float, default=jnp.inf)
    density: Array = eqx.field(converter=as_float, default=7850.0)

    def _checks(self):
        nu, s_y = self.poisson_ratio, self.yield_strength
        return [
            positive(self.youngs_modulus, "Material.youngs_modulus", "Pa"),
            check(
                nu,
                (nu > -1.0) & (nu < 0.5),
                "`Material.poisson_ratio` must lie in the open interval (-1, 0.5)",
            ),
            check(
                s_y,
                s_y > 0,
                "`Material.yield_strength` must be > 0 in Pa (inf for no yield)",
            ),
            positive(self.density, "Material.density", "kg/m^3"),
        ]


class ContactProperties(eqx.Module):
    """Effective properties of a contact pair, as the force laws use them.

    - `effective_modulus`: ``E*`` [Pa] (G-1).
    - `effective_radius`: ``R`` [m] (G-2).
    - `yield_strength`: ``S_y`` of the weaker material [Pa] (G-3).
    - `poisson_ratio`: ``nu`` of that same weaker material (used in JG-1).
    - `shear_modulus`: ``G* = 1 / ((2 - nu1)/G1 + (2 - nu2)/G2)`` [Pa], ``G_k =
      E_k / (2 (1 + nu_k))``, the effective shear modulus of Mindlin's
      tangential stiffness ``k_t = 8 G* a`` (Mindlin 1949; Johnson, *Contact
      Mechanics*, 1985, section 7.2).  None where
      the pair is not built from materials.
    """

    effective_modulus: Array
    effective_radius: Array
    yield_strength: Array
    poisson_ratio: Array
    shear_modulus: Array | None = None

    @property
    def hertz_stiffness(self):
        """``K = (4/3) E* sqrt(R)`` [N/m^1.5] (H-1)."""
        return 4.0 / 3.0 * self.effective_modulus * jnp.sqrt(self.effective_radius)


def effective_modulus(body: Material, other: Material):
    """``E* = 1 / ((1 - nu1^2)/E1 + (1 - nu2^2)/E2)`` (G-1)."""
    c1 = (1.0 - body.poisson_ratio**2) / body.youngs_modulus
    c2 = (1.0 - other.poisson_ratio**2) / other.youngs_modulus
    return 1.0 / (c1 + c2)


def effective_shear_modulus(body: Material, other: Material):
    """``G* = 1 / ((2 - nu1)/G1 + (2 - nu2)/G2)``, ``G = E / (2 (1 + nu))``
    (Mindlin's tangential compliance; Johnson 1985, eq. 7.42)."""

    def compliance(m):
        shear = m.youngs_modulus / (2.0 * (1.0 + m.poisson_ratio))
        return (2.0 - m.poisson_ratio) / shear

    return 1.0 / (compliance(body) + compliance(other))


def effective_radius(radius1, radius2=jnp.inf):
    """``R = R1 R2 / (R1 + R2)``; a flat (``R2 = inf``) gives ``R = R1`` (G-2)."""
    radius1 = as_float(radius1)
    radius2 = as_float(radius2)
    finite2 = jnp.isfinite(radius2)
    r2 = jnp.where(finite2, radius2, 1.0)
    return jnp.where(finite2, radius1 * r2 / (radius1 + r2), radius1)


def contact_properties(
    body: Material, other: Material, radius1, radius2=jnp.inf
) -> ContactProperties:
    """Effective properties of ``body`` (radius ``radius1``) on ``other`` (G-1..G-3).

    ``S_y`` and the Poisson ratio of JG-1 are those of the weaker material (the
    one with the lower yield strength), as (G-3) prescribes.
    """
    weaker_is_body = body.yield_strength <= other.yield_strength
    return ContactProperties(
        effective_modulus=effective_modulus(body, other),
        effective_radius=effective_radius(radius1, radius2),
        yield_strength=jnp.minimum(body.yield_strength, other.yield_strength),
        poisson_ratio=jnp.where(
            weaker_is_body, body.poisson_ratio, other.poisson_ratio
        ),
        shear_modulus=effective_shear_modulus(body, other),
    )
