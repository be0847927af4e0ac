"""Context encoder E_c: raw multimodal context -> (mu_c, sigma_c^2)  (paper §3.1, App. E).

c_raw = [normalized sensed context (wrist F/T, touch, efforts, tracking error, finger velocity, last action),
         sqrt(D_q) * q(x)]  -- the frozen query embedding, rescaled so its entries are O(1) like the sensed ones.

E_c is an MLP (2x128, ReLU) to mu_c with a mirrored decoder back to c_raw. sigma_c^2 is the maximum-likelihood
variance of c_raw under the decoder's isotropic Gaussian p(c_raw | mu_c), i.e. the mean squared reconstruction
residual (sensed part + query_weight * query part). The decoder learns only from routine safe contexts, so
sigma_c^2 stays low on the safe experience and rises when the interaction leaves it (unfamiliar forces,
an unfamiliar object or instruction): the novelty signal the smart gate (eq. 1) thresholds.
"""

import math

import torch
from torch import Tensor, nn


def mlp(in_dim: int, hidden: list[int], out_dim: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    prev = in_dim
    for width in hidden:
        layers += [nn.Linear(prev, width), nn.ReLU()]
        prev = width
    layers.append(nn.Linear(prev, out_dim))
    return nn.Sequential(*layers)


class ContextEncoder(nn.Module):
    def __init__(
        self, sensed_dim: int, query_dim: int, hidden: list[int], latent_dim: int, use_query: bool, query_weight: float
    ) -> None:
        super().__init__()
        self.sensed_dim = sensed_dim
        self.query_dim = query_dim if use_query else 0
        self.raw_dim = sensed_dim + self.query_dim
        self.query_scale = math.sqrt(query_dim)
        self.query_weight = query_weight
        self.encoder = mlp(self.raw_dim, list(hidden), latent_dim)
        self.decoder = mlp(latent_dim, list(reversed(hidden)), self.raw_dim)

    def raw_context(self, sensed: Tensor, query: Tensor | None) -> Tensor:
        """c_raw [B, raw_dim] from the normalized sensed context [B, C] and the query embedding [B, D_q]."""
        if not self.query_dim:
            return sensed
        if query is None:
            raise ValueError("the KVM context encoder uses the query embedding q(x), but none was given")
        return torch.cat([sensed, query.to(sensed) * self.query_scale], dim=-1)

    def residual(self, c_raw: Tensor, recon: Tensor) -> Tensor:
        """sigma_c^2 [B]: mean squared residual of the sensed part + query_weight * that of the query part."""
        sq = (c_raw - recon) ** 2
        sigma2 = sq[..., : self.sensed_dim].mean(-1)
        if self.query_dim:
            sigma2 = sigma2 + self.query_weight * sq[..., self.sensed_dim :].mean(-1)
        return sigma2

    def forward(self, c_raw: Tensor) -> tuple[Tensor, Tensor]:
        """(mu_c [B, latent_dim], sigma_c^2 [B])."""
        mu = self.encoder(c_raw)
        return mu, self.residual(c_raw, self.decoder(mu))
