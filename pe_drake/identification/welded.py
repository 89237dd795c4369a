"""Rigid groups of bodies merged before the physical fit.

Bodies that no excited joint separates (a link and the tool, flange, sensor and cover links
welded to it: the same ``Robot.joint_of_body``) move as one body, so only their sum is
identifiable: body i's regressor columns are the carrier's times the fixed map L_i that moves its
parameters into the carrier's frame (J_C = X_CB J_B X_CBᵀ). Fitted as separate bodies, the fit
moved mass between them at no cost to the data.

:func:`merge_welded` builds the problem with one body per group (the carrier, the member
heaviest a priori, holding the sum); :meth:`WeldedGroups.split` returns per-body parameters, each
member physically valid, their sum the group's, nearest the a-priori values
(:func:`nearest_split`, a small SDP), or, when the solver finds none, the whole group on the
carrier (the others massless; the dynamics are the same).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import NoSolutionFound
from pe_drake.identification.physical_fit import SDP_TOLERANCES, InertiaBlock, solve_sdp
from pe_drake.multibody.inertia import phi_from_pseudo_inertia, pseudo_inertia, validity_problems

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

P = 10  # parameters per body


def moved_parameters_map(X: np.ndarray) -> np.ndarray:
    """L (10, 10) with φ_C = L φ_B the parameters of a body B expressed in frame C, X = X_CB
    (4, 4): the pseudo-inertia transforms as J_C = X J_B Xᵀ (linear in φ)."""
    return np.column_stack([phi_from_pseudo_inertia(X @ pseudo_inertia(e) @ X.T) for e in np.eye(P)])


def _bodies(count: int) -> str:
    """'body' or 'bodies' after a count."""
    return "body" if count == 1 else "bodies"


@dataclasses.dataclass(frozen=True)
class WeldedGroups:
    """The rigid groups of a robot's bodies and the merged problem's bodies.

    Attributes:
        kept: the merged problem's bodies (carriers, single bodies), robot body indices, in order.
        members: {carrier: [(member, L_member)]} of the groups (the carrier not listed).
    """

    kept: tuple[int, ...]
    members: dict[int, list[tuple[int, np.ndarray]]]

    def cols(self) -> np.ndarray:
        """The standard-parameter columns of the kept bodies, (10·len(kept),)."""
        return np.concatenate([np.arange(P * b, P * b + P) for b in self.kept]).astype(int)

    def names(self, body_names: Sequence[str]) -> list[str]:
        """The merged problem's body names, a carrier's saying it holds its group."""
        counts = {b: len(group) for b, group in self.members.items()}
        return [f"{body_names[b]} (with its {counts[b]} welded {_bodies(counts[b])})" if b in counts
                else body_names[b] for b in self.kept]

    def prior(self, prior: np.ndarray) -> np.ndarray:
        """The merged problem's a-priori parameters: each carrier the sum of its group."""
        out = np.asarray(prior, float)[self.cols()].copy()
        for k, b in enumerate(self.kept):
            for member, L in self.members.get(b, ()):
                out[P * k : P * k + P] += L @ prior[P * member : P * member + P]
        return out

    def split(self, phi_merged: np.ndarray, prior: np.ndarray, body_names: Sequence[str]) -> tuple[np.ndarray, list[str]]:
        """The robot's per-body parameters (module docstring) and a note per group."""
        prior = np.asarray(prior, float)
        phi = np.zeros_like(prior)
        phi[self.cols()] = phi_merged
        notes = []
        for carrier, group in self.members.items():
            bodies = [carrier] + [m for m, _ in group]
            maps = [np.eye(P)] + [L for _, L in group]
            names = [body_names[m] for m, _ in group]
            head = (f"{body_names[carrier]} and the {len(group)} {_bodies(len(group))} welded to it "
                    f"({', '.join(names[:3])}{', …' if len(names) > 3 else ''}) fitted as one body")
            parts = nearest_split(phi[P * carrier : P * carrier + P], [prior[P * b : P * b + P] for b in bodies], maps)
            if parts is not None and not validity_problems([body_names[b] for b in bodies], np.concatenate(parts)):
                for b, x in zip(bodies, parts):
                    phi[P * b : P * b + P] = x
                notes.append(f"{head}, split among them nearest their a-priori values")
            else:  # phi already holds the whole group on the carrier
                for b in bodies[1:]:
                    phi[P * b : P * b + P] = 0.0
                notes.append(f"{head}, all of it on {body_names[carrier]} (no physically valid split near the "
                             "a-priori values was found); they are massless in the result, the dynamics are the same")
        return phi, notes


#: The split keeps every member's pseudo-inertia ⪰ this × its a-priori mass × 1 (so Drake accepts
#: each body despite the solver's tolerance): a tenth of physical_fit.PSD_MARGIN, since a group on
#: its own boundary leaves the members' sum no more room than that.
SPLIT_MARGIN = 1e-8


def nearest_split(phi_group: np.ndarray, priors: Sequence[np.ndarray], maps: Sequence[np.ndarray]) -> list[np.ndarray] | None:
    """Members' parameters φ_i, each physically valid, with Σ L_i φ_i = φ_group, nearest their
    a-priori values (in units of the group's a-priori magnitudes); None when the SDP finds none.

    Args:
        phi_group: the group's parameters in the carrier's frame, (10,).
        priors: each member's a-priori parameters in its own frame, the carrier first.
        maps: each member's L_i (the carrier's is the identity).
    """
    k = len(priors)
    total = sum(L @ x for L, x in zip(maps, priors))
    m = max(float(total[0]), 1e-9)
    block = np.r_[m, np.full(3, max(np.max(np.abs(total[1:4])), 1e-3 * m)),
                  np.full(6, max(np.max(np.abs(total[4:])), 1e-6 * m))]
    W = np.diag(1.0 / np.tile(block, k) ** 2)
    x0 = np.concatenate(priors)
    blocks = [InertiaBlock(P * i, np.ones(P), SPLIT_MARGIN * float(prior[0])) for i, prior in enumerate(priors)]
    A, b = np.hstack(maps), np.asarray(phi_group, float)  # Σ L_i φ_i = φ_group, row by row
    try:
        sol = solve_sdp(2.0 * W, -2.0 * W @ x0, blocks, x0, rows=[(a, v, v) for a, v in zip(A, b)],
                        what="split of a welded group", tolerances=SDP_TOLERANCES[:1])
    except NoSolutionFound:
        return None
    return [sol[P * i : P * i + P] for i in range(k)]


def merge_welded(robot: Robot, prior: np.ndarray, bounded: Sequence[str] = ()) -> WeldedGroups:
    """The rigid groups of ``robot``'s bodies with an a-priori mass (module docstring); a body
    the user bounds (``bounded``: mass bounds, CoM boxes) stays a body of its own."""
    from pydrake.multibody.tree import BodyIndex  # lazy: pydrake is heavy

    plant, ctx = robot.plant, robot.plant.CreateDefaultContext()
    names, prior = robot.body_names, np.asarray(prior, float)
    members: dict[int, list[tuple[int, np.ndarray]]] = {}
    grouped: set[int] = set()
    for joint in sorted(set(int(j) for j in robot.joint_of_body)):
        group = [b for b, j in enumerate(robot.joint_of_body)
                 if j == joint and prior[P * b] > 0 and names[b] not in bounded]
        if len(group) < 2:
            continue
        carrier = max(group, key=lambda b: prior[P * b])
        frame_c = plant.get_body(BodyIndex(int(robot.body_indices[carrier]))).body_frame()
        members[carrier] = []
        for b in group:
            if b == carrier:
                continue
            frame_b = plant.get_body(BodyIndex(int(robot.body_indices[b]))).body_frame()
            X = plant.CalcRelativeTransform(ctx, frame_c, frame_b).GetAsMatrix4()
            members[carrier].append((b, moved_parameters_map(X)))
            grouped.add(b)
    kept = tuple(b for b in range(len(names)) if b not in grouped)
    return WeldedGroups(kept, members)
