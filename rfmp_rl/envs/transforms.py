"""The observation windows a policy reads, as TorchRL transforms for any env.

A policy conditions on the window ``[o^c, o^{s-1}]`` (``(2, D)`` for a vector, ``(2, C, H, W)``
for a camera) and, when T_o (``obs_horizon``) > 2, on the gap ``s - c`` (``obs_gap``, float).
Training draws ``c`` uniformly from ``[s - T_o, s - 2]`` (`rfmp_rl.data.store`); acting always
takes the oldest of the last T_o observations, ``c = s - T_o``, so the gap is the constant T_o.
After a reset the first observation is repeated (as the training sampler pads episode starts)
and the gap stays T_o. With T_o = 2 the window is the last two observations and there is no gap.

Per observation the transforms are::

    o (..., D)  -UnsqueezeTransform->  (..., 1, D)  -CatFrames(T_o)->  (..., T_o, D)
                -ContextWindow (T_o > 2)->  (..., 2, D) = [o^{s-T_o}, o^{s-1}],  obs_gap = T_o

and ``InitTracker`` (the ``is_init`` entry ``MultiStepActorWrapper`` re-plans on).
`window_transforms` reads the keys a `FlowPolicy` needs from the policy; `observation_windows`
takes them explicitly (the library's own envs use it). `QuaternionSigns` goes before them when
the observation holds quaternions whose signs the policy was trained canonical
(`rfmp_rl.data.quaternions.canonical_quaternion_signs`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs import CatFrames, Compose, InitTracker, UnsqueezeTransform
from torchrl.envs.transforms import Transform

from rfmp_rl import keys
from rfmp_rl.data.quaternions import (
    ObservedQuaternion,
    canonical_quaternion_signs,
    parse_observation_quaternions,
)

__all__ = ["ContextWindow", "QuaternionSigns", "observation_windows", "window_transforms",
           "step_key"]


def step_key(window_key: NestedKey) -> NestedKey:
    """The one-step entry a window is stacked from: ``obs_window`` -> ``obs_step``,
    ``pixels_window`` -> ``pixels_step``, any other ``name`` -> ``name_step``.

    Example:
        >>> step_key("obs_window"), step_key(("agent", "camera"))
        ('obs_step', ('agent', 'camera_step'))
    """
    last = window_key if isinstance(window_key, str) else window_key[-1]
    last = (last[: -len("_window")] if last.endswith("_window") else last) + "_step"
    return last if isinstance(window_key, str) else (*window_key[:-1], last)


class ContextWindow(Transform):
    """``(..., T_o, *event)`` stacks of the last T_o frames -> ``(..., 2, *event)`` =
    ``[oldest, latest]``, in place, and writes the gap ``T_o`` (float32, the env's batch shape)
    under ``gap_key``.

    Args:
        obs_horizon: T_o (> 2; with T_o = 2 the stack already is the window).
        in_keys: the stacked entries (each overwritten by its window).
        event_dims: per entry, the dims after the frame dim (1 for a vector, 3 for an image).
        gap_key: where the gap goes.

    Example:
        >>> from tensordict import TensorDict
        >>> t = ContextWindow(4, ["obs_window"], [1])
        >>> td = t(TensorDict({"obs_window": torch.arange(8.0).reshape(1, 4, 2)}, [1]))
        >>> td["obs_window"].tolist(), td["obs_gap"].tolist()
        ([[[0.0, 1.0], [6.0, 7.0]]], [4.0])
    """

    def __init__(
        self,
        obs_horizon: int,
        in_keys: list[NestedKey],
        event_dims: list[int],
        gap_key: NestedKey = keys.OBS_GAP,
    ) -> None:
        if obs_horizon <= 2:
            raise ValueError(f"ContextWindow: obs_horizon (T_o) must be > 2, got {obs_horizon}")
        if len(event_dims) != len(in_keys):
            raise ValueError(f"ContextWindow: {len(in_keys)} keys but {len(event_dims)} "
                             f"event_dims")
        super().__init__(in_keys=list(in_keys), out_keys=list(in_keys))
        self.obs_horizon, self.gap_key = int(obs_horizon), gap_key
        self._dims = dict(zip(self.in_keys, (-1 - int(d) for d in event_dims), strict=True))

    def _select(self, key: NestedKey, value: torch.Tensor) -> torch.Tensor:
        dim = self._dims[key]
        if value.shape[dim] != self.obs_horizon:
            raise ValueError(f"ContextWindow: {key!r} stacks {value.shape[dim]} frames along dim "
                             f"{dim} (shape {tuple(value.shape)}), expected T_o = "
                             f"{self.obs_horizon}")
        index = torch.tensor([0, self.obs_horizon - 1], device=value.device)
        return value.index_select(dim, index)  # (..., 2, *event): [o^{s-T_o}, o^{s-1}]

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        for key in self.in_keys:
            value = next_tensordict.get(key, None)
            if value is None:
                raise KeyError(f"ContextWindow: no entry {key!r} (keys: "
                               f"{sorted(map(str, next_tensordict.keys(True, True)))})")
            next_tensordict.set(key, self._select(key, value))
        gap = torch.full(next_tensordict.batch_size, float(self.obs_horizon),
                         device=next_tensordict.device)
        next_tensordict.set(self.gap_key, gap)
        return next_tensordict

    forward = _call

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        for key in self.in_keys:
            spec = observation_spec[key]
            space = getattr(spec, "space", None)
            if getattr(space, "low", None) is not None:  # Bounded: the bounds of two frames
                observation_spec[key] = Bounded(
                    self._select(key, space.low), self._select(key, space.high),
                    dtype=spec.dtype, device=spec.device,
                )
            else:
                shape = list(spec.shape)
                shape[self._dims[key]] = 2
                observation_spec[key] = Unbounded(shape, dtype=spec.dtype, device=spec.device)
        observation_spec[self.gap_key] = Unbounded(
            observation_spec.shape, dtype=torch.float32, device=observation_spec.device
        )
        return observation_spec


class QuaternionSigns(Transform):
    """Canonical quaternion signs in observation vectors, frame by frame, as the training data
    holds them (`rfmp_rl.data.quaternions.canonical_quaternion_signs`).

    Each quaternion field of each env instance is a stream: after a reset its first frame takes
    the field's reference hemisphere, every later frame the sign closest to the frame before.
    The state is the last canonical quaternion per instance and field; a ``_reset`` mask resets
    only the instances it selects. The entries are overwritten in place (the env's other
    entries, e.g. robosuite's ``robot0_eef_quat``, keep the raw signs).

    Args:
        fields: the quaternion columns (`ObservedQuaternion` s or their dicts,
            ``ModelConfig.obs_quaternions``).
        in_keys: the observation vectors ``(*batch, D)`` (default ``observation``).

    Example:
        >>> from tensordict import TensorDict
        >>> t = QuaternionSigns([{"columns": [0, 4], "reference": [1.0, 0.0, 0.0, 0.0]}])
        >>> obs = lambda x, w: TensorDict({"observation": torch.tensor([[x, 0.0, 0.0, w]])}, [1])
        >>> t._reset(obs(0.0, 0.0), obs(-1.0, 0.01))["observation"][0, [0, 3]].tolist()
        [1.0, -0.009999999776482582]
        >>> t._call(obs(1.0, 0.01))["observation"][0, [0, 3]].tolist()  # continuity: kept
        [1.0, 0.009999999776482582]
    """

    def __init__(
        self,
        fields: Sequence[ObservedQuaternion | Mapping[str, Any]],
        in_keys: Sequence[NestedKey] = (keys.OBSERVATION,),
    ) -> None:
        super().__init__(in_keys=list(in_keys), out_keys=list(in_keys))
        self.fields = parse_observation_quaternions(fields)
        if not self.fields:
            raise ValueError("QuaternionSigns: no quaternion fields given")
        self._references = torch.tensor([f.reference for f in self.fields])  # (F, 4)
        self._previous: dict[NestedKey, torch.Tensor] = {}  # key -> (*batch, F, 4)

    def _canonical(self, key: NestedKey, value: torch.Tensor,
                   reset: torch.Tensor | None) -> torch.Tensor:
        refs = self._references.to(value).expand(*value.shape[:-1], len(self.fields), 4)
        previous = self._previous.get(key)
        if previous is None or previous.shape != refs.shape:
            start = refs  # first frames: the references' hemispheres
        elif reset is None:
            start = previous
        else:
            start = torch.where(reset.reshape(*reset.shape, 1, 1), refs, previous.to(value))
        out = value.clone()
        for i, f in enumerate(self.fields):
            if f.start + 4 > value.shape[-1]:
                raise ValueError(f"QuaternionSigns: {key!r} has {value.shape[-1]} values, the "
                                 f"quaternion columns {f.to_dict()['columns']} do not fit")
            q = value[..., f.columns].unsqueeze(-2)  # (*batch, 1, 4): one frame of the stream
            out[..., f.columns] = canonical_quaternion_signs(
                q, previous=start[..., i, :]).squeeze(-2)
        self._previous[key] = torch.stack([out[..., f.columns] for f in self.fields], -2)
        return out

    def _canonicalize_entries(self, tensordict: TensorDictBase,
                              reset: torch.Tensor | None) -> TensorDictBase:
        for key in self.in_keys:
            value = tensordict.get(key, None)
            if value is None:
                raise KeyError(f"QuaternionSigns: no entry {key!r} (keys: "
                               f"{sorted(map(str, tensordict.keys(True, True)))})")
            tensordict.set(key, self._canonical(key, value, reset))
        return tensordict

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._canonicalize_entries(next_tensordict, None)

    forward = _call

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
               ) -> TensorDictBase:
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is not None:
            mask = mask.reshape(tensordict_reset.batch_size)
        else:
            mask = torch.ones(tensordict_reset.batch_size, dtype=torch.bool,
                              device=tensordict_reset.device)
        return self._canonicalize_entries(tensordict_reset, mask)


def observation_windows(
    obs_horizon: int,
    vectors: Mapping[NestedKey, NestedKey] | None = None,
    cameras: Mapping[NestedKey, NestedKey] | None = None,
    *,
    gap_key: NestedKey = keys.OBS_GAP,
    init_key: str = "is_init",
) -> Compose:
    """Per entry, the window transforms (module docstring), and ``InitTracker``.

    Args:
        obs_horizon: T_o >= 2.
        vectors: ``{env entry (..., D): window key}``; default ``{"observation": "obs_window"}``.
        cameras: ``{env entry (..., C, H, W): window key}``; default none.
        gap_key: where the constant gap T_o goes (T_o > 2 only).
        init_key: the `InitTracker` entry.

    Each window is stacked from a one-step entry named by `step_key`.

    Example:
        >>> from rfmp_rl.envs import make_lasa_sphere_env
        >>> env = make_lasa_sphere_env(torch.tensor([1.0, 0.0, 0.0]), [3], obs_horizon=4)
        >>> td = env.reset()
        >>> td["obs_window"].shape, td["obs_gap"].tolist()
        (torch.Size([3, 2, 3]), [4.0, 4.0, 4.0])
    """
    if int(obs_horizon) < 2:
        raise ValueError(f"obs_horizon (T_o) must be >= 2, got {obs_horizon}")
    vectors = dict({keys.OBSERVATION: keys.OBS_WINDOW} if vectors is None else vectors)
    entries = [(src, win, 1) for src, win in vectors.items()]
    entries += [(src, win, 3) for src, win in dict(cameras or {}).items()]
    transforms: list[Transform] = []
    for source, window, event in entries:
        if source == window:
            raise ValueError(f"the window of {source!r} needs its own key (the env's one-step "
                             f"entry stays as it is)")
        step = step_key(window)
        transforms += [
            UnsqueezeTransform(dim=-1 - event, in_keys=[source], out_keys=[step]),
            CatFrames(N=int(obs_horizon), dim=-1 - event, in_keys=[step], out_keys=[window]),
        ]
    if obs_horizon > 2:
        transforms.append(ContextWindow(int(obs_horizon), [w for _, w, _ in entries],
                                        [e for _, _, e in entries], gap_key))
    # last: InitTracker finds its parent env even when this Compose sits inside another one
    return Compose(*transforms, InitTracker(init_key))


def _flow_policy(policy: nn.Module):
    from rfmp_rl.modules import FlowPolicy

    obj = policy
    for _ in range(4):
        if isinstance(obj, FlowPolicy):
            return obj
        obj = getattr(obj, "actor", None) or getattr(obj, "module", None)
    raise TypeError(f"window_transforms takes a FlowPolicy or a wrapper of one "
                    f"(MultiStepActorWrapper); got {type(policy).__name__}")


def window_transforms(
    policy: nn.Module,
    sources: Mapping[NestedKey, NestedKey] | None = None,
) -> Compose:
    """The transforms that make an env emit what ``policy`` reads: its observation window
    (``policy.observation_key``), each camera's window and, when T_o > 2, the gap (the keys of
    ``PolicyModel.condition_keys``), plus ``is_init``.

    Args:
        policy: a `FlowPolicy` or a ``MultiStepActorWrapper`` around one.
        sources: ``{window key: env entry}``; by default the observation window is stacked from
            ``"observation"`` and the window of camera ``name`` from the entry ``name``.

    Raises:
        ValueError: when a window key is its own source (give the policy another key, e.g.
            ``FlowPolicy(model, observation_key="obs_window")``).

    Example:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> from rfmp_rl.modules import FlowPolicy, ModelConfig, build_model
        >>> model = build_model(ModelConfig("srfmp", "R1", obs_dim=3, horizon=4, obs_horizon=3,
        ...                                 down_dims=[16, 32]))
        >>> policy = FlowPolicy(model, observation_key="obs_window")
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), window_transforms(policy))
        >>> sorted(k for k in env.reset().keys() if k.startswith("obs"))
        ['obs_gap', 'obs_step', 'obs_window', 'observation']
    """
    flow = _flow_policy(policy)
    model, sources = flow.model, dict(sources or {})
    vectors, cameras = {}, {}
    if model.cfg.obs_dim > 0:
        window = flow.observation_key
        vectors[sources.pop(window, keys.OBSERVATION)] = window
    for name in model.cameras:
        window = flow.camera_keys[name]
        cameras[sources.pop(window, name)] = window
    if sources:
        raise ValueError(f"window_transforms: sources {sorted(map(str, sources))} name no window "
                         f"the policy reads ({flow.in_keys})")
    return observation_windows(model.cfg.obs_horizon, vectors, cameras, gap_key=flow.gap_key)
