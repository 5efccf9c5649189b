# ruff: noqa: E501 -- the mutant table keeps each snippet on one line, as it is in the file
"""A mutation probe of dobkit's core maths and rules: which wrong changes does the test suite let through?

Each mutant is one small wrong change to one product file (a sign, a factor, a transposed matrix, an
off-by-one, ``<`` for ``<=``, a dropped term, a swapped argument, a wrong unit): an exact original snippet,
which must occur once in the file, and its replacement.  For each mutant the probe writes the change, runs
the tests named for it (``python -m pytest -x -q -n 0``), records whether any test failed (the mutant is
*killed*) or all passed (it *survived*), and puts the file back byte for byte -- also on Ctrl-C or SIGTERM.

Run it from the repository's top level::

    python tests/mutation_probe.py                 # every mutant, the tests named with it
    python tests/mutation_probe.py --killers       # and tests/test_mutation_killers.py after those
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
``equivalent``); ``tests/test_mutation_killers.py`` kills the other 20.  ``--killers`` must therefore
report 105 killed and those 2 equivalent.

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
KILLERS = "tests/test_mutation_killers.py"
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
KIN = ("tests/test_kinematics.py", "tests/test_dynamics.py", "tests/test_arm_model.py", "tests/test_pinned_metrics.py")
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
RUNAWAY = ("tests/test_fmu_master_findings.py", "tests/test_one_monitor.py")
RUN_LIMITS = ("tests/test_one_monitor.py::test_runs_beyond_the_budget_are_refused_before_they_start_naming_the_key",
              "tests/test_compiled_row_kernels.py::test_rates_equal_the_numpy_way_and_pinocchio",
              "tests/test_sweep_limits.py", "tests/test_one_monitor.py")
SCHEDULE = ("tests/test_batch.py", "tests/test_sweep_limits.py",
            "tests/test_one_monitor.py::test_runs_beyond_the_budget_are_refused_before_they_start_naming_the_key")
DSTAB = ("tests/test_sampled_stability.py", "-k", "not nonlinear and not just_inside and not dobkit_simulate",
         "tests/test_digital_gravity.py", "tests/test_analysis_n_joints.py::test_euler_limit_is_ts_lambda_max_two")
BUDGET = ("tests/test_budget.py",)
LINEAR = ("tests/test_analysis_linear.py", "tests/test_pinned_linear.py", "tests/test_analysis_observer.py",
          "tests/test_analysis_n_joints.py")
METRICS = ("tests/test_pinned_metrics.py", "tests/test_pinned_signals.py")
FMU_C = ("tests/test_one_source.py::test_the_c_plant_matches_the_reference", "tests/test_fmu_end_stops.py",
         "tests/test_fmu_export.py::test_co_simulation_follows_the_input_slope_and_gives_exact_output_derivatives")
END_STOPS = ("tests/test_fmu_end_stops.py",)


def M(id, group, file, old, new, tests, what, equivalent=""):      # noqa: N802 -- a table row, read as such
    return Mutant(id, group, file, old, new, tuple(tests), what, equivalent)


ARM, DYNPY, KK, KINPY = "blocks/kernels/arm.py", "blocks/dynamics.py", "blocks/kernels/kinematics.py", "blocks/kinematics.py"
LAW, DK, CH, IKF = "blocks/kernels/laws.py", "blocks/kernels/disturbance.py", "blocks/kernels/chain.py", "blocks/arms/ik.py"
DIV, MON, RL, DS = "blocks/divergence.py", "blocks/monitor.py", "blocks/run_limits.py", "blocks/digital_stability.py"
BU, ME, ES, PC = "blocks/budget.py", "blocks/metrics.py", "fmu/end_stops.py", "fmu/c/plant_model.c"
AL, BW = "analysis/linear/arm_linear.py", "analysis/linear/bandwidth.py"
SC = "blocks/batch/schedule.py"

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
    M("law-obs-bias-sign", "laws", LAW, "(y_dq + z) - bias_forces(k, q, dq)", "(y_dq + z) + bias_forces(k, q, dq)", LAWS,
      "observer: + h in the residual"),
    M("law-obs-eq16-sign", "laws", LAW, "- eq16_weight * y_dq", "+ eq16_weight * y_dq", LAWS,
      "printed Eq. 16 variant: + Y q'"),
    M("law-estimate-sign", "laws", LAW, "return gain_times(gain, dq) + z", "return gain_times(gain, dq) - z", LAWS,
      "d_hat = Y q' - z"),
    M("law-gain-transpose", "laws", LAW, "return (gain * v).sum(axis=1)", "return (gain * v).sum(axis=0)", LAWS,
      "full gain: Y^T v for Y v"),
    M("law-lumped-true", "laws", LAW, "return mass_times(k_nominal, q, ddq)", "return mass_times(k_true, q, ddq)", LAWS,
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
    M("dist-tissue-depth", "disturbances", DK, "depth = skin_height - tool_position(kin, q)[2]",
      "depth = tool_position(kin, q)[2] - skin_height", DIST, "tissue depth with the wrong sign"),
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
      TRACE, "traced calls (codegen.ARM_CALLS, off by default): sin and cos of a revolute joint swapped"),
    M("chain-trace-lower-order", "chain", CH, "        for j in range(i + 1):\n            M[i][j] = M[j][i] = next(values)",
      "        for j in reversed(range(i + 1)):\n            M[i][j] = M[j][i] = next(values)", TRACE,
      "traced calls (codegen.ARM_CALLS): a row of M's lower triangle read in reverse"),
    # ---- IK derivatives of a URDF arm's tool point -------------------------------------------------------------
    M("ik-jrate-factor", "ik", IKF, "return ((plus - minus) / 4.0).T", "return ((plus - minus) / 2.0).T", IK,
      "J' by polarisation: /2 for /4"),
    M("ik-ddq-bias-sign", "ik", IKF, "pinv @ (ddp - Jdot @ dq)", "pinv @ (ddp + Jdot @ dq)", IK, "q'' = J+ (p'' + J' q')"),
    M("ik-ddq-nullspace", "ik", IKF, "+ (np.eye(arm.n) - pinv @ J) @ (Jdot.T", "+ 0.0 * (np.eye(arm.n) - pinv @ J) @ (Jdot.T",
      IK, "q'' without the derivative of J+ in the null space (a redundant arm)"),
    M("ik-sigma-largest", "ik", IKF, "np.linalg.eigvalsh(JJt)[0]", "np.linalg.eigvalsh(JJt)[-1]", IK,
      "singularity check on the largest singular value"),
    # ---- divergence rule ---------------------------------------------------------------------------------------
    M("div-pos-abs", "divergence", DIV, "pos = np.abs(q_ref).max(axis=0)", "pos = q_ref.max(axis=0)", DIVERGENCE,
      "position bound from max q_ref, not max |q_ref|"),
    M("div-violated-abs", "divergence", DIV, "return ~(np.abs(np.asarray(x, dtype=float)) <= self.bounds)",
      "return ~(np.asarray(x, dtype=float) <= self.bounds)", DIVERGENCE, "a large negative value never diverges"),
    M("div-violated-lt", "divergence", DIV, "return ~(np.abs(np.asarray(x, dtype=float)) <= self.bounds)",
      "return ~(np.abs(np.asarray(x, dtype=float)) < self.bounds)", DIVERGENCE, "a value at its bound diverges"),
    M("div-force-no-external", "divergence", DIV,
      "external = _external_disturbance(kernels, tool_kernels)\n    forces = np.abs(external(0.0, q0, dq0, disturbance)) + ",
      "external = _external_disturbance(kernels, tool_kernels)\n    forces = 0.0 * np.abs(external(0.0, q0, dq0, disturbance)) + ",
      DIVERGENCE, "force bound without the external disturbance"),
    M("div-z-no-reach", "divergence", DIV, "return (force + reach, f\"observer z[{i}]", "return (force, f\"observer z[{i}]",
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
      DSTAB + ("tests/test_pinned_delay.py",), "delay buffer: the last shift missing (delay >= 2)"),
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
    tests = (KILLERS,) if killers_only else (m.tests + ((KILLERS,) if killers else ()))
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
    p.add_argument("--killers", action="store_true", help=f"also run {KILLERS} for each mutant")
    p.add_argument("--killers-only", action="store_true", help=f"run only {KILLERS} for each mutant")
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
