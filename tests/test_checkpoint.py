"""Checkpoints: exact round trip, atomic writes, clear errors."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.checkpoint import load_checkpoint, read_checkpoint, save_checkpoint
from rfmp_rl.modules import EMA

ALGOS = ["rfmp", "srfmp", "ddim"]


def _train_a_little(model, steps=3):
    from tensordict import TensorDict

    from rfmp_rl.objectives import make_loss

    model.action_normalizer.fit(model.chunk.unflatten(model.chunk.random_base(64)))
    model.obs_normalizer.fit(torch.randn(64, model.cfg.obs_dim) * 3)
    loss = make_loss(model)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    ema = EMA(model, 0.9)
    for _ in range(steps):
        td = TensorDict(
            {
                "observation": torch.randn(8, 2, model.cfg.obs_dim),
                "action": model.chunk.unflatten(model.chunk.random_base(8)),
            },
            [8],
        )
        value = sum(v for k, v in loss(td).items() if k.startswith("loss_"))
        opt.zero_grad()
        value.backward()
        opt.step()
        ema.update(model)
    return ema


@pytest.mark.parametrize("algorithm", ALGOS)
def test_round_trip_gives_bit_identical_actions(tmp_path, make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "R3 x S3 x R1", horizon=4)
    ema = _train_a_little(model)
    path = save_checkpoint(tmp_path / "ckpt.pt", model, ema, config={"lr": 1e-3}, epoch=7)
    obs = torch.randn(5, 2, 3)
    noise = torch.randn(5, model.noise_dim)
    for use_ema, reference in [(True, ema.module), (False, model)]:
        loaded, payload = load_checkpoint(path, use_ema=use_ema)
        reference.eval()
        with torch.no_grad():
            expected = reference.sample(reference.encode(obs), noise, nfe=2)
            got = loaded.sample(loaded.encode(obs), noise, nfe=2)
        assert torch.equal(expected, got)
    assert payload["algorithm"] == algorithm
    assert payload["horizons"] == {"T_p": 4, "T_a": 2, "T_o": 2}
    assert payload["manifold"]["type"] == "product"
    assert payload["config"] == {"lr": 1e-3} and payload["extra"] == {"epoch": 7}
    torch.testing.assert_close(loaded.action_normalizer.scale, model.action_normalizer.scale)


def test_a_failure_during_save_leaves_the_previous_checkpoint_readable(
    tmp_path, make_tiny_model, monkeypatch
):
    model = make_tiny_model("srfmp", "S2")
    path = save_checkpoint(tmp_path / "ckpt.pt", model, epoch=1)
    before = path.read_bytes()

    def dying_save(obj, f, *args, **kwargs):
        f.write(b"half a checkpoint")  # partial bytes reach the disk, then the process "dies"
        raise KeyboardInterrupt("killed mid-save")

    monkeypatch.setattr(torch, "save", dying_save)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, model, epoch=2)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert read_checkpoint(path)["extra"] == {"epoch": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temporary file left


def test_unreadable_or_foreign_files_are_refused_with_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        read_checkpoint(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt"):
        read_checkpoint(junk)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(ValueError, match="expected format"):
        read_checkpoint(foreign)


def test_checkpoints_store_the_loss_config_and_the_control_rate(tmp_path, make_tiny_model):
    from rfmp_rl.modules import FlowPolicy
    from rfmp_rl.objectives import LossConfig, make_loss

    model = make_tiny_model("srfmp")
    cfg = LossConfig(time_sampling="tau", time_max=3.0, t0_fraction=0.2)
    path = save_checkpoint(tmp_path / "a.pt", FlowPolicy(model), loss=cfg, control_rate_hz=20.0)
    payload = read_checkpoint(path)
    assert LossConfig.from_dict(payload["loss"]) == cfg and payload["control_rate_hz"] == 20.0
    loss = make_loss(model, cfg)  # a loss module gives its options
    assert read_checkpoint(save_checkpoint(tmp_path / "b.pt", model, loss=loss))["loss"] == (
        cfg.to_dict())
    bare = read_checkpoint(save_checkpoint(tmp_path / "c.pt", model))
    assert bare["loss"] is None and bare["control_rate_hz"] is None
    with pytest.raises(TypeError, match="LossConfig"):
        save_checkpoint(tmp_path / "d.pt", model, loss={"time_max": 2.0})
    with pytest.raises(ValueError, match="control_rate_hz"):
        save_checkpoint(tmp_path / "d.pt", model, control_rate_hz=0.0)


#: The model config of a checkpoint written before LossConfig existed (Push-T state SRFMP,
#: small preset, written out by hand): training options and the rate inside it.
OLD_MODEL_CONFIG = {
    "algorithm": "srfmp", "action_manifold": "S2", "horizon": 4, "action_steps": 2,
    "obs_horizon": 2, "obs_dim": 3, "obs_manifold": None, "obs_keys": [["observation", 3]],
    "cameras": {}, "crop_shape": None, "vision_pool": "spatial_softmax", "vision_out_dim": 512,
    "unet_preset": "small", "down_dims": [16, 32], "time_embed_dim": 256, "kernel_size": 5,
    "tau_hidden_dim": 512, "prior_sphere": "uniform", "prior_scale": 1.0, "prior_std": 1.0,
    "prior_repeat": True, "lambda_x": 2.5, "lambda_tau": 2.0, "tau0": 0.0, "tau1": 1.0,
    "time_sampling": "tau", "time_max": 2.0, "t0_fraction": 0.5, "num_diffusion_steps": 100,
    "clip_sample": True, "control_rate_hz": 10.0,
}


def _old_checkpoint(tmp_path, model_config):
    from rfmp_rl.checkpoint import CHECKPOINT_FORMAT
    from rfmp_rl.modules import ModelConfig, build_model

    fields = {k: v for k, v in model_config.items() if k in ModelConfig.__dataclass_fields__}
    torch.manual_seed(0)
    model = build_model(ModelConfig(**fields))
    payload = {  # the entries save_checkpoint wrote then (no "loss", no "control_rate_hz")
        "format": CHECKPOINT_FORMAT, "rfmp_rl_version": "0.1.0", "algorithm": "srfmp",
        "manifold": model.step_manifold.spec(), "horizons": {"T_p": 4, "T_a": 2, "T_o": 2},
        "model_config": dict(model_config), "state_dict": model.state_dict(),
        "ema_state_dict": None, "ema_num_updates": 0, "config": {"lr": 1e-4}, "extra": {},
    }
    torch.save(payload, tmp_path / "old.pt")
    return tmp_path / "old.pt", model


def test_a_checkpoint_written_before_the_loss_config_loads(tmp_path):
    from rfmp_rl.modules import FlowPolicy, ModelConfig
    from rfmp_rl.objectives import LossConfig

    path, model = _old_checkpoint(tmp_path, OLD_MODEL_CONFIG)
    payload = read_checkpoint(path)
    assert LossConfig.from_dict(payload["loss"]) == LossConfig(
        time_sampling="tau", time_max=2.0, t0_fraction=0.5, lambda_x=2.5, lambda_tau=2.0)
    assert payload["control_rate_hz"] == 10.0
    # every field of today's ModelConfig but the ones added since (their defaults apply)
    added = {"obs_quaternions", "tau_max"}
    assert set(payload["model_config"]) == set(ModelConfig.__dataclass_fields__) - added
    loaded, _ = load_checkpoint(path)
    assert loaded.cfg.obs_quaternions is None  # raw observations, as it was trained
    # the explicit embedding sizes it stored rebuild the same network
    assert (loaded.cfg.time_embed_dim, loaded.cfg.tau_hidden_dim) == (256, 512)
    for name, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], value), name
    assert FlowPolicy.from_checkpoint(path).model.cfg.lambda_x == 2.5
    # the dict itself no longer builds a ModelConfig, and says how to convert it
    with pytest.raises(ValueError, match=r"time_max -> LossConfig.time_max.*read_checkpoint"):
        ModelConfig.from_dict(OLD_MODEL_CONFIG)


def test_an_unknown_field_in_an_old_checkpoint_still_raises(tmp_path):
    path, _ = _old_checkpoint(tmp_path, OLD_MODEL_CONFIG)
    payload = torch.load(path, weights_only=True)
    payload["model_config"]["warp_factor"] = 9
    torch.save(payload, tmp_path / "odd.pt")
    read_checkpoint(tmp_path / "odd.pt")  # the payload reads
    with pytest.raises(ValueError, match=r"cannot rebuild .*unknown fields \['warp_factor'\]"):
        load_checkpoint(tmp_path / "odd.pt")
