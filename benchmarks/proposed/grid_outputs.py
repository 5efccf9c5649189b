"""Proposed: evaluate the loop's outputs on the whole time grid in one pass per block.

Not part of the package; ``benchmarks/bench_fastpath.py --proposed`` times it.
After the solver, :func:`dobkit.blocks.loop.simulate` evaluates the loop's
outputs at every grid point (2001 on the paper run), each a full pass over the
blocks: 15-25 % of the fast path's time, while a hand-written loop computes
the same signals with a few vectorised calls.  The blocks' maths
(:mod:`dobkit.blocks.dynamics`) already takes a leading batch axis; only the
block output functions are written for one time point.

The change this file demonstrates:

* ``dobkit/blocks/systems.py``: each factory also sets ``sys.output_columns``,
  the block's output function for column-stacked signals -- ``t`` (T,),
  ``x`` (nstates, T), ``u`` (ninputs, T) -> (noutputs, T) -- written with the
  same dynamics functions as the point version.  :func:`attach_column_outputs`
  below writes them for the blocks of :func:`dobkit.blocks.closed_loop` from
  the outside; inside the factories they would come from the closures.
* ``dobkit/blocks/fastsim.py``: ``CompiledLoop.outputs_on_grid(t, X)`` walks the
  block order once with (n, T) arrays when every block has ``output_columns``,
  and falls back to the point-by-point loop otherwise (an FMU plant).
* ``dobkit/blocks/loop.py``: ``_integrate_compiled`` calls
  ``compiled.outputs_on_grid(t_grid, sol.y)`` instead of
  ``np.column_stack([compiled.output(t, sol.y[:, k]) ...])``.

The outputs are the same numbers to rounding (the reference's vectorised and
scalar inverse kinematics differ in the last bits); the test in
``bench_fastpath.py`` checks them against the point-by-point pass.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from dobkit.blocks.disturbances import external_disturbance
from dobkit.blocks.dynamics import coriolis_vector, gravity, inertia
from dobkit.blocks.loop import DIVERGENCE_BOUND, SimulationError, _check_finite

from .fastsim import PlannedLoop

__all__ = ["attach_column_outputs", "GridLoop", "integrate_with_grid_outputs"]

J = 4


def attach_column_outputs(loop) -> None:
    """Give every block of a dobkit loop an ``output_columns`` function (see the module docstring)."""
    s = loop.scenario
    for block in loop.syslist:
        if block.name == "trajectory":
            traj = block.trajectory
            block.output_columns = lambda t, x, u, p, traj=traj: np.concatenate([a.T for a in traj.evaluate(t)])
        elif block.name == "plant" and hasattr(block, "disturbance_spec"):
            spec, robot = block.disturbance_spec, block.robot_parameters
            block.output_columns = lambda t, x, u, p, spec=spec, robot=robot: np.concatenate(
                [x, external_disturbance(t, x[:J].T, x[J:].T, spec, robot).T])
        elif block.name == "observer":
            Y = block.gain
            block.output_columns = lambda t, x, u, p, Y=Y: Y @ u[2 * J:3 * J] + x
        elif block.name == "controller":
            Kp, Kd, nominal = block.gains["kp"], block.gains["kd"], s.nominal
            with_obs = block.ninputs == 6 * J

            def controller_columns(t, x, u, p, Kp=Kp, Kd=Kd, nominal=nominal, with_obs=with_obs):
                q_ref, dq_ref, ddq_ref, q, dq = (u[i * J:(i + 1) * J] for i in range(5))
                v = ddq_ref + Kd @ (dq_ref - dq) + Kp @ (q_ref - q)
                tau = (inertia(q.T, nominal) @ v.T[..., None])[..., 0] + coriolis_vector(q.T, dq.T, nominal) \
                    + gravity(q.T, nominal)
                return tau.T - (u[5 * J:6 * J] if with_obs else 0.0)
            block.output_columns = controller_columns
        elif block.name == "sensor":
            noise = s.noise

            def sensor_columns(t, x, u, p, noise=noise):
                n_q, n_dq = noise.sample(t)
                return np.concatenate([u[:J] + n_q.T, u[J:] + n_dq.T])
            block.output_columns = sensor_columns


class GridLoop(PlannedLoop):
    """:class:`PlannedLoop` with ``outputs_on_grid``: one pass per block over the whole grid."""

    def outputs_on_grid(self, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The loop's outputs (its ``outlist``) at times ``t`` (T,) for states ``X`` (nstates, T)."""
        blocks = self._blocks
        if not self._planned or not all(hasattr(b, "output_columns") for b in blocks):
            return np.column_stack([self.output(tk, X[:, k]) for k, tk in enumerate(t)])
        Y = np.zeros((self._n_out_total, t.size))
        for k, (_fn, params, xs, idx, ys) in zip(self._order, self._plan):
            Y[ys] = blocks[k].output_columns(t, X[xs], Y[idx], params)
        return Y[self._out_idx]


def integrate_with_grid_outputs(loop, x0, t_grid, sim, progress):
    """``dobkit.blocks.loop._integrate_compiled`` with the grid-output pass (same arguments and returns)."""
    attach_column_outputs(loop)
    compiled = GridLoop(loop)

    def diverged(t, x):
        return DIVERGENCE_BOUND - np.max(np.abs(x))
    diverged.terminal = True

    sol = solve_ivp(compiled.rhs, (0.0, t_grid[-1]), x0, method=sim.method, t_eval=t_grid, rtol=sim.rtol,
                    atol=sim.atol, max_step=sim.max_step, events=diverged)
    if sol.status != 0:
        raise SimulationError(f"scenario '{loop.scenario.name}': {sol.message}")
    _check_finite(t_grid, sol.y, loop.scenario)
    return sol.y, compiled.outputs_on_grid(t_grid, sol.y)
