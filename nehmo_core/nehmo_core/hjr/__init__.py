"""Neural Hamilton-Jacobi reachability: HJI systems, value networks, training, ground truth.

Time is time-to-go ``τ ∈ [0, T]``: ``V(0, x) = l(x)`` and ``∂V/∂τ − min(0, H) = 0`` (avoid tube).

- :mod:`.systems`: :class:`Air3D`, :class:`TwoLinkPair`, the generic :class:`ArmPairSystem`.
- :mod:`.networks`: SIREN value networks, variants ``deepreach | bc | bc+sym | exact`` and
  :class:`ValueFunction` (batched ``value(tau, x)`` / ``gradient(tau, x)``, symmetry applied).
- :mod:`.train_settings`: :class:`TrainSettings` and its presets; :mod:`.train`: the training
  loop; :mod:`.model_files`: checkpoints, shipped models, :func:`load_value_function`;
  :mod:`.train_cli`: the ``nehmo train`` command.
- :mod:`.ground_truth`: ``hj_reachability`` grid solutions (JAX, imported lazily) and
  :func:`validate`.
"""

from nehmo_core.hjr.ground_truth import GroundTruth, ValidationRow, ground_truth, validate
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.networks import VARIANTS, NetworkSettings, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import (
    Air3D,
    ArmPairSystem,
    HJISystem,
    JointInterval,
    TwoLinkPair,
    make_system,
    register_system,
)
from nehmo_core.hjr.train import train
from nehmo_core.hjr.train_settings import TrainSettings

__all__ = [
    "VARIANTS",
    "Air3D",
    "ArmPairSystem",
    "GroundTruth",
    "HJISystem",
    "JointInterval",
    "NetworkSettings",
    "TrainSettings",
    "TwoLinkPair",
    "ValidationRow",
    "ValueFunction",
    "ValueNetwork",
    "ground_truth",
    "load_value_function",
    "make_system",
    "register_system",
    "train",
    "validate",
]
