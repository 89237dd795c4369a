"""The simulated robot moves free of contact; where its capsules would touch, the run says so.

The collision capsules (``robot.capsules``) are a conservative envelope for the optimizer's
self-collision margin, not the links' contact geometry, and Drake's penalty force on their
overlap is no term of any model pe_drake fits (BUILD_NOTES, "Simulated runs without contact").
So :func:`without_contact` filters every pair of the simulated plant, and
:func:`capsule_contacts` tells where a real robot with links of those shapes would collide.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pe_drake.multibody.robot import Robot

#: Checking more than this many configurations per second of motion adds nothing (the
#: capsules move a few mm between checks at the arm's speeds).
CHECK_RATE_HZ = 100.0


def without_contact(robot: Robot) -> None:
    """Filters every collision pair of ``robot``'s SceneGraph in its diagram context, so the
    plant applies no contact force (the geometry stays, for queries of its own)."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role  # lazy: pydrake is heavy

    sg = robot.scene_graph
    ids = sg.model_inspector().GetAllGeometryIds(Role.kProximity)
    if ids:
        sg_context = sg.GetMyMutableContextFromRoot(robot.context)
        sg.collision_filter_manager(sg_context).Apply(CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids)))


@dataclasses.dataclass(frozen=True)
class CapsuleContact:
    """Two links whose capsules overlap during a run."""

    pair: str  # "link_a-link_b"
    depth: float  # the largest overlap [m]
    start: float  # first time of the overlap [s]
    end: float  # last time of the overlap [s]

    def to_dict(self) -> dict[str, float]:
        return {"max_overlap_m": self.depth, "from_s": self.start, "to_s": self.end}


def capsule_contacts(robot: Robot, t: np.ndarray, q: np.ndarray) -> list[CapsuleContact]:
    """The capsule pairs of ``robot`` (the a-priori one: its filters skip adjacent links and the
    capsule file's ignored pairs) that overlap along the motion, checked at most
    :data:`CHECK_RATE_HZ`; t (K,) [s], q (K, n) [rad]."""
    if not getattr(robot, "capsules", ()) or len(t) == 0:
        return []
    step = max(1, int(np.floor((len(t) - 1) / max(t[-1] - t[0], 1e-9) / CHECK_RATE_HZ)))
    plant, sg = robot.plant, robot.scene_graph
    context = robot.plant_context
    sg_context = sg.GetMyContextFromRoot(robot.context)
    inspector = sg.model_inspector()
    found: dict[str, list[float]] = {}
    for k in range(0, len(t), step):
        plant.SetPositions(context, q[k])
        query = sg.get_query_output_port().Eval(sg_context)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.0):
            if pair.distance >= 0:
                continue
            names = sorted(plant.GetBodyFromFrameId(inspector.GetFrameId(g)).name() for g in (pair.id_A, pair.id_B))
            entry = found.setdefault("-".join(names), [0.0, float(t[k]), float(t[k])])
            entry[0], entry[2] = max(entry[0], -pair.distance), float(t[k])
    return [CapsuleContact(name, *values) for name, values in sorted(found.items())]
