"""`orchestrate` script: starts N arms and evaluates the runs from their logs.

Placeholder: the script is not implemented yet. Running it prints a message and exits with status 2.
"""

import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `orchestrate` console script; `argv` is ignored for now."""
    del argv
    print(
        "nehmo_ros orchestrate: not implemented yet; see the README's Limitations", file=sys.stderr
    )
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
