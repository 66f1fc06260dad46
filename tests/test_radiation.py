"""Planck's law, its inverse and derivative, against independent evaluations."""

import math
import warnings

import numpy as np
import pytest
from scipy import constants as sc
from scipy import integrate

from lftomo.radiation import (
    blackbody_intensity,
    dplanck_dT,
    gray_intensity,
    gray_inverse,
    planck,
    planck_inverse,
)

WIEN_B = 2.897771955e-3  # m K (CODATA 2018, exact given h, c, k)


def _planck_naive(T, lam):
    """Textbook form with math.exp, one value at a time."""
    return 2 * sc.h * sc.c**2 / lam**5 / (math.exp(sc.h * sc.c / (lam * sc.k * T)) - 1.0)


@pytest.mark.parametrize("T", [300.0, 1000.0, 1900.0, 3000.0, 5778.0])
@pytest.mark.parametrize("lam", [400e-9, 650e-9, 1e-6, 10e-6, 1e-3])
def test_planck_matches_textbook_formula(T, lam):
    assert planck(T, lam) == pytest.approx(_planck_naive(T, lam), rel=1e-12)


def test_planck_known_value():
    # c1L = 2hc^2 and c2 = hc/k are exact in the 2019 SI (CODATA 2018 values, typed in)
    c1L, c2 = 1.1910429723971884e-16, 1.4387768775039337e-2
    x = c2 / (650e-9 * 1900.0)
    expected = c1L / (650e-9) ** 5 / math.expm1(x)
    assert planck(1900.0, 650e-9) == pytest.approx(expected, rel=1e-9)


def test_planck_broadcasts():
    T = np.array([[1000.0], [2000.0]])
    lam = np.array([500e-9, 650e-9, 800e-9])
    out = planck(T, lam)
    assert out.shape == (2, 3)
    assert out[1, 2] == pytest.approx(_planck_naive(2000.0, 800e-9), rel=1e-12)
    assert isinstance(planck(1000.0, 650e-9), float)


def test_planck_no_overflow_and_rayleigh_jeans():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow / invalid-value warning
        assert planck(10.0, 100e-9) == 0.0  # x ~ 1.4e4: exp(-x) underflows to 0
    # Rayleigh-Jeans limit x -> 0: I -> 2 c k T / lam^4
    T, lam = 3000.0, 1.0
    assert planck(T, lam) == pytest.approx(2 * sc.c * sc.k * T / lam**4, rel=1e-5)


@pytest.mark.parametrize("T", [800.0, 1500.0, 1900.0, 3000.0])
def test_wien_displacement(T):
    lam_peak = WIEN_B / T
    lam = lam_peak * np.linspace(0.9, 1.1, 200001)  # step 1e-6 relative
    i = int(np.argmax(planck(T, lam)))
    assert 0 < i < lam.size - 1
    assert lam[i] == pytest.approx(lam_peak, rel=2e-6)


@pytest.mark.parametrize("T", [300.0, 1000.0, 2500.0])
def test_integral_over_wavelength_is_sigma_T4_over_pi(T):
    # integrate in ln(lam): dlam = lam dln(lam); the tails outside [1e-8, 1] m are < 1e-12 relative
    f = lambda u: planck(T, math.exp(u)) * math.exp(u)  # noqa: E731
    lnpk = math.log(WIEN_B / T)
    pts = [lnpk - 3, lnpk - 1, lnpk, lnpk + 1, lnpk + 3]
    val, err = integrate.quad(f, math.log(1e-8), math.log(1.0), points=pts, limit=500, epsrel=1e-11)
    expected = sc.Stefan_Boltzmann * T**4 / math.pi
    assert val == pytest.approx(expected, rel=1e-6)
    assert gray_intensity(T) == pytest.approx(expected, rel=1e-14)


def test_planck_inverse_round_trip():
    T = np.linspace(300.0, 3000.0, 28)
    lam = np.linspace(400e-9, 1000e-9, 13)
    TT, LL = np.meshgrid(T, lam, indexing="ij")
    I = planck(TT, LL)
    assert np.all(I > 0)
    np.testing.assert_allclose(planck_inverse(I, LL), TT, rtol=1e-12)


def test_planck_inverse_zero_and_negative():
    assert planck_inverse(0.0, 650e-9) == 0.0
    with pytest.raises(ValueError, match="I must be >= 0"):
        planck_inverse(-1.0, 650e-9)
    with pytest.raises(ValueError, match="I must be finite"):
        planck_inverse(np.nan, 650e-9)


def test_gray_inverse_round_trip():
    T = np.linspace(300.0, 3000.0, 50)
    np.testing.assert_allclose(gray_inverse(gray_intensity(T)), T, rtol=1e-14)
    with pytest.raises(ValueError, match="I must be >= 0"):
        gray_inverse(-1e-3)


@pytest.mark.parametrize("T", [300.0, 1200.0, 1900.0, 3000.0])
@pytest.mark.parametrize("lam", [400e-9, 650e-9, 1e-6, 5e-6])
def test_dplanck_dT_matches_finite_difference(T, lam):
    x = sc.h * sc.c / (lam * sc.k * T)
    # step scaled so the central-difference truncation error, ~ (x h / T)^2 relative,
    # is ~1e-10 and round-off ~ 1e-16 / (x h / T) ~ 1e-11
    h = 1e-5 * T / max(x, 1.0)
    fd = (planck(T + h, lam) - planck(T - h, lam)) / (2 * h)
    assert dplanck_dT(T, lam) == pytest.approx(fd, rel=1e-8)


def test_blackbody_intensity_shapes():
    T = np.full((2, 3, 4), 1500.0)
    assert blackbody_intensity(T).shape == (2, 3, 4)
    out = blackbody_intensity(T, [500e-9, 650e-9])
    assert out.shape == (2, 2, 3, 4)
    assert out[1, 0, 0, 0] == pytest.approx(planck(1500.0, 650e-9), rel=1e-14)
    assert blackbody_intensity(T, 650e-9).shape == (1, 2, 3, 4)


@pytest.mark.parametrize(
    "T, lam, match",
    [
        (0.0, 650e-9, "T must be > 0"),
        (-10.0, 650e-9, "T must be > 0"),
        (np.nan, 650e-9, "T must be finite"),
        (np.inf, 650e-9, "T must be finite"),
        (1000.0, 0.0, "wavelength must be > 0"),
        (1000.0, -1e-7, "wavelength must be > 0"),
        ("hot", 650e-9, "T must be numeric"),
        (1000.0, 650.0, "wavelength must be in m"),  # nanometres by mistake
    ],
)
def test_bad_input_raises(T, lam, match):
    with pytest.raises(ValueError, match=match):
        planck(T, lam)
    with pytest.raises(ValueError):
        dplanck_dT(T, lam)


def test_gray_bad_temperature():
    with pytest.raises(ValueError, match="T must be > 0"):
        gray_intensity([1000.0, 0.0])
