"""The parts of python-control's systems that dobkit's engines read, reached through this one module.

python-control describes an interconnection by public attributes
(``syslist``, ``connect_map``, ``input_map``, ``output_map``, each block's
``updfcn``, ``outfcn`` and ``params``) and evaluates systems through the
private ``_rhs``/``_out`` (what ``dynamics``/``output`` call after updating
their parameters).  The engines and the co-simulation master read these
through the functions below, and :func:`check_python_control` confirms that
the installed python-control still keeps them as this module assumes; a
test runs it, so a release that changes them fails with a message saying
what changed rather than with wrong numbers.
"""
from __future__ import annotations

import control as ct
import numpy as np

__all__ = ["subsystems", "connection_maps", "output_function", "update_function", "merged_params",
           "fast_dynamics", "fast_output", "check_python_control", "PythonControlChanged"]


class PythonControlChanged(RuntimeError):
    """The installed python-control no longer keeps what dobkit's engines read."""


def subsystems(system) -> list:
    """The blocks of an interconnection, in the order of its state, input and output vectors."""
    return list(system.syslist)


def connection_maps(system) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(connect_map, input_map, output_map)`` of an interconnection as float arrays.

    Block inputs are ``connect_map @ y + input_map @ u`` with ``y`` all block
    outputs stacked; the interconnection's outputs are
    ``output_map @ [y; block inputs]``.
    """
    return (np.asarray(system.connect_map, dtype=float), np.asarray(system.input_map, dtype=float),
            np.asarray(system.output_map, dtype=float))


def output_function(block):
    """A block's output function ``f(t, x, u, params)`` (python-control's ``outfcn``), or None."""
    return block.outfcn


def update_function(block):
    """A block's update function ``f(t, x, u, params)`` (python-control's ``updfcn``), or None."""
    return block.updfcn


def merged_params(system, block, params=None) -> dict:
    """The parameters python-control passes ``block`` inside ``system`` when called with ``params``.

    python-control's rule: the block's own ``params``, overridden by the
    interconnection's, overridden by those given at call time.
    """
    local = dict(block.params)
    local.update(system.params)
    if params:
        local.update(params)
    return local


def fast_dynamics(system):
    """``f(t, x, u) -> dx`` with the system's current parameters (python-control's ``_rhs``)."""
    return system._rhs


def fast_output(system):
    """``f(t, x, u) -> y`` with the system's current parameters (python-control's ``_out``)."""
    return system._out


def check_python_control() -> None:
    """Raise :class:`PythonControlChanged` unless python-control keeps what this module reads.

    A two-block loop with a parameter is built and evaluated both ways: by
    python-control's public ``dynamics``/``output`` and by the attributes and
    functions above.
    """
    def fail(what: str):
        raise PythonControlChanged(f"python-control {ct.__version__}: {what}; dobkit's engines read it "
                                   "(blocks.diagram.control_compat) and must be updated for this release")

    gain = ct.nlsys(None, lambda t, x, u, p: -p["a"] * u, inputs="e", outputs="v", name="gain", params={"a": 1.0})
    integ = ct.nlsys(lambda t, x, u, p: u, lambda t, x, u, p: x, inputs="v", outputs="e", states="x", name="integ")
    loop = ct.interconnect([gain, integ], inplist=[], outlist=["e"], name="loop")
    for attr in ("syslist", "connect_map", "input_map", "output_map", "params"):
        if not hasattr(loop, attr):
            fail(f"an interconnection has no attribute '{attr}'")
    blocks = subsystems(loop)
    if [b.name for b in blocks] != ["gain", "integ"]:
        fail("syslist no longer lists the blocks in the order given")
    C, B, O = connection_maps(loop)
    if C.shape != (2, 2) or B.shape != (2, 0) or O.shape[0] != 1:
        fail(f"connect_map/input_map/output_map have shapes {C.shape}, {B.shape}, {O.shape}, not (2, 2), (2, 0), (1, .)")
    x = np.array([2.0])
    for params, expected in ((None, -2.0), ({"a": 5.0}, -10.0)):
        public = float(np.ravel(loop.dynamics(0.0, x, [], params))[0])
        g = merged_params(loop, blocks[0], params)
        e = float(np.ravel(output_function(blocks[1])(0.0, x, [], merged_params(loop, blocks[1], params)))[0])
        v = float(np.ravel(output_function(blocks[0])(0.0, [], np.array([e]), g))[0])
        mine = float(np.ravel(update_function(blocks[1])(0.0, x, np.array([v]), {}))[0])
        if not (public == mine == expected):
            fail(f"with params={params} the loop's derivative is {public} by dynamics() and {mine} through "
                 f"updfcn/outfcn/params (expected {expected})")
    loop.dynamics(0.0, x, [], None)         # back to the block's own parameters
    if float(np.ravel(fast_dynamics(loop)(0.0, x, []))[0]) != -2.0 or \
            float(np.ravel(fast_output(blocks[1])(0.0, x, []))[0]) != 2.0:
        fail("_rhs/_out no longer evaluate a system with its current parameters")
