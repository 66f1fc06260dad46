"""Small files and objects shared by the reliability tests (bad inputs, mutations, interrupts)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import lftomo as lt

#: A 10 x 10-lenslet seed camera (100 x 100 pixels): renders and weights in a fraction of a second.
TINY_MLA = {"count": (10, 10)}
TINY_GRID = dict(shape=(3, 3, 3), lower=(-0.006, -0.006, 0.994), upper=(0.006, 0.006, 1.006))


def tiny_camera() -> lt.Camera:
    return lt.Camera.seed(1.0, mla=TINY_MLA)


def tiny_grid() -> lt.Grid:
    return lt.Grid(**TINY_GRID)


def tiny_lightfield() -> lt.LightField:
    scene = lt.Scene(surfaces=[lt.PlanarEmitter(center=(0.0, 0.0, 1.0), size=(0.05, 0.05), radiance=1.0)])
    return lt.render(scene, tiny_camera(), rays_per_pixel=1, seed=0, wavelengths="gray", progress=False)


def tiny_weights() -> lt.WeightMatrix:
    return lt.weights(tiny_camera(), tiny_grid(), sigma_a=5.0, wavelength="gray", rays_per_pixel=1, seed=0,
                      progress=False)


def read_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def rewrite(path: Path, out: Path, *, drop=(), meta=None, **arrays) -> Path:
    """Copy an .npz with members replaced (``arrays``), removed (``drop``) or its JSON meta edited
    (``meta``: a function of the dict returning the dict, or a string written as is)."""
    a = read_arrays(path)
    for k in drop:
        a.pop(k)
    a.update(arrays)
    if meta is not None:
        a["meta"] = np.array(meta if isinstance(meta, str) else json.dumps(meta(json.loads(str(a["meta"])))))
    np.savez(out, **a)
    return out


SCENE_SURFACE = """
[camera]
focus_distance = 1.0
[camera.mla]
count = [10, 10]
[render]
rays_per_pixel = 1
{render}
[[surface]]
center = [0.0, 0.0, 1.0]
size = [0.05, 0.05]
{surface}
"""

SCENE_MEDIUM = """
[camera]
focus_distance = 1.0
[camera.mla]
count = [10, 10]
[render]
rays_per_pixel = 1
wavelength_nm = "gray"
[medium]
phantom = "uniform_box"
shape = [3, 3, 3]
lower = [-0.006, -0.006, 0.994]
upper = [0.006, 0.006, 1.006]
[medium.params]
T = 1500.0
sigma_a = 5.0
"""

#: A Gaussian flame seen by a 12 x 12-lenslet seed camera (the CLI tests of reconstruct --raw and series):
#: format with ``rays``, ``seed``, ``n`` (voxels per side) and ``render`` (more [render] lines, e.g. the wavelength).
BLOB_SCENE = """
[camera]
focus_distance = 1.0
[camera.mla]
count = [12, 12]
[render]
rays_per_pixel = {rays}
seed = {seed}
{render}
[medium]
phantom = "gaussian_blob"
shape = [{n}, {n}, {n}]
lower = [-0.006, -0.006, 0.994]
upper = [0.006, 0.006, 1.006]
[medium.params]
width = 0.004
T_peak = 1800.0
T_ambient = 1000.0
sigma_a_peak = 30.0
"""
