"""Shared by the evaluation tests: counting which episodes a runner really runs, and loading a
script of ``bench/`` as a module."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


def bench_module(name: str) -> Any:
    """``bench/<name>.py`` as a module (its sibling imports, such as ``_report``, resolved)."""
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCH))


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
