"""The ``rfmp_rl.onnx/1`` metadata: parsing, and errors that name the file and the key."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from rfmp_deploy import Policy, parse_metadata
from rfmp_deploy.metadata import REQUIRED_KEYS
from toy_policy import ToySpec, toy_metadata

JSON_KEYS = ("inputs", "observation_keys", "action_manifold", "action_low", "action_high", "noise")


def test_parses_every_field():
    spec = ToySpec(cameras={"front": (3, 24, 32)}, crop=(20, 28), horizon=6, action_steps=3)
    meta = parse_metadata(toy_metadata(spec), "p.onnx")
    assert (meta.obs_horizon, meta.horizon, meta.action_steps) == (2, 6, 3)
    assert (meta.algorithm, meta.nfe, meta.method, meta.t_end) == ("srfmp", 1, "euler", 1.0)
    assert meta.control_rate_hz == 10.0 and meta.period == pytest.approx(0.1)
    assert [(f.key, f.dim) for f in meta.observation_keys] == [("pos", 3), ("quat", 4)]
    assert meta.obs_dim == 7 and meta.action_dim == 8 and meta.noise_dim == 8
    assert meta.cameras == ("front",)
    front = meta.image_inputs[0]
    assert front.shape == (2, 3, 24, 32) and front.image_size == (24, 32)
    assert front.crop == (20, 28)
    assert meta.lowdim_input.shape == (2, 7)
    assert meta.noise_input.name == "prior_noise"
    assert str(meta.action_space) == "R3 x S3 x R1"
    np.testing.assert_array_equal(meta.action_space.low, -np.ones(8))
    assert "R3 x S3 x R1" in meta.summary() and "front" in meta.summary()


def test_keeps_unknown_keys_as_extra():
    props = toy_metadata(ToySpec()) | {"training_run": "abc"}
    assert parse_metadata(props).extra == {"training_run": "abc"}


def test_refuses_another_format_naming_the_file():
    props = toy_metadata(ToySpec()) | {"rfmp_rl.format": "rfmp_rl.onnx/2"}
    with pytest.raises(ValueError, match=r"^robot/p\.onnx: .*'rfmp_rl\.format'.*rfmp_rl\.onnx/2"):
        parse_metadata(props, "robot/p.onnx")


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_missing_key(key):
    props = toy_metadata(ToySpec())
    del props[key]
    with pytest.raises(ValueError, match=rf"^p\.onnx: metadata key '{re.escape(key)}' is missing"):
        parse_metadata(props, "p.onnx")


@pytest.mark.parametrize("obs_horizon", [2, 4, 16])
def test_obs_horizon_is_kept_and_the_windows_stay_two_rows(obs_horizon):
    meta = parse_metadata(toy_metadata(ToySpec(obs_horizon=obs_horizon,
                                               cameras={"front": (3, 24, 32)})))
    assert meta.obs_horizon == obs_horizon
    assert meta.lowdim_input.shape == (2, 7) and meta.image_inputs[0].shape == (2, 3, 24, 32)
    assert f"T_o={obs_horizon}, T_p=4" in meta.summary()


def test_models_without_obs_horizon_load_as_two():
    props = toy_metadata(ToySpec())
    del props["obs_horizon"]
    meta = parse_metadata(props, "p.onnx")
    assert meta.obs_horizon == 2 and "obs_horizon" not in meta.extra


@pytest.mark.parametrize("key", JSON_KEYS)
def test_bad_json(key):
    props = toy_metadata(ToySpec()) | {key: "[{not json"}
    with pytest.raises(ValueError, match=rf"^p\.onnx: metadata key '{key}': is not valid JSON"):
        parse_metadata(props, "p.onnx")


def _inputs(spec: ToySpec, edit) -> str:
    entries = json.loads(toy_metadata(spec)["inputs"])
    edit(entries)
    return json.dumps(entries)


CAM = ToySpec(cameras={"front": (3, 24, 32)})
BAD = {
    "nfe not int": ("nfe", "two", "expected an integer"),
    "nfe zero": ("nfe", "0", "must be >= 1"),
    "rate": ("control_rate_hz", "-5", "positive"),
    "t_end": ("t_end", "nan", "finite"),
    "T_a > T_p": ("action_steps", "5", "exceeds the horizon"),
    "obs dims": ("observation_keys",
                 json.dumps([{"key": "pos", "dim": 3}, {"key": "quat", "dim": 3}]), "sum to 6"),
    "obs entry": ("observation_keys", json.dumps([{"key": "pos"}]), "entry 0"),
    "dup keys": ("observation_keys", json.dumps([{"key": "a", "dim": 3}, {"key": "a", "dim": 4}]),
                 "duplicate"),
    "manifold type": ("action_manifold", json.dumps({"type": "torus"}), "unknown manifold type"),
    "manifold dim": ("action_manifold", json.dumps({"type": "euclidean", "dim": 0}), "dim"),
    "low length": ("action_low", json.dumps([-1.0] * 7), "7 entries"),
    "low > high": ("action_low", json.dumps([2.0] + [-1.0] * 7), "action_low > action_high"),
    "high entry": ("action_high", json.dumps(["x"] + [1.0] * 7), r"action_high\[0\]"),
    "noise dim": ("noise", json.dumps({"distribution": "standard_normal", "dim": 5}), "differs"),
    "noise law": ("noise", json.dumps({"distribution": "uniform", "dim": 8}), "not supported"),
    "noise default": ("noise", json.dumps({"distribution": "standard_normal", "dim": 8,
                                           "default": "ones"}), "'default'"),
    "inputs kind": ("inputs", _inputs(ToySpec(), lambda e: e[0].update(kind="depth")),
                    "unknown kind"),
    "inputs dtype": ("inputs", _inputs(ToySpec(), lambda e: e[0].update(dtype="float64")),
                     "must be float32"),
    "inputs window": ("inputs", _inputs(ToySpec(), lambda e: e[0].update(shape=[3, 7])),
                      r"window of 3 observations, expected 2 \(\[context, latest\]\)"),
    "obs_horizon 1": ("obs_horizon", "1", "must be >= 2, got 1"),
    "obs_horizon text": ("obs_horizon", "four", "expected an integer, got 'four'"),
    "obs_horizon huge": ("obs_horizon", "100000", "T_o=100000 is implausible"),
    "inputs no noise": ("inputs", _inputs(ToySpec(), lambda e: e.pop()), "exactly one 'noise'"),
    "image size": ("inputs", _inputs(CAM, lambda e: e[1].update(image_size=[24, 30])),
                   "differs from the shape"),
    "image channels": ("inputs", _inputs(CAM, lambda e: e[1].update(shape=[2, 4, 24, 32],
                                                                     image_size=[24, 32])),
                       "channels"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_inconsistent_values(case):
    key, value, message = BAD[case]
    spec = CAM if case.startswith("image") else ToySpec()
    props = toy_metadata(spec) | {key: value}
    with pytest.raises(ValueError, match=rf"^p\.onnx: metadata key '{key}':.*{message}"):
        parse_metadata(props, "p.onnx")


# ----- against the graph (through Policy) ------------------------------------------------------
def test_policy_loads_and_exposes_meta(make_model):
    path = make_model(ToySpec(horizon=5, action_steps=3))
    policy = Policy(path, intra_op_threads=1)
    assert policy.meta.horizon == 5 and policy.meta.path == str(path)
    assert "CPUExecutionProvider" in policy.providers


@pytest.mark.parametrize(
    ("meta_spec", "key", "message"),
    [
        (ToySpec(obs_keys=[("pos", 3), ("quat", 5)]), "inputs", r"input 'observation' has size 7"),
        (ToySpec(obs_keys=[]), "inputs", r"missing from the graph: \[\]; not in the metadata: "
                                         r"\['observation'\]"),
        (ToySpec(cameras={"front": (3, 24, 32)}), "inputs", r"missing from the graph: \['front'\]"),
        (ToySpec(noise_dim=6), "inputs", "input 'prior_noise' has size 8"),
        (ToySpec(horizon=6), "horizon", "output 'action' has size 4 on axis 1"),
        (ToySpec(manifold={"type": "euclidean", "dim": 7}), "action_manifold",
         "output 'action' has size 8 on axis 2"),
    ],
    ids=["obs-width", "no-obs-in-meta", "extra-camera", "noise", "horizon", "action-dim"],
)
def test_metadata_that_disagrees_with_the_graph(make_model, meta_spec, key, message):
    path = make_model(ToySpec(), meta_spec=meta_spec)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: metadata key '{key}': "
                                         rf".*{message}"):
        Policy(path)


def test_image_dtype_disagrees_with_the_graph(make_model):
    # The metadata says uint8 camera frames; the graph was built for float images.
    import onnx

    path = make_model(ToySpec(cameras={"front": (3, 8, 8)}))

    model = onnx.load(str(path))
    model.graph.input[1].type.tensor_type.elem_type = onnx.TensorProto.FLOAT
    model.graph.node[1].attribute[0].i = onnx.TensorProto.FLOAT  # Cast float -> float
    onnx.save(model, str(path))
    message = r"metadata key 'inputs': input 'front' is tensor\(float\)"
    with pytest.raises(ValueError, match=message):
        Policy(path)


def test_fixed_batch_is_refused(make_model):
    # What torch.onnx.export produces when the batch axis gets specialised to the example's.
    path = make_model(ToySpec(batch=2))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: input 'observation' has a "
                                         r"fixed batch size 2 .* needs a dynamic batch"):
        Policy(path)


def test_missing_key_through_policy_names_the_file(make_model):
    path = make_model(overrides={"action_manifold": None})
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: metadata key "
                                         r"'action_manifold' is missing"):
        Policy(path)


def test_no_metadata_at_all(make_model):
    path = make_model(overrides=dict.fromkeys(REQUIRED_KEYS))
    with pytest.raises(ValueError, match=r"'rfmp_rl\.format' is missing"):
        Policy(path)


def test_not_a_model(tmp_path):
    garbage = tmp_path / "policy.onnx"
    garbage.write_bytes(b"definitely not protobuf")
    with pytest.raises(ValueError, match=rf"^{re.escape(str(garbage))}: onnxruntime cannot load"):
        Policy(garbage)
    with pytest.raises(FileNotFoundError, match="missing.onnx"):
        Policy(tmp_path / "missing.onnx")


def test_graph_without_action_output(make_model):
    import onnx

    path = make_model()
    model = onnx.load(str(path))
    model.graph.output[0].name = "chunk"
    model.graph.node[-1].output[0] = "chunk"
    onnx.save(model, str(path))
    with pytest.raises(ValueError, match=r"has no 'action' output \(outputs: \['chunk'\]\)"):
        Policy(path)
