"""The edges: Hydra entry points (sysid-run, sysid-diagnose, sysid-report), results files, recordings."""

import os

# The harness's matrices are small (tens of columns): a threaded BLAS only oversubscribes the cores that
# sweeps and test workers already use (a 7-DoF design took 3x longer with two BLAS threads on two cores).
# Set before numpy is first imported by an entry point; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
