"""The GPU batch's kernel, as source :mod:`blocks.engines.gpu.module` puts before each loop's generated functions.

This file is not imported as a module: its text, the loop's functions of
:mod:`blocks.engines.compiled.codegen` (the same text the CPU engines compile, with
numpy's scalar functions rewritten to the device functions below) and the
sizes ``N_STATES``, ``N_THETA``, ``N_WORK``, ``N_OUT``, ``N_ROWS`` are
executed together and compiled by numba-cuda: every function a device
function, ``rk4_members`` the kernel.

``rk4_members`` is :func:`rk4_batch` of :mod:`blocks.engines.compiled.dopri` with one
thread per member: the whole fixed-step RK4 loop on the shared schedule runs
on the device, the sources (the reference) read from the tables shared by all
members, each member's numbers in its own column of ``theta`` (members are the
last axis of every per-member array, so that neighbouring threads read
neighbouring numbers), the tracking metrics' sums kept in the thread's own
memory and written once at the end.
"""
import math

try:
    from numba import cuda, float64
except ImportError:         # the text is compiled with numba-cuda only; this keeps the file importable
    cuda = float64 = None


# numpy's scalar functions as the generated code uses them (blocks.engines.compiled.codegen._CALL_NAMES), with numpy's
# answers where Python's math raises (the simulator runs these in Python: a diverging member must not stop it)
def d_cos(x):
    if math.isinf(x):
        return math.nan
    return math.cos(x)


def d_sin(x):
    if math.isinf(x):
        return math.nan
    return math.sin(x)


def d_tan(x):
    if math.isinf(x):
        return math.nan
    return math.tan(x)


def d_tanh(x):
    return math.tanh(x)


def d_sqrt(x):
    if x < 0.0:
        return math.nan
    return math.sqrt(x)


def d_exp(x):
    if x > 709.0:
        return math.inf
    return math.exp(x)


def d_sign(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x                    # 0.0, -0.0 or NaN, as numpy.sign


def d_floor(x):
    if math.isinf(x) or x != x:
        return x
    return float(math.floor(x))


def d_abs(x):
    return math.fabs(x)


def d_maximum(a, b):
    if a != a or a >= b:        # NaN propagates, as numpy.maximum
        return a
    return b


def d_minimum(a, b):
    if a != a or a <= b:
        return a
    return b


def d_arctan2(a, b):
    return math.atan2(a, b)


def d_rint(x):
    """Round half to even, as numpy.rint."""
    if math.isinf(x) or x != x:
        return x
    f = float(math.floor(x))
    d = x - f
    if d > 0.5 or (d == 0.5 and f - 2.0 * float(math.floor(0.5 * f)) != 0.0):
        return f + 1.0
    return f


def rk4_members(times, grid_index, src_at, src_mid, aux, X0, theta, ext, tables, table_row, flags, keep, keep_rows,
                last_grid, bound, Y, sum_sq, max_abs, final, failed_at, failed_x):
    """Fixed-step RK4 of member ``m = cuda.grid(1)`` on the shared schedule ``times``.

    As ``rk4_batch`` of :mod:`blocks.engines.compiled.dopri`, with members last:
    ``X0``, ``bound``, ``failed_x`` (states, N), ``theta`` (numbers, N),
    ``sum_sq``, ``max_abs``, ``final`` (rows, N), ``Y`` (grid points, kept,
    N) and ``failed_at`` (N).  ``src_at``/``src_mid`` (step times / mid
    points, sources) and ``aux`` (grid points, shared values) are shared;
    member ``m`` reads its table (noise) from ``tables[0][table_row[m]]``
    through the generated ``member_ext``.
    """
    m = cuda.grid(1)
    if m >= X0.shape[1]:
        return
    e = member_ext(ext, tables, table_row[m])
    x = cuda.local.array(N_STATES, float64)
    k1 = cuda.local.array(N_STATES, float64)
    k2 = cuda.local.array(N_STATES, float64)
    k3 = cuda.local.array(N_STATES, float64)
    k4 = cuda.local.array(N_STATES, float64)
    xs = cuda.local.array(N_STATES, float64)
    th = cuda.local.array(N_THETA, float64)
    work = cuda.local.array(N_WORK, float64)
    y = cuda.local.array(N_OUT, float64)
    rows = cuda.local.array(N_ROWS, float64)
    rows_kept = cuda.local.array(N_ROWS, float64)
    ss = cuda.local.array(N_ROWS, float64)
    mx = cuda.local.array(N_ROWS, float64)
    fi = cuda.local.array(N_ROWS, float64)
    for i in range(N_STATES):
        x[i] = X0[i, m]
    for i in range(N_THETA):
        th[i] = theta[i, m]
    for r in range(N_ROWS):
        rows[r] = 0.0
        rows_kept[r] = 0.0
        ss[r] = 0.0
        mx[r] = 0.0
        fi[r] = 0.0
    n_keep = keep.shape[0]
    n_keep_rows = keep_rows.shape[0]
    last = times.shape[0] - 1
    for k in range(times.shape[0]):
        t0 = times[k]
        g = grid_index[k]
        if g >= 0:
            ok = True
            for i in range(N_STATES):
                if not abs(x[i]) <= bound[i, m]:
                    ok = False
            if not ok:
                failed_at[m] = t0
                for i in range(N_STATES):
                    failed_x[i, m] = x[i]
                break
            loop_rhs_rows(t0, x, th, src_at[k], e, work, aux[g], flags, k1, rows)
            for r in range(N_ROWS):
                v = rows[r]
                ss[r] += v * v
                a = abs(v)
                if a > mx[r] or a != a:
                    mx[r] = a
                if g == last_grid:
                    fi[r] = v
            if n_keep > 0 or n_keep_rows > 0:
                loop_outputs_rows(t0, x, th, src_at[k], e, work, aux[g], flags, y, rows_kept)
                for r in range(n_keep):
                    Y[g, r, m] = y[keep[r]]
                for r in range(n_keep_rows):
                    Y[g, n_keep + r, m] = rows_kept[keep_rows[r]]
        elif k < last:
            loop_rhs(t0, x, th, src_at[k], e, work, k1)
        if k == last:
            break
        h = times[k + 1] - t0
        for i in range(N_STATES):
            xs[i] = x[i] + (0.5 * h) * k1[i]
        loop_rhs(t0 + 0.5 * h, xs, th, src_mid[k], e, work, k2)
        for i in range(N_STATES):
            xs[i] = x[i] + (0.5 * h) * k2[i]
        loop_rhs(t0 + 0.5 * h, xs, th, src_mid[k], e, work, k3)
        for i in range(N_STATES):
            xs[i] = x[i] + h * k3[i]
        loop_rhs(times[k + 1], xs, th, src_at[k + 1], e, work, k4)
        for i in range(N_STATES):
            x[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
    for r in range(N_ROWS):
        sum_sq[r, m] = ss[r]
        max_abs[r, m] = mx[r]
        final[r, m] = fi[r]
