"""ARAIM: the multiple-hypothesis solution-separation monitor of the ARAIM Airborne Design Document.

A pure, batched library (docs/design/araim.md): :class:`AraimSettings` (the ISM and the risk allocation),
:class:`AraimRows` (the ranging rows of a batch of epochs), :func:`araim` (protection levels, EMT, σ_acc,
availability, the detection test) and :func:`araim_modes` (one epoch's fault-mode table). Beside the
ranging rows, landmark pixels (:mod:`.vision_rows`) and an inertial position prediction
(:func:`with_inertial_prediction`) enter as rows with fault events of their own (§11).
"""

from testbed.integrity.araim.core import (ARAIM_REASONS, AraimEpochs, AraimReason, AraimRows, ModeTable, araim,
                                          araim_modes)
from testbed.integrity.araim.inertia_rows import with_inertial_prediction
from testbed.integrity.araim.settings import SYSTEMS, AidFaultPrior, AraimSettings, ConstellationIsm, ism_preset

__all__ = ["ARAIM_REASONS", "SYSTEMS", "AidFaultPrior", "AraimEpochs", "AraimReason", "AraimRows", "AraimSettings",
           "ConstellationIsm", "ModeTable", "araim", "araim_modes", "ism_preset", "with_inertial_prediction"]
