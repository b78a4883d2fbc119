"""What a scene provides to the solvers."""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array

from .._checks import AbstractValidated
from .._materials import ContactProperties


class NormalProblem(eqx.Module):
    """One normal degree of freedom at first contact.

    - `mass`: (reduced) mass [kg]; `contact`: effective properties;
    - `velocity`: normal approach speed at first contact [m/s], > 0;
    - `gravity`: acceleration along the approach [m/s^2] (0 for none).
    """

    mass: Array
    contact: ContactProperties
    velocity: Array
    gravity: Array


class AbstractScene(AbstractValidated):
    """A scene: bodies, materials and the state at first contact.

    `data_inputs` lets `diffimpact.fit` and `diffimpact.predict` read a
    user-defined scene from an experiment file: which input quantity of the
    file sets which field, e.g. ``{"impact_velocity": "speed", "angle":
    "angle"}`` (quantities as in the CSV format: ``angle_deg`` is converted to
    ``angle`` in rad).  Empty: the scene has no data mapping.
    `data_required`: the inputs every row of a file must give (the others
    default to the template scene's values).
    """

    data_inputs: ClassVar[Mapping[str, str]] = {}
    data_required: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def normal_problem(self) -> NormalProblem:
        """The scene's normal contact problem at first contact."""

    def extras(self, rebound_velocity) -> dict:
        """Scene-specific outputs, given the normal separation speed."""
        return {}


def rod_inertia(rod, factor):
    """``factor m L^2`` (1/12 about the centre of mass, 1/3 about an end) of a
    uniform rod, plus ``m D^2 / 16`` when ``rod.cross_section_inertia``."""
    i = factor * rod.mass * rod.length**2
    if rod.cross_section_inertia:
        i = i + rod.mass * rod.diameter**2 / 16.0
    return i
