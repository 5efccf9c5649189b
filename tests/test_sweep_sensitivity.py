"""Global sensitivity sweeps ([sensitivity]: Sobol indices, Morris screening) against indices known in closed form.

The estimators are SALib's; what is tested here is the way from a sweep file to the indices: the design as the
sweep's runs, the run metrics as the results file holds them, and the summary that turns them into indices.

Known indices:

* Ishigami's function ``sin x1 + a sin^2 x2 + b x3^4 sin x1`` on [-pi, pi]^3 has Sobol indices in closed form
  (Saltelli et al., *Global Sensitivity Analysis: The Primer*, 2008, section 4.8; derived again below), and a
  linear function has Morris effects ``c (high - low)`` with no spread.
* On the paper's RRPR the prismatic joint 3 is decoupled: M(q) has no entry between d3 and the other joints and
  M33 = k4 = m3 + m4 (paper-notes.md, "lambda_min = 0.25 (prismatic joint)"), so the computed-torque loop and the
  observer (d_hat' = Y M^-1 (d - d_hat)) are block-diagonal too.  The Eq. 4 load on joint 3 cannot move joints 1,
  2 and 4, and the nominal mass of link 1 (in k1 only) cannot move joint 3: those indices are 0.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

from analysis.sweep.runner import run_sweep
from analysis.sweep.sensitivity import Sensitivity, run_count
from analysis.sweep.spec import SWEEP_RUN_BYTES, Distribution, SweepError, load_sweep, sweep_from_dict
from analysis.sweep.summary import html_section, summarize, write_summary
from blocks.engines.budget import Budget, BudgetError

pytest.importorskip("SALib")

A, B = 7.0, 0.1


def ishigami_indices() -> dict:
    """Ishigami's closed-form partial variances (x_i uniform on [-pi, pi]):
    V1 = (1 + b pi^4 / 5)^2 / 2, V2 = a^2 / 8, V13 = b^2 pi^8 (1/18 - 1/50), V = V1 + V2 + V13."""
    v1 = 0.5 * (1.0 + B * math.pi ** 4 / 5.0) ** 2
    v2 = A ** 2 / 8.0
    v13 = B ** 2 * math.pi ** 8 * (1.0 / 18.0 - 1.0 / 50.0)
    v = v1 + v2 + v13
    return {"first": {"x1": v1 / v, "x2": v2 / v, "x3": 0.0}, "total": {"x1": (v1 + v13) / v, "x2": v2 / v,
                                                                        "x3": v13 / v}}


def _design_rows(settings: Sensitivity, model) -> tuple[dict, list[dict]]:
    """A results file's header and rows for a function of the design's values, as the sweep runner writes them
    (one row per run, its index the design row)."""
    x = settings.design()
    y = model(x)
    header = {"name": "design", "runs": settings.runs, "sensitivity": settings.record()}
    rows = [{"run_id": f"r{i}", "index": i, "values": dict(zip(settings.keys, map(float, x[i]))), "status": "ok",
             "metrics": {"f": float(y[i])}} for i in range(settings.runs)]
    return header, rows


def test_the_closed_form_ishigami_indices_are_the_issue_s_numbers():
    known = ishigami_indices()
    assert [round(known["first"][k], 4) for k in ("x1", "x2", "x3")] == [0.3139, 0.4424, 0.0]
    assert [round(known["total"][k], 4) for k in ("x1", "x2", "x3")] == [0.5576, 0.4424, 0.2437]


def test_ishigami_sobol_indices_from_run_metrics_through_the_summary():
    settings = Sensitivity("sobol", 4096, 2, {f"x{i}": Distribution("uniform", {"low": -math.pi, "high": math.pi})
                                              for i in (1, 2, 3)})
    assert settings.runs == 4096 * 5

    def ishigami(x):
        return np.sin(x[:, 0]) + A * np.sin(x[:, 1]) ** 2 + B * x[:, 2] ** 4 * np.sin(x[:, 0])

    summary = summarize(_design_rows(settings, ishigami))
    known = ishigami_indices()
    assert summary.sensitivity_note is None and summary.morris is None
    for which in ("first", "total"):
        for key, exact in known[which].items():
            got, conf = summary.sobol[which]["f"][key], summary.sobol[f"{which}_conf"]["f"][key]
            # the scrambled Sobol sequence converges faster than the bootstrap's interval says
            assert got == pytest.approx(exact, abs=0.01), (which, key)
            assert abs(got - exact) <= conf, (which, key, got, conf)


def test_morris_effects_of_a_linear_function_are_slope_times_range():
    ranges = {"x1": (0.0, 2.0), "x2": (1.0, 1.5), "x3": (-1.0, 1.0)}
    settings = Sensitivity("morris", 20, 5, {k: Distribution("uniform", {"low": lo, "high": hi})
                                             for k, (lo, hi) in ranges.items()}, levels=4)
    assert settings.runs == 20 * 4
    summary = summarize(_design_rows(settings, lambda x: 3.0 * x[:, 0] - 2.0 * x[:, 1]))
    mu_star, sigma = summary.morris["mu_star"]["f"], summary.morris["sigma"]["f"]
    assert mu_star == pytest.approx({"x1": 3.0 * 2.0, "x2": 2.0 * 0.5, "x3": 0.0}, abs=1e-9)
    assert sigma == pytest.approx({"x1": 0.0, "x2": 0.0, "x3": 0.0}, abs=1e-9)


def test_design_values_follow_the_distributions_as_monte_carlo_reads_them():
    """normal: mean and std; lognormal: exp of a normal of mean and sigma (numpy's lognormal); uniform: [low, high]."""
    settings = Sensitivity("sobol", 2048, 7, {"a": Distribution("normal", {"mean": 2.0, "std": 0.5}),
                                              "b": Distribution("lognormal", {"mean": -1.0, "sigma": 0.2}),
                                              "c": Distribution("uniform", {"low": 3.0, "high": 4.0})})
    x = settings.design()
    assert x.shape == (2048 * 5, 3)
    assert np.mean(x[:, 0]) == pytest.approx(2.0, abs=0.01) and np.std(x[:, 0]) == pytest.approx(0.5, rel=0.02)
    logs = np.log(x[:, 1])
    assert np.mean(logs) == pytest.approx(-1.0, abs=0.005) and np.std(logs) == pytest.approx(0.2, rel=0.02)
    assert 3.0 <= x[:, 2].min() < 3.001 and 3.999 < x[:, 2].max() <= 4.0
    assert np.mean(x[:, 2]) == pytest.approx(3.5, abs=0.005)
    assert np.array_equal(settings.design(), x)          # the seed decides the design


# --------------------------------------------------------------------------------------------
# A sweep of the paper's arm: the decoupled prismatic joint
# --------------------------------------------------------------------------------------------
DISTRIBUTIONS = '''[sensitivity.distributions]
"disturbance.f_r[2]" = {kind = "uniform", low = 0.7, high = 2.1}
"nominal_scale.m1" = {kind = "uniform", low = 0.8, high = 1.2}
"nominal_scale.m3" = {kind = "uniform", low = 0.8, high = 1.2}
[outputs]
metrics = ["rms_position_error", "max_tool_position_error_mm"]
'''
ZERO = 1e-9       # the fixed-step batch gives joint 3 the same numbers to the last bit; a looser bound for any engine


@pytest.fixture()
def short(tmp_path):
    return write_short_scenario(tmp_path, t_final=0.3)


@pytest.mark.parametrize("method, table", [("sobol", "samples = 16\n"), ("morris", "samples = 6\nlevels = 4\n")])
def test_a_joint_the_value_cannot_reach_has_index_zero(tmp_path, short, method, table):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "{method}"\nseed = 4\n{table}{DISTRIBUTIONS}')
    spec = load_sweep(path)
    assert len(spec.runs) == (16 * 5 if method == "sobol" else 6 * 4)
    design = spec.sensitivity.design()                # the runs are the design's rows, in order
    assert [list(spec.runs[i].values.values()) for i in (0, 1, len(spec.runs) - 1)] == \
        [design[i].tolist() for i in (0, 1, len(spec.runs) - 1)]
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    summary = summarize(tmp_path / "r.jsonl", spec=spec)
    assert summary.counts.ok == len(spec.runs) and summary.sensitivity_note is None
    found = summary.sobol if method == "sobol" else summary.morris
    main = found["total" if method == "sobol" else "mu_star"]["rms_position_error"]
    # zero: the joint-3 load on joints 1, 2, 4; the link-1 mass on joint 3 (every entry of the method)
    for name, by_metric in found.items():
        per_key = by_metric["rms_position_error"]
        assert [abs(per_key["disturbance.f_r[2]"][j]) for j in (0, 1, 3)] <= [ZERO] * 3, name
        assert abs(per_key["nominal_scale.m1"][2]) <= ZERO, name
    # not zero: the load and the stage's mass on joint 3, both masses on the planar joints
    if method == "sobol":
        assert main["disturbance.f_r[2]"][2] > 0.5 and main["nominal_scale.m3"][2] > 1e-4
        assert min(main["nominal_scale.m1"][j] for j in (0, 1, 3)) > 0.05
    else:           # in m or rad over each value's whole range
        assert main["disturbance.f_r[2]"][2] > 1e-4 and main["nominal_scale.m3"][2] > 1e-7
        assert min(main["nominal_scale.m1"][j] for j in (0, 1, 3)) > 1e-6


@pytest.mark.slow
def test_the_fast_engine_runs_the_design_too_with_zeros_at_the_solver_s_tolerance(tmp_path, short):
    """engine = "fast": one adaptive RK45 run per design row.  Its step sizes follow every joint's error, so joint 3's
    numbers move with the planar joints' values by the solver's tolerance (atol 1e-8 m) rather than not at all."""
    path = write_sweep(tmp_path, f'engine = "fast"\n[sensitivity]\nmethod = "morris"\nsamples = 3\nseed = 2\n'
                                 f'{DISTRIBUTIONS}')
    spec = load_sweep(path)
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    rows = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()[1:]]
    assert {r["engine"] for r in rows} == {"fast"} and len(rows) == 12
    mu_star = summarize(tmp_path / "r.jsonl", spec=spec).morris["mu_star"]["rms_position_error"]
    atol = spec.base.simulation.atol
    assert max(mu_star["disturbance.f_r[2]"][j] for j in (0, 1, 3)) < atol
    assert mu_star["nominal_scale.m1"][2] < atol
    assert mu_star["disturbance.f_r[2]"][2] > 100 * atol and mu_star["nominal_scale.m3"][2] > 100 * atol
    assert min(mu_star["nominal_scale.m1"][j] for j in (0, 1, 3)) > 100 * atol


def test_summary_json_html_and_markdown_carry_the_indices(tmp_path, short):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 8\nseed = 1\n{DISTRIBUTIONS}')
    spec = load_sweep(path)
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    files = write_summary(tmp_path / "r.jsonl", tmp_path / "out", spec=spec)
    data = json.loads(files["json"].read_text())
    assert set(data["sobol"]) == {"first", "total", "first_conf", "total_conf"}
    joints = data["sobol"]["first"]["rms_position_error"]
    assert list(joints) == ["disturbance.f_r[2]", "nominal_scale.m1", "nominal_scale.m3"]
    assert all(len(v) == 4 for v in joints.values())
    assert isinstance(data["sobol"]["total"]["max_tool_position_error_mm"]["nominal_scale.m1"], float)
    assert "morris" not in data and "sensitivity_note" not in data
    listed = [f["file"] for f in data["figures"]]
    assert listed[:2] == ["sobol_rms_position_error.png", "sobol_max_tool_position_error_mm.png"]
    section = html_section(tmp_path / "out")
    assert "<h3>Sobol indices</h3>" in section and "total ST ± 95 %" in section
    # ranked: on joint 3 the load comes first
    assert "<td>RMS position error, Joint 3 (d3)</td><td>1</td><td>Eq. 4 amplitude f_r, Joint 3 (d3)</td>" in section
    markdown = files["markdown"].read_text()
    table = markdown.split("### Sobol indices")[1]
    assert "| metric | rank | value | key | first order S1 ± 95 % | total ST ± 95 % |\n|---|---|---|---|---|---|\n| " \
        in table


def test_no_indices_until_every_run_of_the_design_finished(tmp_path, short):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 4\n{DISTRIBUTIONS}')
    spec = load_sweep(path)
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    lines = (tmp_path / "r.jsonl").read_text().splitlines()
    (tmp_path / "r.jsonl").write_text("\n".join(lines[:-3]) + "\n")          # three runs not finished
    summary = summarize(tmp_path / "r.jsonl", spec=spec)
    assert summary.sobol is None
    assert summary.sensitivity_note == ("no sobol indices: 17 of the 20 runs of the design finished, and the "
                                        "estimators need every run (run the sweep again to finish it)")
    header, rows = json.loads(lines[0])["sweep"], [json.loads(line) for line in lines[1:]]
    rows[5] = dict(rows[5], status="diverged", metrics={})
    summary = summarize((header, rows))
    assert summary.sobol is None and "1 of the 20 runs of the design diverged" in summary.sensitivity_note
    write_summary((header, rows), tmp_path / "out")
    assert "1 of the 20 runs of the design diverged" in html_section(tmp_path / "out")


def test_another_design_is_another_sweep_definition(tmp_path, short):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 4\nseed = 1\n{DISTRIBUTIONS}')
    run_sweep(load_sweep(path), tmp_path / "r.jsonl", workers=1, progress=False)
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 4\nseed = 2\n{DISTRIBUTIONS}')
    with pytest.raises(SweepError, match=r"\[sensitivity\] differ\(s\)"):
        run_sweep(load_sweep(path), tmp_path / "r.jsonl", workers=1, progress=False)


def test_check_prints_the_design(tmp_path, short, capsys):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "morris"\nsamples = 5\n{DISTRIBUTIONS}')
    assert run_sweep_command(["sweep", str(path), "--check", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "20 runs, valid" in out
    assert "sensitivity: morris, r = 5 trajectories of 4 levels x (k + 1) = 20 runs for k = 3 values" in out


# --------------------------------------------------------------------------------------------
# Refused, naming the key
# --------------------------------------------------------------------------------------------
def test_a_value_far_in_a_lognormal_tail_is_refused_by_the_step_budget_not_an_overflow(tmp_path, short):
    """sigma = 50 puts nominal_scale.m3 at about 1e26 in some runs: its substeps (a power of two above the
    stiffness) overflowed numpy's int64 ("OverflowError: Python int too large to convert to C long", a traceback);
    now the run is named with its values and the step budget."""
    table = ('[sensitivity]\nmethod = "sobol"\nsamples = 8\nseed = 1\n[sensitivity.distributions]\n'
             '"nominal_scale.m3" = {kind = "lognormal", mean = 0.0, sigma = 50.0}\n'
             '[outputs]\nmetrics = ["rms_position_error"]\n')
    with pytest.raises(SweepError, match=r"run \d+ \(nominal_scale.m3 = [0-9.e+]+\) needs [0-9.e+]+ substeps per "
                                         r"output step .*more integrator steps than the step budget of 2e\+06"):
        load_sweep(write_sweep(tmp_path, table))


def test_the_morris_levels_bound_at_both_sides(tmp_path, short):
    """SALib lays out levels / 2 grid values per design: levels = 10**9 passed the check and allocated 4 GB when
    the design was drawn (2**62: numpy's "array is too big"); 1000 levels load, 1002 are refused by the key."""
    from analysis.sweep.sensitivity import MAX_LEVELS
    assert MAX_LEVELS == 1000
    ok = load_sweep(write_sweep(tmp_path, f'[sensitivity]\nmethod = "morris"\nsamples = 2\nlevels = 1000\n'
                                           f'{DISTRIBUTIONS}'))
    assert ok.sensitivity.levels == 1000 and ok.sensitivity.design().shape[0] == ok.sensitivity.runs
    for levels in (1002, 10**9, 2**62):
        path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "morris"\nsamples = 2\nlevels = {levels}\n'
                                     f'{DISTRIBUTIONS}')
        with pytest.raises(SweepError, match=rf"'sensitivity.levels' must be at most 1000 .*got {levels}"):
            load_sweep(path)


@pytest.mark.parametrize("text, message", [
    ('method = "sobol"\nsamples = 1000\n',
     "'sensitivity.samples' must be a power of 2 >= 2 for the Sobol method (N of the Saltelli design, which "
     "balances the Sobol sequence only at powers of 2), got 1000; use 512 or 1024"),
    ('method = "sobol"\nsamples = 1\n', "'sensitivity.samples' must be a power of 2 >= 2"),
    ('method = "sobol"\nsamples = 8\nlevels = 4\n', "'sensitivity.levels' is a Morris setting"),
    ('method = "morris"\nsamples = 1\n', "'sensitivity.samples' must be >= 2 Morris trajectories"),
    ('method = "morris"\nsamples = 4\nlevels = 3\n',
     "'sensitivity.levels' must be an even whole number >= 2 (Morris grid levels), got 3"),
    ('method = "fast"\nsamples = 8\n', "'sensitivity.method' must be one of ['sobol', 'morris'], got 'fast'"),
    ('samples = 8\n', "'sensitivity.method' must be one of ['sobol', 'morris'], got nothing"),
    ('method = "sobol"\n', "'sensitivity.samples' must be given"),
    ('method = "sobol"\nsamples = 8.0\n', "'sensitivity.samples' must be a whole number >= 1, got 8.0"),
    ('method = "sobol"\nsamples = 8\nruns = 3\n', "unknown key(s) ['sensitivity.runs']"),
])
def test_bad_settings_are_refused_naming_the_key(tmp_path, short, text, message):
    path = write_sweep(tmp_path, f"[sensitivity]\n{text}{DISTRIBUTIONS}")
    with pytest.raises(SweepError) as err:
        load_sweep(path)
    assert message in str(err.value) and str(path) in str(err.value)


@pytest.mark.parametrize("method, spec, message", [
    ("sobol", '{kind = "choice", values = [0.7, 1.4]}',
     "sensitivity.distributions.\"disturbance.f_r[2]\": kind 'choice' cannot be used with method 'sobol'"),
    ("morris", '{kind = "normal", mean = 1.4, std = 0.1}',
     "sensitivity.distributions.\"disturbance.f_r[2]\": kind 'normal' cannot be used with method 'morris' (a Morris "
     "trajectory moves each value over levels that include both ends of a bounded range); choose from ['uniform']"),
    ("sobol", '{kind = "uniform", low = 2.1, high = 0.7}',
     "sensitivity.distributions.\"disturbance.f_r[2]\": 'low' must be < 'high', got low = 2.1, high = 0.7"),
    ("sobol", '{kind = "normal", mean = 1.4}', "sensitivity.distributions.\"disturbance.f_r[2]\": kind 'normal' "
     "takes ['mean', 'std']; missing ['std']"),
    ("sobol", '{kind = "lognormal", mean = 0.3, sigma = -1}',
     "sensitivity.distributions.\"disturbance.f_r[2]\": 'sigma' must be > 0, got -1"),
])
def test_bad_distributions_are_refused_naming_the_key(tmp_path, short, method, spec, message):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "{method}"\nsamples = 8\n'
                                 f'[sensitivity.distributions]\n"disturbance.f_r[2]" = {spec}\n')
    with pytest.raises(SweepError) as err:
        load_sweep(path)
    assert message in str(err.value)


def test_a_key_the_scenario_lacks_and_an_empty_table_are_refused(tmp_path, short):
    path = write_sweep(tmp_path, '[sensitivity]\nmethod = "sobol"\nsamples = 8\n[sensitivity.distributions]\n'
                                 '"gains.nothing" = {kind = "uniform", low = 0, high = 1}\n')
    with pytest.raises(SweepError, match=r'sensitivity\.distributions\."gains\.nothing"'):
        load_sweep(path)
    path = write_sweep(tmp_path, '[sensitivity]\nmethod = "sobol"\nsamples = 8\n')
    with pytest.raises(SweepError, match=r"'sensitivity\.distributions' is empty"):
        load_sweep(path)


def test_without_salib_a_sensitivity_sweep_is_refused_saying_what_to_install(tmp_path, short):
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 8\n{DISTRIBUTIONS}')
    code = ("import sys; sys.modules['SALib'] = None\n"          # an interpreter where SALib cannot be imported
            "from analysis.sweep.spec import SweepError, load_sweep\n"
            f"try:\n    load_sweep({str(path)!r})\nexcept SweepError as err:\n    print(err)\n")
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.stdout.strip() == (f"{path}: a [sensitivity] sweep needs SALib: pip install 'dobkit[sensitivity]' "
                                  "(or SALib>=1.4)"), out.stderr


def test_grid_or_monte_carlo_beside_sensitivity_is_refused(tmp_path, short):
    for other in ('[grid]\n"gains.kp" = [100, 180]\n', '[monte_carlo]\nruns = 3\n[monte_carlo.distributions]\n'
                  '"gains.kp" = {kind = "uniform", low = 100, high = 200}\n'):
        path = write_sweep(tmp_path, f'{other}[sensitivity]\nmethod = "sobol"\nsamples = 8\n{DISTRIBUTIONS}')
        with pytest.raises(SweepError, match=r"a \[sensitivity\] sweep's runs are its design: it takes no \[grid\]"):
            load_sweep(path)


def test_the_run_count_is_checked_against_the_budget_before_the_design_is_made(tmp_path, short):
    runs = run_count("sobol", 256, 3)
    assert runs == 256 * 5
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = 256\n{DISTRIBUTIONS}')
    assert len(load_sweep(path, budget=Budget(memory=runs * SWEEP_RUN_BYTES)).runs) == runs    # at the budget
    with pytest.raises(BudgetError) as err:                                                      # one byte below
        load_sweep(path, budget=Budget(memory=runs * SWEEP_RUN_BYTES - 1))
    assert err.value.key == "sensitivity.samples" and err.value.limit == "memory"
    assert err.value.estimate.memory == runs * SWEEP_RUN_BYTES
    assert ("the sobol design has 1,280 runs (N = 256 x (k + 2) with k = 3 values), which need about 1.2 MiB"
            in str(err.value)) and "lower sensitivity.samples" in str(err.value)
    # a design of 2^34 x 5 runs would take hours and terabytes to make: refused at once
    path = write_sweep(tmp_path, f'[sensitivity]\nmethod = "sobol"\nsamples = {2 ** 34}\n{DISTRIBUTIONS}')
    with pytest.raises(BudgetError, match="85,899,345,920 runs") as err:
        load_sweep(path)
    assert err.value.key == "sensitivity.samples"


def test_the_example_sweep_file_is_valid_and_its_design_the_issue_s():
    text = (Path(__file__).resolve().parents[1] / "examples" / "sensitivity.toml").read_text(encoding="utf-8")
    data = tomllib.loads(text)
    # the file's table, at N = 8 (the full N = 4096 is benchmarks/bench_sensitivity.py)
    data["sensitivity"]["samples"] = 8
    spec = sweep_from_dict(data, source="sensitivity.toml")
    assert spec.sensitivity.method == "sobol" and len(spec.sensitivity.distributions) == 3
    assert run_count("sobol", 4096, 3) == 20_480
    assert len(spec.runs) == 40
