"""The paper's gradient refinement ("Refine Calibration through Gradient-based Optimization"), in torch.

Loss (both arms, one scale):
``l = sum_m 1/P_m sum_pairs [ alpha * D_R + (1 - alpha) * D_t ]`` with ``D_R`` the geodesic angle between
``R_A R_X`` and ``R_X R_B`` and ``D_t = || (R_A t_X + t_A) - (R_X s t_B + t_X) ||``.
(The paper prints ``arccos(tr(R_E^T R_C) - 1)``; the geodesic angle is ``arccos((tr - 1) / 2)``, used here
through ``atan2`` so its gradient stays finite at zero.)

Each rotation is a Lie-algebra vector ``phi`` around the initial solution, ``R = exp(phi) R0``: the gradient
step is taken on ``phi`` in R^3 and mapped back onto SO(3) by the exponential map (Bregier 2021), as the
paper prescribes. The optimiser is torch's L-BFGS with a strong-Wolfe line search (a gradient method
that converges in tens of steps instead of the thousands plain gradient descent needs on this
badly scaled loss); the best iterate is returned, so the loss never increases over the initial solution.
torch is imported inside the function (start-up time of the CLI) and limited to one thread.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import make_T, so3_exp

from ._closed_form import PairMotions


def _loss_terms(torch, pms, R0s, phis, ts, s, alpha: float, eps: float = 1e-18):
    total = 0.0
    for pm, R0, phi, t in zip(pms, R0s, phis, ts):
        z = phi.new_zeros(())
        S = torch.stack([torch.stack([z, -phi[2], phi[1]]),
                         torch.stack([phi[2], z, -phi[0]]),
                         torch.stack([-phi[1], phi[0], z])])
        R = torch.linalg.matrix_exp(S) @ R0
        RL = pm["R_A"] @ R
        RR = R @ pm["R_B"]
        D = RL.transpose(1, 2) @ RR
        tr = D.diagonal(dim1=1, dim2=2).sum(-1)
        v = torch.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], dim=1)
        ang = torch.atan2(0.5 * torch.sqrt((v * v).sum(1) + eps), 0.5 * (tr - 1.0))
        tL = (pm["R_A"] @ t) + pm["t_A"]
        tR = s * (pm["t_B"] @ R.T) + t
        dt = torch.sqrt(((tL - tR) ** 2).sum(1) + eps)
        total = total + (alpha * ang + (1.0 - alpha) * dt).mean()
    return total


def paper_loss(motions: list[PairMotions], X: list[np.ndarray], scale: float, alpha: float = 0.5) -> float:
    """Value of the paper's loss at hand-eye transforms ``X`` ((4, 4) each) and ``scale``."""
    import torch

    torch.set_num_threads(1)
    with torch.no_grad():
        pms = [_to_torch(torch, pm) for pm in motions]
        val = _loss_terms(torch, pms, [torch.as_tensor(x[:3, :3]) for x in X],
                          [torch.zeros(3, dtype=torch.float64) for _ in X],
                          [torch.as_tensor(x[:3, 3]) for x in X], torch.tensor(float(scale), dtype=torch.float64), alpha)
    return float(val)


def _to_torch(torch, pm: PairMotions) -> dict:
    return {k: torch.as_tensor(np.ascontiguousarray(getattr(pm, k)), dtype=torch.float64) for k in ("R_A", "t_A", "R_B", "t_B")}


def refine_paper(motions: list[PairMotions], X0: list[np.ndarray], scale0: float, alpha: float = 0.5,
                 max_iter: int = 100) -> tuple[list[np.ndarray], float, dict]:
    """Minimise the paper's loss from the closed-form start.

    Args:
        motions: K arms' pair motions (all informative pairs).
        X0: K (4, 4) initial hand-eye transforms.
        scale0: initial scale.
        alpha: rotation/translation weight of the loss (the paper does not state its value).
        max_iter: L-BFGS iterations.

    Returns:
        ``(X list of (4, 4), scale, info)`` with ``info = {"loss_initial", "loss_final", "iterations"}``.
    """
    import torch

    torch.set_num_threads(1)
    pms = [_to_torch(torch, pm) for pm in motions]
    R0s = [torch.as_tensor(x[:3, :3].copy(), dtype=torch.float64) for x in X0]
    phis = [torch.zeros(3, dtype=torch.float64, requires_grad=True) for _ in X0]
    ts = [torch.tensor(x[:3, 3].copy(), dtype=torch.float64, requires_grad=True) for x in X0]
    s = torch.tensor(float(scale0), dtype=torch.float64, requires_grad=True)
    params = phis + ts + [s]
    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=max_iter, tolerance_grad=1e-9, tolerance_change=1e-11,
                            history_size=20, line_search_fn="strong_wolfe")
    best = {"loss": np.inf, "state": None}
    n_eval = [0]

    def closure():
        opt.zero_grad()
        loss = _loss_terms(torch, pms, R0s, phis, ts, s, alpha)
        loss.backward()
        n_eval[0] += 1
        val = float(loss.detach())
        if val < best["loss"]:
            best["loss"] = val
            best["state"] = [p.detach().clone() for p in params]
        return loss

    with torch.no_grad():
        loss0 = float(_loss_terms(torch, pms, R0s, phis, ts, s, alpha))
    start = [p.detach().clone() for p in params]
    opt.step(closure)
    # the best iterate seen; never something worse than the start
    state = best["state"] if best["state"] is not None and best["loss"] <= loss0 else start
    K = len(X0)
    X = [make_T(so3_exp(state[k].numpy()) @ X0[k][:3, :3], state[K + k].numpy()) for k in range(K)]
    return X, float(state[-1]), {"loss_initial": loss0, "loss_final": min(best["loss"], loss0),
                                 "evaluations": n_eval[0]}
