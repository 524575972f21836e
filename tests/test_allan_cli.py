"""fieldcal allan on a text record with known noise, on a session, and on bad input."""
import re

import numpy as np
import pytest

from drivers.sim.device import PAPER_NOISE
from drivers.sim.noise import NoiseGenerator
from fieldcal.cli.main import main


def test_text_record_gives_the_noise_it_was_made_with(tmp_path, capsys):
    rate = 50.0
    noise = PAPER_NOISE["accelerometer"]
    samples = NoiseGenerator(noise, rate, np.random.default_rng(3)).draw(int(2 * 3600 * rate))
    path = tmp_path / "still.csv"
    t = np.arange(len(samples)) / rate
    np.savetxt(path, np.column_stack([t, samples + [0, 0, 9.8]]), delimiter=",", fmt="%.9g",
               header="t,x,y,z")
    assert main(["allan", str(path), "--kind", "specific_force"]) == 0
    out = capsys.readouterr().out
    vrw = [float(v) for v in re.findall(r"VRW ([0-9.]+) m/s/sqrt\(h\)", out)]
    assert len(vrw) == 3 and all(abs(v / 0.06 - 1) < 0.1 for v in vrw)  # paper Table 4: 0.06
    assert "recommended dwell" in out
    png = tmp_path / "allan-accelerometer.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_session_record(tmp_path, capsys):
    procedure = tmp_path / "still-20min.yaml"
    procedure.write_text("name: still\ndwell_s: 1200\npositions:\n"
                         "  - {id: 1, description: z up, axes: {x: south, y: east, z: up}}\n")
    main(["run", "--headless", "--procedure", str(procedure), "--out", str(tmp_path), "--quiet"])
    session = next(tmp_path.glob("still-seed1-*"))
    capsys.readouterr()
    assert main(["allan", str(session), "--triad", "gyroscope"]) == 0
    out = capsys.readouterr().out
    assert "gyroscope: 300000 samples at 250 Hz" in out  # the dwell only, not the handling
    arw = [float(v) for v in re.findall(r"ARW ([0-9.]+) deg/sqrt\(h\)", out)]
    assert all(abs(v / 0.15 - 1) < 0.1 for v in arw)
    assert (session / "allan-gyroscope.png").exists()


@pytest.mark.parametrize("content, message", [
    ("1,2,3\n" * 200, "expected at least 100 rows of 4 numbers 't, x, y, z', got 200 rows of 3"),
    ("".join(f"{i % 7},1,2,3\n" for i in range(200)), "time (first column) must increase on every row"),
    ("a,b,c,d\n" * 200, "expected rows of 4 numbers 't, x, y, z'"),
])
def test_bad_text_record_is_one_line(tmp_path, capsys, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    assert main(["allan", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err and "bad.csv" in err
