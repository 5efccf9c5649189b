"""Model maths, blocks, scenarios and simulation of the Figure-2 loop.

The public API in a few names::

    import blocks
    scenario = blocks.load_scenario("paper")           # or a path to a TOML file
    loop = blocks.closed_loop(scenario, observer=True)  # a control.InterconnectedSystem
    response = blocks.simulate(scenario)                # a control.TimeResponseData

Subpackages and modules a user may also want: :mod:`blocks.kernels` (the
maths as array functions), :mod:`blocks.figure2.batch` (many variants at once),
:mod:`blocks.figure2.metrics` (tracking metrics), :mod:`blocks.diagram.contract` (what a
block promises the engines).
"""
from importlib.metadata import PackageNotFoundError, version

from blocks.lazy import lazy_exports

try:
    __version__ = version("dobkit")
except PackageNotFoundError:       # a source tree that was never installed
    __version__ = "0+unknown"

# Each public name and the module that defines it.  They are imported on first use (PEP 562), so that
# ``import blocks.scenarios.scenario`` or the command line's ``--version`` do not load python-control, scipy and
# matplotlib; ``from blocks import simulate`` works as before.
_WHERE = {
    "diagram.contract": ("Block", "BlockContract", "ContractError", "contract_of", "kernel_block"),
    "diagram.bound_kernels": ("Kernels",),
    "model.disturbances": ("DisturbanceSpec", "external_disturbance"),
    "model.rrpr.dynamics": ("coriolis_matrix", "coriolis_vector", "forward_dynamics", "gravity", "inertia", "inverse_dynamics",
                 "kinetic_energy"),
    "diagram.gains": ("GainError", "validated_gain"),
    "model.arm": ("ArmModel", "UnreachableError"),
    "model.joints": ("JointSpace",),
    "model.rrpr.joints": ("RRPR_JOINTS",),
    "model.rrpr.kinematics": ("forward_kinematics", "inverse_kinematics", "jacobian"),
    "model.rrpr.laceration": ("LacerationPath",),
    "figure2.loop": ("SimulationError", "build_blocks", "closed_loop", "initial_state", "lumped_disturbance", "simulate"),
    "model.noise": ("MeasurementNoise",),
    "model.rrpr.parameters": ("PAPER_PARAMETERS", "ParameterError", "RobotParameters"),
    "diagram.plan": ("AlgebraicLoopError",),
    "scenarios.scenario": ("Scenario", "ScenarioError", "builtin_scenarios", "load_scenario", "scenario_from_dict"),
    "engines.simulator": ("simulate_system",),
    "engines.context": ("Context",),
    "diagram.systems": ("controller", "observer", "plant", "sensor", "trajectory_block"),
    "diagram.trajectory": ("JointSine",),
}
__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals())


__all__ = [
    "__version__",
    # the loop
    "load_scenario", "builtin_scenarios", "scenario_from_dict", "Scenario", "ScenarioError", "closed_loop",
    "build_blocks", "initial_state", "simulate", "SimulationError", "lumped_disturbance", "AlgebraicLoopError",
    "simulate_system", "Context",
    # blocks and their contract
    "plant", "controller", "observer", "trajectory_block", "sensor", "Block", "BlockContract", "Kernels",
    "ContractError", "contract_of", "kernel_block", "GainError", "validated_gain",
    # the arm
    "ArmModel", "RobotParameters", "PAPER_PARAMETERS", "ParameterError", "JointSpace", "RRPR_JOINTS", "inertia",
    "coriolis_vector", "coriolis_matrix", "gravity", "forward_dynamics", "inverse_dynamics", "kinetic_energy",
    "forward_kinematics", "inverse_kinematics", "jacobian", "UnreachableError",
    # disturbances, noise, paths
    "DisturbanceSpec", "external_disturbance", "MeasurementNoise", "LacerationPath", "JointSine",
]
