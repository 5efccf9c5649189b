"""Start values of every FMI type reach the FMU unchanged, or are refused before they wrap (findings F2, F5).

The Reference FMU Feedthrough copies each input to the output of the same type, so a value set as a start value
is read back from the output.  Ranges are those of the C types: Int8 [-128, 127], UInt8 [0, 255], FMI 2 Integer
[-2^31, 2^31 - 1].
"""
from __future__ import annotations

import numpy as np
import pytest
from reference_fmus import reference_fmus  # noqa: F401 - the fixture

from fmu import FMUInstance, FMUStartValueError, FMUUnsupportedError, load

pytestmark = pytest.mark.needs_cc


def feedthrough(reference_fmus, version, start_values):  # noqa: F811
    return FMUInstance(reference_fmus(version, "Feedthrough"), kind="CoSimulation", start_values=start_values,
                       check_interface=False)


@pytest.mark.parametrize("name, value, words", [
    ("Int8_input", 1000, r"1000 is outside the range of its type: a whole number in \[-128, 127\] \(Int8\)"),
    ("UInt8_input", -1, r"-1 is outside the range of its type: a whole number in \[0, 255\] \(UInt8\)"),
    ("UInt64_input", 2 ** 64, r"\d+ is outside the range of its type: a whole number in \[0, 18446744073709551615\]"),
    ("Int16_input", 2.5, r"2.5 is not a whole number in \[-32768, 32767\] \(Int16\)"),
    ("Int32_input", True, r"True is not a whole number"),
    ("Float32_continuous_input", 1e39, r"1e\+39 is outside the Float32 range"),
    ("String_input", 3, r"3 is not a string \(String\)"),
    ("Boolean_input", 2, r"2 is not a Boolean"),
])
def test_fmi3_start_values_outside_their_type_are_refused(reference_fmus, name, value, words):  # noqa: F811
    with pytest.raises(FMUStartValueError, match=rf"Feedthrough.fmu: start value of {name}: {words}"):
        feedthrough(reference_fmus, 3, {name: value})


def test_fmi3_start_values_of_every_type_arrive(reference_fmus):  # noqa: F811
    values = {"Int8_input": -128, "UInt8_input": 255, "Int16_input": -300, "UInt64_input": 2 ** 63 + 1,
              "Float32_continuous_input": 1.5, "Boolean_input": True, "String_input": "héllo wörld",
              "Enumeration_input": 2}
    with feedthrough(reference_fmus, 3, values) as inst:
        inst.do_step(0.0, 0.1)
        np.testing.assert_array_equal(inst.read(["Int8_output", "UInt8_output", "Int16_output",
                                                 "Float32_continuous_output", "Boolean_output",
                                                 "Enumeration_output"]), [-128, 255, -300, 1.5, 1, 2])
        out = inst.variables["UInt64_output"].valueReference
        assert inst._fmu.getUInt64([out])[0] == 2 ** 63 + 1               # exact beyond 2^53
        assert inst._fmu.getString([inst.variables["String_output"].valueReference]) == ["héllo wörld"]


def test_fmi2_integer_is_a_c_int_and_strings_are_settable(reference_fmus):  # noqa: F811
    with pytest.raises(FMUStartValueError, match=r"2147483648 is outside the range of its type: a whole number in "
                                                 r"\[-2147483648, 2147483647\] \(FMI 2 Integer\)"):
        feedthrough(reference_fmus, 2, {"Int32_input": 2 ** 31})
    with feedthrough(reference_fmus, 2, {"Int32_input": -2 ** 31, "String_input": "abc"}) as inst:
        inst.do_step(0.0, 0.1)
        assert inst.read(["Int32_output"])[0] == -2 ** 31
        assert inst._fmu.getString([inst.variables["String_output"].valueReference]) == [b"abc"]


def test_a_discrete_input_is_refused_at_load_not_at_the_first_set(reference_fmus):  # noqa: F811
    """F5: Float64_discrete_input may be set only at events; a block sets its inputs in continuous time."""
    with pytest.raises(FMUUnsupportedError, match=r"inputs of discrete variability, which may be set only at "
                                                  r"events: .*Float64_discrete_input"):
        load(reference_fmus(3, "Feedthrough"))


# Written for wrong changes of tests/mutation_probe.py that the rest of the suite let through: each docstring
# names the mutants the test kills (python tests/mutation_probe.py --only ID --killers shows it).
def test_the_largest_float32_is_a_float32_start_value_and_the_next_double_is_not():
    """sv-float32-max.  IEEE 754 binary32's largest finite value (numpy's finfo) is in the type; a double just
    above it is not."""
    from types import SimpleNamespace

    from fmu.errors import FMUStartValueError
    from fmu.start_values import checked_start_value

    var = SimpleNamespace(name="x", type="Float32")
    top = float(np.finfo(np.float32).max)
    assert checked_start_value(var, top, 3) == [top]
    assert checked_start_value(var, -top, 3) == [-top]
    with pytest.raises(FMUStartValueError, match="outside the Float32 range"):
        checked_start_value(var, float(np.nextafter(top, np.inf)), 3)
