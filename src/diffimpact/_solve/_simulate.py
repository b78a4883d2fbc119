"""One impact, from first contact to separation: `simulate`.

`route` is the one decision of which solver an impact takes, a key of the
table `_SOLVERS`.  Three methods of the 1-DOF normal problem share one
post-processing step (``_normal._assemble``): ``"smooth"`` and ``"events"``
(diffrax solves, `._normal`) and ``"quadrature"`` (the ODE-free energy
solution, `._quadrature`); planar scenes with friction, or whose rotation
couples to the normal motion, are solved by `._planar`, or on request in
contact space (`._contact_space`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._checks import (
    guard,
    inputs_guarded,
    is_traced,
    require_scalars,
    require_type,
)
from .._compile import filter_jit
from .._laws._base import AbstractNormalLaw
from .._laws._friction import Friction
from .._result import (
    RESULTS,
    ImpactResult,
    finish,
    first_failure,
    raise_if_failed,
    with_invalid,
)
from ..scenes._base import AbstractScene
from ..scenes._planar import AbstractPlanarScene
from ._bind import _bind, within_model
from ._contact_space import contact_space_support, solve_contact_space
from ._normal import _assemble, _solve_events, _solve_smooth
from ._planar import solve_planar
from ._quadrature import normal_timeline
from ._settings import SolverSettings
from ._tangential import tangential_report

_METHODS = ("auto", "smooth", "events", "quadrature", "contact_space")


def _quadrature(problem, bound, settings, scene=None, friction=None):
    """The ODE-free path; with ``friction``, also the closed-form tangential
    outcome of ``scene`` (`._tangential`) under the key ``"tangential"``.

    Its travel times integrate ``1/sqrt(potential drop)`` near a turning
    point, where float32 cancellation can make the drop negative (NaN times,
    seen in the stress grid): a float32 impact is computed in float64 when JAX
    has it, and returned in float32.  Without x64 the outputs are checked, and
    a non-finite one is an error, never a silent NaN."""

    def solve(problem, bound, scene, friction):
        timeline = normal_timeline(problem, bound, settings)
        raw = timeline.outputs()
        if friction is not None:
            raw["tangential"] = tangential_report(
                scene, problem, timeline, friction, settings
            )
        return raw

    dtype = problem.velocity.dtype
    if _promotes(dtype):
        return _in_float64(solve, dtype, problem, bound, scene, friction)
    raw = solve(problem, bound, scene, friction)
    if dtype == jnp.float32:
        # (cor_tangential is inf by definition without a tangential
        # approach: not a lost precision)
        checked = {**raw, "tangential": dict(raw.get("tangential", {}))}
        checked["tangential"].pop("cor_tangential", None)
        finite = jnp.all(
            jnp.stack(
                [
                    jnp.all(jnp.isfinite(x))
                    for x in jax.tree.leaves(checked)
                    if eqx.is_inexact_array(x)
                ]
            )
        )
        raw["result"] = first_failure(
            raw["result"],
            RESULTS.where(finite, RESULTS.successful, RESULTS.precision_lost),
        )
    return raw


def _promotes(dtype) -> bool:
    """Whether an impact in ``dtype`` is solved in float64 (float32 where
    JAX has float64): the energy quadratures lose float32's precision near
    a turning point."""
    return dtype == jnp.float32 and jax.config.jax_enable_x64


def _in_float64(solve, dtype, *args):
    """``solve(*args)`` with every floating-point array in float64, its
    outputs returned in ``dtype``."""

    def cast(tree, to):
        return jax.tree.map(
            lambda x: x.astype(to) if eqx.is_inexact_array(x) else x, tree
        )

    return cast(solve(*cast(args, jnp.float64)), dtype)


def _exact_tangential(scene, friction) -> bool:
    """Whether the tangential outcome has the closed form of
    `._tangential` (the law must also be rate-independent): a scene
    whose slip decouples, with rigid friction and no viscous term."""
    return (
        isinstance(scene, AbstractPlanarScene)
        and scene.tangential_decouples
        and friction is not None
        and not friction.compliant
        and friction.stick == "hold"
        and friction.mu_v is None
    )


@filter_jit
def _simulate(inputs, method, settings, n_history, throw, invalid=None):
    # `inputs`: (scene, law, friction).
    # `invalid`: from `guard(..., throw=False)` (a bad row is solved anyway,
    # without the scenes' own checks, and reported as `invalid_input`).
    scene, law, friction = inputs
    with inputs_guarded():
        planar = isinstance(scene, AbstractPlanarScene)
        if planar:  # free flight to the contact in closed form, not integrated
            scene = scene.at_first_contact()
        solver = _SOLVERS[route(scene, law, friction, method, n_history)]
        res = solver(scene, law, friction, settings, n_history)
    result = with_invalid(res.result, invalid)
    res = eqx.tree_at(lambda r: r.result, res, result)
    return finish(res, result, throw)


def route(scene, law, friction, method: str, n_history: int) -> str:
    """Which solver of `_SOLVERS` an impact takes: the one decision
    `simulate` makes, from the scene's kind, the law's, the friction's and
    the method (all static structure, never traced numbers).

    ``"contact_space"`` where asked; ``"planar"`` (the planar ODE) for a
    planar scene with friction, or whose rotation couples to the normal
    motion, unless its tangential outcome has a closed form; otherwise the
    1-DOF normal problem, with no tangential state: ``"quadrature"`` (the
    ODE-free solution, and the closed-form tangential outcome) wherever
    ``"auto"`` allows it, else ``"smooth"`` or ``"events"``."""
    if method == "contact_space":
        return "contact_space"
    planar = isinstance(scene, AbstractPlanarScene)
    coupled = planar and (friction is not None or not scene.normal_decouples)
    # The ODE-free closed forms need a rate-independent power law: a
    # property of the bound law's class, which binding decides.
    bound_type = type(_bound_law(scene, law))
    closed_form = bound_type.power_law and not bound_type.rate_dependent
    exact = _exact_tangential(scene, friction) and closed_form
    if coupled and method == "quadrature" and not exact:
        raise ValueError(_NO_EXACT_TANGENTIAL)
    if coupled and not (exact and method in ("auto", "quadrature")):
        return "planar"
    # "auto": the exact ODE-free solution wherever it applies (a
    # rate-independent power law); the smooth ODE for other laws and for
    # histories.
    smooth = method == "smooth" or (
        method == "auto" and (not closed_form or n_history > 0)
    )
    if smooth and not coupled:
        return "smooth"
    return "events" if method == "events" else "quadrature"


def _bound_law(scene, law):
    """The law bound to the scene's normal problem, traced abstractly (no
    computation; a calibrated law's damping ratio, a root solve, is stood
    in for by zero): only its class is read."""

    def bind(s, w):
        return _bind(w, s.normal_problem(), jnp.zeros(()))

    return jax.eval_shape(bind, scene, law)


def _contact_space(scene, law, friction, settings, n_history):
    """Contact space: an energy quadrature like `_quadrature`, with its
    float32 policy (float64 where JAX has it; without, a non-finite outcome
    is `precision_lost`, in `solve_contact_space`)."""
    dtype = scene.initial_state()[1].dtype
    if _promotes(dtype):
        return _in_float64(solve_contact_space, dtype, scene, law, friction, settings)
    return solve_contact_space(scene, law, friction, settings)


def _planar(scene, law, friction, settings, n_history):
    return solve_planar(scene, law, friction, settings)


def _normal(solve):
    """A solver of the 1-DOF normal problem, assembled into an
    `ImpactResult` (the scene's extras, the tangential outcome where the
    quadrature gives one)."""

    def solver(scene, law, friction, settings, n_history):
        problem, bound, inside = within_model(law, scene.normal_problem())
        raw = solve(problem, bound, settings, n_history, scene, friction)
        tangential = raw.pop("tangential", {})
        result = first_failure(inside, raw.pop("result"))
        out = _assemble(problem, bound, raw)
        result = first_failure(result, _physical(out))
        extras = scene.extras(out["rebound_velocity"])
        if tangential:
            extras = {**extras, **tangential}
        elif isinstance(scene, AbstractPlanarScene):
            extras = {**extras, **scene.frictionless_report(out["contact_time"])}
        return ImpactResult(**out, extras=extras, result=result)

    return solver


_SOLVERS = {
    "contact_space": _contact_space,
    "planar": _planar,
    "smooth": _normal(
        lambda problem, bound, settings, n_history, scene, friction: _solve_smooth(
            problem, bound, settings, n_history
        )
    ),
    "events": _normal(
        lambda problem, bound, settings, n_history, scene, friction: _solve_events(
            problem, bound, settings
        )
    ),
    "quadrature": _normal(
        lambda problem, bound, settings, n_history, scene, friction: _quadrature(
            problem, bound, settings, scene, friction
        )
    ),
}


_NO_EXACT_TANGENTIAL = (
    "method='quadrature' with friction needs a scene whose tangential motion "
    "decouples (scenes.SphereOnIncline), rigid friction without a viscous "
    "term (Friction(mu) or Friction(mu, mu_s=...), not compliant, stick='hold', "
    "mu_v not given) and a rate-independent law (Hertz, JacksonGreen); use "
    "method='smooth' (the ODE) otherwise"
)


def _physical(out):
    """``unphysical`` for a head-on impact that returns more speed than it
    came with, or a dent outside ``[0, d_max]``: no passive contact does
    that, so constants far outside their sources' ranges (a negative decay
    in JG-5, say) or an unconverged quadrature are reported, not returned.
    The 1 % slack is far above the solvers' own errors at any sane setting
    (float32 included; a loose rtol makes an elastic COR 1 + 1e-5), and far
    below the nonsense it is there for (COR 1.5 to 13 in the cases found)."""
    d_m, d_r = out["max_deflection"], out["permanent_deformation"]
    tol = 1e-2
    ok = (
        (out["cor_newton"] <= 1.0 + tol)
        & (d_r >= -tol * d_m)
        & (d_r <= (1.0 + tol) * d_m)
    )
    return RESULTS.where(ok, RESULTS.successful, RESULTS.unphysical)


def check_structure(
    scene: AbstractScene,
    law: AbstractNormalLaw,
    method: str = "auto",
    friction=None,
    n_history: int = 0,
) -> None:
    """The checks of `simulate` on types and structure alone (which method
    can take this scene, law and friction), with no number read: a
    ValueError naming why, as `simulate` raises it.  Callers that set up many
    solves (`diffimpact.fit`) run it once before compiling anything."""
    if method not in _METHODS:
        raise ValueError(f"`method` must be one of {_METHODS}, got {method!r}")
    require_type(scene, AbstractScene, "`scene` must be a diffimpact scene")
    require_type(law, AbstractNormalLaw, "`law` must be a diffimpact contact law")
    if n_history < 0 or (n_history > 0 and method not in ("auto", "smooth")):
        raise ValueError(
            "`n_history` must be >= 0, and histories come from method='smooth'"
        )
    require_type(
        friction,
        Friction,
        "`friction` must be None or a diffimpact.Friction",
        optional=True,
    )
    planar = isinstance(scene, AbstractPlanarScene)
    if friction is not None and not planar:
        raise ValueError(
            f"`friction` acts on tangential motion, which {type(scene).__name__} "
            "(a head-on impact) does not have; use a planar scene such as "
            "scenes.SphereOnIncline"
        )
    if friction is not None and method == "events":
        raise ValueError(
            "friction is solved by method='smooth' (the ODE), or for a sphere "
            "with rigid friction by 'quadrature' (closed form); not by 'events'"
        )
    if (
        n_history > 0
        and planar
        and (friction is not None or not scene.normal_decouples)
    ):
        raise ValueError(
            "`n_history` gives the history of a 1-DOF impact; this planar solve "
            "has none (use n_history=0)"
        )
    if method == "contact_space":
        contact_space_support(scene, law, friction)
    elif (
        isinstance(scene, AbstractPlanarScene)
        and not scene.normal_decouples
        and method not in ("auto", "smooth")
    ):
        raise ValueError(
            f"{type(scene).__name__} is solved by method='smooth' only: its "
            "rotation couples to the normal motion, even without friction"
        )


def simulate(
    scene: AbstractScene,
    law: AbstractNormalLaw,
    method: str = "auto",
    *,
    friction=None,
    settings: SolverSettings = SolverSettings(),
    n_history: int = 0,
    throw: bool = True,
    _guarded: bool = True,
) -> ImpactResult:
    """Simulate one impact of ``scene`` under the normal contact ``law``.

    **Arguments:**

    - `scene`: e.g. `diffimpact.scenes.NormalImpact` or
      `diffimpact.scenes.Collinear`.
    - `law`: a normal force law (`Hertz`, `JacksonGreen`, ...).
    - `method`: ``"auto"`` (default), ``"smooth"``, ``"events"``, ``"quadrature"`` or
      ``"contact_space"``.  ``"smooth"`` integrates the smooth-switched ODE (every law,
      histories), ``"events"`` an event-switched one (1-DOF normal impacts), and
      ``"quadrature"`` solves a normal impact by energy integrals, without an ODE
      (rate-independent laws: Hertz, JacksonGreen; exact to about 1e-11).  With friction
      on a scene whose tangential motion decouples (a sphere on a plane) and rigid
      friction without a viscous term, ``"quadrature"`` also gives the tangential
      outcome in closed form (stick, re-slip and all; see
      `diffimpact._solve._tangential`). ``"contact_space"`` solves a rigid planar scene
      (`PlanarBody`, `FreeBar`, `RotatingLink`, `SphereOnIncline`) with a
      rate-independent power law and rigid Coulomb friction (or none) without an ODE,
      with the geometry frozen at first contact (`diffimpact._solve._contact_space`; its
      difference from the planar ODE, of the order of the rotation during the contact,
      is in docs/limits.md). ``"auto"`` takes ``"quadrature"`` wherever it applies, and
      ``"smooth"`` everywhere else (rate-dependent laws, coupled planar scenes,
      compliant or viscous friction, ``n_history > 0``).
    - `settings`: a `SolverSettings`.
    - `friction`: a `Friction` at the contact point, for planar scenes
      (e.g. `diffimpact.scenes.SphereOnIncline`); None = frictionless,
      which solves the decoupled 1-DOF normal problem (no tangential state).
    - `n_history`: number of equally spaced samples of deflection, velocity and
      force to return in ``result.history`` (``"smooth"`` only; 0 = none).
    - `throw`: what a failed impact or an invalid input value does.  True
      (default): raise, eagerly as a `SimulationError` subclass
      (`OutsideModelError`, ...) or, for an input outside its domain (a
      negative modulus, a NaN speed), `InvalidInputError` naming the field
      and the value; under ``jit``/``vmap`` as an ``equinox`` runtime error
      with the same message (docs/howto/layer.md).  False: never raise for a
      value: return NaN in every floating-point output and the reason in
      ``result.result`` (a `RESULTS` code, ``invalid_input`` for a bad
      input), leaving the other elements of a ``vmap`` batch untouched.
      Wrong types and structure (a string for a scene, an unknown method)
      raise either way, and so does building a module from a concrete bad
      value (``Material(205e9, 0.9)``: no result exists to carry a code).

    **Returns:** an `ImpactResult`.

    ``jax.jit``, ``jax.vmap`` and ``jax.grad`` compose with this function: every
    number in ``scene`` and ``law`` is a traced field.

    (`_guarded=False`, private: no traced check of the inputs, for callers
    that checked every input eagerly and keep traced values inside their
    domains, such as `diffimpact.fit`.  A traced check is a host
    callback, and JAX does not store a program with one in its persistent
    compilation cache.)
    """
    check_structure(scene, law, method, friction, n_history)
    require_type(
        settings, SolverSettings, "`settings` must be a diffimpact.SolverSettings"
    )
    # Every check of the inputs: eagerly a ValueError naming the field, before
    # any solve; traced, threaded through the inputs, so it runs first and
    # cannot be dropped (see `_checks.guard`).  (Raised instead from the
    # result's own check after the solve, a single jitted closed-form call
    # took 0.62x the time, but a vmapped batch 1.1x and a smooth one 1.1x:
    # XLA fused across the inputs; measured, not kept.)
    for name, part in (("scene", scene), ("law", law), ("friction", friction)):
        require_scalars(part, name)
    # (an array either way: eager calls with and without throw share a program)
    invalid = jnp.zeros((), bool)
    if _guarded and throw:
        scene, law, friction = guard((scene, law, friction))
    elif _guarded:
        (scene, law, friction), invalid = guard((scene, law, friction), throw=False)
    traced = is_traced((scene, law, friction))
    inputs = (scene, law, friction)
    res = _simulate(inputs, method, settings, n_history, throw and traced, invalid)
    if throw and not traced:
        raise_if_failed(res.result)
    return res
