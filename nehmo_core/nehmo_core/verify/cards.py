"""Certificates in model cards: where a shipped model's card is, how a certificate enters it.

A value function's card (the JSON beside its weights) keeps its certificates under
``card.certificates``: one entry per (τ, distribution, actuator model), the newest replacing an
older one. Each says which actuator model its rollouts assumed (``actuators``; an entry without
one was made with ideal tracking). The planner reads them back (:func:`certified_level`) to set
its margin ε.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.robots.loader import atomic_write
from nehmo_core.robots.registry import model_file
from nehmo_core.sim.actuators import certificate_actuators
from nehmo_core.verify.certify import Certificate

SUMMARY_KEYS = (
    "tau", "distribution", "delta", "samples", "violations", "epsilon", "confidence",
    "certified", "accepted_share", "wall_time_s", "command",
)  # fmt: skip


def shipped_card_path(name: str, variant: str | None = None) -> Path:
    """The card of a shipped value function (``value_<pair>_<variant>.json``)."""
    slug = (variant or "bc+sym").replace("+", "_")
    try:
        path = model_file(name, f"value_{name}_{slug}.json")
    except NehmoError:
        path = None
    if path is None or not path.exists():
        raise InvalidValueError(
            "--card", "needs a shipped model name (and variant)", f"{name} {variant}"
        )
    return path


def _summary(cert: Certificate) -> dict[str, Any]:
    data = cert.to_dict()
    out = {k: data[k] for k in SUMMARY_KEYS}
    out["distribution"] = {k: v for k, v in data["distribution"].items() if k != "sources"}
    s = data["settings"]
    out["alpha"], out["beta"] = s["alpha"], s["beta"]
    out["adversaries"], out["dt"], out["seed"] = s["adversaries"], s["dt"], s["seed"]
    out["actuators"] = s.get("actuator") or {"name": "ideal"}
    return out


def record_certificate(card_path: Path, cert: Certificate) -> None:
    """Add ``cert`` to ``card.certificates``, replacing one of the same τ, distribution and
    actuator model."""
    meta = json.loads(card_path.read_text())
    card = meta.setdefault("card", {})
    entry = _summary(cert)
    kept = [
        c
        for c in card.get("certificates", [])
        if not (
            abs(c["tau"] - cert.tau) < 1e-9
            and c["distribution"]["name"] == cert.distribution["name"]
            and certificate_actuators(c) == certificate_actuators(entry)
        )
    ]
    card["certificates"] = sorted(
        [*kept, entry],
        key=lambda c: (c["tau"], c["distribution"]["name"], certificate_actuators(c)),
    )
    atomic_write(card_path, json.dumps(meta, indent=2, sort_keys=True) + "\n")


def certified_level(
    card: dict[str, Any], tau: float, actuators: str = "ideal"
) -> tuple[float, list[dict[str, Any]]] | None:
    """The largest certified ``δ`` among a card's certificates at ``τ`` for actuator model
    ``actuators`` and those certificates.

    None when the card holds no such certificate. A certificate that failed its target still
    counts with its ``δ`` (the level tried last), so the planner never trusts less than it.
    """
    found = [
        c
        for c in card.get("certificates", [])
        if abs(c["tau"] - tau) < 1e-6 and certificate_actuators(c) == actuators
    ]
    if not found:
        return None
    return max(c["delta"] for c in found), found
