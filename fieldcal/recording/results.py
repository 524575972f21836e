"""A recording's calibration as a parameter file and as the summary `fieldcal calibrate` prints.

The gyroscope's K from the rotations is full: its lower triangle gives the file's named angles
(Δyz = −m_yx, Δzy = m_zx, Δzx = −m_zy) with their σ; the upper triangle (m_xy, m_xz, m_yz) is in
K, and all six terms with their σ are in the printed summary.
"""
from __future__ import annotations

import math

import numpy as np

from fieldcal.earth import Station
from fieldcal.model import ANGULAR_RATE
from fieldcal.paramfile import ParameterFile, TriadParameters, hash_inputs
from fieldcal.paramfile.document import ROTATION_METHOD
from fieldcal.recording import Recording
from fieldcal.recording.calibrate import RecordingCalibration
from fieldcal.report import solution_header, solution_table
from fieldcal.solvers.classic import ClassicSolution
from fieldcal.solvers.rotation import RotationSolution
from fieldcal.units import display_scale, param_unit

PROCEDURE = "recording"
_LOWER = ("m_yx", "m_zx", "m_zy")
_SIGNS = np.array([-1.0, 1.0, -1.0])  # Δyz, Δzy, Δzx from m_yx, m_zx, m_zy


def gyro_parameters(cal: RecordingCalibration, name: str) -> TriadParameters:
    sol = cal.angular_rate[name]
    if isinstance(sol, ClassicSolution):  # the Ferraris turns
        return TriadParameters.from_solution(sol)
    sigma = dict(zip(sol.param_names, sol.sigma, strict=True))
    return TriadParameters(
        name=name, kind=ANGULAR_RATE, output_unit=sol.output_unit, bias=sol.bias, K=sol.K,
        sigma=np.r_[cal.gyro_bias_sigma[name], [sigma[f"scale_{a}"] for a in "xyz"],
                    [sigma[m] for m in _LOWER]],
        residual_rms=float(np.sqrt(np.mean(sol.residuals**2))), method=ROTATION_METHOD,
        residual_unit="rad")


def parameter_file(cal: RecordingCalibration, recording: Recording, station: Station,
                   device_name: str | None = None, simulation: bool | None = None) -> ParameterFile:
    triads = [TriadParameters.from_solution(s) for s in cal.specific_force.values()]
    triads += [gyro_parameters(cal, n) for n in cal.angular_rate]
    methods = "+".join(dict.fromkeys([s.method for s in cal.specific_force.values()]
                                     + [ROTATION_METHOD if isinstance(s, RotationSolution) else s.method
                                        for s in cal.angular_rate.values()]))
    data = [recording.t] + [recording.triads[n] for n in sorted(recording.triads)]
    return ParameterFile.build(triads, station=station, procedure=PROCEDURE, method=methods,
                               input_sha256=hash_inputs(*data), device_name=device_name,
                               simulation=simulation)


def _value(x: float, unit: str, decimals: str = ".5g") -> str:
    return f"{x:{decimals}} {unit}" if unit != "1" else f"{x:.7f}"


def gyro_table(cal: RecordingCalibration, name: str, truth: np.ndarray | None = None) -> str:
    """Bias, scale factors and the six misalignment terms ± 1σ (and the truth when known:
    [bias (3), k (3), m_xy, m_xz, m_yx, m_yz, m_zx, m_zy])."""
    sol = cal.angular_rate[name]
    values = np.r_[sol.bias, sol.scale_factor, sol.misalignment]
    sigmas = np.r_[cal.gyro_bias_sigma[name], sol.sigma[-9:]]
    labels = ["bias x", "bias y", "bias z", "scale x", "scale y", "scale z",
              *[n.replace("m_", "m ") for n in sol.param_names[-6:]]]
    head = f"  {'parameter':<9} {'solved':>18} {'±1σ':>12}"
    if truth is not None:
        head += f" {'true':>18} {'error/σ':>8}"
    lines = [head]
    for j, label in enumerate(labels):
        index = min(j, 6)  # the six terms share the angle's display
        scale = display_scale(ANGULAR_RATE, sol.output_unit, index)
        unit = param_unit(ANGULAR_RATE, sol.output_unit, index)
        sig = f"{sigmas[j] * 1e6:.3g} ppm" if unit == "1" else f"{sigmas[j] * scale:.3g} {unit}"
        row = f"  {label:<9} {_value(values[j] * scale, unit):>18} {sig:>12}"
        if truth is not None:
            row += f" {_value(truth[j] * scale, unit):>18} {(values[j] - truth[j]) / sigmas[j]:>+8.2f}"
        lines.append(row)
    return "\n".join(lines)


def _tried(tried) -> str:
    """Runs of multiples with the same outcome as one entry: "2-20×: 19 poses, χ²/dof 0.51"."""
    groups: list[list] = []
    for m, n, why in tried:
        if groups and groups[-1][2:] == [n, why]:
            groups[-1][1] = m
        else:
            groups.append([m, m, n, why])
    return "; ".join(f"{a:g}{f'-{b:g}' if b != a else ''}×: {n} poses, {why}" for a, b, n, why in groups)


def summary_lines(cal: RecordingCalibration, truths: dict | None = None) -> list[str]:
    """Poses found, and per triad the fit and every parameter ± 1σ."""
    poses, truths = cal.poses, truths or {}
    still = np.diff(poses.intervals, axis=1)[:, 0]
    lines = [f"protocol: {cal.protocol}",
             f"poses: {len(poses.intervals)} static intervals ({cal.spread.message}; "
             f"{len(poses.intervals) - cal.spread.count} duplicate), threshold {poses.multiple:g}× the "
             f"noise of {cal.noise_source}; shortest {still.min()} samples",
             "  thresholds tried: " + _tried(cal.tried)]
    if len(cal.turns):
        used = "rate equations for the gyro" if cal.table_rate_used else \
            "not used (give the table's rate to use them)"
        lines.append(f"  {len(cal.turns)} turntable turn{'s' * (len(cal.turns) != 1)} found: {used}")
    for name, sol in cal.specific_force.items():
        lines += ["", solution_header(sol), solution_table(sol, truths.get(name))]
    for name, sol in cal.angular_rate.items():
        if isinstance(sol, ClassicSolution):  # the Ferraris turns
            lines += ["", f"{name} (the ±2π integrals of {len(sol.residuals)} full turns, the bias from the "
                      "six poses; misalignment here: the lower triangle, all of K in the file)",
                      solution_table(sol, truths.get(name))]
            continue
        rms = math.degrees(float(np.sqrt(np.mean(sol.residuals**2)))) * 60
        quality = f"χ²/dof {sol.chi2 / sol.dof:.2f}" if sol.dof else "exact fit"
        bias = "estimated" if sol.bias_estimated else "the first pose's mean, less the vertical Earth rate"
        lines += ["", f"{name} (rotations between {len(cal.poses.intervals)} poses, {sol.method}: "
                  f"{sol.evaluations} evaluations; direction residual RMS {rms:.3g} arcmin; {quality}; "
                  f"bias: {bias})", gyro_table(cal, name, truths.get(name))]
    for name, why in cal.failures.items():
        lines += ["", f"{name}: not calibrated: {why}"]
    return lines
