"""What the analyses of :mod:`analysis.report.build` compute and on which grids: :class:`AnalysisSettings`.

:data:`QUICK_SETTINGS` is the quick preview (``dobkit report --quick``); a
report made with it says so and lists how it differs from the full settings
(:func:`preview_differences`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

from analysis.linear.arm_terms import default_points
from analysis.linear.bandwidth import DEFAULT_POINTS

__all__ = ["AnalysisSettings", "QUICK_SETTINGS", "OBSERVER_STUDY_GAINS", "observer_study_gains", "preview_differences"]


@dataclass(frozen=True)
class AnalysisSettings:
    """What the analyses compute and on which grids.

    Attributes
    ----------
    observer_target_rad_s : float
        Target slowest observer mode of the gain design (rad/s), finite and > 0.
    speed_margin : float
        The certificate's joint-speed bound is this times the largest reference
        speed of the scenario per joint (rad/s, m/s), at least ``min_speed``.
    min_speed : n floats
        Floor of that bound per joint (rad/s, m/s); the default is the paper arm's, and
        :meth:`min_speed_for` gives an arm with another joint count 0.5 rad/s per
        revolute and 0.05 m/s per prismatic joint.
    mismatch_factors : floats
        Nominal/true inertia ratios of the pole sweep.
    boundary_range, boundary_points
        Range and scan size of the stability-boundary search.
    workspace_points : n ints
        Grid of the observer-bandwidth survey and the gain design (default
        :data:`analysis.linear.bandwidth.DEFAULT_POINTS`, the paper arm's; :meth:`workspace_points_for`
        gives another arm :func:`~analysis.linear.arm_terms.default_points` unless the counts fit its joints).
    kp_values, kd_values, observer_values : floats
        Grids of the gain studies (scalar gains, the same on every joint).
    study_t_final : float
        Length (s) of the studies' runs: the arm held at the path's start under a
        disturbance step (see :mod:`analysis.simulation.studies`).
    design_t_final : float or None
        Length (s) of the design check's runs on the scenario's path (None: the
        whole path).
    noise_t_final : float
        Length (s) of the runs that measure the torque noise.
    digital_rates_hz : floats
        Sample rates (Hz) of the digital-implementation study (scenarios with a
        ``[controller]`` section; the scenario's own rate is added).
    workers : int
        Processes for the studies (results do not depend on it).
    quick : bool
        A quick preview (``dobkit report --quick``, :data:`QUICK_SETTINGS`):
        the report says so in its title and lists what it leaves out.
    """

    observer_target_rad_s: float = 10.0
    speed_margin: float = 2.0
    min_speed: tuple = (0.5, 0.5, 0.05, 0.5)
    mismatch_factors: tuple = (0.5, 0.595, 0.707, 0.841, 1.0, 1.189, 1.414, 1.682, 2.0)
    boundary_range: tuple = (0.02, 50.0)
    boundary_points: int = 25
    workspace_points: tuple = DEFAULT_POINTS
    kp_values: tuple = (45.0, 90.0, 180.0, 360.0)
    kd_values: tuple = (9.0, 18.0, 36.0, 72.0)
    observer_values: tuple = (1.0, 3.0, 10.0, 30.0, 100.0)
    study_t_final: float = 10.0
    design_t_final: float | None = 6.0
    noise_t_final: float = 2.0
    digital_rates_hz: tuple = (100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0, 10000.0)
    workers: int = field(default=1, compare=False)
    quick: bool = False

    def __post_init__(self) -> None:
        t = self.observer_target_rad_s
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t <= 0:
            raise ValueError(f"observer target must be a finite number > 0 rad/s, got {t!r}")
        for name in ("study_t_final", "noise_t_final") + (("design_t_final",) if self.design_t_final is not None
                                                           else ()):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0 s, got {v!r}")

    def workspace_points_for(self, joints) -> tuple[int, ...]:
        """The grid's points per joint for an arm with these joints (:class:`blocks.model.joints.JointSpace`).

        The settings' own counts when there is one per joint; otherwise the arm's
        :func:`~analysis.linear.arm_terms.default_points`, or in a quick preview
        :data:`QUICK_POINTS_PER_JOINT` on every joint (3^7 = 2187 configurations for a 7-joint arm).
        """
        if len(self.workspace_points) == joints.count:
            return tuple(self.workspace_points)
        if self.quick:
            return (QUICK_POINTS_PER_JOINT,) * joints.count
        return default_points(joints)

    def min_speed_for(self, joints) -> tuple[float, ...]:
        """The certificate's speed floor per joint for an arm with these joints (rad/s, m/s)."""
        if len(self.min_speed) == joints.count:
            return tuple(self.min_speed)
        return tuple(_MIN_SPEED_BY_KIND[k] for k in joints.kinds)

    def as_dict(self) -> dict:
        """JSON-ready settings (without ``workers``, which does not change results)."""
        out = asdict(self)
        out.pop("workers")
        return out


#: Points per joint of a quick preview's workspace grid on an arm its own counts do not fit: the certificate checks
#: every grid point at each of the 2^n vertices of the speed box, so the grid must stay small for 6 or 7 joints.
QUICK_POINTS_PER_JOINT = 3

# Speed floor of the certificate by joint kind (rad/s, m/s), for arms other than the paper's.
_MIN_SPEED_BY_KIND = {"revolute": 0.5, "prismatic": 0.05}

# Small grids and short runs: the same analyses in well under a minute (previews).
QUICK_SETTINGS = AnalysisSettings(quick=True, mismatch_factors=(0.5, 1.0, 2.0), boundary_points=9,
                                  workspace_points=(3, 37, 2, 3), kp_values=(90.0, 180.0), kd_values=(18.0, 36.0),
                                  observer_values=(3.0, 30.0), study_t_final=6.0, design_t_final=2.0,
                                  noise_t_final=0.3, digital_rates_hz=(200.0, 1000.0, 5000.0))


def _values(values, unit: str = "") -> str:
    text = ", ".join(f"{v:g}" for v in values)
    return f"{text} {unit}".rstrip()


# How a person reads each setting that a preview may shrink: field -> (what it is, how to show a value).
_DESCRIBE = {
    "mismatch_factors": ("inertia-mismatch pole sweep", lambda v: f"{len(v)} factors ({_values(v)})"),
    "boundary_points": ("stability-boundary scan", lambda v: f"{v} points"),
    "workspace_points": ("workspace grid (points per joint)", lambda v: " x ".join(str(n) for n in v)),
    "kp_values": ("Kp of the gain study", lambda v: _values(v, "1/s^2")),
    "kd_values": ("Kd of the gain study", lambda v: _values(v, "1/s")),
    "observer_values": ("observer gains {form} of the observer study", lambda v: "v = " + _values(v)),
    "study_t_final": ("length of the study runs", lambda v: f"{v:g} s"),
    "design_t_final": ("length of the design check's runs",
                       lambda v: "the whole path" if v is None else f"{v:g} s"),
    "noise_t_final": ("length of the torque-noise runs", lambda v: f"{v:g} s"),
    "digital_rates_hz": ("sample rates of the digital-implementation study", lambda v: _values(v, "Hz")),
}


#: How the observer study makes its gains from the values ``v``: on the paper's arm, and on any other arm.
OBSERVER_STUDY_GAINS = {True: "Y = v I", False: "Y = v M^(q0)"}


def observer_study_gains(scenario) -> str:
    """How the observer study of ``scenario`` makes its gains from the values ``v`` (the words of
    :data:`OBSERVER_STUDY_GAINS`): ``Y = v I`` on the paper's arm
    (:func:`analysis.report.build.observer_gains`), ``Y = v M^(q0)`` with ``v`` in rad/s on any other arm
    (:func:`analysis.report.build.bandwidth_gains`), the rule :func:`analysis.report.build.run_analysis` follows."""
    paper = scenario.robot.paper is not None and scenario.nominal.paper is not None
    return OBSERVER_STUDY_GAINS[paper]


def preview_differences(settings: AnalysisSettings, full: AnalysisSettings | None = None,
                        joints=None, observer_gains: str = OBSERVER_STUDY_GAINS[True]) -> list[str]:
    """How ``settings`` differ from the full analysis, one phrase per setting: "what: this (full: that)".

    With ``joints`` (:class:`blocks.model.joints.JointSpace`) the workspace grid is the one used on that arm
    (:meth:`AnalysisSettings.workspace_points_for`); ``observer_gains`` says how the observer study makes its
    gains (:func:`observer_study_gains` of the scenario).

    Examples
    --------
    >>> preview_differences(QUICK_SETTINGS)[-2]
    'length of the torque-noise runs: 0.3 s (full: 2 s)'
    """
    full = AnalysisSettings(observer_target_rad_s=settings.observer_target_rad_s) if full is None else full
    out = []
    for f in fields(settings):
        if f.name not in _DESCRIBE:
            continue
        mine, theirs = getattr(settings, f.name), getattr(full, f.name)
        if f.name == "workspace_points" and joints is not None:
            mine, theirs = settings.workspace_points_for(joints), full.workspace_points_for(joints)
        if mine != theirs:
            what, show = _DESCRIBE[f.name]
            if f.name == "observer_values":
                what = what.format(form=observer_gains)
                unit = " rad/s" if "M^(q0)" in observer_gains else ""
                out.append(f"{what}: {show(mine)}{unit} (full: {show(theirs)}{unit})")
                continue
            out.append(f"{what}: {show(mine)} (full: {show(theirs)})")
    return out
