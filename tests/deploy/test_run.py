"""The command line: ``--check`` on the robot PC, ``--robot module:factory`` to drive a robot."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from rfmp_deploy.run import check, main
from toy_policy import ToySpec, example_spec


def test_check_prints_metadata_and_latency(make_model, capsys):
    path = make_model(example_spec())
    assert main(["--model", str(path), "--check", "--runs", "5", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    assert "horizons:     T_o=2, T_p=16, T_a=8 at 10 Hz" in out
    assert "observation:  eef_pos[3], eef_quat[4], gripper[1] -> D_obs=8" in out
    assert "camera:       wrist: RGB uint8, resized to 84x84" in out
    assert "action:       R3 x S3 x R1 (D=8)" in out
    assert "CPUExecutionProvider" in out
    assert "latency:      median" in out and "p95" in out and "over 5 runs" in out


def test_check_numbers(make_policy):
    timing = check(make_policy(ToySpec()), runs=4)
    assert 0 < timing["median_ms"] <= timing["p95_ms"] <= timing["max_ms"]
    assert timing["period_ms"] == pytest.approx(100.0)


def test_bad_model_is_reported_not_raised(make_model, capsys):
    path = make_model(overrides={"rfmp_rl.format": "something/else"})
    assert main(["--model", str(path), "--check"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "rfmp_rl.format" in err


def test_drives_a_robot_from_a_factory(make_model, tmp_path, monkeypatch, capsys):
    (tmp_path / "fake_arm.py").write_text(textwrap.dedent("""
        import numpy as np

        class Arm:
            def __init__(self):
                self.sent = []

            @property
            def done(self):
                return len(self.sent) >= 4

            def read_observation(self):
                return {"pos": np.zeros(3), "quat": np.array([0, 0, 0, 1.0])}

            def send_action(self, action):
                self.sent.append(action)

        ARM = Arm()

        def make():
            return ARM
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    path = make_model(ToySpec())
    code = main(["--model", str(path), "--robot", "fake_arm:make", "--rate", "200", "--async",
                 "--deterministic"])
    assert code == 0
    import fake_arm

    assert len(fake_arm.ARM.sent) == 4
    assert all(a.shape == (8,) and np.isfinite(a).all() for a in fake_arm.ARM.sent)
    out = capsys.readouterr().out
    assert "4 steps in" in out and "underrun" in out  # async: the first step holds


def test_robot_mode_needs_a_factory(make_model):
    path = make_model(ToySpec())
    with pytest.raises(SystemExit):
        main(["--model", str(path)])
    with pytest.raises(SystemExit, match="module:factory"):
        main(["--model", str(path), "--robot", "no_colon"])
