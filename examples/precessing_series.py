"""A time-resolved sequence of the precessing flame: render it, and (``--reconstruct``) reconstruct it.

Truth: :func:`lftomo.phantoms.precessing_flame` (two lobes precessing about the box axis at 50 Hz,
absorption fixed in time) on a grid ``--refine`` times finer than the reconstruction grid (``--n``³)
in a box that the camera sees whole (:func:`flame_grid`),
at ``t = k / frame_rate``, rendered at 650 nm by the seed camera with ``--mla`` lenslets per side
(``--rays`` rays/pixel, seed 1).  Writes ``OUT/lf_XXXX.npz`` (noisy light fields: ``--noise``
relative Gaussian noise with seed 100 + frame index, and in their ``noise_std`` also the Monte
Carlo error of the frame and of the weights, :func:`lftomo.inverse.compare.with_monte_carlo_noise`
— at tens of rays per pixel it is far above 1 %; pixels below 0.2 of the peak étendue left out),
``OUT/W.npz`` (the weight matrix on the reconstruction grid for the block-mean absorption,
:func:`lftomo.effective_truth`; seed 2, other rays than the frames) and ``OUT/truth.npz``
(``T``: the effective true temperature of every frame on the reconstruction grid, K,
shape (frames, n, n, n)).  Then::

    lftomo series OUT/lf_*.npz --weights OUT/W.npz -o OUT/series --bounds 300,2500 --frame-rate 1000

or ``--reconstruct``, which runs the same series here (:func:`lftomo.reconstruct_series`, λ by
the discrepancy rule, ``--workers`` processes) and prints per
frame the mean and maximum of |ΔT|/T where the true T > 800 K and > 1400 K, writing
``OUT/series/series_strip.png`` (frame strip), ``OUT/series/truth_strip.png`` (truth above
reconstruction, frame by frame), ``OUT/series/series.png`` and ``OUT/series/errors.json``.

Usage::

    python examples/precessing_series.py [-o precessing] [--frames 8] [--n 16] [--refine 2] [--mla 60]
        [--rays 64] [--noise 0.01] [--reconstruct [--workers 2] [--max-steps 30]]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

import lftomo as lt
from lftomo.inverse.compare import with_monte_carlo_noise
from lftomo.inverse.result import temperature_errors
from lftomo.io import atomic_write_text, check_output_dir
from lftomo.series import series_figure, series_strip

WL = 650e-9


def flame_grid(cam, n):
    """``n``³ voxels in a box of 0.8 × the camera's field of view per side (x, z; y 1.2 × that), at 1 m:
    :func:`lftomo.phantoms.default_flame_grid`'s shape, scaled so that the camera sees all of it (the
    default 50 mm box needs the seed camera's 60 lenslets; 16 lenslets see the central 20 mm)."""
    w = 0.8 * cam.describe(warn=False)["field_of_view"][0]
    return lt.Grid((n, n, n), (-w / 2, -0.6 * w, 1.0 - w / 2), (w / 2, 0.6 * w, 1.0 + w / 2))


def render(a, out):
    """Frames, weight matrix and effective truths; returns (light-field paths, W, T_true (frames, n, n, n))."""
    cam = lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    fine, grid = flame_grid(cam, a.n * a.refine), flame_grid(cam, a.n)
    media = lt.phantoms.precessing_flame_sequence(fine, a.frames, frame_rate=a.frame_rate, width_scale=3.0)
    paths, truths = [], []
    for k, m in enumerate(media):
        lf = lt.render(lt.Scene(medium=m), cam, rays_per_pixel=a.rays, seed=1, wavelengths=(WL,), progress=False)
        noisy = with_monte_carlo_noise(lt.add_noise(lf, relative_std=a.noise, seed=100 + k), lf,
                                       rays_per_pixel=a.rays, weights_rays_per_pixel=a.rays, min_etendue_fraction=0.2)
        paths.append(noisy.save(out / f"lf_{k:04d}.npz"))
        sa, T = lt.effective_truth(m, grid, WL)
        truths.append(T)
        print(paths[-1])
    W = lt.weights(cam, grid, sigma_a=sa, wavelength=WL, rays_per_pixel=a.rays, seed=2, progress=False)
    print(W.save(out / "W.npz"))
    T_true = np.stack(truths)
    np.savez_compressed(out / "truth.npz", T=T_true)
    return paths, W, T_true


def truth_strip(T_true, T, path, height=0.3):
    """PNG: the effective truth (top row) and the reconstruction (bottom row) of every frame in the
    horizontal plane at ``height`` × the box height (x right, z up), one colour scale."""
    from lftomo.io import atomic_path
    from lftomo.plot import pyplot

    plt = pyplot()
    j = int(round(height * (T.shape[2] - 1)))
    n = T.shape[0]
    lo, hi = float(min(T_true.min(), np.nanmin(T))), float(max(T_true.max(), np.nanmax(T)))
    fig, axes = plt.subplots(2, n, figsize=(1.5 * n + 1.0, 3.4), squeeze=False)
    for k in range(n):
        for r, (F, name) in enumerate(((T_true, "truth"), (T, "series"))):
            im = axes[r, k].imshow(F[k][:, j, :].T, origin="lower", vmin=lo, vmax=hi, cmap="inferno")
            axes[r, k].set_xticks([])
            axes[r, k].set_yticks([])
            axes[r, 0].set_ylabel(name, fontsize=8)
        axes[0, k].set_title(f"frame {k}", fontsize=8)
    fig.colorbar(im, ax=list(axes.ravel()), label="T (K)", shrink=0.8)
    fig.suptitle(f"effective true and reconstructed T in the plane y index {j} (x right, z up)", fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", default="precessing")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--n", type=int, default=16, help="reconstruction voxels per side")
    ap.add_argument("--refine", type=int, default=2, help="truth grid: this many times finer")
    ap.add_argument("--mla", type=int, default=60, help="lenslets per side of the seed camera (its own 60)")
    ap.add_argument("--rays", type=int, default=64, help="rays per pixel of the frames and of the weights")
    ap.add_argument("--noise", type=float, default=0.01, help="relative sensor noise of the frames")
    ap.add_argument("--frame-rate", type=float, default=1000.0, help="frames per second (50 Hz precession)")
    ap.add_argument("--reconstruct", action="store_true", help="reconstruct the series here, report the errors")
    ap.add_argument("--workers", type=int, default=2, help="--reconstruct: local Dask worker processes")
    ap.add_argument("--max-steps", type=int, default=30, help="--reconstruct: solver steps per λ")
    a = ap.parse_args()
    out = check_output_dir(a.output, what="-o/--output")
    paths, W, T_true = render(a, out)
    if not a.reconstruct:
        return
    res = lt.reconstruct_series([str(p) for p in paths], W, out=out / "series", workers=a.workers,
                                regularization="auto", bounds=(300.0, 2500.0), max_steps=a.max_steps)
    series_figure(res, out / "series" / "series.png", frame_rate=a.frame_rate)
    series_strip(res, out / "series" / "series_strip.png")
    T = res.stack()
    seconds = {f["index"]: f["seconds"] for f in json.loads(res.manifest.read_text())["frames"]}
    rows = []
    for k in range(a.frames):
        row = {"frame": k, "seconds": seconds.get(k)}
        for lo in (800.0, 1400.0):
            row[f"T_gt_{lo:.0f}K"] = temperature_errors(T[k], T_true[k], hot=lo)
        rows.append(row)
        e8, e14 = row["T_gt_800K"], row["T_gt_1400K"]
        print(f"frame {k} ({row['seconds']:.1f} s): |dT|/T mean {100 * e8['mean_rel']:.1f} % (max {100 * e8['max_rel']:.0f} %) where T > 800 K, "
              f"{100 * e14['mean_rel']:.1f} % (max {100 * e14['max_rel']:.0f} %) where T > 1400 K")
    atomic_write_text(out / "series" / "errors.json", json.dumps(rows, indent=1))
    truth_strip(T_true, T, out / "series" / "truth_strip.png")
    print(f"wrote {out / 'series'}/ (series_strip.png, truth_strip.png, series.png, errors.json)")


if __name__ == "__main__":
    main()
