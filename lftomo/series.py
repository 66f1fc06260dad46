"""Time-resolved series: one reconstruction per frame, distributed over processes with Dask.

:func:`reconstruct_series` runs :func:`lftomo.reconstruct` on every frame of a
sequence as one ``dask.distributed`` task per frame.  The forward model (a
:class:`~lftomo.WeightMatrix` or :class:`~lftomo.RaySegments`) is sent to each
worker once (``Client.scatter(..., broadcast=True)``) and shared by the tasks
there.  Each frame's result is written atomically (:mod:`lftomo.io`) to
``out/frame_XXXX.npz`` as it completes, and ``out/manifest.json`` (settings,
seeds, versions, the forward model's fingerprint, per-frame status, metrics and
file checksum) is rewritten atomically after every frame.  A rerun with the
same settings skips the frames whose file is complete (recorded as done, same
frame, same SHA-256) and computes the rest; failed frames are retried.

A frame that cannot be reconstructed (unreadable file, wrong sensor shape,
non-finite data, a solver error) is recorded in the manifest with its message
and the series goes on.  A worker process that dies (crash, killed, out of
memory) loses only its running task, which the scheduler reruns elsewhere
(``distributed.scheduler.allowed-failures`` times before the frame is recorded
as failed).

Results do not depend on the worker: a frame's task calls
:func:`lftomo.reconstruct` with the same measurement, forward model and options
as a serial call (the reconstruction is deterministic), and the noise of a
noise-free frame is drawn with the seed ``seed + index``.

The default cluster is a :class:`distributed.LocalCluster` of ``workers``
processes (default: the usable cores) with one thread each, started with one
numba / OpenMP / BLAS thread per process (:data:`WORKER_ENV`), so that the
processes do not oversubscribe the cores.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import platform
import socket
import time
import warnings
from collections import deque
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ._validate import require_in_range
from .errors import LftomoError
from .io import SERIES_FORMAT_PREFIX, SERIES_MANIFEST

__all__ = ["reconstruct_series", "SeriesResult", "FrameResult", "WORKER_ENV", "WORKER_DASK_CONFIG", "MANIFEST",
           "frame_metrics", "series_figure", "series_strip", "fingerprint", "solve_frame", "client_for",
           "local_cluster", "run_tasks"]

#: Environment of the default LocalCluster's worker processes: one thread per library.
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "MKL_NUM_THREADS": "1"}
#: Dask settings of the default LocalCluster.  glibc's malloc is left at its defaults: Dask's nanny
#: sets ``MALLOC_TRIM_THRESHOLD_=65536`` in its workers, which also turns off glibc's adaptive
#: mmap threshold, so every array above 128 KiB is a fresh mmap with its pages faulted in anew
#: (``None`` unsets it).  Dask's own monitoring runs less often: the event-loop tick (20 ms), the
#: workers' statistical profiler (a stack sample every 10 ms), the nannies' memory check (100 ms)
#: and the system monitor (500 ms) are for its dashboard and diagnostics, and on a machine whose
#: every core runs a worker they take CPU from the frames (docs/series.md).
WORKER_DASK_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                      "distributed.admin.tick.interval": "1s",
                      "distributed.worker.profile.enabled": False,
                      "distributed.worker.memory.monitor-interval": "1s",
                      "distributed.admin.system-monitor.interval": "2s"}
#: Scheduler settings of :func:`local_cluster`: the active memory manager off.  Its ReduceReplicas policy
#: drops a worker's replica of the broadcast forward model whenever no task waiting there needs it
#: (between two windows of frames), and the next frame on that worker fetches the whole matrix again (a
#: second copy, seen in the test of one copy per worker).
SCHEDULER_DASK_CONFIG = {"distributed.scheduler.active-memory-manager.start": False}
#: Name of the manifest in the output folder (the other commands know a series' folder by it).
MANIFEST = SERIES_MANIFEST
FORMAT = f"{SERIES_FORMAT_PREFIX}-1"
#: Temperature (K) above which a voxel counts as flame in :func:`frame_metrics`.
FLAME_T = 1500.0


# ---------------------------------------------------------------- results
@dataclasses.dataclass(frozen=True)
class FrameResult:
    """One frame of a series.

    Attributes
    ----------
    index : int
        Position in the sequence (0-based).
    source : str
        The file, or ``"<LightField>"`` / ``"<Measurement>"`` for an object.
    status : {"done", "failed"}
    message : str
        Why the frame failed ("" when done).
    path : Path or None
        ``out/frame_XXXX.npz`` when done.
    metrics : dict
        :func:`frame_metrics` and the reconstruction's summary (λ, χ²/m, steps, seconds).
    """

    index: int
    source: str
    status: str
    message: str
    path: Path | None
    metrics: dict


@dataclasses.dataclass(frozen=True)
class SeriesResult:
    """Summary of :func:`reconstruct_series`: one :class:`FrameResult` per frame.

    The temperature fields stay on disk; :meth:`stack` loads them.
    """

    out: Path
    frames: tuple
    grid_shape: tuple

    @property
    def manifest(self) -> Path:
        return self.out / MANIFEST

    @property
    def n_done(self) -> int:
        return sum(f.status == "done" for f in self.frames)

    @property
    def failed(self) -> tuple:
        """The frames that failed."""
        return tuple(f for f in self.frames if f.status != "done")

    def stack(self, name: str = "T") -> np.ndarray:
        """The fields of every frame, shape ``(n_frames, nx, ny, nz)``; NaN for failed frames.

        Parameters
        ----------
        name : {"T", "sigma_a"}
            Temperature (K) or, for joint fits, absorption (m⁻¹).
        """
        from .io import check_member, read_npz

        out = np.full((len(self.frames), *self.grid_shape), np.nan)
        for k, f in enumerate(self.frames):
            if f.status == "done":
                arrays = read_npz(f.path, what="series frame file", needs="a frame written by reconstruct_series")
                out[k] = check_member(arrays, name, path=f.path, what="series frame file", shape=self.grid_shape)
        return out


def frame_metrics(T: np.ndarray, grid) -> dict[str, float]:
    """Per-frame scalars of a temperature field ``T`` (K, shape ``grid.shape``).

    Returns
    -------
    dict
        ``T_max`` and ``T_min`` (K); ``flame_volume_m3``: the volume of the
        voxels above :data:`FLAME_T` (count × voxel volume, m³); ``T_center``:
        ``T`` trilinearly interpolated at the box centre (the mean of the 2
        middle voxel centres along an axis of even length, the middle one
        along an odd one).
    """
    T = np.asarray(T, dtype=float)
    sub = T
    for axis, n in enumerate(T.shape):
        idx = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        sub = np.take(sub, idx, axis=axis)
    return {"T_max": float(T.max()), "T_min": float(T.min()),
            "flame_volume_m3": float(np.count_nonzero(T > FLAME_T) * np.prod(grid.spacing)),
            "T_center": float(sub.mean())}


# ---------------------------------------------------------------- fingerprints
def _digest(obj: Any, h) -> None:
    """Feed a deterministic description of ``obj`` (arrays by content) to the hash ``h``."""
    import scipy.sparse as sp

    if isinstance(obj, np.ndarray) or type(obj).__module__.startswith("jax"):
        a = np.ascontiguousarray(np.asarray(obj))
        h.update(f"nd{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif sp.issparse(obj):
        c = obj.tocsr()
        h.update(f"csr{c.shape}".encode())
        for a in (c.data, c.indices, c.indptr):
            _digest(a, h)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in dataclasses.fields(obj):
            h.update(f.name.encode())
            _digest(getattr(obj, f.name), h)
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            h.update(repr(k).encode())
            _digest(obj[k], h)
    elif isinstance(obj, (list, tuple)):
        h.update(f"seq{len(obj)}".encode())
        for x in obj:
            _digest(x, h)
    elif obj is None or isinstance(obj, (str, int, float, bool, np.generic)):
        h.update(repr(obj).encode())
    else:
        h.update(type(obj).__name__.encode())
        with contextlib.suppress(TypeError):
            _digest(vars(obj), h)


def fingerprint(obj: Any) -> str:
    """SHA-256 (hex) of ``obj``'s content: arrays, sparse matrices, dataclasses, containers."""
    h = hashlib.sha256()
    _digest(obj, h)
    return h.hexdigest()


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _is_path(frame: Any) -> bool:
    return isinstance(frame, (str, os.PathLike))


def _frame_key(frame: Any) -> tuple[str, str]:
    """(source, key): the file (and its size and mtime) or a content hash of the object."""
    if _is_path(frame):
        p = Path(frame)
        try:
            st = p.stat()
            return str(p), f"file:{p.resolve()}:{st.st_size}:{st.st_mtime_ns}"
        except OSError:
            return str(p), f"file:{p}:missing"
    return f"<{type(frame).__name__}>", "sha256:" + fingerprint(frame)


# ---------------------------------------------------------------- the task (runs on a worker)
def _measurement(frame: Any, index: int, settings: dict):
    """The Measurement of one frame (noise added to a noise-free light field with seed ``seed + index``)."""
    from .inverse.measurement import Measurement, add_noise
    from .lightfield import LightField

    if isinstance(frame, Measurement):
        return frame
    if not isinstance(frame, LightField):
        raise LftomoError(f"frame {index} must be an lftomo.LightField, Measurement or a light-field .npz path, "
                          f"got {type(frame).__name__}")
    if not np.all(np.isfinite(frame.raw)):
        raise LftomoError(f"frame {index}: the light field's raw image has "
                          f"{int(np.count_nonzero(~np.isfinite(frame.raw)))} non-finite pixel(s) (NaN or inf)")
    if frame.noise_std is None:
        if settings["noise"] is None:
            raise LftomoError(f"frame {index}: the light field is noise-free (no noise_std); pass noise=<relative "
                              "std> to add Gaussian noise (seed seed + index), or give noisy frames (lt.add_noise)")
        frame = add_noise(frame, relative_std=settings["noise"], seed=settings["seed"] + index)
    depths = settings["depths"]
    return Measurement.from_lightfield(frame, data=settings["data"], depths=None if depths is None else list(depths),
                                       channel=settings["channel"])


def solve_frame(index: int, frame: Any, forward: Any, settings: dict) -> dict:
    """Reconstruct one frame: the task of :func:`reconstruct_series` (runs on a worker).

    Never raises for a bad frame: returns ``{"status": "failed", "message": ...}``
    instead.  Also returns the worker's process id and ``id(forward)``, from
    which the number of copies of the forward model can be counted.
    """
    from .inverse.reconstruct import reconstruct

    t0 = time.perf_counter()
    info = {"index": index, "worker": f"{socket.gethostname()}:{os.getpid()}", "forward_copy": id(forward)}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            m = _measurement(frame, index, settings)
            m_meta = getattr(frame, "metadata", None) or {}  # raw frames: pixels left out
            rec = reconstruct(m, forward, **{"progress": False, **settings["reconstruct"]})  # the series has its bar
        T = np.asarray(rec.T, dtype=float)
        if not np.all(np.isfinite(T)):
            raise LftomoError(f"frame {index}: the reconstruction returned non-finite temperatures")
        sa = None if rec.sigma_a is None else np.asarray(rec.sigma_a, dtype=float)
        summary = json.loads(json.dumps(rec.summary(), default=float))
        return {**info, "status": "done", "message": "", "T": T, "sigma_a": sa, "grid": rec.grid.to_dict(),
                "metrics": {**frame_metrics(T, rec.grid), "regularization": summary["regularization"],
                            "chi2_per_datum": summary["chi2_per_datum"], "iterations": summary["iterations"],
                            "converged": summary["converged"], "n_data": int(m.size),
                            **{k: int(m_meta[k]) for k in ("n_saturated", "n_uncalibrated") if k in m_meta},
                            "warnings": sorted({str(w.message) for w in caught})},
                "summary": summary, "seconds": time.perf_counter() - t0}
    except Exception as exc:  # noqa: BLE001 - a bad frame is recorded, never fatal to the series
        msg = str(exc) if str(exc).startswith(f"frame {index}") else f"frame {index}: {type(exc).__name__}: {exc}"
        return {**info, "status": "failed", "message": msg, "seconds": time.perf_counter() - t0}


# ---------------------------------------------------------------- manifest (client side)
def _versions() -> dict[str, str]:
    import importlib.metadata as md

    from .version import __version__

    out = {"lftomo": __version__, "python": platform.python_version()}
    for name in ("numpy", "scipy", "jax", "optimistix", "numba", "dask", "distributed"):
        with contextlib.suppress(md.PackageNotFoundError):
            out[name] = md.version(name)
    return out


class _Manifest:
    """``out/manifest.json``: the settings and one record per frame, rewritten atomically after each frame."""

    def __init__(self, out: Path, settings: dict, forward: dict) -> None:
        self.path = out / MANIFEST
        self.settings = json.loads(json.dumps(settings, sort_keys=True, default=str))
        self.forward = forward
        self.records: dict[int, dict] = {}
        self.runs: list[dict] = []
        if self.path.is_file():
            try:
                old = json.loads(self.path.read_text(encoding="utf-8"))
            except (ValueError, OSError) as exc:
                raise LftomoError(f"series manifest {str(self.path)!r} cannot be read ({exc}); remove it or choose "
                                  "another output folder") from None
            if old.get("settings") != self.settings or old.get("forward_model", {}).get("sha256") != forward["sha256"]:
                keys = sorted(k for k in set(self.settings) | set(old.get("settings", {}))
                              if self.settings.get(k) != old.get("settings", {}).get(k))
                if old.get("forward_model", {}).get("sha256") != forward["sha256"]:
                    keys.append("forward model")
                raise LftomoError(f"output folder {str(out)!r} holds a series made with other settings (differing: "
                                  f"{', '.join(keys)}); choose another output folder or remove {MANIFEST} there")
            self.records = {int(r["index"]): r for r in old.get("frames", [])}
            self.runs = list(old.get("runs", []))

    def is_done(self, index: int, key: str) -> bool:
        """Frame ``index`` is complete: recorded done for the same frame, its file present with its checksum."""
        r = self.records.get(index)
        if not r or r.get("status") != "done" or r.get("key") != key:
            return False
        p = self.path.parent / r["file"]
        return p.is_file() and _file_sha256(p) == r.get("sha256")

    def record(self, rec: dict) -> None:
        self.records[int(rec["index"])] = rec
        self.write()

    def write(self) -> None:
        from .io import atomic_write_text

        doc = {"format": FORMAT, "versions": _versions(), "settings": self.settings, "forward_model": self.forward,
               "runs": self.runs, "frames": [self.records[k] for k in sorted(self.records)],
               "updated": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        atomic_write_text(self.path, json.dumps(doc, indent=1, default=float))


def _write_frame(out: Path, res: dict) -> tuple[str, str]:
    """Write a done frame's fields to ``out/frame_XXXX.npz`` atomically; returns (name, sha256)."""
    from .io import atomic_path

    name = f"frame_{res['index']:04d}.npz"
    meta = {"index": res["index"], "grid": res["grid"], "summary": res["summary"], "metrics": res["metrics"]}
    arrays = {"T": res["T"]} if res["sigma_a"] is None else {"T": res["T"], "sigma_a": res["sigma_a"]}
    with atomic_path(out / name) as tmp:
        np.savez(tmp, meta=np.array(json.dumps(meta, default=float)), **arrays)
    return name, _file_sha256(out / name)


# ---------------------------------------------------------------- the cluster
def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: Most local-cluster workers per usable core: each is a process with its own interpreter, JAX and numba.
MAX_WORKERS_PER_CORE = 4


def check_workers(workers: Any, name: str = "workers") -> int:
    """A local cluster's process count: an integer from 1 to :data:`MAX_WORKERS_PER_CORE` × the usable cores."""
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise LftomoError(f"{name} must be an integer >= 1, got {workers!r}")
    top = MAX_WORKERS_PER_CORE * _usable_cores()
    if workers > top:
        raise LftomoError(f"{name}={int(workers)} is more than {MAX_WORKERS_PER_CORE} processes per usable core "
                          f"({_usable_cores()} cores: at most {top}); each worker is a process with its own memory, "
                          "and one per core is the fastest")
    return int(workers)


def local_cluster(workers: int):
    """A ``distributed.LocalCluster`` of ``workers`` single-threaded processes, set up for lftomo.

    Each worker runs with :data:`WORKER_ENV` (one numba, OpenMP and BLAS thread)
    and :data:`WORKER_DASK_CONFIG` (glibc's malloc not tuned by Dask), the
    scheduler with :data:`SCHEDULER_DASK_CONFIG` (each worker keeps its copy of
    the forward model); the dashboard takes a free port.  The caller closes it.

    Dask's nannies also write their variables into this process's
    ``os.environ``, where every later worker would inherit them: a
    ``MALLOC_TRIM_THRESHOLD_`` equal to Dask's own default is taken to be
    such a leftover and removed from it.
    """
    import logging

    import dask
    from distributed import LocalCluster

    key = "MALLOC_TRIM_THRESHOLD_"
    if os.environ.get(key) == str(dask.config.get("distributed.nanny.pre-spawn-environ", {}).get(key)):
        del os.environ[key]  # a nanny's leftover (an earlier default LocalCluster), not the user's setting
    # read by the nannies when they start, and by the scheduler (in this process)
    with dask.config.set({**WORKER_DASK_CONFIG, **SCHEDULER_DASK_CONFIG}):
        return LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True, env=dict(WORKER_ENV),
                            dashboard_address=":0", silence_logs=logging.ERROR)


@contextlib.contextmanager
def client_for(client: Any = None, scheduler: Any = None, workers: Any = None):
    """Yield ``(client, description)``: the given client, one connected to ``scheduler``, or a new
    LocalCluster of ``workers`` single-threaded processes (closed on exit, also on Ctrl-C)."""
    from distributed import Client

    if client is not None and (scheduler is not None or workers is not None):
        raise LftomoError("give either client or scheduler/workers, not both")
    if scheduler is not None and workers is not None:
        raise LftomoError(f"workers={workers!r} only applies to the local cluster; with scheduler={scheduler!r} "
                          "the cluster has its own workers")
    if client is not None:
        if not isinstance(client, Client):
            raise LftomoError(f"client must be a distributed.Client, got {type(client).__name__}")
        yield client, f"client {client.scheduler.address}"
        return
    if scheduler is not None:
        if not isinstance(scheduler, str) or "://" not in scheduler:
            raise LftomoError(f"scheduler must be an address such as 'tcp://host:8786', got {scheduler!r}")
        c = Client(scheduler)
        try:
            yield c, f"scheduler {scheduler}"
        finally:
            c.close()
        return
    n = _usable_cores() if workers is None else check_workers(workers)
    cluster = local_cluster(int(n))
    c = Client(cluster)
    try:
        yield c, f"LocalCluster {int(n)} workers x 1 thread"
    finally:
        c.close()
        cluster.close()


# Tasks resubmitted after a shared input was lost, per task: a worker that dies
# may hold the only copy (Dask's active memory manager drops broadcast replicas
# that no waiting task needs), and the scheduler cannot recompute scattered data.
LOST_INPUT_RETRIES = 3


class _SharedInputs:
    """Objects scattered once to every worker, scattered again when the cluster loses them."""

    def __init__(self, client: Any, objects: Sequence[Any]) -> None:
        self.client, self.objects = client, list(objects)
        self.futures = self._scatter()

    def _scatter(self) -> list:
        return [self.client.scatter(x, broadcast=True) for x in self.objects]

    def lost(self) -> bool:
        return any(f.status != "finished" for f in self.futures)

    def recover(self, exc: BaseException, tries: int) -> bool:
        """True when a task that failed with ``exc`` should be resubmitted (inputs scattered anew if lost)."""
        from concurrent.futures import CancelledError  # a dependency forgotten: Dask cancelled the task

        lost = self.lost()
        if tries >= LOST_INPUT_RETRIES or not (lost or isinstance(exc, CancelledError)):
            return False
        if lost:
            self.client.wait_for_workers(1, timeout=120)  # the nannies restart killed workers
            self.futures = self._scatter()
        return True

    def release(self) -> None:
        with contextlib.suppress(Exception):
            self.client.cancel(self.futures)


def run_tasks(fn: Callable, keys: Sequence[tuple], *shared: Any, client: Any = None, scheduler: str | None = None,
              workers: int | None = None, serial: bool = False):
    """Yield ``(key, fn(*key, *shared))`` for every tuple ``key``: as Dask tasks, as they finish.

    The ``shared`` objects (light fields, weight matrices, ...) are sent to every
    worker once (``Client.scatter(..., broadcast=True)``), not with each task.
    The cluster is :func:`client_for`'s (``client``, ``scheduler`` or a
    LocalCluster of ``workers`` single-threaded processes, closed at the end).
    With ``serial=True`` the calls run here, in order, without Dask.  Ctrl-C
    (or the caller leaving the loop early) cancels the tasks not yet finished.
    The sweeps of ``studies/`` run their noise draws with it.

    Parameters
    ----------
    fn : callable
        Picklable (a module-level function); its result is sent back to the caller.
    keys : sequence of tuple
        The leading arguments of each call.
    *shared
        The trailing arguments, the same for every call.
    """
    keys = [tuple(k) for k in keys]
    if not keys:
        return
    if serial:
        for k in keys:
            yield k, fn(*k, *shared)
        return
    from distributed import as_completed

    with client_for(client, scheduler, workers) as (c, _):
        held = _SharedInputs(c, shared)
        futs = {c.submit(fn, *k, *held.futures, pure=False): k for k in keys}
        tries = dict.fromkeys(futs, 0)
        ac = as_completed(list(futs))
        try:
            for fut in ac:
                k, n = futs.pop(fut), tries.pop(fut)
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - resubmitted only when a shared input was lost
                    if not held.recover(exc, n):
                        raise
                    new = c.submit(fn, *k, *held.futures, pure=False)
                    futs[new], tries[new] = k, n + 1
                    ac.add(new)
                    continue
                yield k, result
        finally:  # Ctrl-C, an error, or the caller stopped early: the other tasks are not needed
            c.cancel([f for f in futs if not f.done()])
            held.release()


# ---------------------------------------------------------------- the series
def _load_frame(frame: Any, index: int, raw: dict | None = None) -> Any:
    """A path is read here (checked by :meth:`LightField.load`, or, with ``raw``, a raw image checked and
    calibrated by its :class:`~lftomo.rawdata.RawFrameConverter`); objects pass through."""
    from .lightfield import LightField
    from .rawio import RAW_SUFFIXES

    if _is_path(frame):
        if raw is not None and Path(frame).suffix.lower() in RAW_SUFFIXES:
            conv = raw["converter"]
            counts = conv.read(frame, what="raw frame")
            return conv.lightfield(counts, raw["forward"], min_etendue_fraction=raw["min_etendue_fraction"],
                                   metadata={"source": "raw frame", "raw": counts.source})
        return LightField.load(frame)
    return frame


def _raw_setup(calibration: Any, forward: Any, *, camera: Any, dark: Any, dark_frames: int,
               camera_description: Any, min_etendue_fraction: float | None, noise: Any) -> tuple[dict, dict]:
    """Check the raw-frame inputs once (before any work): ``(raw, manifest settings)``.

    ``calibration`` is a :class:`~lftomo.rawdata.RawFrameConverter` or the path of a calibration file
    (then ``camera`` is the model camera); the converter's camera and wavelength must be the forward model's.
    """
    from .forward.camera import Camera
    from .forward.weights import WeightMatrix
    from .rawdata import RawFrameConverter

    if not isinstance(forward, WeightMatrix):
        raise LftomoError(f"raw frames (calibration=...) need forward to be an lftomo.WeightMatrix (its Monte Carlo "
                          f"error joins the noise model), got {type(forward).__name__}")
    if noise is not None:
        raise LftomoError(f"noise={noise!r} adds synthetic noise; raw frames are already noisy (their noise model "
                          "comes from the frame, the dark and the calibration): leave noise out")
    if isinstance(calibration, RawFrameConverter):
        if dark is not None or camera_description is not None or camera is not None:
            raise LftomoError("with calibration given as a RawFrameConverter, leave out camera, dark and "
                              "camera_description (the converter holds them)")
        conv = calibration
    else:
        if not isinstance(camera, Camera):
            raise LftomoError(f"calibration={str(calibration)!r} needs camera=<the lftomo.Camera the forward model "
                              f"was built for>, got {type(camera).__name__}")
        conv = RawFrameConverter.load(calibration, camera, dark=dark, dark_frames=dark_frames,
                                      camera_description=camera_description)
    have = json.loads(json.dumps(conv.camera.to_dict()))
    if forward.metadata.get("camera") != have:
        raise LftomoError("the calibration's camera is not the camera the forward model was built for "
                          "(forward.metadata['camera'] differs)")
    wl = forward.metadata.get("wavelength")
    if wl is None or abs(float(wl) - conv.wavelength) > 0.5e-9:
        raise LftomoError(f"the calibration is radiometric at {conv.wavelength * 1e9:.1f} nm but the forward model "
                          f"was built for {'gray' if wl is None else f'{float(wl) * 1e9:.1f} nm'}")
    if min_etendue_fraction is None:
        from .demo import MIN_ETENDUE_FRACTION

        min_etendue_fraction = MIN_ETENDUE_FRACTION
    min_etendue_fraction = require_in_range("min_etendue_fraction", min_etendue_fraction, 0.0, 1.0, high_open=True)
    desc = conv.describe()
    files = {"calibration_sha256": _file_sha256(Path(conv.calibration))}
    if conv.dark is not None and Path(conv.dark.source).is_file():
        files["dark_sha256"] = _file_sha256(Path(conv.dark.source))
    settings = {**desc, **files, "min_etendue_fraction": float(min_etendue_fraction)}
    return {"converter": conv, "forward": forward, "min_etendue_fraction": float(min_etendue_fraction)}, settings


def _check_forward(forward: Any) -> dict:
    """Type check of the forward model and its manifest entry (kind, shape, seed, rays, fingerprint)."""
    from .forward.weights import RaySegments, RefocusWeights, WeightMatrix

    if not isinstance(forward, (WeightMatrix, RaySegments, RefocusWeights)):
        raise LftomoError(f"forward must be an lftomo.WeightMatrix, RaySegments or RefocusWeights, got "
                          f"{type(forward).__name__}")
    meta = getattr(forward, "metadata", {}) or {}
    return {"kind": type(forward).__name__, "shape": list(getattr(forward, "shape", ()) or ()),
            "seed": meta.get("seed"), "rays_per_pixel": meta.get("rays_per_pixel"),
            "wavelength": meta.get("wavelength"), "grid": meta.get("grid"), "sha256": _model_fingerprint(forward)}


def _model_fingerprint(forward: Any) -> str:
    """:func:`fingerprint` of the forward model without the build's timings (``build_seconds``,
    ``estimate``), so that the same model built again (same rays and seed) matches."""
    fields = {f.name: getattr(forward, f.name) for f in dataclasses.fields(forward)}
    if isinstance(fields.get("metadata"), dict):
        fields["metadata"] = {k: v for k, v in fields["metadata"].items() if k not in ("build_seconds", "estimate")}
    return fingerprint(fields)


def _check_option_names(options: dict) -> None:
    """Refuse a keyword that :func:`lftomo.reconstruct` does not take before any cluster starts (each frame
    would otherwise fail on it, and the manifest record it)."""
    import inspect

    from .inverse.fitoptions import check_option_names
    from .inverse.reconstruct import reconstruct

    own = [k for k, p in inspect.signature(reconstruct).parameters.items()
           if p.kind is p.KEYWORD_ONLY and k != "progress"]
    check_option_names(options, own)


def reconstruct_series(
    frames: Sequence[Any],
    forward: Any,
    *,
    out: str | os.PathLike,
    client: Any = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = False,
    noise: float | None = None,
    seed: int = 0,
    data: str = "subaperture",
    depths: Sequence[float] | None = None,
    channel: int = 0,
    on_frame: Callable[[FrameResult], None] | None = None,
    calibration: Any = None,
    camera: Any = None,
    dark: Any = None,
    dark_frames: int = 1,
    camera_description: Any = None,
    min_etendue_fraction: float | None = None,
    **reconstruct_options: Any,
) -> SeriesResult:
    """Reconstruct every frame of a sequence, one Dask task per frame, with resume.

    Parameters
    ----------
    frames : sequence
        Each a noisy :class:`~lftomo.LightField`, a noise-free one (with
        ``noise``), a :class:`~lftomo.Measurement`, or the path of a light-field
        ``.npz`` (:meth:`LightField.save`, ``lftomo render``; read and checked
        on the client just before its task is submitted).  With
        ``calibration``, a frame may also be a raw image file (``.tif``,
        ``.tiff``, ``.png``, ``.npy`` counts of ``camera``): read, checked
        (bit depth, sensor shape) and calibrated on the client as by
        ``lftomo reconstruct --raw`` (:class:`~lftomo.rawdata.RawFrameConverter`;
        saturated and uncalibrated pixels left out and counted in the frame's
        metrics), a bad frame recorded as failed.
    forward : WeightMatrix, RaySegments or RefocusWeights
        The forward model of every frame (as ``weights`` of :func:`lftomo.reconstruct`);
        sent once to each worker.
    out : path
        Output folder: ``frame_XXXX.npz`` (``T``, ``sigma_a`` for joint fits,
        JSON ``meta``) per done frame and ``manifest.json``.
    client : distributed.Client, optional
        An existing client (not closed here).
    scheduler : str, optional
        Address of a running scheduler (``"tcp://host:8786"``), e.g. of a
        dask-jobqueue cluster.
    workers : int, optional
        Processes of the default LocalCluster (one thread each; default the usable cores).
    progress : bool
        A bar over frames on stderr.
    noise : float, optional
        Relative std of Gaussian noise added to noise-free light-field frames,
        drawn with seed ``seed + index`` (:func:`lftomo.add_noise`).
    seed : int
    data, depths, channel
        As :meth:`Measurement.from_lightfield` for light-field frames.
    on_frame : callable, optional
        Called on the client with each new :class:`FrameResult` as it completes.
    calibration : path or RawFrameConverter, optional
        For raw frames: a calibration of ``lftomo calibrate`` with radiometry
        (then ``camera`` is needed), or a converter made by
        :meth:`RawFrameConverter.load`.  Checked once, before any work: the
        radiometry, the sensor settings, the dark frame, the microlens grid
        against the camera, the camera and wavelength against ``forward``
        (a :class:`~lftomo.WeightMatrix`, whose Monte Carlo error joins the noise).
    camera : Camera, optional
        The model camera of the raw frames (that of ``forward``).
    dark : path, optional
        Dark frame of the raw frames (the mean of ``dark_frames`` exposures).
    dark_frames : int
    camera_description : CameraDescription, optional
        Gain, read noise, bit depth if the calibration did not record them.
    min_etendue_fraction : float, optional
        Raw frames: view pixels below this fraction of the peak étendue are left
        out (default :data:`lftomo.demo.MIN_ETENDUE_FRACTION`, as ``lftomo reconstruct``).
    **reconstruct_options
        Passed to :func:`lftomo.reconstruct` (``prior``, ``rule``, ``solver``,
        ``symmetry``, …: values or lftomo's option objects, recorded in the
        manifest by their repr, which a resumed series must match).

    Returns
    -------
    SeriesResult

    Raises
    ------
    LftomoError
        Bad arguments, or an output folder holding a series made with other settings.
    KeyboardInterrupt
        Ctrl-C: the running tasks are cancelled and the default cluster closed;
        every frame written so far is complete and recorded.
    """
    from .io import check_output_dir
    from .progress import progress_bar

    if _is_path(frames) or not isinstance(frames, Sequence):
        raise LftomoError(f"frames must be a sequence (list or tuple) of frames, got {type(frames).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise LftomoError(f"seed must be an integer >= 0, got {seed!r}")
    if noise is not None and not (isinstance(noise, (int, float)) and np.isfinite(noise) and noise > 0):
        raise LftomoError(f"noise must be a relative std > 0 or None, got {noise!r}")
    _check_option_names(reconstruct_options)
    out = check_output_dir(out, what="out", command="series")  # not another command's folder
    fwd = _check_forward(forward)
    raw, raw_settings = None, None
    if calibration is not None:
        raw, raw_settings = _raw_setup(calibration, forward, camera=camera, dark=dark, dark_frames=dark_frames,
                                       camera_description=camera_description,
                                       min_etendue_fraction=min_etendue_fraction, noise=noise)
    elif any(v is not None for v in (camera, dark, camera_description, min_etendue_fraction)):
        raise LftomoError("camera, dark, camera_description and min_etendue_fraction apply to raw frames: give "
                          "calibration=")
    settings = {"noise": noise, "seed": int(seed), "data": data, "depths": None if depths is None else list(depths),
                "channel": int(channel), "reconstruct": dict(reconstruct_options)}
    if raw_settings is not None:
        settings["raw"] = raw_settings
    manifest = _Manifest(out, settings, fwd)
    keys = [_frame_key(f) for f in frames]
    todo = deque(i for i, (_, k) in enumerate(keys) if not manifest.is_done(i, k))
    run = {"run": len(manifest.runs) + 1, "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "cluster": None,
           "frames_to_do": len(todo)}
    manifest.runs.append(run)
    if not todo:  # every frame is complete: no cluster to start
        manifest.write()
        return _result(out, manifest, len(frames))
    with client_for(client, scheduler, workers) as (c, where):
        run["cluster"] = where
        manifest.write()
        _run(c, frames, keys, todo, forward, settings, manifest, out,
             progress_bar(len(todo), progress, "series", unit="frame"), on_frame, raw)
    return _result(out, manifest, len(frames))


def _run(c, frames, keys, todo, forward, settings, manifest, out, bar, on_frame, raw=None) -> None:
    """Submit the frames of ``todo`` (a window of 2 per worker thread in flight), collect and record them."""
    from distributed import as_completed

    run = manifest.runs[-1]["run"]
    held = _SharedInputs(c, [forward])  # once per worker; tasks get the worker's copy
    window = max(2, 2 * sum(c.nthreads().values()))
    in_flight: dict[Any, int] = {}
    tries: dict[int, int] = {}
    ac = as_completed()

    def record(res: dict) -> None:
        i = res["index"]
        rec = {"index": i, "source": keys[i][0], "key": keys[i][1], "status": res["status"],
               "message": res.get("message", ""), "worker": res.get("worker"), "seconds": res.get("seconds"),
               "forward_copy": res.get("forward_copy"), "run": run,
               "completed": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "metrics": res.get("metrics", {})}
        if res["status"] == "done":
            rec["file"], rec["sha256"] = _write_frame(out, res)
        manifest.record(rec)
        bar.update(1)
        if on_frame is not None:
            on_frame(_frame_result(out, rec))

    def submit() -> None:
        while todo and len(in_flight) < window:
            i = todo.popleft()
            try:
                frame = _load_frame(frames[i], i, raw)
            except (ValueError, OSError) as exc:  # LftomoError is a ValueError
                record({"index": i, "status": "failed", "message": f"frame {i}: {exc}"})
                continue
            with warnings.catch_warnings():  # a frame is megabytes and is sent once: Dask's advice does not apply
                warnings.filterwarnings("ignore", message="Sending large graph", category=UserWarning)
                fut = c.submit(solve_frame, i, frame, *held.futures, settings, pure=False,
                               key=f"lftomo-frame-{i}-{os.urandom(4).hex()}")
            in_flight[fut] = i
            ac.add(fut)

    try:
        submit()
        for fut in ac:
            i = in_flight.pop(fut)
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the frame's workers kept dying
                if held.recover(exc, tries.get(i, 0)):  # the forward model was lost with a worker
                    tries[i] = tries.get(i, 0) + 1
                    todo.appendleft(i)
                    submit()
                    continue
                res = {"index": i, "status": "failed", "message": f"frame {i}: the task failed "
                                                                 f"({type(exc).__name__}: {exc})"}
            record(res)
            submit()
    except BaseException:  # Ctrl-C or an error in on_frame: stop the remaining tasks
        c.cancel(list(in_flight))
        raise
    finally:
        bar.close()
        held.release()


def _frame_result(out: Path, rec: dict) -> FrameResult:
    return FrameResult(index=int(rec["index"]), source=rec["source"], status=rec["status"],
                       message=rec.get("message", ""), path=out / rec["file"] if rec.get("file") else None,
                       metrics=dict(rec.get("metrics", {})))


def _result(out: Path, manifest: _Manifest, n: int) -> SeriesResult:
    recs = [manifest.records[i] for i in range(n) if i in manifest.records]
    shape = manifest.forward.get("grid", {}) or {}
    grid_shape = tuple(shape.get("shape", ()))
    for r in recs:  # the reconstruction grid (may be coarser than the forward model's)
        if r["status"] == "done":
            with np.load(out / r["file"], allow_pickle=False) as z:
                grid_shape = tuple(z["T"].shape)
            break
    return SeriesResult(out=out, frames=tuple(_frame_result(out, r) for r in recs), grid_shape=grid_shape)


def series_figure(result: SeriesResult, path: str | os.PathLike, *, frame_rate: float | None = None) -> Path:
    """Summary figure of a series (PNG, written atomically): per frame the maximum
    temperature, the flame volume above :data:`FLAME_T` and ``T`` at the box centre.

    Parameters
    ----------
    result : SeriesResult
    path : path
        The PNG file.
    frame_rate : float, optional
        Frames per second: the abscissa in s instead of frame numbers.
    """
    from .io import atomic_path
    from .plot import pyplot

    plt = pyplot()
    done = [f for f in result.frames if f.status == "done"]
    t = np.array([f.index for f in done], dtype=float)
    xlabel = "frame"
    if frame_rate:
        t, xlabel = t / frame_rate, "time (s)"
    fig, axes = plt.subplots(3, 1, figsize=(6, 7), sharex=True)
    panels = (("T_max", 1.0, "max T (K)"), ("flame_volume_m3", 1e6, f"volume T > {FLAME_T:.0f} K (cm³)"),
              ("T_center", 1.0, "T at box centre (K)"))
    for ax, (key, scale, label) in zip(axes, panels):
        ax.plot(t, [f.metrics[key] * scale for f in done], "o-", ms=3)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for f in result.failed:
        for ax in axes:
            ax.axvline(f.index / frame_rate if frame_rate else f.index, color="r", alpha=0.3)
    axes[-1].set_xlabel(xlabel)
    axes[0].set_title(f"{result.n_done} of {len(result.frames)} frames reconstructed"
                      + (f" ({len(result.failed)} failed: red)" if result.failed else ""))
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return Path(path)


def series_strip(result: SeriesResult, path: str | os.PathLike, *, height: float = 0.3, max_frames: int = 12) -> Path:
    """Frame strip (PNG, written atomically): the temperature of up to ``max_frames`` done frames
    (evenly spaced) in the horizontal plane at ``height`` × the box height (y index
    ``round(height (ny − 1))``), as the camera's top view: x to the right, z (depth) upwards.

    Parameters
    ----------
    result : SeriesResult
    path : path
        The PNG file.
    height : float
        Fraction of the box height, in [0, 1].
    max_frames : int
    """
    from .io import atomic_path
    from .plot import pyplot

    if not 0.0 <= height <= 1.0:
        raise LftomoError(f"height must be a fraction of the box height in [0, 1], got {height!r}")
    done = [f for f in result.frames if f.status == "done"]
    if not done:
        raise LftomoError("series_strip: no frame of the series was reconstructed")
    pick = [done[int(k)] for k in np.unique(np.linspace(0, len(done) - 1, min(max_frames, len(done))).round())]
    stack = result.stack()
    j = int(round(height * (result.grid_shape[1] - 1)))
    slices = [stack[f.index][:, j, :].T for f in pick]  # (nz, nx)
    lo, hi = min(float(s.min()) for s in slices), max(float(s.max()) for s in slices)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(pick), figsize=(1.6 * len(pick) + 1.0, 2.2), squeeze=False)
    for ax, f, sl in zip(axes[0], pick, slices):
        im = ax.imshow(sl, origin="lower", vmin=lo, vmax=hi, cmap="inferno")
        ax.set_title(f"frame {f.index}", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=list(axes[0]), label="T (K)", shrink=0.8)
    fig.suptitle(f"T in the plane y index {j} (x right, z up)", fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return Path(path)
