"""Training settings of a value network: :class:`TrainSettings`, named presets, the schedule.

:class:`Schedule` turns a settings' sample budget into step counts (pretraining, curriculum);
the training loop itself is :mod:`.train`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from nehmo_core.errors import (
    InvalidValueError,
    UnknownNameError,
)
from nehmo_core.hjr.networks import NetworkSettings, check_variant

__all__ = ["DIRICHLET_LOSSES", "LR_SCHEDULES", "PRESETS", "Schedule", "TrainSettings"]

LR_SCHEDULES = ("constant", "cosine", "exponential")
DIRICHLET_LOSSES = ("l1", "l2")


@dataclass(frozen=True)
class TrainSettings:
    """Everything that defines a training run (stored in every checkpoint's JSON sidecar).

    Presets: :meth:`preset` ``"cpu"`` (3×64, batch 500, Adam 3e-4 cosine-decayed, tuned for
    one CPU thread), ``"cpu_12d"`` (``cpu`` at 3×128, batch 2000, squared Dirichlet term: for
    the 12-D arm pairs), ``"cpu_legacy"`` (the dataclass defaults: 3×128, batch 10k, constant
    1e-4) and ``"authors"`` (3×512, 65k batch, lr 2e-5, the authors' proportions).

    ``dirichlet_loss``: ``"l1"`` is DeepReach's ``|W − l̂|`` at ``τ = 0``; ``"l2"`` its square.
    With ``l1`` and the ``bc`` variants, the 12-D arm pairs never leave the trivial ``NN ≡ 0``
    (``V = l``, see :mod:`nehmo_core.hjr.diagnostics`): the absolute value's constant slope at
    zero pins the residual network there, at any weight we tried. The square's slope vanishes
    at zero, so small boundary errors cost little and the PDE term can shape the network.

    ``pde_loss``: ``"l1"`` is DeepReach's ``mean |∂W/∂τ − min(0, H)|``; ``"l2"`` its square.
    Where fewer than half of the states must fall (``H(x, ∇l) < 0``), the absolute value pulls
    every state's slope in ``τ`` toward the median of the targets, 0, with the same force, and a
    network that does not yet tell the falling states apart stays at ``NN ≡ 0`` (the Panda's game
    against a Kinova: 41 % of states). The square's pull vanishes at 0 (``pairs.value_stage``
    retries such a game with it).

    ``gradient_weight``: the L1 Hamiltonian ``ū‖∇_{q¹}W‖₁ − d̄‖∇_{q²}W‖₁`` rewards any gradient
    in the own joints, so a residual network can meet the PDE without learning the value: sine
    ripples of a few millimetres with steep own-joint slopes make ``H ≥ 0`` almost everywhere, and
    ``∂W/∂τ = 0`` then has no residual. The Panda pairs' first value networks did exactly that
    (``‖∇_{q¹}NN‖₁`` ten times the boundary's, ``V(T) = l``). The term ``gradient_weight·mean
    max(0, ‖∇ₓNN‖₁ − ‖∇ₓl̂‖₁)`` makes such slopes cost more than they save and leaves a value's
    own slope free (an L1 penalty on all of it held the Panda network at ``NN = 0``, as the L1
    Dirichlet term does); :mod:`nehmo_core.hjr.diagnostics` measures both.
    """

    variant: str = "bc+sym"
    network: NetworkSettings = field(default_factory=NetworkSettings)
    samples: int = 40_000_000  # total states drawn, pretraining included
    batch_size: int = 10_000
    boundary_fraction: float = 10 / 65  # share of each curriculum batch forced to τ = 0
    pretrain_fraction: float = 1 / 12  # share of the steps spent at τ = 0
    curriculum_fraction: float = 0.9  # share of the remaining steps over which τ_max grows to T
    learning_rate: float = 1e-4  # initial Adam rate
    lr_schedule: str = "constant"  # one of LR_SCHEDULES
    lr_final_fraction: float = 0.01  # last step's rate / learning_rate (cosine, exponential)
    dirichlet_weight: float = 40.0
    dirichlet_loss: str = "l1"  # one of DIRICHLET_LOSSES
    pde_weight: float = 1.0
    pde_loss: str = "l1"  # one of DIRICHLET_LOSSES: mean |r| or mean r² of the PDE residual
    # weight of the mean excess of ‖∇ₓNN‖₁ over ‖∇ₓl̂‖₁ (bc variants): keeps the residual network
    # from meeting the PDE with ripples instead of a value (see the class docstring)
    gradient_weight: float = 0.0
    seed: int = 0
    checkpoint_every: int = 2_000_000  # [samples]
    log_every: int = 10  # [steps]

    def __post_init__(self) -> None:
        check_variant(self.variant)
        positive = ("samples", "batch_size", "learning_rate", "checkpoint_every", "log_every")
        for name in positive:
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        for name in ("boundary_fraction", "pretrain_fraction"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InvalidValueError(name, "must lie in [0, 1)", getattr(self, name))
        if not 0.0 < self.curriculum_fraction <= 1.0:
            raise InvalidValueError(
                "curriculum_fraction", "must lie in (0, 1]", self.curriculum_fraction
            )
        if self.dirichlet_loss not in DIRICHLET_LOSSES:
            raise UnknownNameError("Dirichlet loss", self.dirichlet_loss, DIRICHLET_LOSSES)
        if self.pde_loss not in DIRICHLET_LOSSES:
            raise UnknownNameError("PDE loss", self.pde_loss, DIRICHLET_LOSSES)
        if self.lr_schedule not in LR_SCHEDULES:
            raise UnknownNameError("learning-rate schedule", self.lr_schedule, LR_SCHEDULES)
        if not 0.0 < self.lr_final_fraction <= 1.0:
            raise InvalidValueError(
                "lr_final_fraction", "must lie in (0, 1]", self.lr_final_fraction
            )
        for name in ("dirichlet_weight", "pde_weight", "gradient_weight"):
            if not getattr(self, name) >= 0:
                raise InvalidValueError(name, "must be >= 0", getattr(self, name))

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> TrainSettings:
        """A named preset with optional field overrides."""
        if name not in PRESETS:
            raise UnknownNameError("preset", name, PRESETS)
        return replace(PRESETS[name], **overrides)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def learning_rate_at(self, step: int, total_steps: int) -> float:
        """Adam rate for ``step`` of ``total_steps`` (``lr_schedule``; a pure function)."""
        if self.lr_schedule == "constant" or total_steps <= 1:
            return self.learning_rate
        progress = min(1.0, step / (total_steps - 1))
        if self.lr_schedule == "cosine":
            share = self.lr_final_fraction + (1.0 - self.lr_final_fraction) * 0.5 * (
                1.0 + math.cos(math.pi * progress)
            )
        elif self.lr_schedule == "exponential":
            share = self.lr_final_fraction**progress
        else:
            raise UnknownNameError("learning-rate schedule", self.lr_schedule, LR_SCHEDULES)
        return self.learning_rate * share

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainSettings:
        values = dict(data)
        values["network"] = NetworkSettings(**values.get("network", {}))
        return cls(**values)


# Tuned on Air3D for one CPU thread (bench/results/hjr_tuning.md): a small SIREN and many small
# steps with a cosine-decayed rate beat a wide network and few large steps at the same sample
# budget; most of the time budget goes to the full horizon.
_CPU = TrainSettings(
    network=NetworkSettings(width=64, hidden_layers=3),
    batch_size=500,
    learning_rate=3e-4,
    lr_schedule="cosine",
    lr_final_fraction=0.01,
    pretrain_fraction=0.02,
    curriculum_fraction=0.5,
)

PRESETS: dict[str, TrainSettings] = {
    "cpu": _CPU,
    # The 12-D arm pairs: "cpu" with the width and batch of the shipped models and the squared
    # Dirichlet term, without which their bc / bc+sym networks stay at V = l (hjr_tuning.md).
    "cpu_12d": replace(
        _CPU,
        network=NetworkSettings(width=128, hidden_layers=3),
        batch_size=2000,
        dirichlet_loss="l2",
    ),
    # The first CPU defaults (3×128, batch 10k, constant 1e-4): resumes runs started with them.
    "cpu_legacy": TrainSettings(),
    "authors": TrainSettings(
        network=NetworkSettings(width=512, hidden_layers=3, input_scaling="raw"),
        batch_size=65_000,
        learning_rate=2e-5,
        curriculum_fraction=1.0,
    ),
}


@dataclass(frozen=True)
class Schedule:
    """Step counts derived from the settings."""

    total_steps: int
    pretrain_steps: int
    curriculum_steps: int
    samples: int
    batch_size: int

    @classmethod
    def from_settings(cls, settings: TrainSettings) -> Schedule:
        total = math.ceil(settings.samples / settings.batch_size)
        # The exact variant meets the boundary by construction: pretraining would teach nothing.
        pretrain = 0 if settings.variant == "exact" else round(settings.pretrain_fraction * total)
        curriculum = max(1, round(settings.curriculum_fraction * (total - pretrain)))
        return cls(total, pretrain, curriculum, settings.samples, settings.batch_size)

    def batch_size_at(self, step: int) -> int:
        """States drawn at ``step`` (the last step takes what is left of the budget)."""
        return min(self.batch_size, self.samples - step * self.batch_size)

    def samples_before(self, step: int) -> int:
        return min(self.samples, step * self.batch_size)

    def tau_max(self, step: int, horizon: float) -> float:
        """Upper end of the sampled time-to-go at ``step`` [s]; 0 while pretraining."""
        if step < self.pretrain_steps:
            return 0.0
        return horizon * min(1.0, (step - self.pretrain_steps + 1) / self.curriculum_steps)
