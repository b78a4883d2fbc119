"""Features of an impact's state that a learned function reads: the
contact-space description of the first contact of a planar scene, and any
input of the scene's rows."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float
from ..scenes._planar import AbstractPlanarScene
from ._experiment import Experiment
from ._scenes import scene_spec

# Features of the state at first contact, from the contact-space
# quantities of a planar scene (contact-space page, CS-1): with the contact
# Jacobians J_n (into the flat), J_t and the mass matrix M, the approach
# speed s_0 = J_n q_dot, the slip v_0 = J_t q_dot, and the inverse effective masses
# a = J_n M^-1 J_n^T, b = J_n M^-1 J_t^T, c = J_t M^-1 J_t^T, made
# dimensionless by the body's mass.  They describe the impact independently
# of how the body is parametrised (an ellipse's orientation and a bar's
# tilt give the same features for the same contact).  With the contact
# radius they are what a compliant law's COR depends on besides the
# materials: the approach speed, the effective mass and the curvature
# (Johnson 1985, sec. 11.4; Jackson-Green loading and unloading, JG-5 to
# JG-10).
CONTACT_FEATURES = {
    "normal_speed": "approach speed of the contact point, J_n q_dot [m/s]",
    "tangential_speed": "slip of the contact point at first contact, J_t q_dot [m/s]",
    "slip_ratio": "tangential over normal approach speed, v_0 / s_0 [-]",
    "normal_mobility": "m J_n M^-1 J_n^T: mass over the effective normal mass [-]",
    "coupling": "m J_n M^-1 J_t^T: the normal-tangential coupling [-]",
    "tangential_mobility": "m J_t M^-1 J_t^T [-]",
    "contact_radius": "effective radius of curvature at the first contact (G-2) [m]",
}


def available_features(scene) -> list[str]:
    """The feature names a scene offers: the contact-space features of a
    planar scene, and every input its data rows may set (``orientation`` as
    its cosine and sine)."""
    names = list(CONTACT_FEATURES) if isinstance(scene, AbstractPlanarScene) else []
    if not isinstance(scene, AbstractPlanarScene) and hasattr(scene, "velocity"):
        names.append("normal_speed")
    return names + sorted(scene_spec(scene).inputs)


def feature_values(experiment: Experiment, names) -> Array:
    """The named features of ``experiment``'s scene, shape ``(k,)`` with
    ``orientation`` counted twice (cosine, sine)."""
    scene = experiment.scene
    out = []
    contact = None
    if not names:
        return jnp.zeros(0)
    for name in names:
        if name in CONTACT_FEATURES and isinstance(scene, AbstractPlanarScene):
            if contact is None:
                contact = _contact(scene)
            out.append(contact[name])
        elif name == "normal_speed":
            out.append(as_float(scene.velocity))
        else:
            value = getattr(scene, scene_spec(scene).inputs[name])
            if value is None:  # an optional input left unset (a height)
                raise ValueError(
                    f"feature {name!r}: the scene's {name} is not set (None); "
                    "give it in every row or choose another feature"
                )
            value = as_float(value)
            out.extend(
                [jnp.cos(value), jnp.sin(value)] if name == "orientation" else [value]
            )
    return jnp.stack(out)


def feature_names(features) -> tuple[str, ...]:
    """Feature names as a tuple (one name may be given as a string)."""
    return (features,) if isinstance(features, str) else tuple(features)


def feature_width(names) -> int:
    return sum(2 if n == "orientation" else 1 for n in names)


def _contact(scene: AbstractPlanarScene) -> dict:
    scene = scene.at_first_contact()
    q0, q_dot0 = scene.initial_state()
    _, j_n, j_t = scene.kinematics(q0)
    m = scene.mass_diagonal()
    inv_m = 1.0 / m
    s0, v0 = j_n @ q_dot0, j_t @ q_dot0
    return {
        "contact_radius": scene.contact().effective_radius,
        "normal_speed": s0,
        "tangential_speed": v0,
        "slip_ratio": v0 / s0,
        "normal_mobility": m[0] * jnp.sum(j_n * inv_m * j_n),
        "coupling": m[0] * jnp.sum(j_n * inv_m * j_t),
        "tangential_mobility": m[0] * jnp.sum(j_t * inv_m * j_t),
    }
