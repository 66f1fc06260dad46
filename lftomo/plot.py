"""Figures (matplotlib, Agg-safe): raw image, views, focal stacks."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .io import atomic_path


def pyplot():
    """``matplotlib.pyplot``, imported on first use with the Agg backend unless one is already chosen."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, *, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` atomically (never a partial figure there) and close it; returns the path."""
    plt = pyplot()
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return path


def most_lit_view(lf, channel: int = 0):
    """``(u, v, image)`` of the sub-aperture view with the largest total étendue."""
    et = lf.etendue.ravel()
    weight = np.where(lf.view_mask, et[np.maximum(lf.view_index, 0)], 0.0).sum(axis=(2, 3))
    v, u = np.unravel_index(np.argmax(weight), weight.shape)
    return u, v, lf.subaperture(u, v, channel=channel if lf.n_channels > 1 else None)


def rig_figure(lightfields, names, path: str | Path, *, channel: int = 0) -> Path:
    """One row per camera of a rig: its raw sensor image (as recorded) and its
    most lit sub-aperture view (upright), on a colour scale shared by all
    cameras so that their signals compare."""
    plt = pyplot()
    raws = [lf.raw if lf.n_channels == 1 else lf.raw[channel] for lf in lightfields]
    vmax = max(float(np.max(r)) for r in raws) or 1.0
    fig, ax = plt.subplots(len(raws), 2, figsize=(10, 4.6 * len(raws)), constrained_layout=True, squeeze=False)
    for k, (lf, raw, name) in enumerate(zip(lightfields, raws, names)):
        im = ax[k, 0].imshow(raw, cmap="inferno", vmin=0.0, vmax=vmax)
        ax[k, 0].set_title(f"{name}: raw sensor image (as recorded)")
        fig.colorbar(im, ax=ax[k, 0], shrink=0.8, label="pixel signal")
        u, v, view = most_lit_view(lf, channel)
        im = ax[k, 1].imshow(view, cmap="inferno")
        ax[k, 1].set_title(f"{name}: sub-aperture view (u={u}, v={v}), upright")
        fig.colorbar(im, ax=ax[k, 1], shrink=0.8)
    for a in ax.ravel():
        a.set_xticks([])
        a.set_yticks([])
    return save_figure(fig, path, dpi=90)


def lightfield_overview(lf, path: str | Path, *, channel: int = 0, crop: int = 12) -> Path:
    """One figure: a raw crop (microlens images), the central view, the view mosaic."""
    plt = pyplot()
    raw = lf.raw if lf.n_channels == 1 else lf.raw[channel]
    p = lf.camera.pixels_per_lenslet
    r0 = raw.shape[0] // 2 - crop * p // 2
    c0 = raw.shape[1] // 2 - crop * p // 2
    fig, ax = plt.subplots(1, 3, figsize=(15, 5), constrained_layout=True)
    im = ax[0].imshow(raw[r0 : r0 + crop * p, c0 : c0 + crop * p], cmap="inferno")
    ax[0].set_title(f"raw sensor (centre {crop}x{crop} microlenses;\nas recorded: scene rotated 180°)")
    fig.colorbar(im, ax=ax[0], shrink=0.8, label="pixel signal")
    u, v, view = most_lit_view(lf, channel)
    im = ax[1].imshow(view, cmap="inferno")
    ax[1].set_title(f"sub-aperture view (u={u}, v={v})\nupright: +x right, +y up")
    fig.colorbar(im, ax=ax[1], shrink=0.8)
    ax[2].imshow(lf.mosaic(channel=channel), cmap="inferno")
    ax[2].set_title("all views, views[v, u] tiled (unlit = black)")
    for a in ax:
        a.set_xticks([])
        a.set_yticks([])
    return save_figure(fig, path)


def focal_stack_figure(lf, depths: Sequence[float], path: str | Path, *, channel: int = 0) -> Path:
    """Refocused images at ``depths`` (m) side by side with their α."""
    plt = pyplot()
    n = len(depths)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axs = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.6 * rows), squeeze=False, constrained_layout=True)
    stack = lf.focal_stack(depths)
    if lf.n_channels > 1:
        stack = stack[:, channel]
    vmax = np.nanmax(stack)
    for k, ax in enumerate(axs.ravel()):
        ax.set_xticks([])
        ax.set_yticks([])
        if k >= n:
            ax.axis("off")
            continue
        ax.imshow(stack[k], cmap="inferno", vmin=0, vmax=vmax)
        ax.set_title(f"z = {depths[k]:.3f} m (α = {lf.alpha_of_depth(depths[k]):.4f})")
    fig.suptitle("refocused images (shift-and-add, traced shifts)")
    path = Path(path)
    try:
        with atomic_path(path) as tmp:  # never a partial figure at ``path``
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
    return path
