"""A recording's calibration as a parameter file and as the summary `fieldcal calibrate` prints.

The gyroscope's K from the rotations is full: its lower triangle gives the file's named angles
(Δyz = −m_yx, Δzy = m_zx, Δzx = −m_zy) with their σ; the upper triangle (m_xy, m_xz, m_yz) is in
K, and all six terms with their σ are in the printed summary.
"""
from __future__ import annotations

import math

import numpy as np

from fieldcal.calibration import CLASSIC_METHOD, STILL_METHOD
from fieldcal.earth import Station
from fieldcal.paramfile import ParameterFile
from fieldcal.recording import Recording
from fieldcal.recording.outcome import RecordingCalibration
from fieldcal.recording.place import UnknownPlace
from fieldcal.report import residual_text, solution_header, solution_table

PROCEDURE = "recording"


def _file_station(station: Station | UnknownPlace) -> Station:
    """The station a parameter file records. A file's gravity source is "measured" or "WGS84
    normal gravity" (``fieldcal.earth.GRAVITY_SOURCES``); an unknown place's g (given, from the
    pose means or standard gravity) is not the normal gravity of latitude 0, so it is written as
    a given value at latitude 0, height 0: "measured"."""
    if isinstance(station, UnknownPlace):
        return Station(station.latitude_deg, station.height_m, station.gravity)
    return station


def place_of(provenance) -> Station | UnknownPlace:
    """The place a recording's parameter file was calibrated for (its provenance), as
    ``_file_station`` wrote it: latitude 0, height 0 and a given g is an unknown place, and that g
    normal gravity at 45° the default with its worldwide spread (see place.place_gravity)."""
    from fieldcal.earth import MEASURED, normal_gravity
    from fieldcal.recording.place import DEFAULT_LATITUDE_DEG

    p = provenance
    if p.gravity_source != MEASURED:
        return Station(p.latitude_deg, p.height_m)
    if p.latitude_deg != 0.0 or p.height_m != 0.0:
        return Station(p.latitude_deg, p.height_m, p.gravity_m_s2)
    if math.isclose(p.gravity_m_s2, normal_gravity(DEFAULT_LATITUDE_DEG), rel_tol=1e-12):
        return UnknownPlace()
    return UnknownPlace(gravity=p.gravity_m_s2)


def parameter_file(cal: RecordingCalibration, recording: Recording, station: Station | UnknownPlace,
                   device_name: str | None = None, simulation: bool | None = None,
                   operator: str | None = None, device_serial: str | None = None) -> ParameterFile:
    triads = [*cal.specific_force.values(), *cal.angular_rate.values()]
    methods = "+".join(dict.fromkeys([s.method for s in cal.specific_force.values()]
                                     + [s.method for s in cal.angular_rate.values()]))
    data = [recording.t] + [recording.triads[n] for n in sorted(recording.triads)]  # what was solved from
    return ParameterFile.from_solutions(triads, inputs=data, station=_file_station(station), procedure=PROCEDURE,
                                        method=methods, device_name=device_name, simulation=simulation,
                                        device_serial=device_serial, operator=operator)


# χ²/dof beyond which a fit is not noise the model misses but data that do not fit it: a residual
# RMS ten times the noise. Real recordings' worst seen is 11 (imu_tk's gyro, 21 arcmin); a join of
# a recording with its time-reversed copy whose gyro was not negated, thousands.
MISFIT_LIMIT = 100.0


def misfits(cal: RecordingCalibration) -> list[str]:
    """One phrase per triad whose fit is far beyond its noise (χ²/dof above MISFIT_LIMIT), with the
    figure; [] when every fit is plausible. Not the Ferraris faces' and turns' (CLASSIC_METHOD):
    their χ² weighs each face's mean by its white noise alone, so it counts how each face was set
    down (imucal's own session: χ²/dof 2000, 1.8 mg), which their σ carry by it."""
    found = []
    for name, sol in (*cal.specific_force.items(), *cal.angular_rate.items()):
        ratio = sol.diagnostics.reduced_chi2
        if sol.method == CLASSIC_METHOD or ratio is None or not ratio > MISFIT_LIMIT:
            continue
        if name in cal.angular_rate:
            rms = f"direction residual RMS {math.degrees(sol.residual_rms) * 60:.3g} arcmin"
        else:
            rms = f"residual RMS {sol.residual_rms:.3g} {sol.residual_unit}"
        found.append(f"{name} fits with χ²/dof {ratio:.3g} ({rms}), {math.sqrt(ratio):.0f} times its noise")
    return found


MISFIT_CAUSES = ("likely a pose that was not still, a wrong map (columns, units, axis order, a triad's "
                 "sign) or a gap or jump in time")


def noise_lines(cal: RecordingCalibration, configured: bool) -> list[str]:
    """How the σ were obtained: the config's noise model, or one estimated from the recording
    (each triad's white noise and bias instability, SI units), or white noise alone."""
    from fieldcal.recording.noise_estimate import ESTIMATED

    if not cal.estimated_noise:
        return [f"noise: {NOISE_FROM_CONFIG if configured else NOISE_WHITE_ONLY}"]
    lines = [f"noise: {ESTIMATED}" + (f"; the others' from {NOISE_FROM_CONFIG}" if configured else "")]
    for name, noise in cal.estimated_noise.items():
        unit = "rad/s" if name in cal.angular_rate or name not in cal.specific_force else "m/s²"
        lines.append(f"  {name}: white {noise.white:.3g} {unit}/√Hz, bias instability "
                     f"{noise.bias_instability:.3g} {unit}")
    return lines


NOISE_FROM_CONFIG = "the config's noise model (bias instability included)"
NOISE_WHITE_ONLY = ("white, measured where the summary says; the bias instability is not known, so "
                    "the biases' σ may be too small (give --config with the device's noise)")


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
        header = solution_header(sol)
        if sol.method == CLASSIC_METHOD:  # the Ferraris faces
            header = f"{name} (Ferraris's six-position solution, the faces' norms fitted to g; {residual_text(sol)})"
        elif sol.not_calibrated:  # a sub-model's: what the poses determined
            header = (f"{name} (not calibrated: {sol.not_calibrated_why})" if not sol.calibrated else
                      f"{header[:-1]}; only what the poses determine)")
        lines += ["", header, solution_table(sol, truths.get(name))]
    for name, sol in cal.angular_rate.items():
        fit = sol.diagnostics
        if sol.method == CLASSIC_METHOD:  # the Ferraris turns
            lines += ["", f"{name} (the ±2π integrals of {len(sol.residuals)} full turns, the bias from the "
                      "six poses)", solution_table(sol, truths.get(name))]
            continue
        if sol.method == STILL_METHOD:  # the sub-model's gyro: its bias alone
            less = "" if isinstance(cal.place, UnknownPlace) else ", less the vertical Earth rate"
            lines += ["", f"{name} (the bias alone: the mean of {len(cal.poses.intervals)} still poses{less})",
                      solution_table(sol, truths.get(name))]
            continue
        rms = math.degrees(sol.residual_rms) * 60
        quality = f"χ²/dof {fit.reduced_chi2:.2f}" if fit.dof else "exact fit"
        bias = ("the poses' mean" + ("" if isinstance(cal.place, UnknownPlace) else
                                     ", less the vertical Earth rate")) if fit.held else "estimated"
        lines += ["", f"{name} (rotations between {len(cal.poses.intervals)} poses, {fit.search}: "
                  f"{fit.evaluations} evaluations; direction residual RMS {rms:.3g} arcmin; {quality}; "
                  f"bias: {bias})", solution_table(sol, truths.get(name))]
    lines += [f"  note: {note}" for note in cal.notes]
    for name, why in cal.failures.items():
        lines += ["", f"{name}: not calibrated: {why}"]
    from fieldcal.recording.submodel import summary_line

    partial = summary_line(cal)  # last: what a sub-model solved, what not, what would add it
    return lines + (["", partial] if partial else [])
