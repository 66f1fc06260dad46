"""The joint T + sigma_a fit of a rig: two cameras (the second at 90 deg about the box), two wavelengths each."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lftomo as lt
from lftomo.inverse.reconstruct import reconstruct

WAVELENGTHS = (650e-9, 800e-9)


@pytest.fixture(scope="module")
def rig_data():
    """Noise-free on-grid data of a random 4³ field seen by two cameras at 90°, each camera's
    segment table built from the rays of its render (a solver check, as the one-camera test)."""
    cam_a = lt.Camera.seed(1.0, mla={"count": (12, 12)})
    cam_b = cam_a.with_pose(lt.Pose.look_at(eye=(-1.0, 0.0, 1.0), target=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0)))
    grid = lt.Grid(shape=(4, 4, 4), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))
    rng = np.random.default_rng(0)
    T = 1500.0 + 300.0 * rng.random(grid.shape)
    sa = 10.0 + 20.0 * rng.random(grid.shape)
    scene = lt.Scene(medium=lt.Medium(grid, sigma_a=sa, T=T, sigma_a_rule=lt.SootRule(650e-9, 1.38)))
    ms, tables = [], []
    for cam, seed in ((cam_a, 2), (cam_b, 3)):
        lf = lt.render(scene, cam, rays_per_pixel=8, seed=seed, wavelengths=WAVELENGTHS)
        clean = dataclasses.replace(lf, noise_std=1e-3 * lf.raw + 1e-6 * lf.raw.max(), signal=lf.raw)
        table = lt.ray_segments(cam, grid, rays_per_pixel=8, seed=seed)
        for c in range(len(WAVELENGTHS)):
            ms.append(lt.Measurement.from_lightfield(clean, data="subaperture", channel=c))
            tables.append(table)
    return grid, T, sa, ms, tables


def test_rig_joint_fit_recovers_T_and_sigma_a_exactly(rig_data):
    """Four channels (2 cameras x 2 wavelengths) in one fit: the exact dense LM converges to the
    truth, which it can only do if every channel is compared with its own camera's rows."""
    grid, T, sa, ms, tables = rig_data
    rec = reconstruct(ms, tables, unknowns="T+sigma_a", rule=lt.Fixed(1e-10), bounds=(1000.0, 2500.0),
                      start=(np.full(grid.shape, 1600.0), np.full(grid.shape, 15.0)), solver=lt.DenseLM(max_steps=200))
    rel_T = np.abs(rec.T - T) / T
    rel_sa = np.abs(rec.sigma_a - sa) / sa
    assert rec.converged and rel_T.max() < 1e-8 and rel_sa.max() < 1e-8, (rel_T.max(), rel_sa.max())
    assert rec.details["method"] == "dense-lm"


def test_rig_joint_fit_refuses_mismatched_channels(rig_data):
    grid, T, sa, ms, tables = rig_data
    with pytest.raises(ValueError, match=r"segments\[0\] was built for another camera"):
        reconstruct(ms, [tables[2], tables[2], tables[0], tables[0]], unknowns="T+sigma_a", rule=lt.Fixed(1.0))
    with pytest.raises(ValueError, match="one table per measurement"):
        reconstruct(ms, tables[:3], unknowns="T+sigma_a", rule=lt.Fixed(1.0))
    with pytest.raises(ValueError, match=r"wavelengths must differ \(per camera\)"):
        reconstruct([ms[0], ms[0], ms[2]], [tables[0], tables[0], tables[2]], unknowns="T+sigma_a",
                    rule=lt.Fixed(1.0))
    with pytest.raises(ValueError, match="2 or more wavelengths, got only 650 nm"):
        reconstruct([ms[0], ms[2]], [tables[0], tables[2]], unknowns="T+sigma_a", rule=lt.Fixed(1.0))
    other = lt.ray_segments(lt.Camera.seed(1.0, mla={"count": (12, 12)}),
                            lt.Grid(shape=(3, 3, 3), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006)),
                            rays_per_pixel=1, seed=0)
    with pytest.raises(ValueError, match="must share the grid"):
        reconstruct(ms[:2] + ms[2:], [tables[0], tables[0], other, other], unknowns="T+sigma_a", rule=lt.Fixed(1.0))
