"""Fixed-step ODE solvers on manifolds (Euler-Exp, projected Euler, midpoint, RK4)."""

from rfmp_rl.solvers.config import DEFAULT_SCHEDULES, SolverConfig
from rfmp_rl.solvers.ode import (
    EVALS_PER_STEP,
    ODESolver,
    VectorFieldFn,
    integrate,
    num_steps,
    step_sizes,
)

__all__ = ["EVALS_PER_STEP", "ODESolver", "VectorFieldFn", "integrate", "num_steps", "step_sizes",
           "SolverConfig", "DEFAULT_SCHEDULES"]
