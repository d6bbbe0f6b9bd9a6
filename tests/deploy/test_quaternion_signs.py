"""The controller's observed-quaternion signs: the numpy rule agrees with rfmp_rl's, the
``observation_quaternions`` metadata key is parsed and checked, the processor keeps one stream
per field (reset with the controller), and a model without the key gets its observations as
given."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from rfmp_deploy import Controller, parse_metadata
from rfmp_deploy.observation import ObservationProcessor, canonical_quaternion_signs
from toy_policy import ToySpec, toy_metadata

from rfmp_rl.data.quaternions import canonical_quaternion_signs as torch_rule

HAND = [1.0, 0.0, 0.0, 0.0]
KEY = json.dumps([{"columns": [3, 7], "reference": HAND}])


def streams(seed: int = 0) -> np.ndarray:
    """(3, 50, 4) float32 quaternion streams: slow rotations near the hand's, random sign
    switches, an exact zero sample and an orthogonal pair."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(0, 0.05, (3, 50, 4))
    q = np.array(HAND) + np.cumsum(steps, axis=1)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= rng.choice([-1.0, 1.0], size=(3, 50, 1))
    q[0, 20] = 0.0
    q[1, 30], q[1, 31] = [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 0.0]
    return q.astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_numpy_rule_agrees_with_rfmp_rl(seed):
    q = streams(seed)
    for ref in (HAND, [0.0, 0.0, 0.0, 1.0]):
        expected = torch_rule(torch.from_numpy(q), ref).numpy()
        np.testing.assert_array_equal(canonical_quaternion_signs(q, ref), expected)
    prev = q[:, 9]
    np.testing.assert_array_equal(canonical_quaternion_signs(q[:, 10:], previous=prev),
                                  torch_rule(torch.from_numpy(q[:, 10:]),
                                             previous=torch.from_numpy(prev)).numpy())


def test_metadata_key_is_parsed_and_summarised():
    meta = parse_metadata(toy_metadata(ToySpec()) | {"observation_quaternions": KEY}, "p.onnx")
    (quat,) = meta.observation_quaternions
    assert (quat.start, quat.reference, quat.columns) == (3, (1.0, 0.0, 0.0, 0.0), slice(3, 7))
    assert "quaternions:  observation [3:7] from [1.0, 0.0, 0.0, 0.0]" in meta.summary()
    assert parse_metadata(toy_metadata(ToySpec())).observation_quaternions == ()


@pytest.mark.parametrize("value,match", [
    ('{"columns": [3, 7]}', "expected a JSON list"),
    ('[{"columns": [3, 7]}]', "entry 0 must be"),
    ('[{"columns": [4, 8], "reference": [1, 0, 0, 0]}]', r"outside the observation's D_obs=7"),
    ('[{"columns": [2, 5], "reference": [1, 0, 0, 0]}]', r"\[a, a \+ 4\]"),
    ('[{"columns": [3, 7], "reference": [0, 0, 0, 0]}]', "not all zero"),
    ('[{"columns": [3, 7], "reference": [1, 0, "x", 0]}]', "4 finite numbers"),
    ('[{"columns": [0, 4], "reference": [1, 0, 0, 0]}, '
     '{"columns": [3, 7], "reference": [1, 0, 0, 0]}]', r"entry 1: .* overlap \[0, 4\]"),
])
def test_bad_metadata_names_the_key(value, match):
    props = toy_metadata(ToySpec()) | {"observation_quaternions": value}
    with pytest.raises(ValueError, match=f"p.onnx: metadata key 'observation_quaternions': "
                                         f".*{match}"):
        parse_metadata(props, "p.onnx")


def _observations(q: np.ndarray) -> list[dict]:
    return [{"pos": np.array([0.1 * k, 0.0, 0.3]), "quat": q[k]} for k in range(len(q))]


def test_processor_makes_the_stream_canonical_and_resets():
    q = streams()[0]
    process = ObservationProcessor(parse_metadata(toy_metadata(ToySpec())
                                                  | {"observation_quaternions": KEY}))
    got = np.stack([process(o).lowdim[3:7] for o in _observations(q)])
    np.testing.assert_array_equal(got, canonical_quaternion_signs(q, HAND))
    # a rejected frame leaves the stream as it was
    with pytest.raises(ValueError):
        process({"pos": [0.0, float("nan"), 0.0], "quat": -got[-1]})
    np.testing.assert_array_equal(process({"pos": [0.0, 0.0, 0.0], "quat": -got[-1]}).lowdim[3:7],
                                  got[-1])
    process.reset()  # a new stream starts at the reference's hemisphere
    far = np.array([-0.9, 0.0, 0.0, 0.1], np.float32)
    np.testing.assert_array_equal(process({"pos": [0, 0, 0], "quat": far}).lowdim[3:7], -far)


def test_controller_acts_the_same_on_either_sign_and_old_models_get_raw_values(make_model):
    q = streams()[0]
    canonical = canonical_quaternion_signs(q, HAND)
    assert (canonical != q).any()  # the recorded stream does switch signs

    def actions(model, quats) -> np.ndarray:
        ctl = Controller(str(model), deterministic=True, action_steps=1)
        out = np.stack([ctl.step(o) for o in _observations(quats)])
        ctl.reset()  # the next episode starts from the reference again
        return np.concatenate([out, ctl.step(_observations(-quats[:1])[0])[None]])

    new = make_model(ToySpec(), overrides={"observation_quaternions": KEY})
    np.testing.assert_allclose(actions(new, q), actions(new, canonical), atol=1e-6)
    old = make_model(ToySpec())  # exported before the key: the observation is fed as given
    assert np.abs(actions(old, q) - actions(old, canonical)).max() > 1e-3
