"""How well can the seed camera determine the temperature at all? (issue 5 §5)

The Cramér–Rao bound of the T-only problem without any prior: for data
``y = A I_b(T) + noise`` with noise ``N(0, diag σ²)`` the Fisher information of
the voxel temperatures is ``F = Jᵀ Σ⁻¹ J`` with ``J = A diag(∂I_b/∂T)``.  Any
unbiased estimator has ``var T_i ≥ (F⁻¹)_ii`` (marginal bound; here over the voxels with
T > 800 K, every cooler voxel being told exactly, which only makes it
smaller), and even an
estimator told every other voxel exactly has ``var T_i ≥ 1 / F_ii``
(conditional bound).  A regularized reconstruction can beat the marginal bound
only by trading variance for bias, i.e. by what the prior assumes.

The study builds ``A`` exactly as ``studies/accuracy.py`` does (seed camera,
axisymmetric flame with a 12 mm base, known sigma_a, sub-aperture data with the
étendue cut), evaluates ``F`` at the true field with ``σ = --noise × signal``
(no Monte Carlo error: an optimistic bound), and reports, over the voxels with
T > 800 K, the bounds relative to T and the fraction of voxels whose bound is
below 1 %.  It also prints the singular values of the whitened, T-scaled
Jacobian ``Σ^{-1/2} J diag(T)``: how many independent combinations the data fix
to better than 1 % at this noise.

Usage::

    python studies/information_limit.py [--n 16] [--rays 64] [--noise 0.01] [--symmetry axisymmetric]

``--symmetry axisymmetric`` bounds the temperatures of the ring cells
(:func:`lftomo.ring_grid`) instead of the voxels, ``J = A diag(∂I_b/∂T) P``:
the information the data hold when the flame is known to be axisymmetric (the
model of ``lt.reconstruct(..., symmetry="axisymmetric")``).  The bounds are
also reported per band of the true temperature (800-1100 K, 1100-1400 K,
above 1400 K): the cool fringe is dark at visible wavelengths.

``--unknowns T+sigma_a`` bounds the joint problem of two wavelengths
(``--wavelengths``, soot law ``σ_a ∝ λ^-1.38``): the unknowns are T and σ_a of
every hot voxel (or ring cell), the Jacobian the exact one of the ray-segment
table (``W(σ_a) diag(∂I_b/∂T)`` and ``∂F/∂σ_a``, :meth:`lftomo.RaySegments.jacobian`,
``--rays`` rays per pixel) at the true fields, the data of both channels in
the joint study's best-lit views (``--view-etendue``).  The bound on T then
includes what the unknown σ_a costs.  Its Fisher matrix is ill-conditioned
(condition number ~1e15 at 24³, near double precision's limit), so bounds of
order 100 % are orders of magnitude, not precise values.
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import scipy.sparse as sp

import lftomo as lt
from lftomo import radiation as rad
from lftomo.inverse.compare import effective_truth


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--rays", type=int, default=64, help="rays/pixel of the weight matrix")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--wavelength", type=float, default=650e-9)
    ap.add_argument("--width", type=float, default=0.012)
    ap.add_argument("--min-etendue", type=float, default=0.2)
    ap.add_argument("--symmetry", default="none", choices=["none", "axisymmetric"])
    ap.add_argument("--unknowns", default="T", choices=["T", "T+sigma_a"])
    ap.add_argument("--view-etendue", type=float, default=0.7,
                    help="--unknowns T+sigma_a: views whose median étendue is at least this fraction of the peak")
    ap.add_argument("--wavelengths", default="650e-9,800e-9", help="channels of --unknowns T+sigma_a")
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    if a.n > (20 if a.symmetry == "none" else 40):
        raise SystemExit(f"--n {a.n}: the dense Fisher matrix of the unknowns is formed; use --n <= 20 "
                         "(<= 40 with --symmetry axisymmetric)")
    cam = lt.Camera.seed(1.0)
    grid = lt.phantoms.default_flame_grid((a.n,) * 3)
    fine = lt.phantoms.default_flame_grid((2 * a.n,) * 3)
    flame = lt.phantoms.axisymmetric_flame(fine, width_base=a.width)
    wl = a.wavelength if a.unknowns == "T" else float(a.wavelengths.split(",")[0])
    sa, T = effective_truth(flame, grid, wl)
    if a.symmetry == "none":
        P = sp.identity(grid.n_voxels, format="csr")  # unknowns: the voxels
        Tf = T.ravel()
    else:
        ring = lt.ring_grid(grid)
        P = ring.expansion.tocsr()  # unknowns: the ring cells; a voxel's T is its ring cell's
        Tf = ring.project(T).ravel()  # the ring cells' true T (mean over the ring's voxels)
    hot = Tf > 800
    idx = np.flatnonzero(hot)
    # the measurement's pixel selection: noise-free render of the coarse field
    lf = lt.render(lt.Scene(medium=lt.Medium(grid, sigma_a=sa, T=T)), cam, rays_per_pixel=a.rays, seed=11,
                   wavelengths=(wl,), progress=False)
    noisy = lt.add_noise(lf, relative_std=a.noise, seed=0)

    def whitening(y0):
        """1 / σ of the noise-free data: ``--noise`` of the signal, floored at 1e-3 of the peak's."""
        sigma = a.noise * np.maximum(y0, 1e-3 * y0.max())
        return sp.diags(1.0 / sigma)

    # whitened Jacobian in T/T_true of the hot unknowns only: every cooler one is
    # told exactly (optimistic), so their columns drop out of the marginal bound
    if a.unknowns == "T":
        W = lt.weights(cam, grid, sigma_a=sa, wavelength=wl, rays_per_pixel=a.rays, seed=12, progress=False)
        m = lt.Measurement.from_lightfield(noisy, data="subaperture", depths=None)
        A = m.problem(W, grid).A.tocsr()
        y0 = A @ rad.planck(T.ravel(), wl)
        keep = y0 > 0
        d = rad.dplanck_dT(T.ravel(), wl)
        J = whitening(y0[keep]) @ A[keep] @ sp.diags(d) @ P[:, idx] @ sp.diags(Tf[idx])  # (m, n_hot) sparse
        n_views = len(lf.lit_views)
    else:
        # the joint solver's setting (studies/accuracy_joint.py): the best-lit views, both channels
        from lftomo.inverse.rigsegments import rows_of_pixels

        wls = [float(v) for v in a.wavelengths.split(",")]
        et = lf.etendue / lf.etendue.max()
        views = [vu for vu in lf.lit_views
                 if np.median(et.ravel()[lf.view_index[vu][lf.view_mask[vu]]]) >= a.view_etendue]
        n_views = len(views)
        seg = lt.ray_segments(cam, grid, rays_per_pixel=a.rays, seed=12, views=views, progress=False)
        m = lt.Measurement.from_lightfield(noisy, data="subaperture", views=views)
        rows = rows_of_pixels(m, seg)
        rows = rows[rows >= 0]
        S = P.T @ sa.ravel() / np.asarray(P.sum(axis=0)).ravel()  # σ_a of the unknowns (m⁻¹, first channel)
        s_scale = np.maximum(S[idx], 1e-3 * S.max())  # σ_a in units of itself (floored: the bound on T
        blocks = []                                    # does not depend on how σ_a is scaled)
        for wl_c in wls:
            f_c = (wls[0] / wl_c) ** 1.38
            y_all, dF = seg.jacobian(rad.planck(T.ravel(), wl_c), sa.ravel() * f_c)
            Wc = sp.csr_matrix(seg.weights(sa.ravel() * f_c).matrix)
            Wh = whitening(y_all[rows])
            blocks.append(sp.hstack([
                Wh @ Wc[rows] @ sp.diags(rad.dplanck_dT(T.ravel(), wl_c)) @ P[:, idx] @ sp.diags(Tf[idx]),
                Wh @ dF[rows] @ P[:, idx] @ sp.diags(f_c * s_scale)]))
        J = sp.vstack(blocks).tocsr()  # (m, 2 n_hot): T/T_true, then σ_a/scale
        keep = np.ones(J.shape[0], bool)
    Fh = (J.T @ J).toarray()  # Fisher information on T/T_true (and σ_a/scale)
    w, V = np.linalg.eigh(Fh)
    w_pos = np.maximum(w, w.max() * 1e-300)
    # bounds on T/T_true: the first idx.size unknowns (the σ_a ones, if any, are nuisance parameters)
    rel_m = np.sqrt(np.einsum("ij,j,ij->i", V[:idx.size], 1.0 / w_pos, V[:idx.size]))
    rel_c = 1.0 / np.sqrt(np.diag(Fh)[:idx.size])
    # eigenvalues of Fh are the squared singular values s² of the whitened Jacobian in
    # relative temperature: a unit-norm direction u of δT/T moves the data by s σ; it is
    # fixed to 1 % RMS per voxel when 1/(s √n_hot) < 0.01
    s = np.sqrt(np.maximum(w[::-1], 0.0))
    bands = {}
    for name, b_lo, b_hi in (("800-1100K", 800.0, 1100.0), ("1100-1400K", 1100.0, 1400.0), (">1400K", 1400.0, np.inf)):
        sel = (Tf[idx] > b_lo) & (Tf[idx] <= b_hi)
        if sel.any():
            bands[name] = {"n": int(sel.sum()), "marginal_median": float(np.median(rel_m[sel])),
                           "marginal_fraction_below_1pct": float(np.mean(rel_m[sel] < 0.01)),
                           "conditional_median": float(np.median(rel_c[sel]))}
    out = {
        "n": a.n, "rays": a.rays, "noise": a.noise, "symmetry": a.symmetry, "unknowns": a.unknowns,
        "views": n_views, "m": int(keep.sum()),
        "hot_unknowns": int(hot.sum()), "bands": bands,
        "conditional_bound_rel": {"median": float(np.median(rel_c)), "max": float(np.max(rel_c)),
                                  "fraction_below_1pct": float(np.mean(rel_c < 0.01))},
        "marginal_bound_rel": {"median": float(np.median(rel_m)), "mean": float(np.mean(np.minimum(rel_m, 1e6))),
                               "max": float(np.max(rel_m)),
                               "fraction_below_1pct": float(np.mean(rel_m < 0.01)),
                               "fraction_below_5pct": float(np.mean(rel_m < 0.05))},
        "fisher_condition_number_hot": float(w.max() / max(w.min(), 1e-300)),
        # a unit-norm direction u in relative T moves the data by s·‖u‖ σ; a 1 % RMS change
        # over all observed voxels is ‖u‖ = 0.01 √n_obs
        "directions_fixed_to_1pct_rms": int(np.sum(s * 0.01 * np.sqrt(idx.size) > 1.0)),
        "singular_values_rel_T": [float(v) for v in s[:: max(1, s.size // 32)]],
    }
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
