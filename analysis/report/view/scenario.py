"""Section 1 of the report: the scenario's settings, written for people, and its complete TOML text."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .text import Table, and_words, arm_joints, fmt, gain_text, gain_units, join, kinds, per_joint, units_list

__all__ = ["ScenarioSection", "scenario_section"]

_VARIANTS = {"correct": "correct (Chen 2000 / Mohammadi 2013)",
             "paper-eq16": "paper-eq16 (Eq. 16 as printed, which leaves a bias while the arm moves)"}


@dataclass(frozen=True)
class ScenarioSection:
    """1. The scenario's settings and its complete TOML text."""

    settings: Table
    toml: str


def _disturbance(data: dict, joints) -> str:
    found = kinds(data["kind"])
    if not found:
        return "none"
    words = []
    for kind in found:
        if kind == "paper":
            words.append(f"paper: the constant step f_r = {join(data['f_r'])} ({units_list(joints.force_units)}; "
                         "Eq. 4)")
        else:
            words.append(kind)
    return and_words(words)


def _trajectory(s) -> str:
    data = s.data["trajectory"]
    if data["kind"] == "laceration":
        return f"laceration: {data['stitches']} stitches in {fmt(data['duration'])} s"
    return data["kind"]


def _noise(s) -> str:
    noise = s.data.get("noise")
    if s.noise is None or not noise or not (np.any(noise["q_std"]) or np.any(noise["dq_std"])):
        return "none"
    joints = arm_joints(s)
    return (f"q: {join(noise['q_std'])} ({units_list(joints.position_units)}); q': {join(noise['dq_std'])} "
            f"({units_list(joints.velocity_units)}); "
            f"seed {noise.get('seed', 0)}")


def scenario_section(s, result) -> ScenarioSection:
    joints = arm_joints(s)
    rows = [["name", s.name], ["source", s.source], ["description", s.data.get("description", "")],
            ["Kp (1/s^2)", per_joint(np.diag(s.kp))], ["Kd (1/s)", per_joint(np.diag(s.kd))],
            [f"observer gain Y ({gain_units(joints)})", gain_text(s.observer_gain)],
            ["observer variant", _VARIANTS.get(s.observer_variant, s.observer_variant)],
            ["trajectory", _trajectory(s)],
            ["disturbance", _disturbance(s.data["disturbance"], joints)],
            ["nominal model = true model", "yes" if s.nominal == s.robot else "no (see [nominal_scale])"],
            ["sensor noise (standard deviations)", _noise(s)],
            ["simulated time (s)", fmt(s.simulation.t_final)]]
    return ScenarioSection(Table.of(["setting", "value"], rows), result.scenario.toml)
