"""Trajectory metrics: DTW (against a brute-force reference), goal error, sphere error, jerk."""

from __future__ import annotations

import math
import time

import pytest
import torch

from rfmp_rl.eval import (
    dtw_distance,
    final_goal_distance,
    jerk,
    nearest_demo_dtw,
    on_manifold_error,
)
from rfmp_rl.manifolds import Sphere

S2 = Sphere(2)


def euclid(x, y):
    return (x - y).norm(dim=-1)


def curve(s: torch.Tensor) -> torch.Tensor:
    """A smooth curve on S^2 (an S-shaped path down from the north pole), ``s`` in [0, 1]."""
    s = s.double()[:, None]
    u = torch.cat([1.2 * s, 0.4 * torch.sin(2 * math.pi * s), torch.zeros_like(s)], -1)
    return S2.expmap(S2.origin(len(s), dtype=torch.float64), u)


def brute_force_dtw(a, b, dist_fn):
    """Textbook O(T1 T2) double loop; ties broken diagonal, up, left."""
    cost = dist_fn(a[:, None], b[None]).double()
    t1, t2 = cost.shape
    acc = [[math.inf] * t2 for _ in range(t1)]
    length = [[0] * t2 for _ in range(t1)]
    for i in range(t1):
        for j in range(t2):
            if i == 0 and j == 0:
                acc[0][0], length[0][0] = cost[0, 0].item(), 1
                continue
            options = []
            if i and j:
                options.append((acc[i - 1][j - 1], length[i - 1][j - 1]))
            if i:
                options.append((acc[i - 1][j], length[i - 1][j]))
            if j:
                options.append((acc[i][j - 1], length[i][j - 1]))
            best, n = min(options, key=lambda o: o[0])
            acc[i][j], length[i][j] = cost[i, j].item() + best, n + 1
    return acc[-1][-1] / length[-1][-1]


def test_dtw_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    for _ in range(25):
        t1, t2 = torch.randint(1, 10, (2,), generator=g).tolist()
        a = torch.randn(t1, 2, generator=g, dtype=torch.float64)
        b = torch.randn(t2, 2, generator=g, dtype=torch.float64)
        assert dtw_distance(a, b, euclid) == pytest.approx(brute_force_dtw(a, b, euclid), abs=1e-12)


def test_dtw_known_values():
    line = torch.tensor([[0.0], [1.0], [2.0]])
    # One point against three: path (0,0), (0,1), (0,2), cost 0 + 1 + 2 over 3 points.
    assert dtw_distance(line[:1], line, euclid) == pytest.approx(1.0)

    # Constant cost 2 everywhere: the normalised distance is 2 whatever the path.
    def l1(x, y):
        return (x - y).abs().sum(-1)

    assert dtw_distance(torch.zeros(3, 2), torch.ones(4, 2), l1) == pytest.approx(2.0)
    # Repeating samples is free: [0, 1, 1, 2] aligns with [0, 1, 2] at zero cost.
    assert dtw_distance(torch.tensor([[0.0], [1.0], [1.0], [2.0]]), line, euclid) == 0.0


def test_dtw_self_symmetry_and_time_warping():
    a = curve(torch.linspace(0, 1, 200))
    assert dtw_distance(a, a) == pytest.approx(0.0, abs=1e-6)
    # Same path, different timing (slow start, fast finish) and length: close to zero, far below
    # the distance to a different path; the default distance is the geodesic one.
    warped = curve(torch.linspace(0, 1, 150) ** 2)
    north = S2.origin(dtype=torch.float64)
    other = S2.expmap(north, -S2.logmap(north, a))  # a mirrored through the north pole
    spacing = S2.dist(a[1:], a[:-1]).max().item()
    d_warp = dtw_distance(a, warped)
    assert d_warp < spacing
    assert d_warp == pytest.approx(dtw_distance(warped, a), abs=1e-12)
    assert dtw_distance(a, other) > 50 * d_warp
    assert dtw_distance(a, other) == pytest.approx(dtw_distance(other, a), abs=1e-12)


def test_dtw_default_is_geodesic():
    a = torch.tensor([[0.0, 0.0, 1.0]])
    b = torch.tensor([[1.0, 0.0, 0.0]])
    assert dtw_distance(a, b) == pytest.approx(math.pi / 2, abs=1e-6)


def test_dtw_rejects_bad_shapes():
    with pytest.raises(ValueError):
        dtw_distance(torch.zeros(3, 2), torch.zeros(3, 3))
    with pytest.raises(ValueError):
        dtw_distance(torch.zeros(3), torch.zeros(3))
    with pytest.raises(ValueError):
        dtw_distance(torch.zeros(0, 3), torch.zeros(3, 3))


def test_dtw_is_not_quadratic_in_python():
    # A guard against an accidental Python double loop (which takes seconds), not a benchmark:
    # 200 x 200 typically runs in 10-30 ms.
    a = curve(torch.linspace(0, 1, 200)).float()
    b = curve(torch.linspace(0, 1, 200) ** 2).float()
    dtw_distance(a, b)
    best = min(_timed(dtw_distance, a, b) for _ in range(3))
    assert best < 1.0


def _timed(fn, *args):
    start = time.perf_counter()
    fn(*args)
    return time.perf_counter() - start


def test_nearest_demo():
    demos = torch.stack(
        [
            curve(torch.linspace(0, 1, 60)),
            curve(torch.linspace(0, 0.5, 60)),
            S2.projx(curve(torch.linspace(0, 1, 60)) * torch.tensor([1.0, -1.0, 1.0])),
        ]
    )
    traj = curve(torch.linspace(0, 1, 80) ** 1.5)
    dist, index = nearest_demo_dtw(traj, demos)
    assert index == 0
    assert dist == pytest.approx(dtw_distance(traj, demos[0]), abs=1e-12)
    assert isinstance(dist, float) and isinstance(index, int)
    with pytest.raises(ValueError):
        nearest_demo_dtw(traj, demos[0])


def test_final_goal_distance():
    north = torch.tensor([0.0, 0.0, 1.0])
    traj = torch.stack([curve(torch.linspace(1, 0, 20)), curve(torch.linspace(0, 1, 20))])
    d = final_goal_distance(traj, north)
    assert d.shape == (2,)
    assert d[0].item() == pytest.approx(0.0, abs=1e-6)
    assert d[1].item() == pytest.approx(1.2, abs=1e-6)  # u(1) = (1.2, 0, 0)
    plane = torch.tensor([[0.0, 0.0], [3.0, 4.0]])
    assert final_goal_distance(plane, torch.zeros(2), euclid).item() == pytest.approx(5.0)


def test_on_manifold_error():
    traj = curve(torch.linspace(0, 1, 30))
    assert on_manifold_error(traj).item() == pytest.approx(0.0, abs=1e-12)
    traj[7] *= 1.01
    traj[9] *= 0.995
    assert on_manifold_error(traj).item() == pytest.approx(0.01, abs=1e-9)
    assert on_manifold_error(traj[None].expand(3, 30, 3)).ndim == 0


def test_jerk_known_answers():
    dt = 0.05
    t = torch.arange(40, dtype=torch.float64)[:, None] * dt
    line = torch.cat([3 * t + 1, -2 * t, 0.5 * t], -1)
    assert jerk(line, dt).item() == pytest.approx(0.0, abs=1e-6)
    # x(t) = 2 t^3 (+ lower order terms) has constant third derivative 12; y(t) = -t^3 has -6.
    cubic = torch.cat([2 * t**3 - t**2 + 4 * t, -(t**3), torch.ones_like(t)], -1)
    assert jerk(cubic, dt).item() == pytest.approx(math.hypot(12, 6), rel=1e-6)
    batch = torch.stack([line, cubic])
    torch.testing.assert_close(jerk(batch, dt), torch.stack([jerk(line, dt), jerk(cubic, dt)]))
    with pytest.raises(ValueError, match="4 time steps"):
        jerk(line[:3], dt)
    with pytest.raises(ValueError, match="dt"):
        jerk(line, 0.0)
