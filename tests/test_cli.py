"""End-to-end checks of ``dobkit simulate``: files, schema, reproducibility, clear errors, and the progress display."""
import csv
import io
import json
import re

import numpy as np
import pytest
from conftest import SHORT_SCENARIO_TOML as SHORT

from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import load_sweep
from blocks import load_scenario
from blocks.plumbing import progress
from dobkit import cli
from dobkit.cli import main


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    scenario = folder / "short.toml"
    scenario.write_text(SHORT)
    out = folder / "out"
    status = main(["simulate", "--scenario", str(scenario), "--out", str(out)])
    return status, out, scenario


def test_simulate_writes_every_result(short_run):
    status, out, _ = short_run
    assert status == 0
    names = {p.name for p in out.iterdir()}
    for stem in ("fig4_joint_tracking", "fig5_tracking_error", "fig6_disturbance_estimate",
                 "fig7_estimation_error", "fig8_task_space"):
        assert f"{stem}.png" in names and f"{stem}.svg" not in names      # SVG with --svg
        assert (out / f"{stem}.png").stat().st_size > 10_000
    assert {"metrics.json", "timeseries.csv", "scenario.toml"} <= names
    assert not [n for n in names if "partial" in n]


def test_metrics_schema_and_values(short_run):
    _, out, _ = short_run
    m = json.loads((out / "metrics.json").read_text())
    for key in ("rms_position_error", "rms_disturbance_error", "max_abs_position_error"):
        assert len(m["with_dob"][key]) == 4 and all(np.isfinite(m["with_dob"][key]))
    for key in ("rms_position_error", "max_abs_position_error"):
        assert len(m["without_dob"][key]) == 4
    assert m["units"]["position"] == ["rad", "rad", "m", "rad"]
    # RMS recomputed from the written time series (Eq. 13) equals the metric
    with (out / "timeseries.csv").open() as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    assert header[0] == "time_s" and np.allclose(np.diff(data[:, 0]), 0.01)
    for key in ("with_dob", "without_dob"):
        e = data[:, header.index(f"{key}.q_ref[2]")] - data[:, header.index(f"{key}.q[2]")]
        assert np.sqrt(np.mean(e ** 2)) == pytest.approx(m[key]["rms_position_error"][2], rel=1e-9)
    # without the observer the prismatic joint sags by about M^-1 d / Kp = 1.4 / 0.25 / 180 m
    assert m["without_dob"]["max_abs_position_error"][2] == pytest.approx(1.4 / 0.25 / 180, rel=0.05)


@pytest.mark.slow
def test_written_scenario_reproduces_the_run(short_run, tmp_path):
    _, out, source = short_run
    assert load_scenario(out / "scenario.toml").data == load_scenario(source).data
    again = tmp_path / "again"
    assert main(["simulate", "--scenario", str(out / "scenario.toml"), "--out", str(again)]) == 0
    first = json.loads((out / "metrics.json").read_text())
    second = json.loads((again / "metrics.json").read_text())
    assert first["with_dob"] == second["with_dob"] and first["without_dob"] == second["without_dob"]


def test_bad_scenario_names_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SHORT.replace("[simulation]", "[simulation]\nstep_size = 0.1"))
    out = tmp_path / "out"
    assert main(["simulate", "--scenario", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "simulation.step_size" in err
    assert not out.exists()


def test_refuses_a_non_empty_output_folder(tmp_path, capsys, short_run):
    _, _, scenario = short_run
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("earlier results")
    assert main(["simulate", "--scenario", str(scenario), "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_diverging_run_leaves_no_output(tmp_path, capsys):
    wild = tmp_path / "wild.toml"
    wild.write_text(SHORT.replace('kind = "paper"', 'kind = "paper"\nf_r = [1e12, 1e12, 1e12, 1e12]'))
    out = tmp_path / "out"
    assert main(["simulate", "--scenario", str(wild), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search("diverged (at|by) t =", err)
    assert not out.exists() and not list(tmp_path.glob(".out.partial-*"))


def test_report_refuses_a_missing_sweep_summary_before_any_work(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--quick", "--sweep", str(tmp_path / "no-such-summary"), "--out", str(out)]) == 2
    assert "has no summary.json" in capsys.readouterr().err
    assert not out.exists()


# --- progress -------------------------------------------------------------------------------------------------


class _Recorded(progress.StageProgress):
    """The CLI's own display, keeping every call it receives."""

    made = []

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.calls = []
        _Recorded.made.append(self)

    def __call__(self, stage, fraction):
        self.calls.append((stage, fraction))
        super().__call__(stage, fraction)


def _increasing_to_one(calls, stage):
    fractions = [f for s, f in calls if s == stage]
    assert fractions, f"no progress reported for {stage!r}"
    assert all(0.0 <= f <= 1.0 for f in fractions) and fractions == sorted(fractions) and fractions[-1] == 1.0


def test_simulate_reports_progress_of_both_runs(short_run, tmp_path, monkeypatch, capsys):
    _, _, scenario = short_run
    _Recorded.made.clear()
    monkeypatch.setattr(cli, "StageProgress", _Recorded)
    assert main(["simulate", "--scenario", str(scenario), "--out", str(tmp_path / "out")]) == 0
    (display,) = _Recorded.made
    for stage in ("simulating with observer", "simulating without observer"):
        _increasing_to_one(display.calls, stage)
    # stderr is not a terminal here: a line when each stage ends, saying how long it took, in order (a stage slow
    # enough may also write how far it has got)
    lines = capsys.readouterr().err.splitlines()
    done = [re.fullmatch(r"(.+): done, took (\d+\.\d) s", line) for line in lines]
    assert [m.group(1) for m in done if m] == ["simulating with observer", "simulating without observer",
                                               "writing figures"]
    assert all(m or re.fullmatch(r".+: \d+% after \d+\.\d s", line) for m, line in zip(done, lines))


def test_sweep_reports_finished_runs_up_to_all_of_them(short_run, tmp_path, capsys):
    _, _, scenario = short_run
    path = tmp_path / "s.toml"
    path.write_text(f'scenario = "{scenario}"\n[grid]\n"gains.kp" = [120, 150, 180, 210]\n[batch]\nsize = 1\n')
    calls = []
    run_sweep(load_sweep(path), tmp_path / "r.jsonl", workers=1, progress=lambda stage, f: calls.append((stage, f)))
    _increasing_to_one(calls, "sweep")
    assert [f for _, f in calls] == [0.0, 0.25, 0.5, 0.75, 1.0]          # at the start, then after every batch
    # resumed: the runs found in the results file count from the start
    calls.clear()
    run_sweep(load_sweep(path), tmp_path / "r.jsonl", workers=1, progress=lambda stage, f: calls.append((stage, f)))
    assert calls == [("sweep", 1.0)]
    # the command line's display, on a stream that is not a terminal: a line per tenth of the runs
    args = cli.build_parser().parse_args(["sweep", str(path), "--results", str(tmp_path / "cli.jsonl"),
                                          "--workers", "1"])
    assert args.func(args) == 0
    counts = [line.split()[1] for line in capsys.readouterr().err.splitlines() if line.startswith("sweep: ")]
    assert counts == ["0/4", "1/4", "2/4", "3/4", "4/4"]


class _Clock:
    """A monotonic clock the test moves by hand."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_each_stage_shows_its_own_duration(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    log = io.StringIO()
    with progress.StageProgress(log) as display:
        display("first", 0.0)
        clock.now += 5.0
        display("first", 1.0)
        display("second", 0.2)
        clock.now += 2.0
        display("second", 0.1)            # never backwards within a stage
        assert display.fraction == 0.2
        display("third", 0.0)
        clock.now += 0.5
    assert log.getvalue() == "first: done, took 5.0 s\nsecond: done, took 2.0 s\nthird: done, took 0.5 s\n"
    # a stage cut short by an error says so
    log = io.StringIO()
    with pytest.raises(RuntimeError):
        with progress.StageProgress(log) as display:
            display("doomed", 0.3)
            clock.now += 1.0
            raise RuntimeError("diverged")
    assert log.getvalue() == "doomed: stopped after 1.0 s\n"


def test_a_long_stage_says_how_far_it_has_got_in_a_log(monkeypatch):
    # every step over LOG_EVERY_S (2 s) shows progress: after that long without a line, the next advance writes one
    clock = _Clock()
    monkeypatch.setattr(progress.time, "monotonic", clock)
    log = io.StringIO()
    with progress.StageProgress(log) as display:
        display("noise study", 0.0)
        for k in range(1, 10):
            clock.now += 0.75
            display("noise study", k / 10)
    assert log.getvalue().splitlines() == ["noise study: 30% after 2.2 s", "noise study: 60% after 4.5 s",
                                           "noise study: 90% after 6.8 s", "noise study: done, took 6.8 s"]


def test_on_a_terminal_every_stage_is_a_bar_that_ends_full():
    screen = _Terminal()
    with progress.StageProgress(screen) as display:
        for f in (0.0, 0.25, 0.5):
            display("simulating", f)
        display("writing figures", 0.0)
    finals = [part for part in screen.getvalue().split("\r") if part.strip()]
    assert any(p.startswith("simulating") and "100.0%" in p for p in finals)
    assert any(p.startswith("writing figures") and "100.0%" in p for p in finals)
    assert screen.getvalue().count("\n") == 2              # two finished bars, one line each


def test_counter_writes_a_line_per_tenth_or_nothing():
    log = io.StringIO()
    counter = progress.CountProgress(100, done=0, stream=log)
    for _ in range(100):
        counter.update(1)
    counter.close()
    assert [line.split()[1] for line in log.getvalue().splitlines()] == [f"{10 * k}/100" for k in range(11)]
    silent = io.StringIO()
    progress.CountProgress(10, stream=silent, enabled=False).update(10)
    assert silent.getvalue() == ""
