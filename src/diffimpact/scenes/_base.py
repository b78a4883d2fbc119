"""What a scene provides to the solvers."""

from __future__ import annotations

import abc

import equinox as eqx
from jaxtyping import Array

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


class AbstractScene(eqx.Module):
    @abc.abstractmethod
    def normal_problem(self) -> NormalProblem:
        """The scene's normal contact problem at first contact."""

    def extras(self, rebound_velocity) -> dict:
        """Scene-specific outputs, given the normal separation speed."""
        return {}
