"""diffimpact: differentiable impact simulation and parameter identification in JAX.

Importing diffimpact changes nothing in the host program: it neither writes
JAX's configuration nor creates arrays (so it initialises no backend).

**Precision.** Impact physics spans interferences of micrometres against radii
of millimetres and forces of kilonewtons over microseconds; diffimpact is
validated in float64.  Enable it at the start of your program, before creating
arrays::

    import jax
    jax.config.update("jax_enable_x64", True)

Without it every solve runs in float32, with tolerances floored at what
float32 can honour: outputs agree with float64 to about 5e-4 (relative), and a
solve whose float32 precision breaks down reports ``RESULTS.precision_lost``
instead of returning NaN.  `fit` needs float64 and says so.
"""

from . import scenes as scenes
from ._inference._crossval import CrossValidation as CrossValidation
from ._inference._crossval import cross_validate as cross_validate
from ._inference._experiment import Experiment as Experiment
from ._inference._features import CONTACT_FEATURES as CONTACT_FEATURES
from ._inference._features import available_features as available_features
from ._inference._fit import fit as fit
from ._inference._fit_result import FitResult as FitResult
from ._inference._fit_result import IdentifiabilityWarning as IdentifiabilityWarning
from ._inference._learned import Hybrid as Hybrid
from ._inference._learned import Learned as Learned
from ._inference._learning_curve import LearningCurve as LearningCurve
from ._inference._learning_curve import learning_curve as learning_curve
from ._inference._learning_curve import load_model as load_model
from ._inference._learning_curve import save_model as save_model
from ._inference._network import VelocityNetwork as VelocityNetwork
from ._inference._normal_rows import normal_impact_row as normal_impact_row
from ._inference._posterior import posterior as posterior
from ._inference._posterior_result import ConvergenceWarning as ConvergenceWarning
from ._inference._posterior_result import PosteriorResult as PosteriorResult
from ._inference._predict import predict as predict
from ._inference._priors import AbstractPrior as AbstractPrior
from ._inference._priors import LogNormalPrior as LogNormalPrior
from ._inference._priors import LogUniformPrior as LogUniformPrior
from ._inference._priors import NormalPrior as NormalPrior
from ._inference._priors import UniformPrior as UniformPrior
from ._inference._priors import default_prior as default_prior
from ._inference._residual import Residual as Residual
from ._inference._sweep import sweep as sweep
from ._inference._sweep import sweep_map as sweep_map
from ._inference._sweep_inputs import grid as grid
from ._inference._sweep_inputs import sample as sample
from ._inference._train import TrainResult as TrainResult
from ._inference._train import evaluate as evaluate
from ._inference._train import train as train
from ._io._data import DataError as DataError
from ._io._data import ExperimentData as ExperimentData
from ._io._data import load_experiments as load_experiments
from ._io._write import write_experiments as write_experiments
from ._laws._adams import AdamsImpact as AdamsImpact
from ._laws._base import AbstractBoundLaw as AbstractBoundLaw
from ._laws._base import AbstractNormalLaw as AbstractNormalLaw
from ._laws._dissipative import Flores as Flores
from ._laws._dissipative import HuntCrossley as HuntCrossley
from ._laws._dissipative import LankaraniNikravesh as LankaraniNikravesh
from ._laws._friction import Friction as Friction
from ._laws._hertz import Hertz as Hertz
from ._laws._jackson_green import JacksonGreen as JacksonGreen
from ._laws._line import LineContact as LineContact
from ._materials import ContactProperties as ContactProperties
from ._materials import Material as Material
from ._materials import contact_properties as contact_properties
from ._materials import effective_modulus as effective_modulus
from ._materials import effective_radius as effective_radius
from ._result import RESULTS as RESULTS
from ._result import History as History
from ._result import ImpactResult as ImpactResult
from ._result import InvalidInputError as InvalidInputError
from ._result import NeverSeparatesError as NeverSeparatesError
from ._result import OutsideModelError as OutsideModelError
from ._result import SimulationError as SimulationError
from ._result import SolverError as SolverError
from ._result import StepBudgetError as StepBudgetError
from ._result import result_name as result_name
from ._solve._calibrate import damping_ratio as damping_ratio
from ._solve._critical import critical_angles as critical_angles
from ._solve._critical import held_impulse_ratio as held_impulse_ratio
from ._solve._rigid import RESTITUTION_LAWS as RESTITUTION_LAWS
from ._solve._rigid import RigidContact as RigidContact
from ._solve._rigid import rigid_impact as rigid_impact
from ._solve._settings import SolverSettings as SolverSettings
from ._solve._simulate import simulate as simulate
from ._solve._span import simulate_span as simulate_span
from ._solve._span_types import SpanHistory as SpanHistory
from ._solve._span_types import SpanImpacts as SpanImpacts
from ._solve._span_types import SpanResult as SpanResult
from ._solve._span_types import SpanSettings as SpanSettings

__version__ = "0.1.0"
