"""A tuning interrupted while it writes its results: the previous results stay whole, or none are left, and its
progress says the stage stopped (docs/hostile-inputs.md, "Round 7").
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

TUNING = """
name = "tiny"
scenario = "base.toml"
objective = "worst"
[search]
"gains.kp" = [100, 400]
seed = 1
population = 5
max_evaluations = 13
polish_evaluations = 2
[monte_carlo]
runs = 2
seed = 1
[monte_carlo.distributions]
"nominal_scale.m1" = {kind = "choice", values = [0.9, 1.1]}
"""


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    """A tiny tuning of the paper scenario's first 0.2 s, run once to the end: (tuning file, output folder)."""
    import blocks
    from analysis.tune.runner import run_tune
    folder = tmp_path_factory.mktemp("tiny-tune")
    base = blocks.load_scenario("paper").replace(simulation={"t_final": 0.2}, trajectory={"duration": 10.0})
    (folder / "base.toml").write_text(base.to_toml(), encoding="utf-8")
    (folder / "tiny.toml").write_text(TUNING, encoding="utf-8")
    run_tune(folder / "tiny.toml", folder / "out", workers=1, progress=False, engine="fast")
    return folder / "tiny.toml", folder / "out"


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_an_interrupt_while_a_tuning_writes_its_results_leaves_the_previous_results_or_none(tuned, monkeypatch):
    # Ctrl-C or SIGTERM after the figures, before tune.json: the tuned scenario file and the figures were left
    # without tune.json (or beside the previous run's tune.json)
    import analysis.tune.report
    from analysis.tune.runner import LOG_NAME, run_tune
    path, out = tuned
    whole = _files(out)
    assert {"tune.json", "paper-tuned.toml", "figures/tune_history.png", LOG_NAME} <= set(whole)
    real = analysis.tune.report.write_figures

    def drawn_then_interrupted(*args, **kwargs):
        real(*args, **kwargs)
        raise KeyboardInterrupt("received signal SIGTERM")
    monkeypatch.setattr(analysis.tune.report, "write_figures", drawn_then_interrupted)
    with pytest.raises(KeyboardInterrupt):                 # resumed from the log: straight to the results
        run_tune(path, out, workers=1, progress=False, engine="fast")
    assert _files(out) == whole                            # the previous results, byte for byte, and nothing else
    shutil.rmtree(out / "figures")                        # only the evaluations left: the first writing of results
    (out / "tune.json").unlink()
    (out / "paper-tuned.toml").unlink()
    with pytest.raises(KeyboardInterrupt):
        run_tune(path, out, workers=1, progress=False, engine="fast")
    assert [p.name for p in out.iterdir()] == [LOG_NAME]  # no tuned file, figure or staging folder
    monkeypatch.setattr(analysis.tune.report, "write_figures", real)
    run_tune(path, out, workers=1, progress=False, engine="fast")
    again = _files(out)
    assert set(again) == set(whole)
    assert again["paper-tuned.toml"] == whole["paper-tuned.toml"]


def test_an_interrupted_tunings_progress_says_its_stage_stopped(tuned, monkeypatch, capsys):
    # "tuning: writing results: done, took 2.6 s" was printed above "dobkit tune: interrupted"
    import analysis.tune.report
    from analysis.tune.runner import run_tune
    path, out = tuned

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(analysis.tune.report, "write_figures", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_tune(path, out, workers=1, progress=True, engine="fast")
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("tuning: writing results: stopped after ")
    assert not any(line.startswith("tuning: writing results: done") for line in lines)
