"""The peers a certificate is earned against: disturbance strategies within the box ``d̄``.

A rollout counts as a violation when *any* of the strategies makes contact, so the set acts as
one adversary that picks the best of them for each state. Strategies (names for ``--adversaries``):

- ``learned``: the learned worst case ``d = argmin_d <∇V(τ−t, x), g>`` (for arms
  ``−d̄·sign(∂V/∂q²)``), re-evaluated every step: the game the value function was trained for.
- ``pursuit``: ``argmin_d <∇l(x), g>``, closing the boundary function ``l`` greedily
  (for arms the learned distance: the peer heads for the nearest approach).
- ``corner+`` / ``corner-``: every disturbance component at its upper / lower bound throughout.
- ``corners``: four box corners drawn at random per state, each held constant.
- ``switching``: a strategy that draws a new random corner every 0.1 s.

The default set (:data:`DEFAULT_ADVERSARIES`) leaves out ``corners``, which never found a
violation that another strategy missed in the trial runs and costs four rollouts per state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.systems import HJISystem

DisturbanceFn = Callable[[int, Tensor, Tensor], Tensor]
"""``(step, x (B, n), ∇V (B, n)) -> d (B, k)``."""

ADVERSARIES = ("learned", "pursuit", "corner+", "corner-", "corners", "switching")
SWITCH_PERIOD = 0.1  # [s], how long a switching strategy holds a corner
RANDOM_CORNERS = 4
SWITCHING = 1
DEFAULT_ADVERSARIES = ("learned", "pursuit", "corner+", "corner-", "switching")


@dataclass
class Adversary:
    """One disturbance strategy, ready for a batch of ``batch`` rollouts."""

    name: str
    disturbance: DisturbanceFn = field(repr=False)


def check_adversaries(names: tuple[str, ...]) -> None:
    """Raise unless ``names`` is a non-empty list of known strategy names."""
    if not names:
        raise InvalidValueError(
            "adversaries", f"must name at least one of {list(ADVERSARIES)}", names
        )
    for name in names:
        if name not in ADVERSARIES:
            raise InvalidValueError("adversaries", f"must each be one of {list(ADVERSARIES)}", name)


def _bounds(system: HJISystem, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    lo, hi = system.disturbance_bounds
    return torch.as_tensor(lo, dtype=dtype), torch.as_tensor(hi, dtype=dtype)


def _random_corners(rng: np.random.Generator, batch: int, lo: Tensor, hi: Tensor) -> Tensor:
    pick = torch.as_tensor(rng.integers(0, 2, size=(batch, lo.shape[0])), dtype=torch.bool)
    return torch.where(pick, hi, lo)


def _boundary_gradient(system: HJISystem, x: Tensor) -> Tensor:
    xg = x.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        (grad,) = torch.autograd.grad(system.boundary(xg).sum(), xg)
    return grad


def _constant(d: Tensor) -> DisturbanceFn:
    return lambda step, x, grad: d


def _switching(table: list[Tensor], hold: int) -> DisturbanceFn:
    return lambda step, x, grad: table[(step // hold) % len(table)]


def make_adversaries(
    system: HJISystem,
    names: tuple[str, ...],
    batch: int,
    dt: float,
    rng: np.random.Generator,
    dtype: torch.dtype = torch.float32,
) -> list[Adversary]:
    """The strategies ``names`` for ``batch`` rollouts of step ``dt`` [s]; seeded by ``rng``."""
    check_adversaries(names)
    lo, hi = _bounds(system, dtype)
    out: list[Adversary] = []
    for name in names:
        if name == "learned":
            out.append(Adversary(name, lambda s, x, g: system.worst_disturbance(x, g)))
        elif name == "pursuit":
            out.append(
                Adversary(
                    name, lambda s, x, g: system.worst_disturbance(x, _boundary_gradient(system, x))
                )
            )
        elif name in ("corner+", "corner-"):
            fixed = (hi if name == "corner+" else lo).expand(batch, -1)
            out.append(Adversary(name, _constant(fixed)))
        elif name == "corners":
            for i in range(RANDOM_CORNERS):
                fixed = _random_corners(rng, batch, lo, hi)
                out.append(Adversary(f"corners[{i}]", _constant(fixed)))
        else:
            hold = max(1, round(SWITCH_PERIOD / dt))
            for i in range(SWITCHING):
                table = [_random_corners(rng, batch, lo, hi) for _ in range(64)]
                out.append(Adversary(f"switching[{i}]", _switching(table, hold)))
    return out
