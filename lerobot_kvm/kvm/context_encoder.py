"""Context encoder E_c: raw multimodal context -> (mu_c, sigma_c^2)  (paper §3.1, App. E).

c_raw = [normalized sensed context (wrist F/T, touch, efforts, tracking error, finger velocity, last action),
         sqrt(D_q) * q(x)]  -- the frozen query embedding, rescaled so its entries are O(1) like the sensed ones.

E_c is an MLP (2x128, ReLU) to mu_c with a mirrored decoder back to c_raw. sigma_c^2 is the variance of c_raw
under the decoder's Gaussian p(c_raw | mu_c), estimated per modality: the mean squared reconstruction residual of
the sensed part and of the query part, each in units of its typical size on the safe experience (the smart
gate's window), summed (the query part weighted by `query_weight`):

    sigma_c^2 = r_sensed / s_sensed + query_weight * r_query / s_query

so that neither modality drowns the other (contact transients make the sensed residual heavy-tailed; a
memorised instruction reconstructs almost exactly, so an unfamiliar one stands out by orders of magnitude).
The decoder learns only from routine safe contexts (on the raw residual r_sensed + query_weight * r_query),
so sigma_c^2 stays low on the safe experience and rises when the interaction leaves it (unfamiliar forces,
an unfamiliar object or instruction): the novelty signal the smart gate (eq. 1) thresholds.
"""

import math

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn


def _required(query: Tensor | None) -> Tensor:
    if query is None:
        raise ValueError("the KVM context encoder uses the query embedding q(x), but none was given")
    return query


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
        query = _required(query)
        return torch.cat([sensed, query.to(sensed) * self.query_scale], dim=-1)

    def residual_parts(self, c_raw: Tensor, recon: Tensor) -> Tensor:
        """[B, P] mean squared residual per modality: sensed, then query (P = 2 with the query, else 1)."""
        sq = (c_raw - recon) ** 2
        parts = [sq[..., : self.sensed_dim].mean(-1)]
        if self.query_dim:
            parts.append(sq[..., self.sensed_dim :].mean(-1))
        return torch.stack(parts, dim=-1)

    def weights(self) -> list[float]:
        return [1.0, self.query_weight] if self.query_dim else [1.0]

    def recon_loss(self, parts: Tensor) -> Tensor:
        """[B] raw reconstruction residual r_sensed + query_weight * r_query (what the decoder minimises)."""
        return (parts * parts.new_tensor(self.weights())).sum(-1)

    def sigma2(self, parts: Tensor, scale: Tensor) -> Tensor:
        """[B] sigma_c^2: each modality's residual relative to its scale on the safe experience."""
        return (parts / scale * parts.new_tensor(self.weights())).sum(-1)

    def dim_weights(self, scale: Tensor) -> Tensor:
        """[raw_dim] per-dimension weights with sigma2(parts, scale) == squared residual @ dim_weights."""
        w = [torch.full((self.sensed_dim,), 1.0 / (self.sensed_dim * float(scale[0])))]
        if self.query_dim:
            w.append(torch.full((self.query_dim,), self.query_weight / (self.query_dim * float(scale[1]))))
        return torch.cat(w).to(scale.device)

    def gate_probe(self, scale: Tensor) -> "GateProbe":
        """The encoder folded for the smart gate's per-step test with the residual scales `scale`."""
        return GateProbe(self, self.dim_weights(scale))

    def forward(self, c_raw: Tensor) -> tuple[Tensor, Tensor]:
        """(mu_c [B, latent_dim], residual parts [B, P])."""
        mu = self.encoder(c_raw)
        return mu, self.residual_parts(c_raw, self.decoder(mu))


class GateProbe:
    """E_c rearranged for the smart gate's test at every control step: the same sigma_c^2 in fewer operations.

    At these sizes a step's cost is the number of tensor operations, not their arithmetic, so the probe folds what
    is constant between weight updates: the query's sqrt(D_q) rescaling into the first layer, the encoder's last
    layer and the decoder's first (no ReLU between them) into one layer, and the per-dimension residual weights w
    into the decoder's last layer, so that sigma_c^2 = ||sqrt(w) * (recon - c_raw)||^2 is one more product. mu_c,
    needed only where the gate opens, comes from the encoder's last hidden layer on request (`code`). A snapshot:
    rebuild it whenever the weights or the scales change (the smart gate does, on refresh).
    """

    @torch.no_grad()
    def __init__(self, encoder: ContextEncoder, dim_weights: Tensor) -> None:
        enc = [m for m in encoder.encoder if isinstance(m, nn.Linear)]
        dec = [m for m in encoder.decoder if isinstance(m, nn.Linear)]
        sensed = encoder.sensed_dim
        input_scale = torch.ones(encoder.raw_dim, device=dim_weights.device)
        input_scale[sensed:] = encoder.query_scale  # c_raw = [sensed, query] * input_scale
        first = enc[0].weight * input_scale
        joined = (dec[0].weight @ enc[-1].weight, dec[0].weight @ enc[-1].bias + dec[0].bias)
        self.layers = [
            (first, enc[0].bias.detach().clone()),
            *[(m.weight.detach().clone(), m.bias.detach().clone()) for m in enc[1:-1]],
            joined,
            *[(m.weight.detach().clone(), m.bias.detach().clone()) for m in dec[1:-1]],
        ]
        self.code_after = len(enc) - 2  # the layer whose output is the encoder's last hidden layer
        self.code_layer = (enc[-1].weight.detach().clone(), enc[-1].bias.detach().clone())
        root = dim_weights.sqrt()
        self.out_layer = (dec[-1].weight * root.unsqueeze(-1), dec[-1].bias * root)
        self.minus_input = -(root * input_scale)
        self.uses_query = bool(encoder.query_dim)

    def __call__(self, sensed: Tensor, query: Tensor | None) -> tuple[Tensor, Tensor]:
        """(sigma_c^2 [B], the encoder's last hidden layer [B, H]) of the normalized sensed context [B, C] and the
        query embedding [B, D_q] (unscaled, as `ContextEncoder.raw_context` takes it)."""
        x = torch.cat([sensed, _required(query).to(sensed)], dim=-1) if self.uses_query else sensed
        h = hidden = x
        for i, (weight, bias) in enumerate(self.layers):
            h = torch.relu(F.linear(h, weight, bias))
            if i == self.code_after:
                hidden = h
        residual = F.linear(h, *self.out_layer).addcmul_(x, self.minus_input)
        return torch.linalg.vecdot(residual, residual), hidden

    def code(self, hidden: Tensor) -> Tensor:
        """mu_c [B, latent_dim] from the encoder's last hidden layer."""
        return F.linear(hidden, *self.code_layer)
