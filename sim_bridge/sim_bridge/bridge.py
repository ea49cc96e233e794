"""`sim_bridge` node: simulates the cell's arms in PyBullet and bridges them to ROS 2 topics.

Placeholder: the node is not implemented yet. Running it prints a message and exits with status 2.
"""

import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `sim_bridge` console script; `argv` is ignored for now."""
    del argv
    print("sim_bridge bridge: not implemented yet; see the README's Limitations", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
