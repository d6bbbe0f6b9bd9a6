"""`Policy.__call__`: one batch through onnxruntime, with shape and dtype checks."""

from __future__ import annotations

import numpy as np
import pytest
from toy_policy import ToySpec, reference


def test_call_matches_the_graph_math(make_policy):
    spec = ToySpec(cameras={"front": (3, 12, 16), "wrist": (1, 8, 8)})
    policy = make_policy(spec)
    inputs = policy.random_inputs(batch=3, rng=np.random.default_rng(1))
    assert inputs["observation"].shape == (3, 2, 7)
    assert inputs["images"]["wrist"].shape == (3, 2, 1, 8, 8)
    action = policy(**inputs)
    assert action.shape == (3, 4, 8) and action.dtype == np.float32
    np.testing.assert_allclose(action, reference(spec, **inputs), rtol=1e-5, atol=1e-5)


def test_model_without_lowdim_observation(make_policy):
    spec = ToySpec(obs_keys=[], cameras={"front": (3, 8, 8)})
    policy = make_policy(spec)
    assert policy.meta.lowdim_input is None and policy.meta.obs_dim == 0
    inputs = policy.random_inputs(batch=2, rng=np.random.default_rng(0))
    assert inputs["observation"] is None
    np.testing.assert_allclose(policy(**inputs), reference(spec, **inputs), atol=1e-5)
    with pytest.raises(ValueError, match="no low-dimensional observation input"):
        policy(np.zeros((2, 2, 1), np.float32), inputs["images"], inputs["noise"])


def _inputs(policy):
    return policy.random_inputs(batch=2, rng=np.random.default_rng(0))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda i: i.update(observation=i["observation"].astype(np.float64)),
         "input 'observation': expected dtype float32, got float64"),
        (lambda i: i.update(observation=i["observation"][:, :1]),
         r"input 'observation': expected shape \[2, 2, 7\], got \[2, 1, 7\]"),
        (lambda i: i.update(observation=None), "input 'observation' is required"),
        (lambda i: i.update(noise=i["noise"][:1]), r"expected shape \[1, 2, 7\]"),
        (lambda i: i.update(noise=i["noise"].ravel()), r"'prior_noise': expected a \(B, 8\)"),
        (lambda i: i["images"].pop("front"), "camera input 'front' is missing"),
        (lambda i: i["images"].update(back=i["images"]["front"]),
         r"unknown camera\(s\) \['back'\]"),
        (lambda i: i["images"].update(front=i["images"]["front"].astype(np.float32)),
         "input 'front': expected dtype uint8"),
        (lambda i: i["images"].update(front=i["images"]["front"][..., :4]),
         r"input 'front': expected shape \[2, 2, 3, 8, 8\]"),
        (lambda i: i.update(observation=i["observation"].tolist()), "expected a numpy array"),
    ],
    ids=["obs-dtype", "obs-shape", "obs-none", "batch-mismatch", "noise-rank", "no-camera",
         "extra-camera", "image-dtype", "image-shape", "obs-list"],
)
def test_call_rejects_bad_inputs(make_policy, edit, message):
    policy = make_policy(ToySpec(cameras={"front": (3, 8, 8)}))
    inputs = _inputs(policy)
    edit(inputs)
    with pytest.raises(ValueError, match=message):
        policy(**inputs)
