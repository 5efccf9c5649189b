"""Batched simulation: N variants of one scenario, each member a row of numbers, members run in parallel.

A batch is a base :class:`~blocks.scenarios.scenario.Scenario` and N *variants*,
each a mapping from dotted scenario keys (``"gains.kp"``, ``"nominal_scale.m1"``,
``"disturbance.f_r"``, ``"noise.seed"``, ...; see :data:`BATCH_KEYS`) to that
member's value.  A batch is the loop's plan over a member axis
(:mod:`blocks.figure2.batch.members`): each member's blocks are made as its single run
makes them and their kernel parameters stacked per member, so every key that
reaches only some block's numbers may vary (:data:`BATCH_KEYS`, computed);
what shapes the shared part -- the trajectory, the kinematic lengths it is
solved for, the disturbance kinds, the noise sample period, the solver grid
(:data:`SHARED_KEYS`, :data:`SHARED_SECTIONS`) -- is refused with the reason.
The reference is evaluated once for the whole batch.

::

    from blocks import load_scenario
    from blocks.figure2.batch import simulate_batch
    base = load_scenario("paper")
    variants = [{"gains.kp": kp, "nominal_scale.m1": s} for kp in (100, 180) for s in (0.8, 1.2)]
    result = simulate_batch(base, variants)
    result.metrics["rms_position_error"]          # shape (4 members, n joints): n = 4 for the paper's arm

Accuracy
--------
With the compiled engine (the default when numba is installed) each member
is integrated exactly as its single compiled run is
(:func:`blocks.simulate` with ``engine="compiled"``): Dormand-Prince 5(4)
with its own step control and the scenario's ``rtol``, ``atol`` and
``max_step``, its states on the output grid from each step's dense output,
and its outputs and metrics there as the single run computes them.  Its
numbers equal that run's to rounding (bit for bit on the paper scenario):
a member's numbers do not depend on its batch, its slice or the workers.
The members run in parallel on every core (``workers``).

``method="RK4"`` (the numpy batch's only method, and the default when a
step schedule is asked for with ``substeps`` or ``breakpoints``, as sweeps
and tuning do) integrates every member with the classic fixed-step
Runge-Kutta method on one shared step schedule: the output grid
(``simulation.output_step``, divided by ``substeps``) joined with every time
where the right-hand side is not smooth in time -- the phase boundaries of the
laceration path, where the reference's third derivative jumps, and the sample
times of measurement noise, where its slope jumps -- so RK4 keeps its fourth
order.  By default :func:`auto_substeps` picks the step from the fastest
closed-loop rate (``h * rate <= 0.3``) and the reference's phase length; on
the paper scenario that is the output step itself (5 ms).

Measured against DOP853 runs at ``rtol = 1e-11`` on 20 Monte Carlo variants
of the paper scenario over its 10 s (masses and inertias +-10 %, Kp 120-250,
Kd 30-45, Eq. 4 amplitudes x0.5-2), the RK4 batch's position error is at most
1.1e-7 (:data:`STATE_ERROR`, 2e-7, is tested), while a single run with the
paper's RK45 at ``rtol = 1e-6``, ``atol = 1e-8`` errs by up to 1.5e-6: an RK4
member's difference from its single run is mostly the single run's own error
(over 140 such draws it reached 1.8e-6).
Stated tolerance of the RK4 batch, tested member by member against
:func:`~blocks.figure2.loop.simulate` on gain, model-mismatch, observer,
disturbance (Eq. 4, friction), initial-state and noise variants: positions
agree within :data:`STATE_ATOL` (3e-6 rad or m over 10 s; within 1e-6 on the
2 s runs of the tests) and every metric within
``METRIC_RTOL * |value| + METRIC_ATOL`` (1e-3 relative plus 1e-6 in the
metric's unit).  With tissue contact the right-hand side has kinks
in the state (contact on and off), where RK4 loses its order: there the
agreement is :data:`STATE_ATOL_CONTACT` (1e-5).  A larger ``substeps`` refines
any run.

With RK4 all members share one step schedule, the finest any of them needs, so a
member's numbers depend on its batch only through that schedule: batches run
with the same ``substeps`` and ``breakpoints`` (as the sweep runner does, and
as ``workers > 1`` does for its slices) give every member identical numbers.

Any arm
-------
A scenario with ``[arm]`` (a URDF arm, :mod:`blocks.model.urdf`) batches too: its
members are made from their own validated scenarios
(:meth:`Scenario.with_changes <blocks.scenarios.scenario.Scenario.with_changes>`, about
3 ms of CPU each), so per-joint values have the arm's n entries and the
observer gain from ``gains.observer_bandwidth`` is the single run's;
``arm.nominal_mass_scale`` may vary (the numpy batch evaluates the members in
groups of equal nominal arms; the compiled batch, whose generated code holds
the arm's model as constants, runs one nominal arm and says so), the arm's
other keys may not (:data:`SHARED_KEYS`).  ``engine="auto"`` compiles a batch
by the rule of single runs (:data:`blocks.engines.compiled.compile_estimate.AUTO_COMPILE_SECONDS`).
The numpy batch of a URDF arm does its kernels' arithmetic in Python per
element (seconds per member-independent 10 s run): prefer the compiled one.

Cost
----
On the paper's arm, variants given as numbers of
:data:`~blocks.figure2.batch.variants.COLUMN_KEYS` (model mismatch, Kp, Kd, the
disturbance's numbers) are checked as whole columns and the compiled batch
fills each member's parameter row from a trace made on a few probe members
(:mod:`blocks.figure2.batch.rows`): 1000 members are set up in a few hundredths of
a second.  Other variants make each member's blocks once, as its single run
makes them but without python-control systems
(:func:`blocks.diagram.contract.kernels_only`): about 0.5 ms of CPU per member.
Only what is asked for is kept: metrics are accumulated at the output grid
points while integrating, and full signals are stored only when named in
``signals``.  Measurement noise is stored at every sample time: about
``16 * 8 * t_final / sample_period`` bytes per noise table (1.3 MB for 10 s
at 1 kHz), one table for every member without a ``noise`` key of its own
(the base's) and one per member with its own; batches of more than
:data:`blocks.engines.compiled.batch.NOISE_CHUNK` tables are integrated in chunks of
that many members.

Observer gain
-------------
With ``gains.observer_bandwidth`` (``Y = omega M^(q0)``) each member's ``Y``
is made as its single run makes it: from its own nominal arm (``robot.*``,
``nominal_scale.*``), its own start ``initial.q`` and its own bandwidth; a
member giving ``gains.observer`` beside a bandwidth is refused as its single
run is.
"""
from __future__ import annotations

from blocks.figure2.batch.schedule import auto_substeps, fastest_rate, noise_breakpoints, step_schedule
from blocks.figure2.batch.simulate import (
                       METRIC_ATOL,
                       METRIC_RTOL,
                       METRICS,
                       SIGNALS,
                       STATE_ATOL,
                       STATE_ATOL_CONTACT,
                       STATE_ERROR,
                       BatchResult,
                       simulate_batch,
)
from blocks.figure2.batch.variants import BATCH_KEYS, COLUMN_KEYS, SHARED_KEYS, SHARED_SECTIONS, Variants, shared_reason

__all__ = ["BATCH_KEYS", "COLUMN_KEYS", "SHARED_KEYS", "SHARED_SECTIONS", "shared_reason",
           "METRICS", "SIGNALS", "STATE_ATOL", "STATE_ATOL_CONTACT", "STATE_ERROR", "METRIC_RTOL",
           "METRIC_ATOL",
           "Variants", "BatchResult", "simulate_batch", "step_schedule",
           "auto_substeps", "noise_breakpoints", "fastest_rate"]
