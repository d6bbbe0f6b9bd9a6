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
