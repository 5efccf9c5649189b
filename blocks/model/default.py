"""The arm a function given none works on: the default scenario's (the paper's RRPR with Table 1's values).

Below the diagram and the scenarios, so that a block factory or a report given no arm finds it without importing
the scenario layer; ``blocks/scenarios/paper.toml`` is the same arm, read from its file.
"""
from __future__ import annotations

from blocks.model.arm import ArmModel

__all__ = ["default_arm"]


def default_arm() -> ArmModel:
    """The true arm of the default (paper) scenario: the paper's RRPR with Table 1's values.

    What a function given no arm works on (``fmu.export_plant(path)``, the default joint layout of a report);
    the same arm as ``load_scenario("paper").robot`` without reading the file.
    """
    from blocks.model.rrpr.parameters import PAPER_PARAMETERS
    return PAPER_PARAMETERS
