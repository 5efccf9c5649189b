"""Shared helpers of the benchmarks: interleaved timing, peak memory, and a plain-text table."""
from __future__ import annotations

import gc
import platform
import resource
import statistics
import time
import tracemalloc
from collections.abc import Callable


def time_interleaved(cases: dict[str, Callable[[], object]], repeats: int,
                     repeats_of: dict[str, int] | None = None, clock: str = "wall") -> dict[str, list[float]]:
    """Seconds of each case, run in turn ``repeats`` times so that load on a shared machine hits all
    cases alike.  ``repeats_of`` caps the repeats of slow cases.  ``clock``: ``"wall"``
    (:func:`time.perf_counter`) or ``"cpu"`` (:func:`time.process_time`, this process's CPU time,
    which waiting for a core shared with other work does not inflate); ``"both"`` returns
    ``{name: [(wall, cpu), ...]}``."""
    times: dict[str, list] = {name: [] for name in cases}
    for r in range(repeats):
        for name, fn in cases.items():
            if repeats_of and r >= repeats_of.get(name, repeats):
                continue
            gc.collect()
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            times[name].append({"wall": wall, "cpu": cpu, "both": (wall, cpu)}[clock])
    return times


def peak_memory(fn: Callable[[], object]) -> float:
    """Peak Python heap allocation (MB) while ``fn`` runs, measured with :mod:`tracemalloc`."""
    gc.collect()
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1e6


def max_rss_mb() -> float:
    """Peak resident set size of this process so far (MB), from :func:`resource.getrusage`."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3     # Linux reports kB


def summary(values: list[float]) -> tuple[float, float]:
    """(min, median) of a list of times."""
    return min(values), statistics.median(values)


def machine() -> str:
    """One line naming the machine and the library versions."""
    import os

    import control
    import numpy
    import scipy
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, scipy {scipy.__version__}, python-control {control.__version__}")


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    fmt = lambda row: "| " + " | ".join(str(x).ljust(w) for x, w in zip(row, widths)) + " |"  # noqa: E731
    return "\n".join([fmt(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [fmt(r) for r in rows])


def print_and_save(text: str, figures: dict, json_path: str | None) -> int:
    """Print a benchmark's report and, when asked, write its figures as JSON; the scripts' exit status (0)."""
    import json
    print(text)
    if json_path:
        with open(json_path, "w", encoding="utf-8") as fh:
            json.dump(figures, fh, indent=2)
    return 0
