"""SRFMP's pseudo-time head: an MLP that predicts the pseudo-time velocity v_tau.

SRFMP augments the action chunk with a pseudo-time state tau, xi = [a, tau], and regresses the
stable field u(xi | xi_1) = [-lambda_x Log_{x_1}(x), -lambda_tau (tau - tau_1)] (paper, eq.
"stableriemanianvectorfield"). The UNet predicts the action part v_x; this head predicts the scalar
v_tau. As the paper describes ("an additional MLP to learn v_tau", with tau sinusoidally
embedded), it embeds tau with its own sinusoid + MLP (as the UNet does), concatenates the
observation features and applies an MLP. With the defaults (embedding 256, two hidden layers of
512) the head adds ~0.94M parameters to a robomimic state model and ~1.45M to a Push-T image
model, matching the SRFMP - RFMP differences of the paper's hyperparameter table (1.0e6, 1.4e6).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from rfmp_rl.models.embeddings import DEFAULT_TIME_SCALE, SinusoidalPosEmb

__all__ = ["TauHead"]


class TauHead(nn.Module):
    """``(tau, obs features) -> v_tau``: sinusoidal tau embedding + MLP, then an MLP with Mish.

    Args:
        global_cond_dim: Size of the observation feature vector (0 for none).
        time_embed_dim: Size of the tau embedding (``SinEmb -> Linear(d, 4d) -> Mish ->
            Linear(4d, d)``).
        hidden_dim: Width of the hidden layers of the output MLP.
        num_hidden_layers: Number of hidden ``Linear -> Mish`` layers (at least 1).
        time_scale: Factor applied to tau before the sinusoid (see
            :mod:`rfmp_rl.models.embeddings`).

    Example:
        >>> import torch
        >>> head = TauHead(global_cond_dim=40)
        >>> head(torch.rand(8), torch.randn(8, 40)).shape
        torch.Size([8, 1])
    """

    def __init__(
        self,
        global_cond_dim: int,
        time_embed_dim: int = 256,
        hidden_dim: int = 512,
        num_hidden_layers: int = 2,
        time_scale: float = DEFAULT_TIME_SCALE,
    ) -> None:
        super().__init__()
        if num_hidden_layers < 1:
            raise ValueError(f"num_hidden_layers must be >= 1, got {num_hidden_layers}.")
        self.time_encoder = nn.Sequential(
            SinusoidalPosEmb(time_embed_dim, scale=time_scale),
            nn.Linear(time_embed_dim, 4 * time_embed_dim),
            nn.Mish(),
            nn.Linear(4 * time_embed_dim, time_embed_dim),
        )
        layers: list[nn.Module] = []
        in_dim = time_embed_dim + global_cond_dim
        for _ in range(num_hidden_layers):
            layers += [nn.Linear(in_dim, hidden_dim), nn.Mish()]
            in_dim = hidden_dim
        layers.append(nn.Linear(in_dim, 1))
        self.mlp = nn.Sequential(*layers)

    def forward(self, tau: Tensor, global_cond: Tensor | None = None) -> Tensor:
        """Predict v_tau.

        Args:
            tau: Pseudo-time, shape ``(B,)``, ``(B, 1)`` or ``()`` (broadcast to the batch of
                ``global_cond``).
            global_cond: Observation features ``(B, global_cond_dim)``, or None.

        Returns:
            ``v_tau`` of shape ``(B, 1)``.
        """
        emb = self.time_encoder(tau)  # (B, time_embed_dim) or (1, time_embed_dim)
        if global_cond is not None:
            emb = emb.expand(global_cond.shape[0], -1)
            emb = torch.cat([emb, global_cond], dim=-1)  # (B, time_embed_dim + global_cond_dim)
        return self.mlp(emb)  # (B, 1)
