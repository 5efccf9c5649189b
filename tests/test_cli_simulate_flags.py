"""``dobkit simulate``'s flags: ``--no-figures`` writes the numbers only, figures are PNG unless ``--svg`` asks for
SVG too, the two exclude each other, and ``--engine`` picks one of the simulator's engines.
"""
from __future__ import annotations

import json

import pytest

import blocks
from blocks import load_scenario
from blocks.figure2.metrics import tracking_metrics
from dobkit.cli import SIMULATE_ENGINES, main

# --- dobkit simulate --no-figures, --svg and --engine -----------------------------------------------------------
FIGURE_STEMS = ("fig4_joint_tracking", "fig5_tracking_error", "fig6_disturbance_estimate", "fig7_estimation_error",
                "fig8_task_space")


def _simulate(short_toml, out, *flags) -> tuple[int, dict]:
    status = main(["simulate", "--scenario", str(short_toml), "--out", str(out), *flags])
    return status, (json.loads((out / "metrics.json").read_text()) if status == 0 else {})


def test_no_figures_writes_the_numbers_only(short_toml, tmp_path, capsys):
    status, metrics = _simulate(short_toml, tmp_path / "out", "--no-figures", "--engine", "fast")
    assert status == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["metrics.json", "scenario.toml", "timeseries.csv"]
    assert metrics["engine"] == "fast"
    assert "no figures (--no-figures)" in capsys.readouterr().out


def test_figures_are_png_by_default_and_svg_on_request(short_toml, tmp_path):
    assert _simulate(short_toml, tmp_path / "png", "--engine", "fast")[0] == 0
    names = {p.name for p in (tmp_path / "png").iterdir()}
    assert {f"{s}.png" for s in FIGURE_STEMS} <= names and not any(n.endswith(".svg") for n in names)
    assert _simulate(short_toml, tmp_path / "both", "--engine", "fast", "--svg")[0] == 0
    for stem in FIGURE_STEMS:
        svg = (tmp_path / "both" / f"{stem}.svg").read_text()
        assert svg.lstrip().startswith("<?xml") and "time (s)" in svg          # every figure keeps its axes' labels
        assert (tmp_path / "both" / f"{stem}.png").stat().st_size > 10_000


def test_no_figures_and_svg_exclude_each_other(short_toml, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["simulate", "--scenario", str(short_toml), "--no-figures", "--svg"])
    assert stop.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_the_engine_flag_picks_the_engine(short_toml, tmp_path):
    scenario = load_scenario(short_toml)
    for engine in ("fast", "python-control"):
        status, metrics = _simulate(short_toml, tmp_path / engine, "--no-figures", "--engine", engine)
        assert status == 0 and metrics["engine"] == engine
        # the command's numbers are those of a run with that engine from Python
        same = tracking_metrics(blocks.simulate(scenario, engine=engine))
        assert metrics["with_dob"]["rms_position_error"] == same["rms_position_error"]
    # the PD error dynamics without observer: the prismatic joint sags by M^-1 d / Kp = 1.4 / 0.25 / 180 m
    assert metrics["without_dob"]["max_abs_position_error"][2] == pytest.approx(1.4 / 0.25 / 180, rel=0.05)


def test_the_engine_choices_are_the_simulators(capsys):
    from blocks.figure2.loop import ENGINES

    assert SIMULATE_ENGINES == ENGINES
    with pytest.raises(SystemExit):
        main(["simulate", "--engine", "warp"])
    assert "invalid choice: 'warp'" in capsys.readouterr().err
