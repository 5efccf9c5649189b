"""What ``dobkit simulate`` does to be cheap, checked for what it must not change.

* ``timeseries.csv`` is written without :class:`csv.writer` per row: the bytes must be the ones ``csv.writer`` writes
  (the reference), and every float must read back bit for bit;
* the joint figures' y tick labels are plain text (no mathtext parse per label); the power of ten above an axis stays
  mathtext, and label x power of ten must give the tick's location;
* the cycle collector is off while the command runs and restored afterwards.
"""
import csv
import gc
import io
import struct
import sys

import control as ct
import matplotlib
import numpy as np
import pytest
from conftest import SHORT_SCENARIO_TOML as SHORT

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from analysis.simulation.experiment import _write_timeseries  # noqa: E402
from analysis.simulation.figures import joint_axes  # noqa: E402
from blocks import simulate  # noqa: E402
from blocks.model.rrpr.joints import RRPR_JOINTS  # noqa: E402
from dobkit.cli import build_parser, main  # noqa: E402


def _reference_csv(runs: dict) -> bytes:
    """The file as ``csv.writer`` writes it, one row at a time (what the command wrote before)."""
    first = next(iter(runs.values()))
    header, columns = ["time_s"], [np.asarray(first.time)]
    for key, resp in runs.items():
        for k, label in enumerate(resp.output_labels):
            header.append(f"{key}.{label}")
            columns.append(np.asarray(resp.outputs)[k])
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(header)
    writer.writerows(np.column_stack(columns).tolist())
    return buffer.getvalue().encode()


def _bits(values) -> list[bytes]:
    """Each float's 8 bytes (the sign of zero included); every nan as one value: text keeps no nan payload."""
    return [b"nan" if np.isnan(v) else struct.pack("<d", float(v)) for v in values]


@pytest.fixture(scope="module")
def short_runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("short")
    path = folder / "short.toml"
    path.write_text(SHORT)
    from blocks import load_scenario
    scenario = load_scenario(path)
    return path, {"with_dob": simulate(scenario, observer=True, engine="fast"),
                  "without_dob": simulate(scenario, observer=False, engine="fast")}


def test_time_series_is_what_csv_writer_writes_for_a_real_run(short_runs, tmp_path):
    _, runs = short_runs
    path = tmp_path / "timeseries.csv"
    _write_timeseries(path, runs)
    assert path.read_bytes() == _reference_csv(runs)


def test_time_series_keeps_every_float_bit_for_bit_even_odd_ones(tmp_path):
    # zero of both signs, the smallest subnormal, the largest float, nan, infinities and a repeating binary fraction
    odd = np.array([[0.0, -0.0, 5e-324, 1.7976931348623157e308, np.nan, np.inf, -np.inf, 0.1, -1 / 3, 2.5e-17]])
    time = np.arange(odd.shape[1], dtype=float) * 0.005
    outputs = np.vstack([odd, odd[:, ::-1]])
    runs = {key: ct.TimeResponseData(time, sign * outputs, output_labels=["x[0]", "x[1]"], sysname=key, issiso=False)
            for key, sign in (("a", 1.0), ("b", -1.0))}
    path = tmp_path / "odd.csv"
    _write_timeseries(path, runs)
    assert path.read_bytes() == _reference_csv(runs)
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "a.x[0]", "a.x[1]", "b.x[0]", "b.x[1]"]
    read = np.array(rows[1:], dtype=float)
    assert _bits(read[:, 0]) == _bits(time)
    for column, values in enumerate([outputs[0], outputs[1], -outputs[0], -outputs[1]], start=1):
        assert _bits(read[:, column]) == _bits(values)


def _draw(scales):
    fig, axes = joint_axes("ticks", RRPR_JOINTS)
    t = np.linspace(0.0, 10.0, 201)
    for ax, scale in zip(axes, scales):
        ax.plot(t, scale * np.sin(t) + (0.0 if scale < 1e3 else 3 * scale))
    fig.canvas.draw()
    return fig, axes


def _power_of_ten(offset: str) -> int:
    """The exponent of a mathtext power of ten such as ``$\\times\\mathdefault{10^{\u22124}}\\mathdefault{}$``."""
    assert offset.startswith("$") and offset.endswith("$") and "10^{" in offset, offset
    exponent = offset.split("10^{", 1)[1].split("}", 1)[0]
    return int(exponent.replace("\u2212", "-"))


def test_tick_labels_are_plain_text_and_the_power_of_ten_stays_mathtext():
    scales = (2.5e-4, 0.8, 40.0, 6e4)                # below 1e-3, ordinary, ordinary, from 1e4 on
    fig, axes = _draw(scales)
    try:
        for ax, scale in zip(axes, scales):
            formatter = ax.yaxis.get_major_formatter()
            locs = [loc for loc in ax.get_yticks() if ax.get_ylim()[0] <= loc <= ax.get_ylim()[1]]
            labels = [formatter(loc) for loc in locs]
            assert labels and not any("$" in label for label in labels), labels
            offset = ax.yaxis.get_offset_text().get_text()
            exponent = _power_of_ten(offset) if scale < 1e-3 or scale >= 1e4 else 0
            if exponent == 0:
                assert offset == "", offset
            else:                                   # what the axis shows above it: x 10^-4, x 10^4
                assert exponent == int(np.floor(np.log10(max(abs(v) for v in locs))))
            for loc, label in zip(locs, labels):    # the label times the power of ten is the tick's place
                assert float(label.replace("\u2212", "-")) * 10.0 ** exponent == pytest.approx(loc, rel=1e-9,
                                                                                                 abs=1e-12 * scale)
    finally:
        plt.close(fig)


def test_the_command_runs_without_the_cycle_collector_and_restores_it(short_runs, tmp_path):
    path, _ = short_runs
    assert main(["simulate", "--scenario", str(path), "--engine", "fast", "--no-figures", "--out",
                 str(tmp_path / "first")]) == 0 and gc.isenabled()          # the whole entry point, once
    collections = []

    def count(phase, info):
        # a collection made while the experiment runs (its frame on the stack); the one the restored collector may
        # make as the command returns is not
        frame = sys._getframe()
        while frame is not None and frame.f_code.co_name != "run_experiment":
            frame = frame.f_back
        if phase == "start" and frame is not None:
            collections.append(info["generation"])

    was = gc.isenabled()
    gc.callbacks.append(count)
    try:
        for enabled, out in ((True, tmp_path / "on"), (False, tmp_path / "off")):
            args = build_parser().parse_args(["simulate", "--scenario", str(path), "--engine", "fast",
                                              "--out", str(out)])
            gc.enable() if enabled else gc.disable()
            collections.clear()
            status = args.func(args)                     # the command itself, as main() runs it after parsing
            assert status == 0 and (out / "timeseries.csv").is_file() and (out / "fig8_task_space.png").is_file()
            assert collections == []                     # not one collection while the experiment ran
            assert gc.isenabled() is enabled             # the caller's state back
    finally:
        gc.callbacks.remove(count)
        gc.enable() if was else gc.disable()


def test_only_the_program_freezes_what_it_made_before_it_exits(monkeypatch, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[simulation]\nt_final = -1\n")
    command = ["simulate", "--scenario", str(bad), "--out", str(tmp_path / "never")]
    frozen = gc.get_freeze_count()
    try:
        assert main(command) == 2 and gc.get_freeze_count() == frozen          # a caller in Python: untouched
        monkeypatch.setattr(sys, "argv", ["dobkit", *command])
        assert main() == 2 and gc.get_freeze_count() > frozen                # the program: frozen for its exit
        assert "t_final" in capsys.readouterr().err
    finally:
        gc.unfreeze()
