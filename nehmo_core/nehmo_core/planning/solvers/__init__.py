"""Solvers of problem Opt: the active-set SQP (Python and C loops) and IPOPT, the reference."""
