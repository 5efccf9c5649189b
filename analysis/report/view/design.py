"""Section 5 of the report: the designed observer gain, its convergence certificate and its check in simulation."""
from __future__ import annotations

from dataclasses import dataclass

from .text import (
    Figure,
    Table,
    and_words,
    arm_joints,
    figures,
    fmt,
    gain_units,
    is_paper_arm,
    join,
    kinds,
    span,
    units_list,
)

__all__ = ["DesignSection", "design_section"]


def _yes_no(value) -> str:
    return "n/a (no error at the start)" if value is None else ("yes" if value else "no")


@dataclass(frozen=True)
class DesignSection:
    """5. The designed observer gain, its certificate and its check in simulation."""

    target: str
    c_per_s: str
    base_is_scenario_gain: bool
    mode_ranges: str
    gain: Table
    certificate: Table
    simulation_setup: str | None
    simulation: Table
    figures: list[Figure]
    gain_units: str = "kg m^2/s, kg/s for joint 3"


def design_section(result, scenario, files: dict) -> DesignSection:
    joints = arm_joints(scenario)
    d = result.observer_design
    cd, cs = d.certificate_designed, d.certificate_scenario_gain
    crit_d, crit_s = d.critical_theta2_speed_designed, d.critical_theta2_speed_scenario_gain
    ranges = d.bandwidth_designed.ranges_rad_s
    # the critical speed runs along the bandwidth survey's slice joint (theta2 for the paper's arm)
    along = result.observer_bandwidth.slice_joint_name
    unit = joints.velocity_units[list(joints.names).index(along)] if along in joints.names else "rad/s"
    gain = Table.of([""] + [f"col {j + 1}" for j in range(len(d.Y))],
                    [[f"row {i + 1}"] + [fmt(v, 5) for v in row] for i, row in enumerate(d.Y)])
    certificate = Table.of(
        ["", "scenario gain", "designed gain"],
        [[f"speed bound ({units_list(joints.velocity_units)})", join(d.speed_bound, 3), join(d.speed_bound, 3)],
         ["certificate beta_min (rad/s)", fmt(cs.beta_min_rad_s, 5), fmt(cd.beta_min_rad_s, 5)],
         ["  reached at q", join(cs.q_at, 4), join(cd.q_at, 4)],
         ["  and q'", join(cs.dq_at, 3), join(cd.dq_at, 3)],
         ["condition holds", "yes" if cs.holds else "no", "yes" if cd.holds else "no"],
         ["beta at rest, min (rad/s)", fmt(cs.beta_at_rest_min_rad_s, 5), fmt(cd.beta_at_rest_min_rad_s, 5)],
         [f"largest |{along}'| keeping beta > 0 ({unit})",
          "unlimited" if crit_s.unlimited else fmt(crit_s.speed_factor, 5),
          "unlimited" if crit_d.unlimited else fmt(crit_d.speed_factor, 5)]],
        "Convergence certificate")
    sims = d.simulation
    first = next(iter(sims.values()), None)
    setup = None
    if first is not None:
        own = kinds(scenario.data["disturbance"]["kind"])
        used = kinds(first.disturbance_kind)
        if used == own:
            what = f"the scenario's disturbance ({and_words(used) if used else 'none'})"
        else:
            what = (f"the constant step f_r = [{join(first.f_r, 4)}] ({units_list(joints.force_units)}; the paper's Eq. 4) in "
                    f"place of the scenario's disturbance models ({and_words(own) if own else 'none'})"
                    if used == ["paper"] else f"the disturbance {and_words(used) if used else 'none'}")
        setup = (f"Nonlinear simulation of the scenario's path (first {fmt(first.time[-1], 4)} s, noise removed) "
                 f"with {what}: time to get within {fmt(100 * first.threshold, 2)}% of the largest disturbance, "
                 "and whether V(t) stays below the certified decay over the states the run visited.")
    rows = [[label, fmt(run.beta_run_rad_s, 4),
             f"not within the {fmt(run.time[-1], 3)} s run" if run.convergence_time_s is None
             else fmt(run.convergence_time_s, 4),
             join(run.rms_disturbance_error, 3), _yes_no(run.bound_holds)]
            for label, run in sims.items()]
    return DesignSection(
        target=fmt(d.target_rad_s), c_per_s=fmt(d.c_per_s, 6), base_is_scenario_gain=d.base_is_scenario_gain,
        mode_ranges=", ".join(span(lo, hi, 4) for lo, hi in ranges), gain=gain,
        certificate=certificate, simulation_setup=setup,
        simulation=Table.of(["gain", "beta over the visited states (rad/s)", "time to 2% (s)",
                             f"RMS d - d_hat ({units_list(joints.force_units)})", "V(t) <= V(0) exp(-2 beta t)"], rows,
                            "Nonlinear simulation with each gain"),
        figures=figures(files, ("observer_design", "Estimation error and Lyapunov certificate in simulation")),
        gain_units="kg m^2/s, kg/s for joint 3" if is_paper_arm(scenario) else gain_units(joints))

