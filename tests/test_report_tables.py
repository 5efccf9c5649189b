"""The tables a reader sees: the quick digital report without a column of dashes, Table 3 with one notation per
column, and the printed RMS table with its columns aligned."""
from __future__ import annotations

import numpy as np
import pytest


def _quantized_paper():
    from blocks.scenarios.scenario import load_scenario
    q0 = [0.3, 1.2, 0.1, 0.2]
    return load_scenario("paper").with_changes({
        "trajectory.kind": "joint_sine", "trajectory.amplitude": [0.0] * 4, "trajectory.offset": q0,
        "simulation.t_final": 0.3, "controller.sample_rate": 1000.0,
        "controller.position_resolution": [2 * np.pi / 2 ** 17] * 2 + [1e-6, 2 * np.pi / 2 ** 17]}), q0


def test_quick_digital_report_says_the_noise_was_not_simulated():
    from types import SimpleNamespace

    from analysis.linear.digital import digital_analysis
    from analysis.report.settings import QUICK_SETTINGS
    from analysis.report.view import _header
    from analysis.report.view.digital import digital_section

    scenario, q0 = _quantized_paper()
    analysis = digital_analysis(scenario, rates_hz=(1000.0,), configurations=[np.array(q0)], simulate_noise=False)
    assert analysis.quantization is not None and analysis.quantization.simulated_rms is None
    result = SimpleNamespace(digital=analysis, settings=QUICK_SETTINGS)      # the two fields the views read
    table = digital_section(result, {}, scenario.robot).quantization
    assert table.header == ["joint", "resolution", "torque noise, linear model"]
    assert all(cell.text != "-" for row in table.rows for cell in row)
    assert "does not simulate" in table.caption
    banner = _header(result, scenario).preview
    assert any("torque noise from encoder quantization" in item and "not simulated" in item for item in banner)


def test_table3_uses_one_notation_per_joint_column():
    from analysis.report.view.simulation import simulation_section
    from blocks.scenarios.scenario import load_scenario

    # the README's Table 3 magnitudes (every joint better with the observer, so no explanation is asked for)
    w = {"rms_position_error": [6.32e-5, 2.33e-4, 3.78e-4, 3.54e-4],
         "max_abs_position_error": [1.613e-4, 9.1e-4, 1.2e-3, 8.0e-4],
         "rms_disturbance_error": [0.339, 0.25, 0.0545, 0.0961]}
    wo = {"rms_position_error": [1.61e-4, 5.34e-3, 3.07e-2, 9.75e-3],
          "max_abs_position_error": [3.0e-4, 8.2e-3, 3.11e-2, 1.2e-2]}
    experiment = {"with_dob": w, "without_dob": wo}
    table = simulation_section(None, experiment, load_scenario("paper"), {}).metrics
    numeric = [row for row in table.rows if not row[0].text.strip().startswith("units")]
    assert len(numeric) == 5
    for j in range(1, 5):
        cells = [row[j].text for row in numeric]
        assert len({"e" in c for c in cells}) == 1, cells          # all scientific or all fixed
        expected = [w["rms_position_error"][j - 1], wo["rms_position_error"][j - 1],
                    w["max_abs_position_error"][j - 1], wo["max_abs_position_error"][j - 1],
                    w["rms_disturbance_error"][j - 1]]
        assert [float(c) for c in cells] == pytest.approx(expected, rel=5e-4)
    # joint 1 has 6.32e-5 (which %.4g writes in scientific notation) and 0.339: the column is scientific
    assert [row[1].text for row in numeric] == ["6.320e-05", "1.610e-04", "1.613e-04", "3.000e-04", "3.390e-01"]


def test_the_printed_rms_table_keeps_its_columns_aligned():
    """Every number ends under its 'Joint i' heading, whichever label its row has (the longest is 35 characters)."""
    from analysis.simulation.experiment import format_rms_table
    row = {"rms_position_error": [1.6112e-04, 2.3299e-04, 3.7777e-04, 3.5417e-04],
           "rms_disturbance_error": [0.34, 0.25, 0.055, 0.096], "max_tool_position_error_mm": 2.913}
    metrics = {"units": {"position": ["rad", "rad", "m", "rad"], "disturbance": ["N m", "N m", "N", "N m"]},
               "with_dob": row, "without_dob": {k: v for k, v in row.items() if k != "rms_disturbance_error"}}
    lines = format_rms_table(metrics).splitlines()
    ends = [lines[0].index(f"Joint {i}") + len(f"Joint {i}") for i in range(1, 5)]
    numeric = [line for line in lines if "tracking" in line]
    assert len(numeric) == 3
    for line in numeric:
        assert [line.index(text) + len(text) for text in line.split()[-4:]] == ends, line
