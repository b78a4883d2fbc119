"""Impact scenes: each holds its bodies (mass and inertia), geometry and
materials, and its state at first contact, and says how its contact moves
(the normal problem, or the planar kinematics of the contact point).  Scenes
know materials only: they never solve."""

from ._bar import FreeBar as FreeBar
from ._base import AbstractScene as AbstractScene
from ._base import NormalProblem as NormalProblem
from ._body import PlanarBody as PlanarBody
from ._flexible_bar import FlexibleBar as FlexibleBar
from ._link import RotatingLink as RotatingLink
from ._mechanisms import AbstractMechanism as AbstractMechanism
from ._mechanisms import BouncingBar as BouncingBar
from ._mechanisms import MechanismScales as MechanismScales
from ._mechanisms import SliderCrank as SliderCrank
from ._normal import Collinear as Collinear
from ._normal import NormalImpact as NormalImpact
from ._planar import AbstractPlanarScene as AbstractPlanarScene
from ._planar import SphereOnIncline as SphereOnIncline
from ._shapes import AbstractShape as AbstractShape
from ._shapes import Capsule as Capsule
from ._shapes import Disk as Disk
from ._shapes import Ellipse as Ellipse
from ._shapes import RoundedPolygon as RoundedPolygon
