"""Joint (context, skill) feature h, the energy model E_theta (eq. 11), validity (eq. 2) and the BCE variant.

h_i = normalize(normalize(W_c mu_c + b) + normalize(W_s e_i)): the context code joined with a learned embedding of
skill i (one row per CODA task slot, so a skill created later already has its row). Each part is a unit vector,
so the skill keeps its weight in h however far a context lies from the safe experience: with one projection of
[mu_c ; e_i], a large code drowns the skill, every skill gets the same energy in an unfamiliar context, and a
failure there suppresses the skill that corrects it as well as its culprit. h lies on the unit sphere, which
bounds the Euclidean distances of the triplet loss (eq. 5).

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
        self.context_proj = nn.Linear(latent_dim, feature_dim)
        self.skill_proj = nn.Linear(skill_dim, feature_dim, bias=False)

    def forward(self, mu: Tensor, skills: Tensor) -> Tensor:
        """h [N, feature_dim] of contexts mu [N, L] paired with skill indices [N]."""
        return self._join(self._context(mu), self._skill(skills))

    def all_skills(self, mu: Tensor, skills: Tensor) -> Tensor:
        """h [B, S, feature_dim] of every context [B, L] with every skill in `skills` [S]."""
        return self._join(self._context(mu).unsqueeze(1), self._skill(skills).unsqueeze(0))

    def _context(self, mu: Tensor) -> Tensor:
        return F.normalize(self.context_proj(mu), dim=-1)

    def _skill(self, skills: Tensor) -> Tensor:
        return F.normalize(self.skill_proj(self.skill_embed(skills)), dim=-1)

    @staticmethod
    def _join(context: Tensor, skill: Tensor) -> Tensor:
        return F.normalize(context + skill, dim=-1)


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
