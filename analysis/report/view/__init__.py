"""What the analysis report shows: its numbers and statements, computed from the typed results.

:func:`build_view` turns an :class:`~analysis.report.build.AnalysisResult`, the
experiment's metrics and the scenario into a :class:`ReportView`: the page's
header (a quick preview says so, and what it leaves out), a table of
contents, the summary for the surgical team and one view per section, each
built by its own module (:mod:`.scenario`, :mod:`.simulation`, :mod:`.linear`,
:mod:`.bandwidth`, :mod:`.design`, :mod:`.frequency`, :mod:`.studies`;
numbers and words in :mod:`.text`).  Statements that interpret numbers ("the
observer limits the rejection speed", "the loop goes unstable below ...") are
generated from the result and only made when the result supports it; a
sentence that compares is computed from every number it compares.  The
templates of :mod:`analysis.report.html` only lay the view out (and escape
every text).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from analysis.report.settings import AnalysisSettings, observer_study_gains, preview_differences

from .bandwidth import BandwidthSection, bandwidth_section
from .design import DesignSection, design_section
from .digital import DigitalSection, digital_section
from .frequency import FrequencySection, frequency_section
from .linear import LinearSection, linear_section
from .scenario import ScenarioSection, scenario_section
from .simulation import SimulationSection, simulation_section, worse_with_observer
from .studies import StudiesSection, studies_section
from .summary import plain_summary
from .text import Figure, Paragraph, Table, arm_joints, arm_of, fmt, is_paper_arm, split_caveats, stability_text

__all__ = ["ReportView", "Header", "Table", "Figure", "Paragraph", "build_view", "plain_summary", "worse_with_observer",
           "stability_text", "split_caveats", "fmt", "regenerate_command", "SECTIONS"]

#: The report's sections in order: (anchor id, heading).
SECTIONS = (("summary", "Summary for the surgical team"), ("scenario", "1. Scenario"),
            ("simulation", "2. Simulation of the scenario (paper Figures 4-8, Table 3)"),
            ("linear", "3. Linearized closed loop"), ("bandwidth", "4. Observer bandwidth across the workspace"),
            ("design", "5. Observer gain design"), ("frequency", "6. Disturbance rejection in frequency"),
            ("studies", "7. Gain and noise studies"))
#: The section of scenarios with a digital controller.
DIGITAL_SECTION = ("digital", "8. Digital implementation")


@dataclass(frozen=True)
class Header:
    """The page's title, how to make it again and, for a quick preview, what it leaves out."""

    title: str
    regenerate: str
    full_command: str | None
    preview: list[str] | None


@dataclass(frozen=True)
class ReportView:
    """Everything the report page shows, in order."""

    scenario_name: str
    header: Header
    dobkit_version: str
    python_control_version: str
    contents: list[tuple[str, str]]
    headings: dict[str, str]
    summary: list[str]
    scenario: ScenarioSection
    simulation: SimulationSection
    linear: LinearSection
    bandwidth: BandwidthSection
    design: DesignSection
    frequency: FrequencySection | None
    studies: StudiesSection
    digital: DigitalSection | None = None
    extra_sections: list[str] = field(default_factory=list)
    not_done_frequency: str = ""


def regenerate_command(source: str, settings: AnalysisSettings, quick: bool | None = None) -> str:
    """The ``dobkit report`` command that makes this report again (``quick``: override the preview flag)."""
    quick = settings.quick if quick is None else quick
    command = f"dobkit report --scenario {source}" + (" --quick" if quick else "")
    if settings.observer_target_rad_s != AnalysisSettings().observer_target_rad_s:
        command += f" --observer-target {settings.observer_target_rad_s:g}"
    return command


def _header(result, scenario) -> Header:
    settings = result.settings
    if settings.quick:
        return Header(title=f"dobkit analysis report, quick preview: scenario '{scenario.name}'",
                      regenerate=regenerate_command(scenario.source, settings),
                      full_command=regenerate_command(scenario.source, settings, quick=False),
                      preview=preview_differences(settings, joints=arm_joints(scenario),
                                                  observer_gains=observer_study_gains(scenario)) + _left_out(result))
    return Header(title=f"dobkit analysis report: scenario '{scenario.name}'",
                  regenerate=regenerate_command(scenario.source, settings), full_command=None, preview=None)


def _left_out(result) -> list[str]:
    """What the quick preview does not compute at all (beyond its smaller settings), one phrase each."""
    digital = getattr(result, "digital", None)
    quantization = None if digital is None else digital.quantization
    if quantization is not None and quantization.simulated_rms is None:
        return ["the simulated torque noise from encoder quantization in section 8 (not simulated; the full "
                "report simulates the sampled loop with and without quantization): the linear model's "
                "prediction only"]
    return []


def build_view(result, experiment: dict, scenario, figure_files: dict,
               extra_sections: tuple[str, ...] = ()) -> ReportView:
    """Everything the report shows, computed from the results.

    Parameters
    ----------
    result : analysis.report.build.AnalysisResult
    experiment : dict
        The experiment's metrics (``with_dob``/``without_dob`` of
        :func:`blocks.figure2.metrics.tracking_metrics`); optionally
        ``duration_s``, per run ``time_of_max_abs_position_error``, and
        ``max_depth_below_skin_mm`` (see :func:`analysis.report.build.experiment_metrics`).
    scenario : Scenario
    figure_files : dict
        Figure stem -> PNG path; missing figures are left out.
    extra_sections : tuple of str
        Ready-made HTML sections appended at the end (for example a sweep summary).
    """
    sections = SECTIONS if is_paper_arm(scenario) else tuple(
        (key, "2. Simulation of the scenario (Figures 4-8, Table 3 layout)")
        if key == "simulation" else (key, title) for key, title in SECTIONS)
    contents = list(sections) + ([DIGITAL_SECTION] if result.digital is not None else []) \
        + ([("sweeps", "Sweep summaries")] if extra_sections else [])
    return ReportView(
        scenario_name=scenario.name, header=_header(result, scenario), dobkit_version=result.dobkit_version,
        python_control_version=result.python_control_version, contents=contents, headings=dict(contents),
        summary=plain_summary(result, experiment, scenario),
        scenario=scenario_section(scenario, result),
        simulation=simulation_section(result, experiment, scenario, figure_files),
        linear=linear_section(result, scenario, figure_files),
        bandwidth=bandwidth_section(result, figure_files, scenario),
        design=design_section(result, scenario, figure_files),
        frequency=frequency_section(result, scenario, figure_files),
        studies=studies_section(result, scenario, figure_files),
        digital=digital_section(result, figure_files, arm_of(scenario)),
        extra_sections=list(extra_sections),
        not_done_frequency=next((line for line in getattr(result, "not_done", ()) if line.startswith("frequency")),
                                ""))
