"""Matrix-free nonlinear least squares with optimistix: the pieces both fits use.

* :class:`TruncatedLSMR` — ``lineax.LSMR`` whose step cap counts as success
  (an inexact Newton step inside a trust region).
* :func:`nonlinear_solver` — the optimistix Levenberg–Marquardt or
  Gauss–Newton solver with that linear solver.
* :func:`jacobi_scale` and :func:`scaled_chunks` — chunks of optimistix steps on
  Jacobi-scaled unknowns ``θ = θ_c + D ψ``, ``D = 1/‖column‖`` (see
  :mod:`lftomo.inverse.solvers` for why).
* :func:`influence_probes` — Hutchinson samples of ``zᵀHz`` and ``‖Hz‖²`` of
  the influence matrix ``H = J (JᵀJ + λRᵀR)⁻¹ Jᵀ`` (residual degrees of
  freedom, GCV).
* :func:`hutchinson_dof` — the residual degrees of freedom ``tr(2H − H²)``
  from as many of those probes as the noise-scale estimate needs.

Used by :func:`lftomo.inverse.solvers.solve_temperature` and
:func:`lftomo.inverse.joint.solve_temperature_absorption`.  Importing this
module enables float64 in JAX.
"""

from __future__ import annotations

import functools

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

from ..errors import LftomoError
from ..interrupt import check_interrupt  # noqa: E402

__all__ = ["CHUNK", "TruncatedLSMR", "linear_solver", "nonlinear_solver", "jacobi_scale", "scaled_chunks",
           "influence_probes", "hutchinson_dof", "dof_probes_needed"]

#: Optimistix steps per Jacobi-scaled chunk.
CHUNK = 10

#: Hutchinson probes of the residual degrees of freedom: at least this many (a sample standard
#: error) and at most :data:`DOF_PROBES_MAX` (:func:`hutchinson_dof`).
DOF_PROBES_MIN = 2
DOF_PROBES_MAX = 8
#: The standard error of ``ν`` that :func:`hutchinson_dof` aims at, as a fraction of the standard
#: deviation ``√(2(m − ν))`` of the residual's χ² itself: ``s² = χ²/(m − ν)`` then carries ν's error
#: as at most ``DOF_SE_FRACTION² = 1/16`` of the variance χ²'s noise gives it.
DOF_SE_FRACTION = 0.25


class TruncatedLSMR(lx.AbstractLinearSolver):
    """``lineax.LSMR`` whose step cap counts as success (truncated / inexact Newton step).

    LSMR with ``max_steps`` reports ``max_steps_reached``, which optimistix
    would turn into a failed solve; inside a trust-region method an inexact
    step is fine, so the cap is reported as success.  Other results
    (e.g. ``conlim``) are passed through.
    """

    inner: lx.LSMR

    def init(self, operator, options):
        return self.inner.init(operator, options)

    def compute(self, state, vector, options):
        x, result, stats = self.inner.compute(state, vector, options)
        result = lx.RESULTS.where(result == lx.RESULTS.max_steps_reached, lx.RESULTS.successful, result)
        return x, result, stats

    def transpose(self, state, options):
        return self.inner.transpose(state, options)

    def conj(self, state, options):
        return self.inner.conj(state, options)

    def assume_full_rank(self):
        return False


@functools.lru_cache(maxsize=None)
def linear_solver(linear_rtol: float, linear_max_steps: int) -> lx.AbstractLinearSolver:
    """:class:`TruncatedLSMR` with ``rtol = atol = linear_rtol`` and a cap of ``linear_max_steps`` (cached)."""
    return TruncatedLSMR(lx.LSMR(rtol=linear_rtol, atol=linear_rtol, max_steps=linear_max_steps))


@functools.lru_cache(maxsize=None)
def nonlinear_solver(method: str, rtol: float, atol: float, linear_rtol: float, linear_max_steps: int):
    """``optimistix.LevenbergMarquardt`` (``method="levenberg-marquardt"``) or ``GaussNewton`` with RMS norms
    and :func:`linear_solver` for the steps (cached)."""
    ls = linear_solver(linear_rtol, linear_max_steps)
    if method == "levenberg-marquardt":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, norm=optx.rms_norm, linear_solver=ls)
    return optx.GaussNewton(rtol=rtol, atol=atol, norm=optx.rms_norm, linear_solver=ls)


def jacobi_scale(c2: np.ndarray) -> np.ndarray:
    """``D = 1/‖column‖`` from the squared column norms ``c2`` of a Jacobian,
    the norms floored at 1e-3 of their RMS (a column the data barely see must
    not get an enormous step per unit of the scaled variable)."""
    c = np.sqrt(np.maximum(c2, 0.0))
    rms = float(np.sqrt(np.mean(c2))) if c.size and np.isfinite(c2).all() and c2.max() > 0 else 1.0
    return 1.0 / np.maximum(c, 1e-3 * rms)


def scaled_chunks(residual, solver, args: dict, column_scale, theta, max_steps: int, bar, chunk: int = CHUNK):
    """Chunks of Jacobi-scaled optimistix steps from ``theta`` (the T-only and joint solves).

    Each chunk rescales the unknowns about the current point, ``θ = θ_c + D ψ``
    with ``D = column_scale(θ_c)``, and runs up to ``chunk`` steps of ``solver``
    on ``residual(ψ, args)`` from ``ψ = 0`` (``args["theta_c"]``, ``args["D"]``
    set here), so that the damping sees unknowns of comparable scale.  Yields
    ``(θ, n_steps, result)`` after every chunk until ``max_steps`` steps are
    spent; the caller decides when to stop.  A chunk that ends in a
    non-finite iterate yields ``θ = None``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    zeros = jnp.zeros(theta.shape)
    steps = 0
    while steps < max_steps:
        check_interrupt()  # Ctrl-C under lftomo.interrupt.stop_between_steps: stop between two chunks
        D = column_scale(theta)
        args["theta_c"], args["D"] = jnp.asarray(theta), jnp.asarray(D)
        sol = optx.least_squares(residual, solver, zeros, args=args, max_steps=min(chunk, max_steps - steps),
                                 throw=False)
        n = int(sol.stats["num_steps"])
        steps += n
        bar.update(n)
        theta_new = theta + D * np.asarray(sol.value)
        if not np.all(np.isfinite(theta_new)):
            yield None, n, sol.result
            return
        theta = theta_new
        yield theta, n, sol.result
        if n == 0:
            return


def influence_probes(op, Jd, D, zero, ls, probes, on_probe=None):
    """``(zᵀHz, ‖Hz‖²)`` for each probe ``z``, ``H = J (JᵀJ + λRᵀR)⁻¹ Jᵀ`` (one LSMR solve each).

    ``on_probe``, if given, is called on the host with the number of probes
    done (1, 2, …) after each solve: progress for a slow step.  Leave it
    ``None`` inside a cached jitted function (the T-only rule's).
    """

    def quad(kz):
        k, z = kz
        x = lx.linear_solve(op, (z, zero), ls, throw=False).value
        hz = Jd(D(x))
        out = jnp.vdot(z, hz), jnp.vdot(hz, hz)
        if on_probe is not None:
            # ordered: the calls follow the loop; the result feeds it so it runs after the solve
            jax.debug.callback(lambda k_, _: on_probe(int(k_) + 1), k, out[0], ordered=True)
        return out

    return jax.lax.map(quad, (jnp.arange(probes.shape[0]), probes))  # a loop: HostCSR has no batching rule


def dof_probes_needed(nu: float, m: int) -> int:
    """Rademacher probes that bound the standard error of Hutchinson's ``ν`` by :data:`DOF_SE_FRACTION`
    ``× √(2(m − ν))``, clipped to [:data:`DOF_PROBES_MIN`, :data:`DOF_PROBES_MAX`].

    For a symmetric ``A`` with eigenvalues in [0, 1] (``A = 2H − H²``, ``H`` an influence matrix)
    ``Var(zᵀAz) = 2 Σ_{i≠j} A_ij² ≤ 2‖A‖_F² ≤ 2 tr A``, so ``k`` probes give a standard error of at most
    ``√(2ν/k)`` (Hutchinson 1990; Avron & Toledo 2011, J. ACM 58, 8), at most the aim when
    ``k ≥ ν / (DOF_SE_FRACTION² (m − ν))``.
    """
    nu = max(float(nu), 0.0)
    if not np.isfinite(nu) or m - nu <= 0:
        return DOF_PROBES_MAX
    k = int(np.ceil(nu / (DOF_SE_FRACTION ** 2 * (m - nu))))
    return min(max(k, DOF_PROBES_MIN), DOF_PROBES_MAX)


def hutchinson_dof(quad, m: int, n_unknowns: int, *, n_probes: int | None = None, seed: int = 0,
                   on_probe=None) -> tuple[float, float]:
    """Residual degrees of freedom ``ν = tr(2H − H²)`` by Hutchinson's estimator, and its standard error.

    Parameters
    ----------
    quad : callable
        ``quad(z) -> zᵀ(2H − H²)z`` for a Rademacher probe ``z`` of shape (m,).
    m : int
        Data (rows of ``H``).
    n_unknowns : int
        Unknowns: ``ν`` is clipped to ``[0, n_unknowns]`` (its range for ``H`` of rank ≤ ``n_unknowns``).
    n_probes : int, optional
        Exactly this many probes (≥ 2); default: as many as :func:`dof_probes_needed` asks.
    seed : int
        The probes are the rows of ``default_rng(seed).choice([-1, 1], (k, m))`` in order,
        ``k = max(n_probes, DOF_PROBES_MAX)``: the same vectors for the same seed.
    on_probe : callable, optional
        Called with the number of probes done after each one (progress).

    Returns
    -------
    nu, se : float
        The mean of ``zᵀ(2H − H²)z`` over the probes (clipped) and its sample standard error.  The
        number of probes is :func:`dof_probes_needed` of the running estimate (upper end, two standard
        errors): ``s² = χ²/(m − ν)`` needs ``ν`` only to a fraction of ``m − ν``, so where the data far
        outnumber the degrees of freedom two probes do.
    """
    if n_probes is not None and n_probes < 2:
        raise LftomoError(f"n_probes must be at least 2 (a standard error), got {n_probes}")
    k_max = DOF_PROBES_MAX if n_probes is None else n_probes
    probes = np.random.default_rng(seed).choice([-1.0, 1.0], size=(max(k_max, DOF_PROBES_MAX), m))
    q: list[float] = []
    while len(q) < k_max:
        if n_probes is None and len(q) >= DOF_PROBES_MIN:
            nu, k = float(np.mean(q)), len(q)
            if k >= dof_probes_needed(nu + 2.0 * np.sqrt(2.0 * max(nu, 0.0) / k), m):
                break
        check_interrupt()
        q.append(float(quad(probes[len(q)])))
        if on_probe is not None:
            on_probe(len(q))
    qa = np.asarray(q)
    return float(min(max(qa.mean(), 0.0), n_unknowns)), float(qa.std(ddof=1) / np.sqrt(qa.size))
