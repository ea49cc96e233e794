#!/usr/bin/env bash
# Lint, format check, type check, then the test suite. Run through ./run test.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
echo "== ruff check"; ruff check .
echo "== ruff format --check"; ruff format --check .
echo "== mypy"; mypy
echo "== pytest"; exec pytest "$@"
