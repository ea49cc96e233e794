"""Per-arm planning: problem Opt with worst-case peers and a fail-safe, and the baselines."""
