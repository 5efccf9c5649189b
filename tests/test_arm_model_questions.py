"""What the layers above an arm ask of it (blocks.model.arm.ArmModel), answered by the paper's RRPR and a URDF chain.

The answers are checked against numbers worked out here from the paper's Table 1 and the arms' joint ranges,
and the RRPR's closed-form dM/dq against central differences of its own M(q).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from blocks import load_scenario
from blocks.model.rrpr.laceration import LacerationPath
from blocks.model.rrpr.parameters import ParameterError, RobotParameters
from blocks.scenarios.scenario import default_arm

TABLE_1 = ("m1", "m2", "m3", "m4", "l1", "l2", "I1", "I2", "I3", "I4", "g", "a1", "a2", "d1", "d4")


@pytest.fixture(scope="module")
def chain():
    pytest.importorskip("pinocchio")
    return load_scenario("scope4").robot


def test_the_default_scenarios_arm_is_the_papers():
    arm = default_arm()
    assert arm == RobotParameters() and arm.paper is not None
    assert arm.name == "rrpr" and arm.in_words() == "the paper's RRPR arm"


def test_the_rrpr_answers_from_table_1():
    arm = RobotParameters()
    assert arm.parameter_names() == TABLE_1
    assert arm.parameter_values()["I3"] == 1.4629 and arm.parameter_unit("I3") == "kg m^2"
    assert [n for n in TABLE_1 if not arm.parameter_positive(n)] == ["g", "d1", "d4"]
    assert [name for name, _, _ in arm.calculated_parameters()] == ["k1", "k2", "k3", "k4", "k5"]
    assert arm.with_parameters(m1=11.16).m1 == 11.16 and arm.scaled(m1=2.0).m1 == 11.16
    with pytest.raises(ParameterError, match="unknown robot parameter"):
        arm.with_parameters(mass=1.0)
    # the elbow at a right angle, the slide at Table 1's d3 = 0.24 m
    assert arm.rest_pose() == [0.0, math.pi / 2, 0.24, 0.0]
    assert arm.stacks_constants and arm.constant_gravity and arm.inertia_depends_on == (1,)


def test_the_rrpr_checks_members_as_columns_as_it_checks_one_arm():
    arm = RobotParameters()
    good = {n: np.array([v, 1.1 * v]) for n, v in arm.parameter_values().items()}
    assert arm.parameters_valid(good)
    # a negative inertia in the second member: that arm would be refused on its own
    bad = dict(good, I2=np.array([1.36439, -0.5]))
    assert not arm.parameters_valid(bad)
    with pytest.raises(ParameterError):
        RobotParameters(I2=-0.5)


def test_the_rrpr_closed_form_inertia_partials_agree_with_central_differences():
    arm = RobotParameters()
    q = np.array([[0.3, 1.1, 0.2, -0.4], [-2.0, 2.9, 0.1, 1.0]])
    exact = arm.closed_form_inertia_partials(q)
    h = 1e-5
    for j in range(4):
        dq = np.zeros(4)
        dq[j] = h
        np.testing.assert_allclose(exact[..., j, :, :], (arm.inertia(q + dq) - arm.inertia(q - dq)) / (2 * h),
                                   atol=1e-8)
    # M depends on theta2 alone: the other partials vanish
    assert np.abs(exact[..., [0, 2, 3], :, :]).max() < 1e-9


def test_the_rrpr_laceration_path_is_its_closed_form():
    arm = RobotParameters()
    path = arm.laceration_path(stitches=3, duration=6.0)
    assert isinstance(path, LacerationPath) and path == LacerationPath(params=arm, stitches=3, duration=6.0)


def test_a_chain_answers_for_itself(chain):
    assert chain.paper is None and not chain.stacks_constants and chain.laceration_path() is None
    assert chain.parameter_names() == () and chain.calculated_parameters() == ()
    assert chain.closed_form_inertia_partials(np.zeros(chain.n)) is None
    with pytest.raises(KeyError, match="has no parameter"):
        chain.with_parameters(m1=1.0)
    # at rest at 0 where the range holds 0, else the middle of the range
    expected = [0.0 if lo <= 0.0 <= hi else 0.5 * (lo + hi) for lo, hi in chain.joints.limits]
    assert chain.rest_pose() == expected
    assert chain.joints.outside_limits(chain.rest_pose()) is None
    assert chain.in_words().startswith(f"the {chain.n}-joint arm {list(chain.joints.names)}")


def test_the_fmu_variables_follow_the_arms_answers(chain):
    from blocks.model.disturbances import DisturbanceSpec
    from fmu.variables import plant_parameter_values, plant_variables

    spec = DisturbanceSpec(kinds=("friction",))
    rrpr = {v.name: v for v in plant_variables(RobotParameters(), spec, 4)}
    assert all(rrpr[n].causality == "parameter" and rrpr[n].positive == (n not in ("g", "d1", "d4"))
               for n in TABLE_1)
    assert rrpr["I1"].unit == "kg.m2" and rrpr["k4"].unit == "kg" and rrpr["k4"].causality == "calculatedParameter"
    assert plant_parameter_values(RobotParameters(m1=7.0), spec)["m1"] == 7.0
    spec_chain = DisturbanceSpec(kinds=(), f_r=(0.0,) * chain.n, coulomb=(0.0,) * chain.n,
                                 viscous=(0.0,) * chain.n)
    names = {v.name for v in plant_variables(chain, spec_chain, 4)}
    assert not names & (set(TABLE_1) | {"k1", "k2", "k3", "k4", "k5"})


def test_the_rrpr_exported_map_gives_its_constants_and_the_margins_of_a_positive_definite_inertia():
    """The plant FMU's map of the paper's arm, run on numbers: [k1..k5, g] of Eq. 5-7 (the arm's own kernel
    parameters), the tool lengths, and the margins k1 - k3, k3 - k5, (k1-k3)(k3-k5) - k2^2/4 -- positive for Table 1
    (M(q) positive definite for every theta2: its eigenvalues at theta2 = 0 and pi, by numpy, are > 0) and
    negative for sets whose M(q) is not (a negative I1 breaks k1 > k3, a negative I2 k3 > k5); a URDF arm has no map."""
    arm = default_arm()
    values = arm.parameter_values()
    kernel, tool, calculated, margins = arm.exported_parameter_map(values)
    np.testing.assert_array_equal(np.array(kernel, dtype=float), arm.kernel_params())
    np.testing.assert_array_equal(np.array(tool, dtype=float), arm.tool_params())
    k1, k2, k3, k4, k5 = (float(c[3]) for c in calculated)
    assert [m for _, m in margins] == ["k1 > k3", "k3 > k5", "(k1-k3)(k3-k5) > k2^2/4"]
    np.testing.assert_allclose([float(m) for m, _ in margins],
                               [k1 - k3, k3 - k5, (k1 - k3) * (k3 - k5) - k2 * k2 / 4.0], rtol=1e-12)
    assert all(float(m) > 0 for m, _ in margins)
    for theta2 in (0.0, math.pi):
        assert np.linalg.eigvalsh(arm.inertia(np.array([0.0, theta2, 0.1, 0.0]))).min() > 0
    for name, broken in (("I1", 0), ("I2", 1)):
        bad = dict(values, **{name: -10.0 * values[name]})
        assert float(arm.exported_parameter_map(bad)[3][broken][0]) < 0


def test_a_chain_has_no_exported_map(chain):
    assert chain.exported_parameter_map({}) is None
