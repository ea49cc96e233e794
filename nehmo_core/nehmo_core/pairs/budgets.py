"""How much data and training a pair build spends: ``standard`` and ``tiny``."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BUDGETS", "Budget"]


@dataclass(frozen=True)
class Budget:
    """How much data and training a build spends (``standard``: the shipped models' scale)."""

    uniform: int
    boundary: int
    test: int  # held-out samples (half uniform, half boundary)
    calibration: int  # calibration samples (half uniform, half boundary)
    hidden: str
    epochs: int
    value_samples: str
    value_preset: str
    value_gradient_weight: float  # ``nehmo train --gradient-weight``: no ripples for a value
    certificate_samples: int
    alpha: float  # the certificates' target violation probability (β = 1e-3)
    search_samples: int
    falsify_samples: int
    mirror_samples: int
    reach_samples: int
    visit_episodes: int  # planner episodes per cell of the visit stage


BUDGETS: dict[str, Budget] = {
    "standard": Budget(
        uniform=400_000,
        boundary=800_000,
        test=60_000,
        calibration=80_000,
        hidden="256,256,256",
        epochs=40,
        # 40M samples gamed the Hamiltonian (docs/value-functions.md, "Ripples"); 10M learned it
        value_samples="10M",
        value_preset="cpu_12d",
        value_gradient_weight=1.0,
        certificate_samples=3000,
        alpha=0.01,
        search_samples=500,
        falsify_samples=3000,
        mirror_samples=2000,
        reach_samples=4000,
        visit_episodes=30,
    ),
    # The pipeline end to end in minutes (tests, trying a robot): models too small to plan with.
    "tiny": Budget(
        uniform=3000,
        boundary=3000,
        test=1000,
        calibration=2000,
        hidden="32,32",
        epochs=1,
        value_samples="20k",
        value_preset="cpu",
        value_gradient_weight=1.0,
        certificate_samples=60,
        alpha=0.2,
        search_samples=30,
        falsify_samples=40,
        mirror_samples=100,
        reach_samples=200,
        visit_episodes=1,
    ),
}
