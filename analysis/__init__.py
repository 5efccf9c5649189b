"""Analyses of the Figure-2 loop: linearization, observer bandwidth, gain design, frequency responses, studies,
sweeps, figures and the HTML report.

The public API in a few names (loaded when first used, so ``import analysis`` stays light)::

    import analysis
    result = analysis.run_analysis("paper", analysis.QUICK_SETTINGS)     # typed results, nothing written
    analysis.write_report("paper", "report-py", analysis.QUICK_SETTINGS)  # report.html, analysis.json, figures

Modules, one job each: ``linear``, ``bandwidth``, ``gain_design``,
``frequency``, ``studies`` (the analyses), ``settings`` (what they compute),
``report`` (all of them, ``analysis.json``, the report), ``report_view`` and
``templates/`` (what the page says and how it is laid out), ``figures`` and
``analysis_figures``, ``experiment`` (the paper's experiment), ``sweep``,
``sweep_runner`` and ``sweep_report``.
"""
from __future__ import annotations

import importlib

# name -> the module that defines it
_EXPORTS = {"run_analysis": "report", "analyze": "report", "write_report": "report", "AnalysisResult": "report",
            "AnalysisSettings": "settings", "QUICK_SETTINGS": "settings", "run_experiment": "experiment"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'analysis' has no attribute {name!r}")
