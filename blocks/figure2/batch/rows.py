"""A batch as rows of numbers: each member's ``theta``, start state and bounds filled from the variants' columns.

The compiled batch runs one generated module for every member, each with its
own parameter vector ``theta`` (:mod:`blocks.engines.compiled.batch`).  Making each
member's blocks to read their numbers (:class:`blocks.figure2.batch.members.MemberLoop`)
costs about 0.5 ms of Python per member.  Here the blocks are made for a few
*probe* members only: the first member, and for every number of every varied
key one member that differs from the first in that number alone (the value of
the member that differs most there).  The differences give, once per batch,
which ``theta`` columns (and start-state entries) each variant key moves and
by how much; every member's row is then the first member's plus that map
applied to its own values, one matrix product for the whole batch.

That is exact when the numbers the blocks hold are affine in the varied
values, as they are for :data:`blocks.figure2.batch.variants.COLUMN_KEYS` (Kp, Kd,
the disturbance's numbers, and the nominal arm's constants, Eq. 5-7, which are
sums of masses and inertias times the scales).  It is checked, not assumed:
members far from the first (the last one and the middle one, where every key
differs at once) are also made block by block and their rows compared with
the map's, entry by entry within :data:`TRACE_RTOL` of the entry's size; a
batch that does not pass falls back to making every member's blocks.  The
divergence bounds, which are not affine (largest force at the start), are
computed from the filled rows over all members at once
(:func:`blocks.figure2.physical_bounds.batch_bounds`).
"""
from __future__ import annotations

import numbers
import types

import numpy as np

from blocks.figure2.batch.members import MemberLoop
from blocks.figure2.batch.variants import Variants, nominal_values
from blocks.figure2.physical_bounds import batch_bounds
from blocks.kernels.trace import Frozen, is_table

__all__ = ["MemberRows", "member_rows"]


def member_rows(v: Variants, observer: bool):
    """The batch's members as :class:`MemberRows` when their values came as checked columns
    (:attr:`Variants.columns`) and the trace holds, else as a :class:`~blocks.figure2.batch.members.MemberLoop`."""
    if getattr(v, "columns", None) is not None and len(v) > 3:
        rows = MemberRows.traced(v, observer)
        if rows is not None:
            return rows
    return MemberLoop(v, observer)


class MemberRows:
    """Each member's numbers of the compiled batch as rows: ``theta`` (N, p), start states (N, nstates), bounds.

    Made by :meth:`traced`; reads like :class:`~blocks.figure2.batch.members.MemberLoop` where the compiled batch reads
    (``loop``, ``plan``, ``joints``, ``n``, ``arm``, ``kin``, ``observer``).
    """

    def __init__(self, v: Variants, observer: bool, probes: MemberLoop, theta: np.ndarray, x0: np.ndarray,
                 slices: dict) -> None:
        self.v, self.observer, self.n = v, observer, len(v)
        self.loop, self.plan, self.joints = probes.loop, probes.plan, probes.joints
        self.arm, self.kin = probes.arm, probes.kin
        self._theta, self._x0, self._probes, self._slices = theta, x0, probes, slices

    @classmethod
    def traced(cls, v: Variants, observer: bool) -> MemberRows | None:
        """The rows of ``v`` by the trace of the module docstring, or None when the trace does not hold (or
        the compiled engine cannot take the loop: then the caller's path says why)."""
        from blocks.engines.compiled.batch import _member_theta
        from blocks.engines.compiled.codegen import CompiledUnavailable
        from blocks.engines.compiled.engine import CompiledLoopEngine
        columns, N = v.columns, len(v)
        first = {k: c[0] for k, c in columns.items()}
        picked = [0]
        records = [_record(first)]
        for key, col in columns.items():
            flat = col.reshape(N, -1)
            for j in range(flat.shape[1]):
                far = int(np.argmax(np.abs(flat[:, j] - flat[0, j])))
                if flat[far, j] == flat[0, j]:
                    continue                    # the same in every member: nothing to trace
                value = flat[0].copy()
                value[j] = flat[far, j]
                records.append(_record(first | {key: value.reshape(col.shape[1:])}))
        n_probes = len(records)
        checked = sorted({N - 1, N // 2} - {0})
        records += [_record({k: c[m] for k, c in columns.items()}) for m in checked]
        picked += checked
        try:
            probes = MemberLoop(Variants(v.base, records), observer)
            engine = CompiledLoopEngine(probes.loop)
            exact = np.hstack([_member_theta(engine, probes), probes.initial_state().T])     # (probes, p + nstates)
        except (CompiledUnavailable, ValueError):
            return None
        # the numbers each row entry may be: the varied values, and the nominal arm's constants made from them
        probe_columns = {k: np.array([np.asarray(r[k], dtype=float) for r in records]) for k in columns}
        candidates, everyone = _sources(v.base, probe_columns), _sources(v.base, columns)
        rows = np.empty((N, exact.shape[1]))
        for c in range(exact.shape[1]):
            col = exact[:, c]
            if np.all(col == col[0]):
                rows[:, c] = col[0]             # no varied value moves it
                continue
            found = next((name for name, values in candidates.items() if np.array_equal(values, col)), None)
            if found is None:
                return None                     # an entry the trace cannot name: every member's blocks are made
            rows[:, c] = everyone[found]
        if not np.array_equal(rows[[0] + checked], exact[[0] + list(range(n_probes, len(records)))]):
            return None
        p = engine.theta.size
        return cls(v, observer, probes, np.ascontiguousarray(rows[:, :p]), np.ascontiguousarray(rows[:, p:]),
                   engine.program.theta_slices)

    # -- what the compiled batch reads ---------------------------------------------------------------------------
    def theta(self, engine) -> np.ndarray:
        """Every member's ``theta`` (N, p) in the order ``engine``'s program reads it."""
        if engine.program.theta_slices != self._slices:
            raise ValueError("the rows were traced for another program")
        return self._theta

    def start_states(self) -> np.ndarray:
        """Every member's start state (N, nstates), as its single run starts."""
        return self._x0

    def bounds(self, labels):
        """Every member's divergence bounds in the order of ``labels`` (:func:`blocks.figure2.physical_bounds.batch_bounds`),
        from the members' plant and observer numbers in the rows."""
        probes = self._probes
        plant = _filled(probes.member_params["plant"][0], self._theta[:, self._slices["plant"]])
        gain = _filled(probes.member_params["observer"][0], self._theta[:, self._slices["observer"]])[1] \
            if self.observer else probes.gain[..., :1]
        view = types.SimpleNamespace(v=self.v, joints=self.joints, k_true=plant[0], disturbance=plant[1],
                                     arm=self.arm, n=self.n, observer=self.observer, gain=gain)
        return batch_bounds(view, labels)


def _record(values: dict) -> dict:
    return {k: (np.asarray(v).tolist()) for k, v in values.items()}


def _sources(base, columns: dict) -> dict[str, np.ndarray]:
    """The numbers a member's row entries may be, by name, each (N,): every element of every varied key, and
    when the nominal arm's scales vary its kernel constants made as each member's arm makes them, the same
    operations on all members at once (and the observer gain from a bandwidth through the arm's inertia kernel)."""
    out = {}
    for key, col in columns.items():
        flat = col.reshape(len(col), -1)
        for j in range(flat.shape[1]):
            out[f"{key}[{j}]"] = flat[:, j]
        if col.ndim == 1:                   # a number for every joint (a gain given as one number)
            out[key] = col
    scales = {k.split(".", 1)[1]: c for k, c in columns.items() if k.startswith("nominal_scale.")}
    if scales:
        # the nominal arms' constants in the model's own operations over all members (as each member's arm makes
        # them: blocks.model.arm.ArmModel.stacked_kernel_params), one source per constant
        k = base.nominal.stacked_kernel_params(nominal_values(base, scales))             # (p, N)
        N = k.shape[1]
        out.update({f"nominal.k[{j}]": k[j] for j in range(k.shape[0])})
        omega = base.data["gains"].get("observer_bandwidth")
        if omega is not None:
            # Y = omega M^(q0) of each member's nominal arm (blocks.scenarios.scenario_arm.observer_gain_from_bandwidth):
            # the arm's own inertia kernel over the members' columns, each entry and its negative
            q0 = base.initial["q"]
            if q0 is None:
                q0 = np.asarray(base.trajectory.evaluate(0.0)[0], dtype=float)
            q0 = np.repeat(np.asarray(q0, dtype=float)[:, None], N, axis=1)
            M = np.asarray(base.nominal.kernels.inertia_matrix(k, q0), dtype=float)      # (N, n, n)
            for i in range(M.shape[1]):
                for j in range(M.shape[2]):
                    out[f"observer.Y[{i},{j}]"] = float(omega) * M[:, i, j]
                    out[f"observer.Y[{i},{j}].negative"] = float(omega) * -M[:, i, j]
    return out


def _filled(template, values: np.ndarray):
    """Parameters shaped as ``template`` (one member's, the order of :func:`blocks.kernels.trace.param_values`)
    with each number replaced by its column of ``values`` (N, count): arrays gain a trailing member axis (the
    column layout the numpy kernels take)."""
    out, used = _fill(template, values, 0)
    if used != values.shape[1]:
        raise ValueError(f"parameters hold {used} numbers, the rows {values.shape[1]}")
    return out


def _fill(template, values: np.ndarray, at: int):
    if isinstance(template, (bool, np.bool_, str, type(None), Frozen)) or isinstance(template, numbers.Integral) \
            or is_table(template):
        return template, at
    if isinstance(template, numbers.Real):
        return values[:, at].copy(), at + 1
    if isinstance(template, np.ndarray):
        size = template.size
        return values[:, at:at + size].T.reshape(template.shape + (values.shape[0],)), at + size
    if isinstance(template, tuple):
        parts = []
        for item in template:
            part, at = _fill(item, values, at)
            parts.append(part)
        return (type(template)(*parts) if hasattr(template, "_fields") else tuple(parts)), at
    return template, at
