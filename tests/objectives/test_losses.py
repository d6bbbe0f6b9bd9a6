"""Loss modules: keys, masks, outputs, and training from a TorchRL replay buffer."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data import SlicesToChunks
from rfmp_rl.objectives import DiffusionPolicyLoss, RFMPLoss, SRFMPLoss, make_loss

LOSS_KEYS = {"rfmp": {"loss_rfmp"}, "srfmp": {"loss_srfmp", "loss_tau"}, "ddim": {"loss_diffusion"}}


def batch(model, n=16, generator=None):
    chunk = model.chunk
    return TensorDict(
        {
            "observation": torch.randn(n, 2, model.cfg.obs_dim, generator=generator),
            "action": chunk.unflatten(chunk.random_base(n, generator=generator)),
        },
        [n],
    )


def total(out):
    return sum(v for k, v in out.items() if k.startswith("loss_"))


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_losses_return_scalar_loss_entries_and_detached_diagnostics(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "R3 x S3 x R1", horizon=4)
    out = make_loss(model)(batch(model))
    assert {k for k in out.keys() if k.startswith("loss_")} == LOSS_KEYS[algorithm]  # noqa: SIM118 (TensorDict iterates its batch)
    for key, value in out.items():
        assert value.shape == () and torch.isfinite(value)
        assert value.requires_grad == key.startswith("loss_")
    total(out).backward()
    grads = [p.grad for p in model.network.parameters() if p.requires_grad]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)


def test_losses_refuse_the_wrong_model(make_tiny_model):
    with pytest.raises(TypeError, match="RFMP"):
        RFMPLoss(make_tiny_model("srfmp"))
    with pytest.raises(TypeError, match="SRFMP"):
        SRFMPLoss(make_tiny_model("rfmp"))
    with pytest.raises(TypeError, match="DiffusionModel"):
        DiffusionPolicyLoss(make_tiny_model("rfmp"))


def test_a_misshaped_action_chunk_is_refused_with_the_key(make_tiny_model):
    model = make_tiny_model("rfmp", "S2", horizon=4)
    bad = batch(model)
    bad.set("action", torch.randn(16, 5, 3), inplace=False)
    with pytest.raises(ValueError, match=r"'action' must have shape \(B, 4, 3\)"):
        RFMPLoss(model)(bad)


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_mask_excludes_exactly_the_padded_steps(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "S2", horizon=4)
    loss = make_loss(model)
    data = batch(model, generator=torch.Generator().manual_seed(0))
    per_step = {}

    def capture(values, tensordict=None, *, mask=None, **kw):
        if mask is not None:  # the per-step term (loss_tau is per sample, unmasked)
            per_step["values"], per_step["mask"] = values.detach(), mask
        return type(loss)._reduce_loss(loss, values, tensordict, mask=mask, **kw)

    loss._reduce_loss = capture
    pad = torch.zeros(16, 4, dtype=torch.bool)
    pad[3, 1:] = True
    data["action_is_pad"] = pad
    out = loss(data)
    values, mask = per_step["values"], per_step["mask"]
    assert mask.tolist() == (~pad).tolist()
    main = next(k for k in LOSS_KEYS[algorithm] if k != "loss_tau")
    torch.testing.assert_close(out[main], values[~pad].mean())


def test_set_keys_with_nested_keys_trains(make_tiny_model):
    model = make_tiny_model("srfmp", "S2", horizon=4)
    loss = SRFMPLoss(model)
    loss.set_keys(
        observation=("obs", "state"), action=("demo", "action"), action_is_pad=("demo", "pad")
    )
    assert loss.tensor_keys.observation == ("obs", "state")
    assert ("obs", "state") in loss.in_keys
    data = batch(model)
    renamed = TensorDict(
        {
            ("obs", "state"): data["observation"],
            ("demo", "action"): data["action"],
            ("demo", "pad"): torch.zeros(16, 4, dtype=torch.bool),
        },
        [16],
    )
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    before = [p.detach().clone() for p in model.network.parameters()]
    for _ in range(3):
        opt.zero_grad()
        total(loss(renamed)).backward()
        opt.step()
    after = list(model.network.parameters())
    assert any(not torch.equal(b, p) for b, p in zip(before, after, strict=True))
    with pytest.raises(KeyError):
        loss(data)  # the default keys are no longer read
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(velocity="v")


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_losses_train_from_a_replay_buffer_with_a_slice_sampler(make_tiny_model, algorithm):
    from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer

    model = make_tiny_model(algorithm, "R2", obs_dim=2, horizon=4)
    # 6 episodes of a point moving on a line; observation = position, action = next position
    steps = 30
    t = torch.arange(steps, dtype=torch.float32) / steps
    episodes = []
    for e in range(6):
        direction = torch.tensor([1.0, 0.5 * (e - 2.5)])
        pos = t[:, None] * direction
        episodes.append(
            TensorDict(
                {
                    "observation": pos,
                    "action": pos + direction / steps,
                    "episode": torch.full((steps,), e),
                },
                [steps],
            )
        )
    data = torch.cat(episodes)
    rb = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(data)),
        batch_size=32 * 5,
        sampler=SliceSampler(slice_len=5, traj_key="episode", strict_length=True),
    )
    rb.extend(data)
    to_chunks = SlicesToChunks(horizon=4)
    model.action_normalizer.fit(data["action"])
    model.obs_normalizer.fit(data["observation"])
    loss = make_loss(model)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    torch.manual_seed(0)
    history = []
    for _ in range(60):
        sample = to_chunks(rb.sample())
        assert sample.batch_size == (32,) and sample["action"].shape == (32, 4, 2)
        value = total(loss(sample))
        opt.zero_grad()
        value.backward()
        opt.step()
        history.append(float(value))
    assert sum(history[-10:]) < 0.7 * sum(history[:10])


def fixed_batch(model, n=6, pad=None):
    """A batch with fixed prior noise and flow times: the flows' losses are deterministic."""
    gen = torch.Generator().manual_seed(3)
    td = batch(model, n, generator=gen)
    td["prior_noise"] = torch.randn(n, model.noise_dim, generator=gen)
    td["flow_time"] = torch.rand(n, 1, generator=gen)
    if pad is not None:
        td["action_is_pad"] = pad
    return td


def run(loss, td):
    torch.manual_seed(0)  # DDIM's noise and steps
    return loss(td.clone())


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_every_loss_term_honours_reduction(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "S2", horizon=4)
    pad = torch.zeros(6, 4, dtype=torch.bool)
    pad[2, 2:] = True  # sample 2 keeps its first two steps
    pad[4, 1:] = True  # sample 4 keeps one
    td = fixed_batch(model, pad=pad)
    outs = {r: run(make_loss(model, reduction=r), td) for r in ("none", "sum", "mean")}
    for key in LOSS_KEYS[algorithm]:
        none, total, mean = (outs[r][key] for r in ("none", "sum", "mean"))
        assert none.shape == (6,) and total.shape == () and mean.shape == ()
        torch.testing.assert_close(total, none.sum())
        if key == "loss_tau":  # one value per sample: mean is the plain mean
            torch.testing.assert_close(mean, none.mean())
    # the per-step term: "none" is each sample's mean over its valid steps, "mean" weighs
    # every valid step of the batch once
    main = next(k for k in LOSS_KEYS[algorithm] if k != "loss_tau")
    steps = (~pad).sum(-1).float()
    torch.testing.assert_close(outs["mean"][main], (outs["none"][main] * steps).sum() / steps.sum())
    unpadded = fixed_batch(model)
    none = run(make_loss(model, reduction="none"), unpadded)[main]
    torch.testing.assert_close(run(make_loss(model), unpadded)[main], none.mean())
    for key, value in outs["none"].items():  # diagnostics stay scalars
        if not key.startswith("loss_"):
            assert value.shape == ()


@pytest.mark.parametrize("algorithm", ["rfmp", "srfmp", "ddim"])
def test_select_out_keys_works_on_every_loss(make_tiny_model, algorithm):
    model = make_tiny_model(algorithm, "S2", horizon=4)
    loss = make_loss(model)
    keys = sorted(LOSS_KEYS[algorithm])
    assert set(keys) < set(loss.out_keys) or algorithm == "ddim"
    loss.select_out_keys(*keys)
    assert sorted(loss.out_keys) == keys
    out = run(loss, fixed_batch(model))
    assert sorted(out.keys()) == keys
    loss.reset_out_keys()
    assert set(run(loss, fixed_batch(model)).keys()) == set(loss.out_keys)
    with pytest.raises(ValueError, match="non existent key"):
        loss.select_out_keys("loss_nothing")


def test_camera_keys_are_accepted_keys_renamed_with_set_keys():
    from rfmp_rl.modules import ModelConfig, build_model
    from rfmp_rl.objectives import camera_field

    cfg = ModelConfig("rfmp", "S2", obs_dim=3, horizon=4, down_dims=[16, 32],
                      cameras={"cam": [3, 16, 16], "wrist-rgb": [3, 16, 16]},
                      vision_out_dim=8)
    torch.manual_seed(0)
    model = build_model(cfg)
    loss = RFMPLoss(model)
    assert camera_field("wrist-rgb") == "wrist_rgb"
    assert (loss.tensor_keys.cam, loss.tensor_keys.wrist_rgb) == ("cam", "wrist-rgb")
    assert loss.in_keys == ["action", "observation", "cam", "wrist-rgb"]
    loss.set_keys(cam=("pixels", "cam"), wrist_rgb="wrist_window")
    assert loss.camera_keys == {"cam": ("pixels", "cam"), "wrist-rgb": "wrist_window"}
    assert loss.in_keys == ["action", "observation", ("pixels", "cam"), "wrist_window"]
    n = 3
    image = torch.randint(0, 256, (n, 2, 3, 16, 16), dtype=torch.uint8)
    td = TensorDict({"observation": torch.randn(n, 2, 3), ("pixels", "cam"): image,
                     "wrist_window": image, "action": batch(model, n)["action"]}, [n])
    assert torch.isfinite(loss(td)["loss_rfmp"])
    loss.set_keys(cam=None)  # back to the default
    assert loss.tensor_keys.cam == "cam"
    # the constructor argument does the same; unknown cameras are named
    same = RFMPLoss(model, camera_keys={"cam": ("pixels", "cam"), "wrist-rgb": "wrist_window"})
    assert same.camera_keys == {"cam": ("pixels", "cam"), "wrist-rgb": "wrist_window"}
    with pytest.raises(ValueError, match=r"cameras \['front'\]"):
        RFMPLoss(model, camera_keys={"front": "x"})
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(front="x")
    # a loss without cameras keeps the plain accepted keys
    assert "cam" not in RFMPLoss(make_loss_model()).tensor_keys.__dataclass_fields__


def make_loss_model():
    from rfmp_rl.modules import ModelConfig, build_model

    return build_model(ModelConfig("rfmp", "S2", obs_dim=3, horizon=4, down_dims=[16, 32]))
