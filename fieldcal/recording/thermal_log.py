"""A PX4 thermal-calibration log (a cold-soaked board warming on the bench, held still) -> each
triad's thermal model, by fieldcal's own thermal fit.

PX4's method (``Tools/process_sensor_caldata.py``) logs ``sensor_accel`` and ``sensor_gyro``
with each sensor's ``temperature`` (SDLOG_PROFILE bit 2, "thermal calibration"). Here each
triad's samples are cut into equal windows of time (equal counts, so equal noise), each window's
mean tagged with its mean temperature, and the window means fitted by
``fieldcal.solvers.thermal.solve_thermal_norm`` through ``fieldcal.solvers.held``: the order
of the bias polynomial chosen by its likelihood-ratio test, σ from the noise of the means.

That noise is measured, not assumed: from the second differences of consecutive window means
(d = m₍ᵢ₊₂₎ − 2m₍ᵢ₊₁₎ + mᵢ, whose variance is 6σ² for independent means; a smooth thermal trend
adds only its curvature), by their median absolute deviation (a bump of the bench does not set
it). Correlated noise slower than a window remains: the fit's χ² then says so, and its σ are
inflated by it (``solve_thermal_norm``'s Birge rule). A bias that wanders slowly (a random walk)
cannot be told from the thermal curve within one monotone warm-up, and at the window scale it
hides beneath the white noise: the σ are then too small (seeded gyro runs, 2026-11-27: RMS z
0.96 with white noise alone, 1.4 with a 25 °/h/√h rate random walk, 4.6 at five times that).
Measuring the walk from the residuals at 1 and 4 windows was tried and dropped: too little of it
shows there to be measured, while noise alone then widened every σ (RMS z 0.65).

One pose determines none of K, nor the bias itself (gravity and the Earth rate are in every
reading): each triad comes out with its nine parameters marked not calibrated and its thermal
model, the change of its bias from T_ref (T_ref: the middle of the logged range, as PX4's TREF).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from fieldcal.model import ANGULAR_RATE, PARAM_NAMES, SPECIFIC_FORCE
from fieldcal.recording.errors import RecordingImportError

# (fieldcal triad, PX4 topic, kind, unit)
TOPICS = (("accelerometer", "sensor_accel", SPECIFIC_FORCE, "m/s^2"),
          ("gyroscope", "sensor_gyro", ANGULAR_RATE, "rad/s"))
MAX_WINDOWS = 200  # window means fitted per triad: enough to see a cubic, few enough for a dense fit
MIN_SAMPLES_PER_WINDOW = 10
MIN_WINDOWS = 12  # below this the noise of the means is not measured (second differences: n − 2)
MIN_SPAN_K = 1.0  # a log that did not warm by this much holds no thermal model
NOT_CALIBRATED_WHY = ("one still pose of a thermal log: only the bias's change with temperature is "
                      "determined (calibrate K and b with `fieldcal calibrate` or a procedure)")


@dataclass(frozen=True)
class TriadLog:
    """One triad's samples from the log: ``values`` (n, 3) in ``unit``, ``temperature_c`` (n,)."""

    name: str
    topic: str
    kind: str
    unit: str
    t: np.ndarray
    values: np.ndarray
    temperature_c: np.ndarray
    device_id: int | None


def read_thermal_ulog(path: str | os.PathLike, instance: int = 0) -> list[TriadLog]:
    """The accelerometer and gyro of sensor instance ``instance`` with their temperatures, in
    time order, NaN samples dropped; one-line RecordingImportError for what cannot be used."""
    path = os.fspath(path)
    try:
        from pyulog import ULog
    except ImportError:
        raise RecordingImportError(f"{path}: reading PX4 ULog needs pyulog: pip install 'fieldcal[logs]'",
                                   path) from None
    from fieldcal.recording.inputs import check_input
    from fieldcal.recording.logs import _LastRead
    from fieldcal.recording.noise import captured_output

    check_input(path, "PX4 ULog")
    try:
        with captured_output(), open(path, "rb") as raw:  # pyulog prints its warnings: said in one line
            reads = _LastRead(raw)
            log = ULog(reads, [topic for _, topic, _, _ in TOPICS])
    except OSError as exc:
        raise RecordingImportError(f"{path}: cannot read it ({exc.strerror or exc})", path) from None
    except Exception as exc:  # pyulog raises bare exceptions on a damaged file
        raise RecordingImportError(f"{path}: not a readable ULog ({exc})", path) from None
    if reads.cut_short is not None or log.file_corruption:
        raise RecordingImportError(f"{path}: damaged (cut short or corrupt data): a thermal fit needs the whole "
                                   "warm-up; copy the log again", path)
    found = {(d.name, d.multi_id): d.data for d in log.data_list}
    triads = []
    for name, topic, kind, unit in TOPICS:
        data = found.get((topic, instance))
        if data is None:
            have = sorted({f"{n} instance {i}" for n, i in found})
            raise RecordingImportError(f"{path}: no {topic} instance {instance} in the log (it has "
                                       f"{', '.join(have) or 'neither topic'}): log it with SDLOG_PROFILE's "
                                       "thermal calibration bit (2)", path)
        if "temperature" not in data:
            raise RecordingImportError(f"{path}: {topic} has no temperature field: this PX4 logs no "
                                       "sensor temperature to calibrate against", path)
        stamp = data["timestamp_sample"] if "timestamp_sample" in data else data["timestamp"]
        t = np.asarray(stamp, dtype=float) * 1e-6
        values = np.column_stack([data[a] for a in "xyz"]).astype(float)
        temperature = np.asarray(data["temperature"], dtype=float)
        keep = np.isfinite(t) & np.isfinite(values).all(axis=1) & np.isfinite(temperature)
        if np.count_nonzero(keep) < MIN_WINDOWS * MIN_SAMPLES_PER_WINDOW:
            raise RecordingImportError(f"{path}: {topic} instance {instance} has {np.count_nonzero(keep)} samples "
                                       "with a finite reading and temperature: too few for a thermal fit "
                                       f"(at least {MIN_WINDOWS * MIN_SAMPLES_PER_WINDOW})", path)
        order = np.argsort(t[keep], kind="stable")
        ids = np.asarray(data["device_id"]) if "device_id" in data else None
        triads.append(TriadLog(name, topic, kind, unit, t[keep][order], values[keep][order],
                               temperature[keep][order], None if ids is None else int(np.median(ids))))
    return triads


def window_means(values: np.ndarray, temperature_c: np.ndarray, windows: int | None = None):
    """(means (w, 3), mean temperatures (w,), σ of one window mean per axis (3,)): ``windows``
    equal runs of samples (default: as many as MAX_WINDOWS and MIN_SAMPLES_PER_WINDOW allow;
    the last few samples that do not fill a window are left out)."""
    n = len(values)
    w = windows or min(MAX_WINDOWS, n // MIN_SAMPLES_PER_WINDOW)
    per = n // w
    means = values[:w * per].reshape(w, per, 3).mean(axis=1)
    temps = temperature_c[:w * per].reshape(w, per).mean(axis=1)
    second = means[2:] - 2 * means[1:-1] + means[:-2]
    mad = np.median(np.abs(second - np.median(second, axis=0)), axis=0)
    return means, temps, 1.4826 * mad / np.sqrt(6.0)


@dataclass(frozen=True)
class HeldThermalFit:
    """A triad's thermal model from a still warm-up: the calibration to keep (its nine parameters
    marked not calibrated, the thermal model attached) and the fit's evidence."""

    calibration: object  # fieldcal.calibration.Calibration
    chi2_by_order: dict[int, float]
    chi2: float
    dof: int
    windows: int
    window_sigma: np.ndarray  # (3,) σ of one window mean, the triad's unit
    inflated: bool  # χ² improbable for that noise: the σ were widened by √(χ²/dof) (Birge)


def fit_held_thermal(triad: TriadLog, reference_c: float | None = None) -> HeldThermalFit:
    """The thermal model of one triad held still while warming (see the module docstring)."""
    from fieldcal.calibration import Calibration, nominal_value
    from fieldcal.solvers.held import HeldPoseProblem
    from fieldcal.solvers.thermal import solve_thermal_norm

    span = float(np.ptp(triad.temperature_c))
    if span < MIN_SPAN_K:
        raise ValueError(f"{triad.topic}: its temperature spans {span:.2f} K ({triad.temperature_c.min():.2f} to "
                         f"{triad.temperature_c.max():.2f} °C): too little for a thermal model (at least "
                         f"{MIN_SPAN_K:g} K; cold-soak the board first)")
    means, temps, sigma = window_means(triad.values, triad.temperature_c)
    if not np.all(sigma > 0):
        raise ValueError(f"{triad.topic}: its window means do not scatter at all (a constant or quantised-flat "
                         "reading): the noise the fit weighs by cannot be measured")
    low, high = float(triad.temperature_c.min()), float(triad.temperature_c.max())
    ref = 0.5 * (low + high) if reference_c is None else float(reference_c)
    problem = HeldPoseProblem(means, triad.name, triad.kind, triad.unit)
    pins = problem.pin_count
    covariance = np.vstack([np.tile(sigma, (len(means), 1)), np.ones((pins, 3))])
    fit = solve_thermal_norm(problem, np.r_[temps, np.full(pins, ref)], covariance, reference_c=ref, scale=False)
    solved = fit.calibration
    # The model's range: the samples' (a window mean's temperature is the middle of its window's).
    model = replace(solved.thermal, range_c=(low, high))
    nominal = [nominal_value(triad.kind, triad.unit, p) for p in PARAM_NAMES]
    calibration = Calibration(name=triad.name, kind=triad.kind, output_unit=triad.unit, method="lsq",
                              theta=np.array(nominal, dtype=float), sigma=np.zeros(len(PARAM_NAMES)),
                              residuals=solved.residuals[:3 * len(means)], thermal=model,
                              not_calibrated=PARAM_NAMES, not_calibrated_why=NOT_CALIBRATED_WHY)
    diagnostics = solved.diagnostics
    return HeldThermalFit(calibration, fit.chi2_by_order, float(diagnostics.chi2), int(diagnostics.dof),
                          len(means), sigma, bool(diagnostics.scaled_by_residuals))


def onto(base, fits: list[HeldThermalFit], procedure: str, log_inputs) -> object:
    """``base`` (a ParameterFile whose offsets hold at the fits' reference temperature) with each
    fit's thermal model given to the base's one triad of its kind, in that triad's output unit.
    One line refuses a base with none or several triads of a kind, one in raw counts, or one
    that has a thermal model already (it would be replaced unseen)."""
    from fieldcal.paramfile import ParameterFile, hash_inputs
    from fieldcal.units import SI_PER_UNIT

    triads = list(base.triads)
    for fit in fits:
        cal = fit.calibration
        same = [i for i, t in enumerate(triads) if t.kind == cal.kind]
        if len(same) != 1:
            names = ", ".join(triads[i].name for i in same) or "none"
            raise ValueError(f"--onto: expected one {cal.kind} triad for the log's {cal.name}, the file has {names}")
        target = triads[same[0]]
        if target.thermal is not None:
            raise ValueError(f"--onto: {target.name} has a thermal model already (about "
                             f"{target.thermal.reference_c:.2f} °C): give a file without one")
        si = SI_PER_UNIT[target.kind].get(target.output_unit)
        if si is None:
            raise ValueError(f"--onto: {target.name} reports in {target.output_unit!r}; the log's {cal.name} is in "
                             f"{cal.output_unit}: give a calibration of a device reporting physical units")
        model = cal.thermal
        model = replace(model, bias_terms=model.bias_terms * (SI_PER_UNIT[cal.kind][cal.output_unit] / si),
                        bias_terms_sigma=model.bias_terms_sigma * (SI_PER_UNIT[cal.kind][cal.output_unit] / si))
        triads[same[0]] = replace(target, thermal=model)
    p = base.provenance
    digest = hash_inputs(np.frombuffer(bytes.fromhex(p.input_sha256), dtype=np.uint8), *log_inputs)
    return ParameterFile(triads=tuple(triads),
                         provenance=replace(p, procedure=f"{p.procedure} + {procedure}", input_sha256=digest))
