"""`ActionSpace`: layout, limits, projection and errors with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rfmp_deploy import ActionSpace
from toy_policy import R3_S3_R1

LOW = [-1, -2, -3, -1, -1, -1, -1, 0.0]
HIGH = [1, 2, 3, 1, 1, 1, 1, 0.08]


def test_layout_and_default_action():
    space = ActionSpace(R3_S3_R1, LOW, HIGH)
    assert str(space) == "R3 x S3 x R1" and space.dim == 8
    assert [(s.kind, s.start, s.stop) for s in space.segments] == [
        ("euclidean", 0, 3), ("sphere", 3, 7), ("euclidean", 7, 8)]
    np.testing.assert_array_equal(space.default_action(), np.float32([0, 0, 0, 0, 0, 0, 1, 0.04]))


def test_nested_products_flatten():
    spec = {"type": "product", "components": [
        {"type": "sphere", "n": 2},
        {"type": "product", "components": [{"type": "euclidean", "dim": 1},
                                           {"type": "sphere", "n": 3}]}]}
    space = ActionSpace(spec, [-1] * 8, [1] * 8)
    assert str(space) == "S2 x R1 x S3"
    np.testing.assert_array_equal(space.default_action(), [0, 0, 1, 0, 0, 0, 0, 1])


def test_unbounded_limits_give_no_default():
    space = ActionSpace(R3_S3_R1, [None] + LOW[1:], HIGH)
    assert space.low[0] == -math.inf and space.default_action() is None
    # Sphere coordinates may be unbounded: they never enter the midpoint.
    space = ActionSpace({"type": "sphere", "n": 3}, [None] * 4, [None] * 4)
    np.testing.assert_array_equal(space.default_action(), [0, 0, 0, 1])


def test_project_clips_and_renormalises():
    space = ActionSpace(R3_S3_R1, LOW, HIGH)
    p = space.project(np.array([5.0, -0.5, -9.0, 0.0, 0.0, 3.0, 4.0, 0.05]))
    np.testing.assert_allclose(p.action, [1.0, -0.5, -3.0, 0.0, 0.0, 0.6, 0.8, 0.05], rtol=1e-6)
    assert p.clipped == (0, 2)
    assert len(p.renormalised) == 1 and p.renormalised[0][1] == pytest.approx(5.0)
    text = p.describe(space.low, space.high)
    assert "0 to [-1, 1]" in text and "S3 at 3:7 (norm was 5)" in text
    # Already valid: unchanged, nothing reported.
    q = space.project(p.action)
    np.testing.assert_allclose(q.action, p.action, rtol=1e-6)
    assert not q.changed


@pytest.mark.parametrize(
    ("action", "message"),
    [(np.zeros(7), r"shape \(7,\)"), (np.array([np.nan] + [0.5] * 7), "non-finite"),
     (np.array([0, 0, 0, 0, 0, 0, 1e-9, 0]), "norm")],
)
def test_project_refuses_what_cannot_be_fixed(action, message):
    with pytest.raises(ValueError, match=message):
        ActionSpace(R3_S3_R1, LOW, HIGH).project(action)


def test_errors_known_answers():
    space = ActionSpace(R3_S3_R1, LOW, HIGH)
    a = np.array([[0, 0, 0, 0, 0, 0, 1, 0.0], [1, 1, 1, 0, 0, 0, 1, 0.0]])
    theta = 0.3  # rotate by theta about z: q = (0, 0, sin(theta/2), cos(theta/2))
    b = a.copy()
    b[:, :3] += [0.03, 0.04, 0.0]
    b[:, 3:7] = [0, 0, math.sin(theta / 2), math.cos(theta / 2)]
    b[:, 7] += 0.12  # gripper counts towards the Euclidean error too
    euclidean, angles = space.errors(a, b)
    np.testing.assert_allclose(euclidean, [0.13, 0.13], rtol=1e-12)  # 3-4-12-13
    np.testing.assert_allclose(angles, [[theta / 2], [theta / 2]], rtol=1e-12)
    # Antipodal quaternions: pi apart on S^3 (the same rotation: 2 * min(pi, 0) = 0).
    _, angles = space.errors(a[0], np.r_[a[0, :3], [0, 0, 0, -1], a[0, 7]])
    np.testing.assert_allclose(angles, [math.pi])
