"""Named, weighted cost terms handed to one robust least-squares solver, with their noise levels
re-estimated from the data (variance components).

A :class:`CostTerm` is a residual family: raw residuals and their Jacobian as functions of the parameter
vector, a noise group for every residual, the current noise level (1-sigma, in the residuals' own units) of
each group, and the rule that re-estimates those levels from the fitted residuals. The solver divides
each residual by its group's noise and minimises the robust (soft-L1) sum over all terms; a new residual
family is one more term in the list, not a new solver.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

__all__ = ["CostTerm", "stack", "solve_terms", "redundancy", "robust_cost"]


@dataclass
class CostTerm:
    """One residual family.

    Attributes:
        name: shown in reports ("kinematic loop", "point maps", ...).
        residuals: ``theta (n,) -> (M,)`` raw residuals.
        jacobian: ``theta (n,) -> (M, n)`` their derivatives.
        groups: (M,) int, the noise group of each residual.
        sigma: (G,) the noise level (1-sigma, raw units) of each group.
        update: ``(term, raw (M,), redundancy (M,)) -> (G,)`` new noise levels from the fitted residuals
            and each residual's redundancy ``1 - h_jj`` (None: the levels stay as given).
        views: (M,) int, the view each residual belongs to (for held-out checks), or None.
        info: term-specific numbers for the report.
    """

    name: str
    residuals: Callable[[np.ndarray], np.ndarray]
    jacobian: Callable[[np.ndarray], np.ndarray]
    groups: np.ndarray
    sigma: np.ndarray
    update: Callable | None = None
    views: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    def weights(self) -> np.ndarray:
        """(M,) 1 / sigma of each residual."""
        return 1.0 / np.asarray(self.sigma, dtype=np.float64)[self.groups]


def stack(terms: list[CostTerm], theta: np.ndarray, jac: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Whitened residuals (M,) of all terms and (with ``jac``) their Jacobian (M, n)."""
    r = np.concatenate([t.residuals(theta) * t.weights() for t in terms])
    if not jac:
        return r, None
    return r, np.concatenate([t.jacobian(theta) * t.weights()[:, None] for t in terms])


def robust_cost(z: np.ndarray, f_scale: float) -> np.ndarray:
    """soft-L1 cost of whitened residuals ``z``: ``2 c^2 (sqrt(1 + z^2 / c^2) - 1)`` (quadratic near 0)."""
    c2 = f_scale ** 2
    return 2.0 * c2 * (np.sqrt(1.0 + np.asarray(z) ** 2 / c2) - 1.0)


def solve_terms(terms: list[CostTerm], theta0: np.ndarray, x_scale: np.ndarray, f_scale: float = 2.5,
                max_nfev: int = 40):
    """Minimise the robust sum of all terms' whitened residuals from ``theta0``; scipy's trust region
    (``least_squares``, soft-L1, LSMR steps). Returns scipy's result (``x``, ``fun``, ``jac``, ``nfev``)."""
    return least_squares(lambda x: stack(terms, x, jac=False)[0], theta0, jac=lambda x: stack(terms, x)[1],
                         loss="soft_l1", f_scale=f_scale, x_scale=x_scale, max_nfev=max_nfev, tr_solver="lsmr")


def redundancy(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(1 - h_jj) (M,), C (n, n)`` of a whitened Jacobian (M, n): the redundancy of every residual (the
    share of its variance the parameters do not absorb) and ``C = (J^T J)^+``."""
    C = np.linalg.pinv(J.T @ J)
    h = np.sum((J @ C) * J, axis=1)
    return np.clip(1.0 - h, 0.0, 1.0), C


def update_terms(terms: list[CostTerm], theta: np.ndarray, J: np.ndarray) -> float:
    """Re-estimate every term's noise levels at ``theta`` (whitened Jacobian ``J`` there); returns the largest
    relative change of a level (log), to iterate until the weights settle."""
    red, _ = redundancy(J)
    change, k = 0.0, 0
    for t in terms:
        m = len(t.groups)
        if t.update is not None:
            new = np.asarray(t.update(t, t.residuals(theta), red[k:k + m]), dtype=np.float64)
            change = max(change, float(np.max(np.abs(np.log(new / t.sigma)))))
            t.sigma = new
        k += m
    return change
