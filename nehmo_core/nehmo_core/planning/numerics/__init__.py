"""Numerics under problem Opt: the small QP step and the C code generated for value functions."""
