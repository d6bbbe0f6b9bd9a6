"""The kitchen recipe's scripted expert (one episode, all four subtasks) and its Minari dataset:
Minari reads it, `rfmp_rl.data.read_minari` reads it, and `kitchen_episodes` turns it (and a
``D4RL/kitchen``-style copy with joint-velocity actions) into the env's layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from recipe_loader import load_script

pytest.importorskip("gymnasium_robotics")
pytest.importorskip("minari")

ROOT = Path(__file__).resolve().parents[2]
experts = load_script("kitchen", "experts")  # recipes/kitchen/experts.py, not robosuite's

from rfmp_rl.data import read_minari  # noqa: E402
from rfmp_rl.data.episodes import DataError  # noqa: E402
from rfmp_rl.envs.kitchen import (  # noqa: E402
    KITCHEN_TASKS,
    FrankaKitchenEnv,
    KitchenInstance,
    kitchen_episodes,
)

SEED = 11


@pytest.fixture(scope="module")
def record():
    inst = KitchenInstance()
    rec = experts.run_expert_episode(inst, experts.KitchenExpert(), SEED)
    inst.close()
    rec["seed"] = SEED
    return rec


@pytest.fixture(scope="module")
def dataset(record, tmp_path_factory):
    path = tmp_path_factory.mktemp("kitchen") / "kitchen-expert-v0"
    experts.write_minari_kitchen(path, [record, record], extra_metadata={"note": "test"})
    return path


def test_expert_completes_all_four_subtasks(record):
    assert record["success"], record["completed"]
    assert record["steps"] < 280
    assert record["rewards"].sum() == 4  # one per subtask
    assert record["terminations"][-1] and not record["terminations"][:-1].any()
    q = record["actions"]["ee_pose"][:, 3:7]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    assert record["observations"]["observation"].shape == (record["steps"] + 1, 59)


def test_minari_reads_the_dataset(dataset, record):
    import minari

    ds = minari.MinariDataset(dataset / "data")
    assert ds.total_episodes == 2 and ds.total_steps == 2 * record["steps"]
    ep = next(ds.iterate_episodes())
    np.testing.assert_allclose(ep.actions["ee_pose"], record["actions"]["ee_pose"])
    assert sorted(ep.observations["achieved_goal"]) == sorted(KITCHEN_TASKS)
    assert ds.storage.metadata["dataset_id"] == "rfmp/kitchen-expert-v0"


def test_read_minari_layout(dataset, record):
    eps, manifest = read_minari(dataset)
    assert len(eps) == 2
    ep = eps[0]
    t = record["steps"]
    assert ep["action", "ee_pose"].shape == (t, 9)
    assert ep["action", "joint_velocity"].shape == (t, 9)
    assert ep["observation", "observation"].shape == (t, 59)
    assert ep["observation", "achieved_goal", "kettle"].shape == (t, 7)
    assert manifest.extra["dataset_id"] == "rfmp/kitchen-expert-v0"


def test_kitchen_episodes_match_the_env(dataset, record):
    eps, manifest = kitchen_episodes(dataset)
    assert manifest.extra["kitchen_action_source"] == "ee_pose"
    ep = eps[0]
    assert ep["observation"].shape == (record["steps"], 66)
    env = FrankaKitchenEnv([1], seeds=[SEED])
    first = env.reset()["observation"][0]
    env.close()
    torch.testing.assert_close(ep["observation"][0], first)
    assert ep["action"][0, 6] >= 0  # w >= 0 at the first step
    torch.testing.assert_close(ep["action"][:, :3],
                               torch.as_tensor(record["actions"]["ee_pose"][:, :3],
                                               dtype=torch.float32))


def test_d4rl_style_joint_velocity_dataset(record, tmp_path):
    """A dataset with D4RL/kitchen's flat joint-velocity actions: the ee_pose action is the
    forward kinematics of the joint positions reached at the next step."""
    from gymnasium import spaces
    from minari.data_collector.episode_buffer import EpisodeBuffer
    from minari.dataset.minari_storage import MinariStorage

    inst = KitchenInstance()
    storage = MinariStorage.new(tmp_path / "data", observation_space=inst.sim.observation_space,
                                action_space=spaces.Box(-1.0, 1.0, (9,), dtype=np.float64),
                                jpeg_encoding=False)
    inst.close()
    storage.update_episodes([EpisodeBuffer(
        id=0, observations=record["observations"],
        actions=record["actions"]["joint_velocity"], rewards=record["rewards"],
        terminations=record["terminations"], truncations=record["truncations"], infos={})])
    eps, manifest = kitchen_episodes(tmp_path)
    assert manifest.extra["kitchen_action_source"] == "joint_velocity_fk"
    action, obs = eps[0]["action"].numpy(), eps[0]["observation"].numpy()
    # the pose reached: the next step's observed site pose (and finger positions)
    np.testing.assert_allclose(action[:-1, :3], obs[1:, 18:21], atol=1e-6)
    np.testing.assert_allclose(action[:-1, 7:9], np.clip(obs[1:, 7:9], 0, 0.04), atol=1e-6)
    # ... which trails the expert's own pose commands by the controller's lag
    gap = np.linalg.norm(action[:, :3] - record["actions"]["ee_pose"][:, :3], axis=1)
    assert np.median(gap) < 0.05, np.median(gap)
    np.testing.assert_allclose(np.linalg.norm(action[:, 3:7], axis=1), 1.0, atol=1e-5)


def test_kitchen_episodes_refuses_other_layouts(tmp_path):
    from gymnasium import spaces
    from minari.data_collector.episode_buffer import EpisodeBuffer
    from minari.dataset.minari_storage import MinariStorage

    storage = MinariStorage.new(tmp_path / "data",
                                observation_space=spaces.Box(-1, 1, (4,), dtype=np.float64),
                                action_space=spaces.Box(-1, 1, (9,), dtype=np.float64))
    storage.update_episodes([EpisodeBuffer(
        id=0, observations=np.zeros((3, 4)), actions=np.zeros((2, 9)), rewards=np.zeros(2),
        terminations=np.zeros(2, bool), truncations=np.zeros(2, bool), infos={})])
    with pytest.raises(DataError, match="59-D kitchen observation"):
        kitchen_episodes(tmp_path)


def test_writer_never_overwrites(dataset, record):
    with pytest.raises(FileExistsError, match="already there"):
        experts.write_minari_kitchen(dataset, [record])


def test_writer_takes_a_relative_path(record, tmp_path, monkeypatch):
    """The CLI's default ``--out`` is relative: Minari gets an absolute folder, the dataset
    appears complete at the path asked for and no partial folder is left beside it."""
    import minari

    monkeypatch.chdir(tmp_path)
    experts.write_minari_kitchen(Path("data/kitchen/ds"), [record])
    data = tmp_path / "data" / "kitchen" / "ds" / "data"
    assert sorted(p.name for p in data.parent.iterdir()) == ["data"]
    assert minari.MinariDataset(data).total_episodes == 1


def test_writer_refuses_a_folder_with_files(record, tmp_path):
    (tmp_path / "ds" / "data").mkdir(parents=True)
    (tmp_path / "ds" / "data" / "notes.txt").write_text("a user's file")
    with pytest.raises(FileExistsError, match="not empty"):
        experts.write_minari_kitchen(tmp_path / "ds", [record])
    assert (tmp_path / "ds" / "data" / "notes.txt").read_text() == "a user's file"


def test_expert_through_the_torchrl_env():
    """The same expert acting through `FrankaKitchenEnv` (TorchRL rollout) succeeds, and the
    episode ends (terminated) at its success."""
    env = FrankaKitchenEnv([1], seeds=[SEED + 1])
    out = env.rollout(280, experts.ExpertPolicy(env), break_when_any_done=False,
                      break_when_all_done=True)
    env.close()
    nxt = out["next"]
    assert bool(nxt["success"][0, -1, 0]) and bool(nxt["terminated"][0, -1, 0])
    assert not nxt["success"][0, :-1, 0].any()
    assert nxt["reward"][0].sum().item() == 4
    norms = out["action"][0, :, 3:7].norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms), atol=1e-5, rtol=0)


def test_generate_demos_writes_the_expert_metadata(tmp_path):
    info = experts.generate_demos(1, tmp_path / "ds", seed_start=SEED + 2, verbose=False)
    assert info["successes"] == 1 and info["seeds"] == [SEED + 2]
    eps, manifest = read_minari(tmp_path / "ds")
    assert len(eps) == 1
    import json

    meta = json.loads((tmp_path / "ds" / "data" / "metadata.json").read_text())
    assert meta["expert"]["seeds"] == [SEED + 2] and meta["control_freq_hz"] == 12.5
    assert meta["total_episodes"] == 1 and meta["total_steps"] == info["steps"]
    with pytest.raises(RuntimeError, match="only 0 of 1"):
        experts.generate_demos(1, tmp_path / "none", max_attempts=0, verbose=False)
    assert not (tmp_path / "none").exists()
