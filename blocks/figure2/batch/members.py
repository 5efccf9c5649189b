"""A batch as the loop's plan over a member axis: one plan, N sets of block parameters.

Every member of a batch shares the loop's structure -- its blocks, their
kernels and the evaluation order :func:`blocks.diagram.plan.make_plan` derives -- and
the shared sources (the reference).  What differs between members are the
numbers the blocks' kernels take.  Each member's blocks are made from the
member's model objects exactly as a single run makes them
(:func:`blocks.figure2.loop.build_blocks` on the member's scenario), and their
parameters are stacked on a trailing member axis: the column layout the
kernels take (see :mod:`blocks.kernels`).  So any key that reaches a block's
parameters may vary within a batch, and nothing here names a key.

:class:`MemberLoop` evaluates the plan on rows ``(n, N)`` for the numpy batch;
the compiled batch reads each member's numbers for the traced blocks from
:attr:`MemberLoop.member_params` (:mod:`blocks.engines.compiled.batch`).
"""
from __future__ import annotations

import numbers

import control as ct
import numpy as np

from blocks.diagram.contract import contract_of, kernels_only
from blocks.diagram.plan import make_plan
from blocks.diagram.systems import observer as observer_block
from blocks.engines.divergence import state_meanings
from blocks.figure2.loop import _prepared, build_blocks, closed_loop, initial_state
from blocks.figure2.physical_bounds import batch_bounds
from blocks.kernels import lumped_disturbance
from blocks.kernels.model import with_arm
from blocks.kernels.trace import is_table
from blocks.model.noise import MeasurementNoise

__all__ = ["MemberLoop", "member_scenario", "shared_loop"]


def member_scenario(v, i: int, noisy: bool = False):
    """Member ``i`` of the variants ``v`` as a scenario holding its model objects (not its ``data``), for
    making its blocks.  With ``noisy`` a member without noise gets a zero noise, so that its loop has the
    batch's sensor (adding zero changes no number)."""
    fields = dict(v.members[i])
    if noisy and fields["noise"] is None:
        settings = v.base.data["noise"]
        n = v.base.robot.joints.count
        zero = MeasurementNoise(q_std=(0.0,) * n, dq_std=(0.0,) * n, seed=int(settings["seed"]),
                                sample_period=float(settings["sample_period"]), t_final=v.base.simulation.t_final,
                                joints=v.base.robot.joints)
        # zero samples at the batch's sample instants (a disabled noise keeps none): the members' tables align
        shape = next(nz.table.shape for nz in v.noises if nz is not None)
        object.__setattr__(zero, "_samples", np.zeros(shape))
        fields["noise"] = zero
    # the base's checked settings with the member's model objects (not a new validated scenario: the
    # member's values were checked by Variants, and the view only makes blocks)
    view = object.__new__(type(v.base))
    view.__dict__.update(v.base.__dict__)
    view.__dict__.update(fields)
    return view


def _matrix_observer(blocks: dict, s) -> dict:
    """The blocks with an observer whose kernels take ``Y`` as a matrix (one layout for every member)."""
    out = dict(blocks)
    out["observer"] = observer_block(s.nominal, s.observer_gain, s.observer_variant, matrix_gain=True,
                                     measured="_meas" if s.noise is not None else "")
    return out


def shared_loop(v, observer: bool) -> ct.InterconnectedSystem:
    """The loop whose structure every member shares: the base's, with a sensor when any member has noise and
    an observer taking ``Y`` as a matrix when any member's gain is not diagonal."""
    noisy = [i for i, nz in enumerate(v.noises) if nz is not None]
    if noisy and v.base.noise is None:
        loop = closed_loop(v.scenario(noisy[0]), observer=observer)
    else:
        loop = _prepared(v.base, observer).loop
    if observer and v.y_diag is None:
        s = loop.scenario
        parts = list(_matrix_observer({b.name: b for b in loop.syslist}, s).values())
        outputs = list(loop.output_labels)
        matrix_loop = ct.interconnect(parts, inplist=[], outlist=outputs, outputs=outputs, name=loop.name,
                                      check_unused=False)
        matrix_loop.scenario, matrix_loop.with_observer = s, loop.with_observer
        loop = matrix_loop
    return loop


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and np.array_equal(a, b)
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _is_object(value) -> bool:
    """Whether a parameter is an object the kernels read as structure (a URDF arm's ChainParams), not numbers."""
    return not isinstance(value, (tuple, np.ndarray, numbers.Real, bool, np.bool_, str, type(None)))


def _object_key(params) -> tuple:
    """Identities of the structure objects in one member's parameters: members with equal keys can share a call."""
    if isinstance(params, tuple):
        return tuple(k for p in params for k in _object_key(p))
    return (id(params),) if _is_object(params) else ()


def _stacked(block: str, where: str, values: list, column_value, objects_first: bool = False,
             source: bool = False):
    """The members' values of one parameter in the column layout: the block's own column value when all
    members agree (its tables with a member axis of 1, :func:`_shared_tables`, unless the block is a ``source``
    evaluated on rows of times), else stacked on a trailing member axis.  With ``objects_first`` a structure
    object that differs between members is taken from the first (for reading the numbers beside it)."""
    first = values[0]
    if all(_same(first, other) for other in values[1:]):
        return column_value if source else _shared_tables(column_value)
    if isinstance(first, tuple):
        fields = getattr(first, "_fields", None)
        parts = [_stacked(block, f"{where}.{fields[j]}" if fields else f"{where}[{j}]", [v[j] for v in values],
                          column_value[j], objects_first, source) for j in range(len(first))]
        return type(first)(*parts) if fields else tuple(parts)
    if objects_first and _is_object(first):
        return column_value
    if isinstance(first, (bool, np.bool_, str, type(None))) or not isinstance(first, (np.ndarray, numbers.Real)):
        differing = sorted({repr(v) for v in values})[:3]
        raise ValueError(f"block '{block}': its parameter {where} differs between members ({', '.join(differing)}) "
                         f"and shapes the loop; the members of one batch must share it")
    shapes = {np.shape(v) for v in values}
    if len(shapes) > 1:
        raise ValueError(f"block '{block}': its parameter {where} has different shapes in different members "
                         f"{sorted(shapes)}; the members of one batch must share its shape")
    return np.stack([np.asarray(v, dtype=float) for v in values], axis=-1)


def _shared_tables(column_value):
    """A parameter all members share, in the column layout, with each table in it (noise samples, (rows,
    samples)) given a member axis of 1: a table is indexed by time, not broadcast, so the one table every
    member reads gives its samples at one time as a column (rows, 1), as stacked tables give (rows, N)."""
    if isinstance(column_value, tuple):
        parts = [_shared_tables(p) for p in column_value]
        return type(column_value)(*parts) if hasattr(column_value, "_fields") else tuple(parts)
    if is_table(column_value) and column_value.ndim == 2:
        return column_value[..., None]
    return column_value


class MemberLoop:
    """The loop's plan evaluated for the N members of a batch at once: states ``(nstates, N)``.

    Parameters
    ----------
    variants : blocks.figure2.batch.Variants
    observer : bool
        With or without the disturbance observer.

    Attributes
    ----------
    loop : control.InterconnectedSystem
        The shared structure (see :func:`shared_loop`).
    plan : blocks.diagram.plan.LoopPlan
        Its evaluation plan.
    member_params : dict of str to list
        Each block's kernel parameters, one tuple per member (the one-point layout).
    sources : tuple of blocks.diagram.plan.BlockStep
        Blocks without inputs or states (the reference), shared by all members.

    Raises
    ------
    ValueError
        If a block has no kernels, or the members' blocks differ in structure (naming the block and the
        parameter).
    """

    def __init__(self, variants, observer: bool) -> None:
        v = self.v = variants
        self.observer, self.n = observer, len(v)
        self.joints = v.base.robot.joints.count
        self.loop = shared_loop(v, observer)
        self.plan = plan = make_plan(self.loop)
        noisy = "sensor" in plan.order
        matrix = observer and v.y_diag is None
        self.scenarios = [member_scenario(v, i, noisy) for i in range(self.n)]
        with kernels_only():            # the members' kernels and numbers; no python-control system each
            made = [build_blocks(s, observer=observer) for s in self.scenarios]
            if matrix:
                made = [_matrix_observer(b, s) for b, s in zip(made, self.scenarios)]
        self.member_params, self._kernels0, self._columns, self._groups = {}, {}, {}, {}
        for step in plan.steps:
            kernels = [contract_of(b[step.name]).kernels for b in made]
            if not step.kernel or any(k is None or k.output is not step.output or k.update is not step.update
                                      for k in kernels):
                raise ValueError(f"block '{step.name}' has no kernels or differs in structure between members; "
                                 f"a batch evaluates one plan for all members")
            self.member_params[step.name] = params = [k.params for k in kernels]
            self._kernels0[step.name] = kernels[0]
            # members whose blocks hold different structure objects (the nominal URDF arm of another
            # arm.nominal_mass_scale) are evaluated in groups, each group's numbers stacked as usual
            keys: dict = {}
            for m, p in enumerate(params):
                keys.setdefault(_object_key(p), []).append(m)
            if len(keys) > 1:
                self._groups[step.name] = [
                    (np.array(idx), _stacked(step.name, "params", [params[m] for m in idx], kernels[idx[0]].columns()))
                    for idx in keys.values()]
        self.sources = tuple(s for s in plan.steps if s.x.stop == s.x.start and _size(s.gather) == 0)
        names = {s.name for s in self.sources}
        self._rhs_steps = tuple(s for s in plan.rhs_steps if s.name not in names)
        self._all_steps = tuple(s for s in plan.steps if s.name not in names)
        self._source_rows = np.concatenate([np.arange(s.y.start, s.y.stop) for s in self.sources]) \
            if self.sources else np.zeros(0, dtype=int)
        labels = list(self.loop.output_labels)
        self.signal_rows = {}
        for label, row in zip(labels, plan.out_index):
            self.signal_rows.setdefault(label.split("[")[0], []).append(int(row))
        self.state_meanings = state_meanings(self.loop)
        arm = self.arm = v.base.robot
        if arm.stacks_constants:
            self.k_true = np.stack([r.kernel_params() for r in v.robots], axis=-1)            # (k, N)
            self.k_nominal = np.stack([r.kernel_params() for r in v.nominals], axis=-1)
            self._lumped = [(slice(None), self.k_nominal)]
        else:
            # structure objects are not stacked: the true arm is the members' shared one (its keys cannot vary
            # within a batch), the nominal arms are taken group by group
            if any(r is not arm for r in v.robots):
                raise ValueError("the members of a batch of a URDF arm must share the true arm")
            self.k_true = arm.kernel_params()
            groups: dict = {}
            for m, nominal in enumerate(v.nominals):
                groups.setdefault(id(nominal), (nominal, []))[1].append(m)
            self._lumped = [(np.array(idx), nominal.kernel_params()) for nominal, idx in groups.values()]
        self._lumped_rows = with_arm(lumped_disturbance, arm)
        self.kin = arm.tool_params()                        # the tool point is the shared arm's
        self.nx = plan.nstates

    def column_params(self, name: str) -> tuple:
        """Block ``name``'s parameters over the members: the column layout, a trailing member axis where the
        members differ (stacked on first use; the compiled batch reads :attr:`member_params` instead)."""
        found = self._columns.get(name)
        if found is None:
            found = self._columns[name] = _stacked(name, "params", self.member_params[name],
                                                   self._kernels0[name].columns(), objects_first=name in self._groups,
                                                   source=any(s.name == name for s in self.sources))
        return found

    def bounds(self, labels=None):
        """Every member's divergence bounds (nstates, N) in the order of ``labels`` (default: this loop's states;
        :func:`blocks.figure2.physical_bounds.batch_bounds`)."""
        return batch_bounds(self, self.state_meanings if labels is None else labels)

    # -- what the divergence bounds read (blocks.figure2.physical_bounds.batch_bounds) -------------------------------------
    @property
    def disturbance(self):
        """The external disturbance's parameters over the members (the plant's)."""
        return self.column_params("plant")[1]

    @property
    def gain(self) -> np.ndarray:
        """The observer gains over the members: diagonals (n, N) or matrices (n, n, N)."""
        v = self.v
        y = self.column_params("observer")[1] if self.observer else (v.y_diag if v.y_diag is not None else v.y_full)
        return np.array(np.broadcast_to(y, np.shape(y)[:-1] + (self.n,)))

    # -- start and sources ----------------------------------------------------------------------------------------
    def initial_state(self) -> np.ndarray:
        """Every member's start state (nstates, N), as a single run of that member starts."""
        return np.column_stack([initial_state(self.loop, s) for s in self.scenarios])

    def source_table(self, times: np.ndarray) -> np.ndarray:
        """The shared sources' outputs at ``times``: shape (len(times), rows, 1)."""
        times = np.asarray(times, dtype=float)
        rows = [np.asarray(s.output(times, np.zeros((0, times.size)), np.zeros((0, times.size)),
                                    *self.column_params(s.name)), dtype=float).reshape(-1, times.size)
                for s in self.sources]
        table = np.vstack(rows) if rows else np.zeros((0, times.size))
        return np.ascontiguousarray(table.T[:, :, None])

    # -- the right-hand side ---------------------------------------------------------------------------------------
    def rhs(self, t: float, x: np.ndarray, src: np.ndarray, record: dict | None = None) -> np.ndarray:
        """State derivative (nstates, N) at time ``t`` with the sources' outputs ``src`` (rows, 1) there.

        With ``record`` (a dict) every block's outputs are evaluated and the
        loop's output signals stored in it by name, rows (n, N).
        """
        plan = self.plan
        y = np.empty((plan.nsignals, self.n))
        y[plan.copy_y] = x[plan.copy_x]
        y[self._source_rows] = src
        groups = self._groups
        for s in (self._all_steps if record is not None else self._rhs_steps):
            if s.name in groups:
                out = y[s.y]
                for idx, params in groups[s.name]:
                    out[:, idx] = s.output(t, x[s.x][:, idx], y[s.gather][:, idx], *params)
            else:
                y[s.y] = s.output(t, x[s.x], y[s.gather], *self.column_params(s.name))
        dx = np.empty_like(x)
        for s in plan.updates:
            if s.name in groups:
                rate = dx[s.x]
                for idx, params in groups[s.name]:
                    rate[:, idx] = s.update(t, x[s.x][:, idx], y[s.gather][:, idx], *params)
            else:
                dx[s.x] = s.update(t, x[s.x], y[s.gather], *self.column_params(s.name))
        if record is not None:
            record.update({name: y[rows] for name, rows in self.signal_rows.items()})
            record.setdefault("q_meas", record["q"])
            record.setdefault("dq_meas", record["dq"])
        return dx

    def lumped(self, q, dq, tau, tau_dis) -> np.ndarray:
        """The lumped disturbance ``d`` (n, ..., N) of every member (Eq. 2-3, relative to its nominal model)."""
        if len(self._lumped) == 1:
            return self._lumped_rows(self.k_true, self._lumped[0][1], q, dq, tau, tau_dis)
        d = np.empty(np.broadcast_shapes(np.shape(q), np.shape(tau)))
        for idx, k_nominal in self._lumped:
            d[..., idx] = self._lumped_rows(self.k_true, k_nominal, q[..., idx], dq[..., idx], tau[..., idx],
                                            tau_dis[..., idx])
        return d


def _size(gather) -> int:
    if isinstance(gather, slice):
        return gather.stop - gather.start
    return int(np.size(gather))
