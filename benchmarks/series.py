"""A time-resolved series on a local Dask cluster against the same frames reconstructed serially.

Frames: :func:`lftomo.phantoms.precessing_flame` at ``--frames`` instants (1000 frames/s, 50 Hz
precession) on an ``--n``³ grid in the default flame box, rendered at 650 nm by the seed camera with
``--mla`` lenslets per side (``--rays`` rays/pixel, seed 1); the weight matrix on the same grid for
the phantom's fixed absorption (seed 2, another set of rays); 1 % noise (seed 100 + frame).  Every
frame is reconstructed with the library's defaults (λ by its discrepancy rule; bounds 300–2500 K) or,
with ``--lam``, with that fixed λ and ``--max-steps`` steps (a short frame, where the solver's one
compilation per process weighs most), once serially in this process (``lt.reconstruct``), once by
:func:`lftomo.reconstruct_series` on a LocalCluster of ``--workers`` single-threaded processes.

The fields are bit-identical when this process runs with the workers' thread settings
(``lftomo.series.WORKER_ENV``: ``OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
MKL_NUM_THREADS=1``); a multithreaded BLAS sums the solver's dot products in another order.

The machine's own ceiling is measured in the same run: the frames split over ``--workers``
plain processes at once (no Dask; each compiles the solver once, as a worker does).  On
``--workers`` cores it bounds what any scheduler can reach; ``series / plain processes`` is
Dask's share.

Printed: the serial and series wall times and their ratio (the speed-up; the cluster's start-up
is timed separately and excluded; both include compiling the solver, once in the serial process
and once in each worker), the first and later frames' times of both, whether the fields are bit-identical, the peak resident memory
of each worker process, and how many copies of the forward model the tasks used (distinct
(worker process, object id) pairs: one per worker when it is sent once per worker).

Usage::

    OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \\
        python benchmarks/series.py [--frames 16] [--n 16] [--mla 16] [--workers 2] [--lam 0.01 --max-steps 10]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np

import lftomo as lt


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _import_solvers() -> None:
    import lftomo.inverse.solvers  # noqa: F401 - JAX imported, as in the serial process and the workers


def _cpu_seconds(pids: dict) -> dict:
    """CPU seconds (user + system) used so far by each process of ``{role: [pid, ...]}``, summed per role."""
    import psutil  # a dependency of distributed

    return {role: sum(sum(psutil.Process(p).cpu_times()[:2]) for p in ps) for role, ps in pids.items()}


def _plain_share(frames, W, opts, first: int, step: int) -> list:
    """Frames ``first::step`` reconstructed as the serial loop does, in a plain (non-Dask) process."""
    out = []
    for i in range(first, len(frames), step):
        m = lt.Measurement.from_lightfield(lt.add_noise(frames[i], relative_std=0.01, seed=100 + i), channel=0)
        out.append((i, lt.reconstruct(m, W, **opts).T))
    return out


def _plain_processes(frames, W, opts, n: int) -> tuple[float, list]:
    """Wall time of the frames split over ``n`` plain processes at once (the machine's ceiling), and the fields."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from lftomo.series import WORKER_ENV

    saved = {k: os.environ.get(k) for k in WORKER_ENV}
    os.environ.update(WORKER_ENV)  # inherited by the spawned processes
    try:
        with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"), initializer=_import_solvers) as ex:
            list(ex.map(time.sleep, [0.5] * n))  # every process started and imported before the clock runs
            t0 = time.perf_counter()
            parts = [ex.submit(_plain_share, frames, W, opts, k, n) for k in range(n)]
            fields = dict(x for p in parts for x in p.result())
            return time.perf_counter() - t0, [fields[i] for i in range(len(frames))]
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--mla", type=int, default=16)
    ap.add_argument("--rays", type=int, default=4)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--lam", type=float, default=None,
                    help="a fixed λ with --max-steps LM steps per frame (default: the library's defaults, λ by its rule)")
    ap.add_argument("--max-steps", type=int, default=10)
    a = ap.parse_args()
    wl = 650e-9
    cam = lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    t0 = time.perf_counter()
    media = lt.phantoms.precessing_flame_sequence(grid, a.frames, width_scale=3.0)
    frames = [lt.render(lt.Scene(medium=m), cam, rays_per_pixel=a.rays, seed=1, wavelengths=(wl,), progress=False)
              for m in media]
    W = lt.weights(cam, grid, sigma_a=media[0].sigma_a_at(wl), wavelength=wl, rays_per_pixel=a.rays, seed=2,
                   progress=False)
    print(f"setup: {a.frames} frames of {cam.sensor_shape[0]}x{cam.sensor_shape[1]} px rendered + W {W.shape} "
          f"nnz {W.nnz} ({W.nbytes / 1e6:.1f} MB) in {time.perf_counter() - t0:.1f} s; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    # lt.reconstruct's settings; reconstruct_series takes the same (recorded in its manifest by their repr)
    opts = series_opts = {"bounds": (300.0, 2500.0)}
    if a.lam is not None:
        opts.update(rule=lt.Fixed(a.lam), solver=lt.LevenbergMarquardt(max_steps=a.max_steps))

    t0 = time.perf_counter()
    serial, t_frames = [], []
    for i, lf in enumerate(frames):
        t1 = time.perf_counter()
        m = lt.Measurement.from_lightfield(lt.add_noise(lf, relative_std=0.01, seed=100 + i), channel=0)
        serial.append(lt.reconstruct(m, W, **opts).T)
        t_frames.append(time.perf_counter() - t1)
    t_serial = time.perf_counter() - t0
    print(f"serial: {t_serial:.1f} s ({t_serial / a.frames:.2f} s/frame; first frame {t_frames[0]:.1f} s with the "
          f"solver's compilation, later frames median {np.median(t_frames[1:]) if a.frames > 1 else np.nan:.2f} s); "
          f"load average {os.getloadavg()[0]:.1f}")

    from distributed import Client

    from lftomo.series import local_cluster

    t0 = time.perf_counter()
    cluster = local_cluster(a.workers)  # the cluster reconstruct_series starts by default
    client = Client(cluster)
    client.run(lambda: __import__("lftomo.inverse.solvers"))  # imports (JAX) in every worker, as serial had
    t_start = time.perf_counter() - t0
    # a LocalCluster's scheduler and nannies run in this process, beside the client
    pids = {"workers": list(client.run(os.getpid).values()), "this process (client, scheduler, nannies)": [os.getpid()]}
    cpu0 = _cpu_seconds(pids)
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        res = lt.reconstruct_series(frames, W, out=out, client=client, noise=0.01, seed=100, **series_opts)
        t_series = time.perf_counter() - t0
        cpu = {k: v - cpu0[k] for k, v in _cpu_seconds(pids).items()}
        man = json.load(open(os.path.join(out, "manifest.json")))
        stack = res.stack()
    rss = client.run(_peak_rss_mb)
    client.close()
    cluster.close()
    copies = {(f["worker"], f["forward_copy"]) for f in man["frames"]}
    workers = {f["worker"] for f in man["frames"]}
    same = bool(np.array_equal(stack, np.stack(serial)))
    dT = float(np.max(np.abs(stack - np.stack(serial))))
    print(f"series: {t_series:.1f} s on {a.workers} workers (cluster start {t_start:.1f} s, not included); "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"speed-up serial/series: {t_serial / t_series:.2f}x; frames done {res.n_done}/{a.frames}; "
          f"bit-identical to serial: {same} (max |dT| {dT:.3g} K)")
    print("peak memory per worker (MB): " + ", ".join(f"{v:.0f}" for v in rss.values())
          + f"; this process {_peak_rss_mb():.0f} MB")
    print("CPU seconds during the series: " + ", ".join(f"{k} {v:.1f}" for k, v in cpu.items())
          + f" (of {a.workers} x {t_series:.1f} s of wall time on the workers' cores)")
    print(f"forward-model copies used by the tasks: {len(copies)} on {len(workers)} worker process(es)")
    for w in sorted(workers):  # per worker: its first frame compiles the solver, the later ones reuse it
        secs = [f["seconds"] for f in sorted(man["frames"], key=lambda f: f["completed"]) if f["worker"] == w]
        print(f"  worker {w}: {len(secs)} frames, first {secs[0]:.1f} s, later median "
              f"{np.median(secs[1:]) if len(secs) > 1 else np.nan:.2f} s")
    t_plain, plain = _plain_processes(frames, W, opts, a.workers)
    print(f"ceiling: the same frames split over {a.workers} plain processes at once (no Dask) {t_plain:.1f} s: "
          f"speed-up {t_serial / t_plain:.2f}x; series / plain processes {t_series / t_plain:.2f}; "
          f"bit-identical: {bool(np.array_equal(np.stack(plain), np.stack(serial)))}; load average "
          f"{os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
