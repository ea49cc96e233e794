"""`recorder` node: writes the run's topics to a rosbag2-compatible MCAP log.

Placeholder: the node is not implemented yet. Running it prints a message and exits with status 2.
"""

import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `recorder` console script; `argv` is ignored for now."""
    del argv
    print("nehmo_ros recorder: not implemented yet; see the README's Limitations", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
