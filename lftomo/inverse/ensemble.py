"""How :func:`lftomo.sample_posterior` runs emcee's ensemble, as one object.

The posterior itself is defined once, by :func:`lftomo.inverse.posterior.build_log_posterior`
(data channels, basis, priors, bounds, emission); how it is sampled is an
:class:`EnsembleChain` (walkers, steps, burn-in, thinning, moves, importance samples).  The
keywords :func:`~lftomo.inverse.posterior.sample_posterior` took for both before still work,
each with a DeprecationWarning naming where it lives now (:func:`moved_sampling_options`).

References
----------
Goodman, J. & Weare, J. (2010). Ensemble samplers with affine invariance. *Commun. Appl.
Math. Comput. Sci.* 5, 65–80.
Foreman-Mackey, D., Hogg, D. W., Lang, D. & Goodman, J. (2013). emcee: the MCMC hammer.
*PASP* 125, 306–312.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from ..errors import LftomoError
from .._validate import is_real, require_int, require_positive
from .fitoptions import moved_options

__all__ = ["EnsembleChain", "DEFINITION_KEYWORDS", "SAMPLING_MOVED", "moved_sampling_options"]

#: The posterior's definition, set by :func:`~lftomo.inverse.posterior.build_log_posterior`.
DEFINITION_KEYWORDS = ("prior_mean", "prior_std", "prior", "regularization", "L", "T_scale", "T_ref", "bounds",
                       "emission", "dense_max")


def _check_moves(moves: Any) -> None:
    """emcee's ``moves``: None, a move, or a list of moves or of ``(move, weight > 0)`` pairs."""
    if moves is None:
        return
    items = moves if isinstance(moves, (list, tuple)) and not hasattr(moves, "propose") else [moves]
    ok = len(items) > 0
    for item in items:
        if isinstance(item, tuple) and len(item) == 2 and not hasattr(item, "propose"):
            move, weight = item
            ok = ok and is_real(weight) and math.isfinite(float(weight)) and weight > 0
        else:
            move = item
        ok = ok and callable(getattr(move, "propose", None))
    if not ok:
        raise LftomoError(f"moves must be an emcee move (e.g. emcee.moves.DEMove()), a list of them or a list of "
                          f"(move, weight > 0) pairs, got {moves!r}")


@dataclass(frozen=True)
class EnsembleChain:
    """How the affine-invariant ensemble runs (Goodman & Weare 2010, with emcee).

    Parameters
    ----------
    n_walkers : int, optional
        Walkers, >= max(4, 2 K) for K coefficients (the differential-evolution move draws two walkers
        from the other half of the ensemble); default ``2 · max(K + 1, 8)``.
    n_steps : int
        Steps per walker including burn-in, >= 2.
    burn : int, optional
        Steps discarded as burn-in, < ``n_steps``; default ``n_steps // 4``.
    thin : int
        Keep every ``thin``-th step, >= 1.
    init_scale : float
        Size of the walkers' starting ball relative to the Laplace covariance, > 0:
        walkers start at ``c_start + init_scale · chol(cov) z``.
    moves : emcee move(s), optional
        Passed to :class:`emcee.EnsembleSampler`.  Default: the mixture
        ``[(DEMove(), 0.8), (StretchMove(), 0.2)]`` (docs/accuracy.md, *Posterior sampler moves*).
    n_importance : int
        With the Taylor likelihood: thinned samples given exact log-posteriors and
        importance weights, >= 10.
    strict : bool
        Raise :class:`~lftomo.inverse.posterior.ConvergenceError` instead of warning when the
        chain after burn-in is shorter than 50 integrated autocorrelation times, or the
        importance ESS is low.
    max_field_elements : float
        Memory cap (number of floats) of the temperature-field samples used for the
        per-voxel quantiles, > 0.

    Raises
    ------
    LftomoError
        A value outside the ranges above (the check against K is made when sampling).
    """

    n_walkers: int | None = None
    n_steps: int = 2000
    burn: int | None = None
    thin: int = 1
    init_scale: float = 0.1
    moves: Any = None
    n_importance: int = 2000
    strict: bool = False
    max_field_elements: float = 2e7

    def __post_init__(self) -> None:
        if self.n_walkers is not None:
            require_int("n_walkers", self.n_walkers, minimum=4)
        n_steps = require_int("n_steps", self.n_steps, minimum=2)
        if self.burn is not None and require_int("burn", self.burn, minimum=0) >= n_steps:
            raise LftomoError(f"burn must be < n_steps = {n_steps}, got {self.burn}")
        kept = n_steps - (n_steps // 4 if self.burn is None else int(self.burn))
        if require_int("thin", self.thin, minimum=1) > kept:
            raise LftomoError(f"thin must be <= the {kept} steps kept after burn-in (n_steps - burn), got {self.thin}: "
                              "no sample would be kept")
        _check_moves(self.moves)
        require_positive("init_scale", self.init_scale)
        require_int("n_importance", self.n_importance, minimum=10)
        require_positive("max_field_elements", self.max_field_elements)
        if not isinstance(self.strict, bool):
            raise LftomoError(f"strict must be True or False, got {self.strict!r}")

    @property
    def burn_steps(self) -> int:
        """Burn-in actually discarded: ``burn``, or ``n_steps // 4`` when it is None."""
        return self.n_steps // 4 if self.burn is None else int(self.burn)


_CHAIN_FIELDS = tuple(f.name for f in fields(EnsembleChain))
#: The keywords :func:`~lftomo.inverse.posterior.sample_posterior` took before, and where each lives now.
SAMPLING_MOVED: dict[str, str] = {
    **{k: f"chain=lt.EnsembleChain({k}=...)" for k in _CHAIN_FIELDS},
    **{k: f"lt.build_log_posterior(problem, basis=..., {k}=...) as the posterior" for k in DEFINITION_KEYWORDS},
}


def moved_sampling_options(given: dict[str, Any], chain: EnsembleChain | None,
                           definition_allowed: bool) -> tuple[EnsembleChain, dict[str, Any]]:
    """The chain and the posterior-definition keywords among the keywords ``given`` to
    :func:`~lftomo.inverse.posterior.sample_posterior` beyond its own arguments, each with a
    DeprecationWarning that names where it lives now.

    Parameters
    ----------
    given : dict
        The extra keywords.
    chain : EnsembleChain or None
        The ``chain`` argument; a chain keyword next to it is refused.
    definition_allowed : bool
        False when the posterior is already a :class:`~lftomo.inverse.posterior.LogPosterior`:
        its definition cannot be changed by keywords.

    Returns
    -------
    (EnsembleChain, dict)
        The chain (``chain``, or one built from the moved keywords, or the default) and the
        definition keywords for ``build_log_posterior``.

    Raises
    ------
    TypeError
        A keyword ``sample_posterior`` never took.
    LftomoError
        A chain keyword next to ``chain=``, or a definition keyword next to a LogPosterior.
    """
    unknown = sorted(set(given) - set(SAMPLING_MOVED))
    if unknown:
        raise TypeError(f"sample_posterior() got an unexpected keyword argument {unknown[0]!r}")
    if chain is not None and not isinstance(chain, EnsembleChain):
        raise LftomoError(f"chain must be an lt.EnsembleChain, got {type(chain).__name__}")
    moved_chain = {k: v for k, v in given.items() if k in _CHAIN_FIELDS}
    definition = {k: v for k, v in given.items() if k in DEFINITION_KEYWORDS}
    if moved_chain and chain is not None:
        raise LftomoError(f"{', '.join(moved_chain)} set twice: by chain={chain!r} and as keywords; give it one way")
    if definition and not definition_allowed:
        raise LftomoError(f"{', '.join(definition)} given next to a LogPosterior, which already defines the "
                         "posterior; pass them to lt.build_log_posterior instead")
    moved_options(given, "sample_posterior", table=SAMPLING_MOVED, stacklevel=5)  # the caller of sample_posterior
    chain = EnsembleChain(**moved_chain) if moved_chain else (chain or EnsembleChain())
    return chain, definition
