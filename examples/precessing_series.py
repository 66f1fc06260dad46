"""Render a short time-resolved sequence of the precessing flame, ready for ``lftomo series``.

Writes ``OUT/lf_XXXX.npz`` (noise-free light fields of :func:`lftomo.phantoms.precessing_flame`
at ``t = k / frame_rate``, seed 1) and ``OUT/W.npz`` (the weight matrix on the same grid for the
phantom's absorption, which is fixed in time; seed 2, other rays than the frames).  Then::

    lftomo series OUT/lf_*.npz --weights OUT/W.npz -o OUT/series --noise 0.01 --frame-rate 1000

Usage::

    python examples/precessing_series.py [-o precessing] [--frames 8] [--n 12] [--mla 16] [--rays 4]
"""

from __future__ import annotations

import argparse

import lftomo as lt
from lftomo.io import check_output_dir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", default="precessing")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--n", type=int, default=12, help="voxels per side")
    ap.add_argument("--mla", type=int, default=16, help="lenslets per side of the seed camera")
    ap.add_argument("--rays", type=int, default=4, help="rays per pixel")
    ap.add_argument("--frame-rate", type=float, default=1000.0, help="frames per second (50 Hz precession)")
    a = ap.parse_args()
    out = check_output_dir(a.output, what="-o/--output")
    wl = 650e-9
    cam = lt.Camera.seed(1.0, mla={"count": (a.mla, a.mla)})
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    media = lt.phantoms.precessing_flame_sequence(grid, a.frames, frame_rate=a.frame_rate, width_scale=3.0)
    for k, m in enumerate(media):
        lf = lt.render(lt.Scene(medium=m), cam, rays_per_pixel=a.rays, seed=1, wavelengths=(wl,), progress=False)
        print(lf.save(out / f"lf_{k:04d}.npz"))
    W = lt.weights(cam, grid, sigma_a=media[0].sigma_a_at(wl), wavelength=wl, rays_per_pixel=a.rays, seed=2,
                   progress=False)
    print(W.save(out / "W.npz"))


if __name__ == "__main__":
    main()
