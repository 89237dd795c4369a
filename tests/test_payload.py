"""The payload model and its vendor formats: columns against Drake with a welded body, the
σ linearization against finite differences, frame changes against Drake's SpatialInertia,
each vendor convention rebuilt, the exported URDF read back by Drake."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pe_drake.exceptions import ConfigError, DataError, UnknownNameError
from pe_drake.identification.payload import PayloadBox, PayloadOptions, box_constraint_rows, identify_payload
from pe_drake.identification.payload_formats import (
    PAYLOAD_LINK_NAME,
    default_flange,
    flange_pose_in_link,
    franka_load,
    kuka_load_data,
    payload_in_flange,
    ur_script,
    urdf_with_payload,
    vendor_formats,
)
from pe_drake.multibody.inertia import phi_to_spatial_inertia, spatial_inertia_to_phi
from pe_drake.multibody.payload import PayloadInertia, box_inertia, central_jacobian, link_columns
from pe_drake.multibody.regressor import RegressorModel
from pe_drake.multibody.robot import load_robot
from pe_drake.multibody.urdf import urdf_text_phi
from pe_drake.simulation.payload_synthetic import random_box_payload
from tests.conftest import get_robot, random_postures


def _payload(seed: int = 0) -> PayloadInertia:
    return random_box_payload(np.random.default_rng(seed))


@pytest.mark.parametrize("name,link", [("panda", "panda_link8"), ("ur5", "tool0")])
def test_payload_columns_are_a_welded_body_in_drake(name, link):
    """Y[:, :, cols(link)] φ_payload is what Drake's inverse dynamics adds for a body welded to link."""
    from pydrake.math import RigidTransform

    robot = get_robot(name)
    payload = _payload(3)
    M = phi_to_spatial_inertia(payload.phi)

    def weld(plant, _sg):
        body = plant.AddRigidBody("extra_payload", plant.GetBodyByName(link).model_instance(), M)
        plant.WeldFrames(plant.GetBodyByName(link).body_frame(), body.body_frame(), RigidTransform())

    loaded = load_robot(name, before_finalize=weld)
    rng = np.random.default_rng(1)
    q = random_postures(robot, 6, 2)
    v, vd = rng.uniform(-1, 1, q.shape), rng.uniform(-3, 3, q.shape)
    Y = RegressorModel(robot)(q, v, vd)
    tau_model = Y @ robot.phi_model + Y[..., link_columns(robot, link)] @ payload.phi
    np.testing.assert_allclose(tau_model, loaded.inverse_dynamics(q, v, vd), atol=1e-9)


def test_unknown_payload_link_lists_the_links():
    robot = get_robot("panda")
    with pytest.raises(UnknownNameError, match="panda_link8"):
        link_columns(robot, "gripper")
    with pytest.raises(DataError, match="at least one loaded run"):
        identify_payload(robot, [], [], "panda_link8")


def test_central_jacobian_matches_finite_differences():
    phi = _payload(5).phi

    def f(x):
        p = PayloadInertia.from_phi(x)
        return np.concatenate([[p.mass], p.com, p.inertia_vector])

    J = central_jacobian(phi)
    h = np.full(10, 1e-5)  # f is quadratic in h and I: central differences are exact there
    fd = np.column_stack([(f(phi + h[k] * e) - f(phi - h[k] * e)) / (2 * h[k]) for k, e in enumerate(np.eye(10))])
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(PayloadInertia.from_phi(phi).phi, phi, atol=1e-14)


def test_frame_change_matches_drake_reexpress_and_shift():
    from pydrake.math import RigidTransform, RollPitchYaw

    p = _payload(7)
    X_LF = RigidTransform(RollPitchYaw(0.3, -1.1, 2.0), [0.05, -0.02, 0.107])
    got = p.in_frame(X_LF.GetAsMatrix4())
    M_L = phi_to_spatial_inertia(p.phi)  # about Lo, in L
    M_F = M_L.Shift(X_LF.translation()).ReExpress(X_LF.rotation().inverse())  # about Fo, in F
    np.testing.assert_allclose(got.phi, spatial_inertia_to_phi(M_F), rtol=1e-10, atol=1e-12)


def test_flange_frames_and_vendor_conventions():
    panda, ur5 = get_robot("panda"), get_robot("ur5")
    assert default_flange(panda) == "panda_link8" and default_flange(ur5) == "tool0"
    # panda_link8 sits 0.107 m along panda_link7's z axis, rotated about it.
    X = flange_pose_in_link(panda, "panda_link7", "panda_link8")
    np.testing.assert_allclose(X[:3, 3], [0, 0, 0.107], atol=1e-9)
    with pytest.raises(ConfigError, match="not rigidly attached"):
        flange_pose_in_link(panda, "panda_link6", "panda_link8")
    p = _payload(9)
    pf = payload_in_flange(panda, p, "panda_link7", "panda_link8")
    np.testing.assert_allclose(pf.com, X[:3, :3].T @ (p.com - X[:3, 3]), atol=1e-12)
    franka = franka_load(pf)
    np.testing.assert_allclose(np.reshape(franka["load_inertia"], (3, 3), order="F"), pf.inertia_about_com)
    assert franka["load_mass"] == pf.mass and franka["F_x_Cload"] == pf.com.tolist()
    ur = ur_script(pf)
    args = json.loads("[" + ur["set_target_payload"][len("set_target_payload(") : -1] + "]")
    assert args[0] == pytest.approx(pf.mass, rel=1e-5)
    np.testing.assert_allclose(args[1], pf.com, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(args[2], pf.inertia_vector, rtol=1e-5, atol=1e-12)
    assert ur["set_payload"].startswith(f"set_payload({pf.mass:.6g}, [")
    kuka = kuka_load_data(pf)
    R = Rotation.from_euler("ZYX", [kuka["A"], kuka["B"], kuka["C"]], degrees=True).as_matrix()
    rebuilt = R @ np.diag([kuka["JX"], kuka["JY"], kuka["JZ"]]) @ R.T
    np.testing.assert_allclose(rebuilt, pf.inertia_about_com, atol=1e-12)
    np.testing.assert_allclose([kuka["X"], kuka["Y"], kuka["Z"]], 1000 * pf.com, atol=1e-9)
    assert kuka["krl"].startswith("LOAD_DATA[1]={M ")
    every = vendor_formats(panda, p, "panda_link7")
    assert every["flange"] == "panda_link8" and set(every) >= {"franka", "ur", "kuka"}


@pytest.mark.parametrize("name,link", [("panda", "panda_link8"), ("ur5", "tool0")])
def test_exported_urdf_carries_the_payload(name, link, tmp_path):
    robot = get_robot(name)
    p = _payload(11)
    text = urdf_with_payload(robot, p, link)
    got = urdf_text_phi(text, [PAYLOAD_LINK_NAME])
    np.testing.assert_allclose(got, p.phi, rtol=1e-9, atol=1e-14)
    path = tmp_path / "with_payload.urdf"
    path.write_text(text)
    loaded = load_robot(dataclasses.replace(robot.config, model=str(path)))  # same joints locked
    q = random_postures(robot, 4, 5)
    v = np.full_like(q, 0.3)
    vd = np.full_like(q, -0.7)
    Y = RegressorModel(robot)(q, v, vd)
    want = Y @ robot.phi_model + Y[..., link_columns(robot, link)] @ p.phi
    np.testing.assert_allclose(loaded.inverse_dynamics(q, v, vd), want, atol=1e-8)


def testbox_constraint_rows_hold_for_a_body_inside_and_fail_outside():
    size = np.array([0.1, 0.2, 0.05])
    box = PayloadBox(center=(0.0, 0.0, 0.1), size=tuple(size))
    inside = PayloadInertia(2.0, np.array([0.0, 0.0, 0.1]), box_inertia(2.0, size))
    assert all(a @ inside.phi >= -1e-12 for a, _ in box_constraint_rows(box))
    shifted = PayloadInertia(2.0, np.array([0.0, 0.0, 0.2]), box_inertia(2.0, size))  # CoM outside
    assert min(a @ shifted.phi for a, _ in box_constraint_rows(box)) < 0
    too_big = PayloadInertia(2.0, np.array([0.0, 0.0, 0.1]), box_inertia(2.0, 2 * size))  # spread outside
    assert min(a @ too_big.phi for a, _ in box_constraint_rows(box)) < 0
    with pytest.raises(ConfigError, match="edge length"):
        PayloadBox(center=(0, 0, 0), size=(0.1, 0.0, 0.1))
    with pytest.raises(ConfigError, match="velocity scale|coulomb_velocity_scale"):
        PayloadOptions(coulomb_velocity_scale=0.0)
