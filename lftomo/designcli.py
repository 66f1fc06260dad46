"""``lftomo design SCENE.toml``: what the scene's camera(s) will resolve in its flame, before anything is built.

The scene's ``[medium]`` is the expected flame; its box, at ``--n``³ voxels,
the reconstruction grid.  Writes ``design.json`` (the summary), one figure per
quantity, and with ``--compare`` ``comparison.md`` / ``comparison.json`` /
``comparison.png`` over :func:`lftomo.inverse.design.standard_configurations`.
"""

from __future__ import annotations

import json
from typing import Any

from .errors import LftomoError

__all__ = ["add_design_parser", "run_design"]


def add_design_parser(sub: Any, *, positive_int, nonneg_int, positive_float, output, add_allow_outside) -> None:
    """The ``design`` sub-command on an argparse sub-parser collection."""
    from .inverse.design import DESIGN_QUADRATURE

    d = sub.add_parser("design", help="experiment design: predicted posterior std, resolution and Cramér–Rao bound "
                                      "of the scene's camera(s) on its flame; --compare for a table of rigs")
    d.add_argument("scene", metavar="SCENE.toml", help="scene file with [camera] (or [[camera]] tables) and [medium]")
    d.add_argument("-o", "--output", type=output, default="lftomo-design", help="output directory (default lftomo-design)")
    d.add_argument("--n", type=positive_int, default=16, help="voxels per axis of the reconstruction grid (<= 16)")
    d.add_argument("--noise", type=positive_float, default=0.01, help="relative measurement noise, at most 10 "
                                                                      "(default 0.01)")
    d.add_argument("--rays", type=positive_int, default=64, help="rays per pixel of the weights (default 64)")
    d.add_argument("--wavelength", type=positive_float, default=None,
                   help="m, 1e-7 to 1e-4 (default: the scene's [render] wavelength, its first of several)")
    d.add_argument("--seed", type=nonneg_int, default=0, help="seed of the renders and noise (default 0)")
    d.add_argument("--compare", action="store_true",
                   help="also design the standard configurations (1, 2 at 90°, 3 at 60° cameras; stop; focus; "
                        "900 nm; pixels per microlens) around the first camera and write a comparison table")
    d.add_argument("--quadrature", type=positive_int, default=DESIGN_QUADRATURE,
                   help="sub-voxel emission: weights on the grid refined by this factor per axis "
                        f"(default {DESIGN_QUADRATURE}; 1: uniform emission per voxel)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    add_allow_outside(d)
    d.set_defaults(func=run_design)


def run_design(args: Any) -> int:
    """Run ``lftomo design``; returns the exit status."""
    from .config import load_scene_file
    from .forward.grid import Grid
    from .inverse.design import compare_designs, design, design_configurations, design_table, standard_configurations
    from .inverse.designplot import design_comparison_figure
    from .io import atomic_write_text, check_output_dir, staged_directory

    out = check_output_dir(args.output, what="-o/--output", command="design")  # before the work, not after it
    if args.noise > 10.0:
        raise LftomoError(f"--noise {args.noise!r}: the relative measurement noise must be at most 10")
    scene = load_scene_file(args.scene, allow_outside=bool(getattr(args, "allow_outside_paths", False)))
    flame = scene.scene.medium
    if flame is None:
        raise LftomoError(f"{args.scene} has no [medium]: the design needs the expected flame")
    cams = tuple(getattr(scene, "cameras", None) or (scene.camera,))
    box = flame.grid
    if any(k % args.n for k in box.shape):
        fits = [n for n in range(1, 17) if all(k % n == 0 for k in box.shape)]
        raise LftomoError(f"--n {args.n}: the reconstruction grid must divide the scene's medium grid "
                          f"{tuple(box.shape)} on every axis; allowed: {', '.join(map(str, fits))}")
    grid = Grid(shape=(args.n,) * 3, lower=tuple(box.lower), upper=tuple(box.upper))
    if args.wavelength is None:
        if scene.wavelengths is None:
            raise LftomoError(f"{args.scene} renders the gray band; the design needs one wavelength: give "
                              "--wavelength (m, e.g. 650e-9)")
        args.wavelength = float(scene.wavelengths[0])
    show = not args.quiet
    kw = dict(noise=args.noise, seed=args.seed, quadrature=args.quadrature)
    d = design(cams, grid, flame, wavelength=args.wavelength, rays_per_pixel=args.rays, progress=show, **kw)
    s = d.summary()
    print(f"{len(cams)} camera(s), {s['n_data']} data, lambda {s['regularization']:.3g}: predicted mean error "
          f"{100 * s['predicted_mean_rel']:.2f} % above {d.hot:.0f} K (posterior std {100 * s['posterior_std_mean_rel']:.2f} %, "
          f"Cramér–Rao median {100 * s['crb_median_rel']:.2f} %)")
    rows = None
    if args.compare:
        designs = design_configurations(standard_configurations(cams[0], grid, wavelength=args.wavelength), grid,
                                        flame, rays_per_pixel=args.rays, progress=show, **kw)
        rows = compare_designs(designs)
    with staged_directory(out, command="design") as stage:  # the files appear together, design.json last
        files = [p.name for p in d.figures(stage)]
        if rows is not None:
            table = design_table(rows)
            atomic_write_text(stage / "comparison.md", table)
            atomic_write_text(stage / "comparison.json", json.dumps(rows, indent=1))
            design_comparison_figure(rows, stage / "comparison.png")
            files += ["comparison.md", "comparison.json", "comparison.png"]
            print(table, end="")
        atomic_write_text(stage / "design.json", json.dumps({"scene": str(args.scene), "grid_shape": list(grid.shape),
                                                             "wavelength": args.wavelength, **kw, "summary": s,
                                                             "timing_s": d.timing}, indent=1))
    print(f"wrote {out}/: " + ", ".join(["design.json"] + files))
    return 0
