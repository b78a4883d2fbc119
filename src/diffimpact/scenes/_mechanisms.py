"""Mechanisms with contacts that open and close many times.

A *mechanism* is a planar multibody system in generalised coordinates ``q``
(``n`` of them) whose contacts are penetration functions ``d_k(q)``.  It is
solved over a time span, free flight and every impact in one diffrax solve, by
`diffimpact.simulate_span`.  A scene states only geometry and inertia;
the solver builds Lagrange's equations from it:

- ``positions(q)``: the *weighted coordinates* ``r(q)`` of the bodies (a body's
  centre-of-mass ``x``, ``y`` and its rotation angle), with
  ``inertia_weights()`` the matching masses and moments of inertia ``w``.  The
  kinetic energy is ``T = 1/2 sum_i w_i r_i_dot^2``, so the mass matrix is
  ``M(q) = J^T diag(w) J`` with ``J = dr/dq``, and the velocity-dependent
  inertia forces are ``J^T diag(w) (dJ/dt) q_dot`` (both by automatic
  differentiation of ``positions``).
- ``potential(q)``: gravity [J]; ``applied_forces(t, q, q_dot)``: generalised
  non-conservative forces (a motor torque) [N or N m].
- ``kinematics(q)``: for every contact ``k`` the penetration ``d_k`` [m]
  (> 0 in contact), ``J_n,k`` with ``d_dot_k = J_n,k q_dot``, and ``J_t,k``
  with ``v_t,k = J_t,k q_dot`` the sliding velocity of the contact point.  The
  contact forces enter as ``-J_n^T F_n + J_t^T F_t`` (as in the planar
  scenes, docs/physics/scenes.md).

Units are SI.  The source of both scenes (Constantin et al., "The dynamic
impact study of a crank connecting rod mechanism", Acta Tech. Napocensis 65,
2022) works in ADAMS kg-mm-s units.  Converted here:

- ADAMS ``IMPACT`` stiffness for exponent ``e``: ``F`` is in kg mm s^-2 = 1e-3 N
  and ``g`` in mm, so ``k_SI = k * 1e-3 * 1e3^e`` N/m^e (``k = 250000``,
  ``e = 2`` -> 2.5e8 N/m^2, the `diffimpact.AdamsImpact` default);
  ``c_max`` [kg/s] is the same number in N s/m; ``d`` [mm] -> ``1e-3 d`` m.
- The Hertz stiffness ``K = 4/(3 pi (h1 + h2)) sqrt(R)`` the source evaluates
  from E in MPa (= N/mm^2) and R in mm is in N/mm^1.5; in SI it is
  ``K * 1e3^1.5`` N/m^1.5.  Here it is always computed from the materials
  (G-1, G-2), never typed in: steel/aluminium gives 249787.63
  N/mm^1.5 and steel/cast iron 331779.78 N/mm^1.5, 6.6e-5 and 3.8e-6 below the
  values the source prints (249804.08, 331781.04) from the same formula
  (tests/test_materials.py).
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import (
    AbstractValidated,
    as_float,
    check,
    finite,
    nonnegative,
    optional_float,
    positive,
)
from .._materials import ContactProperties, Material, contact_properties
from ._bar import AbstractRod, FreeBar
from ._base import scene_init


class MechanismScales(eqx.Module):
    """Reference magnitudes that make the solver's state O(1).

    - `coordinates`: a length (or 1 for an angle) per generalised coordinate,
      shape ``(n,)``.
    - `time` [s], `speed` [m/s] (also the reference of the smooth switches'
      widths), `energy` [J], `force` [N].
    """

    coordinates: Array
    time: Array
    speed: Array
    energy: Array
    force: Array


class AbstractMechanism(AbstractValidated):
    """What `diffimpact.simulate_span` needs from a scene (see the module
    docstring for the equations).

    Every method must return finite values for *any* state, not only the
    physical ones: the adaptive solver's rejected trial steps visit wild
    states, and a NaN there, although the step is discarded, turns the
    gradient into NaN (0 * NaN in the backward pass)."""

    @abc.abstractmethod
    def initial_state(self) -> tuple[Array, Array]:
        """``(q0, q_dot0)`` at the start of the span, shape ``(n,)`` each."""

    @abc.abstractmethod
    def positions(self, q) -> Array:
        """Weighted coordinates ``r(q)`` of the bodies, shape ``(m,)``."""

    @abc.abstractmethod
    def inertia_weights(self) -> Array:
        """Masses [kg] and moments of inertia [kg m^2] of ``r``, shape ``(m,)``."""

    @abc.abstractmethod
    def kinematics(self, q) -> tuple[Array, Array, Array]:
        """``(d, J_n, J_t)``: shapes ``(c,)``, ``(c, n)``, ``(c, n)``."""

    @abc.abstractmethod
    def contact(self) -> ContactProperties:
        """Effective properties of the contact pair (G-1..G-3), for binding laws."""

    @abc.abstractmethod
    def scales(self) -> MechanismScales:
        """Reference magnitudes of the solve."""

    def potential(self, q):
        """Potential energy of gravity [J] (default: none)."""
        return jnp.zeros((), jnp.result_type(q))

    def applied_forces(self, t, q, q_dot):
        """Generalised non-conservative applied forces, shape ``(n,)``."""
        return jnp.zeros_like(q)

    def report(self, t, q, q_dot, normal_force, friction_force) -> dict:
        """Scene outputs at one instant (a dict of arrays), vmapped over time."""
        return {}


# --------------------------------------------------------------------------
# A bar bouncing on a board.
# --------------------------------------------------------------------------


@scene_init(angle="tilt (the bar's angle to the board at the first impact, rad)")
class BouncingBar(AbstractRod, AbstractMechanism):
    """A free rigid bar with hemispherical ends dropped onto a flat board under
    gravity, bouncing until it settles (source: Constantin et al. 2022, section
    2.1, the bar on the flat board; docs/physics/scenes.md).

    The bar is the `FreeBar` of the single-impact solver (same fields,
    same geometry) with its *other* end able to touch too.  ``q = (x, y,
    theta)``: centre of mass and the angle between the bar axis and the board
    (the board is ``y = 0``); end A lies on the ``+x`` side and is the lower
    one for ``theta > 0``.  Both ends are hemispheres of radius ``R_b`` centred
    at ``l = L/2 - R_b`` from the centre of mass on the axis; the contact point
    of an end is the lowest point of its cap (docs/physics/scenes.md), so

        ``d_A = R_b + l sin(theta) - y``,   ``d_B = R_b - l sin(theta) - y``,
        ``J_n,A = (0, -1,  l cos(theta))``, ``J_t,A = (1, 0, -(l sin(theta) + R_b))``,
        ``J_n,B = (0, -1, -l cos(theta))``, ``J_t,B = (1, 0,   l sin(theta) - R_b)``.

    (The bar is a capsule: its lowest point is always the lowest point of one
    of the two end caps, so two contacts describe it at any angle, lying flat
    included.)  Mass ``m``, moment of inertia ``m L^2 / 12`` (``+ m D^2 / 16``
    with ``cross_section_inertia``); gravity ``m g y`` is the potential.

    **Start.** At rest, without spin, with the lowest point of end A ``height``
    ``h`` above the board at ``theta = tilt``: the first impact is exactly
    `first_impact` (a `FreeBar`), reached at ``v' = sqrt(2 g h)``.

    **Laws.** The source's board model is ADAMS ``IMPACT`` with (kg-mm-s)
    ``k = 250000``, ``e = 2``, ``c_max = 10``, ``d = 0.1``: in SI
    ``AdamsImpact(2.5e8, 2.0, 10.0, 1e-4)``, the defaults of
    `diffimpact.AdamsImpact` (conversion in the module docstring);
    its second model ``(k = 307692, e = 2.2 | 1.95, c_max = 0.08, d = 0.01)`` is
    ``AdamsImpact(307692 * 1e-3 * 1e3**e, e, 0.08, 1e-5)``.  ``Hertz()`` and
    ``JacksonGreen()`` use the materials (``R = R_b`` on a flat, G-2).  The
    source gives no bar dimensions for this model: the defaults are those of
    Wang & Fu (2019).

    **Arguments:** as `FreeBar`: `mass` [kg]; `body`, `flat`
    (materials); `height` ``h`` [m] (> 0); `length` [m] (0.08); `diameter` [m]
    (0.01); `tilt` [rad] in (0, pi/2] (pi/4); `tip_radius` [m] (``diameter /
    2``); `gravity` [m/s^2] (9.81); `cross_section_inertia` (static, False).

    `report` adds ``angle``, ``angular_velocity`` (``theta_dot``),
    ``height`` (``y``) and ``mechanical_energy``.
    """

    def first_impact(self) -> FreeBar:
        """The first impact as the single-impact scene (for
        `diffimpact.simulate`)."""
        return FreeBar(
            self.mass,
            self.body,
            self.flat,
            height=self.height,
            length=self.length,
            diameter=self.diameter,
            tilt=self.tilt,
            tip_radius=self.tip_radius,
            gravity=self.gravity,
            cross_section_inertia=self.cross_section_inertia,
        )

    def initial_state(self):
        a = self.tilt
        y0 = self.radius + self.arm * jnp.sin(a) + self.height
        zero = jnp.zeros_like(y0)
        return jnp.stack([zero, y0, a]), jnp.stack([zero, zero, zero])

    def positions(self, q):
        return q

    def inertia_weights(self):
        return jnp.stack([self.mass, self.mass, self.inertia])

    def potential(self, q):
        return self.mass * self.gravity * q[1]

    def kinematics(self, q):
        y, theta = q[1], q[2]
        r, arm = self.radius, self.arm
        s, c = jnp.sin(theta), jnp.cos(theta)
        one, zero = jnp.ones_like(s), jnp.zeros_like(s)
        d = jnp.stack([r + arm * s - y, r - arm * s - y])
        j_n = jnp.stack(
            [jnp.stack([zero, -one, arm * c]), jnp.stack([zero, -one, -arm * c])]
        )
        j_t = jnp.stack(
            [
                jnp.stack([one, zero, -(arm * s + r)]),
                jnp.stack([one, zero, arm * s - r]),
            ]
        )
        return d, j_n, j_t

    def contact(self):
        return contact_properties(self.body, self.flat, self.radius)

    def scales(self):
        speed = jnp.sqrt(2.0 * self.gravity * self.height)
        one = jnp.ones_like(self.length)
        return MechanismScales(
            coordinates=jnp.stack([self.length, self.length, one]),
            time=self.length / speed,
            speed=speed,
            energy=self.mass * self.gravity * self.height,
            force=self.mass * self.gravity,
        )

    def report(self, t, q, q_dot, normal_force, friction_force):
        kinetic = 0.5 * (
            self.mass * (q_dot[0] ** 2 + q_dot[1] ** 2) + self.inertia * q_dot[2] ** 2
        )
        return {
            "angle": q[2],
            "angular_velocity": q_dot[2],
            "height": q[1],
            "mechanical_energy": kinetic + self.potential(q),
        }


# --------------------------------------------------------------------------
# A slider-crank with a clearance in the piston-pin joint.
# --------------------------------------------------------------------------


def _safe_norm(x, y):
    """``sqrt(x^2 + y^2)`` with a zero (finite) gradient at the origin."""
    r2 = x * x + y * y
    ok = r2 > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, r2, 1.0)), 0.0)


class SliderCrank(AbstractMechanism):
    """Crank, connecting rod and piston with a radial clearance in the joint
    between the connecting rod's small end (the bearing) and the piston pin
    (source: Constantin et al. 2022, section 2.2).

    **Geometry.** The crank (length ``r``) turns about the origin by ``phi``;
    the crank pin ``A = r (cos phi, sin phi)`` is an ideal revolute joint.  The
    rod (length ``l``, centre of mass at ``a`` from ``A``) makes the angle
    ``beta`` with the ``x`` axis; its small end, the bearing centre, is at
    ``B = A + l (cos beta, sin beta)``.  The piston slides on the ``x`` axis
    (ideal, frictionless prismatic joint); its pin centre is ``P = (x_p, 0)``.
    The clearance joint is free: the eccentricity ``e = P - B`` is a degree of
    freedom, and the generalised coordinates are ``q = (phi, e_x, e_y)``, from
    which ``sin(beta) = -(r sin(phi) + e_y) / l`` and
    ``x_p = r cos(phi) + l cos(beta) + e_x``.  (The eccentricity, micrometres,
    is then a state of its own and keeps full precision.)

    **Journal-in-bearing contact.** Penetration ``d = |e| - c`` with the radial
    clearance ``c``; normal ``n = e / |e|`` (from bearing centre to pin
    centre), so ``J_n = (0, n_x, n_y)``.  The normal force ``F_n(d, d_dot)``
    is the chosen law's; it pushes the pin along ``-n`` and the rod along
    ``+n``.  Friction (Coulomb, F-1) acts on the sliding velocity of the pin's
    surface against the bearing's at the contact point, ``v_t = t . e_dot -
    R_b beta_dot`` with ``t = (-n_y, n_x)`` (the pin does not turn; the
    bearing turns with the rod).  The contact stiffness is Hertz's
    ``(4/3) E* sqrt(R)`` with ``R = R_pin R_bearing / (R_pin + R_bearing)``:
    the two cylinders treated as convex, as the source does (G-2;
    the conformal value ``R_pin R_bearing / (R_bearing - R_pin)`` would be
    2000 times larger).  Note that the source's radii (20 and 20.02 mm) differ
    by 0.02 mm while its radial clearance is 0.03 mm; the radii enter only
    ``K``, the clearance only ``d``.  With ``clearance = 0`` the joint is
    closed from the start and carries its load at the elastic deflection
    ``(F / K)^(2/3)``; the pin starts centred, so under an undamped law
    (Hertz) it also rings about that deflection after the motor's torque
    step (tests/test_multi.py, benchmarks/RESULTS.md).

    **Inertia.** Crank (with whatever turns with it) by its moment of inertia
    about the pivot ``J_O``; rod by mass ``m_2`` and moment of inertia ``J_2``
    about its centre of mass; piston (with its pin) by mass ``m_3``.  Gravity
    (``gravity`` > 0, along ``-y``) acts on the rod only (the crank is balanced,
    the piston slides horizontally); default 0: the mechanism lies in a
    horizontal plane.

    **Motor.** ``T_m = T_0 (1 - phi_dot / omega_0)`` on the crank (source eq.
    9).  The source's numbers (``T_0 = -9e-8``, ``omega_0 = 2``) come without
    usable units; ``omega_0 = 2 rad/s`` is kept, the sign is made positive.

    **Defaults.** The source gives the pin and bearing radii (20 and 20.02 mm),
    the clearance (0.03 mm) and the materials, but no dimensions or masses of
    the mechanism; ``r = 0.05 m``, ``l = 0.2 m``, ``m_2 = 1 kg``,
    ``m_3 = 0.8 kg``, ``J_O = 0.01 kg m^2``, ``T_0 = 0.1 N m`` are ours.  The
    mechanism starts at rest at ``phi = phi0`` with the pin centred in the
    bearing (``e = 0``).  Pin: steel (E 210 GPa, nu 0.3); bearing: aluminium
    (71 GPa, 0.33) by default; `cast_iron_bearing` gives the source's
    second pair (110 GPa, 0.28).

    **Arguments:** `crank_length` ``r`` [m]; `rod_length` ``l`` [m];
    `crank_inertia` ``J_O`` [kg m^2]; `rod_mass` ``m_2`` [kg]; `piston_mass`
    ``m_3`` [kg]; `rod_inertia` ``J_2`` [kg m^2] (None: ``m_2 l^2 / 12``);
    `rod_centre` ``a`` [m] (None: ``l / 2``); `clearance` ``c`` [m] (>= 0);
    `pin_radius`, `bearing_radius` [m]; `pin`, `bearing` (materials);
    `motor_torque` ``T_0`` [N m]; `motor_speed` ``omega_0`` [rad/s] (> 0);
    `crank_angle` ``phi0`` [rad]; `gravity` [m/s^2] (>= 0).

    `report` gives ``piston_position`` ``x_p``, ``crank_angle``,
    ``crank_speed``, ``rod_angle``, ``motor_torque``, the contact force on the
    pin ``joint_force_x``, ``joint_force_y`` (normal plus friction) [N], its
    magnitude ``joint_force``, and ``ideal_piston_position`` (the rigid
    mechanism's closed form at the same crank angle).
    """

    crank_length: Array = eqx.field(converter=as_float, default=0.05)
    rod_length: Array = eqx.field(converter=as_float, default=0.2)
    crank_inertia: Array = eqx.field(converter=as_float, default=0.01)
    rod_mass: Array = eqx.field(converter=as_float, default=1.0)
    piston_mass: Array = eqx.field(converter=as_float, default=0.8)
    rod_inertia: Array | None = eqx.field(converter=optional_float, default=None)
    rod_centre: Array | None = eqx.field(converter=optional_float, default=None)
    clearance: Array = eqx.field(converter=as_float, default=3e-5)
    pin_radius: Array = eqx.field(converter=as_float, default=0.02)
    bearing_radius: Array = eqx.field(converter=as_float, default=0.02002)
    # Made per instance, not at import: an array created at import would
    # start JAX's backend in the host program (and fix its dtype before the
    # host chooses float64).
    pin: Material = eqx.field(default_factory=lambda: Material(210e9, 0.3))
    bearing: Material = eqx.field(default_factory=lambda: Material(71e9, 0.33))
    motor_torque: Array = eqx.field(converter=as_float, default=0.1)
    motor_speed: Array = eqx.field(converter=as_float, default=2.0)
    crank_angle: Array = eqx.field(converter=as_float, default=0.0)
    gravity: Array = eqx.field(converter=as_float, default=0.0)

    def _checks(self):
        out = [
            positive(getattr(self, name), f"SliderCrank.{name}", unit)
            for name, unit in [
                ("crank_length", "m"),
                ("rod_length", "m"),
                ("crank_inertia", "kg m^2"),
                ("rod_mass", "kg"),
                ("piston_mass", "kg"),
                ("pin_radius", "m"),
                ("bearing_radius", "m"),
                ("motor_speed", "rad/s"),
            ]
        ]
        if self.rod_inertia is not None:
            out.append(positive(self.rod_inertia, "SliderCrank.rod_inertia", "kg m^2"))
        if self.rod_centre is not None:
            out.append(nonnegative(self.rod_centre, "SliderCrank.rod_centre", "m"))
        return out + [
            nonnegative(self.clearance, "SliderCrank.clearance", "m"),
            nonnegative(self.gravity, "SliderCrank.gravity", "m/s^2"),
            finite(self.motor_torque, "SliderCrank.motor_torque"),
            finite(self.crank_angle, "SliderCrank.crank_angle"),
            check(
                self.rod_length,
                self.rod_length > self.crank_length + self.clearance,
                "`SliderCrank.rod_length` must exceed crank_length + clearance",
            ),
        ]

    def cast_iron_bearing(self) -> SliderCrank:
        """The same mechanism with the source's steel/cast-iron pair
        (bearing E = 110 GPa, nu = 0.28; Constantin et al. 2022)."""
        return eqx.tree_at(lambda s: s.bearing, self, Material(110e9, 0.28))

    @property
    def hertz_stiffness(self):
        """``K = (4/3) E* sqrt(R)`` [N/m^1.5] of the pin-bearing pair (G-1, G-2,
        H-1); ``K / 1e3**1.5`` is the source's N/mm^1.5 value."""
        return self.contact().hertz_stiffness

    @property
    def _rod_inertia(self):
        if self.rod_inertia is None:
            return self.rod_mass * self.rod_length**2 / 12.0
        return self.rod_inertia

    @property
    def _rod_centre(self):
        return 0.5 * self.rod_length if self.rod_centre is None else self.rod_centre

    def rod_angle(self, q):
        """``beta(q)`` [rad]."""
        phi, ey = q[0], q[2]
        s = -(self.crank_length * jnp.sin(phi) + ey) / self.rod_length
        # Continued linearly beyond |s| = 0.99 (C^1): a rejected trial step of
        # the adaptive solver may visit a state without a rod angle, and a NaN
        # there, even discarded, poisons the gradient (0 * NaN in the backward
        # pass).  Real states have |s| <= (r + c) / l.
        s0 = 0.99
        inside = jnp.abs(s) < s0
        s_in = jnp.where(inside, s, 0.0)
        edge = jnp.sign(s) * jnp.arcsin(s0)
        linear = edge + (s - jnp.sign(s) * s0) / math.sqrt(1.0 - s0 * s0)
        return jnp.where(inside, jnp.arcsin(s_in), linear)

    def piston_position(self, q):
        """``x_p = r cos(phi) + l cos(beta) + e_x`` [m]."""
        return (
            self.crank_length * jnp.cos(q[0])
            + self.rod_length * jnp.cos(self.rod_angle(q))
            + q[1]
        )

    def ideal_piston_position(self, phi):
        """Rigid mechanism, no clearance [m]:
        ``r cos(phi) + sqrt(l^2 - r^2 sin^2(phi))``."""
        r, l = self.crank_length, self.rod_length
        return r * jnp.cos(phi) + jnp.sqrt(l**2 - (r * jnp.sin(phi)) ** 2)

    def initial_state(self):
        zero = jnp.zeros_like(self.crank_angle)
        return jnp.stack([self.crank_angle, zero, zero]), jnp.stack([zero, zero, zero])

    def positions(self, q):
        phi = q[0]
        beta = self.rod_angle(q)
        r, a = self.crank_length, self._rod_centre
        x_g = r * jnp.cos(phi) + a * jnp.cos(beta)
        y_g = r * jnp.sin(phi) + a * jnp.sin(beta)
        return jnp.stack([phi, x_g, y_g, beta, self.piston_position(q)])

    def inertia_weights(self):
        m2, m3 = self.rod_mass, self.piston_mass
        return jnp.stack([self.crank_inertia, m2, m2, self._rod_inertia, m3])

    def potential(self, q):
        return self.rod_mass * self.gravity * self.positions(q)[2]

    def motor(self, crank_speed):
        """``T_m = T_0 (1 - phi_dot / omega_0)`` [N m] (source eq. 9)."""
        return self.motor_torque * (1.0 - crank_speed / self.motor_speed)

    def applied_forces(self, t, q, q_dot):
        zero = jnp.zeros_like(q_dot[0])
        return jnp.stack([self.motor(q_dot[0]), zero, zero])

    def kinematics(self, q):
        ex, ey = q[1], q[2]
        norm = _safe_norm(ex, ey)
        pos = norm > 0
        inv = jnp.where(pos, 1.0 / jnp.where(pos, norm, 1.0), 0.0)
        nx, ny = ex * inv, ey * inv
        zero = jnp.zeros_like(nx)
        j_n = jnp.stack([zero, nx, ny])[None, :]
        dbeta = jax.grad(lambda qq: self.rod_angle(qq))(q)
        j_t = (jnp.stack([zero, -ny, nx]) - self.bearing_radius * dbeta)[None, :]
        return (norm - self.clearance)[None], j_n, j_t

    def contact(self):
        return contact_properties(
            self.pin, self.bearing, self.pin_radius, self.bearing_radius
        )

    def scales(self):
        r, w0 = self.crank_length, self.motor_speed
        c = jnp.maximum(self.clearance, 1e-3 * r)
        inertia = self.crank_inertia + (self.rod_mass + self.piston_mass) * r**2
        energy = 0.5 * inertia * w0**2
        return MechanismScales(
            coordinates=jnp.stack([jnp.ones_like(r), c, c]),
            time=1.0 / w0,
            speed=r * w0,
            energy=energy,
            force=energy / r,
        )

    def report(self, t, q, q_dot, normal_force, friction_force):
        _, j_n, j_t = self.kinematics(q)
        nx, ny = j_n[0, 1], j_n[0, 2]
        f_n, f_t = normal_force[0], friction_force[0]
        # Force of the bearing on the pin: -F_n n + F_t t, t = (-n_y, n_x).
        fx = -f_n * nx - f_t * ny
        fy = -f_n * ny + f_t * nx
        return {
            "piston_position": self.piston_position(q),
            "ideal_piston_position": self.ideal_piston_position(q[0]),
            "crank_angle": q[0],
            "crank_speed": q_dot[0],
            "rod_angle": self.rod_angle(q),
            "motor_torque": self.motor(q_dot[0]),
            "joint_force_x": fx,
            "joint_force_y": fy,
            "joint_force": _safe_norm(fx, fy),
        }
