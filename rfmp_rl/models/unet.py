"""Diffusion Policy's 1-D temporal UNet with FiLM conditioning, used as the RFMP/SRFMP field.

The paper (section "RFMP and SRFMP Implementation") parameterises v(a | o) with the UNet of
Diffusion Policy (Chi et al.), itself built from Janner et al.'s 1-D convolutional residual
blocks. Layout for ``down_dims = (256, 512, 1024)`` and a chunk of length T_p::

    sample (B, T_p, D) -> (B, D, T_p)
    down level 0:  ResBlock(D -> 256),     ResBlock(256 -> 256),   Downsample  -> T_p / 2
    down level 1:  ResBlock(256 -> 512),   ResBlock(512 -> 512),   Downsample  -> T_p / 4
    down level 2:  ResBlock(512 -> 1024),  ResBlock(1024 -> 1024)  (no downsampling)
    mid:           ResBlock(1024 -> 1024) x 2
    up level 2:    cat(skip 2) ResBlock(2048 -> 512),  ResBlock(512 -> 512), Upsample -> T_p / 2
    up level 1:    cat(skip 1) ResBlock(1024 -> 256),  ResBlock(256 -> 256), Upsample -> T_p
    final:         Conv1d(256, 256, k) -> GroupNorm -> Mish -> Conv1d(256 -> D, 1)

As in Diffusion Policy, the finest level's skip is not concatenated on the way up, which keeps
parameter counts identical to theirs (~65M for Push-T with states). Every residual block is
``Conv1d -> GroupNorm -> Mish`` twice, with FiLM in between: a ``Mish -> Linear`` on the global
condition ``[MLP(SinEmb(t)), obs features]`` predicts a per-channel scale and bias
(``cond_predict_scale=True``) or only a bias.

Sequence lengths need not be powers of two: after each upsampling the features are cropped to
the length of the matching down level, so T_p = 4, 8, 16 but also odd lengths work (T_p = 4 with
three levels goes 4 -> 2 -> 1 -> 2 -> 4).

With ``predict_tau=True`` (SRFMP) the time input is the pseudo-time tau and the model also
returns ``v_tau`` from a :class:`~rfmp_rl.models.tau_head.TauHead` (its own tau embedding and the
same observation features, then an MLP).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from rfmp_rl.models.embeddings import DEFAULT_TIME_SCALE, SinusoidalPosEmb
from rfmp_rl.models.tau_head import TauHead

__all__ = [
    "ConditionalResidualBlock1D",
    "ConditionalUnet1D",
    "Conv1dBlock",
    "UNET_PRESETS",
    "make_unet",
]

# Down-sampling widths. "paper": Diffusion Policy / the paper's simulated tasks; "paper_real":
# the paper's real-robot tasks; "small": a CPU size that trains in minutes on 2 cores.
UNET_PRESETS: dict[str, tuple[int, ...]] = {
    "paper": (256, 512, 1024),
    "paper_real": (128, 256, 512),
    "small": (64, 128, 256),
}


class Conv1dBlock(nn.Module):
    """``Conv1d -> GroupNorm -> Mish`` with "same" padding.

    Args:
        in_channels: Input channels.
        out_channels: Output channels (divisible by ``n_groups``).
        kernel_size: Odd convolution kernel size.
        n_groups: GroupNorm groups.

    Example:
        >>> import torch
        >>> Conv1dBlock(2, 16, kernel_size=5)(torch.randn(4, 2, 16)).shape
        torch.Size([4, 16, 16])
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, n_groups: int = 8):
        super().__init__()
        self.block = nn.Sequential(
            nn.Conv1d(in_channels, out_channels, kernel_size, padding=kernel_size // 2),
            nn.GroupNorm(n_groups, out_channels),
            nn.Mish(),
        )

    def forward(self, x: Tensor) -> Tensor:
        """Map ``(B, C_in, L)`` to ``(B, C_out, L)``."""
        return self.block(x)


class ConditionalResidualBlock1D(nn.Module):
    """Two :class:`Conv1dBlock` with FiLM from a global condition, plus a residual path.

    Args:
        in_channels: Input channels.
        out_channels: Output channels.
        cond_dim: Size of the global condition vector.
        kernel_size: Odd convolution kernel size.
        n_groups: GroupNorm groups.
        cond_predict_scale: If True, FiLM predicts a per-channel scale and bias
            (``h <- scale * h + bias``); otherwise only a bias (``h <- h + bias``).

    Example:
        >>> import torch
        >>> block = ConditionalResidualBlock1D(2, 32, cond_dim=10, kernel_size=5)
        >>> block(torch.randn(4, 2, 16), torch.randn(4, 10)).shape
        torch.Size([4, 32, 16])
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        cond_dim: int,
        kernel_size: int = 5,
        n_groups: int = 8,
        cond_predict_scale: bool = True,
    ) -> None:
        super().__init__()
        self.out_channels = out_channels
        self.cond_predict_scale = cond_predict_scale
        self.conv1 = Conv1dBlock(in_channels, out_channels, kernel_size, n_groups)
        self.conv2 = Conv1dBlock(out_channels, out_channels, kernel_size, n_groups)
        film_dim = 2 * out_channels if cond_predict_scale else out_channels
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, film_dim))
        self.residual = (
            nn.Conv1d(in_channels, out_channels, 1)
            if in_channels != out_channels
            else nn.Identity()
        )

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        """Apply the block.

        Args:
            x: Features of shape ``(B, C_in, L)``.
            cond: Global condition of shape ``(B, cond_dim)``.

        Returns:
            Features of shape ``(B, C_out, L)``.
        """
        h = self.conv1(x)  # (B, C_out, L)
        film = self.film(cond).unsqueeze(-1)  # (B, 2 C_out, 1) or (B, C_out, 1)
        if self.cond_predict_scale:
            scale, bias = film.chunk(2, dim=1)  # (B, C_out, 1) each
            h = scale * h + bias
        else:
            h = h + film
        h = self.conv2(h)
        return h + self.residual(x)


class ConditionalUnet1D(nn.Module):
    """Diffusion Policy's FiLM-conditioned 1-D temporal UNet (see the module docstring).

    Args:
        input_dim: Action dimension D per step (ambient coordinates, e.g. 3 for S^2).
        global_cond_dim: Size of the observation feature vector; 0 for an unconditional field.
        time_embed_dim: Size of the time embedding (sinusoid, then ``Linear(d, 4d) -> Mish ->
            Linear(4d, d)`` as in Diffusion Policy). None: ``down_dims[0]`` (256 for the paper
            preset, as in Diffusion Policy; 64 for the small one), so it scales with the net.
        down_dims: Channel widths of the UNet levels, finest first.
        kernel_size: Odd temporal kernel size.
        n_groups: GroupNorm groups in every residual block.
        cond_predict_scale: FiLM predicts scale and bias (True) or bias only (False).
        time_scale: Factor applied to t before the sinusoid; 100 for flow times in [0, 1], 1 for
            integer diffusion steps (see :mod:`rfmp_rl.models.embeddings`).
        predict_tau: SRFMP mode: ``forward`` returns ``(v_x, v_tau)`` and ``t`` is the
            pseudo-time tau. Otherwise it returns ``v_x`` only.
        tau_hidden_dim: Hidden width of the tau head (only with ``predict_tau``). None:
            ``2 * down_dims[0]`` (512 for the paper preset, 128 for the small one).
        tau_num_hidden_layers: Hidden layers of the tau head (only with ``predict_tau``).

    Example:
        >>> import torch
        >>> net = ConditionalUnet1D(input_dim=2, global_cond_dim=40, down_dims=(64, 128, 256))
        >>> a_t, t, obs = torch.randn(8, 16, 2), torch.rand(8), torch.randn(8, 40)
        >>> net(a_t, t, obs).shape
        torch.Size([8, 16, 2])
        >>> srfmp = ConditionalUnet1D(2, 40, down_dims=(64, 128, 256), predict_tau=True)
        >>> v_x, v_tau = srfmp(a_t, t, obs)
        >>> v_x.shape, v_tau.shape
        (torch.Size([8, 16, 2]), torch.Size([8, 1]))
    """

    def __init__(
        self,
        input_dim: int,
        global_cond_dim: int,
        time_embed_dim: int | None = None,
        down_dims: Sequence[int] = UNET_PRESETS["paper"],
        kernel_size: int = 5,
        n_groups: int = 8,
        cond_predict_scale: bool = True,
        time_scale: float = DEFAULT_TIME_SCALE,
        predict_tau: bool = False,
        tau_hidden_dim: int | None = None,
        tau_num_hidden_layers: int = 2,
    ) -> None:
        super().__init__()
        down_dims = tuple(int(d) for d in down_dims)
        if len(down_dims) < 1:
            raise ValueError("down_dims needs at least one level.")
        time_embed_dim = down_dims[0] if time_embed_dim is None else int(time_embed_dim)
        tau_hidden_dim = 2 * down_dims[0] if tau_hidden_dim is None else int(tau_hidden_dim)
        self.time_embed_dim, self.tau_hidden_dim = time_embed_dim, tau_hidden_dim
        if kernel_size % 2 != 1:
            raise ValueError(f"kernel_size must be odd to keep lengths, got {kernel_size}.")
        self.input_dim = input_dim
        self.global_cond_dim = global_cond_dim
        self.down_dims = down_dims
        self.predict_tau = predict_tau

        self.time_encoder = nn.Sequential(
            SinusoidalPosEmb(time_embed_dim, scale=time_scale),
            nn.Linear(time_embed_dim, 4 * time_embed_dim),
            nn.Mish(),
            nn.Linear(4 * time_embed_dim, time_embed_dim),
        )
        cond_dim = time_embed_dim + global_cond_dim
        self.cond_dim = cond_dim

        def block(c_in: int, c_out: int) -> ConditionalResidualBlock1D:
            return ConditionalResidualBlock1D(
                c_in, c_out, cond_dim, kernel_size, n_groups, cond_predict_scale
            )

        widths = (input_dim, *down_dims)
        n_levels = len(down_dims)
        self.down = nn.ModuleList()
        for level in range(n_levels):
            c_in, c_out = widths[level], widths[level + 1]
            is_last = level == n_levels - 1
            self.down.append(
                nn.ModuleList(
                    [
                        block(c_in, c_out),
                        block(c_out, c_out),
                        nn.Identity() if is_last else nn.Conv1d(c_out, c_out, 3, 2, 1),
                    ]
                )
            )
        self.mid = nn.ModuleList([block(down_dims[-1], down_dims[-1]) for _ in range(2)])
        # Up levels n-1 .. 1: each takes cat(x, skip) and returns the width of the level below.
        self.up = nn.ModuleList()
        for level in range(n_levels - 1, 0, -1):
            c_skip, c_below = down_dims[level], down_dims[level - 1]
            self.up.append(
                nn.ModuleList(
                    [
                        block(2 * c_skip, c_below),
                        block(c_below, c_below),
                        nn.ConvTranspose1d(c_below, c_below, 4, 2, 1),
                    ]
                )
            )
        self.final = nn.Sequential(
            Conv1dBlock(down_dims[0], down_dims[0], kernel_size, n_groups),
            nn.Conv1d(down_dims[0], input_dim, 1),
        )
        self.tau_head = (
            TauHead(
                global_cond_dim, time_embed_dim, tau_hidden_dim, tau_num_hidden_layers, time_scale
            )
            if predict_tau
            else None
        )

    def forward(
        self, sample: Tensor, t: Tensor, global_cond: Tensor | None = None
    ) -> Tensor | tuple[Tensor, Tensor]:
        """Evaluate the vector field.

        Args:
            sample: Point on the flow, shape ``(B, T_p, D)``.
            t: Flow time (RFMP), pseudo-time tau (SRFMP) or diffusion step, shape ``(B,)``,
                ``(B, 1)`` or ``()`` (broadcast to the batch).
            global_cond: Observation features ``(B, global_cond_dim)``; None when
                ``global_cond_dim == 0``.

        Returns:
            ``v_x`` of shape ``(B, T_p, D)``, or ``(v_x, v_tau)`` with ``v_tau`` of shape
            ``(B, 1)`` when built with ``predict_tau=True``.
        """
        if (global_cond is None) != (self.global_cond_dim == 0):
            raise ValueError(
                f"global_cond must be given iff global_cond_dim > 0 (got global_cond_dim="
                f"{self.global_cond_dim}, global_cond={'None' if global_cond is None else 'set'})."
            )
        batch = sample.shape[0]
        t = t.reshape(-1).expand(batch)  # (B,)
        cond = self.time_encoder(t)  # (B, time_embed_dim)
        if global_cond is not None:
            cond = torch.cat([cond, global_cond], dim=-1)  # (B, cond_dim)

        x = sample.transpose(1, 2)  # (B, D, T_p)
        skips: list[Tensor] = []
        lengths: list[int] = []
        for res1, res2, downsample in self.down:
            lengths.append(x.shape[-1])
            x = res2(res1(x, cond), cond)
            skips.append(x)
            x = downsample(x)
        for res in self.mid:
            x = res(x, cond)
        for res1, res2, upsample in self.up:
            x = torch.cat([x, skips.pop()], dim=1)
            x = res2(res1(x, cond), cond)
            x = upsample(x)
            x = x[..., : lengths[len(skips) - 1]]  # crop to the level below (no-op if even)
        v_x = self.final(x).transpose(1, 2)  # (B, T_p, D)
        if self.tau_head is None:
            return v_x
        return v_x, self.tau_head(t, global_cond)  # (B, T_p, D), (B, 1)


def make_unet(
    preset: str, input_dim: int, global_cond_dim: int, **overrides: object
) -> ConditionalUnet1D:
    """Build a :class:`ConditionalUnet1D` from a named preset of ``down_dims``.

    Args:
        preset: A key of :data:`UNET_PRESETS` (``"paper"``, ``"paper_real"``, ``"small"``).
        input_dim: Action dimension per step.
        global_cond_dim: Observation feature size.
        **overrides: Any other :class:`ConditionalUnet1D` keyword (``predict_tau``, ...).

    Returns:
        The network; kernel size 5, 8 groups, FiLM scale and bias as in Diffusion Policy, time
        embedding ``down_dims[0]`` (Diffusion Policy's 256 for the paper preset), unless
        overridden.

    Example:
        >>> net = make_unet("small", input_dim=2, global_cond_dim=40, predict_tau=True)
        >>> net.down_dims, net.time_embed_dim, net.tau_hidden_dim
        ((64, 128, 256), 64, 128)
    """
    if preset not in UNET_PRESETS:
        raise KeyError(f"Unknown UNet preset {preset!r}; choose from {sorted(UNET_PRESETS)}.")
    kwargs: dict[str, object] = {"down_dims": UNET_PRESETS[preset]}
    kwargs.update(overrides)
    return ConditionalUnet1D(input_dim, global_cond_dim, **kwargs)  # type: ignore[arg-type]
