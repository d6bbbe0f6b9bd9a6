from __future__ import annotations

import pytest
import torch

from rfmp_rl.manifolds import Horizon, parse_manifold
from rfmp_rl.modules import Normalizer, euclidean_mask


def test_minmax_maps_data_range_to_unit_interval_and_back():
    data = torch.tensor([[0.0, 10.0, 5.0], [4.0, 30.0, 5.0], [2.0, 20.0, 5.0]])
    norm = Normalizer(3)
    norm.fit(data)
    y = norm(data)
    torch.testing.assert_close(y[:, :2].min(0).values, torch.tensor([-1.0, -1.0]))
    torch.testing.assert_close(y[:, :2].max(0).values, torch.tensor([1.0, 1.0]))
    torch.testing.assert_close(y[:, 2], torch.zeros(3))  # constant coordinate: centred only
    torch.testing.assert_close(norm.unnormalize(y), data)
    assert bool(norm.fitted)


def test_sphere_coordinates_are_left_untouched():
    pose = parse_manifold("R3 x S3 x R1")
    mask = euclidean_mask(pose)
    assert mask.tolist() == [True] * 3 + [False] * 4 + [True]
    assert euclidean_mask(Horizon(pose, 2)).tolist() == mask.tolist() * 2
    norm = Normalizer(8, mask)
    data = pose.random_base(100) * torch.tensor([5.0] * 3 + [1.0] * 4 + [3.0])
    norm.fit(data)
    y = norm(data)
    torch.testing.assert_close(y[:, 3:7], data[:, 3:7])  # quaternions unchanged
    assert y[:, :3].abs().max() <= 1 + 1e-6 and y[:, 7].abs().max() <= 1 + 1e-6


def test_statistics_are_buffers_in_the_state_dict():
    norm = Normalizer(2)
    norm.fit(torch.tensor([[0.0, 1.0], [2.0, 3.0]]))
    other = Normalizer(2)
    other.load_state_dict(norm.state_dict())
    x = torch.randn(5, 2)
    torch.testing.assert_close(other(x), norm(x))
    assert {"offset", "scale", "mask"} <= set(norm.state_dict())


def test_bad_data_is_refused_with_the_coordinate():
    norm = Normalizer(2)
    with pytest.raises(ValueError, match=r"coordinates \[1\]"):
        norm.fit(torch.tensor([[0.0, float("nan")], [1.0, 2.0]]))
    with pytest.raises(ValueError, match="last dimension 2"):
        norm.fit(torch.zeros(4, 3))
