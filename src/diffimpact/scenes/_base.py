"""What a scene provides to the solvers."""

from __future__ import annotations

import abc
import dataclasses
import functools
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


def scene_init(**renamed: str):
    """Class decorator of a scene's constructor.  Its positional arguments are
    mass (and inertia), geometry and materials, in that order; the state and
    the environment are keyword-only, and too many positional arguments get a
    message that names them.  A keyword the scene no longer takes (``angle``,
    which meant the incline in one scene, a tilt in another and an
    orientation in a third) is refused with a message naming the field that
    replaced it.  ``renamed``: old name -> ``"new (what it is)"``."""

    def wrap(cls):
        init = cls.__init__
        fields = dataclasses.fields(cls)
        positional = [f.name for f in fields if f.init and not f.kw_only]
        keyword = [f.name for f in fields if f.init and f.kw_only]

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            for old, new in renamed.items():
                if old in kwargs:
                    name = new.split(" ")[0]
                    raise TypeError(
                        f"`{cls.__name__}.{old}` is now `{name}`: write "
                        f"{name}=... ({new.partition(' ')[2].strip('()')})"
                    )
            if len(args) > len(positional):
                raise TypeError(
                    f"{cls.__name__} takes {', '.join(positional)} by position; "
                    f"{', '.join(keyword)} are keyword-only (e.g. "
                    f"{keyword[0]}=...)"
                )
            init(self, *args, **kwargs)

        cls.__init__ = __init__
        return cls

    return wrap


def rod_inertia(rod, factor):
    """``factor m L^2`` (1/12 about the centre of mass, 1/3 about an end) of a
    uniform rod, plus ``m D^2 / 16`` when ``rod.cross_section_inertia``."""
    i = factor * rod.mass * rod.length**2
    if rod.cross_section_inertia:
        i = i + rod.mass * rod.diameter**2 / 16.0
    return i
