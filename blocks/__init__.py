"""Model maths and the block library of the Figure-2 loop.

The public API in a few names::

    import blocks
    scenario = blocks.load_scenario("paper")          # or a path to a TOML file
    loop = blocks.closed_loop(scenario, observer=True) # a control.InterconnectedSystem
    response = blocks.simulate(scenario)               # a control.TimeResponseData
"""
from importlib.metadata import PackageNotFoundError, version

from .disturbances import DisturbanceSpec, external_disturbance
from .dynamics import (coriolis_matrix, coriolis_vector, forward_dynamics, gravity, inertia, inverse_dynamics,
                       kinetic_energy)
from .fastsim import AlgebraicLoopError, CompiledLoop
from .kinematics import UnreachableError, forward_kinematics, inverse_kinematics, jacobian
from .loop import SimulationError, build_blocks, closed_loop, initial_state, lumped_disturbance, simulate
from .noise import MeasurementNoise
from .parameters import PAPER_PARAMETERS, ParameterError, RobotParameters
from .scenario import Scenario, ScenarioError, builtin_scenarios, load_scenario, scenario_from_dict
from .systems import controller, observer, plant, sensor, trajectory_block
from .trajectory import JointSine, LacerationPath

try:
    __version__ = version("dobkit")
except PackageNotFoundError:       # a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["__version__",
    "DisturbanceSpec", "external_disturbance", "coriolis_matrix", "coriolis_vector", "forward_dynamics", "gravity",
    "inertia", "inverse_dynamics", "kinetic_energy", "AlgebraicLoopError", "CompiledLoop", "UnreachableError",
    "forward_kinematics", "inverse_kinematics", "jacobian", "SimulationError", "build_blocks", "closed_loop",
    "initial_state", "lumped_disturbance", "simulate", "MeasurementNoise", "PAPER_PARAMETERS", "ParameterError",
    "RobotParameters", "Scenario", "ScenarioError", "builtin_scenarios", "load_scenario", "scenario_from_dict",
    "controller", "observer", "plant", "sensor", "trajectory_block", "JointSine", "LacerationPath",
]
