"""The analysis report as one self-contained HTML page, laid out by the Jinja2 templates of ``analysis/report/templates``.

The numbers and statements come from :func:`analysis.report.view.build_view`;
the templates (``report.html`` and the ``report_*.html`` it includes) only lay
them out.  Autoescaping is on for every ``.html`` template, so no text of a
result or a scenario (a name, a description) can add markup; the only
ready-made HTML a page takes is a sweep summary section (itself rendered
from a template with autoescaping).  Figures are embedded as base64 PNG: the
page fetches nothing.
"""
from __future__ import annotations

import functools

import jinja2

from analysis.report.view import build_view
from blocks.scenarios.scenario import Scenario

__all__ = ["render_html", "template_environment"]


@functools.cache
def template_environment() -> jinja2.Environment:
    """The Jinja2 environment of the package's templates (autoescaping for ``.html``, strict undefined names)."""
    return jinja2.Environment(loader=jinja2.PackageLoader("analysis.report", "templates"),
                              autoescape=jinja2.select_autoescape(enabled_extensions=("html",),
                                                                  default_for_string=True),
                              undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
                              keep_trailing_newline=True)


def render_html(result, experiment: dict, scenario: Scenario, figure_files: dict,
                extra_sections: tuple[str, ...] = ()) -> str:
    """The report as one HTML string (figures embedded from the PNG files named in ``figure_files``).

    Parameters
    ----------
    result : analysis.report.build.AnalysisResult
        From :func:`analysis.report.build.run_analysis`.
    experiment : dict
        The experiment's metrics (``with_dob``/``without_dob`` of
        :func:`blocks.figure2.metrics.tracking_metrics`); optionally
        ``duration_s`` and, per run, ``time_of_max_abs_position_error``.
    scenario : Scenario
    figure_files : dict
        Figure stem -> PNG path; missing figures are left out.
    extra_sections : tuple of str
        Ready-made HTML sections appended at the end (sweep summaries from
        :func:`analysis.sweep.summary.html_section`), included as they are.
    """
    view = build_view(result, experiment, scenario, figure_files, tuple(extra_sections))
    return template_environment().get_template("report.html").render(v=view)
