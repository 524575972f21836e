"""The numeric environment a run solved in, and how a replay compares its parameter file.

Byte-identical replay is a promise of the same environment: another numpy, scipy or BLAS build,
or another processor (OpenBLAS picks its kernels per processor), sums in another order and moves
the last digits. The session records the environment at its start; a replay in the same one
compares the parameter files byte for byte, elsewhere every parameter within
``TOLERANCE_SIGMA`` of its recorded 1σ, and says which comparison it made.
"""
from __future__ import annotations

import os
import platform
from dataclasses import dataclass

import numpy as np

TOLERANCE_SIGMA = 1e-3


def numeric_environment() -> dict:
    """numpy, scipy and BLAS versions, the BLAS kernel when known, the processor architecture."""
    import scipy

    from fieldcal import __version__

    # fieldcal's own version too: a change in how the solvers search moves the last digits as
    # surely as another BLAS does
    env = {"fieldcal": __version__, "numpy": np.__version__, "scipy": scipy.__version__,
           "blas": _blas(), "machine": platform.machine()}
    kernel = _blas_kernel()
    if kernel:
        env["blas_kernel"] = kernel
    return env


def _blas() -> str:
    try:
        blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name', '?')} {blas.get('version', '?')}"
    except Exception:  # noqa: BLE001 -- a numpy without build information
        return "unknown"


def _blas_kernel() -> str:
    """The kernel the BLAS runs (threadpoolctl, when installed), or the one forced by the environment."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return os.environ.get("OPENBLAS_CORETYPE", "")
    kernels = sorted({str(i.get("architecture")) for i in threadpool_info() if i.get("user_api") == "blas"})
    return ",".join(kernels) or os.environ.get("OPENBLAS_CORETYPE", "")


@dataclass(frozen=True)
class Comparison:
    identical: bool
    text: str  # which comparison was made, and its verdict, for the operator


def compare_parameters(replayed, recorded_bytes: bytes, recorded_environment: dict | None) -> Comparison:
    """The replayed parameter file against the recorded one's bytes."""
    from fieldcal.paramfile import dump, loads

    if b"bias_at_end:" not in recorded_bytes:  # a run before the end-of-calibration bias was solved
        replayed = _without_bias_at_end(replayed)
    same_bytes = dump(replayed).encode() == recorded_bytes
    here = numeric_environment()
    if recorded_environment == here or (same_bytes and recorded_environment is None):
        return Comparison(same_bytes, "parameter file identical to the recorded one, byte for byte" if same_bytes
                          else "parameter file DIFFERS from the recorded one (same numeric environment, "
                               "compared byte for byte)")
    why = "the session does not record its numeric environment" if recorded_environment is None else \
        "numeric environment differs from the recorded one (" + ", ".join(
            f"{k}: {recorded_environment.get(k, '?')} -> {v}" for k, v in here.items()
            if recorded_environment.get(k) != v) + ")"
    worst, where = _worst_deviation(replayed, loads(recorded_bytes.decode(), "recorded parameters.yaml"))
    how = f"{why}; every parameter compared with the recorded one in units of its recorded 1σ"
    if worst <= TOLERANCE_SIGMA:
        return Comparison(True, f"{how}: all within {TOLERANCE_SIGMA:g}σ (largest {worst:.2g}σ)")
    return Comparison(False, f"{how}: parameter file DIFFERS: {where} off by {worst:.2g}σ "
                             f"(tolerance {TOLERANCE_SIGMA:g}σ)")


def _without_bias_at_end(pf):
    """The parameter file as a fieldcal from before ``bias_at_end`` wrote it: the rest of the file is
    what a replay confirms."""
    from dataclasses import replace

    return replace(pf, triads=tuple(replace(t, bias_at_end=None) for t in pf.triads))


def _worst_deviation(replayed, recorded) -> tuple[float, str]:
    """The largest |replayed − recorded| / recorded σ over every named parameter, and which."""
    from fieldcal.model import PARAM_NAMES

    if set(replayed.names) != set(recorded.names):
        return float("inf"), f"the triads ({', '.join(replayed.names)} vs {', '.join(recorded.names)})"
    worst, where = 0.0, ""
    for name in recorded.names:
        a, b = replayed[name], recorded[name]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(a.theta - b.theta) / b.sigma
        z = np.where(a.theta == b.theta, 0.0, z)  # equal values pass even at σ = 0
        i = int(np.argmax(z))
        if z[i] > worst:
            worst, where = float(z[i]), f"{name} {PARAM_NAMES[i]}"
    return worst, where
