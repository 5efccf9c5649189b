"""The arm a plant FMU was exported from, recorded in the FMU so that ``dobkit fmu check`` can rebuild it.

The paper's arm needs no record: its Table-1 values are the FMU's parameters
(:func:`fmu.plant_check.plant_from_description` reads them back).  Another
arm's geometry and inertias are constants in the generated C; the export
writes them to ``resources/dobkit_arm.json`` -- the joints (names, kinds,
ranges) and every number of its :class:`~blocks.kernels.chain.ChainParams`,
floats written exactly (JSON keeps the 17 significant digits of ``repr``) --
and :func:`arm_from_record` builds the same :class:`~blocks.model.urdf.ChainArm`
from it, without the URDF file or pinocchio.
"""
from __future__ import annotations

import json
import math

__all__ = ["ARM_RECORD", "arm_record", "arm_from_record", "RECORD_FORMAT"]

#: The record's path inside the FMU archive.
ARM_RECORD = "resources/dobkit_arm.json"
#: Bumped when the layout changes; a record of another format is refused by name.
RECORD_FORMAT = 1


def _plain(value):
    """Tuples as lists, infinities as None (strict JSON)."""
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _tuples(value):
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def arm_record(arm) -> str | None:
    """The JSON text recording ``arm`` (a chain arm), or None for an arm that needs no record (the paper's).

    Raises
    ------
    TypeError
        For an arm model that is neither the paper's nor a chain arm (nothing to record it by).
    """
    from blocks.model.urdf.chain_model import ChainArm

    if arm.paper is not None:            # the paper's arm: its named parameters are in the FMU, nothing to record
        return None
    if not isinstance(arm, ChainArm):
        raise TypeError(f"cannot record an arm of type {type(arm).__name__} in the FMU; "
                        "the export knows the paper's arm and chain (URDF) arms")
    chain = arm.chain
    fields = {name: _plain(getattr(chain, name)) for name in type(chain).__dataclass_fields__}
    record = {"format": RECORD_FORMAT, "model": "chain", "tool_frame": arm.tool_frame, "source": arm.source,
              "continuous": list(arm.continuous),
              "joints": {"names": list(arm.joints.names), "kinds": list(arm.joints.kinds),
                         "limits": [[_plain(lo), _plain(hi)] for lo, hi in arm.joints.limits]},
              "chain": fields}
    return json.dumps(record, indent=1, allow_nan=False) + "\n"


def arm_from_record(text: str):
    """The :class:`~blocks.model.urdf.ChainArm` of a record written by :func:`arm_record`.

    Raises
    ------
    ValueError
        If the text is not such a record (its format, model or fields), naming what is wrong.
    """
    from blocks.kernels.chain import ChainParams
    from blocks.model.joints import JointSpace
    from blocks.model.urdf.chain_model import ChainArm

    try:
        record = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{ARM_RECORD} is not JSON: {err}") from None
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT or record.get("model") != "chain":
        raise ValueError(f"{ARM_RECORD} is not a chain-arm record of format {RECORD_FORMAT} (got format "
                         f"{record.get('format') if isinstance(record, dict) else None!r})")
    try:
        j = record["joints"]
        limits = tuple((-math.inf if lo is None else float(lo), math.inf if hi is None else float(hi))
                       for lo, hi in j["limits"])
        joints = JointSpace(names=tuple(j["names"]), kinds=tuple(j["kinds"]), limits=limits)
        chain = ChainParams(**{name: _tuples(value) for name, value in record["chain"].items()})
        return ChainArm(chain, joints, record["tool_frame"], continuous=record.get("continuous"),
                        source=record.get("source"))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{ARM_RECORD} does not describe a chain arm: {err}") from None
