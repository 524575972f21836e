"""Acceptance limits: a product spec (YAML) and the PASS/FAIL of a parameter file against it.

A spec says, per triad, what a good unit of the product looks like, in operator units
(``fieldcal.units``: biases in mg or °/h, scale factors as a dimensionless factor, angles in
mrad, the device's own unit where the output is not physical)::

    schema: fieldcal-spec/1
    product: paper MIMU
    triads:
      accelerometer:
        bias:         {unit: mg, min: -50, max: 50, max_sigma: 1.0, max_drift: 5}
        scale:        {unit: "1", min: 0.99, max: 1.01, max_sigma: 1.0e-4}
        misalignment: {unit: mrad, min: -20, max: 20}
        bias_z:       {unit: mg, min: -80, max: 80}    # one parameter: overrides its group's keys
        max_residual: {unit: mg, value: 2.0}
        thermal:                                        # the thermal model's terms (issue 28)
          bias_drift:  {unit: mg/K, min: -1, max: 1, max_sigma: 0.05}   # b₁ per axis
          scale_drift: {unit: ppm/K, min: -100, max: 100}               # s₁ per axis

Every limit is optional; a parameter is checked against its group's limits with its own entry's
keys taking precedence. The unit is required beside every number and must be the unit the
parameter is shown in, so a spec written for a device reporting in g is never silently applied
to one reporting in counts. A triad with thermal limits and no thermal model in the file fails
("not calibrated for temperature"): a spec that limits how the unit moves with temperature is not
met by a calibration that never measured it, as a limit on a parameter left at its nominal value
is never passed. ``evaluate`` is pure: no I/O, no clock.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fieldcal.calibration import nearest, operator_values  # noqa: F401 (its home was here)
from fieldcal.model import FULL_PARAM_NAMES, PARAM_NAMES
from fieldcal.paths import find_named, not_found
from fieldcal.units import ANGLE, BIAS, SCALE, group_of, operator_unit
from fieldcal.validation import MISSING, FieldReader, describe, join, read_yaml_file

SPEC_SCHEMA = "fieldcal-spec/1"
GROUPS = {"bias": BIAS, "scale": SCALE, "misalignment": ANGLE}
PARAMETERS = tuple(dict.fromkeys(PARAM_NAMES + FULL_PARAM_NAMES))
LIMIT_KEYS = ("min", "max", "max_sigma", "max_drift")
TRIAD_KEYS = (*GROUPS, *PARAMETERS, "max_residual", "thermal")
# The thermal model's terms a spec limits: bₖ for k = 1 (bias per K, the bias group's unit per
# K) and s₁ (scale drift, ppm/K), per axis; no max_drift (a previous file's are not compared).
THERMAL_KEYS = ("bias_drift", "scale_drift")
THERMAL_LIMIT_KEYS = ("min", "max", "max_sigma")


class SpecError(ValueError):
    """A product spec that cannot be used; one line naming the file and field."""

    def __init__(self, message: str, path: str = "", field: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.field = field


@dataclass(frozen=True)
class Limit:
    """Limits on one parameter (or a group of them), all in ``unit``; None: not limited."""

    unit: str
    min: float | None = None
    max: float | None = None
    max_sigma: float | None = None
    max_drift: float | None = None

    def over(self, base: Limit | None) -> Limit:
        """This entry's keys, the group's (``base``) where this one gives none."""
        if base is None:
            return self
        return Limit(self.unit, *(getattr(self, k) if getattr(self, k) is not None else getattr(base, k)
                                  for k in LIMIT_KEYS))


@dataclass(frozen=True)
class TriadSpec:
    name: str
    limits: dict[str, Limit]  # by group key (bias, scale, misalignment) or parameter name
    max_residual: tuple[float, str] | None = None  # (value, unit)
    thermal: dict[str, Limit] | None = None  # by THERMAL_KEYS; None: no thermal limits

    def limit_for(self, parameter: str) -> Limit | None:
        group = next(k for k, g in GROUPS.items() if g == group_of(parameter))
        own, base = self.limits.get(parameter), self.limits.get(group)
        if own is not None and base is not None and own.unit != base.unit:
            return own  # the unit check in evaluate names the mismatch against the file
        return own.over(base) if own is not None else base


@dataclass(frozen=True)
class ProductSpec:
    product: str
    triads: tuple[TriadSpec, ...]
    path: str = "<spec>"


# ----------------------------------------------------------------------------------------------
# Loading


def _keys(r: FieldReader, value, where: str, allowed, required=()) -> dict:
    """A mapping with only ``allowed`` keys; an unknown key is named with the nearest valid one."""
    if not isinstance(value, dict):
        r.fail(where, "a mapping", describe(value))
    for key in value:
        if key not in allowed:
            r.fail(join(where, str(key)), f"one of {', '.join(allowed)}",
                   f"the unknown key {describe(key)} (nearest: {nearest(key, allowed)!r})")
    for key in required:
        if key not in value:
            r.fail(join(where, key), "a value", describe(MISSING))
    return value


def _limit(r: FieldReader, raw, where: str, thermal: bool = False) -> Limit:
    allowed = ("unit", *THERMAL_LIMIT_KEYS) if thermal else ("unit", *LIMIT_KEYS)
    m = _keys(r, raw, where, allowed, required=("unit",))
    unit = r.string(m, "unit", where)
    values = {k: r.number(m, k, where, minimum=None if k in ("min", "max") else 0.0)
              for k in LIMIT_KEYS if k in m}
    if "min" in values and "max" in values and values["min"] > values["max"]:
        r.fail(join(where, "max"), f"a number >= min ({values['min']:g})", describe(m["max"]))
    return Limit(unit=unit, **values)


def spec_from_document(doc, path: str = "<spec>") -> ProductSpec:
    r = FieldReader(path, SpecError)
    m = _keys(r, doc, "", ("schema", "product", "triads"), required=("schema", "product", "triads"))
    if m["schema"] != SPEC_SCHEMA:
        r.fail("schema", repr(SPEC_SCHEMA), describe(m["schema"]))
    product = r.string(m, "product", "")
    raw_triads = m["triads"]
    if not isinstance(raw_triads, dict) or not raw_triads:
        r.fail("triads", "a mapping of triad name to limits", describe(raw_triads))
    triads = []
    for name, raw in raw_triads.items():
        where = f"triads.{name}"
        if not isinstance(name, str) or not name:
            r.fail("triads", "triad names that are non-empty strings", describe(name))
        t = _keys(r, raw, where, TRIAD_KEYS)
        limits = {k: _limit(r, v, join(where, k)) for k, v in t.items() if k not in ("max_residual", "thermal")}
        thermal = None
        if "thermal" in t:
            tw = join(where, "thermal")
            raw_thermal = _keys(r, t["thermal"], tw, THERMAL_KEYS)
            if not raw_thermal:
                r.fail(tw, f"limits on {' or '.join(THERMAL_KEYS)}", "an empty mapping")
            thermal = {k: _limit(r, v, join(tw, k), thermal=True) for k, v in raw_thermal.items()}
        residual = None
        if "max_residual" in t:
            rw = join(where, "max_residual")
            res = _keys(r, t["max_residual"], rw, ("value", "unit"), required=("value", "unit"))
            residual = (r.number(res, "value", rw, minimum=0.0), r.string(res, "unit", rw))
        triads.append(TriadSpec(name, limits, residual, thermal))
    return ProductSpec(product, tuple(triads), path)


def load_spec(path: str | os.PathLike) -> ProductSpec:
    """Read and check a product spec, a path or a bare name (NAME.yaml here, else a shipped spec:
    ``paper-mimu``); any problem is a one-line SpecError."""
    found = find_named(path, "product spec")
    if found is None and not Path(path).suffix and not Path(path).exists():
        raise SpecError(not_found(path, "product spec"), os.fspath(path))
    path = found or path  # a path given: the reader says what is wrong with it
    return spec_from_document(read_yaml_file(path, SpecError, "product spec"), os.fspath(path))


# ----------------------------------------------------------------------------------------------
# Evaluation


@dataclass(frozen=True)
class Check:
    """One parameter (or a triad's residual, ``parameter == "residual"``) against its limits."""

    triad: str
    parameter: str
    value: float | None  # operator units; None when the triad is missing
    sigma: float | None
    unit: str
    reasons: tuple[str, ...] = ()  # why it fails; empty: PASS
    drift: float | None = None  # since the previous calibration, operator units
    drift_sigma: float | None = None  # that drift over the combined 1σ of both calibrations
    calibrated: bool = True  # False: the data did not determine it (nominal value, no σ)

    @property
    def passed(self) -> bool:
        return not self.reasons


@dataclass(frozen=True)
class Verdict:
    product: str
    checks: tuple[Check, ...]
    notes: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def failures(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if not c.passed)


def _unit_error(spec: ProductSpec, where: str, want: str, got: str, triad: str) -> SpecError:
    return SpecError(f"{spec.path}: {where}.unit: expected {got!r} (the unit triad {triad!r} is shown "
                     f"in), got {want!r}", spec.path, where)


def _g(x: float) -> str:
    return f"{x:.6g}"


def _parameter_check(spec, ts: TriadSpec, cal, i: int, value: float, sigma: float, unit: str,
                     previous) -> Check:
    name = cal.parameter_names[i]
    limit = ts.limit_for(name)
    if name in cal.not_calibrated:  # a nominal is no measurement: a limit on it is never passed
        why = (f"not calibrated: {cal.not_calibrated_why or 'the data did not determine it'}",)
        return Check(cal.name, name, value, None, unit, why if limit is not None else (), calibrated=False)
    if limit is None:
        return Check(cal.name, name, value, sigma, unit)
    if limit.unit != unit:
        key = name if name in ts.limits else next(k for k, g in GROUPS.items() if g == group_of(name))
        raise _unit_error(spec, f"triads.{ts.name}.{key}", limit.unit, unit, cal.name)
    reasons = []
    if limit.min is not None and value < limit.min:
        reasons.append(f"{_g(value)} {unit} below the minimum {_g(limit.min)} {unit}")
    if limit.max is not None and value > limit.max:
        reasons.append(f"{_g(value)} {unit} above the maximum {_g(limit.max)} {unit}")
    if limit.max_sigma is not None and sigma > limit.max_sigma:
        reasons.append(f"σ {_g(sigma)} {unit} above the maximum {_g(limit.max_sigma)} {unit}")
    drift = drift_sigma = None
    if previous is not None and name in previous.parameter_names:
        p_values, p_sigma, p_units = operator_values(previous)
        j = previous.parameter_names.index(name)
        if p_units[j] == unit:
            drift = float(value - p_values[j])
            combined = math.hypot(sigma, p_sigma[j])
            drift_sigma = drift / combined if combined > 0 else None
            if limit.max_drift is not None and abs(drift) > limit.max_drift:
                reasons.append(f"drifted {_g(drift)} {unit} since the previous calibration, more than "
                               f"{_g(limit.max_drift)} {unit}")
    return Check(cal.name, name, value, sigma, unit, tuple(reasons), drift, drift_sigma)


NOT_CALIBRATED_FOR_TEMPERATURE = "not calibrated for temperature"


def thermal_units(cal) -> dict[str, tuple[float, str]]:
    """(factor, unit) taking each thermal term from the parameter file's units to the spec's:
    b₁ in the bias's operator unit per K (mg/K, °/h/K), s₁ (1/K) in ppm/K."""
    factor, unit = operator_unit(cal.kind, cal.output_unit, BIAS)
    return {"bias_drift": (factor, f"{unit}/K"), "scale_drift": (1e6, "ppm/K")}


def thermal_checks(spec: ProductSpec, ts: TriadSpec, cal) -> list[Check]:
    """The thermal model's b₁ and s₁ per axis against the spec's thermal limits. No model (or no
    scale term where s₁ is limited) fails: "not calibrated for temperature". An order-0 model
    (the fit found no bias term worth its parameters) has b₁ = 0 with no σ: its range limits
    are checked, not max_sigma."""
    model, units, checks = cal.thermal, thermal_units(cal), []
    for key, limit in (ts.thermal or {}).items():
        factor, unit = units[key]
        if limit.unit != unit:
            raise _unit_error(spec, f"triads.{ts.name}.thermal.{key}", limit.unit, unit, cal.name)
        if model is None or (key == "scale_drift" and model.scale_drift is None):
            why = (f"{NOT_CALIBRATED_FOR_TEMPERATURE}: the parameter file has no thermal model"
                   if model is None else f"{NOT_CALIBRATED_FOR_TEMPERATURE}: its thermal model has no scale term")
            checks.append(Check(cal.name, key, None, None, "", (why,), calibrated=False))
            continue
        if key == "bias_drift":
            values = model.bias_terms[0] if model.order else np.zeros(3)
            sigmas = model.bias_terms_sigma[0] if model.order else None
        else:
            values, sigmas = model.scale_drift, model.scale_drift_sigma
        for i, axis in enumerate("xyz"):
            value = float(values[i] * factor)
            sigma = None if sigmas is None else float(sigmas[i] * factor)
            reasons = []
            if limit.min is not None and value < limit.min:
                reasons.append(f"{_g(value)} {unit} below the minimum {_g(limit.min)} {unit}")
            if limit.max is not None and value > limit.max:
                reasons.append(f"{_g(value)} {unit} above the maximum {_g(limit.max)} {unit}")
            if limit.max_sigma is not None and sigma is not None and sigma > limit.max_sigma:
                reasons.append(f"σ {_g(sigma)} {unit} above the maximum {_g(limit.max_sigma)} {unit}")
            checks.append(Check(cal.name, f"{key}_{axis}", value, sigma, unit, tuple(reasons)))
    return checks


def not_the_same_unit(parameters, previous) -> str | None:
    """Why two parameter files cannot be taken as one unit's calibrations (drift is never taken
    across them); None when both name the same serial (and the same model, where both name one)."""
    now, then = parameters.provenance, previous.provenance
    if now.device_serial is None:
        return "this calibration's unit has no serial (give --unit-serial)"
    if then.device_serial is None:
        return "the previous calibration's unit has no serial"
    if now.device_serial != then.device_serial:
        return f"the previous calibration is of unit {then.device_serial!r}, this one of {now.device_serial!r}"
    if now.device_name and then.device_name and now.device_name != then.device_name:
        return f"the previous calibration is of a {then.device_name}, this one of a {now.device_name}"
    return None


def evaluate(spec: ProductSpec, parameters, previous=None) -> Verdict:
    """Every parameter of every triad the spec names, against its limits. ``parameters`` and
    ``previous`` (for the drift) are ``ParameterFile``s; a triad the spec names and the file
    lacks fails."""
    checks, notes = [], []
    drift_limited = any(lim.max_drift is not None for t in spec.triads for lim in t.limits.values())
    unlike = not_the_same_unit(parameters, previous) if previous is not None else None
    if unlike is not None:
        previous = None
        notes.append(f"drift not checked: {unlike}")
    elif previous is None and drift_limited:
        notes.append("drift not checked: no previous calibration of this unit")
    for ts in spec.triads:
        if ts.name not in parameters.names:
            checks.append(Check(ts.name, "triad", None, None, "", (f"not in the parameter file (it has "
                                                                   f"{', '.join(parameters.names)})",)))
            continue
        cal = parameters.triad(ts.name)
        prev = previous.triad(ts.name) if previous is not None and ts.name in previous.names else None
        values, sigmas, units = operator_values(cal)
        for i in range(len(cal.parameter_names)):
            checks.append(_parameter_check(spec, ts, cal, i, float(values[i]), float(sigmas[i]),
                                           units[i], prev))
        if ts.thermal:
            checks.extend(thermal_checks(spec, ts, cal))
        if ts.max_residual is not None:
            limit, unit = ts.max_residual
            factor, shown = operator_unit(cal.kind, cal.residual_unit, BIAS)
            if unit != shown:
                raise _unit_error(spec, f"triads.{ts.name}.max_residual", unit, shown, cal.name)
            rms = cal.residual_rms * factor
            why = (f"RMS {_g(rms)} {unit} above the maximum {_g(limit)} {unit}",) if rms > limit else ()
            checks.append(Check(cal.name, "residual", rms, None, unit, why))
    unchecked = [n for n in parameters.names if n not in {t.name for t in spec.triads}]
    if unchecked:
        notes.append(f"not in the spec, not checked: {', '.join(unchecked)}")
    return Verdict(spec.product, tuple(checks), tuple(notes))


def verdict_lines(verdict: Verdict) -> list[str]:
    """The verdict as a table: one row per check, PASS or FAIL with the reason."""
    from fieldcal.report import aligned, label

    rows = [["triad", "parameter", "value", "", "1σ", "", "drift", "", "result"]]
    for c in verdict.checks:
        value = "" if c.value is None else _g(c.value)
        sigma = "" if c.sigma is None else _g(c.sigma)
        drift = "" if c.drift is None else _g(c.drift) + (f" ({c.drift_sigma:+.1f}σ)"
                                                           if c.drift_sigma is not None else "")
        result = "PASS" if c.passed else "FAIL: " + "; ".join(c.reasons)
        if c.passed and not c.calibrated:
            result = "not calibrated (no limit)"
        rows.append([c.triad, label(c.parameter), value, c.unit, sigma, c.unit if sigma else "", drift,
                     c.unit if drift else "", result])
    verdict_line = (f"{verdict.product}: {'PASS' if verdict.passed else 'FAIL'} "
                    f"({len(verdict.failures)} of {len(verdict.checks)} checks failed)")
    return [aligned(rows, "llrlrlrll"), *(f"note: {n}" for n in verdict.notes), verdict_line]
