"""The reference text's findings, as numbers (small camera, few rays)."""

import math

import pytest

import lftomo as lt
from lftomo.forward.reference_cases import reference_case_metrics


@pytest.fixture(scope="module")
def metrics():
    cam = lt.Camera.seed(1.0, mla={"count": (30, 30)})
    return reference_case_metrics(cam, rays_per_pixel=8, seed=1)


def test_non_emitting_media_only_attenuate_the_target(metrics):
    for case in ("absorbing", "scattering"):
        # a cold medium alone is invisible at 650 nm
        assert metrics[case]["emission_fraction"] < 1e-12
    # pure absorber: the same rays with and without the medium (common random
    # numbers) and exact transport, so the ratio is exp(-tau / cos(theta)):
    # obliquity of the aperture cone and the field <= 4 deg -> tau changes by
    # <= 0.25 %, the attenuation by <= 0.25 % (bound 0.3 %)
    assert metrics["absorbing"]["attenuation"] == pytest.approx(math.exp(-1.0), rel=0.003)
    # scattering: between the extinction-only value and 1 (forward-scattered light)
    assert math.exp(-1.0) < metrics["scattering"]["attenuation"] < 1.0


def test_emitting_medium_barely_changes_under_refocus(metrics):
    e = metrics["emitting"]
    assert e["emission_fraction"] > 0.5  # the medium's own light dominates
    # refocusing from the medium's front to its back: a target seen through a
    # non-emitting medium changes a lot, the emitting medium's image hardly
    assert e["refocus_change"] < metrics["absorbing"]["refocus_change"] / 3
    assert e["refocus_change"] < metrics["target_only_refocus_change"] / 3
