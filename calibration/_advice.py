"""What the calibration's uncertainty means for the two-arm tasks: a warning when the second base is placed
too loosely for a hand-over, with what to change in the capture.

A hand-over needs the two grippers to meet within a few millimetres, and the only thing that places the
secondary's gripper relative to the primary's is ``T_b1_b2``. Over 336 studied task-bench scenes (4-12 views
per arm; docs/calibration.md, "A warning when the second base is too loose for a hand-over"), pipeline hand-overs held in the true world 239 of 289 times (83 %)
where the calibration reported a ``T_b1_b2`` translation sigma under 5 mm, and 30 of 47 times (64 %) above it.
On fresh scenes the split is weaker (docs/calibration.md): the warning states the uncertainty and its fix; it
is not a prediction of the outcome.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: 1-sigma of ``T_b1_b2``'s translation (mm) above which the calibration warns that hand-overs may miss
HANDOVER_SIGMA_MM = 5.0


def base_to_base_advice(uncertainty: Mapping | None) -> str | None:
    """The warning for a second base placed more loosely than a hand-over needs, or None.

    Args:
        uncertainty: ``CalibrationResult.uncertainty`` / calibration.json ``uncertainty`` (its ``T_b1_b2``
            ``translation_norm_mm``, 1 sigma; ``inf`` when the views do not determine it). Missing: None.
    """
    sigma = (uncertainty or {}).get("T_b1_b2", {}).get("translation_norm_mm")
    if sigma is None or not float(sigma) > HANDOVER_SIGMA_MM:
        return None
    told = "is not determined by these views" if not np.isfinite(float(sigma)) else f"is known to +-{float(sigma):.0f} mm"
    return (f"the second base (T_b1_b2) {told} (1 sigma), more than the {HANDOVER_SIGMA_MM:g} mm a hand-over can "
            "take: the grippers must meet within a few millimetres -> fix: capture more views per arm (8 or more), "
            "turned 20-40 deg about different axes, with both arms' cameras seeing the same objects")
