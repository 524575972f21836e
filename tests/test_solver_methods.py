"""fieldcal.solvers.methods: which solver "auto" means, and the refusal of an unknown one
(the mutation run of fieldcal/solvers, docs/benchmarks.md)."""
import pytest

from fieldcal.procedure.positions import load_procedure
from fieldcal.solvers.methods import resolve_method


def test_auto_is_classic_for_an_aligned_procedure_and_powell_otherwise():
    aligned, field = load_procedure("classic-12"), load_procedure("field-18")
    assert aligned.aligned and not field.aligned
    assert resolve_method(aligned, "auto") == "classic"
    assert resolve_method(field, "auto") == "powell"
    for method in ("powell", "lsq", "classic"):  # a method asked for by name is kept
        assert resolve_method(aligned, method) == method and resolve_method(field, method) == method


def test_an_unknown_method_is_refused_naming_the_choices():
    with pytest.raises(ValueError) as raised:
        resolve_method(load_procedure("field-18"), "newton")
    assert str(raised.value) == "method: expected one of auto, powell, lsq, classic, got 'newton'"
