"""Self-collision constraint (Eq. 53): distances, gradients, checks and errors."""

import dataclasses

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.constraints.collision import CollisionConstraint, PostureInCollisionError
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import load_robot
from tests.conftest import random_postures


def _central_differences(constraint, q, h=1e-6):
    K, n = q.shape
    out = np.empty((K, constraint.size, n))
    for j in range(n):
        dq = np.zeros(n)
        dq[j] = h
        plus = constraint.evaluate(q + dq, None, None, derivatives=False).value
        minus = constraint.evaluate(q - dq, None, None, derivatives=False).value
        out[:, :, j] = (plus - minus) / (2 * h)
    return out


@pytest.mark.parametrize("name", ["g1", "panda"])
@pytest.mark.parametrize("aggregate", [True, False])
def test_jacobian_matches_finite_differences(name, aggregate, g1, panda):
    robot = {"g1": g1, "panda": panda}[name]
    constraint = CollisionConstraint(robot, 0.02, aggregate=aggregate)
    q = random_postures(robot, 12, seed=7)
    values = constraint.evaluate(q, None, None)
    fd = _central_differences(constraint, q)
    # Exact segment distances: central differences agree to rounding (~1e-10 m/rad seen);
    # 1e-7 leaves room for a closest point switching regime within ±h.
    assert np.abs(values.d_q - fd).max() < 1e-7
    assert np.abs(values.d_q).max() > 0.05  # not trivially zero


@pytest.mark.parametrize("name", ["g1", "panda"])
def test_distances_match_drake_geometry(name, g1, panda):
    """Our distances equal the exact segment distances of Drake's own geometry poses, and
    Drake's signed distance near contact.

    Away from contact Drake's capsule-capsule distance (GJK) is off by up to ~7 mm at these
    postures (its witness points lie 1-2 mm inside the capsules), so it is only compared
    where |d| < 1 cm; BUILD_NOTES.md measured ~2e-6 m there.
    """
    from pe_drake.multibody.capsules import segment_closest_points

    robot = {"g1": g1, "panda": panda}[name]
    constraint = CollisionConstraint(robot, 0.0, aggregate=False)
    q = random_postures(robot, 20, seed=3)
    ours = constraint.distances(q)
    by_id = {c.geometry_id: k for k, c in enumerate(robot.capsules)}
    column = {frozenset(p): k for k, p in enumerate(constraint.pairs)}
    sg_context = robot.scene_graph.GetMyContextFromRoot(robot.context)
    port = robot.scene_graph.get_query_output_port()
    near = 0
    for k in range(len(q)):
        robot.plant.SetPositions(robot.plant_context, q[k])
        query = port.Eval(sg_context)
        ends = []
        for c in robot.capsules:
            X_WG = query.GetPoseInWorld(c.geometry_id)
            ends.append([X_WG.multiply([0, 0, -c.length / 2]), X_WG.multiply([0, 0, c.length / 2])])
        ends = np.array(ends)
        a, b = np.array(constraint.pairs).T
        s, t = segment_closest_points(ends[a, 0], ends[a, 1], ends[b, 0], ends[b, 1])
        p_a = ends[a, 0] + s[:, None] * (ends[a, 1] - ends[a, 0])
        p_b = ends[b, 0] + t[:, None] * (ends[b, 1] - ends[b, 0])
        radii = np.array([robot.capsules[i].radius + robot.capsules[j].radius for i, j in constraint.pairs])
        assert np.allclose(ours[k], np.linalg.norm(p_a - p_b, axis=1) - radii, atol=1e-12)
        results = query.ComputeSignedDistancePairwiseClosestPoints(100.0)
        assert {frozenset((by_id[d.id_A], by_id[d.id_B])) for d in results} == set(column)
        for d in results:
            if abs(d.distance) < 0.01:
                near += 1
                p = column[frozenset((by_id[d.id_A], by_id[d.id_B]))]
                assert ours[k, p] == pytest.approx(d.distance, abs=2e-5)
    assert near > 0


@pytest.mark.parametrize("name", ["g1", "panda"])
def test_pruned_soft_min_equals_the_soft_min_over_every_pair(name, g1, panda):
    """The aggregate skips pairs whose bounding spheres put them more than 30 h beyond the
    closest pair; value and gradient must equal the log-sum-exp over all pairs (the per-pair
    rows give every d_p and ∂d_p/∂q). Postures near the clap and random ones, where several
    pairs are within a few h of the closest, and none at all (K = 0)."""
    robot = {"g1": g1, "panda": panda}[name]
    aggregate = CollisionConstraint(robot, 0.0)
    every_pair = CollisionConstraint(robot, 0.0, aggregate=False)
    q = random_postures(robot, 40, seed=11)
    if name == "g1":
        q[:10] = robot.nominal_posture()
        for j, value in {0: -1.3, 7: -1.3, 1: -0.25, 8: 0.25}.items():
            q[:10, j] = value
        q[:10, 3] = q[:10, 10] = np.linspace(0.0, 0.5, 10)  # elbows: hands from touching to apart
    pruned = aggregate.evaluate(q, None, None)
    full = every_pair.evaluate(q, None, None)
    h = aggregate.smoothing
    d_min = full.value.min(axis=1, keepdims=True)
    w = np.exp(-(full.value - d_min) / h)
    value = d_min - h * np.log(w.sum(axis=1, keepdims=True))
    d_q = np.einsum("kp,kpn->kn", w / w.sum(axis=1, keepdims=True), full.d_q)
    assert np.sum(w > 1e-3) > len(q)  # some samples do have several pairs near the closest
    np.testing.assert_allclose(pruned.value, value, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pruned.d_q[:, 0], d_q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(aggregate.margins(q, None, None), d_min, rtol=0, atol=1e-15)
    empty = aggregate.evaluate(q[:0], None, None)
    assert empty.value.shape == (0, 1) and empty.d_q.shape == (0, 1, robot.n)


def test_aggregate_is_a_tight_lower_bound_of_the_minimum(g1):
    q = random_postures(g1, 30, seed=5)
    aggregate = CollisionConstraint(g1, 0.02, smoothing=0.002)
    d = aggregate.distances(q)
    g = aggregate.evaluate(q, None, None, derivatives=False).value[:, 0]
    assert (g <= d.min(axis=1) + 1e-15).all()
    assert (g >= d.min(axis=1) - 0.002 * np.log(d.shape[1])).all()
    # margins() reports the exact clearance in metres
    assert np.allclose(aggregate.margins(q, None, None)[:, 0], d.min(axis=1) - 0.02)


def test_shapes_labels_and_bounds(g1):
    q = random_postures(g1, 4, seed=1)
    aggregate = CollisionConstraint(g1, 0.03)
    per_pair = CollisionConstraint(g1, 0.03, aggregate=False)
    P = len(per_pair.pairs)
    assert aggregate.size == 1 and per_pair.size == P == 47
    assert per_pair.labels[0] == per_pair.pair_names[0] and "/" in per_pair.labels[0]
    assert np.all(aggregate.lower == 0.03) and np.all(np.isinf(per_pair.upper))
    full = per_pair.evaluate(q, None, None)
    assert full.value.shape == (4, P) and full.d_q.shape == (4, P, 14) and full.d_v is None
    value_only = aggregate.evaluate(q, None, None, derivatives=False)
    assert value_only.value.shape == (4, 1) and value_only.d_q.shape == (4, 1, 0)
    assert np.allclose(per_pair.evaluate(q[0], None, None).value, full.value[:1])  # (n,) accepted


def test_nominal_posture_is_collision_free(g1, panda):
    q = g1.nominal_posture()
    constraint = CollisionConstraint(g1, 0.02)
    constraint.check_posture(q)  # does not raise
    assert constraint.distances(q).min() > 0.03
    CollisionConstraint(panda, 0.02).check_posture(panda.nominal_posture())


@pytest.mark.parametrize(
    "change, pair",
    [
        ({1: -0.3}, ("left_upper_arm", "torso_left")),  # left arm rolled into the torso
        ({0: -1.3, 7: -1.3, 1: -0.25, 8: 0.25, 3: 0.0, 10: 0.0}, ("left_hand", "right_hand")),  # clap
    ],
)
def test_colliding_posture_names_the_pair(g1, change, pair):
    constraint = CollisionConstraint(g1, 0.02)
    q = np.tile(g1.nominal_posture(), (10, 1))
    for joint, value in change.items():
        q[6, joint] = value
    t = np.linspace(0.0, 0.18, 10)
    with pytest.raises(PostureInCollisionError) as err:
        constraint.check_posture(q, t)
    e = err.value
    assert isinstance(e, InfeasibleError)
    assert e.pair == pair and e.sample == 6 and e.time == pytest.approx(t[6]) and e.violations == 1
    assert e.distance < 0.02 and e.margin == 0.02
    message = str(e)
    assert f"'{pair[0]}' and '{pair[1]}'" in message and "sample 6 (t = 0.120 s)" in message
    assert f"{(0.02 - e.distance) * 1e3:.1f} mm inside the collision margin" in message


def test_errors(g1):
    with pytest.raises(ConfigError, match="no collision capsules"):
        CollisionConstraint(load_robot(dataclasses.replace(resolve_robot_config("ur5").robot, capsules="")), 0.02)
    for margin in (-0.01, float("nan")):
        with pytest.raises(ConfigError, match="collision margin"):
            CollisionConstraint(g1, margin)
    with pytest.raises(ConfigError, match="smoothing"):
        CollisionConstraint(g1, 0.02, smoothing=0.0)
    constraint = CollisionConstraint(g1, 0.02)
    with pytest.raises(ConfigError, match=r"shape \(K, 14\)"):
        constraint.evaluate(np.zeros((3, 7)), None, None)
    with pytest.raises(ConfigError, match="NaN"):
        constraint.distances(np.full(14, np.nan))


def test_every_pair_filtered_is_refused(tmp_path):
    path = tmp_path / "caps.yaml"
    path.write_text(
        "capsules:\n"
        "  - {name: a, link: panda_link3, radius: 0.05, length: 0.1}\n"
        "  - {name: b, link: panda_link4, radius: 0.05, length: 0.1}\n"
    )
    robot = load_robot(dataclasses.replace(resolve_robot_config("panda").robot, capsules=str(path)))
    with pytest.raises(ConfigError, match="every capsule pair is filtered"):
        CollisionConstraint(robot, 0.02)
