"""Uncertainty of every output (past the paper): 1-sigma values for hand-eye, scale, base-to-base.

Two estimators:

- ``jacobian`` (default): the linearised covariance of the absolute problem at the returned solution
  (``_absolute.covariance``: ``(J^T J)^-1`` times the a-posteriori variance factor, with the per-view noise
  estimated from the residuals), propagated to each output through its own Jacobian. A direction the
  views cannot determine has an infinite variance, and so has every output that depends on it. For the paper's
  methods this is the uncertainty of the same data around their answer (a linearisation, not their
  estimator's own spread).
- ``jackknife``: the delete-one-view jackknife of the chosen method itself (N1 + N2 re-solves).

Every block is reported as rotation (deg, RMS total angle and per axis) and translation (mm, per axis and
norm), the scale as absolute and percent.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import inv_T, so3_log

from ._absolute import AbsoluteState


def _block(C6: np.ndarray) -> dict:
    """Summary of a 6x6 covariance of (rotation rad, translation m)."""
    Cr, Ct = C6[:3, :3], C6[3:, 3:]
    dr = np.sqrt(np.clip(np.diag(Cr), 0, None))
    dt = np.sqrt(np.clip(np.diag(Ct), 0, None))
    return {"rotation_deg": float(np.rad2deg(np.sqrt(max(np.trace(Cr), 0.0)))),
            "rotation_axes_deg": np.rad2deg(dr).tolist(),
            "translation_mm": (dt * 1000).tolist(),
            "translation_norm_mm": float(1000 * np.sqrt(max(np.trace(Ct), 0.0)))}


def propagate(G: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``G cov G^T`` (M, M) for a Jacobian G (M, n) and a covariance (n, n) whose undetermined parameters
    carry ``inf`` on the diagonal: each output that depends on one is unbounded (``inf``) too."""
    unbounded = np.isinf(np.diag(cov))
    C = np.where(np.isinf(cov), 0.0, cov)
    out = G @ C @ G.T
    hit = np.any(np.abs(G[:, unbounded]) > 1e-12, axis=1)
    out[hit, :] = 0.0
    out[:, hit] = 0.0
    out[hit, hit] = np.inf
    return out


def _delta(T: np.ndarray, T0: np.ndarray) -> np.ndarray:
    """(6,) local difference of T from T0: [rotvec(R R0^T), t - t0]."""
    return np.concatenate([so3_log(T[:3, :3] @ T0[:3, :3].T), T[:3, 3] - T0[:3, 3]])


def from_covariance(st: AbsoluteState, cov: np.ndarray, names: tuple[str, ...] = ("T_e1_c1", "T_e2_c2")) -> dict:
    """Uncertainty dict of each output from the covariance (12 K + 1) of the absolute problem's local coordinates."""
    K = len(st.X)
    out: dict = {}
    for m in range(K):
        out[names[m]] = _block(cov[12 * m:12 * m + 6, 12 * m:12 * m + 6])
        out[f"T_b{m + 1}_w"] = _block(cov[12 * m + 6:12 * m + 12, 12 * m + 6:12 * m + 12])
    out["scale"] = {"std": float(st.scale * np.sqrt(max(cov[-1, -1], 0.0))),
                    "percent": float(100 * np.sqrt(max(cov[-1, -1], 0.0)))}
    if K == 2:
        B0 = st.W[0] @ inv_T(st.W[1])
        n = 12 * K + 1
        G = np.zeros((6, n))
        h = 1e-6
        for k in list(range(6, 12)) + list(range(18, 24)):
            e = np.zeros(n)
            e[k] = h
            sp, sm = st.perturbed(e), st.perturbed(-e)
            G[:, k] = (_delta(sp.W[0] @ inv_T(sp.W[1]), B0) - _delta(sm.W[0] @ inv_T(sm.W[1]), B0)) / (2 * h)
        out["T_b1_b2"] = _block(propagate(G, cov))
    return out


def from_samples(ref: dict, samples: list[dict]) -> dict:
    """Delete-one jackknife uncertainty from re-solves.

    Args:
        ref: the full solution, ``{"T_e1_c1": (4, 4), ..., "scale": float}``.
        samples: the same keys for each leave-one-view-out solve.
    """
    n = len(samples)
    out: dict = {}
    for key, val in ref.items():
        if key == "scale":
            v = np.array([s["scale"] for s in samples])
            std = float(np.sqrt((n - 1) / n * np.sum((v - v.mean()) ** 2)))
            out["scale"] = {"std": std, "percent": 100 * std / val}
            continue
        d = np.stack([_delta(s[key], val) for s in samples])
        d = d - d.mean(0)
        out[key] = _block((n - 1) / n * d.T @ d)
    return out
