"""The command line: ``--check`` on the robot PC, ``--robot module:factory`` to drive a robot."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
from rfmp_deploy.cli import check, main
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


def _fake_arm_module(folder, name: str, steps: int) -> None:
    """``folder/<name>.py``: an arm that is ``done`` after ``steps`` actions; ``make()`` returns
    the module's ``ARM``."""
    (folder / f"{name}.py").write_text(textwrap.dedent(f"""
        import numpy as np

        class Arm:
            def __init__(self):
                self.sent = []

            @property
            def done(self):
                return len(self.sent) >= {steps}

            def read_observation(self):
                return {{"pos": np.zeros(3), "quat": np.array([0, 0, 0, 1.0])}}

            def send_action(self, action):
                self.sent.append(action)

        ARM = Arm()

        def make():
            return ARM
    """))


def test_drives_a_robot_from_a_factory(make_model, tmp_path, monkeypatch, capsys):
    _fake_arm_module(tmp_path, "fake_arm", steps=4)
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


# ----- the rate given to the loop is the controller's period -----------------------------------
def test_check_judges_latency_against_the_given_rate(make_model, make_policy, capsys,
                                                      monkeypatch):
    assert check(make_policy(ToySpec()), runs=2, rate_hz=50.0)["period_ms"] == pytest.approx(20.0)
    path = make_model(ToySpec())
    assert main(["--model", str(path), "--check", "--runs", "3", "--rate", "50"]) == 0
    assert "(period 20.0 ms: OK)" in capsys.readouterr().out
    import rfmp_deploy.cli as cli

    slow = {"median_ms": 12.0, "p95_ms": 12.0, "max_ms": 13.0}
    monkeypatch.setattr(cli, "check", lambda *a, rate_hz=None, **k: {
        **slow, "period_ms": 1e3 / (rate_hz or 10.0)})
    assert main(["--model", str(path), "--check", "--rate", "50"]) == 0
    assert "over half the period: --async is recommended" in capsys.readouterr().out
    assert main(["--model", str(path), "--check", "--rate", "100"]) == 0
    assert "SLOWER than the control period: use --async" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--model", str(path), "--check", "--rate", "0"])


def test_the_cli_goes_asynchronous_when_inference_exceeds_half_the_period(
        make_model, tmp_path, monkeypatch, capsys):
    _fake_arm_module(tmp_path, "arm2", steps=2)
    monkeypatch.syspath_prepend(str(tmp_path))
    import rfmp_deploy.cli as cli

    monkeypatch.setattr(cli, "check", lambda *a, rate_hz=None, **k: {
        "median_ms": 15.0, "p95_ms": 15.0, "max_ms": 15.0, "period_ms": 1e3 / rate_hz})
    path = make_model(ToySpec())
    assert main(["--model", str(path), "--robot", "arm2:make", "--rate", "50"]) == 0
    assert "inference runs asynchronously" in capsys.readouterr().out
    assert main(["--model", str(path), "--robot", "arm2:make", "--rate", "20"]) == 0
    assert "synchronous inference" in capsys.readouterr().out


def test_run_gives_the_controller_its_rate(make_policy):
    from rfmp_deploy import Controller, run
    from toy_policy import make_observation

    now = [0.0]
    spec = ToySpec()

    class Slow:
        def __init__(self, policy):
            self.policy, self.meta = policy, policy.meta

        def __call__(self, *inputs):
            now[0] += 0.03  # 30 ms: under the model's 100 ms period, over 20 ms at 50 Hz
            return self.policy(*inputs)

    class Robot:
        def read_observation(self):
            return make_observation(spec)

        def send_action(self, action):
            pass

    controller = Controller(Slow(make_policy(spec)), clock=lambda: now[0])
    run(controller, Robot(), rate_hz=50.0, max_steps=3, clock=lambda: now[0],
        sleep=lambda s: now.__setitem__(0, now[0] + s))
    overruns = [e for e in controller.events if e.kind == "overrun"]
    assert overruns and "control period 20.0 ms" in overruns[0].message


def test_importing_the_command_line_keeps_the_run_function():
    import rfmp_deploy
    import rfmp_deploy.cli  # noqa: F401  (a submodule named `run` used to replace the function)

    assert callable(rfmp_deploy.run) and rfmp_deploy.run.__module__ == "rfmp_deploy.loop"
