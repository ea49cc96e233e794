"""The paper's reported results (Tables II–IV), to print beside ours.

Keys are ``(setup, row)`` with rows written as for :func:`nehmo_core.eval.setups.parse_row`.
Times are per planning step [ms] (centralized planners: per plan), ``None`` where the paper
gives none ("-") or only a bound (``<1.0`` is kept as text in :data:`PAPER_NOTES`).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PAPER", "PAPER_NOTES", "TABLES", "PaperRow", "paper_row"]


@dataclass(frozen=True)
class PaperRow:
    """One row of the paper: SR and CR [%], planning time and MPL as (mean, std)."""

    label: str
    sr: float
    cr: float
    time_ms: tuple[float, float] | None = None
    mpl: tuple[float, float] | None = None


PAPER: dict[tuple[str, str], PaperRow] = {
    # Table II: dual UR5
    ("dual_ur5", "nehmo"): PaperRow("NeHMO", 92, 2, (36, 35), (8.5, 4.6)),
    ("dual_ur5", "nehmo_no_sym"): PaperRow("NeHMO (w/o Sym)", 90, 3, (35, 33), (8.3, 4.6)),
    ("dual_ur5", "opt_deepreach"): PaperRow("Opt + DeepReach", 66, 34, (16, 4.1), (6.2, 2.7)),
    ("dual_ur5", "chomp"): PaperRow("CHOMP", 86, 14, (570, 270), (6.7, 3.2)),
    ("dual_ur5", "naive"): PaperRow("Naive", 66, 34, None, (6.2, 2.7)),
    # Table III: three and five UR5
    ("triple_ur5", "nehmo"): PaperRow("NeHMO", 86, 5, (41, 43)),
    ("triple_ur5", "chomp"): PaperRow("CHOMP", 68, 32, (650, 300)),
    ("triple_ur5", "naive"): PaperRow("Naive", 59, 41),
    ("five_ur5", "nehmo"): PaperRow("NeHMO", 66, 8, (43, 52)),
    ("five_ur5", "chomp"): PaperRow("CHOMP", 32, 68, (1800, 1100)),
    ("five_ur5", "naive"): PaperRow("Naive", 38, 62),
    # Table IV: UR5-Kinova, challenging set (UR5 planner / Kinova planner)
    ("ur5_kinova_challenging", "naive/naive"): PaperRow("Naive / Naive", 0, 100),
    ("ur5_kinova_challenging", "nehmo/nehmo"): PaperRow("NeHMO / NeHMO", 79, 6, (46, 46)),
    ("ur5_kinova_challenging", "nehmo/reckless"): PaperRow("NeHMO / Naive", 47, 39, (41, 75)),
}

# The paper's NeHMO is our nehmo_paper (no self-clearance rows); ``nehmo`` adds them.
for (_setup, _row), _paper in list(PAPER.items()):
    if "nehmo" in _row.split("/"):
        PAPER[(_setup, _row.replace("nehmo", "nehmo_paper"))] = _paper

PAPER_NOTES: dict[tuple[str, str], str] = {
    ("dual_ur5", "naive"): "time < 1.0 ms",
    ("triple_ur5", "naive"): "time < 1.0 ms",
    ("five_ur5", "naive"): "time < 1.0 ms",
    ("dual_ur5", "ha_et_al"): "Ha et al. (RL): SR 79, CR 13, < 1.0 ms, MPL 4.7 ± 1.3; not run",
}

TABLES: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    # table id: ((setup, rows), ...); rows beyond the paper's are extras (OMPL)
    # nehmo_paper: the paper's Opt exactly (no self-clearance rows)
    "II": (
        (
            "dual_ur5",
            ("nehmo", "nehmo_paper", "nehmo_no_sym", "opt_deepreach", "chomp", "naive", "ompl"),
        ),
    ),
    "III": (
        ("triple_ur5", ("nehmo", "nehmo_paper", "chomp", "naive")),
        ("five_ur5", ("nehmo", "nehmo_paper", "chomp", "naive")),
    ),
    "IV": (
        (
            "ur5_kinova_challenging",
            (
                "naive/naive",
                "nehmo/nehmo",
                "nehmo_paper/nehmo_paper",
                "nehmo/reckless",
                "nehmo_paper/reckless",
            ),
        ),
    ),
}


def paper_row(setup: str, row: str) -> PaperRow | None:
    """The paper's numbers for ``row`` on ``setup``, or None (a row the paper does not have)."""
    return PAPER.get((setup, row))
