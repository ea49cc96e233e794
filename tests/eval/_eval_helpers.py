"""Shared by the evaluation tests: counting which episodes a runner really runs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


def record_calls(
    monkeypatch: pytest.MonkeyPatch, module: Any, name: str, key: Callable[..., Any]
) -> list[Any]:
    """Wrap ``module.name`` so that every call appends ``key(*args)`` to the returned list."""
    calls: list[Any] = []
    original = getattr(module, name)

    def recorded(*args: Any) -> Any:
        calls.append(key(*args))
        return original(*args)

    monkeypatch.setattr(module, name, recorded)
    return calls
