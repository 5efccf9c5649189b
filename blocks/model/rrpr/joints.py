"""The paper's RRPR joints: ``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]`` and ranges.

Examples
--------
>>> from blocks.model.rrpr.joints import RRPR_JOINTS
>>> RRPR_JOINTS.count
4
>>> RRPR_JOINTS.labels[2]
'Joint 3 (d3)'
"""
from __future__ import annotations

import math

from blocks.model.joints import JointSpace

__all__ = ["RRPR_JOINTS", "D3_STROKE"]

#: Stroke of the paper's prismatic joint d3 (m, positive downwards).  The paper gives no stroke; Table 1's
#: d3 = 0.24 m is the stage's working extension (the tool at the skin), and the stroke is taken as 0 to twice that
#: (docs/model.md, "Joint ranges").
D3_STROKE = (0.0, 0.48)

#: The paper's arm: ``[theta1 (rad), theta2 (rad), d3 (m, positive downwards), theta4 (rad)]``.  The revolute
#: joints of a SCARA turn without end (the elbow's singularities are the path's concern); d3 has its stroke.
#: The analyses survey it within those ranges, the prismatic range spanning the laceration path's depths (about
#: 0.24 m) with a wide margin, revolute joints a full turn; the grid is fine along theta2, the only joint its
#: inertia depends on.
RRPR_JOINTS = JointSpace(names=("theta1", "theta2", "d3", "theta4"),
                         kinds=("revolute", "revolute", "prismatic", "revolute"),
                         limits=((-math.inf, math.inf), (-math.inf, math.inf), D3_STROKE, (-math.inf, math.inf)),
                         survey_ranges=((-math.pi, math.pi), (-math.pi, math.pi), (0.10, 0.35), (-math.pi, math.pi)),
                         survey_points=(5, 73, 3, 5))
