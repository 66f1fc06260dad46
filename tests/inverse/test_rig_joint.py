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


def test_rig_channels_read_their_own_camera_table(rig_data):
    """Each channel of a rig is evaluated through its own camera's table only: the joint model's whitened
    data residual (host sparse Jacobians, JAX with host products, JAX autodiff) equals the stacked tables'
    ``W(σ_a) I_b + background`` read at the channel's stacked rows, its exact sparse Jacobian equals
    JAX's forward-mode derivative of the autodiff residual, and its Jacobi column scale the one of that
    derivative and the prior's."""
    import jax

    from lftomo.inverse.joint import JointModel, SigmaSpace, _check_channels
    from lftomo.inverse.lsq import jacobi_scale
    from lftomo.inverse.regularizers import resolve_prior
    from lftomo.radiation import blackbody

    grid, T, sa, ms, tables = rig_data
    ms, wls, stack, rows = _check_channels(ms, tables)
    kw = dict(grid=grid, symmetry=None, prior=resolve_prior("curvature"), bounds=(1000.0, 2500.0), alpha=1.38,
              space=SigmaSpace("log", 200.0, 1e-4, None), ridge=0.0)
    host, autodiff = (JointModel(ms, wls, stack, rows, engine=e, **kw) for e in ("host", "jax"))
    assert [t is u for t, u in zip(host.tables, tables)] == [True] * 4
    theta = np.random.default_rng(4).normal(0.0, 0.5, 2 * host.n_u)
    Tv = 1000.0 + 1500.0 / (1.0 + np.exp(-theta[: host.n_u]))
    sref = kw["space"].sigma_of_unit(1.0 / (1.0 + np.exp(-theta[host.n_u:])))
    expected = []
    for c, m in enumerate(ms):
        W = stack.weights(sref * host.factors[c])
        signal = W.matrix @ blackbody(Tv, wls[c]) + W.background
        assert (rows[c] >= 0).all()
        expected.append((signal[rows[c]] - m.y) / m.sigma)
    expected = np.concatenate(expected)
    r_host, J_host = host.data_jacobian(theta)
    m_total = expected.size
    for r in (r_host, *(np.asarray(model.residual(theta, 1.0))[:m_total] for model in (host, autodiff))):
        np.testing.assert_allclose(r, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    J_ad = np.asarray(jax.jacfwd(lambda p: autodiff.residual(p, 1.0)[:m_total])(theta))
    np.testing.assert_allclose(J_host.toarray(), J_ad, rtol=1e-7, atol=1e-9 * np.abs(J_ad).max())
    # the Jacobi column scale from one pass over each channel's rows = 1/‖column‖ of [J; √λ J_prior]
    lam = 30.0
    Jr = host.prior_jacobian(theta)[1].toarray()
    c2 = (J_ad ** 2).sum(axis=0) + lam * (Jr ** 2).sum(axis=0)
    np.testing.assert_allclose(host.column_scale(theta, lam), jacobi_scale(c2), rtol=1e-7)


def test_a_stack_names_the_table_of_a_channels_rows(rig_data):
    grid, T, sa, ms, tables = rig_data
    from lftomo.inverse.rigsegments import SegmentStack

    stack = SegmentStack([tables[0], tables[2]])
    n0, n1 = tables[0].n_rows, tables[2].n_rows
    k, local = stack.table_of_rows(np.array([-1, n0, n0 + n1 - 1]))
    assert k == 1 and local.tolist() == [-1, 0, n1 - 1]
    k, local = stack.table_of_rows(np.array([0, n0 - 1]))
    assert k == 0 and local.tolist() == [0, n0 - 1]
    with pytest.raises(ValueError, match="one camera's"):
        stack.table_of_rows(np.array([n0 - 1, n0]))
    with pytest.raises(ValueError, match="none"):
        stack.table_of_rows(np.array([-1, -1]))


def test_a_rigs_coarse_start_coarsens_each_camera_table_once(rig_data, monkeypatch):
    """The coarse-to-fine start of a rig pairs each channel with its camera's coarsened table, one per camera
    (two channels of one camera share it, as their fine tables are shared), so that the coarse fit's stack
    holds one table per camera."""
    from lftomo.inverse import reconstruct as rec_module
    from lftomo.inverse.joint import _check_channels

    grid, T, sa, ms, tables = rig_data
    monkeypatch.setattr(rec_module, "COARSE_START_MIN_VOXELS", 0)
    problem = lt.Problem.from_data(ms, tables, unknowns="T+sigma_a")
    coarse = rec_module._coarse_problem(problem, "auto", {})
    f = coarse.forward
    assert (f[0] is f[1], f[2] is f[3], f[0] is f[2]) == (True, True, False)
    assert tuple(f[0].metadata["grid"]["shape"]) == (2, 2, 2)
    _, _, stack, _ = _check_channels(list(coarse.measurements), f)
    assert len(stack.tables) == 2
