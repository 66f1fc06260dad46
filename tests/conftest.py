import pytest

import lftomo as lt


@pytest.fixture(scope="session")
def seed_camera():
    """The reference camera focused at 1 m."""
    return lt.Camera.seed(1.0)


@pytest.fixture(scope="session")
def small_camera():
    """Seed optics with a 20 x 20 MLA (fast renders; same lenses and pitch)."""
    return lt.Camera.seed(1.0, mla={"count": (20, 20)})


@pytest.fixture(scope="session")
def ideal_camera():
    """Seed camera with the ideal thin main lens (no aberrations)."""
    return lt.Camera.seed(1.0, main_lens={"ideal": True})


def white_plane(z=1.0, size=0.4, radiance=1.0):
    return lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, z), size=(size, size), radiance=radiance)])
