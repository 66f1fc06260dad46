"""The ``lftomo`` command: a thin layer over the public API."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _load(scene_path):
    from .config import load_scene_file

    return load_scene_file(scene_path)


def cmd_camera(args) -> int:
    cfg = _load(args.scene)
    d = cfg.camera.describe(warn=False)  # the report prints its warnings itself
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    print(f"camera of {cfg.source}")
    units = {
        "f_number": "", "px": "px", "views": "", "magnification": "", "per_metre": "px/m",
    }
    for k, v in d.items():
        if k == "warnings":
            continue
        unit = next((u for key, u in units.items() if key in k), "m")
        if isinstance(v, float):
            print(f"  {k:40s} {v:.6g} {unit}")
        else:
            print(f"  {k:40s} {v}")
    for w in d["warnings"]:
        print(f"WARNING: {w}")
    return 0


def cmd_render(args) -> int:
    from . import plot
    from .forward.render import render

    cfg = _load(args.scene)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    rpp = args.rays_per_pixel or cfg.rays_per_pixel
    seed = cfg.seed if args.seed is None else args.seed
    t0 = time.perf_counter()
    print(f"lftomo render: {cfg.source} -> {out}/ ({rpp} rays/pixel, seed {seed})", file=sys.stderr)
    lf = render(cfg.scene, cfg.camera, rays_per_pixel=rpp, seed=seed, wavelengths=cfg.wavelengths or "gray",
                progress=not args.quiet)
    t_render = time.perf_counter() - t0
    lf.save(out / "lightfield.npz")
    files = [out / "lightfield.npz"]
    files += lf.export_images(out, fmt="png")
    files.append(plot.lightfield_overview(lf, out / "overview.png"))
    depths = cfg.focal_stack_depths or (cfg.camera.focus_distance,)
    files.append(plot.focal_stack_figure(lf, depths, out / "focal_stack.png"))
    from .io_images import write_image16

    stack = lf.focal_stack(depths)
    for d, img in zip(depths, stack):
        img0 = img if lf.n_channels == 1 else img[0]
        files.append(write_image16(out / f"refocus_{d * 1000:.0f}mm.png", img0))
    summary = {
        "scene": cfg.source,
        "rays_per_pixel": rpp,
        "seed": seed,
        "render_seconds": t_render,
        "total_signal": float(np.sum(lf.raw)),
        "files": [str(f) for f in files],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"rendered {lf.camera.sensor_shape[0]}x{lf.camera.sensor_shape[1]} px in {t_render:.1f} s; wrote:")
    for f in files + [out / "summary.json"]:
        print(f"  {f}")
    return 0


def cmd_weights(args) -> int:
    from .forward.weights import weights

    cfg = _load(args.scene)
    medium = cfg.scene.medium
    if medium is None:
        raise ValueError(f"scene file {cfg.source!r} has no [medium]: the weight matrix needs its grid and sigma_a")
    rpp = args.rays_per_pixel or cfg.rays_per_pixel
    seed = cfg.seed if args.seed is None else args.seed
    channels = [None] if cfg.wavelengths is None else list(cfg.wavelengths)
    out = Path(args.output)
    if out.suffix != ".npz":
        out = out.with_suffix(".npz")
    limit = None if args.memory_limit_gb is None else args.memory_limit_gb * 1e9
    for wl in channels:
        path = out if len(channels) == 1 else out.with_name(f"{out.stem}_{wl * 1e9:.0f}nm.npz")
        band = "gray" if wl is None else f"{wl * 1e9:.0f} nm"
        print(f"lftomo weights: {cfg.source} -> {path} ({rpp} rays/pixel, seed {seed}, {band})", file=sys.stderr)
        W = weights(cfg.camera, medium.grid, sigma_a=medium.sigma_a_at(wl), sigma_s=medium.sigma_s, g=medium.g,
                    wavelength="gray" if wl is None else wl, rays_per_pixel=rpp, seed=seed,
                    surfaces=cfg.scene.surfaces or None, memory_limit=limit, progress=not args.quiet)
        W.save(path)
        est = W.metadata["estimate"]
        print(f"{W.shape[0]} pixel rows x {W.shape[1]} voxels in {len(W.blocks)} views: nnz {W.nnz} "
              f"(estimated {est['nnz']}), {W.nbytes / 1e6:.1f} MB, {W.metadata['build_seconds']:.1f} s; wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lftomo", description="Plenoptic camera simulation and flame tomography.")
    sub = p.add_subparsers(dest="command", required=True)
    c = sub.add_parser("camera", help="print the camera design report of a scene file (default: built-in scene)")
    c.add_argument("scene", nargs="?", default=None, help="TOML scene file")
    c.add_argument("--json", action="store_true", help="print JSON")
    c.set_defaults(func=cmd_camera)
    r = sub.add_parser("render", help="render the raw light field, views and a focal stack")
    r.add_argument("scene", nargs="?", default=None, help="TOML scene file (default: built-in target scene)")
    r.add_argument("-o", "--output", default="lftomo-render", help="output directory")
    r.add_argument("--rays-per-pixel", type=int, default=None, help="override render.rays_per_pixel")
    r.add_argument("--seed", type=int, default=None, help="override render.seed")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_render)
    w = sub.add_parser("weights", help="build the ray-voxel weight matrix of the scene's medium grid (.npz)")
    w.add_argument("scene", help="TOML scene file with a [medium]")
    w.add_argument("-o", "--output", default="weights.npz", help="output .npz (several wavelengths: suffix _<nm>nm)")
    w.add_argument("--rays-per-pixel", type=int, default=None, help="override render.rays_per_pixel")
    w.add_argument("--seed", type=int, default=None, help="override render.seed")
    w.add_argument("--memory-limit-gb", type=float, default=None,
                   help="refuse a build estimated above this size (default: half the machine's memory)")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    w.set_defaults(func=cmd_weights)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ValueError as exc:
        print(f"lftomo: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
