"""What a user sees for an arm of any joint count: Figures 4-8, Table 3 and the report's simulation section.

The arm here is a small model written in this file (:class:`Chain`, a
:class:`blocks.model.arm.ArmModel`): a planar chain of revolute joints about the
vertical axis (links of known lengths) with prismatic joints that lower the
tool, decoupled unit inertias and no gravity.  Its tool point has a closed form
(:func:`chain_tool`), written separately from the kernels the figures use,
so that Figure 8 is checked against an independent derivation.  The runs are
synthetic signals of known shape (a reference, a known tracking error, a known
disturbance and estimate): each figure panel must show exactly those numbers,
scaled to the unit its label names.  The paper's own outputs are pinned by the
existing report and CLI tests (and were compared byte for byte when this was
written).
"""
from __future__ import annotations

import math
import types

import control as ct
import numpy as np
import pytest

from analysis.report.view.simulation import simulation_section, worse_with_observer_short
from analysis.simulation import figures
from analysis.simulation.experiment import format_rms_table
from blocks.model.arm import ArmModel
from blocks.model.joints import JointSpace
from blocks.model.rrpr.joints import RRPR_JOINTS
from blocks.model.rrpr.parameters import RobotParameters

# ----------------------------------------------------------------------------------------------------------------
# A small arm model of any joint count


def _kernels() -> types.ModuleType:
    """Row kernels of n decoupled joints of unit inertia (kg m^2 or kg), no gravity, no velocity terms."""
    k = types.ModuleType("chain_kernels")

    def inertia_matrix(params, q):
        n = len(q)
        shape = np.shape(q[0])
        return np.broadcast_to(np.eye(n), shape + (n, n)).copy()

    k.inertia_matrix = inertia_matrix
    k.mass_times = lambda params, q, v: np.asarray(v, dtype=float)
    k.mass_solve = lambda params, q, r: np.asarray(r, dtype=float)
    k.gravity_forces = lambda params, q: np.zeros_like(np.asarray(q, dtype=float))
    k.bias_forces = lambda params, q, dq: np.zeros_like(np.asarray(q, dtype=float))
    k.plant_acceleration = lambda params, q, dq, f: np.asarray(f, dtype=float)
    return k


def _tool_kernels() -> types.ModuleType:
    """Tool point of the chain, joint-first rows: revolute joints turn the links in the plane, prismatic ones
    lower the tool."""
    t = types.ModuleType("chain_tool_kernels")

    def tool_position(kin, q):
        lengths, kinds, height = kin
        x = y = angle = 0.0
        z = height
        for qi, length, kind in zip(q, lengths, kinds):
            if kind == "revolute":
                angle = angle + qi
                x, y = x + length * np.cos(angle), y + length * np.sin(angle)
            else:
                z = z - qi
        return np.array([x + 0 * z, y + 0 * z, z + 0 * x])

    t.tool_position = tool_position
    return t


class Chain(ArmModel):
    """A serial chain of ``kinds`` (revolute links of ``lengths`` m in the plane, prismatic joints lowering the
    tool from ``height`` m)."""

    kernels = _kernels()
    tool_kernels = _tool_kernels()

    def __init__(self, kinds, lengths, height=0.5):
        self.joints = JointSpace(names=tuple(f"{'r' if k == 'revolute' else 'p'}{i + 1}" for i, k in enumerate(kinds)),
                                 kinds=tuple(kinds))
        self.lengths, self.height = tuple(lengths), float(height)

    def kernel_params(self):
        return ()

    def tool_params(self):
        return (self.lengths, self.joints.kinds, self.height)


def chain_tool(arm: Chain, q: np.ndarray) -> np.ndarray:
    """The chain's tool point (m) for joint positions ``q`` of shape (m, n), by a direct sum over the links."""
    out = np.zeros((len(q), 3))
    for r, row in enumerate(q):
        angle, z = 0.0, arm.height
        for value, length, kind in zip(row, arm.lengths, arm.joints.kinds):
            if kind == "revolute":
                angle += value
                out[r, 0] += length * math.cos(angle)
                out[r, 1] += length * math.sin(angle)
            else:
                z -= value
        out[r, 2] = z
    return out


ARMS = {
    2: Chain(["revolute", "prismatic"], [0.3, 0.0]),
    7: Chain(["revolute", "revolute", "prismatic", "revolute", "revolute", "revolute", "revolute"],
             [0.3, 0.25, 0.0, 0.1, 0.05, 0.04, 0.02]),
}

# ----------------------------------------------------------------------------------------------------------------
# Synthetic runs of known shape


def _error(i: int, t):
    return 1e-3 * (i + 1) * np.sin(2.0 * t)         # rad or m: what joint i lags behind its reference


def _runs(arm: Chain, m: int = 201):
    """Responses with and without the observer: q_ref_i = 0.1 (i + 1) sin t, q = q_ref - e_i (with), 3 e_i (without);
    d_i = i + 1 (N m or N), d_hat_i = d_i (1 - exp(-5 t))."""
    n = arm.n
    t = np.linspace(0.0, 2.0, m)
    q_ref = np.array([0.1 * (i + 1) * np.sin(t) for i in range(n)])
    e = np.array([_error(i, t) for i in range(n)])
    d = np.array([np.full_like(t, i + 1.0) for i in range(n)])
    d_hat = d * (1 - np.exp(-5 * t))
    scenario = types.SimpleNamespace(robot=arm, controller=None, trajectory=types.SimpleNamespace(),
                                     data={"trajectory": {"kind": "joint_sine"}, "disturbance": {"kind": "paper"}})

    def response(q, observer):
        signals = {"q_ref": q_ref, "q": q, "tau_dis": d}
        if observer:
            signals |= {"d": d, "d_hat": d_hat}
        labels = [f"{name}[{i}]" for name in signals for i in range(n)]
        resp = ct.TimeResponseData(t, np.vstack(list(signals.values())), output_labels=labels, issiso=False)
        resp.scenario = scenario
        return resp

    return t, q_ref, e, d, d_hat, response(q_ref - e, True), response(q_ref - 3 * e, False)


def _drawn(monkeypatch, tmp_path, with_dob, without_dob) -> tuple[dict, list]:
    """Every figure paper_figures draws (title, panels with their titles, labels and lines), recorded as it is
    written; and the files written."""
    seen = {}
    real = figures.save_figure

    def record(fig, out_dir, stem, formats=figures.FIGURE_FORMATS):
        seen[stem] = {"title": fig.get_suptitle(), "axes": [
            {"projection": ax.name, "title": ax.get_title(), "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(),
             "lines": [(ln.get_label(), np.asarray(ln.get_xdata(), dtype=float), np.asarray(ln.get_ydata(), dtype=float))
                       for ln in ax.get_lines()]} for ax in fig.axes]}
        return real(fig, out_dir, stem, formats)

    monkeypatch.setattr(figures, "save_figure", record)
    files = figures.paper_figures(with_dob, without_dob, tmp_path, formats=("png",))
    return seen, files


# ----------------------------------------------------------------------------------------------------------------
# The grid


def test_joint_grid_shape_is_the_papers_2x2_for_four_and_holds_every_joint():
    assert figures.joint_grid_shape(4) == (2, 2)
    assert figures.joint_grid_shape(1) == (1, 1)
    assert figures.joint_grid_shape(2) == (1, 2)
    assert figures.joint_grid_shape(3) == (1, 3)
    assert figures.joint_grid_shape(6) == (2, 3)
    assert figures.joint_grid_shape(7) == (3, 3)
    for n in range(1, 13):
        rows, cols = figures.joint_grid_shape(n)
        assert rows * cols >= n > (rows - 1) * cols, n          # room for all, no empty row
    with pytest.raises(ValueError, match=r"joint count .* got 0"):
        figures.joint_grid_shape(0)


# ----------------------------------------------------------------------------------------------------------------
# Figures 4-8


@pytest.mark.parametrize("n", sorted(ARMS))
def test_figures_have_one_panel_per_joint_with_its_name_unit_and_numbers(monkeypatch, tmp_path, n):
    arm = ARMS[n]
    t, q_ref, e, d, d_hat, with_dob, without_dob = _runs(arm)
    seen, files = _drawn(monkeypatch, tmp_path, with_dob, without_dob)
    assert sorted(p.name for p in files) == sorted(f"{stem}.png" for stem in (
        "fig4_joint_tracking", "fig5_tracking_error", "fig6_disturbance_estimate", "fig7_estimation_error",
        "fig8_task_space"))
    assert all(p.stat().st_size > 1000 for p in files)
    rows, cols = figures.joint_grid_shape(n)
    for stem in ("fig4_joint_tracking", "fig5_tracking_error", "fig6_disturbance_estimate", "fig7_estimation_error"):
        panels = seen[stem]["axes"]
        assert len(panels) == n, stem
        for i, panel in enumerate(panels):
            assert panel["title"] == f"Joint {i + 1} ({arm.joints.names[i]})"
            # the foot of each column carries the time axis
            assert panel["xlabel"] == ("time (s)" if i + cols >= n else ""), (stem, i)
    prismatic = [i for i, k in enumerate(arm.joints.kinds) if k == "prismatic"]
    assert prismatic, "each test arm has a prismatic joint"
    for i in range(n):
        scale, unit = (1e3, "mm") if i in prismatic else (1.0, "rad")
        fig4, fig5 = seen["fig4_joint_tracking"]["axes"][i], seen["fig5_tracking_error"]["axes"][i]
        assert fig4["ylabel"] == f"position ({unit})"
        assert fig5["ylabel"] == f"error ({unit})"
        by_label = {label: y for label, _, y in fig5["lines"]}
        # q_ref - (q_ref - e) loses the last digits of q_ref (about 1e-16 of 0.7): an absolute tolerance
        np.testing.assert_allclose(by_label["with observer"], scale * _error(i, t), rtol=0, atol=1e-14 * scale)
        np.testing.assert_allclose(by_label["without observer"], scale * 3 * _error(i, t), rtol=0, atol=1e-14 * scale)
        force = "N" if i in prismatic else "N m"
        fig6, fig7 = seen["fig6_disturbance_estimate"]["axes"][i], seen["fig7_estimation_error"]["axes"][i]
        assert fig6["ylabel"] == f"disturbance ({force})"
        assert fig7["ylabel"] == f"error ({force})"
        np.testing.assert_allclose(fig7["lines"][0][2], (i + 1.0) * np.exp(-5 * t), rtol=0, atol=1e-14 * (i + 1))
    assert "scenario's path (joint_sine)" in seen["fig4_joint_tracking"]["title"]


@pytest.mark.parametrize("n", sorted(ARMS))
def test_figure8_draws_the_arms_tool_point(monkeypatch, tmp_path, n):
    arm = ARMS[n]
    t, q_ref, e, d, d_hat, with_dob, without_dob = _runs(arm)
    seen, _ = _drawn(monkeypatch, tmp_path, with_dob, without_dob)
    panels = seen["fig8_task_space"]["axes"]
    expected = {"reference": 1e3 * chain_tool(arm, q_ref.T), "with observer": 1e3 * chain_tool(arm, (q_ref - e).T),
                "without observer": 1e3 * chain_tool(arm, (q_ref - 3 * e).T)}
    assert [p["projection"] for p in panels].count("3d") == 1
    flat = [p for p in panels if p["projection"] != "3d"]
    assert [p["ylabel"] for p in flat] == ["x (mm)", "y (mm)", "z (mm)"]
    for k, panel in enumerate(flat):
        lines = {label.split(" (")[0]: y for label, _, y in panel["lines"]}
        for name, p in expected.items():
            np.testing.assert_allclose(lines[name], p[:, k], rtol=1e-12, atol=1e-9)
    # the tool does move in every direction on these arms, so the check above could fail
    assert np.ptp(expected["reference"], axis=0).min() > 1.0


def test_a_run_lacking_a_joint_signal_is_refused_by_name(tmp_path):
    arm = ARMS[7]
    *_, with_dob, without_dob = _runs(arm)
    with pytest.raises(KeyError, match=r"q_ref\[7\]' \(an arm of 8 joints\)"):
        figures.paper_figures(with_dob, without_dob, tmp_path, formats=("png",),
                              joints=JointSpace(arm.joints.names + ("extra",), arm.joints.kinds + ("revolute",)))


# ----------------------------------------------------------------------------------------------------------------
# Table 3


def _metrics(arm: Chain) -> dict:
    n = arm.n
    position = [1e-4 * (i + 1) for i in range(n)]
    return {"units": {"position": list(arm.joints.position_units), "disturbance": list(arm.joints.force_units)},
            "with_dob": {"rms_position_error": position, "max_abs_position_error": [3 * v for v in position],
                         "final_abs_position_error": position, "rms_disturbance_error": [0.01 * (i + 1) for i in range(n)],
                         "max_tool_position_error_mm": 1.25, "rms_tool_position_error_mm": 0.5},
            "without_dob": {"rms_position_error": [10 * v for v in position],
                            "max_abs_position_error": [30 * v for v in position],
                            "final_abs_position_error": [10 * v for v in position],
                            "max_tool_position_error_mm": 12.5, "rms_tool_position_error_mm": 5.0}}


@pytest.mark.parametrize("n", sorted(ARMS))
def test_printed_table_has_one_row_per_joint_with_its_units(n):
    arm = ARMS[n]
    metrics = _metrics(arm)
    lines = format_rms_table(metrics, arm).splitlines()
    rows = [line for line in lines if line.startswith("Joint ")]
    assert len(rows) == n
    for i, row in enumerate(rows):
        assert row.startswith(arm.joints.labels[i])
        words = row[len(arm.joints.labels[i]):].split()
        # with, unit, without, unit, d - d_hat, unit
        force = arm.joints.force_units[i].split()
        assert float(words[0]) == pytest.approx(1e-4 * (i + 1), rel=1e-4)
        assert words[1] == arm.joints.position_units[i]
        assert float(words[2]) == pytest.approx(1e-3 * (i + 1), rel=1e-4)
        assert words[3] == arm.joints.position_units[i]
        assert float(words[4]) == pytest.approx(0.01 * (i + 1), rel=1e-4)
        assert words[5:] == force
    assert "Worst tool-tip error, with observer: 1.250 mm" in lines


def test_the_papers_arm_keeps_the_papers_table_layout():
    metrics = _metrics(types.SimpleNamespace(n=4, joints=RRPR_JOINTS))
    text = format_rms_table(metrics, RobotParameters())
    assert text == format_rms_table(metrics)
    head = text.splitlines()[0].split()
    assert head[-4:] == ["Joint", "3", "Joint", "4"]
    with pytest.raises(ValueError, match="metrics hold 7 joints, the arm has 2"):
        format_rms_table(_metrics(ARMS[7]), ARMS[2])


# ----------------------------------------------------------------------------------------------------------------
# The report's simulation section


@pytest.mark.parametrize("n", sorted(ARMS))
def test_report_table_has_one_row_per_joint_and_no_paper_comparison(n):
    arm = ARMS[n]
    scenario = types.SimpleNamespace(robot=arm, nominal=arm, trajectory=types.SimpleNamespace(),
                                     data={"trajectory": {"kind": "joint_sine"}, "disturbance": {"kind": "paper"}})
    section = simulation_section(None, _metrics(arm), scenario, {})
    table = section.metrics
    assert len(table.rows) == n
    assert table.header[:2] == ["joint", "position unit"] and table.header[-2] == "force unit"
    for i, row in enumerate(table.rows):
        cells = [c.text for c in row]
        assert cells[0] == arm.joints.labels[i]
        assert cells[1] == arm.joints.position_units[i]
        assert float(cells[2]) == pytest.approx(1e-4 * (i + 1), rel=1e-3)        # RMS with the observer
        assert float(cells[5]) == pytest.approx(3e-3 * (i + 1), rel=1e-3)        # largest without
        assert cells[6] == arm.joints.force_units[i]
        assert float(cells[7]) == pytest.approx(0.01 * (i + 1), rel=1e-3)
    assert "not compared" in section.intro and f"{n} joints" in section.intro
    assert section.worse == []                       # every joint is better with the observer here


def test_summary_names_a_worse_joint_of_any_arm_in_its_unit():
    arm = ARMS[7]
    metrics = _metrics(arm)
    metrics["with_dob"]["rms_position_error"][6] = 0.5          # joint 7 worse with the observer
    text = worse_with_observer_short(metrics, arm.joints)
    assert "Joint 7 (r7), RMS error 0.5 rad with it against 0.007 rad without" in text
    metrics = _metrics(ARMS[2])
    metrics["with_dob"]["rms_position_error"][1] = 0.5          # the prismatic joint, in m
    assert "Joint 2 (p2), RMS error 0.5 m with it" in worse_with_observer_short(metrics, ARMS[2].joints)


# ----------------------------------------------------------------------------------------------------------------
# Analysis figures and report words for any arm


def test_design_figure_groups_the_estimation_error_by_the_arms_units():
    """|d - d_hat| is drawn once per unit (never N m and N summed), each the norm over that unit's joints."""
    from analysis.linear.figures import design_axes
    from analysis.linear.gain_design import SimulationCheck

    arm = ARMS[7]                   # joints 1, 2, 4-7 revolute (N m), joint 3 prismatic (N)
    t = np.linspace(0.0, 1.0, 11)
    err = np.array([[(j + 1) * np.exp(-tk) for j in range(7)] for tk in t])      # (time, joint)
    run = SimulationCheck(Y=np.eye(7).tolist(), time=t.tolist(), error_norm=np.linalg.norm(err, axis=1).tolist(),
                          lyapunov_ratio=np.exp(-2 * t).tolist(), beta_run_rad_s=1.0, convergence_time_s=None,
                          rms_disturbance_error=[0.0] * 7, bound_holds=None, threshold=0.02, largest_disturbance=7.0,
                          disturbance_kind="step", f_r=[1.0] * 7, error_per_joint=err.tolist())
    fig = design_axes({"scenario gain": run}, arm.joints)
    try:
        panels = [ax for ax in fig.axes if ax.get_ylabel().startswith("|d - d_hat|")]
        labels = [ax.get_ylabel() for ax in panels]
        assert labels == ["|d - d_hat|, joints 1, 2, 4, 5, 6, 7 (N m)", "|d - d_hat|, joint 3 (N)"]
        revolute = np.sqrt(sum((j + 1) ** 2 for j in (0, 1, 3, 4, 5, 6))) * np.exp(-t)
        np.testing.assert_allclose(panels[0].get_lines()[0].get_ydata(), revolute, rtol=1e-12)
        np.testing.assert_allclose(panels[1].get_lines()[0].get_ydata(), 3 * np.exp(-t), rtol=1e-12)
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)


def test_report_words_name_the_arms_units():
    from analysis.linear.figures import _units_words
    from analysis.report.view.text import gain_units, mixed_units, units_list

    assert mixed_units(RRPR_JOINTS.force_units) == "N m; N on joint 3"          # what the paper's report says
    assert gain_units(RRPR_JOINTS) == "kg m^2/s; kg/s on joint 3"
    assert units_list(RRPR_JOINTS.position_units) == "rad, rad, m, rad"
    two_prismatic = JointSpace(("a", "b", "c", "d"), ("prismatic", "revolute", "prismatic", "revolute"))
    assert mixed_units(two_prismatic.force_units) == "N; N m on joints 2 and 4"
    assert mixed_units(("N m",) * 7) == "N m"
    assert gain_units(ARMS[7].joints) == "kg m^2/s; kg/s on joint 3"
    assert _units_words(RRPR_JOINTS) == "N m; N on Joint 3"
    assert _units_words(ARMS[2].joints) == "N m; N on Joint 2"
