"""TensorDict-facing modules: the vector field and the acting policy.

Both read and write by key, so they compose with TorchRL envs, collectors, replay buffers and
`MultiStepActorWrapper`; the wrapped `FlowModel` / `DiffusionModel` only ever sees tensors.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Composite, TensorSpec
from torchrl.envs.utils import ExplorationType, exploration_type

from rfmp_rl import keys
from rfmp_rl.modules.policy_model import DiffusionModel, FlowModel
from rfmp_rl.solvers import SolverConfig

__all__ = ["VectorField", "FlowPolicy"]

#: Exploration types under which a policy acts from the prior's mode (no random draw).
_MODE_TYPES = (ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN)


class _VectorFieldAdapter(nn.Module):
    """``(*conditioning inputs, x, time) -> velocity`` (inputs as `condition_keys` orders them)."""

    def __init__(self, model: FlowModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, *tensors: torch.Tensor):
        *inputs, x, time = tensors
        return self.model.velocity(x, time, self.model.encode_inputs(*inputs))


class VectorField(TensorDictModule):
    """The learned field v(x, t | o) as a `TensorDictModule`.

    Reads the observation window (and camera windows), the flat flow state and the time (t for
    RFMP, tau for SRFMP); writes the velocity (and ``velocity_tau`` for SRFMP).

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> cfg = ModelConfig("rfmp", "S2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> vf = VectorField(model)
        >>> td = TensorDict({"observation": torch.randn(5, 2, 3),
        ...                  "x_t": model.chunk.random_base(5), "time": torch.rand(5, 1)}, [5])
        >>> vf(td)["velocity"].shape
        torch.Size([5, 12])
    """

    def __init__(
        self,
        model: FlowModel,
        *,
        observation_key: NestedKey = keys.OBSERVATION,
        camera_keys: Mapping[str, NestedKey] | None = None,
        gap_key: NestedKey = keys.OBS_GAP,
        state_key: NestedKey = "x_t",
        time_key: NestedKey = "time",
        velocity_key: NestedKey = "velocity",
        velocity_tau_key: NestedKey = "velocity_tau",
    ) -> None:
        in_keys = model.condition_keys(observation_key, camera_keys, gap_key)
        in_keys += [state_key, time_key]
        out_keys = [velocity_key, velocity_tau_key] if model.stable else [velocity_key]
        super().__init__(_VectorFieldAdapter(model), in_keys=in_keys, out_keys=out_keys)


class FlowPolicy(TensorDictModuleBase):
    """Acting policy: observation window in, action chunk ``(..., T_p, D)`` out.

    Samples with a fixed solver budget. Under
    ``set_exploration_type(ExplorationType.DETERMINISTIC)`` (or ``MODE``, or ``MEAN``) it starts
    from the prior's mode (a fixed point on the manifold) instead of a random sample, so
    evaluation is reproducible; under ``RANDOM`` it samples the prior. If
    the input holds ``noise_key`` (standard-normal prior noise ``(..., noise_dim)``), that noise
    is used — the same input an exported ONNX policy takes. Works with `FlowModel` (RFMP,
    SRFMP), `DiffusionModel` (DDIM, where ``nfe`` is the number of DDIM steps) and
    `ConsistencyModel` (CP, where ``nfe`` counts consistency evaluations: 1 is one-step).

    Wrap it in ``torchrl.modules.MultiStepActorWrapper(policy, n_steps=T_p,
    replan_interval=T_a)`` to execute T_a actions of each chunk (receding horizon)::

        obs    o^{s-2} o^{s-1}
        chunk          |a^s ... a^{s+T_a-1} ... a^{s+T_p-1}|
        executed       |<-------- T_a -------->|  then re-plan

    Args:
        model: the network (`FlowModel` or `DiffusionModel`).
        solver: the inference budget (`rfmp_rl.solvers.SolverConfig`; the algorithm's defaults
            fill what it leaves out). When given, the five arguments below must stay unset.
        nfe: function evaluations per chunk (default 1).
        method: ODE method (flows only).
        t_end: end time T of the integration (may exceed 1).
        schedule: ``"uniform"`` or ``"srfmp"`` (default: SRFMP's for SRFMP).
        refine_dt: SRFMP refinement step.
        observation_key, camera_keys, gap_key, action_key, noise_key: TensorDict keys.
        spec: the action's TensorSpec (or a ``Composite`` holding ``action_key``, such as an
            env's ``full_action_spec``): ``policy.spec`` is ``Composite({action_key: spec})``
            as TorchRL's actors keep theirs (``policy.action_spec`` the leaf).
        safe: clamp every action to the demonstrated range (the action normaliser's min/max on
            the Euclidean coordinates; manifold parts are projected onto the manifold), then,
            with ``spec``, project it into the spec (``spec.project``).

    Example:
        >>> from tensordict import TensorDict
        >>> from rfmp_rl.modules import ModelConfig, build_model
        >>> cfg = ModelConfig("srfmp", "S2", obs_dim=3, horizon=4, down_dims=[32, 64])
        >>> model = build_model(cfg)
        >>> policy = FlowPolicy(model, nfe=1)
        >>> policy(TensorDict({"observation": torch.randn(5, 2, 3)}, [5]))["action"].shape
        torch.Size([5, 4, 3])
    """

    def __init__(
        self,
        model: FlowModel | DiffusionModel,
        *,
        solver: SolverConfig | None = None,
        nfe: int | None = None,
        method: str | None = None,
        t_end: float | None = None,
        schedule: str | None = None,
        refine_dt: float | None = None,
        observation_key: NestedKey = keys.OBSERVATION,
        camera_keys: Mapping[str, NestedKey] | None = None,
        gap_key: NestedKey = keys.OBS_GAP,
        action_key: NestedKey = keys.ACTION,
        noise_key: NestedKey = keys.PRIOR_NOISE,
        spec=None,
        safe: bool = False,
    ) -> None:
        super().__init__()
        self.model = model
        self.safe = bool(safe)
        given = {k: v for k, v in {"nfe": nfe, "method": method, "t_end": t_end,
                                   "schedule": schedule, "refine_dt": refine_dt}.items()
                 if v is not None}
        if solver is not None and given:
            raise TypeError(f"FlowPolicy: give either solver= or {sorted(given)}, not both")
        solver = (solver or SolverConfig(**given)).resolve(model.cfg.algorithm)
        if isinstance(model, FlowModel):  # validate the budget now, not mid-rollout
            solver.step_sizes(model.cfg.lambda_x)
        else:
            model.ddim_timesteps(solver.nfe)
        self.solver = solver
        self.solver_kwargs = solver.sample_kwargs()
        self.observation_key, self.gap_key = observation_key, gap_key
        self.camera_keys = dict(camera_keys or {name: name for name in model.cameras})
        self.action_key, self.noise_key = action_key, noise_key
        self.in_keys = model.condition_keys(observation_key, self.camera_keys, gap_key)
        # per-sample dims of each input: window (2, D_obs), camera windows (2, C, H, W), gap
        self._event_dims = ([2] if model.cfg.obs_dim > 0 else []) + [4] * len(model.cameras)
        self._event_dims += [0] if model.cfg.obs_horizon > 2 else []
        self.out_keys = [action_key]
        self._spec = self._output_spec(spec)

    def _output_spec(self, spec) -> Composite:
        """``Composite({action_key: leaf spec or None})`` from a leaf spec, a ``Composite``
        holding the action key (an env's ``full_action_spec``) or None, as TorchRL's actors
        keep theirs."""
        if spec is not None and not isinstance(spec, TensorSpec):
            raise TypeError(f"FlowPolicy: spec must be a TorchRL TensorSpec, got "
                            f"{type(spec).__name__}")
        if isinstance(spec, Composite):
            if self.action_key not in spec.keys(True, True):
                raise KeyError(f"FlowPolicy: the spec holds no {self.action_key!r} entry (it "
                               f"holds {sorted(map(str, spec.keys(True, True)))})")
            spec = spec[self.action_key]
        if spec is not None:
            if not spec.shape or spec.shape[-1] != self.model.action_dim:
                raise ValueError(f"FlowPolicy: the action spec's shape {tuple(spec.shape)} does "
                                 f"not end in the action size {self.model.action_dim}")
            spec = spec.clone()
        out = Composite()
        out[self.action_key] = spec
        return out

    @property
    def spec(self) -> Composite:
        """The output spec, keyed like ``out_keys``: ``spec[action_key]`` is the action spec
        given at construction, or None."""
        return self._spec

    @property
    def action_spec(self) -> TensorSpec | None:
        """The action's spec (None when none was given)."""
        return self._spec[self.action_key]

    def _clamp(self, action: torch.Tensor) -> torch.Tensor:
        """``(B, T_p, D)`` actions inside the demonstrated range, manifold parts on the manifold."""
        norm = self.model.action_normalizer
        inf = torch.full_like(norm.data_min, float("inf"))
        low = torch.where(norm.mask, norm.data_min, -inf).to(action.dtype)
        high = torch.where(norm.mask, norm.data_max, inf).to(action.dtype)
        return self.model.step_manifold.projx(torch.maximum(torch.minimum(action, high), low))

    @classmethod
    def from_checkpoint(
        cls,
        path,
        nfe: int | None = None,
        t_end: float | None = None,
        *,
        use_ema: bool = True,
        **kwargs,
    ) -> FlowPolicy:
        """The policy of a checkpoint, in eval mode, integrating with the solver the checkpoint
        stores (the one its run selected and evaluated with; the algorithm's defaults for
        checkpoints that store none), with ``nfe`` / ``t_end`` overriding it. ``kwargs`` go to
        `FlowPolicy` (keys).

        Example:
            >>> from rfmp_rl.checkpoint import save_checkpoint
            >>> from rfmp_rl.modules import ModelConfig, build_model
            >>> model = build_model(ModelConfig("srfmp", "S2", obs_dim=3, horizon=4,
            ...                                 down_dims=[32, 64]))
            >>> path = save_checkpoint("srfmp.pt", model, solver=SolverConfig(nfe=3))
            >>> FlowPolicy.from_checkpoint(path).solver.nfe, FlowPolicy.from_checkpoint(
            ...     path, nfe=1).solver
            (3, SolverConfig(nfe=1, t_end=1.0, method='euler', schedule='srfmp', refine_dt=None))
        """
        from dataclasses import replace

        from rfmp_rl.checkpoint import load_checkpoint

        model, payload = load_checkpoint(path, use_ema=use_ema)
        solver = SolverConfig.from_dict(payload.get("solver") or {})
        overrides = {k: v for k, v in {"nfe": nfe, "t_end": t_end}.items() if v is not None}
        return cls(model.eval(), solver=replace(solver, **overrides), **kwargs)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        model = self.model
        # inputs go to the model's device (an env on the CPU, a policy on a GPU); the action
        # comes back on the device the observations came from
        device = model.obs_normalizer.offset.device
        inputs = []
        for key, dims in zip(self.in_keys, self._event_dims, strict=True):
            value = tensordict.get(key)
            if dims:  # windows set the batch shape: (..., 2, D_obs) or (..., 2, C, H, W)
                leading, source = value.shape[:-dims], value.device
            inputs.append(value.reshape(-1, *value.shape[value.ndim - dims:]).to(device))
        noise = tensordict.get(self.noise_key, None)
        if noise is not None:
            noise = noise.reshape(-1, noise.shape[-1]).to(device)
        deterministic = noise is None and exploration_type() in _MODE_TYPES
        cond = model.encode_inputs(*inputs)
        action = model.sample(cond, noise, deterministic=deterministic, **self.solver_kwargs)
        if self.safe:
            action = self._clamp(action)
        action = action.reshape(*leading, *action.shape[-2:]).to(source)
        if self.safe and self.action_spec is not None:
            action = self.action_spec.project(action)
        tensordict.set(self.action_key, action)
        return tensordict
