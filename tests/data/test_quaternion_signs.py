"""The sign rule of observed and commanded quaternions (`canonical_quaternion_signs`): the first
sample in the reference's hemisphere, then continuity; causal (online == offline); the column
spec of observation vectors."""

from __future__ import annotations

import pytest
import torch

from rfmp_rl.data.quaternions import (
    ObservedQuaternion,
    canonical_quaternion_signs,
    canonicalize_observation_quaternions,
    parse_observation_quaternions,
)

HAND = (1.0, 0.0, 0.0, 0.0)  # robosuite's Panda hand pointing down, xyzw


def hand_stream(n: int = 40) -> torch.Tensor:
    """A hand pointing down and tilting slightly about y: w crosses 0 (xyzw, unit norm)."""
    w = torch.linspace(-0.02, 0.02, n, dtype=torch.float64)
    q = torch.stack([torch.ones(n), torch.zeros(n), 0.05 * torch.ones(n), w], -1)
    return (q / q.norm(dim=-1, keepdim=True)).to(torch.float64)


def test_first_sample_takes_the_reference_hemisphere():
    q = torch.tensor([[0.0, 0.0, 0.6, -0.8]])
    torch.testing.assert_close(canonical_quaternion_signs(q), -q)  # identity: w >= 0
    torch.testing.assert_close(canonical_quaternion_signs(q, (0.0, 0.0, 1.0, 0.0)), q)


def test_a_recorded_sign_flip_is_undone_and_later_samples_follow():
    q = hand_stream()
    recorded = q.clone()
    recorded[10:25] = -recorded[10:25]  # the recorder switched sign for a while
    recorded[0] = -recorded[0]  # and started with the other one
    out = canonical_quaternion_signs(recorded, HAND)
    torch.testing.assert_close(out, q)
    assert bool(((out[1:] * out[:-1]).sum(-1) > 0).all())


def test_continuity_keeps_a_stream_whose_w_crosses_zero_where_a_hemisphere_rule_jumps():
    q = hand_stream()
    out = canonical_quaternion_signs(q, HAND)
    torch.testing.assert_close(out, q)  # already continuous: nothing to change
    hemisphere = torch.where(q[:, 3:] < 0, -q, q)  # w >= 0 frame by frame
    assert float((hemisphere[1:] - hemisphere[:-1]).norm(dim=-1).max()) > 1.9  # a jump


def test_only_signs_change_never_norms():
    q = torch.randn(3, 20, 4, dtype=torch.float64) * 3
    out = canonical_quaternion_signs(q, HAND)
    torch.testing.assert_close(out.abs(), q.abs())
    ratio = (out / q)[..., 0]
    assert bool(((ratio == 1) | (ratio == -1)).all())


def test_a_zero_dot_product_keeps_the_recorded_sign():
    q = torch.tensor([[0.0, 0.0, 0.0, -1.0],   # first: flipped to w >= 0
                      [0.0, 0.0, 1.0, 0.0],    # orthogonal to the previous: kept
                      [0.0, 0.0, -1.0, 0.0],   # opposite: flipped
                      [1.0, 0.0, 0.0, 0.0]])   # orthogonal again: kept
    expected = torch.tensor([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                             [1.0, 0.0, 0.0, 0.0]])
    torch.testing.assert_close(canonical_quaternion_signs(q), expected)
    # step by step (one frame of state) gives the same
    prev = None
    for k in range(4):
        got = canonical_quaternion_signs(q[k:k + 1], previous=prev)
        torch.testing.assert_close(got[0], expected[k])
        prev = got[0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_online_frame_by_frame_equals_the_whole_episode(dtype):
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(2, 3, 30, 4, generator=gen, dtype=dtype)  # batch (2, 3), 30 frames
    q[..., 7, :] = 0.0  # a zero sample: dot products 0 on both sides
    whole = canonical_quaternion_signs(q, HAND)
    prev, frames = None, []
    for k in range(q.shape[-2]):
        frame = canonical_quaternion_signs(q[..., k:k + 1, :], HAND, previous=prev)
        frames.append(frame)
        prev = frame[..., 0, :]
    torch.testing.assert_close(torch.cat(frames, dim=-2), whole)
    # pieces: the first 11 frames, then the rest continued from the last canonical one
    head = canonical_quaternion_signs(q[..., :11, :], HAND)
    tail = canonical_quaternion_signs(q[..., 11:, :], HAND, previous=head[..., -1, :])
    torch.testing.assert_close(torch.cat([head, tail], dim=-2), whole)
    # time on another axis
    torch.testing.assert_close(
        canonical_quaternion_signs(q.movedim(-2, 0), HAND, dim=0).movedim(0, -2), whole)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match=r"\(\.\.\., T, 4\)"):
        canonical_quaternion_signs(torch.zeros(5, 3))
    with pytest.raises(ValueError, match="4 values"):
        canonical_quaternion_signs(torch.zeros(5, 4), (1.0, 0.0))
    assert canonical_quaternion_signs(torch.zeros(0, 4)).shape == (0, 4)


def test_observation_columns_are_canonicalised_and_the_rest_left_alone():
    q = hand_stream(12).float()
    flipped = q.clone()
    flipped[4:] = -flipped[4:]
    cube = torch.tensor([0.0, 0.0, 0.6, -0.8]).expand(12, 4)  # world frame, w < 0
    obs = torch.cat([torch.arange(12.0)[:, None], flipped, cube, torch.ones(12, 1)], -1)
    fields = parse_observation_quaternions([{"columns": [1, 5], "reference": list(HAND)},
                                            ObservedQuaternion(5)], obs_dim=10)
    out = canonicalize_observation_quaternions(obs, fields)
    torch.testing.assert_close(out[:, 1:5], q)
    torch.testing.assert_close(out[:, 5:9], -cube)
    torch.testing.assert_close(out[:, [0, 9]], obs[:, [0, 9]])
    torch.testing.assert_close(obs[:, 1:5], flipped)  # the input is not modified


@pytest.mark.parametrize("entry,match", [
    ({"columns": [0, 3], "reference": [0, 0, 0, 1]}, r"\[a, a \+ 4\]"),
    ({"columns": [6, 10], "reference": [0, 0, 0, 1]}, "outside the observation's 9"),
    ({"columns": [0, 4], "reference": [0, 0, 0]}, "4 finite numbers"),
    ({"columns": [0, 4], "reference": [0, 0, 0, 0]}, "not all zero"),
    ({"columns": [0, 4], "reference": [0, 0, float("nan"), 1]}, "4 finite numbers"),
    ({"columns": [0, 4]}, "expected"),
])
def test_bad_specs_name_the_entry(entry, match):
    with pytest.raises(ValueError, match=f"obs_quaternions entry 0: .*{match}"):
        parse_observation_quaternions([entry], obs_dim=9)


def test_overlapping_columns_are_refused():
    with pytest.raises(ValueError, match=r"entry 1: columns \[2, 6\] overlap \[0, 4\]"):
        parse_observation_quaternions([{"columns": [0, 4], "reference": [0, 0, 0, 1]},
                                       {"columns": [2, 6], "reference": [0, 0, 0, 1]}])
