"""Neural Hamilton-Jacobi reachability: HJI systems, value networks, training, ground truth."""
