import os as _os

__version__ = "0.2.0"

# The station's linear algebra is small (at most a few hundred rows); OpenBLAS's threads only
# contend for the cores, most of all on a shared 2-core machine, where a 108x108 triangular
# inverse measured 20 ms threaded against 0.5 ms on one thread. Set before numpy loads (every
# fieldcal entry point imports this package first); an explicit setting in the environment wins.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")
del _name
