"""Value-function files: checkpoints and models (safetensors + JSON), shipped models, loading.

Files in a run directory: ``checkpoint.safetensors`` + ``checkpoint.json`` (network and Adam
state, schedule position), ``model.safetensors`` + ``model.json`` (the final network). Loading
never unpickles: tensors come from safetensors, the rest from JSON.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

import nehmo_core
from nehmo_core.errors import (
    InvalidValueError,
    ModelFileError,
    UnknownNameError,
)
from nehmo_core.hjr.networks import ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import HJISystem, make_system
from nehmo_core.hjr.train_settings import Schedule, TrainSettings
from nehmo_core.robots.registry import OPTIONAL, SHIPPED, model_file, value_variants

__all__ = [
    "CHECKPOINT",
    "MODEL",
    "OPTIONAL_VALUE_FUNCTIONS",
    "SHIPPED_VALUE_FUNCTIONS",
    "load_value_function",
    "shipped_value_path",
]

FORMAT = "nehmo-hjr"
FORMAT_VERSION = 1
CHECKPOINT = "checkpoint"
MODEL = "model"


def _sidecar(
    kind: str,
    system: HJISystem,
    settings: TrainSettings,
    step: int,
    schedule: Schedule,
    wall_seconds: float,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "nehmo_version": nehmo_core.__version__,
        "torch_version": torch.__version__,
        "system": system.describe(),
        "variant": settings.variant,
        "settings": settings.to_dict(),
        "step": step,
        "total_steps": schedule.total_steps,
        "samples": schedule.samples_before(step),
        "wall_seconds": wall_seconds,
        "complete": step >= schedule.total_steps,
    }


def _write_atomic(path: Path, write: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _save(
    out_dir: Path,
    stem: str,
    tensors: dict[str, Tensor],
    meta: dict[str, Any],
) -> None:
    from safetensors.torch import save_file

    tensors = {k: v.detach().cpu().clone().contiguous() for k, v in tensors.items()}
    _write_atomic(out_dir / f"{stem}.safetensors", lambda p: save_file(tensors, str(p)))
    text = json.dumps(meta, indent=2, sort_keys=True)
    _write_atomic(out_dir / f"{stem}.json", lambda p: p.write_text(text + "\n"))


def _checkpoint_tensors(network: ValueNetwork, optimizer: torch.optim.Optimizer) -> dict:
    tensors = {f"model.{k}": v for k, v in network.state_dict().items()}
    for index, state in optimizer.state_dict()["state"].items():
        for name, value in state.items():
            tensors[f"optim.{index}.{name}"] = torch.as_tensor(value)
    return tensors


def _read_sidecar(path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ModelFileError(f"missing model sidecar {path}") from exc
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"model sidecar {path} is not valid JSON: {exc}") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ModelFileError(f"{path} is not a {FORMAT} sidecar")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(
            f"{path} has format_version {meta.get('format_version')}; expected {FORMAT_VERSION}"
        )
    return meta


def _read_tensors(path: Path) -> dict[str, Tensor]:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        return load_file(str(path))
    except FileNotFoundError as exc:
        raise ModelFileError(f"missing weights file {path}") from exc
    except (SafetensorError, OSError) as exc:
        raise ModelFileError(f"cannot read weights file {path}: {exc}") from exc


def _strip_prefix(tensors: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    return {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}


def _value_file(name: str, variant: str) -> Path:
    return model_file(name, f"value_{name}_{variant.replace('+', '_')}.safetensors")


OPTIONAL_VALUE_FUNCTIONS: dict[str, tuple[str, ...]] = value_variants(OPTIONAL)
"""Value functions (system: variants) whose code path exists but whose weights this repository
does not ship: a variant counts as shipped once its files (``model.safetensors`` and
``model.json`` of a ``nehmo train`` run, copied to :func:`shipped_value_path`) are in
``models/``. The pose-conditioned UR5-Kinova pair, from either arm's side."""
SHIPPED_VALUE_FUNCTIONS: dict[str, tuple[str, ...]] = {
    **value_variants(SHIPPED),
    **{
        name: present
        for name, variants in OPTIONAL_VALUE_FUNCTIONS.items()
        if (present := tuple(v for v in variants if _value_file(name, v).exists()))
    },
}
"""Value functions in ``models/`` (system: variants; the optional ones as found at import; both
lists come from :data:`~nehmo_core.robots.registry.ARM_PAIRS`)."""


def shipped_value_path(name: str, variant: str = "bc+sym") -> Path:
    """File of a shipped value function: ``models/value_<pair>_<variant>.safetensors``.

    Also the place of an optional one (:data:`OPTIONAL_VALUE_FUNCTIONS`) not trained yet.
    """
    known = {**OPTIONAL_VALUE_FUNCTIONS, **SHIPPED_VALUE_FUNCTIONS}
    if name not in known:
        raise UnknownNameError("shipped value function", name, known)
    variants = tuple(dict.fromkeys([*known[name], *OPTIONAL_VALUE_FUNCTIONS.get(name, ())]))
    if variant not in variants:
        raise UnknownNameError(f"variant shipped for {name}", variant, variants)
    return _value_file(name, variant)


def load_value_function(
    path: str | Path, system: HJISystem | None = None, variant: str | None = None
) -> ValueFunction:
    """Load a trained value function: a shipped one by name, a run directory or a file.

    ``load_value_function("ur5_ur5", variant="bc+sym")`` loads a shipped model (variants per
    :data:`SHIPPED_VALUE_FUNCTIONS`). A directory loads its ``model.safetensors`` (or, for an
    unfinished run, its checkpoint). ``system`` must be given for systems that are not
    registered by name; when given, its name must match the file's. Never unpickles.
    """
    if isinstance(path, str) and path in SHIPPED_VALUE_FUNCTIONS:
        path = shipped_value_path(path, variant or "bc+sym")
    elif isinstance(path, str) and path in OPTIONAL_VALUE_FUNCTIONS:
        file = shipped_value_path(path, variant or "bc+sym")
        if not file.exists():
            raise ModelFileError(
                f"the {variant or 'bc+sym'} value function of {path!r} is not shipped and not "
                f"trained yet ({file} is missing): train it with 'nehmo train --system {path} "
                f"--variant {variant or 'bc+sym'} --out RUN' and copy RUN/model.safetensors and "
                f"RUN/model.json to {file.name} and {file.with_suffix('.json').name} there"
            )
        path = file
    elif isinstance(path, str) and "/" not in path and not Path(path).exists():
        raise UnknownNameError("shipped value function", path, SHIPPED_VALUE_FUNCTIONS)
    elif variant is not None:
        raise InvalidValueError("variant", "is only used with a shipped model name", variant)
    path = Path(path)
    if path.is_dir():
        model = path / f"{MODEL}.safetensors"
        path = model if model.exists() else path / f"{CHECKPOINT}.safetensors"
    if path.suffix != ".safetensors":
        raise ModelFileError(f"expected a run directory or a .safetensors file; got {path}")
    meta = _read_sidecar(path.with_suffix(".json"))
    name = meta["system"]["name"]
    if system is None:
        system = make_system(name)
    elif system.name != name:
        raise ModelFileError(f"{path} was trained for system {name!r}, not {system.name!r}")
    settings = TrainSettings.from_dict(meta["settings"])
    network = ValueNetwork(system, settings.variant, settings.network)
    tensors = _read_tensors(path)
    if meta["kind"] == CHECKPOINT:
        tensors = _strip_prefix(tensors, "model.")
    try:
        network.load_state_dict(tensors)
    except RuntimeError as exc:
        raise ModelFileError(f"weights in {path} do not fit the network: {exc}") from exc
    network.cap_residual = bool(meta.get("card", {}).get("cap_residual", False))
    value_function = ValueFunction(network)
    value_function.card = dict(meta.get("card", {}))
    return value_function
