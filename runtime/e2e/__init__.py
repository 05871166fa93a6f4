"""End-to-end learning through the planner (Algorithm 2 of the published paper): a model inside the transcribed NLP,
differentiated through K unrolled extragradient steps or by the implicit function theorem at a converged plan
(README.md in this folder: its use and contracts)."""

from ..solvers.adjoint import Implicit as Implicit
from ..solvers.adjoint import Unrolled as Unrolled
from .config import E2EConfig as E2EConfig
from .expert import expert_from_dataset as expert_from_dataset
from .planner import PlannerState as PlannerState
from .planner import UnrolledPlanner as UnrolledPlanner
from .planner import default_planner_solver as default_planner_solver
from .planner import make_implicit_solve as make_implicit_solve
from .train import E2EReport as E2EReport
from .train import run_e2e as run_e2e

__all__ = ["E2EConfig", "E2EReport", "Implicit", "PlannerState", "Unrolled", "UnrolledPlanner",
           "default_planner_solver", "expert_from_dataset", "make_implicit_solve", "run_e2e"]
