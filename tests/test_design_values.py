"""Design values are checked once, each by its Param (pipeline/design_values.py, issue 29)."""

from __future__ import annotations

import math

import pytest

from trackreplay import design_values
from trackreplay.errors import InputError
from trackreplay.stages import stage_named
from trackreplay.trackers.interface import Param


def test_a_param_refuses_a_value_outside_its_bounds_or_not_finite():
    gate = Param("gate_m", 1.0, low=0.0, high=math.inf)
    gate.check(2.5)
    with pytest.raises(ValueError, match=r"^gate_m = 0 must be in \(0, inf\)$"):
        gate.check(0.0)
    with pytest.raises(ValueError, match=r"^gate_m = nan must be finite$"):
        gate.check(float("nan"))
    # without bounds only a value that is not finite is refused
    free = Param("x", 1.0)
    free.check(-1e300)
    free.check("text")
    with pytest.raises(ValueError, match=r"^x = inf must be finite$"):
        free.check(math.inf)


@pytest.mark.parametrize(("stage", "key", "value", "message"), [
    ("radar", "ospa_cutoff_m", -1.0, "design value ospa_cutoff_m = -1 must be in (0, inf)"),
    ("radar", "ospa_order", 0.5, "design value ospa_order = 0.5 must be in (0.999999, 100)"),
    ("array", "track_gate_deg", 180.0, "design value track_gate_deg = 180 must be in (0, 180)"),
    ("array", "spacing_wavelengths", 0.0, "design value spacing_wavelengths = 0 must be in (0, 1e+06)"),
    ("radar", "sigma_range_m", math.inf, "design value sigma_range_m = inf must be finite"),
])
def test_a_stage_refuses_its_own_design_values_by_their_params(stage, key, value, message):
    with pytest.raises(InputError) as caught:
        design_values.check(stage_named(stage), {key: value})
    assert caught.value.problem == message


def test_an_unknown_value_is_left_to_the_tracker_that_needs_it():
    # None: a sensor value a recording does not say; the tracker needing it stops, not the resolution
    design_values.check(stage_named("array"), {"spacing_wavelengths": None, "ospa_cutoff_deg": None})


def test_every_stage_declares_its_checked_values_as_params():
    for name in ("radar", "xcorr", "array", "tdoa-fdoa", "colored"):
        stage = stage_named(name)
        params = design_values.stage_params(stage)
        assert set(stage.evaluation_defaults) <= set(params), name
        assert all(isinstance(p, Param) for p in params.values()), name
