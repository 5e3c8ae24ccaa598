"""Typed parameter values: taken as typed inside the solver's limits, clamped with a note outside, refused with
a note when not a number; slider ranges on their step grid."""

from __future__ import annotations

import pytest

from neuraldem.scenes.hopper.parameters import PARAMETERS
from neuraldem.serve.inputs import parameter_value, typed_value


def test_a_value_inside_the_solver_limits_is_taken_as_typed():
    checked = typed_value("alpha", "70", PARAMETERS.limits("alpha"))  # beyond the trained range: the GP warns
    assert checked.value == 70.0 and checked.note == ""


@pytest.mark.parametrize(("text", "value", "note"), [
    ("99", 75.0, "alpha=99 is outside what the solver can run (0 .. 75): clamped to 75"),
    ("-5", 0.0, "alpha=-5 is outside what the solver can run (0 .. 75): clamped to 0"),
])
def test_a_value_beyond_the_solver_limits_is_clamped_with_a_note(text, value, note):
    checked = typed_value("alpha", text, PARAMETERS.limits("alpha"))
    assert checked.value == value and checked.note == note


@pytest.mark.parametrize("text", ["abc", "", "nan", "inf"])
def test_text_that_is_no_finite_number_keeps_the_old_value(text):
    checked = typed_value("mu_s", text, PARAMETERS.limits("mu_s"))
    assert checked.value is None and "the previous value is kept" in checked.note and "mu_s" in checked.note


def test_slider_values_and_typed_values_are_one_point():
    assert parameter_value(40.49999999999999) == parameter_value(40.5) == 40.5
    assert parameter_value(0.1 + 0.2) == 0.3


def test_the_slider_spans_the_trained_range_on_its_step_grid():
    from neuraldem.scenes.hopper.explorer.page import slider_range

    assert slider_range(0.166162, 59.812773, 0.5) == (0.5, 59.5)
    assert slider_range(0.051715, 0.997082, 0.01) == (0.06, 0.99)
    assert slider_range(0.0, 1.0, 0.25) == (0.0, 1.0)
