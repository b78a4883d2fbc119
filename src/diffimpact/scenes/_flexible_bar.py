"""A free elastic bar dropped onto a flat at an angle: `FreeBar` with assumed
vibration modes (docs/physics/scenes.md).

Source: Wang & Fu, "Analytical study of Babbitt/steel composite structural bars
in oblique contact-impact with a solid flat surface", Mech. Sci. 10, 213-228
(2019), eqs. (6)-(10): the axial modes ``cos(i pi x / L)`` and the bending modes
of a free-free beam, ``cosh + cos - beta (sinh + sin)`` with ``cos(lambda)
cosh(lambda) = 1``.  They write the motion with Kane's equations over the full
kinetic energy; here the modes are taken about the mean axes of the bar
(Canavin & Likins, J. Spacecraft 14, 724 (1977); Agrawal & Shabana, Comput.
Struct. 21, 1303 (1985)), where the free-free modes of a uniform bar are
orthogonal to its rigid motions, so the mass matrix is diagonal at the
undeformed shape.  What that leaves out (our estimate, not the source's): the
coupling of the modes to the rotation through the deformed shape.  The
gyroscopic terms (``2 Omega G_ij q_dot_j``, ``G_ij`` the overlap of axial
shape ``i`` and bending shape ``j``: 0.98 for the second axial and first
bending one) and the mass matrix's first-order terms in ``q`` (``Omega_dot``
coupling) are of relative size ``Omega / omega`` ~ 2e-3 to 5e-3 of the modal
forces (``Omega`` ~ 50-100 rad/s during the impact, ``omega_b,1`` = 2.2e4 to
4.5e4 rad/s for the four bars of the source); the centrifugal ones
``(Omega / omega)^2`` ~ 1e-5.  Euler-Bernoulli bending at ``L / D = 8``
overestimates the bending frequencies by a few per cent (shear and rotary
inertia, Timoshenko), a larger error.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import check, optional_float
from ._bar import FreeBar
from ._base import scene_init


@functools.cache
def _bending_constants(n: int) -> tuple[tuple[float, ...], ...]:
    """``(lambda_i, 1 - beta_i, 1 + beta_i, beta_i, norm_i)`` of the first `n`
    free-free bending modes: ``cos(lambda) cosh(lambda) = 1`` solved by Newton
    from ``(i + 1/2) pi``; ``1 - beta`` in a form without cancellation (``beta
    -> 1`` as ``lambda`` grows); ``norm_i`` the root mean square of the shape
    over the bar (Gauss-Legendre, 200 points), so that every mode's modal mass
    is the bar's mass."""
    out = []
    nodes, weights = np.polynomial.legendre.leggauss(200)
    xi = 0.5 * (nodes + 1.0)
    for i in range(1, n + 1):
        lam = (i + 0.5) * math.pi
        for _ in range(50):
            f = math.cos(lam) * math.cosh(lam) - 1.0
            df = math.cos(lam) * math.sinh(lam) - math.sin(lam) * math.cosh(lam)
            lam -= f / df
        denominator = math.sinh(lam) - math.sin(lam)
        one_minus = (math.cos(lam) - math.sin(lam) - math.exp(-lam)) / denominator
        beta = 1.0 - one_minus
        shape = _bending_shape(np, xi, lam, one_minus, 1.0 + beta, beta)
        norm = math.sqrt(0.5 * float(np.sum(weights * shape**2)))
        out.append((lam, one_minus, 1.0 + beta, beta, norm))
    return tuple(out)


def _bending_shape(xp, xi, lam, one_minus, one_plus, beta):
    """``cosh + cos - beta (sinh + sin)`` at ``xi = x / L``, written as
    ``((1 - beta) e^z + (1 + beta) e^-z) / 2 + cos z - beta sin z``."""
    z = lam * xi
    return (
        0.5 * (one_minus * xp.exp(z) + one_plus * xp.exp(-z))
        + xp.cos(z)
        - beta * xp.sin(z)
    )


def _bending_slope(xp, xi, lam, one_minus, one_plus, beta):
    """``d shape / d xi`` of `_bending_shape`."""
    z = lam * xi
    return lam * (
        0.5 * (one_minus * xp.exp(z) - one_plus * xp.exp(-z))
        - xp.sin(z)
        - beta * xp.cos(z)
    )


@scene_init(angle="tilt (the bar's angle to the flat at first contact, rad)")
class FlexibleBar(FreeBar):
    """`FreeBar` whose bar vibrates: `axial_modes` axial and `bending_modes`
    bending modes of the free-free uniform bar (Wang & Fu 2019, eqs. 6-10)
    are added to its rigid motion.

    **Coordinates.** ``q = (x, y - y_0, theta - theta_0, a_1..a_na, b_1..b_nb)``:
    `FreeBar`'s three, then the modal amplitudes [m].  With ``x`` measured
    along the undeformed axis from the far end (``0 <= x <= L``) and ``e_a``,
    ``e_b`` the axis (towards the contact end) and its normal in the plane, a
    point of the axis moves by ``u(x) e_a + w(x) e_b`` with

        ``u = sum_i a_i sqrt(2) cos(i pi x / L)``  (axial),
        ``w = sum_i b_i psi_i(x)``,  ``psi_i = (cosh + cos - beta_i (sinh +
        sin))(lambda_i x / L) / norm_i``  (bending),

    each shape of root mean square 1 over the bar, so that every modal mass is
    the bar's mass ``m`` and its stiffness ``m omega_i^2``:

        ``omega_a,i = i pi c / L``,  ``omega_b,i = lambda_i^2 c r / L^2``,
        ``c = sqrt(E_s / rho)``, ``r = D / 4``

    (``rho = m / (A L)``, ``A = pi D^2 / 4``; ``r`` the radius of gyration of
    the circular section; Euler-Bernoulli bending, no rotary inertia or
    shear).  ``E_s`` is `structural_modulus`, by default the body's Young's
    modulus (Wang & Fu's composite modulus ``E_b(xi)``).  The tip's cap
    centre is the axis point ``x_c = L - R_b``; it moves with the modes, and
    the cap turns with the axis there (slope ``w'(x_c)``), so that

        ``d = R_b - y + (l + u_c) sin(theta) - w_c cos(theta)``,
        ``v_t = d/dt [x + (l + u_c) cos(theta) + w_c sin(theta)]
        - R_b d/dt [theta - w'_c]``,

    which are `FreeBar`'s when the modes are at rest.  Uniform gravity does no
    work on a free-free mode (each integrates to zero over the bar).

    **Energy.** ``result.extras["vibration_energy_after"]`` [J]: the modes'
    kinetic and strain energy at separation, taken from the rigid motion.
    The contact point's velocities after the impact include the tip's
    vibration at separation; the centre of mass's and the spin are the rigid
    motion.  The solve ends at the first separation: a vibrating tip that
    touches the flat again is not followed.  A mode with a node at the tip's
    centre (e.g. the 8th axial one for ``R_b / L = 1/16``) is not excited and
    stays at rest.

    **Arguments:** as `FreeBar`, and `axial_modes`, `bending_modes` (static
    ints >= 0; default 2 each; 0 and 0 is the rigid bar), `structural_modulus`
    [Pa] (default None: ``body.youngs_modulus``).  The bar meets the flat
    undeformed and at rest in its modes (it falls without spin).
    """

    rigid_coordinates: ClassVar[int | None] = 3

    axial_modes: int = eqx.field(static=True, default=2, kw_only=True)
    bending_modes: int = eqx.field(static=True, default=2, kw_only=True)
    structural_modulus: Array | None = eqx.field(
        converter=optional_float, default=None, kw_only=True
    )

    def _checks(self):
        out = super()._checks()
        for name in ("axial_modes", "bending_modes"):
            n = getattr(self, name)
            if isinstance(n, bool) or not isinstance(n, int) or n < 0:
                raise ValueError(
                    f"`FlexibleBar.{name}` must be an integer >= 0, got {n!r}"
                )
        if self.structural_modulus is not None:
            e = self.structural_modulus
            out.append(
                check(
                    e,
                    jnp.isfinite(e) & (e > 0),
                    "`FlexibleBar.structural_modulus` must be a finite number > 0 [Pa]",
                )
            )
        return out

    @property
    def modes(self) -> int:
        return self.axial_modes + self.bending_modes

    @property
    def frequencies(self) -> Array:
        """Natural frequencies ``omega_i`` [rad/s], axial then bending."""
        e = self.body.youngs_modulus
        if self.structural_modulus is not None:
            e = self.structural_modulus
        area = 0.25 * math.pi * self.diameter**2
        wave = jnp.sqrt(e * area * self.length / self.mass)  # c = sqrt(E / rho)
        axial = [
            i * math.pi * wave / self.length for i in range(1, self.axial_modes + 1)
        ]
        bending = [
            lam**2 * wave * 0.25 * self.diameter / self.length**2
            for lam, *_ in _bending_constants(self.bending_modes)
        ]
        return jnp.stack(axial + bending) if self.modes else jnp.zeros(0)

    def _tip_shapes(self):
        """``(phi, psi, psi')`` at the cap centre: the axial and bending shapes
        and the bending slopes ``d psi / dx`` [1/m]."""
        xi = 1.0 - self.radius / self.length
        phi = [
            math.sqrt(2.0) * jnp.cos(i * math.pi * xi)
            for i in range(1, self.axial_modes + 1)
        ]
        psi, slope = [], []
        for lam, one_minus, one_plus, beta, norm in _bending_constants(
            self.bending_modes
        ):
            psi.append(_bending_shape(jnp, xi, lam, one_minus, one_plus, beta) / norm)
            slope.append(
                _bending_slope(jnp, xi, lam, one_minus, one_plus, beta)
                / (norm * self.length)
            )
        stack = lambda v: jnp.stack(v) if v else jnp.zeros(0)  # noqa: E731
        return stack(phi), stack(psi), stack(slope)

    def mass_diagonal(self):
        rigid = super().mass_diagonal()
        return jnp.concatenate([rigid, jnp.full(self.modes, self.mass)])

    def initial_state(self):
        q0, q_dot0 = super().initial_state()
        rest = jnp.zeros(self.modes, q0.dtype)
        return jnp.concatenate([q0, rest]), jnp.concatenate([q_dot0, rest])

    def generalized_gravity(self):
        return jnp.concatenate(
            [super().generalized_gravity(), jnp.zeros(self.modes, self.mass.dtype)]
        )

    def internal_force(self, q):
        """The modes' elastic forces ``-m omega_i^2 q_i`` (0 on the rigid
        coordinates); None without modes (the rigid bar)."""
        if not self.modes:
            return None
        stiffness = self.mass * self.frequencies**2
        return jnp.concatenate([jnp.zeros(3, q.dtype), -stiffness * q[3:]])

    def kinematics(self, q):
        if not self.modes:
            return super().kinematics(q)
        na = self.axial_modes
        d_rigid, j_n, j_t = super().kinematics(q[:3])
        phi, psi, slope = self._tip_shapes()
        theta = self.tilt + q[2]
        s, c = jnp.sin(theta), jnp.cos(theta)
        u, w = phi @ q[3 : 3 + na], psi @ q[3 + na :]
        d = d_rigid + u * s - w * c
        j_n = jnp.concatenate([j_n.at[2].add(u * c + w * s), phi * s, -psi * c])
        j_t = jnp.concatenate(
            [j_t.at[2].add(-u * s + w * c), phi * c, psi * s + self.radius * slope]
        )
        return d, j_n, j_t

    def vibration_energy(self, q, q_dot):
        """Kinetic and strain energy of the modes [J]."""
        modal, rate = q[3:], q_dot[3:]
        return 0.5 * self.mass * jnp.sum(rate**2 + (self.frequencies * modal) ** 2)

    def report(self, q, q_dot):
        out = super().report(q, q_dot)
        out["vibration_energy_after"] = self.vibration_energy(q, q_dot)
        return out
