"""Joint (context, skill) feature h, the energy model E_theta (eq. 11), validity (eq. 2) and the BCE variant.

h_i = normalize(W [mu_c ; e_i] + b): the context code joined with a learned embedding of skill i (one row per
CODA task slot, so a skill created later already has its row). h lies on the unit sphere, which bounds the
Euclidean distances of the triplet loss (eq. 5).

E_theta is an MLP (3x256, ReLU) with a bounded output E = E_max * tanh(raw / E_max): eq. 6 rewards low energy
on safe samples without limit, so an unbounded energy would run to -inf.

The "w/o energy model" ablation is `RiskClassifier`: the same MLP giving a failure logit l trained with BCE.
Its energy-equivalent is E = l / gamma - l0', so that eq. 2 gives v = 1 - sigmoid(l) = P(safe).
"""

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from .context_encoder import mlp


def validity(energy: Tensor, gamma: float, l0: float) -> Tensor:
    """Eq. 2: v = 1 / (1 + exp(-gamma * (-E - l0')))."""
    return torch.sigmoid(gamma * (-energy - l0))


class JointFeature(nn.Module):
    def __init__(self, latent_dim: int, n_skills: int, skill_dim: int, feature_dim: int) -> None:
        super().__init__()
        self.skill_embed = nn.Embedding(n_skills, skill_dim)
        self.proj = nn.Linear(latent_dim + skill_dim, feature_dim)

    def forward(self, mu: Tensor, skills: Tensor) -> Tensor:
        """h [N, feature_dim] of contexts mu [N, L] paired with skill indices [N]."""
        return F.normalize(self.proj(torch.cat([mu, self.skill_embed(skills)], dim=-1)), dim=-1)

    def all_skills(self, mu: Tensor, skills: Tensor) -> Tensor:
        """h [B, S, feature_dim] of every context [B, L] with every skill in `skills` [S]."""
        emb = self.skill_embed(skills)  # [S, E]
        b, s = mu.shape[0], emb.shape[0]
        joined = torch.cat([mu.unsqueeze(1).expand(b, s, -1), emb.unsqueeze(0).expand(b, s, -1)], dim=-1)
        return F.normalize(self.proj(joined), dim=-1)


class EnergyModel(nn.Module):
    def __init__(self, feature_dim: int, hidden: list[int], energy_max: float) -> None:
        super().__init__()
        self.net = mlp(feature_dim, list(hidden), 1)
        self.energy_max = energy_max

    def forward(self, h: Tensor) -> Tensor:
        raw = self.net(h).squeeze(-1)
        return self.energy_max * torch.tanh(raw / self.energy_max)


class RiskClassifier(nn.Module):
    """MLP binary classifier (failure logit) for the "w/o energy model" ablation."""

    def __init__(self, feature_dim: int, hidden: list[int]) -> None:
        super().__init__()
        self.net = mlp(feature_dim, list(hidden), 1)

    def forward(self, h: Tensor) -> Tensor:
        return self.net(h).squeeze(-1)

    @staticmethod
    def energy_equivalent(logit: Tensor, gamma: float, l0: float) -> Tensor:
        return logit / gamma - l0
