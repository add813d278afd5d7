"""Every family's evaluation gate and cut-off follow the data set's measurement noise by the one
rule of pipeline/stages/evaluation_gates.py (docs/evaluation.md, "Evaluation design values");
a value the file records or --set gives wins, and a file that says nothing keeps the fixed ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trackreplay import design_values
from trackreplay.contract import read_dataset, write_dataset
from trackreplay.stages import stage_named
from trackreplay.stages.evaluation_gates import gate_sigmas, round_up

DATA = Path(__file__).resolve().parents[1] / "data"


def _gates(stage: str, path: Path, overrides=None) -> dict:
    design = design_values.resolve(stage_named(stage), read_dataset(path), overrides)
    return {k: design[k] for k in design if k.startswith(("assignment_gate_", "ospa_cutoff_"))}


@pytest.mark.parametrize("stage, demo, unit, dims, spread", [
    ("xcorr", "xcorr_crossing_demo", "deg", 1, 1.8),            # the weak target's peaks, σ 1.8°
    ("colored", "colored_imm_demo", "m", 2, np.sqrt(200.0)),  # σ² = 100 m² on each axis
])
def test_the_gate_is_the_rule_applied_to_the_recorded_noise(stage, demo, unit, dims, spread):
    gate = round_up(gate_sigmas(dims) * spread)
    assert _gates(stage, DATA / f"{demo}.mcap") == {f"assignment_gate_{unit}": gate, f"ospa_cutoff_{unit}": 2 * gate}


def test_the_emitter_gate_is_the_joint_crlb_at_the_truth():
    # the demo's √tr of the joint CRLB's position block is 663 m at its one geometry
    assert _gates("tdoa-fdoa", DATA / "tdoa_fdoa_demo.mcap") == {"assignment_gate_m": 2900.0, "ospa_cutoff_m": 5800.0}


def test_set_wins_and_the_array_family_keeps_its_fixed_values():
    got = _gates("xcorr", DATA / "xcorr_crossing_demo.mcap", {"assignment_gate_deg": "4"})
    assert got == {"assignment_gate_deg": 4.0, "ospa_cutoff_deg": 14.2}
    assert _gates("array", DATA / "array_crossing_demo.mcap") == {"assignment_gate_deg": 3.0,
                                                                         "ospa_cutoff_deg": 10.0}


def test_a_recording_that_does_not_say_its_noise_keeps_the_fixed_values(tmp_path):
    ds = read_dataset(DATA / "colored_imm_demo.mcap")
    ch = ds.channel("/colored/measurements")
    bare = tmp_path / "bare.mcap"
    with write_dataset(bare) as w:  # no record: the noise variance is unknown
        w.write_grid("/colored/measurements", ch.times(), {"position_m": ch.grid("position_m")})
    assert _gates("colored", bare) == {"assignment_gate_m": 50.0, "ospa_cutoff_m": 100.0}
    # the variance given on the command line is the data set's noise, so the gate follows it
    assert _gates("colored", bare, {"measurement_variance_m2": "25"}) == {"assignment_gate_m": 31.0,
                                                                                   "ospa_cutoff_m": 62.0}
