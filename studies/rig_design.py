"""Does a second (third) camera pay off, and does lt.design predict it?  (issue 37 goals)

The flame (``--flame``: the off-axis two-lobed flame by default) is defined on
a ``2n``³ grid and rendered there; the reconstruction grid is ``n``³ over the
same box (no inverse crime).  For each configuration of
:func:`lftomo.inverse.design.standard_configurations` (``--configs``), at the
same total rays per pixel (a rig of k cameras traces ``--rays / k`` per camera):

* :func:`lftomo.design` predicts the mean error above ``--hot`` (the bias of a
  noise-free fit at the design's λ with the noise spread linearised at the
  truth, as the folded normal's mean), the posterior std and the Cramér–Rao
  bound;
* the default reconstruction of ``--draws`` simulated measurements (a render
  with 4× the rays standing in for the camera's images, ``--noise`` relative
  noise, the weights' Monte Carlo error in σ) gives the achieved mean
  |ΔT|/T above ``--hot``.

Usage::

    python studies/rig_design.py [--n 16] [--rays 64] [--configs "one camera,two cameras at 90°"] [--json out.json]
        [--sampler stratified] [--noise-scale given|estimated] [--quadrature 2]

Prints each configuration's row as it completes (and rewrites ``--json``
atomically after each), then one Markdown table ranked by predicted error, the
ratio of the two-camera to the one-camera achieved error and the Spearman rank
correlation of predicted and achieved errors.  ``--resume F.json`` (repeatable)
takes the rows of earlier runs with the same settings and computes only the
configurations they lack: a stopped run continues where it stopped, and
configurations run in separate processes are ranked together.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import lftomo as lt
from lftomo.forward.sampler import DEFAULT_SAMPLER
from lftomo.inverse.design import (DESIGN_QUADRATURE, compare_designs, design_configurations, design_table,
                                   standard_configurations)
from lftomo.io import atomic_write_text, check_output_file

#: the arguments two runs must share for their rows to be ranked together
SAME_SETTINGS = ("n", "rays", "noise", "flame", "hot", "draws", "sampler", "noise_scale", "quadrature", "first_draw")


def resumed_rows(paths: list[str], args: dict) -> dict[str, dict]:
    """Rows of earlier runs' ``--json`` files, by configuration name (checked before any work)."""
    rows: dict[str, dict] = {}
    for p in paths:
        try:
            doc = json.loads(Path(p).read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise SystemExit(f"--resume {p!r}: cannot read it as JSON ({err})") from None
        if not (isinstance(doc, dict) and isinstance(doc.get("args"), dict) and isinstance(doc.get("rows"), list)):
            raise SystemExit(f"--resume {p!r}: not a rig_design.py --json file (needs 'args' and 'rows')")
        differ = [f"{k}={doc['args'].get(k)!r} (now {args[k]!r})" for k in SAME_SETTINGS
                  if doc["args"].get(k) != args[k]]
        if differ:
            raise SystemExit(f"--resume {p!r}: made with other settings: {', '.join(differ)}")
        for r in doc["rows"]:
            ok = (isinstance(r, dict) and isinstance(r.get("name"), str)
                  and all(isinstance(r.get(k), (int, float)) and math.isfinite(r[k])
                          for k in ("predicted_mean_rel", "reconstruction_mean_rel")))
            if not ok:
                raise SystemExit(f"--resume {p!r}: a row lacks a name or finite predicted/achieved errors: {r!r:.200}")
            rows[r["name"]] = r
    return rows


def save_rows(path: str, args: dict, rows: list, **summary) -> None:
    """Write the run's settings and rows to ``path`` atomically (NaN, e.g. ρ of one row, as null: strict JSON)."""
    clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in summary.items()}
    atomic_write_text(path, json.dumps({"args": args, "rows": rows, **clean}, indent=1, allow_nan=False))


def config_row(name: str, cfg: dict, grid, flame, a) -> dict:
    """One configuration's summary row, the achieved error averaged over ``a.draws`` noise draws."""
    draws = []
    rule = None if a.noise_scale == "default" else lt.Discrepancy(noise_scale=a.noise_scale)
    for draw in range(a.draws):
        designs = design_configurations({name: cfg}, grid, flame, rays_per_pixel=a.rays, noise=a.noise, hot=a.hot,
                                        seed=1000 * (a.first_draw + draw), sampler=a.sampler, quadrature=a.quadrature,
                                        rule=rule, progress=True)
        draws.append(compare_designs(designs)[0])
    # the predictions barely depend on the draw (λ does): the first draw's, with the mean achieved error
    row = draws[0]
    row["reconstruction_draws"] = [q["reconstruction_mean_rel"] for q in draws]
    row["reconstruction_mean_rel"] = float(np.mean(row["reconstruction_draws"]))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=16, help="reconstruction voxels per axis (<= 16)")
    ap.add_argument("--rays", type=int, default=64, help="total rays per pixel of the weights")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--flame", default="two_lobed", choices=["two_lobed", "axisymmetric"])
    ap.add_argument("--hot", type=float, default=800.0)
    ap.add_argument("--draws", type=int, default=1, help="noise draws (independent renders) per configuration")
    ap.add_argument("--configs", default="one camera,two cameras at 90°,three cameras at 60°",
                    help="comma-separated names of standard_configurations, or 'all'")
    ap.add_argument("--sampler", default=DEFAULT_SAMPLER,
                    choices=["stratified", "independent"], help="pixel sampler of the renders and the weights")
    ap.add_argument("--noise-scale", default="default", choices=["default", "given", "estimated"],
                    help="the discrepancy rule's noise scale (lt.Discrepancy); default: the library's rule")
    ap.add_argument("--quadrature", type=int, default=DESIGN_QUADRATURE,
                    help="sub-voxel emission: the weights on the grid refined by this factor (lt.design(quadrature=))")
    ap.add_argument("--first-draw", type=int, default=0, help="draw k uses design seed 1000 (first_draw + k)")
    ap.add_argument("--json", default="", help="write the rows here (rewritten after each configuration)")
    ap.add_argument("--resume", action="append", default=[], metavar="JSON",
                    help="rows of an earlier --json run with the same settings: those configurations are not redone")
    a = ap.parse_args()
    if a.json:
        try:  # before hours of work, not after the first configuration
            check_output_file(a.json, what="--json")
        except lt.LftomoError as err:
            raise SystemExit(str(err)) from None
    t0 = time.perf_counter()
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    fine = lt.phantoms.default_flame_grid((2 * a.n,) * 3)
    flame = getattr(lt.phantoms, f"{a.flame}_flame")(fine)
    configs = standard_configurations(lt.Camera.seed(1.0), grid)
    if a.configs != "all":
        names = [s.strip() for s in a.configs.split(",")]
        unknown = sorted(set(names) - set(configs))
        if unknown:
            raise SystemExit(f"--configs: unknown {unknown}; known: {sorted(configs)}")
        configs = {k: configs[k] for k in names}
    done = resumed_rows(a.resume, vars(a))
    rows = []
    for name, cfg in configs.items():
        if name in done:
            rows.append(done[name])
            continue
        t1 = time.perf_counter()
        rows.append(config_row(name, cfg, grid, flame, a))
        print(f"{name} ({time.perf_counter() - t1:.0f} s):\n{design_table(rows[-1:])}", end="", flush=True)
        if a.json:
            save_rows(a.json, vars(a), rows, complete=False)
    rows.sort(key=lambda r: r["predicted_mean_rel"])
    print(design_table(rows), end="")
    by = {r["name"]: r for r in rows}
    if "one camera" in by and "two cameras at 90°" in by:
        ratio = by["two cameras at 90°"]["reconstruction_mean_rel"] / by["one camera"]["reconstruction_mean_rel"]
        print(f"two cameras at 90° / one camera, achieved mean error above {a.hot:.0f} K: {ratio:.2f} "
              f"({a.draws} draw(s)); predicted: "
              f"{by['two cameras at 90°']['predicted_mean_rel'] / by['one camera']['predicted_mean_rel']:.2f}")
    pred_order = [r["name"] for r in sorted(rows, key=lambda r: r["predicted_mean_rel"])]
    real_order = [r["name"] for r in sorted(rows, key=lambda r: r["reconstruction_mean_rel"])]
    rho = spearmanr([r["predicted_mean_rel"] for r in rows], [r["reconstruction_mean_rel"] for r in rows])[0]
    print(f"order by prediction: {pred_order}\norder by reconstruction: {real_order}\n"
          f"same order: {pred_order == real_order}; Spearman rho {rho:.2f}; {time.perf_counter() - t0:.0f} s")
    if a.draws > 1:
        for r in sorted(rows, key=lambda r: r["reconstruction_mean_rel"]):
            d = np.asarray(r["reconstruction_draws"])
            print(f"  {r['name']}: achieved {100 * d.mean():.2f} ± {100 * d.std(ddof=1) / np.sqrt(d.size):.2f} % "
                  f"(mean ± standard error over {d.size} draws), predicted {100 * r['predicted_mean_rel']:.2f} %")
    if a.json:
        save_rows(a.json, vars(a), rows, complete=True, same_order=pred_order == real_order, spearman_rho=float(rho))


if __name__ == "__main__":
    main()
