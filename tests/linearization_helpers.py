"""Checks shared by the tests of the fits' linearisations (``SolvePath.linearization``)."""

import numpy as np
import pytest


def assert_gradients_are_half_the_differences(path, lin, theta, lam, indices, *, abs_data, abs_prior, h=1e-5):
    """``J_dᵀ r_d`` and ``J_rᵀ r_r`` of ``lin`` (per unit of the scaled unknowns, ``lin.scale``) against half
    the central differences of ``χ²`` and ``‖R‖²`` from ``path.terms`` (step ``h`` in θ), at ``indices``."""
    for k in indices:
        e = np.zeros(theta.size)
        e[k] = h
        (cp, rp), (cm, rm) = path.terms(theta + e, lam), path.terms(theta - e, lam)
        d_data = (cp - cm) * path.m_total / (2 * h)
        d_prior = (rp**2 - rm**2) / (2 * h)
        assert 2 * lin.gd[k] / lin.scale[k] == pytest.approx(d_data, rel=1e-5, abs=abs_data), k
        assert 2 * lin.gr[k] / lin.scale[k] == pytest.approx(d_prior, rel=1e-5, abs=abs_prior), k
