"""Analysis of the Figure-2 loop: linearization, observer bandwidth, gain design, studies, sweeps, figures, reports.

The public API in a few names::

    import analysis
    result = analysis.run_analysis("paper", analysis.QUICK_SETTINGS)     # typed results (result.to_json())
    analysis.write_report("paper", "report-py", analysis.QUICK_SETTINGS)  # report.html, analysis.json, figures
    experiment = analysis.run_experiment("paper", "run")                 # the paper's Figures 4-8 and Table 3

Modules, one job each: ``linear`` (poles of the linearized loop, inertia
mismatch), ``bandwidth`` (observer modes over the workspace), ``gain_design``
(a matrix observer gain and its convergence certificate), ``frequency``
(disturbance-rejection responses), ``studies`` (gain grids and observer-gain
sweeps from simulations), ``settings`` (what the analyses compute),
``experiment`` and ``figures`` (the paper's figures and table), ``report`` /
``report_view`` / ``report_html`` / ``templates/`` (the analysis and its HTML
report: what the page says and how it is laid out), ``sweep`` / ``sweep_runner`` /
``sweep_report`` (grids and Monte Carlo draws over scenario keys),
``results`` (strict JSON for the typed results).
"""
from blocks.lazy import lazy_exports

# Each public name and its module, imported on first use (PEP 562): ``from analysis.sweep import load_sweep``
# checks a sweep file without loading matplotlib and every analysis.
_WHERE = {
    "bandwidth": ("BandwidthSurvey", "bandwidth_survey", "observer_modes"),
    "experiment": ("ExperimentResult", "run_experiment"),
    "figures": ("convergence_figure", "paper_figures", "save_figure"),
    "frequency": ("FrequencyAnalysis", "frequency_analysis"),
    "gain_design": ("ObserverDesign", "convergence_certificate", "design_observer_gain"),
    "linear": ("MismatchStudy", "OperatingPoint", "mismatch_analysis", "operating_point_analysis"),
    "report": ("AnalysisResult", "analyze", "run_analysis", "write_report"),
    "settings": ("QUICK_SETTINGS", "AnalysisSettings"),
    "studies": ("Studies", "gain_grid_study", "observer_gain_study"),
    "sweep": ("SweepError", "SweepSpec", "load_sweep"),
    "sweep_report": ("SweepSummary", "write_summary"),
    "sweep_runner": ("SweepOutcome", "run_sweep"),
}
__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals())


__all__ = [
    "run_analysis", "analyze", "write_report", "AnalysisSettings", "QUICK_SETTINGS", "AnalysisResult",
    "run_experiment", "ExperimentResult", "paper_figures", "convergence_figure", "save_figure",
    "operating_point_analysis", "mismatch_analysis", "OperatingPoint", "MismatchStudy",
    "bandwidth_survey", "observer_modes", "BandwidthSurvey",
    "design_observer_gain", "convergence_certificate", "ObserverDesign",
    "frequency_analysis", "FrequencyAnalysis", "gain_grid_study", "observer_gain_study", "Studies",
    "load_sweep", "run_sweep", "write_summary", "SweepSpec", "SweepOutcome", "SweepSummary", "SweepError",
]
