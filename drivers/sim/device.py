"""The simulated MIMU of the paper: true errors of Table 3, noise of Table 4.

Misalignments are not given in the paper; the defaults are a few tenths of a milliradian, the
size the paper's Table 5 unit shows in its cross-axis terms.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from drivers.noise import DEFAULT_FLICKER_TAU_MAX_S, TriadNoise
from drivers.sim.physics import ANGULAR_RATE, SPECIFIC_FORCE, TriadTruth, lower_triangular_k

STANDARD_GRAVITY = 9.80665  # m/s² per g, for mg
DEG = math.pi / 180.0
MG = 1e-3 * STANDARD_GRAVITY

# Paper Table 4: random walks per √h, bias instabilities as IEEE Std 952 B.
PAPER_NOISE = {
    "accelerometer": TriadNoise(white=0.06 / 60.0, bias_instability=0.05 * MG),
    "gyroscope": TriadNoise(white=0.15 * DEG / 60.0, bias_instability=0.5 * DEG / 3600.0),
    "inclinometer": TriadNoise(white=0.08 / 60.0, bias_instability=0.06 * MG),
}

# 16-bit ADC mid-scale and sensitivity for the raw-count variant (about ±8 g full scale).
COUNTS_ZERO = 32768.0
COUNTS_PER_M_S2 = 415.0
COUNTS_PER_RAD_S = 32768.0 / (400 * DEG)  # ±400 °/s full scale


def paper_mimu(raw_counts: bool = False, flicker_tau_max_s: float = DEFAULT_FLICKER_TAU_MAX_S
               ) -> dict[str, TriadTruth]:
    """Accelerometer, gyroscope and inclinometer triads with paper Table 3 errors, whose flicker
    (bias instability) wanders with correlation times up to ``flicker_tau_max_s``."""
    spec = {
        # kind, bias (SI), scale factors, misalignment Δyz, Δzy, Δzx (rad)
        "accelerometer": (SPECIFIC_FORCE, np.array([1.0, 2.0, 3.0]) * MG, [1.0001, 1.0002, 1.0003],
                          [2.0e-4, -3.0e-4, 4.0e-4]),
        "gyroscope": (ANGULAR_RATE, np.array([0.01, 0.02, 0.03]) * DEG, [1.0001, 1.0002, 1.0003],
                      [-3.0e-4, 2.0e-4, 5.0e-4]),
        "inclinometer": (SPECIFIC_FORCE, np.array([-1.0, -2.0, -3.0]) * MG, [0.9991, 0.9992, 0.9993],
                         [1.0e-4, 2.5e-4, -2.0e-4]),
    }
    triads = {}
    for name, (kind, bias, scale, mis) in spec.items():
        K = lower_triangular_k(scale, mis)
        unit = "m/s^2" if kind == SPECIFIC_FORCE else "rad/s"
        lsb = 0.0
        if raw_counts:
            sensitivity = COUNTS_PER_M_S2 if kind == SPECIFIC_FORCE else COUNTS_PER_RAD_S
            K = K * sensitivity
            bias = bias * sensitivity + COUNTS_ZERO
            unit, lsb = "count", 1.0
        noise = replace(PAPER_NOISE[name], flicker_tau_max_s=flicker_tau_max_s)
        triads[name] = TriadTruth(kind=kind, K=K, bias=bias, noise=noise, lsb=lsb,
                                  output_unit=unit)
    return triads
