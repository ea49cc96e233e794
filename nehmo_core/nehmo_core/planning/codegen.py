"""Generated C for CasADi functions, compiled with the system compiler once and cached on disk.

``compile_function(fn)`` writes ``fn``'s C code, compiles it into a shared library under
``$NEHMO_CACHE/casadi/`` and loads it with ``casadi.external``. The cache key hashes the
serialized function (graph and every weight), the CasADi version, the compiler and its flags, so
a new model or a new compiler never reuses a stale library. Without a working compiler the
function runs on CasADi's virtual machine instead (same numbers, slower); the returned
:class:`CompiledFunction` says which backend is in use.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from nehmo_core.errors import UnknownNameError
from nehmo_core.robots.loader import cache_dir

__all__ = ["BACKENDS", "CompiledFunction", "compile_function"]

BACKENDS = ("auto", "compiled", "vm")
"""``compiled``: generated C (raise if that fails); ``vm``: CasADi's virtual machine;
``auto``: compiled when a compiler works, else the VM with a warning."""

CFLAGS = ("-O3", "-fPIC", "-shared")
_CODEGEN_VERSION = "1"


@dataclass(frozen=True)
class CompiledFunction:
    """A CasADi function and the backend that evaluates it (``compiled`` or ``vm``)."""

    function: ca.Function
    backend: str
    library: Path | None = None


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def _key(fn: ca.Function, compiler: str) -> str:
    h = hashlib.sha256()
    for part in (fn.serialize(), ca.__version__, compiler, " ".join(CFLAGS), _CODEGEN_VERSION):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def _build(fn: ca.Function, compiler: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        source = f"{fn.name()}.c"
        cg = ca.CodeGenerator(source, {"with_header": False, "verbose": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        library = Path(tmp) / "lib.so"
        cmd = [compiler, *CFLAGS, str(Path(tmp) / source), "-o", str(library), "-lm"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        os.replace(library, target)  # atomic: concurrent builders never see a partial file


def compile_function(fn: ca.Function, backend: str = "auto") -> CompiledFunction:
    """Evaluate ``fn`` through cached generated C (``backend`` in :data:`BACKENDS`)."""
    if backend not in BACKENDS:
        raise UnknownNameError("backend", backend, BACKENDS)
    if backend == "vm":
        return CompiledFunction(fn, "vm")
    compiler = _compiler()
    try:
        if compiler is None:
            raise FileNotFoundError("no C compiler (gcc or cc) on PATH")
        target = cache_dir() / "casadi" / f"{fn.name()}_{_key(fn, compiler)}.so"
        if not target.exists():
            _build(fn, compiler, target)
        return CompiledFunction(ca.external(fn.name(), str(target)), "compiled", target)
    except (OSError, subprocess.CalledProcessError, RuntimeError) as exc:
        if backend == "compiled":
            raise
        detail = getattr(exc, "stderr", "") or str(exc)
        warnings.warn(
            f"compiling {fn.name()} failed ({detail.strip()[:200]}); using CasADi's VM",
            RuntimeWarning,
            stacklevel=2,
        )
        return CompiledFunction(fn, "vm")
