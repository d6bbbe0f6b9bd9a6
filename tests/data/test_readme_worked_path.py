"""rfmp_rl/data/README.md, "From a bag to a controller": the topic config, the `rfmp-convert ros`
command, the training code, the export and the deploy check, read from that file and run on two
recorded bags (PoseStamped + Float64 commands, action flat on R3 x S3 x R1). Only the training
budget (steps, batch size) is made smaller."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

pytest.importorskip("rosbags", reason="needs rosbags (rfmp_rl[data])")
pytest.importorskip("onnxruntime", reason="the export check needs onnxruntime")
pytest.importorskip("onnx", reason="the export needs onnx")

from test_rosbag import SEC, T0, Bag, gripper, position, rotation  # noqa: E402

from rfmp_rl.data.convert import main as convert_main  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def worked_path() -> list[tuple[str, str]]:
    """The (language, code) blocks of the data README's section, in order."""
    text = (ROOT / "rfmp_rl" / "data" / "README.md").read_text()
    section = text.split("## From a bag to a controller", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```(\w+)\n(.*?)```", section, flags=re.S)


def record(folder: Path, name: str, sign: float) -> None:
    """3 s at 20 Hz of commanded and measured pose and gripper; ``sign`` -1 records -q."""
    bag = Bag("mcap")
    for k in range(61):
        t = 0.05 * k
        ns = T0 + round(t * SEC)
        bag.pose("/cmd_pose", ns, ns, position(t), sign * rotation(t))
        bag.scalar("/gripper_cmd", ns, gripper(t), "Float64")
        bag.pose("/ee_pose", ns, ns, position(t) - 0.01, rotation(t))
        bag.scalar("/gripper_state", ns, gripper(t) * 0.9, "Float64")
    bag.write(folder / name)


def test_readme_bag_to_controller_runs_as_written(tmp_path, monkeypatch, capsys):
    blocks = worked_path()
    assert [lang for lang, _ in blocks] == ["yaml", "bash", "python", "bash"]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bags").mkdir()
    record(tmp_path / "bags", "run_0", 1.0)
    record(tmp_path / "bags", "run_1", -1.0)  # recorded as -q: trained as +q like run_0
    (tmp_path / "topics.yaml").write_text(blocks[0][1])
    assert yaml.safe_load(blocks[0][1])["action_manifold"] == "R3 x S3 x R1"

    (convert,) = [shlex.split(line, comments=True) for line in blocks[1][1].splitlines() if line]
    assert convert[0].endswith("rfmp-convert")
    assert convert_main(convert[1:]) == 0
    assert "2 episodes, 62 steps, 10 Hz" in capsys.readouterr().out

    code = blocks[2][1]
    small = code.replace("steps=20000", "steps=2, val_batches=1").replace("batch_size=64",
                                                                           "batch_size=4")
    assert small.count("steps=2,") == 1 and small.count("batch_size=4") == 1
    exec(compile(small, "rfmp_rl/data/README.md", "exec"), {})
    assert (tmp_path / "runs" / "teleop" / "best.pt").is_file()

    from rfmp_rl.data import DemonstrationStore

    store = DemonstrationStore.load(tmp_path / "data" / "teleop")
    action = store.episode(1)["action"]
    assert action.shape == (31, 8)
    q = action[:, 3:7].double()
    torch.testing.assert_close(q.norm(dim=-1), torch.ones(31, dtype=torch.float64), atol=1e-6,
                               rtol=0)
    expected = np.array([rotation(t) for t in np.arange(31) / 10])
    np.testing.assert_allclose(q.numpy(), expected, atol=1e-5)  # +q, as run_0

    env = dict(os.environ, PYTHONPATH=f"{ROOT / 'deploy'}{os.pathsep}{ROOT}",
               OMP_NUM_THREADS="1")
    for line in blocks[3][1].splitlines():
        words = shlex.split(line, comments=True)
        words = [w for w in words if not w.startswith("PYTHONPATH=")]
        words[0] = sys.executable
        words = [str(ROOT / w) if w == "export/to_onnx.py" else w for w in words]
        result = subprocess.run(words, cwd=tmp_path, env=env, capture_output=True, text=True,
                                timeout=300)
        assert result.returncode == 0, result.stdout + result.stderr
    assert "action:       R3 x S3 x R1 (D=8)" in result.stdout
    assert (tmp_path / "policy.onnx").is_file()
