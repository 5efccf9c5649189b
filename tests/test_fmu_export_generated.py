"""The plant FMU's generated maths (fmu.generated) against the C written by hand before it and the kernels.

``HANDWRITTEN`` is the plant maths the FMU carried before its C was generated
(k1..k5 from Table 1, M(q) filled entry by entry and solved by Cholesky, the
disturbance models written out), kept here as an independent reference: it
shares no code with the kernels the generated C comes from.
"""
from __future__ import annotations

import ctypes
import subprocess
import zipfile

import numpy as np
import pytest

from blocks.diagram.contract import contract_of
from blocks.diagram.systems import plant
from blocks.model.disturbances import DISTURBANCE_KINDS, DisturbanceSpec
from blocks.model.rrpr.parameters import RobotParameters
from fmu import FMUInstance, export_plant
from fmu.build import COMPILE_FLAGS, find_compiler
from fmu.generated import plant_c

pytestmark = pytest.mark.needs_cc

STATES = [f"q[{i}]" for i in range(4)] + [f"dq[{i}]" for i in range(4)]
ALL = DisturbanceSpec(kinds=DISTURBANCE_KINDS, skin_height=0.12 - 0.24 - 0.271 + 0.01)

HANDWRITTEN = r"""
#include <math.h>
#include <string.h>
#include "plant_config.h"

typedef struct { double k1, k2, k3, k4, k5; } K;

static void constants(const double *p, K *k)
{
    const double l1 = p[P_l1], l2 = p[P_l2];
    const double m34 = p[P_m3] + p[P_m4];
    const double s1 = p[P_m2] * (l2 * l2 + 4.0 * l1 * l1);
    const double s2 = m34 * (4.0 * l1 * l1 + 4.0 * l2 * l2);
    k->k1 = p[P_I1] + p[P_I2] + p[P_I3] + p[P_I4] + p[P_m1] * l1 * l1 + s1 + s2;
    k->k2 = 2.0 * (2.0 * l1 * l2 * p[P_m2] + 4.0 * l1 * l2 * m34);
    k->k3 = p[P_I2] + p[P_I3] + p[P_I4] + p[P_m2] * l2 * l2 + 4.0 * l2 * l2 * m34;
    k->k4 = m34;
    k->k5 = p[P_I4];
}

void ref_constants(const double *p, double *out)
{
    K k;
    constants(p, &k);
    out[0] = k.k1; out[1] = k.k2; out[2] = k.k3; out[3] = k.k4; out[4] = k.k5;
}

void ref_disturbance(const double *p, const int *sw, double t, const double *x, double *tau_dis)
{
    const double *q = x, *dq = x + 4;
    int i;
    for (i = 0; i < 4; i++) tau_dis[i] = 0.0;
    if (sw[0]) {
        const double s = (double)((2.0 * t + 1.0 > 0.0) - (2.0 * t + 1.0 < 0.0));
        for (i = 0; i < 4; i++) tau_dis[i] += p[P_f_r_0 + i] * s;
    }
    if (sw[1]) {
        const double vs = p[P_friction_velocity];
        for (i = 0; i < 4; i++) tau_dis[i] -= p[P_coulomb_0 + i] * tanh(dq[i] / vs) + p[P_viscous_0 + i] * dq[i];
    }
    if (sw[2]) {
        const double a1 = p[P_a1], a2 = p[P_a2];
        const double s1 = sin(q[0]), c1 = cos(q[0]), s12 = sin(q[0] + q[1]), c12 = cos(q[0] + q[1]);
        const double jx0 = -a1 * s1 - a2 * s12, jx1 = -a2 * s12, jy0 = a1 * c1 + a2 * c12, jy1 = a2 * c12;
        const double vx = jx0 * dq[0] + jx1 * dq[1], vy = jy0 * dq[0] + jy1 * dq[1], vz = -dq[2];
        const double depth = p[P_skin_height] - (p[P_d1] - q[2] - p[P_d4]);
        if (depth > 0.0) {
            double fz = p[P_tissue_stiffness] * depth - p[P_tissue_damping] * vz;
            const double fx = -p[P_tissue_drag] * vx, fy = -p[P_tissue_drag] * vy;
            if (fz < 0.0) fz = 0.0;
            tau_dis[0] += jx0 * fx + jy0 * fy;
            tau_dis[1] += jx1 * fx + jy1 * fy;
            tau_dis[2] += -fz;
        }
    }
}

static int solve_spd4(double A[4][4], const double *b, double *y)
{
    double L[4][4] = {{0.0}}, w[4];
    int i, j, k;
    for (j = 0; j < 4; j++) {
        double s = A[j][j];
        for (k = 0; k < j; k++) s -= L[j][k] * L[j][k];
        if (!(s > 0.0)) return 0;
        L[j][j] = sqrt(s);
        for (i = j + 1; i < 4; i++) {
            double r = A[i][j];
            for (k = 0; k < j; k++) r -= L[i][k] * L[j][k];
            L[i][j] = r / L[j][j];
        }
    }
    for (i = 0; i < 4; i++) {
        double s = b[i];
        for (k = 0; k < i; k++) s -= L[i][k] * w[k];
        w[i] = s / L[i][i];
    }
    for (i = 3; i >= 0; i--) {
        double s = w[i];
        for (k = i + 1; k < 4; k++) s -= L[k][i] * y[k];
        y[i] = s / L[i][i];
    }
    return 1;
}

int ref_derivatives(const double *p, const int *sw, double t, const double *x, const double *u, double *dx)
{
    K k;
    double M[4][4], rhs[4], tau_dis[4], N[4];
    const double *dq = x + 4, c2 = cos(x[1]), s2 = sin(x[1]);
    int i;
    constants(p, &k);
    memset(M, 0, sizeof M);
    M[0][0] = k.k1 + k.k2 * c2;
    M[0][1] = M[1][0] = k.k3 + 0.5 * k.k2 * c2;
    M[1][1] = k.k3;
    M[2][2] = k.k4;
    M[0][3] = M[3][0] = -k.k5;
    M[1][3] = M[3][1] = -k.k5;
    M[3][3] = k.k5;
    N[0] = -k.k2 * s2 * dq[1] * (dq[0] + 0.5 * dq[1]);
    N[1] = 0.5 * k.k2 * s2 * dq[0] * dq[0];
    N[2] = 0.0;
    N[3] = 0.0;
    ref_disturbance(p, sw, t, x, tau_dis);
    for (i = 0; i < 4; i++) rhs[i] = u[i] + tau_dis[i] - N[i];
    rhs[2] -= -k.k4 * p[P_g];
    for (i = 0; i < 4; i++) dx[i] = dq[i];
    return solve_spd4(M, rhs, dx + 4);
}
"""

_D = ctypes.POINTER(ctypes.c_double)
_I = ctypes.POINTER(ctypes.c_int)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("generated")
    path = export_plant(folder / "plant.fmu", disturbance=ALL, fmi_version=2)
    config = zipfile.ZipFile(path).read("sources/plant_config.h").decode()
    (folder / "plant_config.h").write_text(config)
    (folder / "ref.c").write_text(HANDWRITTEN)
    lib = folder / "libref.so"
    flags = [f for f in COMPILE_FLAGS if f != "-fvisibility=hidden"]         # the reference's symbols are called
    subprocess.run(find_compiler() + flags + [f"-I{folder}", str(folder / "ref.c"), "-o", str(lib),
                                                             "-lm"], check=True, capture_output=True, text=True)
    ref = ctypes.CDLL(str(lib))
    ref.ref_derivatives.argtypes = [_D, _I, ctypes.c_double, _D, _D, _D]
    ref.ref_disturbance.argtypes = [_D, _I, ctypes.c_double, _D, _D]
    ref.ref_constants.argtypes = [_D, _D]
    return path, ref, config


def _params(config: str, start: dict) -> np.ndarray:
    """The FMU's real parameter vector (PlantData.p order) from plant_config.h's START_PARAMS and names."""
    line = next(x for x in config.splitlines() if x.startswith("#define PARAM_NAMES"))
    names = [s.strip().strip('"') for s in line.split("{", 1)[1].rstrip("}").split(",")]
    line = next(x for x in config.splitlines() if x.startswith("#define START_PARAMS"))
    values = [float(s) for s in line.split("{", 1)[1].rstrip("}").split(",")]
    return np.array([start.get(n, v) for n, v in zip(names, values)])


def _random_state(rng):
    q = rng.uniform([-3, -3, 0.0, -3], [3, 3, 0.45, 3])
    return np.concatenate((q, rng.normal(0.0, 2.0, 4)))


@pytest.mark.parametrize("kinds", [(), ("paper",), ("friction",), ("paper", "friction", "tissue"), ("tissue",)])
def test_model_exchange_derivatives_match_the_handwritten_c_and_the_kernel(exported, kinds):
    path, ref, config = exported
    rng = np.random.default_rng(len(kinds) + 7 * ("tissue" in kinds))
    switches = {f"disturbance_{k}": k in kinds for k in DISTURBANCE_KINDS}
    spec = DisturbanceSpec(kinds=kinds, skin_height=ALL.skin_height)
    kernel = contract_of(plant(RobotParameters(), spec)).kernels
    p = _params(config, {})
    sw = (ctypes.c_int * 3)(*[int(k in kinds) for k in DISTURBANCE_KINDS])
    worst_ref = worst_kernel = 0.0
    with FMUInstance(path, "ModelExchange", start_values=switches) as f:
        taus = f.value_references([f"tau[{i}]" for i in range(4)])
        dis = f.value_references([f"tau_dis[{i}]" for i in range(4)])
        for _ in range(60):
            t, x, u = rng.uniform(0.0, 2.0), _random_state(rng), rng.normal(0.0, 3.0, 4)
            f.set_time(t)
            f.set_states(x)
            f.set_real(taus, u)
            got = f.derivatives()
            expected = np.empty(8)
            assert ref.ref_derivatives(p.ctypes.data_as(_D), sw, t, x.ctypes.data_as(_D), u.ctypes.data_as(_D),
                                       expected.ctypes.data_as(_D)) == 1
            scale = np.max(np.abs(expected))
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-13 * scale)
            worst_ref = max(worst_ref, float(np.max(np.abs(got - expected)) / scale))
            np.testing.assert_allclose(got, kernel.update(t, x, u, *kernel.params), rtol=1e-13, atol=1e-15 * scale)
            worst_kernel = max(worst_kernel, float(np.max(np.abs(got - kernel.update(t, x, u, *kernel.params)))))
            tau_dis = np.empty(4)
            ref.ref_disturbance(p.ctypes.data_as(_D), sw, t, x.ctypes.data_as(_D), tau_dis.ctypes.data_as(_D))
            np.testing.assert_allclose(f.get_real(dis), tau_dis, rtol=1e-13, atol=1e-13)
    print(f"largest difference, generated vs handwritten: {worst_ref:.3g} (relative to max |dx|); "
          f"vs the numpy kernel: {worst_kernel:.3g}")


def test_tuned_table1_parameters_reach_the_generated_maths(exported):
    """m1, l2, I4 set at start: k1..k5 and the derivatives follow (the numbers come from theta, not the text)."""
    path, ref, config = exported
    start = {"m1": 7.1, "l2": 0.23, "I4": 1.1, "g": 9.81, "coulomb[1]": 0.9}
    p = _params(config, start)
    k_ref = np.empty(5)
    ref.ref_constants(p.ctypes.data_as(_D), k_ref.ctypes.data_as(_D))
    rng = np.random.default_rng(11)
    sw = (ctypes.c_int * 3)(1, 1, 1)
    with FMUInstance(path, "ModelExchange", start_values=start) as f:
        k = f.get_real(f.value_references(["k1", "k2", "k3", "k4", "k5"]))
        np.testing.assert_allclose(k, k_ref, rtol=1e-15)
        taus = f.value_references([f"tau[{i}]" for i in range(4)])
        for _ in range(20):
            t, x, u = rng.uniform(0.0, 2.0), _random_state(rng), rng.normal(0.0, 3.0, 4)
            f.set_time(t)
            f.set_states(x)
            f.set_real(taus, u)
            expected = np.empty(8)
            ref.ref_derivatives(p.ctypes.data_as(_D), sw, t, x.ctypes.data_as(_D), u.ctypes.data_as(_D),
                                expected.ctypes.data_as(_D))
            np.testing.assert_allclose(f.derivatives(), expected, rtol=1e-12, atol=1e-13 * np.max(np.abs(expected)))


def test_generated_header_is_sized_by_the_arm_and_written_once_per_combination():
    params = RobotParameters()
    from fmu.variables import plant_variables
    reals = [v for v in plant_variables(params, ALL, 4) if v.c_name is not None]
    gen = plant_c(params, ALL, [v.name for v in reals], {v.name: v.start for v in reals})
    assert "#define N_JOINTS 4" in gen.text and gen.n_theta == 27 and gen.n_calculated == 5
    assert gen.functions == 2 + 1 + 8 + 2         # theta, calculated; dynamics; tau_dis per combination; update, check
    assert gen.text.count("static void plant_dynamics(") == 1
    for mask in range(8):
        assert f"static void plant_tau_dis_{mask}(" in gen.text
    # no general 4x4 solve, no hand-written inertia matrix: the closed-form kernel's operations
    assert "M[4][4]" not in gen.text and "solve_spd4" not in gen.text
    with pytest.raises(Exception, match="parameter map disagrees"):
        plant_c(params, ALL, [v.name for v in reals], {v.name: v.start * 1.01 for v in reals})
