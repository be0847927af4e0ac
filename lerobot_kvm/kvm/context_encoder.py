"""Context encoder E_c: raw multimodal context -> (mu_c, sigma_c^2)  (paper §3.1, App. E).

c_raw = [normalized sensed context (wrist F/T, touch, efforts, tracking error, finger velocity, last action),
         sqrt(D_q) * q(x)]  -- the frozen query embedding, rescaled so its entries are O(1) like the sensed ones.

E_c is an MLP (2x128, ReLU) to mu_c with a mirrored decoder back to c_raw. sigma_c^2 is the variance of c_raw
under the decoder's Gaussian p(c_raw | mu_c), estimated per modality: the mean squared reconstruction residual of
the sensed part and of the query part, each in units of its typical size on the safe experience (the smart
gate's window), summed (the query part weighted by `query_weight`):

    sigma_c^2 = r_sensed / s_sensed + query_weight * r_query / s_query

so that neither modality drowns the other (contact transients make the sensed residual heavy-tailed).
The decoder learns only from routine safe contexts (on the raw residual r_sensed + query_weight * r_query),
so sigma_c^2 stays low on the safe experience and rises when the interaction leaves it (unfamiliar forces, an
unfamiliar object): the novelty signal the smart gate (eq. 1) thresholds. An unfamiliar instruction is not
reliably one: a 32-dimensional code reconstructs a sentence near a known one about as well as the known ones
(docs/measurements.md), so the smart gate tests the instruction itself against the safe experience's.
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
    """E_c: encodes c_raw to mu_c and reconstructs it."""

    def __init__(
        self,
        sensed_dim: int,
        query_dim: int,
        hidden: list[int],
        latent_dim: int,
        use_query: bool,
        query_weight: float,
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
    """E_c rearranged for the smart gate's test at every control step: the same sigma_c^2 in fewer operations on
    fewer weights.

    At these sizes a step's cost is the number of tensor operations and the weights they read, not their
    arithmetic. The probe folds what is constant between weight updates: the encoder's last layer and the
    decoder's first (no ReLU between them) into one layer, the per-dimension residual weights w into the decoder's
    last layer (so sigma_c^2 = ||sqrt(w) * (recon - c_raw)||^2 is one more product). And the query q(x), 384 of
    c_raw's dimensions, changes only with the instruction, so its share is computed once per query and reused
    while it stays the same: its columns of the first layer, and its part of the residual, A h + b(q) with A the
    decoder's query rows (weighted) and h its last hidden layer. With A = QR (Q orthonormal, R square),
    ||A h + b||^2 = ||R h + Q^T b||^2 + ||b - Q Q^T b||^2, two sums of squares: the per-step residual has R's
    rows in place of A's, and the constant second term rides along as one more entry of it. mu_c, needed only
    where the gate opens, comes from the encoder's last hidden layer on request (`code`). A snapshot: rebuild it
    whenever the weights or the scales change (the smart gate does, on refresh).
    """

    @torch.no_grad()
    def __init__(self, encoder: ContextEncoder, dim_weights: Tensor) -> None:
        enc = [m for m in encoder.encoder if isinstance(m, nn.Linear)]
        dec = [m for m in encoder.decoder if isinstance(m, nn.Linear)]
        sensed = self.sensed_dim = encoder.sensed_dim
        self.uses_query = bool(encoder.query_dim)
        first = enc[0].weight.detach()
        self.sensed_first = first[:, :sensed].T.contiguous()  # [C, H]: the right operand of addmm
        self.query_first = (first[:, sensed:] * encoder.query_scale, enc[0].bias.detach().clone())
        joined = (dec[0].bias + dec[0].weight @ enc[-1].bias, (dec[0].weight @ enc[-1].weight).T.contiguous())
        self.layers = [  # (bias, weight^T): the operands of addmm
            *[(m.bias.detach().clone(), m.weight.detach().T.contiguous()) for m in enc[1:-1]],
            joined,
            *[(m.bias.detach().clone(), m.weight.detach().T.contiguous()) for m in dec[1:-1]],
        ]
        self.code_after = len(enc) - 2  # the layer (0: the first) whose output is the encoder's last hidden layer
        self.code_layer = (enc[-1].bias.detach().clone(), enc[-1].weight.detach().T.contiguous())
        root = dim_weights.sqrt()
        out = dec[-1].weight * root.unsqueeze(-1)  # [raw_dim, H]
        bias = dec[-1].bias * root
        self.minus_sensed = -root[:sensed]
        self.minus_query = -root[sensed:] * encoder.query_scale
        self.sensed_bias, self.query_bias = bias[:sensed], bias[sensed:]
        rows = [out[:sensed]]
        if self.uses_query:
            self.query_basis, square = torch.linalg.qr(out[sensed:])
            rows += [square, torch.zeros_like(square[:1])]  # the last entry carries ||b - Q Q^T b||
        self.out_weight = torch.cat(rows).T.contiguous()  # [H, C (+ rank + 1)]
        self._query: Tensor | None = None
        self._query_terms: tuple[Tensor, Tensor] = (self.query_first[1], self.sensed_bias)

    def _terms(self, query: Tensor | None, like: Tensor) -> tuple[Tensor, Tensor]:
        """(the first layer's bias plus the query's share [B, H], the residual's offset [B, C + rank + 1]: the
        sensed part's bias, Q^T b(q) and ||b(q) - Q Q^T b(q)||), recomputed only when the query changes."""
        if not self.uses_query:
            return self._query_terms
        query = _required(query).to(like)
        last = self._query
        if last is None or last.shape != query.shape or not torch.equal(last, query):
            b = torch.addcmul(self.query_bias, query, self.minus_query)
            along = b @ self.query_basis
            across = torch.linalg.vector_norm(b - along @ self.query_basis.T, dim=-1, keepdim=True)
            offset = torch.cat([self.sensed_bias.expand(len(query), -1), along, across], dim=-1)
            self._query, self._query_terms = query.clone(), (F.linear(query, *self.query_first), offset)
        return self._query_terms

    def __call__(self, sensed: Tensor, query: Tensor | None) -> tuple[Tensor, Tensor]:
        """(sigma_c^2 [B], the encoder's last hidden layer [B, H]) of the normalized sensed context [B, C] and the
        query embedding [B, D_q] (unscaled, as `ContextEncoder.raw_context` takes it)."""
        first, offset = self._terms(query, sensed)
        h = hidden = torch.addmm(first, sensed, self.sensed_first).relu_()
        for i, (bias, weight) in enumerate(self.layers, 1):
            h = torch.addmm(bias, h, weight).relu_()
            if i == self.code_after:
                hidden = h
        residual = torch.addmm(offset, h, self.out_weight)
        residual[:, : self.sensed_dim].addcmul_(sensed, self.minus_sensed)
        return torch.linalg.vecdot(residual, residual), hidden

    def code(self, hidden: Tensor) -> Tensor:
        """mu_c [B, latent_dim] from the encoder's last hidden layer."""
        return torch.addmm(self.code_layer[0], hidden, self.code_layer[1])
