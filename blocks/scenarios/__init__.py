"""Scenarios: the TOML files shipped here, the scenario object and its one key checker, the URDF arm a scenario
names, and the suturing task (a task-space path) on any arm."""
from blocks.lazy import lazy_exports

__getattr__, __dir__ = lazy_exports(__name__, {}, globals())
