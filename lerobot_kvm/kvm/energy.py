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

`SkillScorer` is either network over the joint feature rearranged for the gate-open control step.
"""

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from .context_encoder import mlp

GAMMA = 1.0  # eq. 2, App. E: gamma
L0 = -5.0  # eq. 2, App. E: l0' (v = 1/2 at E = 5)
ENERGY_MAX = 20.0  # eq. 11's bound E = E_max * tanh(raw / E_max), so that eq. 6's first term cannot run away


def validity(energy: Tensor, gamma: float, l0: float) -> Tensor:
    """Eq. 2: v = 1 / (1 + exp(-gamma * (-E - l0'))), written -gamma * (E + l0') (the same floats, one operation
    fewer: it runs at every gate-open step)."""
    return torch.sigmoid((energy + l0) * -gamma)


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


class SkillScorer:
    """E_theta (or the classifier's logit) of contexts with every skill in few tensor operations: a snapshot of the
    joint feature and one network, for the gate-open control step (no gradients).

    At these sizes a step's cost is its number of tensor operations, and the joint feature with every skill
    repeats per skill what is the same for all of them. The skill half of the join is constant between weight
    updates, and the network's first layer is linear: with c the context's unit vector and s_i skill i's,
    W1 normalize(c + s_i) = (W1 c + W1 s_i) / |c + s_i| and |c + s_i|^2 = 1 + 2 c.s_i + |s_i|^2, so the first layer
    takes one product for the context and a stored W1 s_i per skill. Rebuild it whenever the weights change.
    """

    @torch.no_grad()
    def __init__(self, joint: JointFeature, net: nn.Sequential, n_skills: int, bound: float | None) -> None:
        proj = joint.context_proj
        units = joint._skill(torch.arange(n_skills, device=proj.weight.device))  # [S, F]
        layers = [(m.bias.detach(), m.weight.detach().T) for m in net if isinstance(m, nn.Linear)]
        if bound is not None:  # E = bound * tanh(raw / bound): the division rides in the output layer
            layers[-1] = (layers[-1][0] / bound, layers[-1][1] / bound)
        # (bias, weight^T), the operands of addmm; copies, so that the snapshot never shares the weights' memory
        self.first, *self.layers = [(b.clone().contiguous(), w.clone().contiguous()) for b, w in layers]
        self.context = (proj.bias.detach().clone(), proj.weight.detach().T.contiguous())
        self.skill_first = units @ self.first[1]  # [S, H]: W1 s_i
        self.skill_units = units.T.contiguous()  # [F, S]
        self.skill_norms = units.square().sum(-1) + 1.0  # [S]: |c|^2 + |s_i|^2, c a unit vector
        self.bound = bound

    def __call__(self, mu: Tensor) -> Tensor:
        """[B, S] scores of the codes mu [B, L] with every skill (the network's output on `JointFeature.all_skills`)."""
        c = F.normalize(torch.addmm(self.context[0], mu, self.context[1]), dim=-1)  # [B, F]
        squares = torch.addmm(self.skill_norms, c, self.skill_units, alpha=2.0)  # |c + s_i|^2
        inv = squares.clamp_min_(1e-24).rsqrt_()  # F.normalize's floor (1e-12) on the norm
        pre = (c @ self.first[1]).unsqueeze(1) + self.skill_first  # [B, S, H]
        h = torch.addcmul(self.first[0], pre, inv.unsqueeze(-1)).flatten(0, 1)
        for bias, weight in self.layers:
            h = torch.addmm(bias, h.relu_(), weight)
        raw = h.view(len(mu), -1)
        return raw if self.bound is None else raw.tanh_().mul_(self.bound)
