"""Analysis of the Figure-2 loop: linearization, observer bandwidth, gain design, studies, sweeps, figures, reports.

The public API in a few names::

    import analysis
    result = analysis.run_analysis("paper", analysis.QUICK_SETTINGS)     # typed results (result.to_json())
    analysis.write_report("paper", "report-py", analysis.QUICK_SETTINGS)  # report.html, analysis.json, figures
    experiment = analysis.run_experiment("paper", "run")                 # the paper's Figures 4-8 and Table 3

Sub-packages, one subject each:

- ``linear``: the loop linearized (poles, inertia mismatch, observer bandwidth over the workspace, gain design,
  disturbance-rejection frequency responses, the sampled loop), for any arm model;
- ``simulation``: from nonlinear simulations (the paper's experiment, its Figures 4-8 and Table 3, gain and
  noise studies);
- ``report``: all analyses of a scenario in one ``analysis.json`` and a self-contained HTML page;
- ``jobs``: what the resumable jobs share (one key checker, the results logs, Dask clusters, figures);
- ``sweep`` and ``tune``: the two kinds of job, grids and Monte Carlo draws over scenario keys, and gain tuning;

and ``results`` (strict JSON for the typed results).
"""
from blocks.lazy import lazy_exports

# Each public name and its module, imported on first use (PEP 562): ``from analysis.sweep.spec import load_sweep``
# checks a sweep file without loading matplotlib and every analysis.
_WHERE = {
    "linear.bandwidth": ("BandwidthSurvey", "bandwidth_survey", "observer_modes"),
    "simulation.experiment": ("ExperimentResult", "run_experiment"),
    "simulation.figures": ("convergence_figure", "paper_figures", "save_figure"),
    "linear.frequency": ("FrequencyAnalysis", "frequency_analysis"),
    "linear.gain_design": ("ObserverDesign", "convergence_certificate", "design_observer_gain"),
    "linear.loop": ("MismatchStudy", "OperatingPoint", "mismatch_analysis", "operating_point_analysis"),
    "report.build": ("AnalysisResult", "analyze", "run_analysis", "write_report"),
    "report.settings": ("QUICK_SETTINGS", "AnalysisSettings"),
    "simulation.studies": ("Studies", "gain_grid_study", "observer_gain_study"),
    "sweep.spec": ("SweepError", "SweepSpec", "load_sweep"),
    "sweep.summary": ("SweepSummary", "write_summary"),
    "sweep.runner": ("SweepOutcome", "run_sweep"),
    "tune.spec": ("TuneError", "TuneSpec", "load_tuning"),
    "tune.runner": ("run_tune",),
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
    "load_tuning", "run_tune", "TuneSpec", "TuneError",
]
