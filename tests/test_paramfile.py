"""The parameter file: exact round trip, determinism, calibrate(), and one-line errors for bad files."""
from __future__ import annotations

import copy
import hashlib
import math
import os
import re
import struct

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import fieldcal
from fieldcal.earth import GRAVITY_SOURCES, Station
from fieldcal.model import ANGULAR_RATE, PARAM_NAMES, SPECIFIC_FORCE, distort_with, k_from_params
from fieldcal.paramfile import (SCHEMA, ParameterFile, ParameterFileError, Provenance, TriadParameters,
                                dump, hash_inputs, load, loads, save)
from fieldcal.solvers import StaticNormProblem, solve_classic, solve_norm

STATION = Station(latitude_deg=48.15, height_m=520.0)
THETA_ACC = np.array([0.05, -0.03, 0.02, 1.001, 0.998, 1.002, 1e-3, -2e-3, 5e-4])
THETA_GYRO_DEG = np.array([0.3, -0.2, 0.1, 57.3, 57.2, 57.4, 2e-3, 1e-3, -1.5e-3])  # deg/s out


def _directions(n: int) -> np.ndarray:
    """n well-spread unit vectors (a Fibonacci sphere)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


@pytest.fixture(scope="module")
def averages():
    rng = np.random.default_rng(7)
    g = STATION.gravity
    means = distort_with(THETA_ACC, g * _directions(18)) + rng.normal(scale=2e-4, size=(18, 3))
    rates = np.radians(10.0) * np.vstack([np.eye(3), -np.eye(3), np.eye(3), -np.eye(3)])
    gyro = distort_with(THETA_GYRO_DEG, rates) + rng.normal(scale=1e-3, size=rates.shape)
    return means, rates, gyro


@pytest.fixture(scope="module")
def norm_solution(averages):
    means, _, _ = averages
    return solve_norm(StaticNormProblem(means, STATION.gravity), np.full(means.shape, 2e-4))


@pytest.fixture(scope="module")
def classic_solution(averages):
    _, rates, gyro = averages
    return solve_classic(gyro, rates, "gyroscope", ANGULAR_RATE, output_unit="deg/s")


@pytest.fixture(scope="module")
def pf(averages, norm_solution, classic_solution):
    means, _, gyro = averages
    return ParameterFile.from_solutions([norm_solution, classic_solution], station=STATION,
                                        procedure="field-18", inputs=[means, gyro],
                                        device_name="IMU-7 rev B", device_serial="000123",
                                        simulation=True)


def _bits(x) -> bytes:
    return struct.pack("<d", x)


def _assert_bit_identical(a: ParameterFile, b: ParameterFile) -> None:
    assert a == b
    for ta, tb in zip(a.triads, b.triads, strict=True):
        for attr in ("bias", "K", "file_sigma"):  # what the file holds
            assert getattr(ta, attr).tobytes() == getattr(tb, attr).tobytes(), attr
        assert _bits(ta.residual_rms) == _bits(tb.residual_rms)
    for attr in ("latitude_deg", "height_m", "gravity_m_s2"):
        assert _bits(getattr(a.provenance, attr)) == _bits(getattr(b.provenance, attr))


# ------------------------------------------------------------------------------------------------
# Round trip and determinism


def test_round_trip_is_exact(pf, tmp_path):
    path = save(pf, tmp_path / "cal.yaml")
    back = load(path)
    _assert_bit_identical(pf, back)
    assert back.provenance == pf.provenance
    assert back.provenance.software_version == fieldcal.__version__
    assert back.names == ("accelerometer", "gyroscope")


def test_dump_is_deterministic_and_stable_through_a_round_trip(pf, tmp_path, averages,
                                                               norm_solution, classic_solution):
    text = dump(pf)
    assert dump(pf) == text
    rebuilt = ParameterFile.from_solutions([norm_solution, classic_solution], station=STATION,
                                           procedure="field-18", inputs=list(copy.deepcopy(averages[::2])),
                                           device_name="IMU-7 rev B", device_serial="000123",
                                           simulation=True)
    assert dump(rebuilt) == text
    a = save(pf, tmp_path / "a.yaml").read_bytes()
    b = save(load(tmp_path / "a.yaml"), tmp_path / "b.yaml").read_bytes()
    assert a == b == text.encode("utf-8")


def test_dump_layout(pf):
    doc = yaml.safe_load(dump(pf))
    assert list(doc) == ["schema", "provenance", "triads"]
    assert doc["schema"] == SCHEMA
    gyro = doc["triads"]["gyroscope"]
    assert gyro["input_unit"] == "rad/s"
    assert gyro["scale_factor"]["unit"] == "deg/s per rad/s"
    assert gyro["bias"]["unit"] == "deg/s"
    assert gyro["misalignment"]["unit"] == "rad"
    assert gyro["residual_rms"]["unit"] == "deg/s"  # classic residuals are in output units
    acc = doc["triads"]["accelerometer"]
    assert acc["residual_rms"]["unit"] == "m/s^2"
    assert acc["K"][0][1:] == [0.0, 0.0] and acc["K"][1][2] == 0.0
    assert doc["provenance"]["station"]["gravity_m_s2"] == STATION.gravity
    assert doc["provenance"]["device"] == {"name": "IMU-7 rev B", "serial": "000123"}


def test_no_wall_clock_in_the_file(pf, averages, norm_solution, classic_solution, monkeypatch):
    import time
    first = dump(pf)
    monkeypatch.setattr(time, "time", lambda: 4e9)
    monkeypatch.setattr(time, "time_ns", lambda: 4 * 10**18)
    assert dump(pf) == first


finite = st.floats(allow_nan=False, allow_infinity=False)
nonneg = st.floats(min_value=0.0, allow_nan=False, allow_infinity=False)
diag = st.floats(min_value=1e-3, max_value=1e3).flatmap(lambda x: st.sampled_from([x, -x]))
offdiag = st.floats(min_value=-1e-2, max_value=1e-2)
printable = st.characters(exclude_categories=("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp", "Zs"),
                          include_characters=" ")
label = st.text(printable, min_size=1, max_size=12)


@st.composite
def triad_parameters(draw, name: str):
    method = draw(st.sampled_from(["powell", "lsq", "classic"]))
    K = np.diag(draw(st.lists(diag, min_size=3, max_size=3)))
    for i, j in ((1, 0), (2, 0), (2, 1)):
        K[i, j] = draw(offdiag)
    if method == "classic":
        for i, j in ((0, 1), (0, 2), (1, 2)):
            K[i, j] = draw(offdiag)
    assume(np.linalg.cond(K) < 1e10)
    kind = draw(st.sampled_from([SPECIFIC_FORCE, ANGULAR_RATE]))
    return TriadParameters(name=name, kind=kind, output_unit=draw(label),
                           bias=draw(st.lists(finite, min_size=3, max_size=3)), K=K,
                           sigma=draw(st.lists(nonneg, min_size=9, max_size=9)),
                           residual_rms=draw(nonneg), method=method)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(names=st.lists(label, min_size=1, max_size=3, unique=True), data=st.data(),
       lat=st.floats(-90, 90), height=st.floats(-500.0, 9000.0),
       g=st.floats(min_value=9.7, max_value=9.9, exclude_min=True, exclude_max=True),
       device=st.one_of(st.none(), label), simulation=st.sampled_from([None, True, False]))
def test_any_valid_parameter_file_round_trips_bit_for_bit(names, data, lat, height, g, device,
                                                          simulation):
    triads = tuple(data.draw(triad_parameters(n)) for n in names)
    prov = Provenance(procedure=data.draw(label), method="powell", input_sha256=hash_inputs(np.zeros(3)),
                      latitude_deg=lat, height_m=height, gravity_m_s2=g,
                      gravity_source=data.draw(st.sampled_from(GRAVITY_SOURCES)),
                      device_name=device, device_serial=device,
                      simulation=simulation)
    pf = ParameterFile(triads=triads, provenance=prov)
    text = dump(pf)
    back = loads(text, "generated.yaml")
    _assert_bit_identical(pf, back)
    assert dump(back) == text


# ------------------------------------------------------------------------------------------------
# The parameters themselves


def test_calibrate_inverts_distort_with_for_any_invertible_K():
    rng = np.random.default_rng(3)
    truth = rng.normal(size=(50, 3)) * 9.8
    lower = TriadParameters(name="a", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=THETA_ACC[:3],
                            K=k_from_params(THETA_ACC), sigma=np.zeros(9), residual_rms=0.0,
                            method="powell")
    np.testing.assert_allclose(lower.calibrate(distort_with(THETA_ACC, truth)), truth, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lower.calibrate(distort_with(THETA_ACC, truth[:1])[0]), truth[0], atol=1e-12)
    np.testing.assert_allclose(lower.scale_factor, THETA_ACC[3:6], rtol=1e-15)
    np.testing.assert_allclose(lower.misalignment, THETA_ACC[6:9], rtol=1e-12)
    np.testing.assert_allclose(lower.theta, THETA_ACC, rtol=1e-12)

    K = k_from_params(THETA_ACC) + 0.01 * rng.normal(size=(3, 3))  # full, as from the classic method
    full = TriadParameters(name="b", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=[1.0, 2.0, 3.0],
                           K=K, sigma=np.zeros(9), residual_rms=0.0, method="classic")
    raw = truth @ K.T + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(full.calibrate(raw), truth, atol=1e-12)
    with pytest.raises(ValueError):
        full.calibrate(np.zeros((4, 2)))


def test_a_norm_calibration_is_written_and_read_back(pf, norm_solution, averages):
    """The solver's Calibration is what the file holds: read back, it calibrates as the
    solution does, and both recover the simulated truth."""
    t = loads(dump(pf))["accelerometer"]
    assert t == norm_solution and t.diagnostics is None and norm_solution.diagnostics.converged
    assert (t.name, t.kind, t.output_unit, t.method) == ("accelerometer", SPECIFIC_FORCE, "m/s^2", "powell")
    np.testing.assert_array_equal(t.K, norm_solution.K)
    np.testing.assert_array_equal(t.sigma, norm_solution.sigma)
    np.testing.assert_allclose(t.theta, norm_solution.theta, rtol=1e-12, atol=1e-18)
    assert list(t.named()) == list(PARAM_NAMES)
    assert t.residual_rms == norm_solution.residual_rms and t.residual_unit == "m/s^2"
    np.testing.assert_allclose(t.calibrate(averages[0]), norm_solution.calibrate(averages[0]), atol=1e-12)
    norms = np.linalg.norm(t.calibrate(averages[0]), axis=1)
    np.testing.assert_allclose(norms, STATION.gravity, atol=2e-3)
    np.testing.assert_allclose(t.theta, THETA_ACC, atol=5e-4)


def test_a_classic_calibration_keeps_the_full_matrix(pf, classic_solution, averages):
    t = loads(dump(pf))["gyroscope"]
    assert t == classic_solution
    assert t.method == "classic" and t.residual_unit == "deg/s" and t.input_unit == "rad/s"
    np.testing.assert_array_equal(t.K, classic_solution.K)
    # The file names the lower triangle's angles: the terms m_yx, m_zx, m_zy up to sign.
    m = classic_solution.named()
    np.testing.assert_allclose(t.misalignment, [-m["m_yx"][0], m["m_zx"][0], -m["m_zy"][0]], rtol=1e-12)
    np.testing.assert_array_equal(t.sigma, classic_solution.file_sigma)
    np.testing.assert_array_equal(t.file_sigma[6:], [m[n][1] for n in ("m_yx", "m_zx", "m_zy")])
    _, rates, gyro = averages
    np.testing.assert_allclose(t.calibrate(gyro), classic_solution.calibrate(gyro), atol=1e-15)
    np.testing.assert_allclose(t.calibrate(gyro), rates, atol=1e-4)
    # Every term of the full K against the simulated one (upper triangle zero), within 4σ.
    K_true = k_from_params(THETA_GYRO_DEG)
    k_true, sigma = np.diag(K_true), classic_solution.sigma
    assert np.all(np.abs(classic_solution.scale_factor - k_true) < 4 * sigma[3:6])
    terms = (K_true / k_true[:, None] - np.eye(3))[~np.eye(3, dtype=bool)]
    assert np.all(np.abs(classic_solution.misalignment - terms) < 4 * sigma[6:])


def test_parameters_are_immutable(pf):
    with pytest.raises(ValueError):
        pf.triads[0].K[0, 0] = 2.0
    with pytest.raises(AttributeError):
        pf.triads[0].name = "other"  # type: ignore[misc]


def test_constructors_reject_invalid_parameters(norm_solution):
    t = norm_solution
    prov = Provenance(procedure="p", method="powell", input_sha256="0" * 64, latitude_deg=0.0,
                      height_m=0.0, gravity_m_s2=9.8, gravity_source="measured")
    with pytest.raises(ValueError, match="unique"):
        ParameterFile(triads=(t, t), provenance=prov)
    with pytest.raises(ValueError, match="invertible"):
        TriadParameters(name="x", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=np.zeros(3),
                        K=np.ones((3, 3)), sigma=np.zeros(9), residual_rms=0.0, method="classic")
    with pytest.raises(ValueError, match="lower-triangular"):
        TriadParameters(name="x", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=np.zeros(3),
                        K=np.eye(3) + np.triu(np.full((3, 3), 0.01), 1), sigma=np.zeros(9),
                        residual_rms=0.0, method="powell")
    with pytest.raises(ValueError, match="kind"):
        TriadParameters(name="x", kind="magnetic", output_unit="uT", bias=np.zeros(3), K=np.eye(3),
                        sigma=np.zeros(9), residual_rms=0.0, method="classic")
    with pytest.raises(ValueError, match="sigma"):
        TriadParameters(name="x", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=np.zeros(3),
                        K=np.eye(3), sigma=-np.ones(9), residual_rms=0.0, method="classic")
    with pytest.raises(ValueError, match="input_sha256"):
        Provenance(procedure="p", method="powell", input_sha256="xyz", latitude_deg=0.0,
                   height_m=0.0, gravity_m_s2=9.8, gravity_source="measured")
    assert issubclass(ParameterFileError, ValueError)


def test_hash_inputs_is_deterministic_and_sensitive():
    a = np.arange(12.0).reshape(4, 3)
    h = hash_inputs(a, a + 1)
    assert h == hash_inputs(a.copy(), a + 1) and len(h) == 64 and int(h, 16) >= 0
    assert hash_inputs(np.asfortranarray(a)) == hash_inputs(a)  # logical content, not memory layout
    others = [hash_inputs(a + 1, a), hash_inputs(a), hash_inputs(a, a + 1, a),
              hash_inputs(a.reshape(3, 4), a + 1), hash_inputs(a.astype(np.float32), a + 1),
              hash_inputs(np.nextafter(a, 99), a + 1), hash_inputs(np.concatenate([a, a + 1]))]
    assert len({h, *others}) == len(others) + 1
    with pytest.raises(TypeError):
        hash_inputs(np.array([object()]))


def test_hash_inputs_hashes_its_documented_bytes_of_any_array():
    """The header and the C-order bytes (tobytes) of each array, whatever its dtype, shape or
    layout: read in place, the hash is the one the format defines (and old files hold)."""
    grid = np.arange(24.0).reshape(4, 6)
    arrays = [grid, grid[:, ::2], grid.T, np.float64(3.5), np.zeros((0, 3)), np.array([True, False]),
              np.arange(5, dtype=np.int16), np.array(["2026-11-27T19:00"], dtype="datetime64[s]")]
    expected = hashlib.sha256(b"fieldcal-inputs/1\0")
    for a in arrays:
        arr = np.ascontiguousarray(a)
        expected.update(f"{arr.dtype.str}|{','.join(map(str, arr.shape))}|{arr.nbytes}\0".encode("ascii"))
        expected.update(arr.tobytes())
    assert hash_inputs(*arrays) == expected.hexdigest()


# ------------------------------------------------------------------------------------------------
# Atomic save


def test_save_leaves_no_temp_files_and_replaces(pf, tmp_path):
    target = tmp_path / "cal.yaml"
    target.write_text("old contents\n")
    save(pf, target)
    save(pf, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]
    assert load(target) == pf
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask


def test_a_crash_during_save_keeps_the_old_file(pf, tmp_path, monkeypatch):
    target = tmp_path / "cal.yaml"
    save(pf, target)
    before = target.read_bytes()

    def crash(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError):
        save(pf, target)
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]


# ------------------------------------------------------------------------------------------------
# Bad files: one line, naming the file and the field


# after "<file>: <field>": a wrong value, a missing key or an unknown one (with the nearest name)
_SHAPE = re.compile(r": (expected .+, got .+|missing .+|unknown key .+)( \(line \d+\))?")


def _load_error(path) -> ParameterFileError:
    with pytest.raises(ParameterFileError) as info:
        load(path)
    msg = str(info.value)
    assert "\n" not in msg and "\r" not in msg, msg
    assert str(path) in msg, msg
    return info.value


def _write_doc(path, doc) -> None:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def test_the_documented_message_shape(pf, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    doc = yaml.safe_load(dump(pf))
    doc["triads"]["accelerometer"]["bias"]["y"] = "abc"
    _write_doc(tmp_path / "cal.yaml", doc)
    err = _load_error("cal.yaml")
    assert str(err) == "cal.yaml: triads.accelerometer.bias.y: expected a number, got 'abc' (line 24)"
    assert err.field == "triads.accelerometer.bias.y" and err.path == "cal.yaml"


ACC = "triads.accelerometer"
GYRO = "triads.gyroscope"


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def mutate(doc):
        node = doc
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return mutate


def _delete(*keys):
    def mutate(doc):
        node = doc
        for k in keys[:-1]:
            node = node[k]
        del node[keys[-1]]
    return mutate


def _scale(*keys_and_factor):
    *keys, factor = keys_and_factor

    def mutate(doc):
        node = doc
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] *= factor
    return mutate


def _singular_gyro(doc):
    g = doc["triads"]["gyroscope"]
    g["K"][1] = list(g["K"][0])
    g["K"][1][1], g["K"][0][1] = g["K"][0][0], g["K"][0][0]  # rows equal, diagonal non-zero


MUTATIONS = [
    ("missing bias.y", _delete("triads", "accelerometer", "bias", "y"), f"{ACC}.bias.y"),
    ("missing kind", _delete("triads", "accelerometer", "kind"), f"{ACC}.kind"),
    ("missing K", _delete("triads", "gyroscope", "K"), f"{GYRO}.K"),
    ("missing schema", _delete("schema"), "schema"),
    ("missing station", _delete("provenance", "station"), "provenance.station"),
    ("missing sigma", _delete("triads", "accelerometer", "misalignment", "sigma"), f"{ACC}.misalignment.sigma"),
    ("kind not a string", _set("triads", "accelerometer", "kind", 3), f"{ACC}.kind"),
    ("unknown kind", _set("triads", "accelerometer", "kind", "magnetic_field"), f"{ACC}.kind"),
    ("string for a number", _set("triads", "gyroscope", "scale_factor", "z", "57.3"),
     f"{GYRO}.scale_factor.z"),
    ("dot-less exponent", _set("triads", "accelerometer", "bias", "sigma", "x", "1e-5"),
     f"{ACC}.bias.sigma.x"),
    ("bool for a number", _set("triads", "accelerometer", "bias", "x", True), f"{ACC}.bias.x"),
    ("null for a number", _set("triads", "accelerometer", "residual_rms", "value", None),
     f"{ACC}.residual_rms.value"),
    ("NaN", _set("triads", "accelerometer", "scale_factor", "sigma", "y", math.nan),
     f"{ACC}.scale_factor.sigma.y"),
    ("infinity in K", _set("triads", "gyroscope", "K", 2, 1, math.inf), f"{GYRO}.K[2][1]"),
    ("list for a number", _set("provenance", "station", "height_m", [1.0]), "provenance.station.height_m"),
    ("negative sigma", _set("triads", "gyroscope", "misalignment", "sigma", "delta_zx", -1e-6),
     f"{GYRO}.misalignment.sigma.delta_zx"),
    ("negative residual", _set("triads", "gyroscope", "residual_rms", "value", -1.0),
     f"{GYRO}.residual_rms.value"),
    ("K row too short", lambda d: d["triads"]["gyroscope"]["K"][1].pop(), f"{GYRO}.K[1]"),
    ("K with 4 rows", lambda d: d["triads"]["gyroscope"]["K"].append([0.0, 0.0, 1.0]), f"{GYRO}.K"),
    ("K a flat list", _set("triads", "accelerometer", "K", [1.0] * 9), f"{ACC}.K"),
    ("vector with a 4th axis", _set("triads", "accelerometer", "bias", "w", 0.0), f"{ACC}.bias.w"),
    ("vector as a list", _set("triads", "accelerometer", "bias", [0.0, 0.0, 0.0]), f"{ACC}.bias"),
    ("sigma missing z", _delete("triads", "gyroscope", "bias", "sigma", "z"), f"{GYRO}.bias.sigma.z"),
    ("singular full K", _singular_gyro, f"{GYRO}.K"),
    ("zero scale factor", _set("triads", "accelerometer", "K", 1, 1, 0.0), f"{ACC}.K[1][1]"),
    ("upper triangle in a norm K", _set("triads", "accelerometer", "K", 0, 2, 1e-4), f"{ACC}.K[0][2]"),
    ("K edited, scale factor not", _scale("triads", "accelerometer", "K", 2, 2, 1 + 1e-7),
     f"{ACC}.scale_factor.z"),
    ("scale factor edited, K not", _scale("triads", "gyroscope", "scale_factor", "x", 1 + 1e-8),
     f"{GYRO}.scale_factor.x"),
    ("misalignment edited, K not", _scale("triads", "accelerometer", "misalignment", "delta_yz", 1.001),
     f"{ACC}.misalignment.delta_yz"),
    ("K edited, misalignment not", _scale("triads", "gyroscope", "K", 2, 0, 0.5),
     f"{GYRO}.misalignment.delta_zy"),
    ("unknown schema version", _set("schema", "fieldcal-parameters/2"), "schema"),
    ("foreign schema", _set("schema", "imucal/1"), "schema"),
    ("wrong bias unit", _set("triads", "accelerometer", "bias", "unit", "mg"), f"{ACC}.bias.unit"),
    ("wrong input unit", _set("triads", "gyroscope", "input_unit", "deg/s"), f"{GYRO}.input_unit"),
    ("wrong scale unit", _set("triads", "gyroscope", "scale_factor", "unit", "deg/s"),
     f"{GYRO}.scale_factor.unit"),
    ("angles in degrees", _set("triads", "gyroscope", "misalignment", "unit", "deg"),
     f"{GYRO}.misalignment.unit"),
    ("unknown key", _set("triads", "accelerometer", "temperature", 25.0), f"{ACC}.temperature"),
    ("unknown top-level key", _set("created", "2024-05-01"), "created"),
    ("latitude out of range", _set("provenance", "station", "latitude_deg", 91.0),
     "provenance.station.latitude_deg"),
    ("zero gravity", _set("provenance", "station", "gravity_m_s2", 0.0), "provenance.station.gravity_m_s2"),
    ("gravity of a neutron star", _set("provenance", "station", "gravity_m_s2", 1e6),
     "provenance.station.gravity_m_s2"),
    ("station deep underground", _set("provenance", "station", "height_m", -1e9), "provenance.station.height_m"),
    ("unknown gravity source", _set("provenance", "station", "gravity_source", "guessed"),
     "provenance.station.gravity_source"),
    ("unknown triad method", _set("triads", "gyroscope", "method", "voodoo"), f"{GYRO}.method"),
    ("unknown file method", _set("provenance", "method", "powell+voodoo"), "provenance.method"),
    ("bad hash", _set("provenance", "input_sha256", "abc123"), "provenance.input_sha256"),
    ("simulation not a bool", _set("provenance", "simulation", "yes please"), "provenance.simulation"),
    ("serial as a number", _set("provenance", "device", "serial", 123), "provenance.device.serial"),
    ("operator with a line break", _set("provenance", "operator", "A.\nNg"), "provenance.operator"),
    ("operator blank", _set("provenance", "operator", "  "), "provenance.operator"),
    ("no triads", _set("triads", {}), "triads"),
    ("triad not a mapping", _set("triads", "gyroscope", "classic"), GYRO),
]


@pytest.mark.parametrize("mutate, field", [m[1:] for m in MUTATIONS], ids=[m[0] for m in MUTATIONS])
def test_a_bad_field_is_named_in_one_line(pf, tmp_path, mutate, field):
    doc = yaml.safe_load(dump(pf))
    mutate(doc)
    path = tmp_path / "cal.yaml"
    _write_doc(path, doc)
    err = _load_error(path)
    assert _SHAPE.fullmatch(str(err)[len(f"{path}: {field}"):]), str(err)
    assert err.field == field


@pytest.mark.parametrize("where, value, nearest", [
    (("triads", "accelerometer", "method"), "powel", "powell"),
    (("triads", "gyroscope", "method"), "clasic", "classic"),
    (("provenance", "method"), "powell+rotaton", "rotation"),
    (("provenance", "station", "gravity_source"), "measurd", "measured"),
])
def test_an_unknown_name_is_answered_with_the_nearest_valid_one(pf, tmp_path, where, value, nearest):
    doc = yaml.safe_load(dump(pf))
    _set(*where, value)(doc)
    path = tmp_path / "cal.yaml"
    _write_doc(path, doc)
    err = str(_load_error(path))
    assert err.startswith(f"{path}: {'.'.join(where)}: expected ") and "\n" not in err
    assert f"{nearest!r}" in err.split(", got ")[1], err


def test_constructors_hold_the_station_and_methods_to_the_loaders_bounds():
    ok = dict(procedure="p", method="powell", input_sha256="0" * 64, latitude_deg=0.0, height_m=0.0,
              gravity_m_s2=9.8, gravity_source="measured")
    Provenance(**ok)
    for field, bad in (("gravity_m_s2", 1e6), ("height_m", -1e9), ("method", "voodoo"),
                       ("gravity_source", "guessed")):
        with pytest.raises(ValueError, match=f"provenance.{field}"):
            Provenance(**{**ok, field: bad})
    with pytest.raises(ValueError, match="x.method.*nearest"):
        TriadParameters(name="x", kind=SPECIFIC_FORCE, output_unit="m/s^2", bias=np.zeros(3),
                        K=np.eye(3), sigma=np.zeros(9), residual_rms=0.0, method="voodoo")


def test_a_number_string_gets_a_hint(pf, tmp_path):
    doc = yaml.safe_load(dump(pf))
    doc["triads"]["accelerometer"]["bias"]["sigma"]["x"] = "1e-5"
    _write_doc(tmp_path / "cal.yaml", doc)
    assert "1.0e-05" in str(_load_error(tmp_path / "cal.yaml"))


def test_changes_within_the_tolerance_are_accepted_and_K_wins(pf, tmp_path):
    doc = yaml.safe_load(dump(pf))
    sf = doc["triads"]["accelerometer"]["scale_factor"]
    sf["x"] *= 1 + 1e-12
    _write_doc(tmp_path / "cal.yaml", doc)
    assert load(tmp_path / "cal.yaml") == pf


def _nodes(node, path=()):
    """Every (path, value) below the root, depth first."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield (*path, key), value
        yield from _nodes(value, (*path, key))


def _dotted(keys) -> str:
    out = ""
    for k in keys:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else k)
    return out


OPTIONAL = {("provenance", "simulation"), ("provenance", "device"), ("provenance", "device", "name"),
            ("provenance", "device", "serial")}
NOT_A_STRING = [1.5, None, True, [], {}, ["a"]]
NOT_A_NUMBER = ["abc", "1.5", None, True, False, math.nan, math.inf, -math.inf, [1.0], {}, {"x": 1.0}]
NOT_A_MAPPING = ["abc", 1.5, None, True, [], [1.0, 2.0, 3.0]]


@pytest.fixture(scope="module")
def pf_document(pf) -> dict:
    """pf's file as YAML reads it, parsed once: each example below breaks a deep copy (parsing it
    again in each, from a new dump, was half of the test's CPU)."""
    return yaml.safe_load(dump(pf))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_broken_field_is_named(pf_document, tmp_path_factory, data):
    """Delete any required key or give any node a value of the wrong type: one line naming it."""
    doc = copy.deepcopy(pf_document)
    nodes = list(_nodes(doc))
    keys, value = data.draw(st.sampled_from(nodes), label="node")
    if isinstance(value, bool):
        replacements = ["abc", 1.5, [], {}]
    elif isinstance(value, str):
        replacements = NOT_A_STRING
    elif isinstance(value, float):
        replacements = NOT_A_NUMBER
    elif isinstance(value, dict):
        replacements = NOT_A_MAPPING
    else:  # a K matrix or row
        replacements = ["abc", 1.5, None, {}, [1.0, 2.0]]
    # deleting one of two triads leaves a valid file; deleting a K element is a short row
    deletable = keys not in OPTIONAL and not isinstance(keys[-1], int) and keys[:-1] != ("triads",)
    choice = data.draw(st.sampled_from((["<delete>"] if deletable else []) + replacements), label="change")
    if keys in OPTIONAL and choice is None:
        return  # null means "not given" for optional fields
    parent = doc
    for k in keys[:-1]:
        parent = parent[k]
    if choice == "<delete>":
        del parent[keys[-1]]
    else:
        parent[keys[-1]] = copy.deepcopy(choice)
    path = tmp_path_factory.mktemp("broken") / "cal.yaml"
    _write_doc(path, doc)
    err = _load_error(path)
    assert err.field == _dotted(keys), str(err)
    assert str(err).startswith(f"{path}: {err.field}: "), str(err)
    assert _SHAPE.fullmatch(str(err)[len(f"{path}: {err.field}"):]), str(err)


FILE_PROBLEMS = [
    ("not YAML", b"schema: [fieldcal-parameters/1\ntriads: {\n"),
    ("bad indentation", b"schema: x\n  triads: 1\n - a\n"),
    ("empty file", b""),
    ("only a comment", b"# nothing here\n"),
    ("a list", b"- schema\n- triads\n"),
    ("a scalar", b"fieldcal-parameters/1\n"),
    ("not UTF-8", b"schema: \xff\xfe\x00bad\n"),
    ("an impossible date", b"schema: 2024-02-30\n"),
    ("a python tag", b"schema: !!python/object/apply:os.system ['true']\n"),
    ("a duplicate key", b"schema: fieldcal-parameters/1\nschema: fieldcal-parameters/1\n"),
]


@pytest.mark.parametrize("content", [c for _, c in FILE_PROBLEMS], ids=[n for n, _ in FILE_PROBLEMS])
def test_a_bad_file_is_one_line_naming_the_file(tmp_path, content):
    path = tmp_path / "cal.yaml"
    path.write_bytes(content)
    err = _load_error(path)
    assert str(err).startswith(f"{path}: ")


def test_a_missing_file_is_one_line(tmp_path):
    err = _load_error(tmp_path / "nope.yaml")
    assert "cannot read" in str(err)
    err = _load_error(tmp_path)  # a directory
    assert "cannot read" in str(err)


def test_a_duplicated_triad_is_rejected_not_merged(pf, tmp_path):
    text = dump(pf)
    triads = text.index("triads:\n")
    block = text[text.index("  accelerometer:\n"):text.index("  gyroscope:\n")]
    path = tmp_path / "cal.yaml"
    path.write_text(text[:triads] + "triads:\n" + block + block)
    err = _load_error(path)
    assert "appears twice" in str(err) and "line " in str(err)


def test_build_from_triads_and_a_station(norm_solution, classic_solution, averages):
    triads = [norm_solution, classic_solution]
    sha = hash_inputs(averages[0], averages[2])
    pf = ParameterFile.build(triads, station=STATION, procedure="field-18", method="powell",
                             input_sha256=sha, simulation=True)
    assert pf.provenance.gravity_m_s2 == STATION.gravity
    assert pf.provenance.gravity_source == STATION.gravity_source == "WGS84 normal gravity"
    assert pf["gyroscope"] is pf.triads[1] and pf.provenance.device_name is None
    with pytest.raises(KeyError):
        pf.triad("magnetometer")
    with pytest.raises(ValueError, match="exactly one"):
        ParameterFile.from_solutions([norm_solution], station=STATION, procedure="p")
    measured = Station(latitude_deg=10.0, gravity_m_s2=9.78)
    pf = ParameterFile.build(triads, station=measured, procedure="p", method="classic", input_sha256=sha)
    assert pf.provenance.gravity_source == "measured" and pf.provenance.gravity_m_s2 == 9.78
    assert "simulation" not in yaml.safe_load(dump(pf))["provenance"]
