"""The parameter file's ``bias_at_end`` section (issue 22): additive and optional. Written with its
σ and the time it holds at, read back bit for bit, a file without it still loads (and a replay of
a session whose run wrote none still confirms it), a bad field is one line naming it; and the
solver's predictor against a hand-worked case."""
import dataclasses

import numpy as np
import pytest
import yaml

from drivers.noise import TriadNoise
from fieldcal.calibration import BiasAtEnd
from fieldcal.earth import Station
from fieldcal.model import distort_with
from fieldcal.paramfile import ParameterFile, ParameterFileError, dump, loads
from fieldcal.solvers import StaticNormProblem, solve_norm

STATION = Station(latitude_deg=40.0, height_m=50.0)
THETA = np.array([0.05, -0.03, 0.02, 1.001, 0.998, 1.002, 1e-3, -2e-3, 5e-4])
END = BiasAtEnd(value=[0.051, -0.029, 0.0205], covariance=np.diag([4e-8, 5e-8, 6e-8]), time_s=1234.5)


def directions(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    return np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])


@pytest.fixture(scope="module")
def solution():
    means = distort_with(THETA, STATION.gravity * directions(18))
    means = means + np.random.default_rng(3).normal(scale=2e-4, size=means.shape)
    return solve_norm(StaticNormProblem(means, STATION.gravity), np.full(means.shape, 2e-4)), means


def file_of(cal, means) -> ParameterFile:
    return ParameterFile.from_solutions([cal], station=STATION, procedure="p", inputs=[means])


def test_written_read_back_bit_for_bit_and_without_it_as_before(solution):
    cal, means = solution
    with_end = file_of(dataclasses.replace(cal, bias_at_end=END), means)
    text = dump(with_end)
    doc = yaml.safe_load(text)["triads"]["accelerometer"]["bias_at_end"]
    assert doc == {"x": 0.051, "y": -0.029, "z": 0.0205, "unit": "m/s^2",
                   "sigma": {a: float(np.sqrt(v)) for a, v in zip("xyz", (4e-8, 5e-8, 6e-8))}, "time_s": 1234.5}
    back = loads(text)
    assert back == with_end and dump(back) == text
    end = back["accelerometer"].bias_at_end
    assert end.value.tobytes() == END.value.tobytes() and end.sigma.tobytes() == END.sigma.tobytes()
    # a file from before the section: loads, with none, and its text is what that fieldcal wrote
    without = file_of(cal, means)
    assert "bias_at_end" not in dump(without) and loads(dump(without))["accelerometer"].bias_at_end is None
    assert loads(dump(without)) != with_end


@pytest.mark.parametrize("mutate, field", [
    (lambda e: e.update(unit="mg"), "bias_at_end.unit"),
    (lambda e: e["sigma"].update(y=-1.0), "bias_at_end.sigma.y"),
    (lambda e: e.pop("time_s"), "bias_at_end.time_s"),
    (lambda e: e.update(when=3), "bias_at_end"),
])
def test_a_bad_field_is_one_line_naming_it(solution, mutate, field):
    cal, means = solution
    doc = yaml.safe_load(dump(file_of(dataclasses.replace(cal, bias_at_end=END), means)))
    mutate(doc["triads"]["accelerometer"]["bias_at_end"])
    with pytest.raises(ParameterFileError) as caught:
        loads(yaml.safe_dump(doc, sort_keys=False), "cal.yaml")
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"cal.yaml: triads.accelerometer.{field}")


def test_a_replay_of_a_run_from_before_the_section_compares_the_rest(solution):
    from fieldcal.run.environment import compare_parameters, numeric_environment

    cal, means = solution
    recorded = dump(file_of(cal, means)).encode()
    replayed = file_of(dataclasses.replace(cal, bias_at_end=END), means)
    assert compare_parameters(replayed, recorded, numeric_environment()).identical
    moved = file_of(dataclasses.replace(cal, bias_at_end=END, residual_rms=cal.residual_rms * 2), means)
    assert not compare_parameters(moved, recorded, numeric_environment()).identical


def test_with_white_noise_alone_the_bias_at_the_end_is_the_constant():
    """No bias process: nothing in the residuals is correlated with the bias at the end, so the
    predictor is the solved constant itself, with its covariance (by hand: Ĝ = 0, V = 0)."""
    from fieldcal.solvers.endbias import bias_at_end
    from fieldcal.solvers.solve import TriadModel, average_covariance
    from fieldcal.procedure.windows import STATIC, Window

    n = 18
    windows = [Window(STATIC, i, 100.0 * i, 50.0) for i in range(n)]
    K = np.diag(THETA[3:6])
    truth_means = distort_with(THETA, STATION.gravity * directions(n))
    means = truth_means + np.random.default_rng(5).normal(scale=3e-4, size=truth_means.shape)
    for noise in (TriadNoise(white=3e-4 * np.sqrt(50.0)),):  # 3e-4 m/s² per 50 s window
        model = TriadModel("specific_force", "m/s^2", noise, K)
        cov = average_covariance(model, windows, 250.0)
        problem = StaticNormProblem(means, STATION.gravity)
        cal = solve_norm(problem, cov)
        end = bias_at_end(problem, cal, noise, K, [w.start for w in windows], [w.duration for w in windows],
                          2000.0, cov)
        np.testing.assert_allclose(end.value, cal.theta[:3], rtol=0, atol=1e-15)
        np.testing.assert_allclose(end.covariance, cal.covariance[:3, :3], rtol=1e-4)
        assert end.time_s == 2000.0
