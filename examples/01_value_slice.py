"""Load a shipped value function and plot a 2-D slice of it to a PNG.

    ./run python examples/01_value_slice.py --out value_slice.png

The slice varies the first joint of each arm of the ``ur5_ur5`` pair (bases 0.6 m apart, facing
each other) and keeps every other joint at ``--joints`` [rad]. The contour ``V = 0`` bounds the
states from which the other arm can force a collision within the time-to-go ``--tau`` [s].
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from nehmo_core.hjr import load_value_function


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pair", default="ur5_ur5", help="shipped pair model")
    parser.add_argument("--variant", default="bc+sym", help="bc+sym | bc | deepreach")
    parser.add_argument("--tau", type=float, default=0.6, help="time-to-go [s]")
    parser.add_argument("--joints", type=float, default=0.0, help="the other joints [rad]")
    parser.add_argument("--resolution", type=int, default=101, help="grid points per axis")
    parser.add_argument("--out", default="value_slice.png", help="PNG file to write")
    args = parser.parse_args()

    vf = load_value_function(args.pair, variant=args.variant)
    n = vf.system.state_dim  # (q¹, q²): both arms' joints
    q = np.linspace(-np.pi, np.pi, args.resolution)
    q1a, q1b = np.meshgrid(q, q, indexing="xy")
    x = np.full((q1a.size, n), args.joints)  # (B, n)
    x[:, 0] = q1a.ravel()  # joint 1 of arm 1
    x[:, n // 2] = q1b.ravel()  # joint 1 of arm 2
    v = np.asarray(vf.value(np.full(len(x), args.tau), x)).reshape(q1a.shape)  # [m]

    fig, ax = plt.subplots(figsize=(5, 4))
    mesh = ax.pcolormesh(q1a, q1b, v, shading="auto", cmap="RdBu")
    ax.contour(q1a, q1b, v, levels=[0.0], colors="k")
    fig.colorbar(mesh, ax=ax, label="V [m]")
    ax.set_xlabel("arm 1, joint 1 [rad]")
    ax.set_ylabel("arm 2, joint 1 [rad]")
    ax.set_title(f"{args.pair} {args.variant}, τ = {args.tau} s")
    out = Path(args.out)
    fig.savefig(out, dpi=100, bbox_inches="tight")
    print(f"V in [{v.min():.3f}, {v.max():.3f}] m; unsafe share {np.mean(v <= 0):.2f}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
