"""The pieces every section of the report is made of: numbers as text, tables, figures, and words for numbers.

Nothing here knows a section; each section module
(:mod:`analysis.report.view.simulation`, ...) builds its part of the page
from these.
"""
from __future__ import annotations

import base64
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blocks.model.joints import JointSpace
from blocks.scenarios.scenario import default_arm

__all__ = ["fmt", "join", "span", "settling", "pole", "Cell", "Table", "Figure", "Paragraph", "figures",
           "joints_text", "mode_text", "value", "kinds", "and_words", "split_caveats", "stable_ranges",
           "stability_text", "gain_text", "matrix_rows", "per_joint", "column", "MODE_SHARE",
           "ZERO_REL", "is_paper_arm", "units_list", "mixed_units", "gain_units", "arm_joints", "arm_of"]

#: How the report names the joints in tables and captions (the same names as the figures).
# A component of a unit mode direction at least this large counts as "the mode moves this joint".
MODE_SHARE = 0.1
# Relative size below which a computed DC gain or offset is called zero.
ZERO_REL = 1e-6


# ---------------------------------------------------------------------------------------------------------------
# Numbers


def fmt(value, digits: int = 4) -> str:
    """A number for the report (significant digits), '-' for None, 'inf' for infinity, 'nan' for NaN.

    Examples
    --------
    >>> fmt(0.000123456), fmt(None), fmt(float("inf")), fmt(0)
    ('0.0001235', '-', 'inf', '0')
    """
    if value is None:
        return "-"
    value = float(value)
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if value == 0:
        return "0"
    return f"{value:.{digits}g}"


def column(values, digits: int = 4) -> list[str]:
    """Numbers of one table column in one notation: scientific for all when :func:`fmt` would write any of them
    so, else :func:`fmt`'s fixed notation (None, NaN and infinity as :func:`fmt` writes them).

    Examples
    --------
    >>> column([0.0001613, 6.32e-05])
    ['1.613e-04', '6.320e-05']
    >>> column([0.339, 0.25, None])
    ['0.339', '0.25', '-']
    """
    finite = [v is not None and math.isfinite(float(v)) for v in values]
    texts = [fmt(v, digits) for v in values]
    if not any(ok and "e" in text for ok, text in zip(finite, texts)):
        return texts
    return [f"{float(v):.{digits - 1}e}" if ok else text for v, ok, text in zip(values, finite, texts)]


def join(values, digits: int = 4) -> str:
    """Numbers as a comma-separated list (see :func:`fmt`)."""
    return ", ".join(fmt(v, digits) for v in values)


def span(lo, hi, digits: int = 3) -> str:
    """'a to b', or 'a' when both print the same."""
    a, b = fmt(lo, digits), fmt(hi, digits)
    return a if a == b else f"{a} to {b}"


def settling(value, digits: int = 3) -> str:
    return "not settled" if value is None else fmt(value, digits)


def pole(p: complex) -> str:
    if abs(p.imag) < 1e-9 * max(1.0, abs(p.real)):
        return fmt(p.real, 6)
    return f"{fmt(p.real, 6)} {'+' if p.imag > 0 else '-'} {fmt(abs(p.imag), 6)}j"


def per_joint(values, digits: int = 4) -> str:
    """One value per joint: '180 (every joint)' when they are equal, else 'a, b, c, d (joints 1-4)' (n joints)."""
    values = [float(v) for v in values]
    if all(v == values[0] for v in values):
        return f"{fmt(values[0], digits)} (every joint)"
    return f"{join(values, digits)} (joints 1-{len(values)})"


def matrix_rows(M, digits: int = 4) -> str:
    """A matrix as rows a person reads: '[a, b, c, d]; [e, f, g, h]; ...'."""
    return "; ".join("[" + join(row, digits) + "]" for row in np.asarray(M, dtype=float))


def gain_text(Y, digits: int = 4) -> str:
    """An observer gain for people: '10 I', 'diag(1, 2, 3, 4)' or its rows.

    Examples
    --------
    >>> gain_text(10.0 * np.eye(4)), gain_text(np.diag([1.0, 2, 3, 4]))
    ('10 I', 'diag(1, 2, 3, 4)')
    """
    Y = np.asarray(Y, dtype=float)
    if np.array_equal(Y, np.diag(np.diag(Y))):
        d = np.diag(Y)
        return f"{fmt(d[0], digits)} I" if np.all(d == d[0]) else f"diag({join(d, digits)})"
    return matrix_rows(Y, digits)


def _is_number(text: str) -> bool:
    """Whether a table cell holds a number (right-aligned in the page)."""
    try:
        float(text.replace(" ", "").split(",")[0].replace("+", "").rstrip("j") or "x")
        return True
    except ValueError:
        return text in ("-", "inf", "not settled")


# ---------------------------------------------------------------------------------------------------------------
# The pieces a page is made of


@dataclass(frozen=True)
class Cell:
    """One table cell: its text and whether it is a number."""

    text: str
    numeric: bool


@dataclass(frozen=True)
class Table:
    """A table: header texts, rows of cells, an optional caption."""

    header: list[str]
    rows: list[list[Cell]]
    caption: str | None = None

    @classmethod
    def of(cls, header, rows, caption: str | None = None) -> Table:
        """A table from header and row texts; number cells are recognized."""
        return cls([str(h) for h in header], [[Cell(str(c), _is_number(str(c))) for c in row] for row in rows],
                   caption)


@dataclass(frozen=True)
class Figure:
    """An embedded PNG figure: caption (also its alt text) and ``data:`` URI."""

    caption: str
    data_uri: str


@dataclass(frozen=True)
class Paragraph:
    """A paragraph of plain text, optionally led by a bold word."""

    text: str
    lead: str | None = None


def figures(files: dict, *items: tuple[str, str]) -> list[Figure]:
    """The figures among ``(stem, caption)`` items that were written (``files``: stem -> PNG path), in order."""
    return [Figure(caption, "data:image/png;base64," + base64.b64encode(Path(files[stem]).read_bytes()).decode("ascii"))
            for stem, caption in items if stem in files]


# ---------------------------------------------------------------------------------------------------------------
# Words for numbers


def joints_text(indices) -> str:
    """'joint 3', 'joints 1 and 2', 'joints 1, 2 and 4' (0-based indices in)."""
    names = [str(i + 1) for i in indices]
    if len(names) == 1:
        return f"joint {names[0]}"
    return f"joints {', '.join(names[:-1])} and {names[-1]}"


def mode_text(direction) -> str:
    """What a unit mode direction (disturbance space) moves: 'joint 3 alone' or 'joints 1, 2 and 4 together'."""
    v = np.abs(np.asarray(direction, dtype=float))
    idx = [i for i in range(len(v)) if v[i] >= MODE_SHARE]
    return f"{joints_text(idx)} alone" if len(idx) == 1 else f"{joints_text(idx)} together"


def value(x, j: int, joints: JointSpace, digits: int = 3) -> str:
    """A position of joint ``j`` of ``joints`` with its unit."""
    return f"{fmt(x, digits)} {joints.position_units[j]}"


def arm_of(scenario):
    """A scenario's true arm (:class:`blocks.model.arm.ArmModel`; the default scenario's when it has none)."""
    arm = getattr(scenario, "robot", None)
    return arm if isinstance(getattr(arm, "joints", None), JointSpace) else default_arm()


def arm_joints(scenario) -> JointSpace:
    """The joints of a scenario's arm (the default scenario's when it has none)."""
    return arm_of(scenario).joints


def units_list(units) -> str:
    """One unit per joint, as a list: ``rad, rad, m, rad``."""
    return ", ".join(units)


def mixed_units(units, word: str = "joint") -> str:
    """The units of a per-joint quantity in few words: the most common one, then the others by joint.

    Examples
    --------
    >>> mixed_units(("N m", "N m", "N", "N m")), mixed_units(("N m",) * 6)
    ('N m; N on joint 3', 'N m')
    """
    units = tuple(units)
    common = max(dict.fromkeys(units), key=units.count)
    rest = []
    for unit in dict.fromkeys(u for u in units if u != common):
        idx = [j + 1 for j, u in enumerate(units) if u == unit]
        rest.append(f"{unit} on {word}{'s' if len(idx) > 1 else ''} " + and_words([str(j) for j in idx]))
    return "; ".join([common] + rest)


def gain_units(joints: JointSpace) -> str:
    """Units of the observer gain Y (inertia per second): ``kg m^2/s; kg/s on joint 3`` for the paper's arm."""
    return mixed_units(["kg m^2/s" if k == "revolute" else "kg/s" for k in joints.kinds])


def is_paper_arm(scenario) -> bool:
    """Whether a scenario's arm is the paper's (:attr:`blocks.model.arm.ArmModel.paper`: the report's comparisons with the
    paper apply)."""
    return getattr(scenario.robot, "paper", None) is not None


def kinds(kind) -> list[str]:
    """The disturbance kinds of a scenario's data as a list (empty for "none")."""
    if kind == "none":
        return []
    return [kind] if isinstance(kind, str) else list(kind)


def and_words(words) -> str:
    """'a', 'a and b', 'a, b and c'."""
    words = list(words)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


STATE_DEPENDENT = {"friction": "friction depends on the joint velocities",
                   "tissue": "the tissue force depends on the tool's position and velocity"}


def split_caveats(result, scenario, observer: bool) -> list[str]:
    """Why the perfect-model analytic forms (pole split, closed-form responses) may not hold for this scenario."""
    reasons = []
    if scenario.nominal != scenario.robot:
        reasons.append("the nominal model differs from the true one")
    reasons += [STATE_DEPENDENT[k] for k in kinds(scenario.data["disturbance"]["kind"]) if k in STATE_DEPENDENT]
    op = result.operating_points[0]
    if not observer and np.max(np.abs(np.subtract(op.q_equilibrium_without_dob, op.q0))) > 0:
        reasons.append("the arm rests off q0 (by M^-1 d / Kp), where M(q) differs")
    return reasons


def stable_ranges(boundaries) -> list[tuple[float, float]]:
    """The intervals of the inertia factor ``a`` over which a boundary search found the loop stable."""
    lo, hi = boundaries.range
    edges = [lo] + list(boundaries.factors) + [hi]
    stable, out = boundaries.stable_at_low_end, []
    for a, b in zip(edges[:-1], edges[1:]):
        if stable:
            out.append((a, b))
        stable = not stable
    return out


def stability_text(boundaries, subject: str, perfect_model: bool = True, prefix: str = "Model error: ") -> str:
    """A sentence on where a loop is stable over the inertia factors searched, from a boundary search result.

    Parameters
    ----------
    boundaries : analysis.linear.loop.BoundarySearch
    subject : str
        What the sentence is about, e.g. "with the observer the held loop".
    perfect_model : bool
        Whether the scenario's nominal model is the true one (then the factor
        ``a`` is nominal/true inertia; otherwise it scales the scenario's nominal inertia).
    """
    lo, hi = boundaries.range
    found = boundaries.factors
    first_stable = boundaries.stable_at_low_end
    ref = "the true one" if perfect_model else "the scenario's nominal inertia, which itself differs from the true one"
    if not found:
        state = "stays stable" if first_stable else "is unstable"
        return (f"{prefix}{subject} {state} for every nominal inertia from {fmt(lo)} to {fmt(hi)} times {ref}: no "
                "stability boundary in the range searched.")
    edges = [lo] + found + [hi]
    stable, parts = first_stable, []
    for a, b in zip(edges[:-1], edges[1:]):
        parts.append(f"{'stable' if stable else 'unstable'} for a nominal inertia from {fmt(a, 4)} to {fmt(b, 4)}")
        stable = not stable
    return (f"{prefix}{subject} is " + ", ".join(parts) + f" times {ref}; it changes stability at a = "
            + ", ".join(fmt(a, 6) for a in found) + f" (searched {fmt(lo)} to {fmt(hi)}).")
