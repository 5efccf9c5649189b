"""The figures a reader sees (analysis.simulation.figures, analysis.linear.figures): the formats asked for, Fig. 6 of
a digital run drawn as the sampled steps it is, the gain study's all-zero panel said so, and the observer design's
errors per unit (N m apart from N)."""
from __future__ import annotations

import numpy as np
import pytest

import blocks
from blocks import load_scenario


def test_figure_formats_are_checked(short_toml, tmp_path):
    from analysis.simulation.figures import paper_figures

    resp = blocks.simulate(load_scenario(short_toml), engine="fast")
    with pytest.raises(ValueError, match=r"figure formats must be one or more of \['png', 'svg'\], got \('jpg',\)"):
        paper_figures(resp, resp, tmp_path, formats=("jpg",))
    assert not any(tmp_path.iterdir())


def test_gain_study_zero_panel_says_zero_to_rounding():
    import matplotlib.pyplot as plt

    from analysis.linear.figures import gain_study_axes
    from analysis.simulation.studies import gain_grid_study
    from blocks.scenarios.scenario import load_scenario

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
    from blocks.figure2.digital_loop import simulate_sampled
    from blocks.figure2.metrics import signal
    from blocks.scenarios.scenario import load_scenario

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
    from blocks.scenarios.scenario import load_scenario

    scenario = load_scenario("paper").with_changes({"simulation.t_final": 0.2})
    with_dob, without = blocks.simulate(scenario), blocks.simulate(scenario, observer=False)
    seen = _figure6(monkeypatch, tmp_path, with_dob, without)
    assert seen["title"] == "Figure 6: disturbance and its estimate (with observer)"
    assert not any("sampled" in t or "Hz" in t for t in seen["texts"])
    assert all(style == "default" for _, style, _, _ in seen["lines"])


def test_design_figure_separates_torques_and_forces():
    import matplotlib.pyplot as plt

    from analysis.linear.figures import design_axes
    from analysis.linear.gain_design import confirm_by_simulation
    from blocks.figure2.metrics import signal
    from blocks.scenarios.scenario import load_scenario

    scenario = load_scenario("paper")
    runs = confirm_by_simulation(scenario, [("scenario gain", scenario.observer_gain)], t_final=0.3,
                                 disturbance={"kind": "paper"})
    run = runs["scenario gain"]
    fig = design_axes(runs, scenario.robot.joints)
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
