"""The compiled engine's integrators, as source the code generator puts into each loop's module.

This file is not imported as a module: :mod:`blocks.engines.compiled.codegen`
places its text before the generated functions of one loop
(``loop_sources``, ``loop_rhs``, ``loop_outputs``, ``loop_rhs_rows``,
``loop_outputs_rows``, ``member_ext``) and compiles the whole with numba
(each loop structure gets its own module, cached on disk).

``dp_step`` is one step of the Dormand-Prince 5(4) pair with the step-size
control of :class:`scipy.integrate.RK45` (same tableau, error norm, safety factor 0.9,
step factors 0.2 to 10, no growth right after a rejected step, initial step
of Hairer, Norsett and Wanner II.4, ``max_step``), written once: the
continuous driver ``dopri_run`` and the sampled driver ``sampled_ticks``
both step through it, each integrating the module's ``step_rhs``.  Its
quartic dense output gives the states on the output grid as
:func:`blocks.engines.integrate.integrate_on_grid` does.  Each accepted step is
checked against the divergence bound.  ``grid_outputs`` evaluates the
outputs (and row groups) on the grid afterwards.  ``rk4_batch`` is the
batch's fixed-step RK4 on a shared step schedule, members in parallel, with
the tracking metrics' sums accumulated per member as it goes.
"""
import math

import numpy as np

try:
    from numba import prange
except ImportError:         # the text is compiled with numba only; this keeps the file importable
    prange = range

#: Functions compiled with ``parallel=True``.
PARALLEL = ("rk4_batch", "dopri_batch")
# Functions compiled to release the GIL: threads run a batch's members side by side through them
NOGIL = ("sampled_members",)
# Functions inlined into their callers (numba's IR inlining): a call of a separately compiled function passes
# every array as a struct and is not inlined by LLVM, which cost about 0.5 ms of a 1.8 ms paper run and 0.1 ms of
# its 0.6 ms of outputs on the grid; the right-hand sides stay calls (called from many places, inlined they would
# double the compile time)
INLINE = ("loop_derivative", "step_rhs", "loop_sources", "rms_norm", "dense_into", "dense_coefficients",
          "bounded_step", "dp_step", "loop_outputs_rows", "accumulate_rows")
# Of those, the loop's own functions, inlined only into a small program's drivers (codegen.SMALL_PROGRAM_LINES)
INLINE_WHEN_SMALL = ("loop_sources", "loop_outputs_rows")

# Dormand-Prince 5(4), as scipy.integrate.RK45
DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0])
DP_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [1 / 5, 0.0, 0.0, 0.0, 0.0],
    [3 / 40, 9 / 40, 0.0, 0.0, 0.0],
    [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]])
DP_B = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
DP_E = np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])
DP_P = np.array([
    [1.0, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
    [0.0, 0.0, 0.0, 0.0],
    [0.0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
    [0.0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
    [0.0, 127303824393 / 49829197408, -318862633887 / 49829197408, 701980252875 / 199316789632],
    [0.0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
    [0.0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423]])
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
ERROR_EXPONENT = -1.0 / 5.0

# What a called kernel gets for its states or inputs when it has none (numba takes a global array as a constant)
NO_ARRAY = np.empty(0)

# Status codes of dopri_run
RUNNING, FINISHED, DIVERGED, STEP_TOO_SMALL = 0, 1, 2, 3
# Slots of dopri_run's state vector
S_T, S_H, S_NFEV, S_DONE, S_STARTED, S_T_OLD = 0, 1, 2, 3, 4, 5


def loop_derivative(t, x, theta, ext, src, work, out):
    """The loop's state derivative at ``(t, x)`` into ``out``: its sources, then its right-hand side."""
    loop_sources(t, theta, ext, work, src)
    loop_rhs(t, x, theta, src, ext, work, out)


def rms_norm(v):
    total = 0.0
    for i in range(v.shape[0]):
        total += v[i] * v[i]
    return math.sqrt(total) / math.sqrt(v.shape[0])


def initial_step(t0, y0, f0, t_bound, max_step, rtol, atol, theta, ext, src, work, f1):
    """scipy's ``select_initial_step`` for an error estimator of order 4."""
    n = y0.shape[0]
    interval = abs(t_bound - t0)
    if interval == 0.0:
        return 0.0
    scale = atol + np.abs(y0) * rtol
    d0 = rms_norm(y0 / scale)
    d1 = rms_norm(f0 / scale)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * d0 / d1
    h0 = min(h0, interval)
    y1 = y0 + h0 * f0
    loop_derivative(t0 + h0, y1, theta, ext, src, work, f1)
    d2 = rms_norm((f1 - f0) / scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / 5.0)
    if n == 0:
        return np.inf
    return min(100 * h0, h1, interval, max_step)


def dense_into(Q, y_old, h, t_old, t, out, k):
    """The step's quartic interpolant at time ``t`` into column ``k`` of ``out`` (as scipy's RkDenseOutput)."""
    x = (t - t_old) / h
    p0 = x
    p1 = p0 * x
    p2 = p1 * x
    p3 = p2 * x
    for i in range(y_old.shape[0]):
        out[i, k] = h * (Q[i, 0] * p0 + Q[i, 1] * p1 + Q[i, 2] * p2 + Q[i, 3] * p3) + y_old[i]


def step_rhs(t, x, theta, ext, src, work, aux, out):
    """The state derivative the Dormand-Prince step integrates: the continuous loop's (sources, then its
    right-hand side).  A sampled program defines its own ``step_rhs`` after this text (the sampled outputs
    held in ``aux``), which replaces this one in its module."""
    loop_derivative(t, x, theta, ext, src, work, out)


def dp_step(t, t_bound, h_abs, max_step, rtol, atol, y, f, theta, ext, aux, src, work, K, y_new, f_new, y_stage,
            err, out):
    """One accepted Dormand-Prince 5(4) step of ``x' = step_rhs`` from ``t`` towards ``t_bound`` with the step
    control of :class:`scipy.integrate.RK45`; False when the step became too small.

    Every driver (``dopri_run``, ``sampled_ticks``) steps through this one
    function.  ``f`` is the derivative at ``(t, y)``; ``K`` gets the stages
    (``K[0] = f``), ``y_new``/``f_new`` the step's end, and ``out``
    ``[t_new, next h_abs, h, right-hand-side calls]``.
    """
    n = y.shape[0]
    min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
    if h_abs > max_step:
        h_abs = max_step
    elif h_abs < min_step:
        h_abs = min_step
    accepted = False
    rejected = False
    h = 0.0
    t_new = t
    nfev = 0
    while not accepted:
        if h_abs < min_step:
            out[3] = nfev
            return False
        h = h_abs
        t_new = t + h
        if t_new - t_bound > 0:
            t_new = t_bound
        h = t_new - t
        h_abs = abs(h)
        # stages: K[0] = f, K[s] = f(t + c_s h, y + h sum_j a_sj K[j]), as scipy's rk_step
        for i in range(n):
            K[0, i] = f[i]
        for s in range(1, 6):
            for i in range(n):
                acc = 0.0
                for j in range(s):
                    acc += K[j, i] * DP_A[s, j]
                y_stage[i] = y[i] + acc * h
            step_rhs(t + DP_C[s] * h, y_stage, theta, ext, src, work, aux, K[s])
        for i in range(n):
            acc = 0.0
            for j in range(6):
                acc += K[j, i] * DP_B[j]
            y_new[i] = y[i] + h * acc
        step_rhs(t + h, y_new, theta, ext, src, work, aux, f_new)
        for i in range(n):
            K[6, i] = f_new[i]
        nfev += 6
        for i in range(n):
            acc = 0.0
            for j in range(7):
                acc += K[j, i] * DP_E[j]
            scale = atol + max(abs(y[i]), abs(y_new[i])) * rtol
            err[i] = acc * h / scale
        error_norm = rms_norm(err)
        if error_norm < 1.0:
            if error_norm == 0.0:
                factor = MAX_FACTOR
            else:
                factor = min(MAX_FACTOR, SAFETY * error_norm ** ERROR_EXPONENT)
            if rejected:
                factor = min(1.0, factor)
            h_abs *= factor
            accepted = True
        else:
            h_abs *= max(MIN_FACTOR, SAFETY * error_norm ** ERROR_EXPONENT)
            rejected = True
    out[0] = t_new
    out[1] = h_abs
    out[2] = h
    out[3] = nfev
    return True


def dense_coefficients(K, y, y_old, Q):
    """The accepted step's quartic interpolant, ``Q = K^T P`` (as scipy's RkDenseOutput), and its start ``y_old``."""
    for i in range(y.shape[0]):
        y_old[i] = y[i]
        for m in range(4):
            acc = 0.0
            for j in range(7):
                acc += K[j, i] * DP_P[j, m]
            Q[i, m] = acc


def bounded_step(t, t_bound, h_abs, max_step, rtol, atol, y, f, theta, ext, aux, src, work, K, y_new, f_new, y_stage,
                 err, out, y_old, Q, bound, state):
    """``dp_step`` as a driver takes it: its right-hand-side calls added to ``state[S_NFEV]``, the accepted
    step's dense coefficients (``y_old``, ``Q``) and its end checked against each state's ``bound`` (NaN fails
    too).  Returns ``RUNNING``, ``STEP_TOO_SMALL`` or ``DIVERGED``."""
    ok = dp_step(t, t_bound, h_abs, max_step, rtol, atol, y, f, theta, ext, aux, src, work, K, y_new, f_new, y_stage,
                 err, out)
    state[S_NFEV] += out[3]
    if not ok:
        return STEP_TOO_SMALL
    dense_coefficients(K, y, y_old, Q)
    for i in range(y.shape[0]):
        if not abs(y_new[i]) <= bound[i]:
            return DIVERGED
    return RUNNING


def dopri_run(t_grid, theta, ext, rtol, atol, max_step, bound, max_steps, state, y, f, K, Q, y_old, X):
    """Advance the integration by at most ``max_steps`` accepted steps; return a status code.

    ``state`` holds ``[t, h_abs, nfev, grid points done, started, t_old]``;
    ``y`` and ``f`` the current state and derivative (``y`` is the start
    state on the first call).  States on the grid are written into ``X``
    (n, T).  On divergence, ``y_old``, ``Q`` and ``state[S_T_OLD]`` describe
    the step that crossed the bound.
    """
    n = y.shape[0]
    t_bound = t_grid[-1]
    src = np.empty(loop_source_count())
    work = np.empty(loop_work_size())
    y_new = np.empty(n)
    f_new = np.empty(n)
    y_stage = np.empty(n)
    err = np.empty(n)
    aux = np.empty(1)           # a continuous loop holds no sampled outputs
    out = np.zeros(4)
    if state[S_STARTED] == 0.0:
        t = t_grid[0]
        loop_derivative(t, y, theta, ext, src, work, f)
        state[S_H] = initial_step(t, y, f, t_bound, max_step, rtol, atol, theta, ext, src, work, f_new)
        state[S_NFEV] = 2.0
        state[S_T] = t
        state[S_STARTED] = 1.0
        for i in range(n):
            X[i, 0] = y[i]
        state[S_DONE] = 1.0
    t = state[S_T]
    h_abs = state[S_H]
    done = int(state[S_DONE])
    n_grid = t_grid.shape[0]
    steps = 0
    while t < t_bound and steps < max_steps:
        code = bounded_step(t, t_bound, h_abs, max_step, rtol, atol, y, f, theta, ext, aux, src, work, K, y_new,
                            f_new, y_stage, err, out, y_old, Q, bound, state)
        if code == STEP_TOO_SMALL:
            state[S_T] = t
            return STEP_TOO_SMALL
        t_new = out[0]
        h_abs = out[1]
        h = out[2]
        state[S_T_OLD] = t
        if code == DIVERGED:
            for i in range(n):
                y[i] = y_new[i]
            state[S_T] = t_new
            state[S_H] = h
            return DIVERGED
        while done < n_grid and t_grid[done] <= t_new:
            dense_into(Q, y_old, h, t, t_grid[done], X, done)
            done += 1
        for i in range(n):
            y[i] = y_new[i]
            f[i] = f_new[i]
        t = t_new
        steps += 1
    state[S_T] = t
    state[S_H] = h_abs
    state[S_DONE] = float(done)
    if t >= t_bound:
        return FINISHED
    return RUNNING


def grid_outputs(t_grid, X, theta, ext, aux, flags, Y, R):
    """The loop's outputs and the flagged row groups at every grid time from its states there.

    ``Y[:, k]`` and ``R[:, k]`` from ``X[:, k]``; ``aux`` holds one row of
    shared values per grid time, or a single row for all.
    """
    src = np.empty(loop_source_count())
    work = np.empty(loop_work_size())
    y = np.empty(Y.shape[0])
    rows = np.zeros(loop_row_count())
    shared = aux.shape[0] == 1
    for k in range(t_grid.shape[0]):
        loop_sources(t_grid[k], theta, ext, work, src)
        loop_outputs_rows(t_grid[k], X[:, k], theta, src, ext, work, aux[0] if shared else aux[k], flags, y, rows)
        for i in range(y.shape[0]):
            Y[i, k] = y[i]
        for i in range(R.shape[0]):
            R[i, k] = rows[i]


def source_table(times, theta, ext, table):
    """The sources' outputs at each of ``times``: ``table[k]`` (shared by every member of a batch)."""
    work = np.empty(loop_work_size())
    for k in range(times.shape[0]):
        loop_sources(times[k], theta, ext, work, table[k])


def accumulate_rows(m, g, last_grid, rows, sum_sq, max_abs, final):
    """Member ``m``'s rows at grid point ``g`` into its metrics: squares added to ``sum_sq[m]``, the largest
    magnitude (nan wins) in ``max_abs[m]``, the value at grid point ``last_grid`` in ``final[m]``."""
    for r in range(sum_sq.shape[1]):
        v = rows[r]
        sum_sq[m, r] += v * v
        a = abs(v)
        if a > max_abs[m, r] or a != a:
            max_abs[m, r] = a
        if g == last_grid:
            final[m, r] = v


def rk4_batch(times, grid_index, src_at, src_mid, aux, X0, theta, ext, tables, table_row, flags, keep, keep_rows,
              last_grid, bound, Y, sum_sq, max_abs, final, failed_at, failed_x):
    """Fixed-step RK4 of every member on the shared schedule ``times``, members in parallel.

    ``src_at``/``src_mid`` are the sources' outputs at the step times and
    the mid points, ``aux`` the shared values of the row groups at each grid
    point; ``X0`` (N, n) the start states, ``theta`` (N, p) the members'
    parameters, ``tables`` the members' tables (``member_ext``; member ``m``
    reads row ``table_row[m]``).  At each grid point the flagged row groups
    are evaluated with the step's first stage and accumulated per member:
    ``sum_sq`` and ``max_abs`` (N, rows) and their value at the last grid
    point (grid index ``last_grid``), ``final``.  When ``keep`` or ``keep_rows`` are not empty the
    outputs ``keep`` and rows ``keep_rows`` are stored in ``Y[member, grid
    index]``.  A member whose state is non-finite or beyond its bound at a
    grid point (``bound[m, i]``: each member's physical bounds, see
    :mod:`blocks.engines.divergence`) gets that time in ``failed_at``, that state in
    ``failed_x[m]``, and stops.  Nothing is allocated per step.
    """
    n_members, n = X0.shape
    n_out = loop_output_count()
    n_keep = keep.shape[0]
    n_keep_rows = keep_rows.shape[0]
    for m in prange(n_members):
        x = X0[m].copy()
        th = theta[m]
        e = member_ext(ext, tables, table_row[m])
        work = np.empty(loop_work_size())
        k1 = np.empty(n)
        k2 = np.empty(n)
        k3 = np.empty(n)
        k4 = np.empty(n)
        xs = np.empty(n)
        y = np.empty(n_out)
        rows = np.zeros(loop_row_count())
        rows_kept = np.zeros(loop_row_count())
        last = times.shape[0] - 1
        for k in range(times.shape[0]):
            t0 = times[k]
            g = grid_index[k]
            if g >= 0:
                ok = True
                for i in range(n):
                    if not abs(x[i]) <= bound[m, i]:
                        ok = False
                if not ok:
                    failed_at[m] = t0
                    for i in range(n):
                        failed_x[m, i] = x[i]
                    break
                loop_rhs_rows(t0, x, th, src_at[k], e, work, aux[g], flags, k1, rows)
                accumulate_rows(m, g, last_grid, rows, sum_sq, max_abs, final)
                if n_keep > 0 or n_keep_rows > 0:
                    loop_outputs_rows(t0, x, th, src_at[k], e, work, aux[g], flags, y, rows_kept)
                    for r in range(n_keep):
                        Y[m, g, r] = y[keep[r]]
                    for r in range(n_keep_rows):
                        Y[m, g, n_keep + r] = rows_kept[keep_rows[r]]
            elif k < last:
                loop_rhs(t0, x, th, src_at[k], e, work, k1)
            if k == last:
                break
            h = times[k + 1] - t0
            for i in range(n):
                xs[i] = x[i] + (0.5 * h) * k1[i]
            loop_rhs(t0 + 0.5 * h, xs, th, src_mid[k], e, work, k2)
            for i in range(n):
                xs[i] = x[i] + (0.5 * h) * k2[i]
            loop_rhs(t0 + 0.5 * h, xs, th, src_mid[k], e, work, k3)
            for i in range(n):
                xs[i] = x[i] + h * k3[i]
            loop_rhs(times[k + 1], xs, th, src_at[k + 1], e, work, k4)
            for i in range(n):
                x[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])


def batch_grid_point(m, g, t, x, theta, ext, aux, flags, keep, keep_rows, last_grid, src_grid, work, yo, rows, Y,
                     sum_sq, max_abs, final):
    """Member ``m``'s outputs and flagged rows at grid point ``g`` (time ``t``, states ``x``), as ``grid_outputs``
    evaluates them for a single run (the sources' outputs there, shared by all members, from ``src_grid[g]``):
    their squares added to ``sum_sq[m]``, their largest magnitude in ``max_abs[m]``, their value at grid point
    ``last_grid`` in ``final[m]``, the outputs ``keep`` and rows ``keep_rows`` stored in ``Y[m, g]``."""
    loop_outputs_rows(t, x, theta, src_grid[g], ext, work, aux[g], flags, yo, rows)
    accumulate_rows(m, g, last_grid, rows, sum_sq, max_abs, final)
    n_keep = keep.shape[0]
    for r in range(n_keep):
        Y[m, g, r] = yo[keep[r]]
    for r in range(keep_rows.shape[0]):
        Y[m, g, n_keep + r] = rows[keep_rows[r]]


def dopri_member(m, t_grid, src_grid, X0, theta, ext, rtol, atol, max_step, aux, flags, keep, keep_rows, bound, Y,
                 sum_sq, max_abs, final, failed_x, counts):
    """Member ``m`` of ``dopri_batch``: its whole run, as ``dopri_run`` makes a single one; its status code.

    ``counts[m]`` gets ``[accepted steps, right-hand-side calls, time reached]``; on ``DIVERGED`` the state at
    the end of the step that crossed the bound is in ``failed_x[m]``, on ``STEP_TOO_SMALL`` the state where the
    step became too small.
    """
    n = X0.shape[1]
    n_grid = t_grid.shape[0]
    t_bound = t_grid[n_grid - 1]
    src = np.empty(loop_source_count())
    work = np.empty(loop_work_size())
    y = X0[m].copy()
    f = np.empty(n)
    K = np.empty((7, n))
    y_new = np.empty(n)
    f_new = np.empty(n)
    y_stage = np.empty(n)
    err = np.empty(n)
    y_old = np.empty(n)
    Q = np.empty((n, 4))
    xg = np.empty(n)
    yo = np.empty(loop_output_count())
    rows = np.zeros(loop_row_count())
    held = np.empty(1)          # a continuous loop holds no sampled outputs
    out = np.zeros(4)
    state = np.zeros(6)
    lim = bound[m]
    last_grid = n_grid - 1
    t = t_grid[0]
    for i in range(n):
        if not abs(y[i]) <= lim[i]:
            failed_x[m, i] = y[i]
            counts[m, 2] = t
            return DIVERGED
    loop_derivative(t, y, theta, ext, src, work, f)
    h_abs = initial_step(t, y, f, t_bound, max_step, rtol, atol, theta, ext, src, work, f_new)
    state[S_NFEV] = 2.0
    batch_grid_point(m, 0, t, y, theta, ext, aux, flags, keep, keep_rows, last_grid, src_grid, work, yo, rows, Y,
                     sum_sq, max_abs, final)
    g = 1
    steps = 0
    code = FINISHED
    while t < t_bound:
        code = bounded_step(t, t_bound, h_abs, max_step, rtol, atol, y, f, theta, ext, held, src, work, K, y_new,
                            f_new, y_stage, err, out, y_old, Q, lim, state)
        if code == STEP_TOO_SMALL:
            for i in range(n):
                failed_x[m, i] = y[i]
            break
        t_new = out[0]
        h_abs = out[1]
        h = out[2]
        steps += 1
        if code == DIVERGED:
            for i in range(n):
                failed_x[m, i] = y_new[i]
            t = t_new
            break
        while g < n_grid and t_grid[g] <= t_new:
            dense_row(Q, y_old, h, t, t_grid[g], xg)
            batch_grid_point(m, g, t_grid[g], xg, theta, ext, aux, flags, keep, keep_rows, last_grid, src_grid,
                             work, yo, rows, Y, sum_sq, max_abs, final)
            g += 1
        for i in range(n):
            y[i] = y_new[i]
            f[i] = f_new[i]
        t = t_new
        code = FINISHED
    counts[m, 0] = steps
    counts[m, 1] = state[S_NFEV]
    counts[m, 2] = t
    return code


def dopri_batch(t_grid, src_grid, X0, theta, ext, tables, table_row, rtol, atol, max_step, aux, flags, keep, keep_rows,
                bound, Y, sum_sq, max_abs, final, status, failed_x, counts):
    """Every member run on its own as ``dopri_run`` runs a single one, members in parallel.

    ``src_grid`` holds the sources' outputs at the grid times (shared by all
    members), ``X0`` (N, n) the start states, ``theta`` (N, p) the members' parameters,
    ``tables`` their tables (``member_ext``; member ``m`` reads row
    ``table_row[m]``), ``bound[m]`` member ``m``'s state bounds, ``aux`` the
    row groups' shared values at each grid point.  Each member takes its own
    Dormand-Prince steps (the step control of ``dp_step``), its states on the
    output grid from each step's dense output, and there its outputs and the
    flagged row groups as ``grid_outputs`` evaluates them: the sums
    ``sum_sq``, ``max_abs``, ``final`` (N, rows) and the kept ``Y``, as
    ``rk4_batch`` keeps them.  ``status[m]`` gets the member's code
    (``FINISHED``, ``DIVERGED``, ``STEP_TOO_SMALL``), ``counts[m]`` its
    accepted steps, right-hand-side calls and the time reached.
    """
    for m in prange(X0.shape[0]):
        e = member_ext(ext, tables, table_row[m])
        status[m] = dopri_member(m, t_grid, src_grid, X0, theta[m], e, rtol, atol, max_step, aux, flags, keep,
                                 keep_rows, bound, Y, sum_sq, max_abs, final, failed_x, counts)


# ------------------------------------------------------------------------------------------------------------
# The sampled-data loop (blocks.engines.hybrid.HybridSystem.simulate), compiled: at each tick the sampled blocks'
# outputs and updates (sampled_tick), then the continuous states integrated to the next tick with the sampled
# outputs held (step_rhs, which a sampled program defines as its sampled_rhs), by the same dp_step as dopri_run,
# restarted at every tick with first step = the interval, as blocks.engines.integrate.integrate_on_grid does there.
# Generated functions: blocks.engines.compiled.codegen.sampled_program.
# ------------------------------------------------------------------------------------------------------------
# Status of sampled_ticks beside RUNNING, FINISHED, DIVERGED (a step), STEP_TOO_SMALL: a tick's update diverged
TICK_DIVERGED = 4
# Slot of sampled_ticks' state vector holding the next tick (the others as dopri_run's: S_T, S_NFEV, S_DONE,
# S_T_OLD; S_DONE is the next grid point to fill)
S_TICK = 1


def dense_row(Q, y_old, h, t_old, t, out):
    """The step's quartic interpolant at time ``t`` into the vector ``out`` (as ``dense_into``)."""
    x = (t - t_old) / h
    p0 = x
    p1 = p0 * x
    p2 = p1 * x
    p3 = p2 * x
    for i in range(y_old.shape[0]):
        out[i] = h * (Q[i, 0] * p0 + Q[i, 1] * p1 + Q[i, 2] * p2 + Q[i, 3] * p3) + y_old[i]


def sampled_grid_point(g, t, x, theta, ext, held, src, work, store, X, Y, yg, err_a, err_b, sum_sq):
    """The loop's outputs at grid point ``g`` (time ``t``, states ``x``, the sampled outputs ``held``): into rows
    ``X[g]``, ``Y[g]`` when ``store``, and ``(y[err_a[c]] - y[err_b[c]])^2`` added to ``sum_sq[c]``."""
    loop_sources(t, theta, ext, work, src)
    sampled_outputs(t, x, theta, src, ext, work, held, yg)
    if store:
        for i in range(x.shape[0]):
            X[g, i] = x[i]
        for i in range(yg.shape[0]):
            Y[g, i] = yg[i]
    for c in range(err_a.shape[0]):
        e = yg[err_a[c]] - yg[err_b[c]]
        sum_sq[c] += e * e


def sampled_ticks(t_grid, base_period, n_ticks, k_stop, theta, ext, rtol, atol, max_step, bound, state, x, held,
                  store, X, Y, err_a, err_b, sum_sq, y_old, Q):
    """Run the ticks from ``state[S_TICK]`` up to (not including) ``k_stop``; return a status code.

    ``x`` (n,) and ``held`` (all block outputs, the sampled ones held) carry
    the loop from call to call; ``state`` is ``[t, next tick, rhs calls,
    next grid point, -, t_old]``.  At each grid point the states and the
    outputs are written into rows of ``X`` (T, n) and ``Y`` (T, outputs) when
    ``store``, and ``(y[err_a[c]] - y[err_b[c]])^2`` is added to
    ``sum_sq[c]``.  A state beyond its ``bound`` after a tick's update gives
    ``TICK_DIVERGED`` (``x`` holds the state, ``state[S_T]`` the time); after
    a step, ``DIVERGED`` with ``x`` the step's end and ``y_old``, ``Q``,
    ``state[S_T_OLD]`` the step (for the crossing time).
    """
    n = x.shape[0]
    n_grid = t_grid.shape[0]
    t_end = t_grid[n_grid - 1]
    src = np.empty(loop_source_count())
    work = np.empty(loop_work_size())
    held_new = np.empty(held.shape[0])
    xn = np.empty(n)
    f = np.empty(n)
    K = np.empty((7, n))
    y_new = np.empty(n)
    f_new = np.empty(n)
    y_stage = np.empty(n)
    err = np.empty(n)
    xg = np.empty(n)
    yg = np.empty(loop_output_count())
    out = np.zeros(4)
    k = int(state[S_TICK])
    g = int(state[S_DONE])
    while k <= n_ticks and k < k_stop:
        t0 = k * base_period
        if k < n_ticks:
            t1 = min((k + 1) * base_period, t_end)
        else:
            t1 = t_end
        # the tick: sampled outputs (held from now) and updates
        loop_sources(t0, theta, ext, work, src)
        for i in range(n):
            xn[i] = x[i]
        for j in range(held.shape[0]):
            held_new[j] = held[j]
        sampled_tick(t0, x, theta, src, ext, work, held, held_new, xn)
        for j in range(held.shape[0]):
            held[j] = held_new[j]
        for i in range(n):
            x[i] = xn[i]
        for i in range(n):
            if not abs(x[i]) <= bound[i]:
                state[S_T] = t0
                state[S_TICK] = k
                state[S_DONE] = g
                return TICK_DIVERGED
        # the grid points of this interval, [t0, t1) (the last tick takes the rest)
        upto = g
        if k < n_ticks:
            while upto < n_grid and t_grid[upto] < t1:
                upto += 1
        else:
            upto = n_grid
        if t1 > t0:
            step_rhs(t0, x, theta, ext, src, work, held, f)
            state[S_NFEV] += 1.0
            h_abs = min(t1 - t0, max_step)
            t = t0
            h = 0.0
            while t < t1:
                code = bounded_step(t, t1, h_abs, max_step, rtol, atol, x, f, theta, ext, held, src, work, K, y_new,
                                    f_new, y_stage, err, out, y_old, Q, bound, state)
                if code == STEP_TOO_SMALL:
                    state[S_T] = t
                    state[S_TICK] = k
                    state[S_DONE] = g
                    return STEP_TOO_SMALL
                t_new = out[0]
                h_abs = out[1]
                h = out[2]
                if code == DIVERGED:
                    for i in range(n):
                        x[i] = y_new[i]
                    state[S_T_OLD] = t
                    state[S_T] = t_new
                    state[S_TICK] = k
                    state[S_DONE] = g
                    return DIVERGED
                while g < upto and t_grid[g] <= t_new:
                    dense_row(Q, y_old, h, t, t_grid[g], xg)
                    sampled_grid_point(g, t_grid[g], xg, theta, ext, held, src, work, store, X, Y, yg, err_a, err_b,
                                       sum_sq)
                    g += 1
                for i in range(n):
                    x[i] = y_new[i]
                    f[i] = f_new[i]
                state[S_T_OLD] = t
                t = t_new
            # the next tick starts from the last step's interpolant at t1, as the numpy engine's grid does
            dense_row(Q, y_old, h, state[S_T_OLD], t1, xn)
            for i in range(n):
                x[i] = xn[i]
        else:
            while g < upto:
                sampled_grid_point(g, t_grid[g], x, theta, ext, held, src, work, store, X, Y, yg, err_a, err_b,
                                   sum_sq)
                g += 1
        k += 1
    state[S_TICK] = k
    state[S_DONE] = g
    state[S_T] = min(k * base_period, t_end)
    if k > n_ticks:
        return FINISHED
    return RUNNING


def sampled_members(start, stride, t_grid, base_period, n_ticks, X0, held0, theta, ext, tables, table_row, rtol,
                    atol, max_step, bound, err_a, err_b, sum_sq, failed_at, failed_state, status):
    """The sampled loop of members ``start, start + stride, ...``: ``X0`` (N, n) start states, ``held0`` the start
    held outputs, ``theta`` (N, p), member ``m``'s tables row ``table_row[m]`` (``member_ext``).

    Each member's tracking sums go to ``sum_sq[m]`` (see ``sampled_ticks``);
    a member that diverges or whose step becomes too small gets its status
    in ``status[m]``, the time in ``failed_at[m]`` and its state then in
    ``failed_state[m]``, and stops; the others go on.  (The caller runs one
    call per thread, the GIL released: numba's ``prange`` cannot take the
    parameters' tuple, which holds tuples.)
    """
    for m in range(start, X0.shape[0], stride):
        status[m] = sampled_member(m, t_grid, base_period, n_ticks, X0, held0, theta, ext, tables, table_row, rtol,
                                   atol, max_step, bound, err_a, err_b, sum_sq, failed_at, failed_state)


def sampled_member(m, t_grid, base_period, n_ticks, X0, held0, theta, ext, tables, table_row, rtol, atol, max_step,
                   bound, err_a, err_b, sum_sq, failed_at, failed_state):
    """Member ``m`` of ``sampled_batch``: its whole run; its status code."""
    n = X0.shape[1]
    x = X0[m].copy()
    held = held0.copy()
    state = np.zeros(6)
    e = member_ext(ext, tables, table_row[m])
    dummy_x = np.empty((1, n))
    dummy_y = np.empty((1, loop_output_count()))
    y_old = np.empty(n)
    Q = np.empty((n, 4))
    code = sampled_ticks(t_grid, base_period, n_ticks, n_ticks + 1, theta[m], e, rtol, atol, max_step, bound,
                         state, x, held, False, dummy_x, dummy_y, err_a, err_b, sum_sq[m], y_old, Q)
    if code != FINISHED:
        failed_at[m] = state[S_T]
        for i in range(n):
            failed_state[m, i] = x[i]
    return code
