from __future__ import annotations

import pytest
import torch
from torch import nn

from rfmp_rl.modules import EMA


def test_ema_tracks_the_weights_with_the_given_decay():
    net = nn.Linear(1, 1, bias=False)
    nn.init.zeros_(net.weight)
    ema = EMA(net, decay=0.9, warmup=False)
    with torch.no_grad():
        net.weight.fill_(1.0)
    ema.update(net)
    torch.testing.assert_close(ema.module.weight, torch.tensor([[0.1]]))
    ema.update(net)
    torch.testing.assert_close(ema.module.weight, torch.tensor([[0.19]]))
    assert not ema.module.weight.requires_grad


def test_warmup_follows_diffusion_policy_and_caps_at_decay():
    ema = EMA(nn.Linear(1, 1), decay=0.999)
    assert ema.current_decay() == pytest.approx(0.1)
    ema.set_num_updates(10_000)
    assert ema.current_decay() == pytest.approx(0.999)
    with pytest.raises(ValueError, match="decay"):
        EMA(nn.Linear(1, 1), decay=1.0)
