"""The paper's Table I, for the side-by-side report.

Columns: Quality (best epsilon over all trials), ETA (s, mean time to a valid grasp of the learned
planner), Nodes (mean), MSE (mm^2, fingertip error of the direct transformation tau_r), ETA_0 (s, the
baseline RRT) with its success rate. ``None`` is the paper's dash; an ETA_0 printed without a rate is
taken as 100 % success, "0%" as no success (ETA_0 ``None``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PaperRow", "PAPER_TABLE1", "ROWS"]


@dataclass(frozen=True)
class PaperRow:
    row: str
    label: str
    quality: float
    eta_s: float
    nodes: int
    mse_mm2: float | None
    eta0_s: float | None
    eta0_success: float


PAPER_TABLE1: dict[str, PaperRow] = {
    r.row: r
    for r in [
        PaperRow("ham", "Ham", 0.25, 1.3, 774, 6.5**2, None, 0.0),
        PaperRow("jam", "Jam", 0.24, 0.65, 817, 8.7**2, 2.1, 1.0),
        PaperRow("chips", "Chips", 0.17, 1.5, 469, 13.4**2, 3.2, 0.04),
        PaperRow("salt", "Salt", 0.12, 1.29, 972, 13.8**2, 8.3, 0.53),
        PaperRow("small_cup", "Small cup", 0.19, 1.8, 636, 7.6**2, 9.0, 0.65),
        PaperRow("bottle", "Bottle", 0.07, 3.0, 530, None, None, 0.0),
        PaperRow("big_cup", "Big cup", 0.12, 2.0, 813, None, 1.5, 0.45),
        PaperRow("ham_arc", "Ham (arc, obstacles)", 0.25, 6.1, 502, None, None, 0.0),
        PaperRow("chips_between_cans", "3 Chips (obstacles)", 0.08, 6.9, 207, None, None, 0.0),
        PaperRow("chips_flat", "Chips flat (obstacles)", 0.08, 5.6, 179, None, None, 0.0),
        PaperRow("jam_hole", "Jam in a hole (obstacles)", 0.13, 3.2, 290, None, 2.3, 0.78),
    ]
}

ROWS: tuple[str, ...] = tuple(PAPER_TABLE1)
