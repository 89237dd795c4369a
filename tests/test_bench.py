"""The solve benchmark runs end to end and prints its one BENCH line (issue 11)."""

import re

from pe_drake.bench import bench_main as main


def test_bench_solve_prints_every_field(capsys):
    # UR5 converges within a few dozen iterations: a small budget keeps this a smoke test.
    assert main(["solve", "--robot", "ur5", "--max-iterations", "60", "--repeats", "3"]) == 0
    out = capsys.readouterr().out
    line = [row for row in out.splitlines() if row.startswith("BENCH ")]
    assert len(line) == 1
    fields = dict(item.split("=", 1) for item in line[0].split()[1:])
    expected = {
        "robot", "old_s", "new_s", "speedup", "old_cond", "new_cond", "old_iterations", "new_iterations",
        "new_callbacks_s", "new_solver_s", "grad_ms", "match_s", "match_iterations", "match_cond",
    }
    assert set(fields) == expected and fields["robot"] == "ur5"
    assert float(fields["new_cond"]) > 1 and float(fields["grad_ms"]) > 0
    assert re.search(r"old cond \+ 3 % (reached in|not reached)", out)


def test_bench_payload_prints_its_errors(capsys):
    assert main(["payload", "--robot", "ur5", "--payloads", "1", "--seed", "3"]) == 0
    line = [row for row in capsys.readouterr().out.splitlines() if row.startswith("BENCH ")]
    fields = dict(item.split("=", 1) for item in line[0].split()[1:])
    assert fields["robot"] == "ur5" and float(fields["excitation_s"]) > 0
    assert float(fields["mass_percent"]) < 0.5 and float(fields["com_mm"]) < 1.0
