"""The C backend: the numba kernel's functions translated to one self-contained C file."""
