"""Sweep summaries: figures that survive any data, words for people, escaped names, and a folder that is
always one whole summary of one results file."""
from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
from sweep_files import run_sweep_command, write_short_scenario, write_sweep

from analysis.sweep import summary as sweep_report
from analysis.sweep.runner import run_sweep
from analysis.sweep.spec import SweepError, load_sweep
from analysis.sweep.summary import html_section, summarize, write_summary

ULP = np.finfo(float).eps


@pytest.fixture()
def short_file(tmp_path):
    """The first 0.3 s of the paper scenario (its 10 s path), as a file the sweep files refer to."""
    return write_short_scenario(tmp_path, t_final=0.3)


_write = write_sweep

_cli = run_sweep_command


def _rows(columns: dict, keys=None) -> list[dict]:
    """Result rows from metric columns (lists of values, None for a value that was not finite)."""
    n = len(next(iter(columns.values())))
    rows = []
    for i in range(n):
        metrics = {}
        for name, values in columns.items():
            metrics[name] = values[i]
        rows.append({"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": 100.0 + i} | (keys or {}),
                     "status": "ok", "metrics": metrics})
    return rows


FEW = '[outputs]\nmetrics = ["rms_position_error", "max_tool_position_error_mm"]\n'
HEADER = {"name": "h", "runs": 0, "worst_metric": "max_tool_position_error_mm", "worst_count": 3}

DATA = {
    "constant": [2.9] * 12,
    "one ulp apart": [1e-4, 1e-4 * (1 + ULP), 1e-4, 1e-4 * (1 + 2 * ULP)] * 3,
    "one run": [3.1],
    "with not finite": [1.0, None, 2.0, None, 3.0],
    "nothing finite": [None, None, None],
    "near the float limit": [1e308, -1e308, 5e307, 1.0],
    "negative and tiny": [-1e-300, 2e-300, 0.0, 5e-301],
}


@pytest.mark.parametrize("case", list(DATA))
def test_figures_and_statistics_survive_any_data(tmp_path, case):
    values = DATA[case]
    columns = {"max_tool_position_error_mm": values, "rms_position_error": [[v, v, v, v] for v in values]}
    rows = _rows(columns)
    files = write_summary((dict(HEADER, runs=len(rows)), rows), tmp_path / "out")
    summary = json.loads(files["json"].read_text())
    listed = [f["file"] for f in summary["figures"]]
    assert "hist_max_tool_position_error_mm.png" in listed and "hist_rms_position_error.png" in listed
    for name in listed:
        assert (tmp_path / "out" / name).stat().st_size > 0
        assert (tmp_path / "out" / name).with_suffix(".svg").stat().st_size > 0
    finite = [v for v in values if v is not None]
    stats = summary["statistics"].get("max_tool_position_error_mm")
    if not finite:
        assert stats is None
        return
    assert stats["count"] == len(finite) and stats["not_finite"] == len(values) - len(finite)
    assert stats["min"] == min(finite) and stats["max"] == max(finite)
    scale = max(abs(v) for v in finite) or 1.0
    mean = math.fsum(v / scale for v in finite) / len(finite) * scale       # no overflow on the way
    assert stats["mean"] == pytest.approx(mean, rel=1e-12, abs=1e-300)
    assert "Infinity" not in files["json"].read_text() and "NaN" not in files["json"].read_text()


def _texts_inside(fig) -> list[str]:
    """What is drawn outside the figure (cut off in the PNG): axes with their tick labels and axis labels, and
    the figure's title."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    parts = [(ax.get_xlabel() or "axes", ax.get_tightbbox(renderer)) for ax in fig.axes]
    parts += [(t.get_text(), t.get_window_extent(renderer)) for t in fig.texts if t.get_text()]
    return [name for name, extent in parts
            if extent.x0 < box.x0 - 1 or extent.x1 > box.x1 + 1 or extent.y0 < box.y0 - 1 or extent.y1 > box.y1 + 1]


def test_axes_have_no_offset_text_and_no_label_is_cut(tmp_path):
    """Values near 1.5e-4 with small spreads made matplotlib print '1e-4' over the unit label; a four-panel
    figure cut the last label to '[N m'."""
    rng = np.random.default_rng(3)
    n = 60
    d = (1.5e-4 + 1e-7 * rng.random((n, 4))).tolist()
    rows = _rows({"rms_disturbance_error": d, "max_abs_disturbance_error": d,
                  "max_tool_position_error_mm": (2.9 + 1e-3 * rng.random(n)).tolist()})
    table, _ = sweep_report._load((dict(HEADER, runs=n), rows), None)
    summary = sweep_report._summary(table, "")
    drawn = list(sweep_report._draw_figures(table, summary))
    assert {stem for _, stem, _ in drawn} >= {"hist_rms_disturbance_error", "worst_vs_gains_kp"}
    for fig, stem, _ in drawn:
        fig.canvas.draw()
        for ax in fig.axes:
            assert ax.xaxis.get_offset_text().get_text() == "", stem
            assert ax.yaxis.get_offset_text().get_text() == "", stem
        assert _texts_inside(fig) == [], stem
    hist = next(fig for fig, stem, _ in drawn if stem == "hist_rms_disturbance_error")
    labels = [ax.get_xlabel() for ax in hist.axes]
    assert labels == ["Joint 1 (theta1) [µN m]", "Joint 2 (theta2) [µN m]", "Joint 3 (d3) [µN]",
                      "Joint 4 (theta4) [µN m]"]


def test_names_and_values_cannot_add_html_to_the_summary(tmp_path):
    header = dict(HEADER, name="<img src=x onerror=alert(1)>", description="<script>alert(2)</script> | a pipe",
                  scenario="<b>base</b>", runs=2)
    rows = _rows({"max_tool_position_error_mm": [1.0, 2.0]}, keys={"observer.variant": "<i>eq16</i>"})
    rows.append({"run_id": "bad", "index": 2, "values": {"gains.kp": 1.0}, "status": "diverged", "metrics": {},
                 "message": "<a href='x'>diverged</a>"})
    files = write_summary((header, rows), tmp_path / "out")
    markdown = files["markdown"].read_text()
    for raw in ("<img", "<script", "<b>", "<i>", "<a href"):
        assert raw not in markdown
    assert "&lt;script&gt;alert(2)&lt;/script&gt; \\| a pipe" in markdown
    section = html_section(tmp_path / "out")
    for raw in ("<img src=x", "<script", "<b>base", "<i>eq16", "<a href"):
        assert raw not in section


def test_captions_and_metric_names_are_for_people(tmp_path, short_file):
    path = _write(tmp_path, '[grid]\n"gains.kp" = [150, 250]\n[monte_carlo]\nruns = 3\nseed = 2\n'
                            '[monte_carlo.distributions]\n'
                            '"disturbance.f_r[2]" = {kind = "normal", mean = 1.4, std = 0.2}\n' + FEW)
    assert _cli(["sweep", str(path), "--workers", "1", "--no-progress"]) == 0
    folder = tmp_path / "s-summary"
    summary = json.loads((folder / "summary.json").read_text())
    captions = {f["file"]: f["caption"] for f in summary["figures"]}
    assert captions["worst_vs_disturbance_f_r_2.png"].startswith(
        "Peak tool-tip error against the Eq. 4 amplitude f_r, Joint 3 (d3) (disturbance.f_r[2])")
    assert captions["hist_rms_position_error.png"].startswith("Distribution of the RMS position error over the 6")
    section = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html_section(folder))
    figcaptions = re.findall(r"<figcaption>(.*?)</figcaption>", section)
    assert len(figcaptions) == len(captions) and not any(re.fullmatch(r"[\w]+", c) for c in figcaptions)
    assert "RMS position error, Joint 1 (theta1)" in section and "Peak tool-tip error" in section
    for code in ("rms_position_error", "max_tool_position_error_mm", "worst_vs_"):
        assert code not in section
    markdown = (folder / "summary.md").read_text()
    assert "| RMS position error, Joint 3 (d3) |" in markdown and "rms_position_error[" not in markdown


def test_a_failed_summary_leaves_the_previous_one_whole(tmp_path, short_file):
    spec = load_sweep(_write(tmp_path, '[grid]\n"gains.kp" = [150, 250]\n' + FEW))
    results = tmp_path / "r.jsonl"
    run_sweep(spec, results, workers=1, progress=False)
    folder = tmp_path / "sum"
    write_summary(results, folder, spec=spec)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(ValueError):
        write_summary(results, folder, formats=("png", "no-such-format"), spec=spec)      # fails after some figures
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(SweepError, match="not a sweep summary"):
        write_summary(results, tmp_path / "mine", spec=spec)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_the_summary_folder_belongs_to_its_results_file(tmp_path, short_file, capsys):
    path = _write(tmp_path, '[grid]\n"gains.kp" = [150, 250]\n' + FEW)
    assert _cli(["sweep", str(path), "--results", str(tmp_path / "other.jsonl"), "--workers", "1",
                 "--no-progress"]) == 0
    summary = json.loads((tmp_path / "other-summary" / "summary.json").read_text())
    assert summary["results"] == "other.jsonl" and summary["definition"] == load_sweep(path).definition
    assert not (tmp_path / "s-summary").exists()
    # --summary-only writes it again from the results alone
    for p in (tmp_path / "other-summary").iterdir():
        p.unlink()
    (tmp_path / "other-summary").rmdir()
    assert _cli(["sweep", str(path), "--results", str(tmp_path / "other.jsonl"), "--summary-only"]) == 0
    assert (tmp_path / "other-summary" / "summary.md").is_file()
    assert _cli(["sweep", str(path), "--results", str(tmp_path / "none.jsonl"), "--summary-only"]) == 2
    assert "run the sweep first" in capsys.readouterr().err


def test_the_report_embeds_only_the_figures_of_a_whole_summary(tmp_path, short_file):
    spec = load_sweep(_write(tmp_path, '[grid]\n"gains.kp" = [150, 250]\n' + FEW))
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    folder = tmp_path / "sum"
    files = write_summary(tmp_path / "r.jsonl", folder, spec=spec)
    n = len(files["summary"].figures)
    (folder / "hist_from_another_sweep.png").write_bytes((folder / files["summary"].figures[0].file).read_bytes())
    assert html_section(folder).count("<img") == n
    (folder / files["summary"].figures[-1].file).unlink()
    with pytest.raises(SweepError, match="is not there"):
        html_section(folder)


def test_an_ordinary_gain_grid_is_summarised(tmp_path, short_file):
    """`gains.kp = [100, 180, 250]`, whose final errors on the held prismatic joint agree to a few ulp
    (the near-constant data that broke the histograms; the unit tests above cover it case by case)."""
    spec = load_sweep(_write(tmp_path, '[grid]\n"gains.kp" = [100, 180, 250]\n[outputs]\n'
                                       'metrics = ["rms_disturbance_error", "max_tool_position_error_mm"]\n'))
    run_sweep(spec, tmp_path / "r.jsonl", workers=1, progress=False)
    files = write_summary(tmp_path / "r.jsonl", tmp_path / "sum", spec=spec)
    summary = summarize(tmp_path / "r.jsonl", spec)
    assert summary.counts.finished == 3
    assert [f.file for f in files["summary"].figures] == [
        "hist_rms_disturbance_error.png", "hist_max_tool_position_error_mm.png", "worst_vs_gains_kp.png"]


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


SUMMARY_HEADER = {"name": "h", "runs": 3, "worst_metric": "max_tool_position_error_mm", "worst_count": 3}


SUMMARY_ROWS = [{"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": 100.0 + i}, "status": "ok",
                 "metrics": {"max_tool_position_error_mm": 1.0 + i, "rms_position_error": [1e-4] * 4}}
                for i in range(3)]


@pytest.mark.parametrize("previous", [False, True], ids=["first summary", "over a previous summary"])
def test_an_interrupt_as_the_summarys_staging_folder_is_made_leaves_nothing_of_it(tmp_path, monkeypatch, previous):
    # Ctrl-C or SIGTERM after mkdtemp made '.NAME.partial-XXXX' and before its name came back: the folder stayed
    from analysis.sweep.summary import write_summary
    out = tmp_path / "s-summary"
    if previous:
        write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    before = _files(tmp_path)
    real = os.mkdir

    def made_then_interrupted(path, *args, **kwargs):
        real(path, *args, **kwargs)
        if ".partial-" in os.fspath(path):
            raise KeyboardInterrupt("received signal SIGTERM")
    monkeypatch.setattr(os, "mkdir", made_then_interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    monkeypatch.setattr(os, "mkdir", real)
    assert _files(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == (["s-summary"] if previous else [])
    files = write_summary((SUMMARY_HEADER, SUMMARY_ROWS), out, formats=("png",))
    assert files["json"] == out / "summary.json" and files["json"].is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s-summary"]


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_sweep_statistics_worst_runs_and_influence_are_the_textbook_ones():
    """su-std-ddof, su-p95, su-ranks-ties, su-mean-scale, su-worst-order.  Against Python's statistics module
    (mean, sample standard deviation, median, the 5 % and 95 % cut points of the inclusive -- linear -- method)
    and scipy.stats.spearmanr (ties get their mean rank); the worst runs are the largest values, largest first."""
    import statistics

    from scipy.stats import spearmanr

    from analysis.sweep.summary import summarize

    rng = np.random.default_rng(5)
    kp = np.repeat([100.0, 120.0, 140.0, 160.0, 180.0, 200.0, 220.0], 3)         # a swept key with ties
    metric = np.round(30.0 + 0.05 * kp + rng.normal(0.0, 4.0, kp.size), 1)     # mm; rounded: ties here too
    rows = [{"run_id": f"run{i:04d}", "index": i, "values": {"gains.kp": float(kp[i])}, "status": "ok",
             "metrics": {"max_tool_position_error_mm": float(metric[i])}} for i in range(kp.size)]
    header = {"name": "h", "runs": len(rows), "worst_metric": "max_tool_position_error_mm", "worst_count": 4}
    summary = summarize((header, rows))
    st = summary.statistics["max_tool_position_error_mm"]
    data = metric.tolist()
    cuts = statistics.quantiles(data, n=20, method="inclusive")
    assert st.mean == pytest.approx(statistics.fmean(data), rel=1e-12)
    assert st.std == pytest.approx(statistics.stdev(data), rel=1e-12)
    assert st.median == pytest.approx(statistics.median(data), rel=1e-12)
    assert st.p5 == pytest.approx(cuts[0], rel=1e-12) and st.p95 == pytest.approx(cuts[-1], rel=1e-12)
    expected = sorted(range(kp.size), key=lambda i: -metric[i])[:4]
    assert [w.value for w in summary.worst] == [metric[i] for i in expected]
    assert summary.influence["gains.kp"] == pytest.approx(spearmanr(kp, metric).statistic, rel=1e-12)


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
