"""Solver objects: which algorithm minimises the regularised least-squares objective, with its settings.

A solver is a small immutable object (as optimistix and lineax make
solvers objects) given as ``solver=`` to :func:`lftomo.reconstruct` and
:func:`lftomo.solve_temperature`; its parameters are its attributes, and a
parameter left at ``None`` keeps the fit's own default (:func:`lftomo.inverse.solvers.temperature_fit` for
``unknowns="T"``, :func:`lftomo.inverse.joint.solve_temperature_absorption`
for ``"T+sigma_a"``).

``LevenbergMarquardt`` and ``GaussNewton``
    optimistix's matrix-free solvers: each step solves its linear system by
    LSMR on products with the sparse forward operator (both fits).
``DenseLM``
    Levenberg–Marquardt on exact dense normal equations, for few unknowns
    (axisymmetric ring cells, a smooth basis, a 16³ grid): both fits; the
    T-only fit needs a quadratic prior (not total variation).
``AutoSolver``
    The fit's own choice by problem size (what ``solver=None`` gives), with
    settings that apply to whichever algorithm it picks.
"""

from __future__ import annotations

from typing import Any
from ..errors import LftomoError

__all__ = ["Solver", "LevenbergMarquardt", "GaussNewton", "DenseLM", "AutoSolver", "resolve_solver"]


class Solver:
    """An algorithm for the regularised least-squares fit and its settings.

    Subclasses set :attr:`method` (the fit functions' ``method=`` name) and
    :attr:`fits` (``"T"``, ``"T+sigma_a"``: which fits run it).
    """

    method: str = ""
    fits: tuple[str, ...] = ()

    def keywords(self) -> dict[str, Any]:
        """Keyword arguments of the fit function: ``method`` and every parameter not None."""
        return {"method": self.method, **{k: v for k, v in vars(self).items() if v is not None}}

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in sorted(vars(self).items()) if v is not None)
        return f"{type(self).__name__}({params})"


def _steps(name: str, value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise LftomoError(f"{name} must be an integer >= 1 or None (the fit's default), got {value!r}")
    return int(value)


def _tolerance(name: str, value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= float(value) < 1.0:
        raise LftomoError(f"{name} must be a number in [0, 1) or None (the fit's default), got {value!r}")
    return float(value)


def _polish(value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise LftomoError(f"polish_steps must be an integer >= 0 or None (the fit's default), got {value!r}")
    return int(value)


def _engine(value: Any) -> str | None:
    if value is not None and value not in ENGINES:
        raise LftomoError(f"engine must be one of {ENGINES} or None (the fit's default), got {value!r}")
    return value


#: How the joint fit evaluates its forward model and derivatives: host sparse Jacobians, or JAX autodiff.
ENGINES = ("host", "jax")
#: Parameters that only the joint T + σₐ fit has.
JOINT_ONLY = ("polish_steps", "engine")


class _MatrixFree(Solver):
    fits = ("T", "T+sigma_a")

    def __init__(self, max_steps: int | None = None, rtol: float | None = None, atol: float | None = None,
                 linear_max_steps: int | None = None, linear_rtol: float | None = None,
                 polish_steps: int | None = None, engine: str | None = None) -> None:
        self.max_steps = _steps("max_steps", max_steps)
        self.rtol = _tolerance("rtol", rtol)
        self.atol = _tolerance("atol", atol)
        self.linear_max_steps = _steps("linear_max_steps", linear_max_steps)
        self.linear_rtol = _tolerance("linear_rtol", linear_rtol)
        self.polish_steps = _polish(polish_steps)
        self.engine = _engine(engine)


class LevenbergMarquardt(_MatrixFree):
    """optimistix ``LevenbergMarquardt``, matrix-free (LSMR per step).

    Parameters
    ----------
    max_steps : int, optional
        Nonlinear steps per solve.
    rtol, atol : float, optional
        Convergence tolerances of the nonlinear solve.
    linear_max_steps : int, optional
        LSMR iterations per step (a truncated step beyond it).
    linear_rtol : float, optional
        LSMR tolerance of each step.
    polish_steps : int, optional
        Joint fit only: after λ is chosen, continue that λ's solve for up to
        this many more steps.
    engine : {"host", "jax"}, optional
        Joint fit only: forward model and exact derivatives from host sparse
        Jacobians (the fit's default) or JAX autodiff (same values, slower).
    """

    method = "levenberg-marquardt"


class GaussNewton(_MatrixFree):
    """optimistix ``GaussNewton``, matrix-free (LSMR per step); parameters as :class:`LevenbergMarquardt`."""

    method = "gauss-newton"


class AutoSolver(Solver):
    """The fit's own choice of algorithm, with settings: dense Levenberg–Marquardt up to a number
    of unknowns, matrix-free Levenberg–Marquardt above it (``unknowns="T"``:
    :func:`lftomo.inverse.solvers.resolve_method`, which also keeps a total-variation prior
    matrix-free; ``"T+sigma_a"``: :func:`lftomo.inverse.joint.solve_temperature_absorption`).  This is
    what ``solver=None`` gives, with every setting at the fit's default.

    Parameters
    ----------
    max_steps : int, optional
        Nonlinear steps per solve, whichever algorithm is chosen.
    polish_steps, engine : optional
        Joint fit only, as for :class:`LevenbergMarquardt`.
    """

    method = "auto"
    fits = ("T", "T+sigma_a")

    def __init__(self, max_steps: int | None = None, polish_steps: int | None = None,
                 engine: str | None = None) -> None:
        self.max_steps = _steps("max_steps", max_steps)
        self.polish_steps = _polish(polish_steps)
        self.engine = _engine(engine)


class DenseLM(Solver):
    """Levenberg–Marquardt on exact dense normal equations, for fits with few unknowns.

    Each step forms ``JᵀJ`` (n × n) from the sparse weights and solves the
    damped normal equations by Cholesky (:mod:`lftomo.inverse.denselm`; the
    T-only fit: :mod:`lftomo.inverse.densetemperature`, quadratic priors).
    Memory and time grow as n² and n³: a few thousand unknowns.

    Parameters
    ----------
    max_steps : int, optional
        Levenberg–Marquardt trial points per solve.
    polish_steps, engine : optional
        As for :class:`LevenbergMarquardt`.
    """

    method = "dense-lm"
    fits = ("T", "T+sigma_a")

    def __init__(self, max_steps: int | None = None, polish_steps: int | None = None,
                 engine: str | None = None) -> None:
        self.max_steps = _steps("max_steps", max_steps)
        self.polish_steps = _polish(polish_steps)
        self.engine = _engine(engine)


def resolve_solver(solver: Any, *, fit: str) -> Solver:
    """Check that ``solver`` is a :class:`Solver` that runs ``fit`` (``"T"`` or ``"T+sigma_a"``).

    Raises
    ------
    LftomoError
        Not a Solver, or one that does not run this fit, naming those that do.
    """
    allowed = [c.__name__ for c in (LevenbergMarquardt, GaussNewton, DenseLM, AutoSolver) if fit in c.fits]
    if not isinstance(solver, Solver):
        raise LftomoError(f"solver must be one of lftomo's solver objects ({', '.join(allowed)}), got {solver!r}")
    if fit not in solver.fits:
        raise LftomoError(f"solver {solver!r} does not run unknowns={fit!r}; use one of {', '.join(allowed)}")
    given = [k for k in JOINT_ONLY if getattr(solver, k, None) is not None]
    if fit != "T+sigma_a" and given:
        raise LftomoError(f"{', '.join(given)} of solver {solver!r} appl{'ies' if len(given) == 1 else 'y'} to the "
                         "joint fit (unknowns='T+sigma_a') only")
    return solver
