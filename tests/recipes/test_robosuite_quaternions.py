"""Observed quaternions in the robosuite recipe: on one recorded PickPlaceCan episode (whose
``obj_to_eef_quat`` robosuite writes with sign jumps), the training data, the evaluation env
replaying the episode and the deploy controller's observation processor see the same
canonical observations; a checkpoint without the rule keeps raw observations everywhere."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from recipe_loader import ROOT, compose, load_recipe

pytest.importorskip("robosuite")
os.environ.setdefault("MUJOCO_GL", "egl")

from rfmp_rl import keys  # noqa: E402
from rfmp_rl.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from rfmp_rl.data import read_robomimic  # noqa: E402
from rfmp_rl.envs.robosuite import ROBOSUITE_LOW_DIM_KEYS, make_robosuite_env  # noqa: E402
from rfmp_rl.modules import build_model  # noqa: E402
from rfmp_rl.onnx_export import InferenceGraph, onnx_metadata  # noqa: E402

SMALL = ["model.down_dims=[16,32]", "threads=1"]


@pytest.fixture(scope="module")
def recipe():
    yield from load_recipe("robosuite")


def _model(utils, cfg, action_dim: int):
    model = build_model(utils.make_model_config(cfg))
    model.action_normalizer.set_stats(-torch.ones(action_dim), torch.ones(action_dim))
    return model


def _controller(model):
    from rfmp_deploy.metadata import parse_metadata
    from rfmp_deploy.observation import ObservationProcessor

    return ObservationProcessor(parse_metadata(onnx_metadata(InferenceGraph(model, nfe=1), 20.0)))


def _raw(td) -> torch.Tensor:
    return torch.cat([td[k][0] for k in ROBOSUITE_LOW_DIM_KEYS], -1)


def test_training_data_env_and_controller_agree_on_a_recorded_episode(recipe, tmp_path,
                                                                      monkeypatch):
    from experts import generate_demos  # recipes/robosuite, on the path while `recipe` lives

    monkeypatch.syspath_prepend(str(ROOT / "deploy"))
    utils = recipe["utils"]
    cfg = compose("robosuite", ["task=PickPlaceCan", "action_space=abs_pose", *SMALL])
    assert cfg.obs_quaternions == "canonical"  # the recipe's default
    path = tmp_path / "can.hdf5"
    (seed,) = generate_demos("PickPlaceCan", 1, "abs_pose", path=str(path), verbose=False,
                             max_attempts=3)["seeds"]
    raw, _ = read_robomimic(path, obs_keys=ROBOSUITE_LOW_DIM_KEYS, load_images=False,
                            raw_quaternion_signs=True)
    (episode,) = utils.policy_episodes(raw, cfg)
    recorded = torch.cat([raw[0]["obs", k].float() for k in ROBOSUITE_LOW_DIM_KEYS], -1)
    rel = recorded[:, 12:16]  # obj_to_eef_quat: robosuite's mat2quat puts w >= 0
    assert bool(((rel[1:] * rel[:-1]).sum(-1) < 0).any()), "the recording has no sign jump"
    training = episode[keys.OBSERVATION]
    assert not torch.equal(training, recorded)
    canonical = training[:, 12:16]
    assert bool(((canonical[1:] * canonical[:-1]).sum(-1) > 0).all())

    processor = _controller(_model(utils, cfg, 8))
    env = make_robosuite_env(**utils.env_kwargs(cfg), batch_size=[1], seeds=[seed])
    td = env.reset()
    seen_env, seen_ctl, seen_raw = [], [], []
    for action in raw[0]["action"].float():
        seen_env.append(td[keys.OBSERVATION][0])
        seen_raw.append(_raw(td))  # what robosuite reports, fed to the controller by key
        frame = processor({k: td[k][0].numpy() for k in ROBOSUITE_LOW_DIM_KEYS})
        seen_ctl.append(torch.from_numpy(frame.lowdim))
        td = env.step(td.set(keys.ACTION, action[None]))["next"]
    env.close()
    torch.testing.assert_close(torch.stack(seen_raw), recorded)  # the replay is the recording
    torch.testing.assert_close(torch.stack(seen_env), training)
    torch.testing.assert_close(torch.stack(seen_ctl), training)
    # the env's windows are built from the canonical vector
    assert torch.equal(td["obs_window"][0, -1], td[keys.OBSERVATION][0])


def test_a_checkpoint_without_the_rule_keeps_raw_observations(recipe, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "deploy"))
    utils = recipe["utils"]
    cfg = compose("robosuite", ["task=Lift", *SMALL])
    model = _model(utils, cfg, 7)
    assert [q["columns"] for q in model.cfg.obs_quaternions] == [[3, 7], [12, 16]]
    path = tmp_path / "old.pt"
    save_checkpoint(path, model, config=OmegaConf.to_container(cfg), control_rate_hz=20.0)
    payload = torch.load(path, weights_only=False)
    del payload["model_config"]["obs_quaternions"]  # written before the rule existed
    torch.save(payload, path)

    old, _ = load_checkpoint(path)
    assert old.cfg.obs_quaternions is None
    kwargs = utils.env_kwargs(cfg, old)
    assert kwargs["obs_quaternions"] is None
    assert "observation_quaternions" not in onnx_metadata(InferenceGraph(old, nfe=1), 20.0)
    processor = _controller(old)
    env = make_robosuite_env(**kwargs, batch_size=[1], seeds=[3])
    td = env.reset()
    for _ in range(3):
        raw = _raw(td)
        torch.testing.assert_close(td[keys.OBSERVATION][0], raw)
        lowdim = processor({k: td[k][0].numpy() for k in ROBOSUITE_LOW_DIM_KEYS}).lowdim
        np.testing.assert_array_equal(lowdim, raw.numpy())
        td = env.step(td.set(keys.ACTION, torch.zeros(1, 7)))["next"]
    env.close()
    # the recipe's raw setting trains without the rule
    raw_cfg = compose("robosuite", ["task=Lift", "obs_quaternions=raw", *SMALL])
    assert utils.make_model_config(raw_cfg).obs_quaternions is None
    with pytest.raises(ValueError, match="obs_quaternions must be 'canonical' or 'raw'"):
        utils.check_config(compose("robosuite", ["task=Lift", "obs_quaternions=sometimes"]))
