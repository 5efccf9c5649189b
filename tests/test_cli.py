"""End-to-end checks of ``dobkit simulate``: files, schema, reproducibility and clear errors."""
import csv
import json

import numpy as np
import pytest

from conftest import SHORT_SCENARIO_TOML as SHORT
from blocks import load_scenario
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
        assert {f"{stem}.png", f"{stem}.svg"} <= names
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
    assert "diverged at t =" in err
    assert not out.exists() and not list(tmp_path.glob(".out.partial-*"))


def test_report_refuses_a_missing_sweep_summary_before_any_work(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--quick", "--sweep", str(tmp_path / "no-such-summary"), "--out", str(out)]) == 2
    assert "has no summary.json" in capsys.readouterr().err
    assert not out.exists()
