"""The ``lftomo`` command: a thin layer over the public API."""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import time
import warnings
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from .errors import LftomoError
from ._validate import require_regular_file


def _load(scene_path, args=None):
    from .config import load_scene_file

    return load_scene_file(scene_path, allow_outside=bool(getattr(args, "allow_outside_paths", False)))


def cmd_camera(args) -> int:
    cfg = _load(args.scene, args)
    names = list(cfg.camera_names) if cfg.is_rig else [None]
    cams = list(cfg.cameras) if cfg.is_rig else [cfg.camera]
    reports = [c.describe(warn=False) for c in cams]  # the report prints its warnings itself
    if args.json:
        out = reports[0] if not cfg.is_rig else {n: d for n, d in zip(names, reports)}
        print(json.dumps(out, indent=2))
        return 0
    units = {
        "f_number": "", "px": "px", "views": "", "magnification": "", "per_metre": "px/m", "_deg": "deg",
    }
    for name, d in zip(names, reports):
        print(f"camera of {cfg.source}" if name is None else f"camera {name!r} of {cfg.source}")
        for k, v in d.items():
            if k == "warnings":
                continue
            unit = next((u for key, u in units.items() if key in k), "m")
            if isinstance(v, float):
                print(f"  {k:40s} {v:.6g} {unit}")
            elif isinstance(v, list) and v and all(isinstance(a, float) for a in v):
                print(f"  {k:40s} " + ", ".join(f"{a:.6g}" for a in v) + f" {unit}")
            else:
                print(f"  {k:40s} {v}")
        for w in d["warnings"]:
            print(f"WARNING: {w}")
    return 0


def _suffixed(path: Path, name: str) -> Path:
    """``dir/stem.ext`` -> ``dir/stem_name.ext`` (the per-camera outputs of a rig)."""
    return path.with_name(f"{path.stem}_{name}{path.suffix}")


def cmd_render(args) -> int:
    """Render the scene file's camera, or every camera of a rig (outputs suffixed by camera name)."""
    import shutil

    from .forward.render import render
    from .io import check_output_dir, staged_directory

    cfg = _load(args.scene, args)
    out = check_output_dir(args.output, what="-o/--output", command="render")  # before the work, not after it
    rpp = cfg.rays_per_pixel if args.rays_per_pixel is None else args.rays_per_pixel
    seed = cfg.seed if args.seed is None else args.seed
    sampler = cfg.sampler if args.sampler is None else args.sampler
    allocation = cfg.allocation if args.allocation is None else args.allocation
    from .demo import save_lightfield_products
    from .lightfield import FarDepthWarning

    print(f"lftomo render: {cfg.source} -> {out}/ ({rpp} rays/pixel {allocation}, seed {seed}, {sampler} sampler"
          + (f", {len(cfg.cameras)} cameras: {', '.join(cfg.camera_names)})" if cfg.is_rig else ")"), file=sys.stderr)
    with staged_directory(out, command="render") as stage:  # all files appear together, summary.json last
        files: list[Path] = []
        per_camera = {}
        for cam, name in zip(cfg.cameras, cfg.camera_names):
            t0 = time.perf_counter()
            lf = render(cfg.scene, cam, rays_per_pixel=rpp, seed=seed, wavelengths=cfg.wavelengths or "gray",
                        progress=not args.quiet, sampler=sampler, allocation=allocation)
            t_render = time.perf_counter() - t0
            depths = cfg.focal_stack_depths or (cam.focus_distance,)
            with warnings.catch_warnings():  # the scene file's far depths were warned about as it was read
                warnings.simplefilter("ignore", FarDepthWarning)
                if not cfg.is_rig:
                    cam_files = [out / f.name for f in save_lightfield_products(lf, stage, depths)]
                else:
                    tmp = stage / f".camera-{name}"
                    cam_files = []
                    for f in save_lightfield_products(lf, tmp, depths):
                        f.rename(_suffixed(stage / f.name, name))
                        cam_files.append(_suffixed(out / f.name, name))
                    shutil.rmtree(tmp)
            files += cam_files
            per_camera[name] = {"render_seconds": t_render, "total_signal": float(np.sum(lf.raw)),
                                "pose": None if cam.pose is None else cam.pose.to_dict(),
                                "files": [str(f) for f in cam_files]}
            print(f"rendered {name}: {lf.camera.sensor_shape[0]}x{lf.camera.sensor_shape[1]} px in {t_render:.1f} s"
                  if cfg.is_rig else
                  f"rendered {lf.camera.sensor_shape[0]}x{lf.camera.sensor_shape[1]} px in {t_render:.1f} s; wrote:")
        summary = {
            "scene": cfg.source,
            "rays_per_pixel": rpp,
            "seed": seed,
            "sampler": sampler,
            "allocation": lf.metadata["allocation"],  # what was used: below 16 rays, uniform
        }
        if cfg.is_rig:
            summary["cameras"] = per_camera
        else:
            summary.update({k: per_camera["camera"][k] for k in ("render_seconds", "total_signal")})
        summary["files"] = [str(f) for f in files]
        (stage / "summary.json").write_text(json.dumps(summary, indent=2))
    if cfg.is_rig:
        print("wrote:")
    for f in files + [out / "summary.json"]:
        print(f"  {f}")
    return 0


def _npz_output(output: str) -> Path:
    """The .npz file ``-o`` names (another suffix replaced, said on stderr), checked before the work."""
    from .io import npz_output_path

    out = npz_output_path(output, what="-o/--output")
    if Path(output).suffix not in ("", ".npz"):
        print(f"lftomo: note: -o {output} is written as {out} (an .npz archive)", file=sys.stderr)
    return out


def cmd_weights(args) -> int:
    from .forward.weights import weights
    from .io import check_output_file

    cfg = _load(args.scene, args)
    medium = cfg.scene.medium
    if medium is None:
        raise LftomoError(f"scene file {cfg.source!r} has no [medium]: the weight matrix needs its grid and sigma_a")
    rpp = cfg.rays_per_pixel if args.rays_per_pixel is None else args.rays_per_pixel
    seed = cfg.seed if args.seed is None else args.seed
    sampler = cfg.sampler if args.sampler is None else args.sampler
    channels = [None] if cfg.wavelengths is None else list(cfg.wavelengths)
    out = _npz_output(args.output)
    # one file per camera of a rig (suffix: its name) and per wavelength (suffix: nm)
    jobs = []
    for cam, name in zip(cfg.cameras, cfg.camera_names):
        base = _suffixed(out, name) if cfg.is_rig else out
        for wl in channels:
            jobs.append((cam, wl, base if len(channels) == 1 else base.with_name(f"{base.stem}_{wl * 1e9:.0f}nm.npz")))
    for _, _, path in jobs:  # before the build, not after it
        check_output_file(path, what="-o/--output")
    limit = None if args.memory_limit_gb is None else args.memory_limit_gb * 1e9
    guide = _weights_guide(args.guide, cfg)
    rows = "uniform" if guide is None else "adaptive"
    for cam, wl, path in jobs:
        band = "gray" if wl is None else f"{wl * 1e9:.0f} nm"
        print(f"lftomo weights: {cfg.source} -> {path} ({rpp} rays/pixel {rows}, seed {seed}, {sampler} sampler, "
              f"{band})", file=sys.stderr)
        W = weights(cam, medium.grid, sigma_a=medium.sigma_a_at(wl), sigma_s=medium.sigma_s, g=medium.g,
                    wavelength="gray" if wl is None else wl, rays_per_pixel=rpp, seed=seed,
                    surfaces=cfg.scene.surfaces or None, memory_limit=limit, progress=not args.quiet,
                    sampler=sampler, allocation=rows, guide=guide)
        W.save(path)
        est = W.metadata["estimate"]
        print(f"{W.shape[0]} pixel rows x {W.shape[1]} voxels in {len(W.blocks)} views: nnz {W.nnz} "
              f"(estimated {est['nnz']}), {W.nbytes / 1e6:.1f} MB, {W.metadata['build_seconds']:.1f} s; wrote {path}")
    return 0


def _weights_guide(path, cfg):
    """The light field of ``--guide`` (None without it), read and checked before any build."""
    if path is None:
        return None
    from .lightfield import LightField

    if cfg.is_rig:
        raise LftomoError(f"--guide gives one camera's image, but scene file {cfg.source!r} has "
                          f"{len(cfg.cameras)} cameras; build each camera's matrix from a scene file of its own")
    from ._validate import json_differences

    guide = LightField.load(path)
    diffs = json_differences(cfg.cameras[0].to_dict(), guide.camera.to_dict())
    if diffs:
        raise LftomoError(f"--guide {str(path)!r} was taken with another camera than the scene's (scene vs guide): "
                          + "; ".join(diffs))
    return guide


def cmd_demo(args) -> int:
    from .demo import run_demo
    from .io import check_output_dir

    out = check_output_dir(args.output, what="-o/--output", command="demo")  # named as the user gave it
    print(f"lftomo demo: {'quick' if args.quick else 'default'} run, seed {args.seed} -> {out}/", file=sys.stderr)
    run_demo(out, quick=args.quick, seed=args.seed, progress=not args.quiet)
    if args.quiet:
        print(out / "index.html")
    return 0


def _fit_rule(args) -> Any:
    """The λ rule of ``--rule``, ``--regularization`` and ``--noise-scale``, checked before any work."""
    from .inverse.reconstruct import rule_from_names

    if args.rule is not None and args.regularization != "auto":
        raise LftomoError(f"--rule {args.rule} chooses lambda; --regularization {args.regularization:g} fixes it: "
                          "give one of them")
    try:
        return rule_from_names(args.rule or "discrepancy", args.regularization, args.noise_scale)
    except ValueError as exc:
        raise LftomoError(f"--rule/--regularization/--noise-scale: {exc}") from None


def _refuse_given(args, names: tuple[str, ...], where: str) -> None:
    """LftomoError if any option ``names`` (argparse dests) was given: it would be ignored here."""
    given = [f"--{k.replace('_', '-')}" for k in names if getattr(args, k) is not None]
    if given:
        raise LftomoError(f"{' and '.join(given)} only appl{'ies' if len(given) == 1 else 'y'} {where}")


def cmd_reconstruct(args) -> int:
    from .demo import run_reconstruct

    if not args.posterior:
        _refuse_given(args, ("posterior_steps", "posterior_basis"), "with --posterior")
    _fit_rule(args)  # refused before the render and the weights, not after them
    if args.dark is None:
        _refuse_given(args, ("dark_frames",), "with --dark")
    if args.scene is None and args.raw is None:  # (--raw without a scene file is refused by name below)
        _refuse_given(args, ("recon_shape", "rays_per_pixel", "sampler"), "to scene mode (a TOML scene file); with "
                      "--lightfield and --weights the grid and rays are those of the files")
    m = run_reconstruct(
        args.output, scene=args.scene, lightfield=args.lightfield, weights=args.weights, noise=args.noise,
        data=args.data, depths=args.depths, regularization=args.regularization, rule=args.rule or "discrepancy",
        noise_scale=args.noise_scale, prior=args.prior,
        bounds=args.bounds, posterior=args.posterior, posterior_basis=args.posterior_basis or "flame",
        posterior_steps=args.posterior_steps or 500, recon_shape=args.recon_shape,
        rays_per_pixel=args.rays_per_pixel, seed=args.seed, sampler=args.sampler, channel=args.channel,
        max_steps=args.max_steps,
        min_etendue_fraction=args.min_etendue_fraction, symmetry=args.symmetry, quadrature=args.quadrature,
        progress=not args.quiet, allow_outside=args.allow_outside_paths, raw=args.raw, calibration=args.calibration,
        dark=args.dark, dark_frames=args.dark_frames, camera=args.camera)
    r = m["reconstruction"]
    print(f"reconstructed {'x'.join(map(str, r['grid_shape']))} voxels from {m['measurement']['n_data']} "
          f"{r['data']} data: lambda {r['regularization']:.3g} ({r['lambda_rule']}), chi2/m {r['chi2_per_datum']:.3g}, "
          f"{m['timings_s']['total']:.1f} s")
    if r.get("lambda_note"):  # the rule's fallback (no λ attains the target, ...): say so, not only in the JSON
        print(f"  lambda rule: {r['lambda_note']}")
    for key in ("errors_T_gt_800K", "errors_T_gt_1400K"):
        e = r.get(key)
        if e:
            print(f"  {key}: mean {100 * e['mean_rel']:.1f} %, max {100 * e['max_rel']:.1f} %, rms {e['rms_K']:.0f} K")
    if r.get("scale_uncertainty"):
        s = r["scale_uncertainty"]
        print(f"  radiometric scale uncertainty {100 * s['rel_std']:.2f} % (blackbody temperature): "
              f"+-{s['T_std_K_at_max_T']:.1f} K at the hottest voxel, common to all voxels")
    if "posterior" in m:
        p = m["posterior"]
        if p["basis"] == "field":
            print(f"  posterior: full-grid Laplace ({p['method']}), lambda {p['regularization']:.3g} by evidence, "
                  f"median std {p['median_std_K']:.0f} K" + (f", 90 % coverage {p['coverage_90']:.2f}"
                                                              if "coverage_90" in p else ""))
        else:
            taus = [t for t in p["tau"] if t is not None]
            tau = f"tau max {max(taus):.1f}" if taus else "tau not estimated (chain too short)"
            print(f"  posterior: acceptance {p['acceptance_mean']:.2f}, {tau}, "
                  f"{'converged' if p['converged'] else 'NOT converged'}; {p.get('likelihood_note', '')}")
    print(f"wrote {Path(args.output)}/: " + ", ".join(m["files"]))
    return 0


def cmd_calibrate(args) -> int:
    """``lftomo calibrate``: microlens grid (and radiometric factors) of a real camera from raw frames."""
    from .calibration import calibrate_grid, calibration_figure, radiometric_calibration, save_calibration
    from .rawio import load_camera_description, read_raw

    if (args.blackbody is None) != (args.temperature is None):
        raise LftomoError("--blackbody and --temperature go together (the blackbody frame and its temperature in K)")
    if args.blackbody is None:
        _refuse_given(args, ("temperature_std",), "with --blackbody and --temperature")
    if args.dark is None:
        _refuse_given(args, ("dark_frames",), "with --dark")
    args.temperature_std = 0.0 if args.temperature_std is None else args.temperature_std
    args.dark_frames = 1 if args.dark_frames is None else args.dark_frames
    cam = load_camera_description(args.camera) if args.camera else None
    if args.blackbody is not None and cam is None:
        raise LftomoError("--blackbody needs --camera CAMERA.toml (wavelength, gain, f-number of the acquisition)")
    if args.blackbody is not None and cam.gain is None:
        raise LftomoError(f"--blackbody: camera file {cam.source!r} needs [sensor] gain_e_per_count for the noise "
                         "of the calibration factors")
    out = _npz_output(args.output)
    scene_camera = None
    if args.scene is not None:
        from .config import load_scene_file
        scene_camera = load_scene_file(args.scene).camera
    bits = cam.bit_depth if cam else None
    white = read_raw(args.white, bit_depth=bits, what="white frame")
    if cam is not None and cam.sensor_shape is not None and white.shape != cam.sensor_shape:
        raise LftomoError(f"white frame {white.source!r} has shape {white.shape}, but camera file {cam.source!r} "
                         f"says [sensor] shape = {list(cam.sensor_shape)}")
    frames = {}
    for key, path in (("dark", args.dark), ("blackbody", args.blackbody)):
        if path is not None:
            f = read_raw(path, bit_depth=white.bit_depth, allow_float=key == "dark", what=f"--{key} frame")
            if f.shape != white.shape:
                raise LftomoError(f"--{key} frame {f.source!r} has shape {f.shape}, but white frame "
                                 f"{white.source!r} has shape {white.shape}")
            frames[key] = f
    dark = frames.get("dark")
    n_sat = int(white.saturated.sum())
    grid = calibrate_grid(white.counts, dark=None if dark is None else dark.counts)
    radio = None
    if args.blackbody is not None:
        radio = radiometric_calibration(frames["blackbody"], temperature=args.temperature,
                                        temperature_std=args.temperature_std, wavelength=cam.wavelength,
                                        etendue=cam.paraxial_pixel_etendue, gain=cam.gain,
                                        read_noise=cam.read_noise or 0.0, dark=dark, dark_frames=args.dark_frames)
    d = grid.describe()
    meta = {"white": white.source, "dark": None if dark is None else dark.source, "blackbody": args.blackbody,
            "camera": None if cam is None else cam.to_dict(), "grid": d,
            "etendue": None if radio is None else {"kind": "paraxial", "value_m2sr": cam.paraxial_pixel_etendue}}
    save_calibration(out, grid, radiometric=radio, metadata=meta)
    fig = calibration_figure(out.with_suffix(".png"), grid, white.counts)
    print(f"microlens grid of {white.source} ({white.shape[0]}x{white.shape[1]} px, {white.bit_depth}-bit, "
          f"{n_sat} saturated px):")
    print(f"  pitch            {d['pitch_px'][0]:.4f} x {d['pitch_px'][1]:.4f} px (rows x cols)")
    print(f"  rotation         {d['rotation_deg']:.4f} deg")
    print(f"  offset           ({d['offset_px'][0]:.3f}, {d['offset_px'][1]:.3f}) px from the image centre")
    print(f"  lenslets         {d['lenslets'][0]} x {d['lenslets'][1]} ({d['lenslets_fitted']} fitted, "
          f"rms residual {d['rms_residual_px']:.3f} px)")
    if cam is not None and cam.expected_pitch_px is not None:
        print(f"  nominal pitch    {cam.expected_pitch_px:.4f} px ([mla] pitch_um / [sensor] pixel_pitch_um)")
    if radio is not None:
        f = radio.factor[radio.valid]
        print(f"radiometric factor at {radio.wavelength * 1e9:.1f} nm, T_bb {radio.temperature:.1f} K: median "
              f"{np.median(f):.4g} W/m per count over {f.size} px, noise {100 * np.median(radio.rel_std_noise[radio.valid]):.2f} %, "
              f"source temperature {100 * radio.rel_std_temperature:.2f} % (paraxial etendue "
              f"{cam.paraxial_pixel_etendue:.4g} m2 sr)")
    if scene_camera is not None:
        _print_scene_match(grid, scene_camera, args.scene)
    print(f"wrote {out}, {fig}")
    return 0


def _print_scene_match(grid, camera, scene) -> None:
    """Whether ``grid`` is the scene camera's microlens lattice, and if not the scene-file keys that make it so."""
    from .rawdata import check_grid_matches_camera

    try:
        r = check_grid_matches_camera(grid, camera, what="the calibrated grid")
        print(f"  scene camera     {scene}: matches ({r['rms_px']:.3f} px RMS, {r['max_px']:.3f} px max)")
    except LftomoError:
        cam = camera.with_microlens_grid(grid)
        mla, sensor = cam.mla, cam.sensor
        print(f"the camera of {scene} has another microlens lattice; for these frames set in it:")
        print(f"  [camera.mla]\n  count = [{mla.count[0]}, {mla.count[1]}]\n  pitch = {mla.pitch!r}\n"
              f"  diameter = {mla.diameter!r}\n  rotation = {mla.rotation!r}\n"
              f"  offset = [{mla.offset[0]!r}, {mla.offset[1]!r}]\n  [camera.sensor]\n"
              f"  shape = [{sensor.shape[0]}, {sensor.shape[1]}]")


def _series_first_frame(args, frames):
    """The first readable light-field frame (None if none is), with the options that apply to every frame
    checked on it before the cluster starts: ``--noise`` for noise-free frames, ``--channel``."""
    from .lightfield import LightField

    for k, f in enumerate(frames):
        try:
            first = LightField.load(f)
        except (ValueError, OSError):  # a bad frame is recorded as failed when its turn comes
            continue
        if first.noise_std is None and args.noise is None:
            raise LftomoError(f"FRAMES[{k}] {f!r} is noise-free (no noise_std, e.g. an lftomo render): give --noise "
                              "(the relative noise to add, e.g. 0.01)")
        if args.channel >= first.n_channels:
            raise LftomoError(f"--channel {args.channel}: the frames have {first.n_channels} channel(s) "
                              f"(FRAMES[{k}] {f!r}); allowed 0..{first.n_channels - 1}")
        return first
    return None


def _series_forward(args, first, out):
    """The forward model of ``lftomo series``: ``--weights`` (camera of ``first``, the first readable frame, or
    None) or a scene file (its camera and [medium], built with seed render.seed + 2 and kept as DIR/weights.npz)."""
    from .demo import grid_of_weight_file
    from .forward.weights import WeightMatrix, weights

    if args.weights is not None:
        if first is None:
            raise LftomoError("no frame could be read (light-field .npz files written by lftomo render / "
                              "LightField.save): the camera of --weights is unknown")
        cam = first.camera
        grid, _ = grid_of_weight_file(Path(args.weights))
        try:
            return WeightMatrix.load(args.weights, cam, grid)
        except ValueError as exc:
            raise LftomoError(f"--weights: {exc}") from None
    cfg = _load(args.scene, args)
    medium = cfg.scene.medium
    if medium is None:
        raise LftomoError(f"scene file {cfg.source!r} has no [medium]: the weight matrix needs its grid and sigma_a")
    wl = None if cfg.wavelengths is None else cfg.wavelengths[0]
    print(f"lftomo series: weight matrix of {cfg.source} ({cfg.rays_per_pixel} rays/pixel, seed {cfg.seed + 2})",
          file=sys.stderr)
    W = weights(cfg.camera, medium.grid, sigma_a=medium.sigma_a_at(wl), sigma_s=medium.sigma_s, g=medium.g,
                wavelength="gray" if wl is None else wl, rays_per_pixel=cfg.rays_per_pixel, seed=cfg.seed + 2,
                surfaces=cfg.scene.surfaces or None, progress=not args.quiet, sampler=cfg.sampler)
    W.save(out / "weights.npz")
    return W


def _series_raw_check(args) -> None:
    """``lftomo series`` raw-frame options: refused in a bad combination (before any work)."""
    if args.calibration is None:
        raw_only = ("dark", "dark_frames", "camera", "recon_shape", "rays_per_pixel", "quadrature")
        given = [f"--{k.replace('_', '-')}" for k in raw_only if getattr(args, k) is not None]
        if given:
            raise LftomoError(f"{', '.join(given)} only appl{'ies' if len(given) == 1 else 'y'} to raw frames, "
                              "with --calibration cal.npz")
        return
    if args.scene is None:
        raise LftomoError("raw frames (--calibration) need a SCENE.toml (its camera, [medium] grid and sigma_a) "
                          "instead of --weights")
    if args.noise is not None:
        raise LftomoError("--noise adds synthetic noise; raw frames are already noisy (their noise model comes "
                          "from the frame, the dark and the calibration): leave --noise out")
    if args.dark is None:
        _refuse_given(args, ("dark_frames",), "with --dark")


def _series_raw_forward(args, out):
    """Raw frames: the calibration, dark and sensor settings checked once, then the weight matrix as
    ``lftomo reconstruct --raw`` builds it (kept as DIR/weights.npz); returns ``(W, raw options)``."""
    from .demo import raw_scene_model, raw_scene_weights

    cfg, grid, conv = raw_scene_model(args.scene, args.calibration, dark=args.dark, dark_frames=args.dark_frames or 1,
                                      camera_file=args.camera, recon_shape=args.recon_shape,
                                      allow_outside=args.allow_outside_paths)
    print(f"lftomo series: raw frames calibrated by {args.calibration} at {conv.wavelength * 1e9:.1f} nm; weight "
          f"matrix of {cfg.source} on {'x'.join(map(str, grid.shape))} voxels", file=sys.stderr)
    W, _, info = raw_scene_weights(cfg, grid, conv.wavelength, rays_per_pixel=args.rays_per_pixel,
                                   quadrature=args.quadrature, progress=not args.quiet)
    print(f"lftomo series: weight matrix at {info['rays_per_pixel_weights']} rays/pixel on the "
          f"{'x'.join(map(str, W.metadata['grid']['shape']))} grid", file=sys.stderr)
    W.save(out / "weights.npz")
    # sub-voxel emission: T on the reconstruction grid, interpolated to W's finer grid
    return W, {"calibration": conv, **({"grid": grid} if info["quadrature"] > 1 else {})}


def cmd_series(args) -> int:
    """``lftomo series``: one reconstruction per frame on a Dask cluster, resumable; a summary figure."""
    from .io import check_output_dir
    from .series import check_workers, reconstruct_series, series_figure, series_strip

    scenes = [f for f in args.frames if f.endswith(".toml")]
    frames = [f for f in args.frames if not f.endswith(".toml")]
    if len(scenes) > 1 or (scenes and args.weights is not None) or (not scenes and args.weights is None):
        raise LftomoError("give the forward model either as --weights W.npz or as one SCENE.toml (got "
                          f"{len(scenes)} .toml file(s){' and --weights' if args.weights else ''})")
    if not frames:
        raise LftomoError("no FRAMES given: light-field .npz files (lftomo render / LightField.save)")
    if args.scheduler is not None and args.workers is not None:
        raise LftomoError("--workers sizes the local cluster; with --scheduler the cluster has its own workers")
    if args.workers is not None:
        check_workers(args.workers, name="--workers")
    args.scene = scenes[0] if scenes else None
    _series_raw_check(args)
    # a mistyped path is refused before the cluster starts; what a file holds is checked per frame (a bad frame
    # is recorded as failed and the series goes on)
    for k, f in enumerate(frames):
        require_regular_file(f, what="light-field file" if args.calibration is None else "raw frame",
                             prefix=f"FRAMES[{k}]: ")
    raw_kw: dict = {}
    out = check_output_dir(args.output, what="-o/--output")
    if args.calibration is not None:
        W, raw_kw = _series_raw_forward(args, out)
    else:
        W = _series_forward(args, _series_first_frame(args, frames), out)
    from .inverse.solverchoice import AutoSolver

    rule = _fit_rule(args)
    opts = {"rule": rule, "bounds": tuple(args.bounds), "solver": AutoSolver(max_steps=args.max_steps)}
    if args.prior is not None:
        opts["prior"] = args.prior
    t0 = time.perf_counter()
    res = reconstruct_series(frames, W, out=out, scheduler=args.scheduler, workers=args.workers,
                             progress=not args.quiet, noise=args.noise, seed=args.seed, data=args.data,
                             depths=args.depths, channel=args.channel, **raw_kw, **opts)
    figs = [series_figure(res, out / "series.png", frame_rate=args.frame_rate).name]
    if res.n_done:
        figs.append(series_strip(res, out / "series_strip.png").name)
    print(f"{res.n_done} of {len(res.frames)} frames reconstructed on {'x'.join(map(str, res.grid_shape))} voxels "
          f"in {time.perf_counter() - t0:.1f} s; wrote {out}/ (frame_XXXX.npz, manifest.json, {', '.join(figs)})")
    for f in res.failed:
        print(f"  FAILED {f.message}")
    return 1 if res.failed else 0


# ---- argument types: argparse names the option in its error message
def _int_in(text: str, lo: int, hi: int) -> int:
    """``int(text)`` if ``lo <= value <= hi``; else an argparse error saying what is allowed."""
    allowed = f"an integer from {lo} to {hi}"
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}") from None
    if not lo <= v <= hi:
        raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}")
    return v


def _output(text: str) -> str:
    """An output path: not empty (an empty -o would write into the current folder unasked)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a file or folder name, got {text!r}")
    return text


def _nonneg_int(text: str) -> int:
    return _int_in(text, 0, 2**31 - 1)


def _pos_int(text: str) -> int:
    return _int_in(text, 1, 2**31 - 1)


def _seed(text: str) -> int:
    from ._validate import MAX_SEED

    return _int_in(text, 0, MAX_SEED)


def _rays(text: str) -> int:
    from ._validate import MAX_RAYS_PER_PIXEL

    return _int_in(text, 1, MAX_RAYS_PER_PIXEL)


def _float_where(text: str, ok, allowed: str) -> float:
    """``float(text)`` if finite and ``ok(value)``; else an argparse error saying ``allowed``."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}") from None
    if not (np.isfinite(v) and ok(v)):
        raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}")
    return v


def _pos_float(text: str) -> float:
    return _float_where(text, lambda v: v > 0, "a finite number > 0")


def _steps(text: str) -> int:
    from ._validate import MAX_SOLVER_STEPS

    return _int_in(text, 1, MAX_SOLVER_STEPS)


def _posterior_steps(text: str) -> int:
    from ._validate import MAX_SOLVER_STEPS

    return _int_in(text, 2, MAX_SOLVER_STEPS)


def _relative_noise(text: str) -> float:
    return _float_where(text, lambda v: 0 < v <= 10, "a relative noise > 0 and <= 10")


def _float_where_nonneg(text: str) -> float:
    return _float_where(text, lambda v: v >= 0, "a finite number >= 0")


def _fraction(text: str) -> float:
    return _float_where(text, lambda v: 0.0 <= v < 1.0, "a number in [0, 1)")


def _regularization(text: str):
    if text == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number >= 0, got {text!r}") from None
    if not (np.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected 'auto' or a finite number >= 0, got {text!r}")
    return v


def _float_list(text: str, expected: str = "comma-separated numbers, e.g. 0.98,1.0,1.02") -> list[float]:
    try:
        vals = [float(t) for t in text.replace(" ", "").split(",") if t]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}") from None
    if not vals:
        raise argparse.ArgumentTypeError(f"expected at least one number, got {text!r}")
    return vals


def _depths(text: str) -> list[float]:
    vals = _float_list(text)
    if not all(np.isfinite(v) and v > 0 for v in vals):
        raise argparse.ArgumentTypeError(f"depths must be positive distances in m from the aperture stop, got {text!r}")
    return vals


def _bounds(text: str) -> tuple[float, float]:
    from ._validate import require_bounds

    vals = _float_list(text, "T_min,T_max in K, e.g. 300,2500")
    try:
        return require_bounds(vals, "bounds")
    except LftomoError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _shape3(text: str) -> tuple[int, int, int]:
    try:
        vals = [int(t) for t in text.replace("x", ",").split(",") if t]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three integers nx,ny,nz, got {text!r}") from None
    if len(vals) != 3 or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected three integers >= 1 (nx,ny,nz), got {text!r}")
    return tuple(vals)


def _add_allow_outside(p: argparse.ArgumentParser) -> None:
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="let the scene file's path = keys (textures, media) name files outside its folder")


def _add_sampler(p: argparse.ArgumentParser, what: str) -> None:
    from .forward.sampler import DEFAULT_SAMPLER, SAMPLERS

    p.add_argument("--sampler", choices=SAMPLERS, default=None,
                   help=f"pixel sampler (lftomo.forward.sampler): {what}; default the scene's [render] sampler, "
                        f"else {DEFAULT_SAMPLER!r}")


def _add_series_parser(sub) -> None:
    """The ``series`` sub-command (its options mirror ``reconstruct``'s)."""
    from .rawdata import RAW_WEIGHT_RAYS

    sr = sub.add_parser("series", help="reconstruct a time-resolved series of light fields, one Dask task per "
                                       "frame (resumable; a summary figure)")
    sr.add_argument("frames", nargs="+", metavar="FRAMES",
                    help="light-field .npz files (lftomo render / LightField.save), or raw frames with --calibration, "
                         "in time order; and one SCENE.toml among them, whose camera and [medium] give the weight "
                         "matrix (or --weights)")
    sr.add_argument("--weights", default=None, help="weight matrix .npz (lftomo weights) on the reconstruction grid")
    sr.add_argument("-o", "--output", type=_output, default="lftomo-series", help="output directory (default lftomo-series; a rerun resumes there)")
    sr.add_argument("--scheduler", default=None, help="address of a Dask scheduler, e.g. tcp://host:8786 "
                                                      "(default: a local cluster)")
    sr.add_argument("--workers", type=_pos_int, default=None,
                    help="processes of the local cluster, one thread each (default: the usable cores)")
    sr.add_argument("--noise", type=_relative_noise, default=None,
                    help="relative Gaussian noise added to noise-free frames (seed --seed + frame index); "
                         "required for noise-free frames such as lftomo render's")
    sr.add_argument("--seed", type=_seed, default=0, help="base noise seed (default 0)")
    sr.add_argument("--data", choices=("subaperture", "refocus"), default="subaperture", help="data kind")
    sr.add_argument("--depths", type=_depths, default=None, help="refocus depths in m, comma-separated")
    sr.add_argument("--regularization", type=_regularization, default="auto", help="'auto' or lambda >= 0")
    sr.add_argument("--rule", choices=("discrepancy", "gcv", "lcurve"), default=None,
                    help="lambda rule with --regularization auto (default discrepancy)")
    sr.add_argument("--prior", choices=("gradient", "laplacian", "tv", "curvature"), default=None,
                    help="smoothness prior (default: the library's, curvature)")
    sr.add_argument("--noise-scale", choices=("given", "estimated"), default=None,
                    help="discrepancy rule: trust sigma (given, the default) or estimate its scale")
    sr.add_argument("--bounds", type=_bounds, default=(300.0, 3000.0), help="T_min,T_max in K (default 300,3000)")
    sr.add_argument("--max-steps", type=_steps, default=None,
                    help="nonlinear steps per solve (default the library's: 200 for T)")
    sr.add_argument("--channel", type=_nonneg_int, default=0, help="wavelength channel of the frames (default 0)")
    sr.add_argument("--frame-rate", type=_pos_float, default=None, help="frames per second, for the figure's time axis")
    sr.add_argument("--calibration", default=None, help="raw frames (PNG, TIFF, .npy) of the SCENE's camera: the "
                                                        "calibration .npz of lftomo calibrate with --blackbody")
    sr.add_argument("--dark", default=None, help="with --calibration: dark frame (same exposure, lens capped)")
    sr.add_argument("--dark-frames", type=_pos_int, default=None, help="with --calibration: frames averaged in --dark")
    sr.add_argument("--camera", default=None, help="with --calibration: camera TOML (gain, read noise, bit depth) "
                                                   "if the calibration did not record them")
    sr.add_argument("--recon-shape", type=_shape3, default=None,
                    help="with --calibration: reconstruction grid nx,ny,nz (default half the [medium] shape)")
    sr.add_argument("--rays-per-pixel", type=_rays, default=None,
                    help="with --calibration: rays per pixel of the weight matrix (default the larger of the "
                         f"SCENE's render.rays_per_pixel and {RAW_WEIGHT_RAYS})")
    sr.add_argument("--quadrature", type=_pos_int, default=None,
                    help="with --calibration: sub-voxel emission, the weight matrix on a K-fold finer grid "
                         "(default 2, as lftomo reconstruct --raw; 1: on the reconstruction grid)")
    sr.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_allow_outside(sr)
    sr.set_defaults(func=cmd_series)


def build_parser() -> argparse.ArgumentParser:
    from .rawdata import RAW_WEIGHT_RAYS

    p = argparse.ArgumentParser(prog="lftomo", description="Plenoptic camera simulation and flame tomography.")
    sub = p.add_subparsers(dest="command", required=True)
    c = sub.add_parser("camera", help="print the camera design report of a scene file, one per camera of a rig "
                                                "(default: built-in scene)")
    c.add_argument("scene", nargs="?", default=None, help="TOML scene file")
    c.add_argument("--json", action="store_true", help="print JSON")
    _add_allow_outside(c)
    c.set_defaults(func=cmd_camera)
    r = sub.add_parser("render", help="render the raw light field, views and a focal stack")
    r.add_argument("scene", nargs="?", default=None, help="TOML scene file (default: built-in target scene)")
    r.add_argument("-o", "--output", type=_output, default="lftomo-render",
                   help="output directory (default lftomo-render)")
    r.add_argument("--rays-per-pixel", type=_rays, default=None, help="override render.rays_per_pixel")
    r.add_argument("--seed", type=_seed, default=None, help="override render.seed")
    _add_sampler(r, "override render.sampler")
    from .forward.allocation import ALLOCATIONS

    r.add_argument("--allocation", choices=ALLOCATIONS, default=None,
                   help="how the rays are shared among the pixels (lftomo.forward.allocation): the same number each, "
                        "or after a pilot, where the light is, for the same cost; default the scene's [render] "
                        "allocation, else 'uniform'")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_allow_outside(r)
    r.set_defaults(func=cmd_render)
    w = sub.add_parser("weights", help="build the ray-voxel weight matrix of the scene's medium grid (.npz)")
    w.add_argument("scene", help="TOML scene file with a [medium]")
    w.add_argument("-o", "--output", type=_output, default="weights.npz",
                   help="output .npz (default weights.npz; several wavelengths: suffix _<nm>nm)")
    w.add_argument("--rays-per-pixel", type=_rays, default=None, help="override render.rays_per_pixel")
    w.add_argument("--seed", type=_seed, default=None, help="override render.seed")
    _add_sampler(w, "override render.sampler (the rays are those of lftomo render with the same seed and sampler)")
    w.add_argument("--guide", default=None, metavar="LIGHTFIELD.npz",
                   help="share the rays among the rows where this light field (the measurement, or lftomo "
                        "render's lightfield.npz of a first guess, of the same camera) is bright: at most the same "
                        "rays in all, lower error where the light is (allocation='adaptive'; from 16 rays per "
                        "pixel); default: the same rays for every row")
    w.add_argument("--memory-limit-gb", type=_pos_float, default=None,
                   help="refuse a build estimated above this size (default: LFTOMO_MEMORY_LIMIT_GB if set, "
                        "else half the machine's memory)")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_allow_outside(w)
    w.set_defaults(func=cmd_weights)
    d = sub.add_parser("demo", help="the whole story on the built-in flame: render, weights, reconstruction, "
                                     "posterior, refocus vs views; writes an HTML report")
    d.add_argument("-o", "--output", type=_output, default="lftomo-demo", help="report directory (default lftomo-demo)")
    d.add_argument("--quick", action="store_true", help="small camera and grids, short chain (3-4 min on 2 cores)")
    d.add_argument("--seed", type=_seed, default=0, help="base seed (render s, noise s+1, weights s+2, "
                                                               "posterior s+3)")
    d.add_argument("--quiet", action="store_true", help="no stage messages, progress bars or summary")
    d.set_defaults(func=cmd_demo)
    rc = sub.add_parser("reconstruct", help="reconstruct the temperature field from a saved light field + weight "
                                            "matrix, or from a scene file")
    rc.add_argument("scene", nargs="?", default=None,
                    help="TOML scene file with a [medium] (renders the truth and the weights); "
                         "or give --lightfield and --weights")
    rc.add_argument("--lightfield", default=None, help="light field .npz (lftomo render / LightField.save)")
    rc.add_argument("--weights", default=None, help="weight matrix .npz (lftomo weights) on the reconstruction grid")
    rc.add_argument("-o", "--output", type=_output, default="lftomo-reconstruct",
                    help="output directory (default lftomo-reconstruct)")
    rc.add_argument("--noise", type=_relative_noise, default=None,
                    help="relative Gaussian noise added to a noise-free light field (default 0.01)")
    rc.add_argument("--data", choices=("subaperture", "refocus"), default="subaperture", help="data kind")
    rc.add_argument("--depths", type=_depths, default=None,
                    help="refocus depths in m, comma-separated (with --data refocus; default the scene's "
                         "output.focal_stack_depths)")
    rc.add_argument("--regularization", type=_regularization, default="auto", help="'auto' or lambda >= 0")
    rc.add_argument("--rule", choices=("discrepancy", "gcv", "lcurve"), default=None,
                    help="lambda rule with --regularization auto (default discrepancy)")
    rc.add_argument("--noise-scale", choices=("given", "estimated"), default=None,
                    help="discrepancy rule: trust the noise model's sigma (given), or only its shape and estimate "
                         "its scale from the residual of the least-regularized fit (estimated); default given, "
                         "estimated with --symmetry axisymmetric")
    rc.add_argument("--prior", choices=("gradient", "laplacian", "tv", "curvature"), default=None,
                    help="smoothness prior (default curvature: second differences, free faces)")
    rc.add_argument("--bounds", type=_bounds, default=(300.0, 3000.0), help="T_min,T_max in K (default 300,3000)")
    rc.add_argument("--min-etendue-fraction", type=_fraction, default=0.2,
                    help="leave out view pixels of etendue below this fraction of the peak (rims of the microlens "
                         "images, default 0.2)")
    rc.add_argument("--max-steps", type=_steps, default=None,
                    help="nonlinear steps per solve (default the library's: 200 for T; fewer steps leave the "
                         "λ search's χ² unconverged)")
    rc.add_argument("--symmetry", choices=("none", "axisymmetric"), default="none",
                    help="axisymmetric: fit one temperature per ring of voxels about the grid's vertical axis "
                         "(lftomo.ring_grid; for axisymmetric flames: removes the depth ambiguity of one camera); "
                         "applies to the reconstruction and to --posterior-basis field")
    rc.add_argument("--quadrature", type=_pos_int, default=None,
                    help="sub-voxel emission: the weights live on a grid this many times finer than the "
                         "reconstruction grid and T is interpolated to it before Planck's law (scene and raw mode "
                         "build them so, default 2; file mode reconstructs on the --weights grid coarsened this "
                         "many times, default 1)")
    rc.add_argument("--posterior", action="store_true",
                    help="also compute a posterior (see --posterior-basis)")
    rc.add_argument("--posterior-basis", choices=("flame", "dct", "field"), default=None,
                    help="with --posterior: emcee on the 6-parameter flame (default; with --quadrature > 1 "
                         "evaluated on the weights' quadrature grid, the fields written on the reconstruction "
                         "grid) or 12 DCT modes, or 'field': the full-grid Laplace "
                         "posterior with lambda by empirical Bayes (lftomo.laplace_posterior)")
    rc.add_argument("--posterior-steps", type=_posterior_steps, default=None, help="emcee steps, 2 to 10^6 (default 500)")
    rc.add_argument("--recon-shape", type=_shape3, default=None,
                    help="scene mode: reconstruction grid nx,ny,nz dividing the [medium] shape (default half)")
    rc.add_argument("--rays-per-pixel", type=_rays, default=None,
                    help="scene mode: override render.rays_per_pixel; with --raw: the weight matrix's (default "
                         f"the larger of render.rays_per_pixel and {RAW_WEIGHT_RAYS})")
    rc.add_argument("--seed", type=_seed, default=None,
                    help="seed s: scene mode renders with s, noise s+1, weights s+2 (default render.seed); "
                         "file mode: noise s+1")
    _add_sampler(rc, "scene mode: override render.sampler (the render and the weights)")
    rc.add_argument("--channel", type=_nonneg_int, default=None, help="wavelength channel (default: the first / "
                                                                      "the one matching --weights)")
    rc.add_argument("--raw", default=None, help="raw frame (PNG, TIFF, .npy) of the SCENE's camera to reconstruct, "
                                                "with --calibration (docs/real_cameras.md)")
    rc.add_argument("--calibration", default=None, help="with --raw: calibration .npz of lftomo calibrate with "
                                                        "--blackbody (microlens grid and radiometric factors)")
    rc.add_argument("--dark", default=None, help="with --raw: dark frame (same exposure, lens capped)")
    rc.add_argument("--dark-frames", type=_pos_int, default=None, help="with --dark: frames averaged in it "
                                                                       "(default 1)")
    rc.add_argument("--camera", default=None, help="with --raw: camera TOML (gain, read noise, bit depth) if the "
                                                   "calibration did not record one")
    rc.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_allow_outside(rc)
    rc.set_defaults(func=cmd_reconstruct)
    _add_series_parser(sub)
    cal = sub.add_parser("calibrate", help="microlens grid (and radiometric factors) of a real camera from a "
                                           "white frame (and a blackbody frame): PNG, TIFF or .npy")
    cal.add_argument("white", help="white (flat-field) raw frame")
    cal.add_argument("--dark", default=None, help="dark frame (same exposure, lens capped)")
    cal.add_argument("--dark-frames", type=_pos_int, default=None, help="frames averaged in --dark (default 1)")
    cal.add_argument("--blackbody", default=None, help="raw frame of a blackbody source filling the view")
    cal.add_argument("--temperature", type=_pos_float, default=None, help="blackbody temperature, K")
    cal.add_argument("--temperature-std", type=_float_where_nonneg, default=None,
                     help="standard uncertainty of the blackbody temperature, K (default 0)")
    cal.add_argument("--camera", default=None, help="camera/acquisition TOML (bit depth, wavelength, gain, f-number)")
    cal.add_argument("--scene", default=None, help="scene TOML whose camera will reconstruct these frames: says "
                     "whether its microlens lattice is the calibrated one, else prints the [camera.mla] and "
                     "[camera.sensor] keys that make it so")
    cal.add_argument("-o", "--output", type=_output, default="calibration.npz",
                     help="output .npz (default calibration.npz; a .png figure beside it)")
    cal.set_defaults(func=cmd_calibrate)
    from .designcli import add_design_parser

    add_design_parser(sub, positive_int=_pos_int, nonneg_int=_nonneg_int, positive_float=_pos_float, output=_output,
                      add_allow_outside=_add_allow_outside)
    return p


def _file_errors() -> tuple[type[BaseException], ...]:
    """Exceptions of damaged files that a loader might still let through (a last guard)."""
    import zipfile
    import zlib

    return (zipfile.BadZipFile, EOFError, zlib.error)


def _numba_errors() -> tuple[type[BaseException], ...]:
    try:
        from numba.core.errors import NumbaError
    except ImportError:  # pragma: no cover
        return ()
    return (NumbaError,)


def main(argv=None) -> int:
    """Run the ``lftomo`` command.

    Exit status: 0 success; 2 a bad argument, scene file, input file or output
    location (``lftomo: error: ...`` on stderr, no traceback); 1 ``lftomo series``
    with frames that failed (listed, the others done); 130 interrupted
    (Ctrl-C), with every output file either as before or complete; 141 the
    reader of its standard output went away (a closed pipe, ``| head``).
    """
    args = build_parser().parse_args(argv)
    out = getattr(args, "output", None)
    fresh = isinstance(out, str) and not Path(out).exists()
    status = 2
    try:
        status = _run_command(args)
    finally:
        if fresh and status != 0:
            _remove_if_empty(Path(out))
    return status


def _remove_if_empty(folder: Path) -> None:
    """Remove an output folder this run made and left empty (a run refused after making it)."""
    try:
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
    except OSError:
        pass


def _run_command(args) -> int:
    """``args.func(args)``, with the errors a user can cause turned into an exit status and one line."""
    from ._validate import memory_limit

    try:
        memory_limit()  # a bad LFTOMO_MEMORY_LIMIT_GB is named as such, not as the first table that sizes an array
        status = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return status
    except BrokenPipeError:  # the reader of our output went away (`| head`): not an error of the input
        _silence_stdout()
        return 141
    except KeyboardInterrupt:
        print("lftomo: interrupted; no output file was left half-written", file=sys.stderr)
        return 130
    except LftomoError as exc:  # lftomo's own checks: the message names the input
        print(f"lftomo: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:  # numpy's or scipy's checks: an input that slipped past lftomo's
        print(f"lftomo: error: {exc} ({type(exc).__name__} from {_origin(exc)}: an input lftomo's checks let "
              "through; please report this with the command line)", file=sys.stderr)
        return 2
    except OSError as exc:  # a file that cannot be read or written: not a bug of lftomo
        print(f"lftomo: error: {exc.strerror or exc}" + (f": {exc.filename!r}" if exc.filename else ""),
              file=sys.stderr)
        return 2
    except MemoryError:
        print("lftomo: error: out of memory; use a smaller camera, grid or ray count, or lower "
              "LFTOMO_MEMORY_LIMIT_GB so that the size checks refuse such runs up front", file=sys.stderr)
        return 2
    except _file_errors() as exc:
        print(f"lftomo: error: a file is corrupt or truncated ({type(exc).__name__}: {exc})", file=sys.stderr)
        return 2
    except _numba_errors() as exc:  # an input that slipped past the checks into a kernel
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        print(f"lftomo: error: a compiled kernel refused its input ({type(exc).__name__}: {first}); "
              "please report this with the command line", file=sys.stderr)
        return 2


def _silence_stdout() -> None:
    """Point stdout at the null device, so that the interpreter's last flush to a closed pipe is quiet."""
    import os

    with contextlib.suppress(OSError, ValueError):
        fd = sys.stdout.fileno()  # none under a capturing test runner or in a notebook: nothing to silence
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, fd)
        finally:
            os.close(devnull)


def _origin(exc: BaseException) -> str:
    """The module where ``exc`` was raised (its innermost traceback frame)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb.tb_frame.f_globals.get("__name__", "?") if tb is not None else "?"


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """One line per warning for a command-line user (the category where it is not a UserWarning or one of lftomo's)."""
    kind = "" if issubclass(category, UserWarning) else f" ({category.__name__})"
    return f"lftomo: warning{kind}: {message}\n"


def console_main() -> NoReturn:
    """The ``lftomo`` executable: :func:`main`, then the process's exit with its status.

    Once the command has returned its files are complete or as before, and a
    Ctrl-C has nothing left to stop; one that arrived while Python shuts down
    would interrupt a finalizer (numba's and llvmlite's run then) and print
    its traceback. From then on SIGINT is ignored.  Warnings print as
    ``lftomo: warning: <message>``, without the source line that raised them.
    """
    warnings.formatwarning = _format_warning
    code = main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise SystemExit(code)


if __name__ == "__main__":
    console_main()
