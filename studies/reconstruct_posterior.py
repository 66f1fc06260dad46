"""`lftomo reconstruct --posterior` on a flame finer than its grids: z-scores and field errors of the posterior.

For each flame base width (``--widths``, mm) and seed (``--seeds``) it writes a scene of the standard
axisymmetric flame on 48³ (650 nm, seed camera at 1 m, 64 rays/pixel) and runs the command
``lftomo reconstruct SCENE --recon-shape 16,16,16 --posterior --posterior-basis B --seed S`` (through
:func:`lftomo.demo.run_reconstruct`): the weights on the 32³ quadrature grid, so neither the reconstruction
grid nor the quadrature grid is the truth's (no inverse crime).  The seed draws the render, the noise, the
weights and the chain.  Per run it prints the z-score ``(posterior mean − true) / posterior std`` of each
:class:`lftomo.ParametricFlame` coefficient (``--basis flame``; none for ``dct``), the posterior mean field's mean and largest ``|ΔT|/T`` against
the effective truth above 800 K, the share of those voxels whose truth lies within mean ± 1.645 std, and the
posterior stage's time.  Results are appended to ``OUT/results.jsonl``.

docs/accuracy.md, *`lftomo reconstruct --posterior` samples the form on the quadrature grid*, has this
script's numbers for the current code and for commit c6c49eb (the basis on the reconstruction grid).

Usage::

    python studies/reconstruct_posterior.py [--widths 12,3] [--seeds 0,1,2] [--basis flame|dct] \
        [--out reconstruct_posterior_runs]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import lftomo as lt
from lftomo.demo import run_reconstruct

SCENE = """
[camera]
preset = "seed"
focus_distance = 1.0
[render]
rays_per_pixel = 64
seed = 0
wavelength_nm = 650
[medium]
phantom = "axisymmetric_flame"
shape = [48, 48, 48]
[medium.params]
width_base = {width}
"""


def true_coefficients(truth_grid: dict, width_m: float) -> dict[str, float]:
    """The scene flame's ParametricFlame coefficients: ``axisymmetric_flame``'s defaults on its box (which
    :meth:`ParametricFlame.initial_guess` returns) with the scene's base width."""
    flame = lt.ParametricFlame(lt.Grid.from_dict(truth_grid))
    c = dict(zip(flame.names, (float(v) for v in flame.initial_guess())))
    c["width_base"] = width_m
    return c


def one_run(out: Path, width_mm: float, seed: int, basis: str) -> dict:
    """One ``lftomo reconstruct --posterior`` run and its scores."""
    scene = out / f"flame_{width_mm:g}mm.toml"
    scene.write_text(SCENE.format(width=width_mm * 1e-3), encoding="utf-8")
    run_dir = out / f"run_{basis}_{width_mm:g}mm_seed{seed}"
    m = run_reconstruct(run_dir, scene=scene, recon_shape=(16, 16, 16), posterior=True, posterior_basis=basis,
                        seed=seed, progress=False)
    po = m["posterior"]
    true = true_coefficients(m["inputs"]["truth_grid"], width_mm * 1e-3)
    z = {n: (mu - true[n]) / sd for n, mu, sd in zip(po["names"], po["mean"], po["std"]) if n in true}
    f = np.load(run_dir / "fields.npz", allow_pickle=False)
    T, T_true, T_std = f["T_posterior_mean"], f["T_true"], f["T_posterior_std"]
    hot = T_true > 800.0
    rel = np.abs(T[hot] / T_true[hot] - 1.0)
    return {"basis": basis, "width_mm": width_mm, "seed": seed, "basis_grid": po.get("basis_grid"), "z": z,
            "mean_rel_T_gt_800K": float(rel.mean()), "max_rel_T_gt_800K": float(rel.max()),
            "coverage90_T_gt_800K": float(np.mean(np.abs(T[hot] - T_true[hot]) <= 1.645 * T_std[hot])),
            "posterior_s": m["timings_s"].get("posterior"),
            "reconstruction_mean_rel_T_gt_800K": m["reconstruction"]["errors_T_gt_800K"]["mean_rel"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--widths", default="12,3", help="comma-separated flame base widths (mm)")
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated seeds")
    ap.add_argument("--basis", choices=("flame", "dct"), default="flame", help="--posterior-basis")
    ap.add_argument("--out", default="reconstruct_posterior_runs")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for width in (float(w) for w in args.widths.split(",")):
        for seed in (int(s) for s in args.seeds.split(",")):
            r = one_run(out, width, seed, args.basis)
            with open(out / "results.jsonl", "a", encoding="utf-8") as fh:
                fh.write(json.dumps(r) + "\n")
            zs = "  ".join(f"{k} {v:+.2f}" for k, v in r["z"].items())
            print(f"{width:g} mm seed {seed} {args.basis} on {r['basis_grid']}: z {zs}; posterior mean above 800 K "
                  f"{100 * r['mean_rel_T_gt_800K']:.2f} % (max {100 * r['max_rel_T_gt_800K']:.1f} %), 90 % "
                  f"coverage {100 * r['coverage90_T_gt_800K']:.0f} %, posterior {r['posterior_s']:.0f} s", flush=True)


if __name__ == "__main__":
    main()
