"""End to end: ``pe-drake identify --payload`` from q/tau CSVs (filtered, not sample-aligned runs)
of an optimized payload motion, to payload.json with the vendor formats and the URDF."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.simulation.payload_synthetic import payload_run, random_box_payload, random_true_arm
from tests.conftest import get_robot
from tests.test_payload_identification import _plan


def test_identify_payload_command_writes_payload_json_and_urdf(tmp_path, capsys):
    robot, plan = get_robot("ur5"), _plan("ur5")
    plan.write(tmp_path / "motion", robot)
    rng = np.random.default_rng(24)
    arm, payload = random_true_arm(robot, rng), random_box_payload(rng)
    loaded = payload_run(robot, plan.motion, arm, "tool0", payload, seed=1)
    empty = payload_run(robot, plan.motion, arm, "tool0", None, rate_hz=900.0, seed=2)
    write_measurement_csv(tmp_path / "loaded.csv", loaded.replace(v=None, vd=None))
    write_measurement_csv(tmp_path / "unloaded.csv", empty.replace(v=None, vd=None))
    args = ["identify", "--robot", "ur5", "--payload", "tool0", "--data", str(tmp_path / "loaded.csv"),
            "--unloaded", str(tmp_path / "unloaded.csv"), "--trajectory", str(tmp_path / "motion" / "trajectory.json"),
            "--out", str(tmp_path / "out")]
    assert main(args) == 0
    d = json.loads((tmp_path / "out" / "payload.json").read_text())
    assert abs(d["mass"] - payload.mass) < 0.005 * payload.mass
    assert np.linalg.norm(np.array(d["com"]) - payload.com) < 1e-3
    assert len(d["inertia_about_com"]) == len(d["inertia_about_com_std"]) == 6
    assert d["vendor"]["flange"] == "tool0" and d["vendor"]["ur"]["set_payload"].startswith("set_payload(")
    assert "pe_drake_payload" in (tmp_path / "out" / "model_with_payload.urdf").read_text()
    assert "set_target_payload(" in capsys.readouterr().out
    # A motion optimized for another link is refused; so is a second --data without --payload.
    assert main([*args[:4], "wrist_3_link", *args[5:-1], str(tmp_path / "out2")]) == 2
    assert "optimized for a payload on 'tool0'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["identify", "--robot", "ur5", "--data", "a.csv", "--data", "b.csv", "--out", str(tmp_path / "o3")])
