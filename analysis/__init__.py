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
from .bandwidth import BandwidthSurvey, bandwidth_survey, observer_modes
from .experiment import ExperimentResult, run_experiment
from .figures import convergence_figure, paper_figures, save_figure
from .frequency import FrequencyAnalysis, frequency_analysis
from .gain_design import ObserverDesign, convergence_certificate, design_observer_gain
from .linear import MismatchStudy, OperatingPoint, mismatch_analysis, operating_point_analysis
from .report import AnalysisResult, analyze, run_analysis, write_report
from .settings import QUICK_SETTINGS, AnalysisSettings
from .studies import Studies, gain_grid_study, observer_gain_study
from .sweep import SweepError, SweepSpec, load_sweep
from .sweep_report import SweepSummary, write_summary
from .sweep_runner import SweepOutcome, run_sweep

__all__ = [
    "run_analysis", "analyze", "write_report", "AnalysisSettings", "QUICK_SETTINGS", "AnalysisResult",
    "run_experiment", "ExperimentResult", "paper_figures", "convergence_figure", "save_figure",
    "operating_point_analysis", "mismatch_analysis", "OperatingPoint", "MismatchStudy",
    "bandwidth_survey", "observer_modes", "BandwidthSurvey",
    "design_observer_gain", "convergence_certificate", "ObserverDesign",
    "frequency_analysis", "FrequencyAnalysis", "gain_grid_study", "observer_gain_study", "Studies",
    "load_sweep", "run_sweep", "write_summary", "SweepSpec", "SweepOutcome", "SweepSummary", "SweepError",
]
