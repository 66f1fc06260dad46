"""reconstruct_series on a LocalCluster (2 worker processes x 1 thread): equal to serial
lt.reconstruct bit for bit, survives a killed worker, resumes, records bad frames."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

import lftomo as lt
from lftomo.series import WORKER_DASK_CONFIG, local_cluster, reconstruct_series

distributed = pytest.importorskip("distributed")

N_FRAMES = 6
NOISE, SEED = 0.01, 20
#: lt.reconstruct's options, given to reconstruct_series as they are (recorded in the manifest by their repr)
OPTS = RECONSTRUCT = {"rule": lt.Fixed(1e-3), "bounds": (500.0, 2500.0),
                      "solver": lt.LevenbergMarquardt(max_steps=2)}


@pytest.fixture(scope="module")
def client():
    cluster = local_cluster(2)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def serial(gray_blob):
    """The 6 frames' fields by serial lt.reconstruct (noise seed SEED + index), the reference."""
    cam, grid, flame, lf, W = gray_blob
    out = []
    for i in range(N_FRAMES):
        m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=NOISE, seed=SEED + i))
        out.append(lt.reconstruct(m, W, **RECONSTRUCT).T)
    return np.stack(out)


def test_workers_run_single_threaded_with_glibc_malloc_defaults(client):
    """Dask's nanny sets MALLOC_TRIM_THRESHOLD_ (a frame's solve 1.5-1.8x slower): our cluster unsets it."""
    env = client.run(lambda: {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "NUMBA_NUM_THREADS",
                                                               "OPENBLAS_NUM_THREADS")})
    assert len(env) == 2
    for e in env.values():
        assert e == {"MALLOC_TRIM_THRESHOLD_": None, "NUMBA_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def test_workers_run_without_dasks_profiler(client):
    """Dask's monitoring (a stack sample of a busy worker every 10 ms, a 20 ms event-loop tick, ...) took
    CPU from the frames on 2 cores: the workers of our cluster run with the profiler off and the slower
    intervals of WORKER_DASK_CONFIG."""
    import dask

    keys = ("distributed.worker.profile.enabled", "distributed.admin.tick.interval",
            "distributed.worker.memory.monitor-interval")
    seen = client.run(lambda: {k: dask.config.get(k) for k in keys})
    assert len(seen) == 2
    for cfg in seen.values():
        assert cfg == {k: WORKER_DASK_CONFIG[k] for k in keys}, cfg



def test_scheduler_keeps_every_workers_copy_of_the_forward_model(client):
    """The active memory manager is off on our cluster's scheduler: its ReduceReplicas policy dropped a
    worker's broadcast copy of W between two windows of frames, and the next frame fetched W again
    (test_series_equals_serial_bit_for_bit failed once in CI: two copies on one worker)."""
    running = client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.extensions["amm"].running)
    assert running is False

def _manifest(out):
    return json.loads((out / "manifest.json").read_text())


def test_series_equals_serial_bit_for_bit(gray_blob, serial, client, tmp_path):
    cam, grid, flame, lf, W = gray_blob
    res = reconstruct_series([lf] * N_FRAMES, W, out=tmp_path, client=client, noise=NOISE, seed=SEED, **OPTS)
    assert res.n_done == N_FRAMES and not res.failed
    T = res.stack()
    assert T.shape == (N_FRAMES, *grid.shape)
    assert np.array_equal(T, serial)  # bit for bit, not within a tolerance
    assert not np.array_equal(T[0], T[1])  # the frames' noise draws differ (seed + index)
    man = _manifest(tmp_path)
    assert man["settings"]["seed"] == SEED
    assert man["settings"]["reconstruct"]["solver"] == repr(lt.LevenbergMarquardt(max_steps=2))
    assert man["versions"]["dask"] and man["forward_model"]["kind"] == "WeightMatrix"
    # the forward model: one copy per worker process, shared by its tasks
    copies = {(f["worker"], f["forward_copy"]) for f in man["frames"]}
    workers = {f["worker"] for f in man["frames"]}
    assert len(copies) == len(workers) <= 2
    # per-frame metrics agree with the field on disk
    f0 = res.frames[0]
    assert f0.metrics["T_max"] == T[0].max() and f0.path.name == "frame_0000.npz"


def test_killed_worker_the_series_still_completes(gray_blob, serial, client, tmp_path):
    cam, grid, flame, lf, W = gray_blob
    pids = client.run(os.getpid)
    killed = []

    def kill_holders(frame):
        """After the first frame: kill every worker process that holds the forward model.

        Its running task is lost, and so is the scattered weight matrix, which
        the scheduler cannot recompute (Dask's memory manager may have dropped
        all replicas but one): the series must send it again.
        """
        if not killed:
            holders = {a for k, who in client.who_has().items() if str(k).startswith("WeightMatrix-") for a in who}
            assert holders
            for addr in holders:
                os.kill(pids[addr], signal.SIGKILL)
                killed.append(pids[addr])

    res = reconstruct_series([lf] * 3, W, out=tmp_path, client=client, noise=NOISE, seed=SEED,
                             on_frame=kill_holders, **OPTS)
    assert killed and res.n_done == 3, [f.message for f in res.failed]
    assert np.array_equal(res.stack(), serial[:3])
    client.wait_for_workers(2, timeout=60)  # the nanny restarts it for the next tests


# 86 s on 2 loaded cores (load average 8), about 25 s idle: each lt.reconstruct call compiles its JAX solver anew
@pytest.mark.heavy
def test_interrupted_series_resumes_without_redoing_frames(gray_blob, serial, client, tmp_path):
    cam, grid, flame, lf, W = gray_blob
    n = 4
    frames = [lf] * n
    seen = []

    def stop_after_two(frame):
        seen.append(frame.index)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        reconstruct_series(frames, W, out=tmp_path, client=client, noise=NOISE, seed=SEED, on_frame=stop_after_two,
                           **OPTS)
    first = {f["index"]: f for f in _manifest(tmp_path)["frames"] if f["status"] == "done"}
    assert sorted(first) == sorted(seen)
    redone = []
    res = reconstruct_series(frames, W, out=tmp_path, client=client, noise=NOISE, seed=SEED,
                             on_frame=lambda f: redone.append(f.index), **OPTS)
    assert sorted(redone) == sorted(set(range(n)) - set(first))  # only the missing frames ran
    man = _manifest(tmp_path)
    for f in man["frames"]:
        assert f["run"] == (1 if f["index"] in first else 2)
        if f["index"] in first:
            assert f["completed"] == first[f["index"]]["completed"] and f["sha256"] == first[f["index"]]["sha256"]
    assert [r["frames_to_do"] for r in man["runs"]] == [n, n - len(first)]
    assert np.array_equal(res.stack(), serial[:n])
    # a third run: nothing to do; a damaged frame file is recomputed
    (tmp_path / "frame_0003.npz").write_bytes(b"garbage")
    again = []
    reconstruct_series(frames, W, out=tmp_path, client=client, noise=NOISE, seed=SEED,
                       on_frame=lambda f: again.append(f.index), **OPTS)
    assert again == [3]
    # other settings: refused, naming what differs
    with pytest.raises(lt.LftomoError, match="other settings.*seed"):
        reconstruct_series(frames, W, out=tmp_path, client=client, noise=NOISE, seed=SEED + 1, **OPTS)


def test_bad_frames_are_recorded_per_frame(gray_blob, client, tmp_path):
    cam, grid, flame, lf, W = gray_blob
    noisy = lt.add_noise(lf, relative_std=NOISE, seed=1)
    # a light-field file with one NaN pixel (a bad frame on disk; LightField itself refuses NaN)
    good = noisy.save(tmp_path / "good.npz")
    with np.load(good, allow_pickle=False) as z:
        arrays = dict(z)
    arrays["raw"] = arrays["raw"].copy()
    arrays["raw"].flat[7] = np.nan
    np.savez(tmp_path / "nan.npz", **arrays)
    nan = str(tmp_path / "nan.npz")
    other_cam = lt.Camera.seed(1.0, mla={"count": (10, 10)})
    other = lt.add_noise(lt.render(lt.Scene(medium=flame), other_cam, rays_per_pixel=1, seed=0, wavelengths="gray",
                                   progress=False), relative_std=NOISE, seed=1)
    (tmp_path / "corrupt.npz").write_bytes(b"PK\x03\x04 not really")
    frames = [noisy, nan, other, str(tmp_path / "missing.npz"), str(tmp_path / "corrupt.npz"), lf, np.zeros(3)]
    res = reconstruct_series(frames, W, out=tmp_path / "out", client=client, **OPTS)
    status = {f.index: (f.status, f.message) for f in res.frames}
    assert status[0] == ("done", "")
    assert status[1][0] == "failed" and "frame 1: " in status[1][1]
    assert "nan.npz" in status[1][1] and "non-finite" in status[1][1]
    assert status[2][0] == "failed" and "frame 2" in status[2][1] and "sensor of shape" in status[2][1]
    assert status[3][0] == "failed" and "missing.npz" in status[3][1] and "does not exist" in status[3][1]
    assert status[4][0] == "failed" and "corrupt.npz" in status[4][1]
    assert status[5][0] == "failed" and "noise-free" in status[5][1] and "noise=" in status[5][1]
    assert status[6][0] == "failed" and "must be an lftomo.LightField" in status[6][1]
    T = res.stack()
    assert np.isfinite(T[0]).all() and np.isnan(T[1:]).all()
    man = _manifest(tmp_path / "out")
    assert [f["status"] for f in man["frames"]] == ["done"] + ["failed"] * 6


def test_bad_arguments_are_refused_by_name(gray_blob, tmp_path):
    cam, grid, flame, lf, W = gray_blob
    with pytest.raises(lt.LftomoError, match="forward must be"):
        reconstruct_series([lf], "W.npz", out=tmp_path)
    with pytest.raises(lt.LftomoError, match="frames must be a sequence"):
        reconstruct_series("frame.npz", W, out=tmp_path)
    with pytest.raises(lt.LftomoError, match="workers must be an integer >= 1, got 0"):
        reconstruct_series([lf], W, out=tmp_path, workers=0)
    with pytest.raises(lt.LftomoError, match="scheduler must be an address"):
        reconstruct_series([lf], W, out=tmp_path, scheduler="localhost")
    with pytest.raises(lt.LftomoError, match="noise must be"):
        reconstruct_series([lf], W, out=tmp_path, noise=-1.0)
    # a misspelt reconstruct option: refused before a cluster starts or the folder is written (each frame had
    # failed on it, and the manifest recorded it)
    with pytest.raises(lt.LftomoError, match=r"max_step=3: not an option of lftomo.reconstruct \(did you mean "):
        reconstruct_series([lf], W, out=tmp_path / "typo", workers=1, max_step=3)
    assert not (tmp_path / "typo").exists()


def test_precessing_flame_is_periodic_mirrored_at_half_period_with_fixed_absorption():
    g = lt.phantoms.default_flame_grid((10, 10, 10))
    P = 0.02
    m0 = lt.phantoms.precessing_flame(g, 0.0, period=P)
    assert np.allclose(lt.phantoms.precessing_flame(g, P, period=P).T, m0.T, rtol=1e-12, atol=0)
    # half a period turns the lobes by π about the vertical axis through the box centre: x -> -x, z -> -z
    half = lt.phantoms.precessing_flame(g, P / 2, period=P)
    assert np.allclose(half.T, m0.T[::-1, :, ::-1], rtol=1e-12, atol=0)
    assert not np.allclose(lt.phantoms.precessing_flame(g, P / 4, period=P).T, m0.T)  # it does move
    seq = lt.phantoms.precessing_flame_sequence(g, 3, frame_rate=1000.0, period=P)
    assert all(np.array_equal(s.sigma_a, m0.sigma_a) for s in seq)  # one weight matrix serves every frame
    assert np.allclose(seq[1].T, lt.phantoms.precessing_flame(g, 1e-3, period=P).T, rtol=0, atol=0)
    # T = T_ambient + (T_peak - T_ambient) θ with θ in [0, 1]
    assert m0.T.min() >= 300.0 and m0.T.max() <= 1900.0 and m0.T.max() > 1500.0
    with pytest.raises(lt.LftomoError, match="orbit must be in"):
        lt.phantoms.precessing_flame(g, 0.0, orbit=0.5)
    with pytest.raises(lt.LftomoError, match="period"):
        lt.phantoms.precessing_flame(g, 0.0, period=0.0)
    with pytest.raises(lt.LftomoError, match="n_frames"):
        lt.phantoms.precessing_flame_sequence(g, 0)


def test_frame_metrics_center_volume_and_extremes():
    from lftomo.series import frame_metrics

    g = lt.Grid(shape=(4, 3, 2), lower=(0.0, 0.0, 0.0), upper=(0.004, 0.003, 0.002))  # 1 mm voxels
    T = np.full(g.shape, 1000.0)
    T[1:3, 1, :] = 2000.0  # the 2 x 1 x 2 centre block (x even: voxels 1, 2; y odd: 1; z even: 0, 1)
    T[0, 0, 0] = 1600.0
    m = frame_metrics(T, g)
    assert m["T_center"] == 2000.0 and m["T_max"] == 2000.0 and m["T_min"] == 1000.0
    assert np.isclose(m["flame_volume_m3"], 5 * 1e-9, rtol=1e-12)


def test_run_tasks_on_the_cluster_equals_serial_calls(client):
    """The sweeps' task runner: every key's result, whatever order the tasks finish in; shared arguments
    reach every task; serial=True calls in order without Dask."""
    from lftomo.series import frame_metrics, run_tasks

    g = lt.Grid(shape=(4, 3, 2), lower=(0.0, 0.0, 0.0), upper=(0.004, 0.003, 0.002))
    fields = [np.full(g.shape, 1000.0 + 300.0 * k) for k in range(5)]
    keys = [(f,) for f in fields]
    serial = list(run_tasks(frame_metrics, keys, g, serial=True))
    assert all(k[0] is f for (k, _), f in zip(serial, fields))  # in order
    want = {float(k[0].flat[0]): r for k, r in serial}
    got = {float(k[0].flat[0]): r for k, r in run_tasks(frame_metrics, keys, g, client=client)}
    assert got == want and len(got) == 5
    assert want[1600.0]["flame_volume_m3"] == pytest.approx(24e-9) and want[1300.0]["flame_volume_m3"] == 0.0
    assert list(run_tasks(frame_metrics, [], g, client=client)) == []
