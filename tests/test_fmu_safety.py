"""Memory safety around native FMU code: log routing, closed instances, restored FMU states.

A regression in these places crashes the interpreter (segmentation fault)
rather than raising, so each crash-prone scenario runs in a child Python
process: a crash then fails the test (non-zero exit code) instead of ending
pytest.  The FMUs are real: the plant exported by dobkit (FMI 2 and 3) and
the hand-written lag FMU of tests/fmu_lag.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fmu import FMUInstance, FMUStepError, export_plant
from fmu.package import package_fmu

LAG_DIR = Path(__file__).parent / "fmu_lag"

pytestmark = pytest.mark.needs_cc          # every test builds the plant or the lag FMU


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("safety")
    return {
        2: export_plant(folder / "plant2.fmu", fmi_version=2),
        3: export_plant(folder / "plant3.fmu", fmi_version=3),
        "lag": package_fmu(folder / "lag.fmu", (LAG_DIR / "modelDescription.xml").read_text(),
                           {"lag.c": LAG_DIR / "lag.c"}, ["lag.c"], "lag", 2),
    }


# Each script prints "key: value" lines.  They use FMUInstance (cheap to import); "closed" also load().
LOGGER_SCRIPT = """
import gc, sys
import numpy as np
from fmu import FMUInstance, FMUStepError

def fail(inst, t, u):
    inst.set_time(t)
    inst.set_states(np.zeros(8))
    inst.set_real(inst.value_references([f"tau[{i}]" for i in range(4)]), u)
    try:
        inst.derivatives()
    except FMUStepError as err:
        return str(err)
    return "no error"

a = FMUInstance(sys.argv[1], "ModelExchange", name="A")
b = FMUInstance(sys.argv[2], "ModelExchange", name="B")   # loaded last: the one that captured every message
print("A first:", fail(a, 0.3, [0.0, np.inf, 0.0, 0.0]))
print("A log:", a.messages)
print("B log:", b.messages)
b.close()
del b
gc.collect()
junk = [bytearray(256) for _ in range(20000)]                # reuse the memory of B's callback
print("A second:", fail(a, 0.4, [np.nan, 0.0, 0.0, 0.0]))
print("done: yes")
"""

CLOSED_SCRIPT = """
import sys
import numpy as np
from fmu import FMUError, FMUInstance, load
x, u = np.zeros(8), np.zeros(4)
for version, path in (("2", sys.argv[1]), ("3", sys.argv[2])):
    s = load(path)
    s.fmu.close()
    s.fmu.close()                                            # idempotent
    cs = FMUInstance(path, "CoSimulation")
    vr = cs.value_references(["q[0]"])
    cs.close()
    calls = {"rhs": lambda: s._rhs(0.0, x, u), "out": lambda: s._out(0.0, x, u),
             "set_time": lambda: s.fmu.set_time(0.1), "derivatives": lambda: s.fmu.derivatives(),
             "get_states": lambda: s.fmu.get_states(), "do_step": lambda: cs.do_step(0.0, 0.01),
             "get_real": lambda: cs.get_real(vr), "set_real": lambda: cs.set_real(vr, [1.0]),
             "get_integer": lambda: cs.get_integer("n_substeps")}
    for name, call in calls.items():
        try:
            call()
            print(f"{version} {name}: returned")
        except FMUError as err:
            print(f"{version} {name}: {err}")
print("done: yes")
"""

STATES_SCRIPT = """
import sys
from fmpy.fmi1 import FMICallException
from fmu import FMUInstance

def blob(f):
    fm = f._fmu
    if f.fmi_version == 2:
        return bytearray(fm.serializeFMUstate(fm.getFMUstate()))
    return bytearray(fm.serializeFMUState(fm.getFMUState()))

def restore(f, data):
    fm = f._fmu
    if f.fmi_version == 2:
        fm.setFMUstate(fm.deSerializeFMUstate(bytes(data)))
    else:
        fm.setFMUState(fm.deserializeFMUState(bytes(data)))

def first_difference(a, b):
    return min(i for i in range(len(a)) if a[i] != b[i])

for version, path in (("2", sys.argv[1]), ("3", sys.argv[2])):
    me, cs = FMUInstance(path, "ModelExchange"), FMUInstance(path, "CoSimulation")
    cs5 = FMUInstance(path, "CoSimulation", start_values={"n_substeps": 5})
    mode_at = first_difference(blob(me), blob(cs))          # same data, modes continuous-time vs step
    sub_at = first_difference(blob(cs), blob(cs5))          # same data but n_substeps
    good = blob(cs)
    cases = {"mode 10": (mode_at, 10), "mode 2^20": (mode_at, 2 ** 20), "mode -1": (mode_at, -1),
             "n_substeps 0": (sub_at, 0), "n_substeps -7": (sub_at, -7)}
    for name, (offset, value) in cases.items():
        data = bytearray(good)
        data[offset:offset + 4] = value.to_bytes(4, "little", signed=True)
        try:
            restore(cs, data)
            cs.do_step(cs.time, 0.01)
            print(f"{version} {name}: accepted")
        except FMICallException as err:
            print(f"{version} {name}: refused {err.function} | {cs.messages[-1]}")
    try:
        restore(cs, blob(me))                                # a Model Exchange state into Co-Simulation
        print(f"{version} ME state in CS: accepted")
    except FMICallException as err:
        print(f"{version} ME state in CS: refused {err.function} | {cs.messages[-1]}")
    restore(cs, good)                                        # an untouched state still works
    cs.do_step(0.0, 0.01)
    print(f"{version} good: stepped to {cs.time:g}")
print("done: yes")
"""


@pytest.fixture(scope="module", autouse=True)
def children(fmus, tmp_path_factory):
    """The three child processes, started together with the module (they run while the in-process tests do)."""
    cwd = tmp_path_factory.mktemp("children")
    runs = {"logger": (LOGGER_SCRIPT, fmus[2], fmus["lag"]), "closed": (CLOSED_SCRIPT, fmus[2], fmus[3]),
            "states": (STATES_SCRIPT, fmus[2], fmus[3])}
    started = {key: subprocess.Popen([sys.executable, "-c", code, *map(str, args)], cwd=cwd, text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
               for key, (code, *args) in runs.items()}
    yield started
    for child in started.values():
        if child.poll() is None:
            child.kill()
            child.communicate()


def lines(child: subprocess.Popen) -> dict[str, str]:
    """``key: value`` lines a child printed; fails on a crash (negative exit code) or any error exit."""
    stdout, stderr = child.communicate(timeout=300)
    assert child.returncode == 0, f"child exited with {child.returncode}\n{stdout}\n{stderr[-3000:]}"
    return dict(line.split(": ", 1) for line in stdout.splitlines() if ": " in line)


# --- in this process (no crash possible): messages of the failing call, no terminate after an error ------

def test_an_error_names_only_messages_of_the_failing_call(fmus):
    """The lag logs 'exceeds x_max' on a failed step; a later silent failure must not repeat it."""
    with FMUInstance(fmus["lag"], "CoSimulation", start_values={"x_max": 0.5}) as lag:
        u, e = lag.value_references(["u"]), lag.value_references(["e"])
        lag.set_real(u, [1.0])
        with pytest.raises(FMUStepError, match="exceeds x_max"):
            for k in range(100):
                lag.do_step(0.1 * k, 0.1)
        with pytest.raises(FMUStepError) as err:
            lag.set_real(e, [0.0])                    # e is computed: the lag refuses without a message
    message = str(err.value)
    assert "exceeds" not in message and message.endswith("during setting inputs (the FMU logged no message)")


@pytest.mark.parametrize("version", [2, 3])
def test_no_terminate_after_an_error_status(fmus, version):
    """After an error only freeing is allowed: the plant FMU logs any refused fmiTerminate."""
    f = FMUInstance(fmus[version], "CoSimulation")
    tau = f.value_references([f"tau[{i}]" for i in range(4)])
    f.set_real(tau, [0.0, np.nan, 0.0, 0.0])
    with pytest.raises(FMUStepError, match="non-finite"):
        f.do_step(0.0, 0.01)
    log = f.messages
    f.close()
    assert f.closed and not any("Terminate" in m for m in log), log


# --- 1: log messages -------------------------------------------------------------------------------------

def test_each_fmi2_instance_gets_its_own_messages_and_a_freed_one_crashes_nothing(children):
    out = lines(children["logger"])
    assert "non-finite derivative" in out["A first"] and "at t = 0.3 s" in out["A first"]
    assert "non-finite derivative" in out["A log"]
    assert out["B log"] == "[]"
    assert "non-finite derivative" in out["A second"] and "t = 0.4" in out["A second"]
    assert "t = 0.29" not in out["A second"]          # only what the failing call logged
    assert out["done"] == "yes"


# --- 2: closed instances ---------------------------------------------------------------------------------

def test_every_call_on_a_closed_instance_raises(children):
    out = lines(children["closed"])
    assert out.pop("done") == "yes"
    assert len(out) == 18
    for key, message in out.items():
        assert message.endswith("the FMU instance is closed; load the FMU again to use it"), (key, message)


# --- 3: FMU states from outside --------------------------------------------------------------------------

def test_tampered_serialized_states_are_refused(children):
    """Offsets are found by comparing real states, not assumed: ME vs CS differ only in the mode."""
    out = lines(children["states"])
    assert out.pop("done") == "yes"
    for version in ("2", "3"):
        deser = "fmi2DeSerializeFMUstate" if version == "2" else "fmi3DeserializeFMUState"
        for name, words in (("mode 10", "mode 10 is not a valid instance mode"),
                            ("mode 2^20", f"mode {2 ** 20} is not a valid instance mode"),
                            ("mode -1", "mode -1 is not a valid instance mode"),
                            ("n_substeps 0", "n_substeps must be >= 1, got 0"),
                            ("n_substeps -7", "n_substeps must be >= 1, got -7"),
                            ("ME state in CS", "belongs to a Model Exchange instance")):
            got = out[f"{version} {name}"]
            assert got.startswith(f"refused {deser}") and words in got, (version, name, got)
        assert out[f"{version} good"] == "stepped to 0.01"
