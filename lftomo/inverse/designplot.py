"""Figures of an experiment design (:mod:`lftomo.inverse.design`): one per quantity.

Each figure shows three central slices of a field on the reconstruction grid
(x–y at the probe's depth, x–z and y–z through it), with the 800 K contour of
the true field, so that a design can be read where the flame is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..plot import pyplot, save_figure

__all__ = ["design_figures", "design_comparison_figure"]


def _slices(field: np.ndarray, voxel: Sequence[int]):
    i, j, k = voxel
    # (title, 2-D array with rows = vertical axis, extent axes)
    return (("x–y (z through the probe)", field[:, :, k].T, ("x", "y")),
            ("x–z (y through the probe)", field[:, j, :].T, ("x", "z")),
            ("y–z (x through the probe)", field[i, :, :].T, ("y", "z")))


def _extent(grid, axes: tuple[str, str]) -> list[float]:
    a, b = ("xyz".index(axes[0]), "xyz".index(axes[1]))
    lo, hi = np.asarray(grid.lower) * 1e3, np.asarray(grid.upper) * 1e3
    return [lo[a], hi[a], lo[b], hi[b]]


def _field_figure(path: Path, design: Any, field: np.ndarray, title: str, label: str, voxel, *,
                  cmap: str = "viridis", log: bool = False) -> Path:
    plt = pyplot()
    from matplotlib.colors import LogNorm

    fig, ax = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True)
    finite = field[np.isfinite(field)]
    norm = None
    if log and finite.size and finite.max() > 0:
        pos = finite[finite > 0]
        norm = LogNorm(vmin=max(float(pos.min()), float(pos.max()) * 1e-4), vmax=float(pos.max()))
    truth = _slices(design.T_true, voxel)
    for a, (name, img, axes), (_, t_img, _) in zip(ax, _slices(field, voxel), truth):
        ext = _extent(design.grid, axes)
        im = a.imshow(np.ma.masked_invalid(img), origin="lower", extent=ext, cmap=cmap, norm=norm, aspect="auto")
        if (t_img > design.hot).any() and (t_img <= design.hot).any():
            a.contour(t_img, levels=[design.hot], colors="w", linewidths=0.8, origin="lower", extent=ext)
        a.set_title(name)
        a.set_xlabel(f"{axes[0]} (mm)")
        a.set_ylabel(f"{axes[1]} (mm)")
    fig.colorbar(im, ax=ax, shrink=0.85, label=label)
    fig.suptitle(title)
    return save_figure(fig, path, dpi=100)


def design_figures(design: Any, directory: Path, *, prefix: str = "design") -> list[Path]:
    """Write the posterior std, predicted error, Cramér–Rao bound and point-spread figures; return their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    v0 = design.probes[0]
    cams = f"{len(design.cameras)} camera{'s' if len(design.cameras) > 1 else ''}"
    what = f"{cams}, {design.wavelength * 1e9:.0f} nm, noise {100 * design.noise:g} %, λ {design.regularization:.3g}"
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = lambda f: 100.0 * f / design.T_true  # noqa: E731
        paths = [
            _field_figure(directory / f"{prefix}_posterior_std.png", design, rel(design.T_std),
                          f"Predicted posterior standard deviation ({what}); white: {design.hot:.0f} K contour",
                          "σ_T / T (%)", v0),
            _field_figure(directory / f"{prefix}_predicted_error.png", design, rel(design.expected_abs_error),
                          f"Predicted error E|bias + spread·Z| ({what})", "|ΔT| / T (%)", v0),
            _field_figure(directory / f"{prefix}_cramer_rao.png", design, rel(design.crb),
                          f"Cramér–Rao bound without a prior, voxels above {design.hot:.0f} K ({what})",
                          "bound / T (%)", v0, cmap="magma", log=True),
        ]
    for n, (psf, voxel, w) in enumerate(zip(design.psf, design.probes, design.psf_widths)):
        mm = " / ".join(f"{1e3 * x:.1f}" for x in w)
        paths.append(_field_figure(directory / f"{prefix}_psf_{n}.png", design, psf,
                                   f"Point-spread function at voxel {voxel} (RMS widths x / y / z: {mm} mm; {what})",
                                   "resolution-matrix column", voxel, cmap="RdBu_r"))
    return paths


def design_comparison_figure(rows: Sequence[dict], path: str | Path) -> Path:
    """Bar chart of :func:`lftomo.inverse.design.compare_designs` rows: predicted
    mean error, posterior std and (when present) the one-draw reconstruction's error."""
    plt = pyplot()
    names = [r["name"] for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(rows) + 2), 4.2), constrained_layout=True)
    ax.bar(x - 0.25, [100 * r["predicted_mean_rel"] for r in rows], 0.25, label="predicted error")
    ax.bar(x, [100 * r["posterior_std_mean_rel"] for r in rows], 0.25, label="posterior std")
    if all("reconstruction_mean_rel" in r for r in rows):
        ax.bar(x + 0.25, [100 * r["reconstruction_mean_rel"] for r in rows], 0.25, label="one reconstruction")
    ax.set_xticks(x, names, rotation=20, ha="right")
    ax.set_ylabel("mean over hot voxels, % of T")
    ax.legend()
    return save_figure(fig, path, dpi=100)
