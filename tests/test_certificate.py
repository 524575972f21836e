"""The HTML certificate of a simulated unit's session, parsed: self-contained, every parameter of
the file with its value and σ, PASS/FAIL per the spec, the file's SHA-256 as recorded."""
import hashlib
from html.parser import HTMLParser
from pathlib import Path

import pytest

from fieldcal.acceptance import operator_values
from fieldcal.cli.main import main
from fieldcal.paramfile import load

QUICK = str(Path(__file__).parent / "faults" / "quick.yaml")


class Page(HTMLParser):
    """Tables as lists of rows of cell text; every tag's attributes; the facts table as a dict."""

    def __init__(self, text):
        super().__init__()
        self.tables, self.attrs, self._cell = [], [], None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.attrs.append((tag, dict(attrs)))
        if tag == "table":
            self.tables.append((dict(attrs), []))
        elif tag == "tr":
            self.tables[-1][1].append([])
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self.tables[-1][1][-1].append(self._cell)
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("cert")
    assert main(["run", "--headless", "--quiet", "--procedure", QUICK, "--out", str(root / "s"),
                 "--seed", "12", "--registry", str(root / "r.sqlite")]) == 0
    [directory] = (root / "s").iterdir()
    return directory


def test_certificate_holds_every_parameter_and_the_verdict(tmp_path, capsys, session):
    spec = tmp_path / "spec.yaml"  # paper_mimu's accelerometer bias z is 3 mg: capped at 2.5 mg
    spec.write_text("schema: fieldcal-spec/1\nproduct: paper MIMU\ntriads:\n"
                    "  accelerometer: {bias: {unit: mg, min: -10, max: 2.5}}\n")
    out = tmp_path / "cert.html"
    assert main(["certificate", str(session), "--spec", str(spec), "--out", str(out)]) == 3
    page = Page(out.read_text(encoding="utf-8"))
    # self-contained: nothing fetched from anywhere
    assert not [a for _, a in page.attrs if "src" in a or "href" in a]
    assert not any(tag in ("script", "link", "img", "iframe") for tag, _ in page.attrs)
    facts = dict(page.tables[0][1])
    params = session / "parameters-001.yaml"
    sha = hashlib.sha256(params.read_bytes()).hexdigest()
    assert facts["Parameter file"] == f"parameters-001.yaml, SHA-256 {sha} (verified)"
    assert facts["Acceptance"] == "FAIL against paper MIMU"
    assert "g = " not in facts["Local gravity"] and "m/s²" in facts["Local gravity"]
    pf = load(params)
    triads = {a["data-triad"]: rows for a, rows in page.tables[1:]}
    assert set(triads) == set(pf.names)
    for cal in pf.triads:
        rows = triads[cal.name][1:]
        values, sigmas, units = operator_values(cal)
        assert len(rows) == len(cal.parameter_names)
        for row, v, s, u in zip(rows, values, sigmas, units):
            assert float(row[1]) == pytest.approx(v, rel=1e-6, abs=1e-12)
            assert float(row[2]) == pytest.approx(s, rel=1e-2)
            assert row[3] == u
    results = {row[0]: row[4] for row in triads["accelerometer"][1:]}
    assert results["bias z"].startswith("FAIL: ") and "above the maximum 2.5 mg" in results["bias z"]
    assert all(r == "PASS" for name, r in results.items() if name != "bias z")
    # written again only with --force
    assert main(["certificate", str(session), "--out", str(out)]) == 2
    assert main(["certificate", str(session), "--out", str(out), "--force"]) == 0
    assert "Acceptance" not in dict(Page(out.read_text(encoding="utf-8")).tables[0][1])
