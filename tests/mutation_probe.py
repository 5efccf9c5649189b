# ruff: noqa: E501 -- the mutant table keeps each snippet on one line, as it is in the file
"""A mutation probe of dobkit's core maths and rules: which wrong changes does the test suite let through?

Each mutant is one small wrong change to one product file (a sign, a factor, a transposed matrix, an
off-by-one, ``<`` for ``<=``, a dropped term, a swapped argument, a wrong unit): an exact original snippet,
which must occur once in the file, and its replacement.  For each mutant the probe writes the change, runs
the tests named for it (``python -m pytest -x -q -n 0``), records whether any test failed (the mutant is
*killed*) or all passed (it *survived*), and puts the file back byte for byte -- also on Ctrl-C or SIGTERM.

Run it from the repository's top level::

    python tests/mutation_probe.py                 # every mutant, the tests named with it
    python tests/mutation_probe.py --killers       # and the killer tests (KILLED_BY) after those
    python tests/mutation_probe.py --only arm-m01-half chain-rnea-gravity-sign
    python tests/mutation_probe.py --group dynamics --json /tmp/probe.json
    python tests/mutation_probe.py --list          # the mutants, no runs

A mutant judged *equivalent* (no test can tell it from the original, or only on a measure-zero set the
product does not promise) carries the reason in ``equivalent``; it is still run and reported.

Measured on 2026-12-02 (107 mutants over the RRPR's M, N, G, kinematics and IK, the control and observer
laws, the disturbance models, the URDF chain kernels and their traced calls, the IK derivatives, the
divergence rule, the monitor, the run limits and step rates, the sampled-loop stability, the budgets, the
linearization and bandwidth, the metrics, the end stops and the FMU's C plant): the targeted tests killed
85; 22 survived, of which 2 are equivalent (``dist-tissue-inside``, ``ds-bisect-mean``: see their
``equivalent``); the first pass's killer tests (``KILLED_BY``) kill the other 20.  ``--killers`` must therefore
report 105 killed and those 2 equivalent.

Second pass, measured on 2026-12-02: 91 more mutants where the first did not go.  Per group: mutants, killed
by the targeted tests, survivors, killed by the second pass's killer tests (no survivor was judged
equivalent):

=============== ======= ====== ========= ============ =====================================================
group           mutants killed survivors killed after survivors
=============== ======= ====== ========= ============ =====================================================
fmu_c2            15       3      12         12        instance (new input keeps its slope, h = 0, step from
                                                       another time), saved states (switch of 2, no magic,
                                                       buffer size), controller core (step 10 % off Ts, time
                                                       in ticks, stopTime past the table), FMI 2/3 status
                                                       and last successful time
fmu_py            10       9       1          1        sv-float32-max
digital            9       9       0          0
compiled          17      12       5          5        dp-max-factor, dp-rejected-cap, dp-h1-order,
                                                       dp-err-scale (step control only), tr-fold-minus
noise              3       3       0          0
task_path         10       9       1          1        tp-dds-T (the tests' segments were 1 s long)
resolved_rate      7       6       1          1        rr-dv-feedback (zero on the path)
sweep_tune        12       6       6          6        su-std-ddof, su-p95, su-ranks-ties, su-worst-order,
                                                       ev-damping-max, ev-energy-total
report_numbers     8       6       2          2        fr-lowpass-edge, gd-return-lo (1e-10 below target)
total             91      63      28         28
=============== ======= ====== ========= ============ =====================================================

The FMU's C mutants reach the tests because nothing caches a built FMU: every test session exports the plant
and controller FMUs afresh from ``fmu/c`` (module fixtures in a session folder; ``fmu.build`` compiles every
time and keeps no objects), so a mutant is compiled in -- the C mutants the targeted tests kill show it.  A
mutant of ``blocks/engines/compiled/dopri.py`` changes the compiled loops' cache key (the key hashes that file's text),
so numba compiles it instead of loading the cached original; the killer tests of the stepper run the file's
text as plain Python beside scipy's RK45, no cache involved.  With both passes ``--killers`` must report 196
killed and the first pass's 2 equivalents.
The killer tests live with the tests of their subjects (``KILLED_BY`` names each one and the mutants it
kills); some sit in files a mutant's targeted list names, so a run without ``--killers`` now kills a few of
the survivors counted above.

The table printed at the end has one row per mutant: its id, the file, whether it was killed, by which
test (the first failure) and the time the run took.  Set ``DOBKIT_CACHE_DIR`` to a folder of the probe's
own: a mutant of a kernel changes the generated code, so the numba cache key changes with it, but the
probe should not fill another worker's cache.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The tests written for the mutants the targeted tests let through, each beside the tests of its subject, with the
# mutants it kills (its docstring names them too).  ``--killers`` runs them after a mutant's targeted tests.
KILLED_BY = {
    "tests/test_kinematics.py::test_tool_velocity_is_the_time_derivative_of_the_pose": ("kin-vel-row3",),
    "tests/test_kinematics.py::test_the_inner_reach_is_the_links_difference_whichever_is_longer": ("kinpy-reach-abs",),
    "tests/test_kinematics.py::test_ik_with_no_singularity_margin_accepts_the_folded_and_the_stretched_arm": ("kinpy-ik-margin-le",),
    "tests/test_divergence.py::test_a_bound_holds_the_magnitude_inclusive_on_both_sides": ("div-violated-lt", "div-violated-abs"),
    "tests/test_divergence.py::test_runaway_is_growth_beyond_the_factor_in_consecutive_steps": ("div-runaway-factor", "div-runaway-reset"),
    "tests/test_budget_limits.py::test_the_step_budget_allows_the_evaluations_scipy_makes_in_that_many_steps": ("mon-evals-factor", "mon-counted-ge"),
    "tests/test_budget_limits.py::test_an_estimate_of_exactly_the_budget_fits_and_one_more_does_not": ("bu-check-ge",),
    "tests/test_budget_limits.py::test_the_step_estimate_bounds_the_steps_the_schedule_takes": ("bu-schedule-breaks",),
    "tests/test_budget_limits.py::test_jobs_sharing_a_budget_each_get_their_part_of_the_memory": ("bu-share",),
    "tests/test_metrics.py::test_the_disturbance_error_is_against_the_lumped_disturbance_when_the_run_has_it": ("me-d-source",),
    "tests/test_fmu_end_stops.py::test_the_stops_are_set_from_the_smallest_effective_inertia_over_the_poses": ("es-inertia-min",),
    "tests/test_fmu_end_stops.py::test_a_joint_bounded_on_one_side_gets_a_stop_on_that_side": ("es-bounded-and",),
    "tests/test_arm_paths.py::test_the_ik_singularity_margin_is_on_the_smallest_singular_value": ("ik-sigma-largest",),
    "tests/test_sampled_stability.py::test_the_sampled_map_of_each_observer_variant_and_its_stable_limit": ("ds-variant-swap", "ds-eq16-sign", "ds-return-hi"),
    "tests/test_divergence.py::test_the_bounds_of_a_held_arm_are_the_rules_numbers_by_hand": ("div-pos-abs", "div-force-no-external"),
    "tests/test_run_limits.py::test_the_step_rate_takes_the_largest_mismatch_of_a_nominal_model_given_in_python": ("rl-mismatch-min",),
    "tests/test_run_limits.py::test_the_step_estimate_of_a_stiff_loop_is_scipys_step_count_on_its_fastest_mode": ("rl-span-times",),
    "tests/test_run_limits.py::test_the_observer_rate_bounds_the_slides_fastest_mode_when_the_true_arm_is_lighter": ("sched-obs-nominal-only",),
    "tests/test_fmu_plant_instance.py::test_a_new_input_value_without_a_slope_is_held_over_the_step": ("c-set-input-keeps-slope",),
    "tests/test_fmu_plant_instance.py::test_do_step_refuses_a_zero_step_and_a_step_from_another_time": ("c-dostep-zero-h", "c-dostep-time-check"),
    "tests/test_fmu_plant_instance.py::test_a_serialized_state_with_a_switch_of_two_or_without_its_magic_is_refused": ("c-restore-switch-check", "c-state-magic"),
    "tests/test_fmu_plant_instance.py::test_serializing_into_a_buffer_of_another_size_is_refused": ("c-state-size-lt",),
    "tests/test_fmu_plant_instance.py::test_fmi2_status_reports_the_last_successful_time_and_a_failed_step": ("c-fmi2-last-time", "c-fmi2-status"),
    "tests/test_fmu_plant_instance.py::test_fmi3_do_step_returns_the_time_it_reached": ("c-fmi3-last-time",),
    "tests/test_controller_fmu_core.py::test_the_controller_runs_only_at_its_sample_period_and_its_time_is_in_seconds": ("c-ctrl-step-period", "c-ctrl-time"),
    "tests/test_controller_fmu_core.py::test_a_stop_time_past_the_reference_table_is_refused": ("c-ctrl-stop-time",),
    "tests/test_fmu_start_values.py::test_the_largest_float32_is_a_float32_start_value_and_the_next_double_is_not": ("sv-float32-max",),
    "tests/test_dormand_prince_steps.py::test_dormand_prince_steps_are_scipys_rk45_steps": ("dp-a31", "dp-c4", "dp-b4-sign", "dp-e-typo", "dp-p-sign", "dp-safety", "dp-max-factor", "dp-rejected-cap", "dp-dense-p3", "dp-h0-factor", "dp-h1-order", "dp-err-scale", "dp-rms-n"),
    "tests/test_dormand_prince_steps.py::test_the_first_step_is_scipys_initial_step": ("dp-h1-order", "dp-h0-factor"),
    "tests/test_arm_paths.py::test_the_tool_paths_velocity_and_acceleration_are_the_derivatives_of_its_position": ("tp-dds-T",),
    "tests/test_sweep_summary.py::test_sweep_statistics_worst_runs_and_influence_are_the_textbook_ones": ("su-std-ddof", "su-p95", "su-ranks-ties", "su-mean-scale", "su-worst-order"),
    "tests/test_arm_paths.py::test_the_resolved_rate_acceleration_is_the_derivative_of_the_rate_along_the_motion_off_the_path": ("rr-dv-feedback",),
    "tests/test_tune_constraints.py::test_the_damping_margin_is_that_of_the_least_damped_joint": ("ev-damping-max",),
    "tests/test_tune_constraints.py::test_the_tune_score_of_an_infeasible_candidate_is_worse_than_every_feasible_one": ("ev-energy-total",),
    "tests/test_urdf_trace.py::test_constant_folding_in_a_trace_is_the_arithmetic": ("tr-fold-minus",),
    "tests/test_analysis_observer.py::test_the_designed_gain_meets_its_target_on_its_own_grid": ("gd-return-lo",),
    "tests/test_analysis_frequency.py::test_a_low_pass_band_ends_at_its_first_crossing_of_the_level": ("fr-lowpass-edge",),
}
KILLERS = tuple(KILLED_BY)
TIMEOUT = 900          # s per mutant; a run past it counts as killed (a hang is a failure), and says so


@dataclass(frozen=True)
class Mutant:
    """One wrong change: ``old`` (exactly once in ``file``) becomes ``new``; ``tests`` are pytest arguments."""

    id: str
    group: str
    file: str
    old: str
    new: str
    tests: tuple
    what: str
    equivalent: str = ""          # why no test can kill it, when that is the verdict


@dataclass
class Outcome:
    id: str
    group: str
    file: str
    what: str
    killed: bool
    by: str
    seconds: float
    equivalent: str = ""
    killers_run: bool = False
    timed_out: bool = False
    tail: list = field(default_factory=list)


# --------------------------------------------------------------------------------------------------------------
# Tests per target (targeted: the module's own tests and the independent references that cover it)
# --------------------------------------------------------------------------------------------------------------
DYN = ("tests/test_dynamics.py", "tests/test_arm_model.py", "tests/test_one_source.py")
KIN = ("tests/test_kinematics.py", "tests/test_dynamics.py", "tests/test_arm_model.py", "tests/test_metrics.py")
LAWS = ("tests/test_one_source.py", "tests/test_loop.py::test_lumped_disturbance_is_what_the_nominal_model_leaves_unexplained",
        "tests/test_loop.py::test_pd_error_dynamics_are_s_plus_6_times_s_plus_30",
        "tests/test_loop.py::test_observer_removes_constant_disturbance",
        "tests/test_loop.py::test_observer_error_decays_as_exp_of_minus_Y_M_inv_t",
        "tests/test_loop.py::test_paper_eq16_leaves_velocity_bias_M_qdot",
        "tests/test_loop.py::test_model_mismatch_steady_error_and_observer",
        "tests/test_arm_loop.py::test_bound_law_is_a_copy_for_another_arm_and_the_original_for_the_rrpr")
DIST = ("tests/test_dynamics.py", "tests/test_tissue_any_arm.py::test_rrpr_numbers_are_the_closed_form_bit_for_bit",
        "tests/test_tissue_any_arm.py::test_tissue_force_of_a_urdf_arm_agrees_with_pinocchio",
        "tests/test_tissue_any_arm.py::test_drag_and_damping_do_no_positive_work", "tests/test_one_source.py")
CHAIN = ("tests/test_urdf_model.py", "tests/test_urdf_ik.py",
         "tests/test_tissue_any_arm.py::test_tissue_force_of_a_urdf_arm_agrees_with_pinocchio",
         "tests/test_compiled_row_kernels.py::test_compiled_kernels_agree_with_pinocchio")
IK = ("tests/test_urdf_ik.py", "tests/test_arm_model.py")
TRACE = ("tests/test_arm_calls.py", "tests/test_urdf_trace.py", "tests/test_compiled_row_kernels.py")
MONITOR = ("tests/test_one_monitor.py",)
DIVERGENCE = ("tests/test_one_monitor.py", "tests/test_compiled_row_kernels.py::test_force_bound_equals_the_numpy_way_and_pinocchio")
RUNAWAY = ("tests/test_cosim_misbehaving_fmus.py", "tests/test_one_monitor.py")
RUN_LIMITS = ("tests/test_one_monitor.py::test_runs_beyond_the_budget_are_refused_before_they_start_naming_the_key",
              "tests/test_compiled_row_kernels.py::test_rates_equal_the_numpy_way_and_pinocchio",
              "tests/test_sweep_limits.py", "tests/test_one_monitor.py")
SCHEDULE = ("tests/test_batch.py", "tests/test_sweep_limits.py",
            "tests/test_one_monitor.py::test_runs_beyond_the_budget_are_refused_before_they_start_naming_the_key")
DSTAB = ("tests/test_sampled_stability.py", "-k", "not nonlinear and not just_inside and not dobkit_simulate",
         "tests/test_digital_gravity.py", "tests/test_analysis_n_joints.py::test_euler_limit_is_ts_lambda_max_two")
BUDGET = ("tests/test_budget.py",)
LINEAR = ("tests/test_analysis_linear.py", "tests/test_analysis_nominal_model.py", "tests/test_analysis_observer.py",
          "tests/test_analysis_n_joints.py")
METRICS = ("tests/test_metrics.py", "tests/test_derived_signals.py")
FMU_C = ("tests/test_one_source.py::test_the_c_plant_matches_the_reference", "tests/test_fmu_end_stops.py",
         "tests/test_fmu_export.py::test_co_simulation_follows_the_input_slope_and_gives_exact_output_derivatives")
END_STOPS = ("tests/test_fmu_end_stops.py",)


def M(id, group, file, old, new, tests, what, equivalent=""):      # noqa: N802 -- a table row, read as such
    return Mutant(id, group, file, old, new, tuple(tests), what, equivalent)


ARM, DYNPY, KK, KINPY = ("blocks/model/rrpr/dynamics_kernels.py", "blocks/model/rrpr/dynamics.py",
                         "blocks/model/rrpr/tool_kernels.py", "blocks/model/rrpr/kinematics.py")
LAW, DK, CH, IKF = "blocks/kernels/laws.py", "blocks/kernels/disturbance.py", "blocks/kernels/chain.py", "blocks/model/urdf/ik.py"
RR_FILE = "blocks/model/urdf/resolved_rate.py"      # J' by polarisation lives beside the law that uses it
DIV, MON, RL, DS = "blocks/engines/divergence.py", "blocks/engines/monitor.py", "blocks/figure2/run_limits.py", "blocks/figure2/digital_stability.py"
BOUNDS = "blocks/figure2/physical_bounds.py"          # the scenario's physical bounds the divergence rule is given
SPLINES = "blocks/kernels/splines.py"        # the paths' polynomial pieces
BU, ME, ES, PC = "blocks/engines/budget.py", "blocks/figure2/metrics.py", "fmu/end_stops.py", "fmu/c/plant_model.c"
AL, BW = "analysis/linear/arm_linear.py", "analysis/linear/bandwidth.py"
SC = "blocks/figure2/batch/schedule.py"

MUTANTS = [
    # ---- RRPR dynamics: M, N, G (Eq. 5-7) -------------------------------------------------------------------
    M("arm-m01-half", "dynamics", ARM, "k[2] + 0.5 * k2c2, k[2]", "k[2] + 1.0 * k2c2, k[2]", DYN,
      "m01 = k3 + k2 c2 (factor 2: the 1/2 dropped)"),
    M("arm-M-coupling-sign", "dynamics", ARM, "M[..., 3, 1] = -m33", "M[..., 3, 1] = m33", DYN,
      "inertia_matrix: the -k5 couplings get + (paper's printed last row)"),
    M("arm-mtimes-row3", "dynamics", ARM, "coupling - m33 * (v[0] + v[1])", "coupling - m33 * (v[0] - v[1])", DYN,
      "mass_times row 3: v0 - v1"),
    M("arm-msolve-x3", "dynamics", ARM, "out[3] = out[0] + out[1] + r[3] / m33", "out[3] = out[0] + out[1] - r[3] / m33",
      DYN, "mass_solve: x3 sign of r3 / m33"),
    M("arm-coriolis-half", "dynamics", ARM, "-h * dq[1] * (dq[0] + 0.5 * dq[1])", "-h * dq[1] * (dq[0] + dq[1])", DYN,
      "N q' row 0: the 1/2 on q2'^2 dropped"),
    M("arm-coriolis-row1", "dynamics", ARM, "out[1] = 0.5 * h * dq[0] * dq[0]", "out[1] = 0.5 * h * dq[0] * dq[1]", DYN,
      "N q' row 1: q1' q2' for q1'^2"),
    M("arm-bias-gravity-sign", "dynamics", ARM, "out = coriolis_forces(k, q, dq)\n    out[2] = out[2] - k[3] * k[5]",
      "out = coriolis_forces(k, q, dq)\n    out[2] = out[2] + k[3] * k[5]", DYN, "h: G with the wrong sign (d3 up)"),
    M("arm-plant-acc-sign", "dynamics", ARM, "mass_solve(k, q, force - bias_forces(k, q, dq))",
      "mass_solve(k, q, force + bias_forces(k, q, dq))", DYN, "q'' = M^-1 (force + h)"),
    M("dyn-dM-half", "dynamics", DYNPY, "dM[..., 0, 1] = dM[..., 1, 0] = -0.5 * k2s2", "dM[..., 0, 1] = dM[..., 1, 0] = -k2s2",
      DYN + ("tests/test_analysis_observer.py", "tests/test_analysis_n_joints.py"), "dM/dtheta2: off-diagonal without 1/2"),
    M("dyn-C00", "dynamics", DYNPY, "C[..., 0, 0] = -h * dq[..., 1]", "C[..., 0, 0] = -h * dq[..., 0]", DYN,
      "Christoffel C00 with q1' for q2'"),
    M("dyn-invdyn-swap", "dynamics", DYNPY, "kern.bias_forces(k, _rows(q), _rows(dq))\n    return _joint_last(rows)",
      "kern.bias_forces(k, _rows(q), _rows(ddq))\n    return _joint_last(rows)", DYN, "inverse_dynamics: h at q'' for q'"),
    # ---- RRPR kinematics (Eq. 8 corrected) -------------------------------------------------------------------
    M("kin-z-sign", "kinematics", KK, "out[2] = kin[2] - q[2] - kin[3]", "out[2] = kin[2] + q[2] - kin[3]", KIN,
      "z = d1 + d3 - d4"),
    M("kin-phi-sign", "kinematics", KK, "out[3] = t12 - q[3]", "out[3] = t12 + q[3]", KIN, "phi = t1 + t2 + t4"),
    M("kin-J01-printed", "kinematics", KK, "- a2s12, -a2s12, kin[0]", "- a2s12, -a2c12, kin[0]", KIN,
      "J01 = -l2 cos (the paper's misprint)"),
    M("kin-vel-row3", "kinematics", KK, "out[3] = dq[0] + dq[1] - dq[3]", "out[3] = dq[0] + dq[1] + dq[3]", KIN,
      "tool_velocity: phi' with + theta4'"),
    M("kin-accbias-w12", "kinematics", KK, "(dq[0] + dq[1]) * (dq[0] + dq[1])", "(dq[0] + dq[1]) * dq[1]", KIN,
      "J' q': (q1' + q2') q2' for (q1' + q2')^2"),
    M("kinpy-J33", "kinematics", KINPY, "J[..., 3, 3] = -1.0", "J[..., 3, 3] = 1.0", KIN, "jacobian: last row [1,1,0,1]"),
    M("kinpy-Jdot-w12", "kinematics", KINPY, "w12 = dq[..., 0], dq[..., 0] + dq[..., 1]",
      "w12 = dq[..., 0], dq[..., 0] - dq[..., 1]", KIN, "J' q': q1' - q2'"),
    M("kinpy-ik-t1-sign", "kinematics", KINPY, "np.arctan2(y, x) - np.arctan2(a2 * s2", "np.arctan2(y, x) + np.arctan2(a2 * s2",
      KIN, "IK theta1 = atan2(y,x) + ..."),
    M("kinpy-reach-abs", "kinematics", KINPY, "return abs(params.a1 - params.a2), params.a1 + params.a2",
      "return params.a1 - params.a2, params.a1 + params.a2", KIN, "inner reach a1 - a2 without abs (a2 > a1)"),
    M("kinpy-ik-margin-le", "kinematics", KINPY, "(np.abs(s2) < min_sin_theta2)", "(np.abs(s2) <= min_sin_theta2)", KIN,
      "IK refuses the boundary |sin theta2| = 0 although min_sin_theta2 = 0 accepts it"),
    # ---- control laws: computed torque (Eq. 11), observer (Eq. 16 corrected), lumped d (Eq. 2-3) -------------
    M("law-ct-dhat-sign", "laws", LAW, "bias_forces(k, q, dq) - d_hat", "bias_forces(k, q, dq) + d_hat", LAWS,
      "computed torque: + d_hat"),
    M("law-ct-no-ff", "laws", LAW, "v = ddq_ref + kd", "v = 0.0 * ddq_ref + kd", LAWS, "computed torque: no q_ref''"),
    M("law-obs-bias-sign", "laws", LAW, "(y_dq + z) - model.bias_forces(k, q, dq)", "(y_dq + z) + model.bias_forces(k, q, dq)", LAWS,
      "observer: + h in the residual"),
    M("law-obs-eq16-sign", "laws", LAW, "- eq16_weight * y_dq", "+ eq16_weight * y_dq", LAWS,
      "printed Eq. 16 variant: + Y q'"),
    M("law-estimate-sign", "laws", LAW, "return gain_times(gain, dq) + z", "return gain_times(gain, dq) - z", LAWS,
      "d_hat = Y q' - z"),
    M("law-gain-transpose", "laws", LAW, "return (gain * v).sum(axis=1)", "return (gain * v).sum(axis=0)", LAWS,
      "full gain: Y^T v for Y v"),
    M("law-lumped-true", "laws", LAW, "return model.mass_times(k_nominal, q, ddq)", "return model.mass_times(k_true, q, ddq)", LAWS,
      "lumped d: M (true) q'' for M^ q''"),
    # ---- disturbance models (Eq. 4 and beside it) --------------------------------------------------------------
    M("dist-eq4-sign", "disturbances", DK, "np.sign(2.0 * t + 1.0)", "np.sign(2.0 * t - 1.0)", DIST,
      "Eq. 4 as sgn(2t - 1): -f_r for t < 0.5 s"),
    M("dist-friction-vs", "disturbances", DK, "np.tanh(dq / friction_velocity)", "np.tanh(dq * friction_velocity)", DIST,
      "friction: tanh(q' v_s)"),
    M("dist-tissue-damping", "disturbances", DK, "stiffness * depth - damping * vz", "stiffness * depth + damping * vz",
      DIST, "tissue: + c z'"),
    M("dist-tissue-inside", "disturbances", DK, "inside = depth > 0.0", "inside = depth >= 0.0", DIST,
      "tissue acts at depth 0 (the skin itself)",
      equivalent="depth exactly 0 is the one point of the contact's jump (no force above, c |z'| just below): "
                 "a set of measure zero that no integrator lands on, and the docstring's p > 0 is a choice there"),
    M("dist-tissue-fx", "disturbances", DK, "fx = -drag * vx * inside", "fx = -drag * vy * inside", DIST,
      "tissue drag: v_y in F_x"),
    M("dist-tissue-depth", "disturbances", DK, "depth = skin_height - model.tool_position(kin, q)[2]",
      "depth = model.tool_position(kin, q)[2] - skin_height", DIST, "tissue depth with the wrong sign"),
    M("dist-friction-args", "disturbances", DK, "friction_disturbance(dq, p.coulomb, p.viscous, p.friction_velocity)",
      "friction_disturbance(dq, p.viscous, p.coulomb, p.friction_velocity)", DIST + ("tests/test_loop.py",),
      "external_disturbance: Coulomb and viscous swapped"),
    # ---- URDF chain kernels (RNEA, CRBA, tool point) -----------------------------------------------------------
    M("chain-rot-transpose", "chain", CH, "R[a][b] = -ss\n        R[b][a] = ss", "R[a][b] = ss\n        R[b][a] = -ss", CHAIN,
      "axis rotation transposed (turns the other way)"),
    M("chain-rodrigues-transpose", "chain", CH, "_mul(ux[r][col], s)", "_mul(ux[col][r], s)", CHAIN,
      "Rodrigues (an oblique axis): [u]x transposed"),
    M("chain-prismatic-axis", "chain", CH, "_vscale(_matvec(Rp, axis), q[i]", "_vscale(axis, q[i]", CHAIN,
      "prismatic joint slides along its axis in its own frame, not the parent's"),
    M("chain-rnea-gravity-sign", "chain", CH, "tuple(-g for g in gravity)", "tuple(g for g in gravity)", CHAIN,
      "RNEA: the base accelerates at +g"),
    M("chain-rnea-gyro", "chain", CH, "n_c = _vadd(_matvec(Ic, dw), _cross(w, _matvec(Ic, w)))",
      "n_c = _vadd(_matvec(Ic, dw), _ZERO3)", CHAIN, "RNEA: gyroscopic term w x I w dropped"),
    M("chain-rnea-coriolis", "chain", CH, "A[i] = _sadd(_sadd(Ax, _vscale(S, ddq[i])), _motion_cross(V[i], Sdq))",
      "A[i] = _sadd(Ax, _vscale(S, ddq[i]))", CHAIN, "RNEA: the velocity-product acceleration v x S q' dropped"),
    M("chain-body-parallel-axis", "chain", CH, "v = _sub(Ic[a][b], _mul(h[a], c[b]))", "v = _add(Ic[a][b], _mul(h[a], c[b]))",
      CHAIN, "parallel-axis theorem: + m c c^T"),
    M("chain-crba-force", "chain", CH, "(_cross(u, h), _matvec(I, u))", "(_cross(h, u), _matvec(I, u))", CHAIN,
      "CRBA: h x u for u x h"),
    M("chain-cholesky-transpose", "chain", CH, "_mul(L[c][i], x[c]) for c in range(i + 1, n)",
      "_mul(L[i][c], x[c]) for c in range(i + 1, n)", CHAIN, "back substitution with L for L^T"),
    M("chain-tool-jacobian", "chain", CH, "col = _vadd(S[:3], _cross(S[3:], p))", "col = _vadd(S[:3], _cross(p, S[3:]))",
      CHAIN, "tool Jacobian: p x w for w x p"),
    M("chain-tool-accbias", "chain", CH, "acc = _vadd(_vadd(A[:3], _cross(A[3:], p)), _cross(w, pdot))",
      "acc = _vadd(A[:3], _cross(A[3:], p))", CHAIN, "tool J' q': centripetal w x p' dropped"),
    M("chain-frames-S", "chain", CH, "self.S[i] = _cross(p, a) + a", "self.S[i] = _cross(a, p) + a", CHAIN,
      "base-frame motion subspace: a x p for p x a"),
    M("chain-along-swap", "chain", CH, "return _dot(k.axes[i], n) if k.kinds[i] == \"revolute\" else _dot(k.axes[i], f)",
      "return _dot(k.axes[i], f) if k.kinds[i] == \"revolute\" else _dot(k.axes[i], n)", CHAIN,
      "joint force: moment for a prismatic joint, force for a revolute one"),
    M("chain-trace-cos-sin", "chain", CH, "out += [np.cos(q[i]), np.sin(q[i])] if", "out += [np.sin(q[i]), np.cos(q[i])] if",
      TRACE, "traced calls (codegen.ARM_CALLS, on by default): sin and cos of a revolute joint swapped"),
    M("chain-trace-lower-order", "chain", CH, "        for j in range(i + 1):\n            M[i][j] = M[j][i] = next(values)",
      "        for j in reversed(range(i + 1)):\n            M[i][j] = M[j][i] = next(values)", TRACE,
      "traced calls (codegen.ARM_CALLS): a row of M's lower triangle read in reverse"),
    # ---- IK derivatives of a URDF arm's tool point -------------------------------------------------------------
    M("ik-jrate-factor", "ik", RR_FILE, "return ((plus - minus) / 4.0).T", "return ((plus - minus) / 2.0).T", IK,
      "J' by polarisation: /2 for /4"),
    M("ik-ddq-bias-sign", "ik", IKF, "pinv @ (ddp - Jdot @ dq)", "pinv @ (ddp + Jdot @ dq)", IK, "q'' = J+ (p'' + J' q')"),
    M("ik-ddq-nullspace", "ik", IKF, "+ (np.eye(arm.n) - pinv @ J) @ (Jdot.T", "+ 0.0 * (np.eye(arm.n) - pinv @ J) @ (Jdot.T",
      IK, "q'' without the derivative of J+ in the null space (a redundant arm)"),
    M("ik-sigma-largest", "ik", IKF, "np.linalg.eigvalsh(JJt)[0]", "np.linalg.eigvalsh(JJt)[-1]", IK,
      "singularity check on the largest singular value"),
    # ---- divergence rule ---------------------------------------------------------------------------------------
    M("div-pos-abs", "divergence", BOUNDS, "pos = np.abs(q_ref).max(axis=0)", "pos = q_ref.max(axis=0)", DIVERGENCE,
      "position bound from max q_ref, not max |q_ref|"),
    M("div-violated-abs", "divergence", DIV, "return ~(np.abs(np.asarray(x, dtype=float)) <= self.bounds)",
      "return ~(np.asarray(x, dtype=float) <= self.bounds)", DIVERGENCE, "a large negative value never diverges"),
    M("div-violated-lt", "divergence", DIV, "return ~(np.abs(np.asarray(x, dtype=float)) <= self.bounds)",
      "return ~(np.abs(np.asarray(x, dtype=float)) < self.bounds)", DIVERGENCE, "a value at its bound diverges"),
    M("div-force-no-external", "divergence", BOUNDS,
      "external = _external_disturbance(kernels, tool_kernels)\n    forces = np.abs(external(0.0, q0, dq0, disturbance)) + ",
      "external = _external_disturbance(kernels, tool_kernels)\n    forces = 0.0 * np.abs(external(0.0, q0, dq0, disturbance)) + ",
      DIVERGENCE, "force bound without the external disturbance"),
    M("div-z-no-reach", "divergence", BOUNDS, "return (force + reach, f\"{name} (= d_hat", "return (force, f\"{name} (= d_hat",
      DIVERGENCE, "observer state bound without Y q'"),
    M("div-runaway-factor", "divergence", DIV, "grew = np.abs(y_next) > RUNAWAY_FACTOR * np.abs(y)",
      "grew = np.abs(y_next) > np.abs(y)", RUNAWAY, "runaway: any growth counts"),
    M("div-runaway-reset", "divergence", DIV, "self.streak = np.where(grew, self.streak + 1, 0)",
      "self.streak = np.where(grew, self.streak + 1, self.streak)", RUNAWAY, "runaway: streak not reset (not consecutive)"),
    # ---- monitor -----------------------------------------------------------------------------------------------
    M("mon-grid-last", "monitor", MON, "k = int(np.argmax(bad))\n            raise self.diverged(float(t_grid[k]), states[:, k])",
      "k = len(bad) - 1 - int(np.argmax(bad[::-1]))\n            raise self.diverged(float(t_grid[k]), states[:, k])",
      MONITOR + ("tests/test_loop.py::test_diverging_simulation_raises_with_time",), "check_grid reports the last bad point"),
    M("mon-members-first", "monitor", MON, "new = bad & np.isnan(failed_at)", "new = bad", MONITOR,
      "a member's failure time overwritten"),
    M("mon-evals-factor", "monitor", MON, "return self.budget.steps * EVALUATIONS_PER_STEP.get(self.method, 6)",
      "return self.budget.steps", MONITOR, "step budget counted in evaluations 1:1"),
    M("mon-counted-ge", "monitor", MON, "if count[0] > self.max_evaluations:", "if count[0] >= self.max_evaluations:", MONITOR,
      "counted: refuses the last allowed evaluation"),
    # ---- step-size and run limits -------------------------------------------------------------------------------
    M("rl-span-times", "run_limits", RL, "steps = t_final * rate / STABILITY_SPAN", "steps = t_final * rate * STABILITY_SPAN",
      RUN_LIMITS, "steps = T lambda * span"),
    M("rl-pd-slow-pole", "run_limits", RL, "0.5 * (kd + np.sqrt(np.abs(disc)))", "0.5 * (kd - np.sqrt(np.abs(disc)))",
      RUN_LIMITS, "arm_rates: the slow PD pole for the fast one"),
    M("rl-mismatch-min", "run_limits", RL, "np.abs(np.linalg.eigvals(M_inv @ M_hat)).max()",
      "np.abs(np.linalg.eigvals(M_inv @ M_hat)).min()", RUN_LIMITS, "arm_rates: smallest mismatch"),
    M("rl-min-candidate", "run_limits", RL, "steps, key, reason = max(candidates)", "steps, key, reason = min(candidates)",
      RUN_LIMITS, "the smallest step count wins"),
    M("sched-pd-slow-pole", "run_limits", SC, "0.5 * (kd + np.sqrt(np.abs(disc))), np.sqrt(kp)).max(axis=1)",
      "0.5 * (kd - np.sqrt(np.abs(disc))), np.sqrt(kp)).max(axis=1)", SCHEDULE,
      "rates_by_source (the RRPR's): the slow PD pole for the fast one"),
    M("sched-friction-vs", "run_limits", SC, "damping = dist.coulomb / dist.friction_velocity + dist.viscous",
      "damping = dist.coulomb * dist.friction_velocity + dist.viscous", SCHEDULE, "rates_by_source: F_c v_s for F_c / v_s"),
    M("sched-obs-nominal-only", "run_limits", SC, "for inv in (M_inv, M_hat_inv)], axis=0)", "for inv in (M_hat_inv,)], axis=0)",
      SCHEDULE, "rates_by_source: the observer's rate on the nominal inertia only (a lighter true arm is faster)"),
    # ---- sampled-loop stability ----------------------------------------------------------------------------------
    M("ds-held-integral-ts", "digital_stability", DS, "A * period, np.eye(n) * period", "A * period, np.eye(n)", DSTAB,
      "held integral without Ts"),
    M("ds-eq16-sign", "digital_stability", DS, "rate = A @ residual - eq16_weight * (Y @ W)",
      "rate = A @ residual + eq16_weight * (Y @ W)", DSTAB, "printed Eq. 16 with + Y w"),
    M("ds-A-order", "digital_stability", DS, "A = -Y @ Minv", "A = -Minv @ Y", DSTAB + ("tests/test_sampled_stability.py",),
      "A = -M^-1 Y for -Y M^-1 (a non-scalar gain)"),
    M("ds-delay-shift", "digital_stability", DS, "for j in range(delay - 1):", "for j in range(max(delay - 2, 0)):",
      DSTAB + ("tests/test_digital_delay.py",), "delay buffer: the last shift missing (delay >= 2)"),
    M("ds-bisect-mean", "digital_stability", DS, "mid = math.sqrt(lo * hi)", "mid = 0.5 * (lo + hi)", DSTAB,
      "bisection at the arithmetic mean",
      equivalent="the bracket still halves around the same crossing; the result lies within rtol of the limit either way"),
    M("ds-return-hi", "digital_stability", DS, "    return float(lo)\n\n\ndef sampled_stability",
      "    return float(hi)\n\n\ndef sampled_stability", DSTAB, "largest stable scale: the unstable end of the bracket"),
    M("ds-variant-swap", "digital_stability", DS, "weight = 1.0 if variant == \"paper-eq16\" else 0.0",
      "weight = 1.0 if variant == \"correct\" else 0.0", DSTAB, "observer variants swapped"),
    M("ds-gravity-sign", "digital_stability", DS, "command = command + S @ Q", "command = command - S @ Q", DSTAB,
      "controller's gravity slope sign"),
    # ---- budgets ------------------------------------------------------------------------------------------------
    M("bu-count-zero", "budget", BU, "number < 1 or number != int(number)", "number < 0 or number != int(number)", BUDGET,
      "a step budget of 0 accepted"),
    M("bu-share", "budget", BU, "memory=max(1, self.memory // max(1, int(parts)))", "memory=max(1, self.memory)", BUDGET,
      "share: memory not divided"),
    M("bu-check-ge", "budget", BU, "if estimate.steps > self.steps:", "if estimate.steps >= self.steps:", BUDGET,
      "a run of exactly the step budget refused"),
    M("bu-schedule-breaks", "budget", BU, "* int(substeps) + int(breakpoints)", "* int(substeps)", BUDGET,
      "schedule_steps without the breakpoints"),
    M("bu-signals-joints", "budget", BU, "members * SIGNAL_POINT_BYTES_PER_JOINT * joints * int(grid_points)",
      "members * SIGNAL_POINT_BYTES_PER_JOINT * int(grid_points)", BUDGET, "kept signals not per joint"),
    M("bu-largest-fixed", "budget", BU, "return max(0, int((memory - fixed) // per_member))",
      "return max(0, int(memory // per_member))", BUDGET, "largest_batch ignores the fixed part"),
    # ---- linearization and bandwidth -----------------------------------------------------------------------------
    M("lin-Tv-sign", "linear", AL, "T_v = -M_nom @ (n_v + loop.kd) - Y", "T_v = -M_nom @ (n_v + loop.kd) + Y", LINEAR,
      "linearization: + Y in the velocity feedback"),
    M("lin-obs-row", "linear", AL, "[loop.Y @ loop.kp, loop.Y @ loop.kd, Z]", "[loop.Y @ loop.kp, loop.Y @ loop.kp, Z]", LINEAR,
      "observer row: Y Kp for Y Kd"),
    M("lin-C-ed", "linear", AL, "np.hstack([Z, -loop.Y, -I])", "np.hstack([Z, loop.Y, -I])", LINEAR,
      "estimation-error output: + Y dq"),
    M("lin-analytic-obs", "linear", AL, "np.linalg.eigvals(-joint_matrix(Y, \"Y\", n) @ np.linalg.inv(M))",
      "np.linalg.eigvals(-joint_matrix(Y, \"Y\", n) @ M)", LINEAR, "analytic observer poles of -Y M for -Y M^-1"),
    M("bw-modes-M", "linear", BW, "A = Y @ np.linalg.inv(arm.inertia(q))", "A = Y @ arm.inertia(q)", LINEAR,
      "observer modes of Y M"),
    M("bw-modes-order", "linear", BW, "order = np.argsort(w.real, axis=-1)", "order = np.argsort(-w.real, axis=-1)", LINEAR,
      "modes fastest first"),
    # ---- metrics ------------------------------------------------------------------------------------------------
    M("me-rms-n1", "metrics", ME, "np.sqrt(self.sum_sq_e / n)", "np.sqrt(self.sum_sq_e / (n - 1))", METRICS,
      "RMS over n - 1 points"),
    M("me-final-index", "metrics", ME, "np.abs(e[:, -1])", "np.abs(e[:, -2])", METRICS, "final error one point early"),
    M("me-mm", "metrics", ME, "\"max_tool_position_error_mm\": 1e3 * self.max_tool", "\"max_tool_position_error_mm\": 1e2 * self.max_tool",
      METRICS, "m to mm by 100"),
    M("me-ed-sign", "metrics", ME, "ed = d - d_hat", "ed = d + d_hat", METRICS, "d + d_hat"),
    M("me-d-source", "metrics", ME, "d = signal(response, \"d\") if \"d[0]\" in labels else signal(response, \"tau_dis\")",
      "d = signal(response, \"tau_dis\")", METRICS, "disturbance error against tau_dis even when d (lumped) is there"),
    # ---- end stops (Python values and the C plant) ---------------------------------------------------------------
    M("es-inertia-min", "end_stops", ES, "return 1.0 / inv_diag.max(axis=0)", "return 1.0 / inv_diag.min(axis=0)", END_STOPS,
      "effective inertia: the largest over poses"),
    M("es-stiffness-w", "end_stops", ES, "stiffness=float(m[i] * w * w)", "stiffness=float(m[i] * w)", END_STOPS, "k = m w"),
    M("es-damping-2", "end_stops", ES, "damping=float(2.0 * zeta * m[i] * w)", "damping=float(zeta * m[i] * w)", END_STOPS,
      "c = zeta m w"),
    M("es-bounded-and", "end_stops", ES, "if math.isfinite(lo) or math.isfinite(hi)]", "if math.isfinite(lo) and math.isfinite(hi)]",
      END_STOPS, "a joint bounded on one side gets no stop"),
    M("c-stop-upper-damping", "fmu_c", PC, "force = -k * (q - upper[s]) - c * dq;", "force = -k * (q - upper[s]) + c * dq;", FMU_C,
      "upper stop: + c q'"),
    M("c-stop-upper-clamp", "fmu_c", PC, "if (force > 0.0) force = 0.0;", "if (force < 0.0) force = 0.0;", FMU_C,
      "upper stop only pulls"),
    M("c-stop-lower-sign", "fmu_c", PC, "force = k * (lower[s] - q) - c * dq;", "force = k * (q - lower[s]) - c * dq;", FMU_C,
      "lower stop spring sign"),
    M("c-rk4-weights", "fmu_c", PC, "2.0 * k3[i] + k4[i]", "k3[i] + 2.0 * k4[i]", FMU_C, "RK4 weights of k3 and k4 swapped"),
    M("c-input-ramp", "fmu_c", PC, "u[i] = u0[i] + (t - t0) * d->du[i];", "u[i] = u0[i];",
      FMU_C + ("tests/test_fmu_events.py", "tests/test_fmu_cosim.py"), "input derivatives ignored"),
    M("c-der-q", "fmu_c", PC, "*value = d->x[N_JOINTS + (vr - VR_Q)];", "*value = d->x[(vr - VR_Q)];",
      FMU_C + ("tests/test_fmu_events.py", "tests/test_fmu_cosim.py", "tests/test_cosim_coupling.py"), "der(q) = q"),
]


# --------------------------------------------------------------------------------------------------------------
# Second pass: the FMU's other C files and its Python side, the digital controller, the compiled engine, the
# noise, the task-space paths, the redundant-arm IK, the sweep/tune maths and the report's numbers
# --------------------------------------------------------------------------------------------------------------
FMU_C2 = ("tests/test_fmu_safety.py", "tests/test_fmu_cosim.py", "tests/test_cosim_coupling.py",
          "tests/test_fmu_export.py::test_co_simulation_follows_the_input_slope_and_gives_exact_output_derivatives")
CTRL_C = ("tests/test_controller_fmu.py",)
FMU_PY = ("tests/test_cosim_coupling.py", "tests/test_cosim_coupling_input.py", "tests/test_fmu_cosim.py")
START = ("tests/test_fmu_start_values.py",)
DIGITAL = ("tests/test_digital.py", "tests/test_digital_delay.py", "tests/test_digital_observer.py")
TICKS = ("tests/test_sampling_events.py", "tests/test_digital.py")
DOPRI = ("tests/test_compiled.py::test_compiled_equals_numpy_engine",
         "tests/test_compiled.py::test_compiled_equals_numpy_engine_on_random_variants",
         "tests/test_compiled.py::test_compiled_batch_equals_numpy_batch_and_single_compiled_runs")
TRACED = ("tests/test_fastpath.py::test_the_generated_float_right_hand_side_equals_the_numpy_plan_bit_for_bit",
          "tests/test_compiled.py::test_generated_right_hand_side_and_outputs_equal_the_plan_executed_with_numpy",
          "tests/test_urdf_trace.py")
NOISE = ("tests/test_derived_signals.py", "tests/test_loop.py::test_measurement_noise_is_reproducible_by_seed",
         "tests/test_arm_digital.py::test_noise_of_n_joints_is_seeded_and_keeps_the_rrpr_draw",
         "tests/test_analysis_digital.py::test_quantization_noise_is_predicted_within_20_percent")
LACERATION = ("tests/test_trajectory.py",)
TOOL_PATH = ("tests/test_arm_loop_path.py::test_reference_puts_pinocchios_tool_frame_on_the_path_between_samples",
             "tests/test_arm_loop_path.py::test_reference_rates_are_the_derivatives_of_its_positions")
REDUNDANT = ("tests/test_ik_redundant.py",)
SUMMARY = ("tests/test_sweep_summary.py", "tests/test_sweep_results.py")
COSTS = ("tests/test_tune_costs.py",)
EVALUATE = ("tests/test_tune_constraints.py", "tests/test_tune_linear.py", "tests/test_tune_sampled.py")
FREQ = ("tests/test_analysis_frequency.py",)
DESIGN = ("tests/test_analysis_observer.py", "tests/test_analysis_n_joints.py::test_gain_design_for_the_cylindrical_arm_has_its_closed_form",
          "tests/test_analysis_n_joints.py::test_certificate_and_critical_speed_for_the_cylindrical_arm")

PI, PSt, CC = "fmu/c/plant_instance.c", "fmu/c/plant_state.c", "fmu/c/controller_core.c"
F2, F3 = "fmu/c/fmi2_common.c", "fmu/c/fmi3_common.c"
CPL, MST, SV = "fmu/coupling.py", "fmu/master.py", "fmu/start_values.py"
DG, SMP, NZ, NZK = "blocks/diagram/digital.py", "blocks/engines/sampling.py", "blocks/model/noise.py", "blocks/kernels/noise.py"
DP, TR = "blocks/engines/compiled/dopri.py", "blocks/kernels/trace.py"
TJ, TP, RR = "blocks/diagram/trajectory.py", "blocks/scenarios/tool_path.py", "blocks/model/urdf/resolved_rate.py"
TK = "blocks/model/task_path.py"
LAC = "blocks/model/rrpr/laceration.py"      # the RRPR's closed-form IK of the laceration path
SU, CO, EV = "analysis/sweep/summary.py", "analysis/tune/costs.py", "analysis/tune/evaluate.py"
FR, GD = "analysis/linear/frequency.py", "analysis/linear/gain_design.py"

MUTANTS += [
    # ---- the FMU's C instance, saved states, controller core and FMI layers ------------------------------------
    M("c-set-input-keeps-slope", "fmu_c2", PI, "inst->d.du[vr - VR_TAU] = 0.0;", "(void)0;", FMU_C2,
      "a new input value keeps the old input derivative (FMI 2: a set value without a slope must be held)"),
    M("c-dostep-zero-h", "fmu_c2", PI, "if (!(h > 0.0) || !isfinite(h)) {", "if (!(h >= 0.0) || !isfinite(h)) {", FMU_C2,
      "doStep accepts h = 0"),
    M("c-dostep-time-check", "fmu_c2", PI, "if (fabs(t - t0) > 1e-9 * (1.0 + fabs(t0))) {",
      "if (fabs(t - t0) > 1e-1 * (1.0 + fabs(t0))) {", FMU_C2, "doStep from another time than the FMU's accepted"),
    M("c-restore-switch-check", "fmu_c2", PI, "if (d->sw[i] != 0 && d->sw[i] != 1) {",
      "if (d->sw[i] != 0 && d->sw[i] != 1 && 0) {", FMU_C2, "a restored state with a disturbance switch of 2 accepted"),
    M("c-restore-mode-kind", "fmu_c2", PI, "if (inst->cosim ? (mode == MODE_EVENT || mode == MODE_CONTINUOUS) : mode == MODE_STEP) {",
      "if (inst->cosim ? (mode == MODE_EVENT) : mode == MODE_STEP) {", FMU_C2,
      "a Model Exchange continuous-time state restored into a Co-Simulation instance"),
    M("c-state-size-lt", "fmu_c2", PSt, "if (!bytes || size != sizeof(SavedState)) {", "if (!bytes || size < sizeof(SavedState)) {",
      FMU_C2, "serializing into a buffer larger than the state accepted"),
    M("c-state-magic", "fmu_c2", PSt, "|| memcmp(bytes, PLANT_STATE_MAGIC, sizeof PLANT_STATE_MAGIC) != 0) {", ") {", FMU_C2,
      "a serialized state without the FMU's magic accepted"),
    M("c-ctrl-end-ge", "fmu_c2", CC, "if (c->k + 1 >= CTRL_NTICKS) {", "if (c->k + 1 > CTRL_NTICKS) {", CTRL_C,
      "the controller steps one tick past its reference table"),
    M("c-ctrl-step-period", "fmu_c2", CC, "if (!(fabs(h - CTRL_PERIOD) <= 1e-9 * CTRL_PERIOD)) {",
      "if (!(fabs(h - CTRL_PERIOD) <= 1e-1 * CTRL_PERIOD)) {", CTRL_C, "a communication step 10 % off the sample period accepted"),
    M("c-ctrl-time", "fmu_c2", CC, "*value = ctrl_time(c);", "*value = (double)c->k;", CTRL_C, "the controller's time in ticks, not s"),
    M("c-ctrl-buffer-fill", "fmu_c2", CC, "c->x[CTRL_BUF_START + i + j] = c->out[2 * N + j];",
      "c->x[CTRL_BUF_START + i + j] = 0.0;", CTRL_C, "the delay buffer starts empty, not with the first command"),
    M("c-ctrl-stop-time", "fmu_c2", CC, "if (stop_defined && stop_time > CTRL_REFERENCE_END * (1.0 + 1e-12)) {",
      "if (stop_defined && stop_time > 2.0 * CTRL_REFERENCE_END) {", CTRL_C, "a stopTime past the reference table accepted"),
    M("c-fmi2-status", "fmu_c2", F2, "*value = fmi2_layer_failed(c) ? fmi2Error : fmi2OK;", "*value = fmi2OK;", FMU_C2,
      "fmi2GetStatus says OK after a failed step"),
    M("c-fmi2-last-time", "fmu_c2", F2, "*value = fmi2_layer_time(c);", "*value = 0.0;", FMU_C2,
      "fmi2LastSuccessfulTime is 0"),
    M("c-fmi3-last-time", "fmu_c2", F3, "if (lastSuccessfulTime) *lastSuccessfulTime = time;",
      "if (lastSuccessfulTime) *lastSuccessfulTime = 0.0;", FMU_C2, "FMI 3 doStep's lastSuccessfulTime is 0"),
    # ---- the FMU's Python side: coupling, master, start values -------------------------------------------------
    M("cpl-hermite-h", "fmu_py", CPL, "(r3 - 2 * r2 + r) * h * d0", "(r3 - 2 * r2 + r) * d0", FMU_PY + ("tests/test_doctests.py",),
      "cubic Hermite: the start slope without h"),
    M("cpl-default-zoh", "fmu_py", CPL, "return \"linear\" if able else \"zoh\"", "return \"zoh\"", FMU_PY,
      "the default coupling is always zoh"),
    M("mst-rk4-mid-input", "fmu_py", MST, "(inputs_at(tj + 0.5 * dt),)", "(inputs_at(tj),)", FMU_PY,
      "the Python side's RK4 reads its midpoint inputs at the stage start"),
    M("mst-ended-held", "fmu_py", MST, "ended = cmd + h * dcmd if linear else cmd", "ended = cmd", FMU_PY,
      "linear coupling: the applied torque at the step's end taken as held"),
    M("mst-slope-state", "fmu_py", MST, "x_d = x + delta * rhs(t, x, u) if x.size else x", "x_d = x", FMU_PY,
      "output slope: the Python side's state held"),
    M("mst-applied-slope", "fmu_py", MST, "v[w.appl_pos] = applied0 + r * applied_slope", "v[w.appl_pos] = applied0", FMU_PY,
      "linear coupling: the applied torque the observer reads held over the step"),
    M("mst-slope-prev", "fmu_py", MST, "((y_m - y_m_prev) / h if y_m_prev", "((y_m - y_m_prev) * h if y_m_prev", FMU_PY,
      "without FMU derivatives: the measured slope times h for over h"),
    M("sv-int-high", "fmu_py", SV, "if not low <= number <= high:", "if not low <= number < high:", START,
      "an integer start value at its type's maximum refused"),
    M("sv-float32-max", "fmu_py", SV, "abs(number) > FLOAT32_MAX:", "abs(number) >= FLOAT32_MAX:", START,
      "the largest Float32 refused"),
    M("sv-fmi2-integer", "fmu_py", SV, "if type_name in (\"Integer\", \"Enumeration\") and fmi_version == 2:",
      "if type_name == \"Enumeration\" and fmi_version == 2:", START, "an FMI 2 Integer not given Int32's range"),
    # ---- the digital controller: encoder, filter, quantization, delay, observer discretizations ----------------
    M("dg-filter-pole", "digital", DG, "math.exp(-2 * math.pi * self.velocity_cutoff * self.period)",
      "math.exp(-math.pi * self.velocity_cutoff * self.period)", DIGITAL, "velocity filter pole at f_c / 2"),
    M("dg-diff-gain", "digital", DG, "pole * x[n:] + (1.0 - pole) * (q_s - x[:n]) / period",
      "pole * x[n:] + (q_s - x[:n]) / period", DIGITAL, "velocity filter without its (1 - a) input gain"),
    M("dg-quant-floor", "digital", DG, "np.where(steps, np.rint(q / np.where(steps, resolution, 1.0)) * resolution, q)",
      "np.where(steps, np.floor(q / np.where(steps, resolution, 1.0)) * resolution, q)", DIGITAL,
      "encoder truncates instead of rounding"),
    M("dg-sat-lower", "digital", DG, "np.minimum(np.maximum(command[i], -limit[i]), limit[i])",
      "np.minimum(np.maximum(command[i], -0.5 * limit[i]), limit[i])", DIGITAL, "lower torque limit at half"),
    M("dg-buffer-order", "digital", DG, "return np.concatenate((x[n:], u))", "return np.concatenate((u, x[n:]))", DIGITAL,
      "delay buffer pushes at the front (delay >= 2 reorders)"),
    M("dg-euler-half", "digital", DG, "return z + period * observer_rate(", "return z + 0.5 * period * observer_rate(", DIGITAL,
      "Euler observer with Ts / 2"),
    M("dg-zoh-c-ts", "digital", DG, "augmented[:n, n] = c * period", "augmented[:n, n] = c", DIGITAL,
      "ZOH observer: the constant column without Ts"),
    M("dg-estimate-q", "digital", DG, "return observer_estimate(gain, u[2 * n:3 * n], z)",
      "return observer_estimate(gain, u[n:2 * n], z)", DIGITAL, "sampled d_hat = Y q + z for Y q' + z"),
    M("smp-tick-round", "digital", SMP, "return int(math.floor(t_end / base_period * (1 + 1e-12)))",
      "return int(math.floor(t_end / base_period))", TICKS, "the last tick lost to a rounding error"),
    # ---- the compiled engine: Dormand-Prince tableau, step control, dense output, trace ------------------------
    M("dp-a31", "compiled", DP, "[44 / 45, -56 / 15, 32 / 9, 0.0, 0.0]", "[44 / 45, -56 / 16, 32 / 9, 0.0, 0.0]", DOPRI,
      "Dormand-Prince a_41 = -56/16"),
    M("dp-c4", "compiled", DP, "DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0])",
      "DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 10, 1.0])", DOPRI, "Dormand-Prince c_5 = 8/10"),
    M("dp-b4-sign", "compiled", DP, "125 / 192, -2187 / 6784, 11 / 84])", "125 / 192, 2187 / 6784, 11 / 84])", DOPRI,
      "Dormand-Prince b_5 sign"),
    M("dp-e-typo", "compiled", DP, "17253 / 339200", "17253 / 33920", DOPRI, "error weights e_5 by 10 (step control only)"),
    M("dp-p-sign", "compiled", DP, "[1.0, -8048581381 / 2820520608,", "[1.0, 8048581381 / 2820520608,", DOPRI,
      "dense output P_01 sign"),
    M("dp-safety", "compiled", DP, "SAFETY = 0.9", "SAFETY = 0.8", DOPRI, "step safety factor 0.8"),
    M("dp-max-factor", "compiled", DP, "MAX_FACTOR = 10.0", "MAX_FACTOR = 5.0", DOPRI, "step growth at most 5"),
    M("dp-rejected-cap", "compiled", DP, "factor = min(1.0, factor)", "factor = min(2.0, factor)", DOPRI,
      "after a rejection the step may grow"),
    M("dp-dense-p3", "compiled", DP, "    p3 = p2 * x\n    for i in range(y_old.shape[0]):\n        out[i, k]",
      "    p3 = p2\n    for i in range(y_old.shape[0]):\n        out[i, k]", DOPRI, "dense output on the grid: x^3 for x^4"),
    M("dp-h0-factor", "compiled", DP, "h0 = 0.01 * d0 / d1", "h0 = 0.1 * d0 / d1", DOPRI, "first-step guess 10 x"),
    M("dp-h1-order", "compiled", DP, "h1 = (0.01 / max(d1, d2)) ** (1.0 / 5.0)", "h1 = (0.01 / max(d1, d2)) ** (1.0 / 4.0)",
      DOPRI, "first-step guess with exponent 1/4"),
    M("dp-err-scale", "compiled", DP, "scale = atol + max(abs(y[i]), abs(y_new[i])) * rtol", "scale = atol + abs(y[i]) * rtol",
      DOPRI, "error scale from the step's start only"),
    M("dp-rms-n", "compiled", DP, "return math.sqrt(total) / math.sqrt(v.shape[0])", "return math.sqrt(total)", DOPRI,
      "error norm not divided by sqrt(n)"),
    M("tr-fold-minus", "compiled", TR, "\"-\": x - y,", "\"-\": y - x,", TRACED, "constant folding of a - b as b - a"),
    M("tr-rsub", "compiled", TR, "def __rsub__(self, o):\n        return _elementwise(o, self,",
      "def __rsub__(self, o):\n        return _elementwise(self, o,", TRACED, "c - x traced as x - c"),
    M("tr-zero-minus", "compiled", TR, "if op == \"-\" and _is_const(a, 0.0):\n            return self.graph.node(\"call\", (\"negative\", b))",
      "if op == \"-\" and _is_const(a, 0.0):\n            return b", TRACED, "0 - x traced as x"),
    M("tr-rtruediv", "compiled", TR, "def __rtruediv__(self, o):\n        return _elementwise(o, self,",
      "def __rtruediv__(self, o):\n        return _elementwise(self, o,", TRACED, "c / x traced as x / c"),
    # ---- measurement noise -------------------------------------------------------------------------------------
    M("nz-weight-swap", "noise", NZK, "return (1.0 - weight) * table[:, index] + weight * table[:, index + 1]",
      "return weight * table[:, index] + (1.0 - weight) * table[:, index + 1]", NOISE, "interpolation weights swapped"),
    M("nz-std-swap", "noise", NZ, "np.array(self.q_std + self.dq_std)", "np.array(self.dq_std + self.q_std)", NOISE,
      "position noise drawn with the velocity std"),
    M("nz-count", "noise", NZ, "count = int(math.ceil(self.t_final / self.sample_period)) + 2",
      "count = int(math.ceil(self.t_final / self.sample_period))", NOISE, "the samples end a period before t_final"),
    # ---- task-space paths: the laceration (RRPR) and the tool path of any arm ----------------------------------
    M("tj-smooth-d1", "task_path", SPLINES, "30 * tau ** 2 * (1 - tau) ** 2,", "30 * tau ** 2 * (1 - tau),", LACERATION,
      "smoothstep5 derivative with (1 - tau) once"),
    M("tj-bump-dd", "task_path", SPLINES, "384 * u * du ** 2 - 384 * u ** 2", "384 * u * du ** 2 - 192 * u ** 2", LACERATION,
      "bump6 second derivative: 192 u^2"),
    M("tj-dds-T", "task_path", TK, "step * ddsig / T ** 2", "step * ddsig / T", LACERATION, "s'' over T for T^2"),
    M("tj-bulge-ddw", "task_path", TK, "4 * bulge * (1 - 2 * s), -8 * bulge", "4 * bulge * (1 - 2 * s), -4 * bulge", LACERATION,
      "bulge curvature w'' = -4 b for -8 b"),
    M("tj-bias-w12", "task_path", LAC, "bx = ax + a1 * c1 * w1 ** 2 + a2 * c12 * w12 ** 2", "bx = ax + a1 * c1 * w1 ** 2 + a2 * c12 * w2 ** 2",
      LACERATION, "IK acceleration bias: w2^2 for (w1 + w2)^2 in x"),
    M("tj-aphi-sign", "task_path", LAC, "e1 + e2 - aphi)", "e1 + e2 + aphi)", LACERATION, "theta4'' = e1 + e2 + phi''"),
    M("tj-phase-cap", "task_path", TK, "phase = min(max(math.floor(t / T), 0), 2 * stitches - 2)",
      "phase = min(max(math.floor(t / T), 0), 2 * stitches - 1)", LACERATION, "a phase past the last stitch"),
    M("tp-quintic-c4", "task_path", SPLINES, "c4 = -15.0 * d + 7.0 * dv - da", "c4 = -15.0 * d + 7.0 * dv - 0.5 * da", TOOL_PATH,
      "joint table quintic: c4 with da / 2"),
    M("tp-quintic-ddq", "task_path", SPLINES, "s * (12.0 * c4 + s * (20.0 * c5))", "s * (12.0 * c4 + s * (12.0 * c5))", TOOL_PATH,
      "joint table quintic: q'' with 12 c5"),
    M("tp-dds-T", "task_path", TP, "(dds / T ** 2)[..., None] * step", "(dds / T)[..., None] * step", TOOL_PATH,
      "tool path p'' over T for T^2"),
    # ---- the redundant arm's resolved-rate IK -------------------------------------------------------------------
    M("rr-hermite-k4", "resolved_rate", RR, "c0 * (h * h), a1", "c0 * h, a1", REDUNDANT,
      "task-space quintic between samples: the start acceleration scaled by h, not h^2"),
    M("rr-hermite-rate", "resolved_rate", RR, "a0, b0 * h, c0", "a0, b0, c0", REDUNDANT,
      "task-space quintic between samples: the start rate not scaled by h"),
    M("rr-limit-push", "resolved_rate", RR, "(into_lo ** 2 - into_hi ** 2)", "(into_hi ** 2 - into_lo ** 2)", REDUNDANT,
      "the limit term pushes a joint into its end"),
    M("rr-limit-slope", "resolved_rate", RR, "slope = -self.kn - 2.0 * self.kl * (into_lo + into_hi)", "slope = -self.kn",
      REDUNDANT, "dz/dq without the limit term's slope"),
    M("rr-dpinv-first", "resolved_rate", RR, "dpinv = P @ np.linalg.solve(JJt, Jd).T - pinv @ Jd @ pinv",
      "dpinv = - pinv @ Jd @ pinv", REDUNDANT, "d/dt J+ without P J'^T (J J^T)^-1"),
    M("rr-dv-feedback", "resolved_rate", RR, "dv = ddp + self.kp * (dp - J @ dq)", "dv = ddp", REDUNDANT,
      "v' without the task feedback's rate"),
    M("rr-rate-null", "resolved_rate", RR, "return pinv @ v + z - pinv @ (J @ z)", "return pinv @ v + z", REDUNDANT,
      "posture term not projected into the null space"),
    # ---- sweep statistics, tune constraint costs and margins -----------------------------------------------------
    M("su-std-ddof", "sweep_tune", SU, "np.std(w, ddof=1)", "np.std(w, ddof=0)", SUMMARY, "sample std over n, not n - 1"),
    M("su-p95", "sweep_tune", SU, "_QUANTILES = (0.05, 0.5, 0.95)", "_QUANTILES = (0.05, 0.5, 0.9)", SUMMARY, "p95 at 0.9"),
    M("su-ranks-ties", "sweep_tune", SU, "return sums[inverse] / counts[inverse]", "return ranks", SUMMARY,
      "Spearman ranks without the mean rank of ties"),
    M("su-mean-scale", "sweep_tune", SU, "mean, std = float(np.mean(w)) * top,", "mean, std = float(np.mean(w)),", SUMMARY,
      "mean left in units of the largest value"),
    M("su-worst-order", "sweep_tune", SU, "key=lambda item: (-item[0], -item[1]))]", "key=lambda item: (item[0], -item[1]))]",
      SUMMARY, "worst runs listed best first"),
    M("co-cost-sign", "sweep_tune", CO, "(reference - best.objective if binds else 0.0)", "(best.objective - reference if binds else 0.0)",
      COSTS, "a binding constraint's cost negative"),
    M("co-binds-le", "sweep_tune", CO, "and best.objective < reference", "and best.objective <= reference", COSTS,
      "a constraint that changes nothing said to bind"),
    M("co-search-count", "sweep_tune", CO, "return 1 + len(costed_constraints(spec.limits))", "return len(costed_constraints(spec.limits))",
      COSTS, "the costed search count without the reference search"),
    M("ev-damping-max", "sweep_tune", EV, "out[\"min_damping_ratio\"] = float(np.min(ev.damping_ratio) - limits.min_damping_ratio)",
      "out[\"min_damping_ratio\"] = float(np.max(ev.damping_ratio) - limits.min_damping_ratio)", EVALUATE,
      "damping margin of the best-damped joint"),
    M("ev-noise-max", "sweep_tune", EV, "float(np.min(1.0 - ev.torque_noise_rms / limits.torque_noise_rms))",
      "float(np.max(1.0 - ev.torque_noise_rms / limits.torque_noise_rms))", EVALUATE, "noise margin of the quietest joint"),
    M("ev-ts-lambda-M", "sweep_tune", EV, "np.linalg.eigvals(Y @ np.linalg.inv(self._M_sampled))", "np.linalg.eigvals(Y @ self._M_sampled)",
      EVALUATE, "sampled margin from Y M for Y M^-1"),
    M("ev-energy-total", "sweep_tune", EV, "else INFEASIBLE * (1.0 + total)", "else INFEASIBLE * total", EVALUATE,
      "an infeasible candidate with a tiny violation ranks below feasible ones"),
    # ---- the report's numbers: frequency responses and the observer gain design -----------------------------------
    M("fr-closed-s", "report_numbers", FR, "-s * pd_inv @ np.linalg.inv(s * M + Y)", "-pd_inv @ np.linalg.inv(s * M + Y)", FREQ,
      "closed form E without the observer's zero at s = 0"),
    M("fr-closed-ed", "report_numbers", FR, "out.append(s * M @ np.linalg.inv(s * M + Y) if observer",
      "out.append(M @ np.linalg.inv(s * M + Y) if observer", FREQ, "closed form E_d without s"),
    M("fr-dc-sign", "report_numbers", FR, "dc = float(np.real(D[out, inp] - C[out] @ np.linalg.solve(A, B[:, inp])))",
      "dc = float(np.real(D[out, inp] + C[out] @ np.linalg.solve(A, B[:, inp])))", FREQ, "DC gain D + C A^-1 B"),
    M("fr-lowpass-level", "report_numbers", FR, "kind, level = \"low-pass\", abs(dc) / math.sqrt(2.0)",
      "kind, level = \"low-pass\", abs(dc) / 2.0", FREQ, "low-pass band edge at -6 dB"),
    M("fr-lowpass-edge", "report_numbers", FR, "band = [0.0, crossing(change[0]) if change.size else None]",
      "band = [0.0, crossing(change[-1]) if change.size else None]", FREQ, "low-pass band edge at the last crossing"),
    M("gd-return-lo", "report_numbers", GD, "    Y = base + c_hi * M_ref\n", "    Y = base + c_lo * M_ref\n", DESIGN,
      "designed gain from the bracket's low (too slow) end"),
    M("gd-decay-mdot", "report_numbers", GD, "S = (Y + Y.T) / 2.0 - M_dot / 2.0", "S = (Y + Y.T) / 2.0 - M_dot", DESIGN,
      "decay rate with M' for M'/2"),
    M("gd-critical-half", "report_numbers", GD, "Ys_inv_half @ (M_dot / 2.0) @ Ys_inv_half", "Ys_inv_half @ M_dot @ Ys_inv_half",
      DESIGN, "critical speed with M' for M'/2"),
]


# --------------------------------------------------------------------------------------------------------------
def _apply(m: Mutant) -> str:
    """Write mutant ``m`` into its file; return the original text."""
    path = ROOT / m.file
    text = path.read_text()
    count = text.count(m.old)
    if count != 1:
        raise SystemExit(f"mutant {m.id}: the snippet occurs {count} times in {m.file} (must be once): {m.old!r}")
    path.write_text(text.replace(m.old, m.new))
    return text


def _first_failure(output: str) -> str:
    for pattern in (r"^FAILED (\S+)", r"^ERROR (\S+)", r"^(\S+::\S+) FAILED"):
        found = re.search(pattern, output, re.M)
        if found:
            return found.group(1)
    return ""


def run_mutant(m: Mutant, killers: bool, timeout: float = TIMEOUT, killers_only: bool = False) -> Outcome:
    """Apply ``m``, run its tests (and the killer tests), put the file back, say whether it was killed."""
    tests = KILLERS if killers_only else (m.tests + (KILLERS if killers else ()))
    # a -k option applies to every file given; split the run where a mutant's list carries one
    runs, current = [], []
    items = list(tests)
    i = 0
    while i < len(items):
        if items[i] == "-k":
            runs.append(current + ["-k", items[i + 1]])
            current = []
            i += 2
            continue
        current.append(items[i])
        i += 1
    if current:
        runs.append(current)
    original = _apply(m)
    started = time.monotonic()
    killed, by, tail, timed_out = False, "", [], False
    try:
        for args in runs:
            cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-n", "0", "-p", "no:cacheprovider", *args]
            try:
                done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                killed, by, timed_out = True, f"timeout after {timeout:g} s", True
                break
            if done.returncode in (4, 5):      # a usage error or no tests collected: the probe's fault, not a kill
                raise SystemExit(f"mutant {m.id}: pytest could not run {args} (exit {done.returncode}):\n"
                                 + "\n".join(done.stdout.strip().splitlines()[-5:] + done.stderr.strip().splitlines()[-5:]))
            if done.returncode != 0:
                killed = True
                by = _first_failure(done.stdout) or f"pytest exit {done.returncode}"
                tail = done.stdout.strip().splitlines()[-15:]
                break
    finally:
        (ROOT / m.file).write_text(original)
    return Outcome(m.id, m.group, m.file, m.what, killed, by, round(time.monotonic() - started, 1), m.equivalent,
                   killers or killers_only, timed_out, tail)


def _table(outcomes: list[Outcome]) -> str:
    rows = [f"{'mutant':28s} {'group':18s} {'verdict':10s} {'s':>6s}  first failing test / why equivalent"]
    for o in outcomes:
        verdict = "killed" if o.killed else ("EQUIVALENT" if o.equivalent else "SURVIVED")
        note = o.by if o.killed else (o.equivalent or o.what)
        rows.append(f"{o.id:28s} {o.group:18s} {verdict:10s} {o.seconds:6.1f}  {note}")
    killed = sum(o.killed for o in outcomes)
    survived = [o for o in outcomes if not o.killed]
    rows.append(f"\n{len(outcomes)} mutants: {killed} killed, {len(survived)} survived "
                f"({sum(bool(o.equivalent) for o in survived)} of them judged equivalent)")
    return "\n".join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", help="mutant ids to run")
    p.add_argument("--group", nargs="*", help="groups to run")
    p.add_argument("--killers", action="store_true", help=f"also run the {len(KILLERS)} tests of KILLED_BY for each mutant")
    p.add_argument("--killers-only", action="store_true", help=f"run only the {len(KILLERS)} tests of KILLED_BY for each mutant")
    p.add_argument("--list", action="store_true", help="list the mutants and stop")
    p.add_argument("--json", help="write the outcomes to this file as they come")
    p.add_argument("--timeout", type=float, default=TIMEOUT)
    args = p.parse_args(argv)
    ids = [m.id for m in MUTANTS]
    if len(set(ids)) != len(ids):
        raise SystemExit("duplicate mutant ids")
    chosen = [m for m in MUTANTS if (not args.only or m.id in args.only) and (not args.group or m.group in args.group)]
    if args.only and len(chosen) != len(set(args.only)):
        raise SystemExit(f"unknown mutant ids: {sorted(set(args.only) - set(ids))}")
    for m in chosen:                            # every snippet must be found once before anything runs
        text = (ROOT / m.file).read_text()
        if text.count(m.old) != 1:
            raise SystemExit(f"mutant {m.id}: snippet occurs {text.count(m.old)} times in {m.file}: {m.old!r}")
    if args.list:
        for m in chosen:
            print(f"{m.id:28s} {m.group:18s} {m.file:36s} {m.what}")
        print(f"{len(chosen)} mutants")
        return 0
    os.environ.setdefault("DOBKIT_CACHE_DIR", "/tmp/dobkit-cache-mutation-probe")
    # a SIGTERM ends the probe as Ctrl-C does: through run_mutant's finally, which puts the file back
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(f"stopped by signal {signum}"))
    outcomes = []
    for m in chosen:
        o = run_mutant(m, args.killers, args.timeout, args.killers_only)
        outcomes.append(o)
        print(f"{o.id:28s} {'killed' if o.killed else 'SURVIVED':9s} {o.seconds:6.1f} s  {o.by}", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps([asdict(x) for x in outcomes], indent=1))
    print()
    print(_table(outcomes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
