"""`QuaternionSigns`: the env side of the observed-quaternion rule, one stream per instance and
field, reset per instance; frame by frame it gives what the whole episode gets offline."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from rfmp_rl.data.quaternions import (
    canonicalize_observation_quaternions,
    parse_observation_quaternions,
)
from rfmp_rl.envs.transforms import QuaternionSigns

FIELDS = [{"columns": [1, 5], "reference": [1.0, 0.0, 0.0, 0.0]},
          {"columns": [5, 9], "reference": [0.0, 0.0, 0.0, 1.0]}]


def episode(seed: int, n: int = 25) -> torch.Tensor:
    """(n, 10) observations: a counter, two quaternion streams recorded with random signs, 1."""
    gen = torch.Generator().manual_seed(seed)
    q = torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]) \
        + torch.cumsum(0.05 * torch.randn(n, 8, generator=gen), 0)
    q = q.reshape(n, 2, 4)
    q = q / q.norm(dim=-1, keepdim=True)
    q = q * (torch.randint(0, 2, (n, 2, 1), generator=gen) * 2 - 1)
    return torch.cat([torch.arange(float(n))[:, None], q.reshape(n, 8), torch.ones(n, 1)], -1)


def td(obs: torch.Tensor, reset: list[bool] | None = None) -> TensorDict:
    out = TensorDict({"observation": obs.clone()}, [obs.shape[0]])
    if reset is not None:
        out.set("_reset", torch.tensor(reset)[:, None])
    return out


def test_frame_by_frame_equals_the_episode_and_partial_resets_restart_one_stream():
    fields = parse_observation_quaternions(FIELDS)
    a, b, c = episode(0), episode(1), episode(2, 10)
    t = QuaternionSigns(FIELDS)
    got_a, got_b, got_c = [], [], []
    out = t._reset(td(torch.zeros(2, 10)), td(torch.stack([a[0], b[0]])))["observation"]
    got_a.append(out[0]), got_b.append(out[1])
    for k in range(1, 15):
        out = t._call(td(torch.stack([a[k], b[k]])))["observation"]
        got_a.append(out[0]), got_b.append(out[1])
    # instance 1 starts a new episode (c); instance 0 goes on with a
    out = t._reset(td(torch.zeros(2, 10), [False, True]),
                   td(torch.stack([a[14], c[0]])))["observation"]
    torch.testing.assert_close(out[0], got_a[-1])  # the same frame again: unchanged
    got_c.append(out[1])
    for k in range(1, 10):
        out = t._call(td(torch.stack([a[14 + k], c[k]])))["observation"]
        got_a.append(out[0]), got_c.append(out[1])
    for got, ep in ((got_a, a[:24]), (got_b, b[:15]), (got_c, c)):
        expected = canonicalize_observation_quaternions(ep, fields)
        torch.testing.assert_close(torch.stack(got), expected)
    assert not torch.equal(canonicalize_observation_quaternions(a, fields), a)  # it did work


def test_bad_settings_and_missing_entries_are_named():
    with pytest.raises(ValueError, match="no quaternion fields"):
        QuaternionSigns([])
    t = QuaternionSigns(FIELDS)
    with pytest.raises(KeyError, match="no entry 'observation'"):
        t._call(TensorDict({"obs": torch.zeros(1, 10)}, [1]))
    with pytest.raises(ValueError, match=r"has 6 values, the quaternion columns \[5, 9\]"):
        t._call(td(torch.zeros(1, 6)))


def test_every_robosuite_task_names_its_observed_quaternions():
    from rfmp_rl.envs.robosuite import (
        ROBOSUITE_TASKS,
        low_dim_key_dims,
        num_arms,
        robosuite_obs_quaternions,
    )

    for task in ROBOSUITE_TASKS:
        width = sum(low_dim_key_dims(task).values())
        spans = [q["columns"] for q in robosuite_obs_quaternions(task)]
        assert spans[0] == [3, 7], task  # robot0_eef_quat
        assert all(b - a == 4 and b <= width for a, b in spans), (task, spans, width)
        # every arm's hand, and the object's quaternions where the layout is mapped
        mapped = task not in ("ToolHang", "TwoArmTransport")
        assert len(spans) == num_arms(task) + (2 if mapped and task != "Lift" else int(mapped))
    assert [q["columns"] for q in robosuite_obs_quaternions("TwoArmTransport")] == [[3, 7],
                                                                                   [12, 16]]
