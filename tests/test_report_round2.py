"""What a reader sees in reports and figures, round 2 (issue 21, item 4): counts from one source, units a
reader expects, one number format per column and figures that say what they draw."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from analysis.tune.report import evaluations_text, html_section, write_figures
from analysis.tune.results import PointResult, TuneFigure, TuneHistory, TuneResult
from dobkit.tune_commands import _summary, constraint_lines


# --------------------------------------------------------------------------------------------
# The tuning's evaluation counts
# --------------------------------------------------------------------------------------------
def _point(objective: float) -> PointResult:
    return PointResult(gains={"gains.kp": 100.0}, objective=objective, worst=objective, mean=objective,
                       values=[objective] * 3, nominal=objective, torque_noise_rms=[1.0, 1.0, 0.01, 0.5],
                       peak_torque=[30.0, 30.0, 5.0, 28.0], spectral_abscissa=-2.0, violations={},
                       feasible=True, diverged=0)


def _tuning() -> TuneResult:
    """A history counted by hand: 1 base, 6 search, 4 polish, 1 final = 12 evaluations; 5 refused (not
    simulated); of the 7 with a simulation, 4 simulated now, 1 from the log, so 2 repeats."""
    phase = ["base"] + ["search"] * 6 + ["polish"] * 4 + ["final"]
    simulated = [True, True, False, True, False, True, False, True, False, False, True, True]
    objective = [2.0 if s else None for s in simulated]
    history = TuneHistory(phase=phase, objective=objective, feasible=list(simulated), simulated=simulated)
    return TuneResult(name="t", source="t.toml", description="", definition="abc", scenario="paper",
                      objective="worst", metric="rms_tool_error_mm", runs=3, parameters=["gains.kp"],
                      units=["1/s^2"], bounds=[[50.0, 500.0]], limits={"torque_noise_rms": [2.0, 2.0, 0.02, 1.0]},
                      base=_point(2.0), tuned=_point(1.5), feasible=True, message="Tuned gains", history=history,
                      evaluations={"search": 6, "polish": 4, "simulated": 4, "from_log": 1, "linear_only": 5},
                      seconds=1.0, scenario_file="t-tuned.toml")


COUNTS = ("12 evaluations (1 with the base gains, 6 search, 4 polish, 1 final): 5 refused by the linear "
          "constraints without simulating, 7 with a simulation of the set (4 simulated in this run, 1 taken "
          "from the evaluation log of an earlier, stopped run, 2 repeats of gains already simulated)")


def test_evaluation_counts_are_one_sentence_everywhere(tmp_path):
    result = _tuning()
    assert evaluations_text(result) == COUNTS
    made = write_figures(result, tmp_path / "figures")
    caption = dict(made)["tune_history.png"]
    assert COUNTS in caption
    assert COUNTS in _summary(result, tmp_path)
    # a folder written before the counts had one source: its stored caption is made again from the history
    folder = tmp_path
    stale = TuneFigure(file="tune_history.png", caption="(38 simulated; 59 more refused)")
    result = TuneResult(**{**result.__dict__, "figures": [stale]})
    (folder / "tune.json").write_text(result.to_json(), encoding="utf-8")
    section = re.sub(r"\s+", " ", html_section(folder))
    assert section.count(COUNTS) == 3                   # the paragraph, the caption and the image's alt text
    assert "38 simulated" not in section
    # no second count in other words (the old "36 + 60 evaluations", "simulated now")
    assert "simulated now" not in section and "6 + 4" not in section


def test_tune_output_gives_the_prismatic_joint_newtons():
    lines = "\n".join(constraint_lines(_tuning()))
    assert "torque noise RMS [N m, N m, N, N m]" in lines
    assert "[N m]:" not in lines


# --------------------------------------------------------------------------------------------
# The joint-1 offset without the observer: the README states the number the report computes
# --------------------------------------------------------------------------------------------
def test_readme_joint1_offset_is_the_rest_pose_the_report_computes():
    """Without the observer, at rest ``Kp e = M(q)^-1 d`` (perfect model, computed torque): the rest pose is
    the fixed point ``q = q0 + M(q)^-1 d / Kp``, solved here by iteration with the arm's inertia alone."""
    from analysis.linear.loop import operating_point_analysis
    from blocks import inertia
    from blocks.scenario import load_scenario

    scenario = load_scenario("paper")
    q0 = np.asarray(scenario.trajectory.evaluate(0.0)[0], dtype=float)
    point = operating_point_analysis(scenario, q0)
    d = np.asarray(point.disturbance_at_rest)
    kp = np.diag(scenario.kp)
    q = q0.copy()
    for _ in range(50):
        q = q0 + np.linalg.solve(inertia(q, scenario.robot), d) / kp
    offset = q[0] - q0[0]
    # at the path's start (M(q0)) it would be 1.84e-5: the README's old 1.8e-5 was that other number
    assert abs(np.linalg.solve(inertia(q0, scenario.robot), d)[0] / kp[0] - 1.84e-5) < 0.01e-5
    assert point.q_equilibrium_without_dob[0] - q0[0] == pytest.approx(offset, rel=1e-6)
    readme = re.sub(r"\s+", " ", (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8"))
    stated = re.search(r"rests with joint 1 only ([0-9.e-]+) rad off", readme)
    assert stated is not None
    assert float(stated.group(1)) == pytest.approx(offset, rel=5e-3)
    assert f"{offset:.3g}".replace("e-05", "e-5") == stated.group(1)


# --------------------------------------------------------------------------------------------
# The quick digital report: no column of dashes, and the banner says the noise was not simulated
# --------------------------------------------------------------------------------------------
def _quantized_paper():
    from blocks.scenario import load_scenario
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
    table = digital_section(result, {}).quantization
    assert table.header == ["joint", "resolution", "torque noise, linear model"]
    assert all(cell.text != "-" for row in table.rows for cell in row)
    assert "does not simulate" in table.caption
    banner = _header(result, scenario).preview
    assert any("torque noise from encoder quantization" in item and "not simulated" in item for item in banner)


# --------------------------------------------------------------------------------------------
# The gain study's heat map: an all-zero panel says so instead of a +-0.1 colour bar
# --------------------------------------------------------------------------------------------
def test_gain_study_zero_panel_says_zero_to_rounding():
    import matplotlib.pyplot as plt

    from analysis.linear.figures import gain_study_axes
    from analysis.simulation.studies import gain_grid_study
    from blocks.scenario import load_scenario

    scenario = load_scenario("paper")
    kp, kd = [100.0, 400.0], [40.0]
    with_dob = gain_grid_study(scenario, kp, kd, observer=True, t_final=1.0)
    without = gain_grid_study(scenario, kp, kd, observer=False, t_final=1.0)
    # the observer's integral action: at rest its estimate equals the step, so the held arm rests on target
    assert all(run.tool_mm.steady_state_error < 1e-9 for row in with_dob.runs for run in row)
    fig = gain_study_axes(with_dob, without)
    try:
        panels = [ax for ax in fig.axes if ax.get_title()]
        assert len(panels) == 8
        zero = [ax for ax in panels if "zero to rounding" in ax.get_title()]
        assert len(zero) == 1 and "steady-state error (mm)\nwith observer" in zero[0].get_title()
        assert {t.get_text() for t in zero[0].texts} == {"0"}
        assert len(fig.axes) == 8 + 7                    # a colour bar on every panel but that one
        # without the observer the arm sags by M^-1 d / Kp: a real scale, with its colour bar and numbers
        sagging = [ax for ax in panels if ax.get_title() == "tool tip steady-state error (mm)\nwithout observer"]
        assert len(sagging) == 1 and all(float(t.get_text()) > 1.0 for t in sagging[0].texts)
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------------------------
# Fig. 6 of a digital run: the sampled estimate as steps, under a title that says sampled and quantized
# --------------------------------------------------------------------------------------------
def _figure6(monkeypatch, tmp_path, with_dob, without_dob) -> dict:
    """Fig. 6's suptitle, texts and estimate lines as paper_figures drew them (recorded before it is written)."""
    from analysis.simulation import figures

    seen = {}
    real = figures.save_figure

    def record(fig, out_dir, stem, formats=figures.FIGURE_FORMATS):
        if stem == "fig6_disturbance_estimate":
            seen["title"] = fig.get_suptitle()
            seen["texts"] = [t.get_text() for t in fig.texts]
            seen["lines"] = [(ln.get_label(), ln.get_drawstyle(), ln.get_xdata(), ln.get_ydata())
                             for ax in fig.axes for ln in ax.get_lines() if "d_hat" in ln.get_label()]
        return real(fig, out_dir, stem, formats)

    monkeypatch.setattr(figures, "save_figure", record)
    figures.paper_figures(with_dob, without_dob, tmp_path, formats=("png",))
    return seen


def test_digital_figure6_draws_the_sampled_estimate_as_steps(monkeypatch, tmp_path):
    from blocks.digital_loop import simulate_sampled
    from blocks.metrics import signal
    from blocks.scenario import load_scenario

    scenario = load_scenario("paper-digital").with_changes({"simulation.t_final": 0.2})
    with_dob, without = simulate_sampled(scenario), simulate_sampled(scenario, observer=False)
    seen = _figure6(monkeypatch, tmp_path, with_dob, without)
    assert "sampled, quantized estimate" in seen["title"]
    rate, step_ms = scenario.controller.sample_rate, 1e3 * scenario.simulation.time_grid[1]
    assert rate == 1000 and step_ms == pytest.approx(5.0)           # the case the issue saw: 1 kHz on 5 ms
    assert any(f"computed at {rate:g} Hz from quantized encoder readings" in t and "5 ms output instants" in t
               for t in seen["texts"])
    d_hat = signal(with_dob, "d_hat")
    assert len(seen["lines"]) == 4
    for j, (label, style, x, y) in enumerate(seen["lines"]):
        assert style == "steps-post" and "sampled" in label
        np.testing.assert_array_equal(x, with_dob.time)
        np.testing.assert_array_equal(y, d_hat[j])


def test_continuous_figure6_keeps_its_curve_and_title(monkeypatch, tmp_path):
    import blocks
    from blocks.scenario import load_scenario

    scenario = load_scenario("paper").with_changes({"simulation.t_final": 0.2})
    with_dob, without = blocks.simulate(scenario), blocks.simulate(scenario, observer=False)
    seen = _figure6(monkeypatch, tmp_path, with_dob, without)
    assert seen["title"] == "Figure 6: disturbance and its estimate (with observer)"
    assert not any("sampled" in t or "Hz" in t for t in seen["texts"])
    assert all(style == "default" for _, style, _, _ in seen["lines"])


# --------------------------------------------------------------------------------------------
# Table 3: one notation per column
# --------------------------------------------------------------------------------------------
def test_table3_uses_one_notation_per_joint_column():
    from analysis.report.view.simulation import simulation_section
    from blocks.scenario import load_scenario

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


# --------------------------------------------------------------------------------------------
# The observer-design figure: |d - d_hat| per unit, never a norm over N m and N together
# --------------------------------------------------------------------------------------------
def test_design_figure_separates_torques_and_forces():
    import matplotlib.pyplot as plt

    from analysis.linear.figures import design_axes
    from analysis.linear.gain_design import confirm_by_simulation
    from blocks.metrics import signal
    from blocks.scenario import load_scenario

    scenario = load_scenario("paper")
    runs = confirm_by_simulation(scenario, [("scenario gain", scenario.observer_gain)], t_final=0.3,
                                 disturbance={"kind": "paper"})
    run = runs["scenario gain"]
    fig = design_axes(runs)
    try:
        labels = [ax.get_ylabel() for ax in fig.axes]
        assert "|d - d_hat|, joints 1, 2, 4 (N m)" in labels and "|d - d_hat|, joint 3 (N)" in labels
        assert not any("N m, N" in label or "mixed" in label for label in labels)
        # the prismatic panel's curve is joint 3's own error, from an independent run of the same variant
        import blocks
        from analysis.linear.loop import first_seconds
        variant = first_seconds(scenario, 0.3, gains={"observer": np.asarray(scenario.observer_gain).tolist()},
                                noise={"q_std": [0.0] * 4, "dq_std": [0.0] * 4}, disturbance={"kind": "paper"})
        again = blocks.simulate(variant, observer=True)
        e3 = np.abs(signal(again, "d")[2] - signal(again, "d_hat")[2])
        prismatic = next(ax for ax in fig.axes if ax.get_ylabel().endswith("(N)"))
        y = np.asarray(prismatic.get_lines()[0].get_ydata(), dtype=float)
        ok = np.isfinite(y)
        np.testing.assert_allclose(y[ok], e3[ok], rtol=1e-9, atol=1e-12)
        revolute = next(ax for ax in fig.axes if ax.get_ylabel().endswith("(N m)"))
        torques = np.array(run.error_per_joint)[:, [0, 1, 3]]
        y = np.asarray(revolute.get_lines()[0].get_ydata(), dtype=float)
        ok = np.isfinite(y)
        np.testing.assert_allclose(y[ok], np.sqrt((torques ** 2).sum(axis=1))[ok], rtol=1e-12)
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------------------------
# The sweep summary: lengths in mm with significant digits, never pm
# --------------------------------------------------------------------------------------------
def test_sweep_summary_gives_tiny_lengths_in_mm():
    from analysis.sweep import summary as sweep_report

    n = 12
    # joint 3 (d3, m) rests 353.8 pm off: the number
    errors = [[1e-6, 2e-6, 3.538e-10 * (1 + 0.01 * i), 4e-6] for i in range(n)]
    rows = [{"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": 100.0 + i}, "status": "ok",
             "metrics": {"final_abs_position_error": errors[i], "max_tool_position_error_mm": 1e-6 * (1 + i)}}
            for i in range(n)]
    header = {"name": "h", "runs": n, "worst_metric": "max_tool_position_error_mm", "worst_count": 3}
    table, _ = sweep_report._load((header, rows), None)
    summary = sweep_report._summary(table, "")
    view = sweep_report._view(summary)
    by_label = {label: (unit, numbers) for label, unit, numbers, _, _ in view["statistics"]}
    joint3 = next(v for k, v in by_label.items() if "d3" in k)
    assert joint3[0] == "mm"
    # min over the runs: 3.538e-10 m = 3.538e-07 mm, four significant digits
    assert float(joint3[1][2]) == pytest.approx(3.538e-7, rel=1e-4)
    assert joint3[1][2] == "3.538e-07"
    assert all(unit in ("mm", "rad", "") for unit, _ in by_label.values())
    # the worst runs' tool-tip error: mm as computed (1.2e-05 mm for the last run), not 12 nm
    assert view["worst_unit"] == "mm" and view["worst"][0][2] == "1.2e-05"
    for fig, stem, _ in sweep_report._draw_figures(table, summary):
        for ax in fig.axes:
            for label in (ax.get_xlabel(), ax.get_ylabel()):
                assert "[pm]" not in label and "[nm]" not in label, (stem, label)


# --------------------------------------------------------------------------------------------
# The engine note: once per command, not once per sweep worker
# --------------------------------------------------------------------------------------------
def test_sweep_prints_the_engine_note_once_for_all_workers(tmp_path, capfd, monkeypatch):
    import warnings

    import blocks
    import blocks.engine_choice
    from analysis.sweep.runner import run_sweep
    from blocks.loop import EngineFallbackWarning

    # a fallback is noted once per reason and process: start as a new process would, whatever ran before here
    monkeypatch.setattr(blocks.engine_choice, "_fallbacks_reported", set())

    # RK23 is a solver the compiled engine does not have: engine='auto' falls back to numpy in every worker
    short = blocks.load_scenario("paper").replace(simulation={"t_final": 0.05, "method": "RK23"},
                                                  trajectory={"duration": 10.0})
    (tmp_path / "short.toml").write_text(short.to_toml(), encoding="utf-8")
    (tmp_path / "s.toml").write_text('scenario = "short.toml"\nengine = "fast"\n[grid]\n"gains.kp" = [100, 120, 140, '
                                     '160]\n[batch]\nsize = 1\n', encoding="utf-8")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_sweep(tmp_path / "s.toml", tmp_path / "r.jsonl", workers=2, progress=False)
    assert outcome.ran == 4
    notes = [w for w in caught if issubclass(w.category, EngineFallbackWarning)]
    assert len(notes) == 1 and "RK23" in str(notes[0].message)
    # and no worker printed its own copy on the shared stderr
    assert "uses the numpy engine" not in capfd.readouterr().err


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
