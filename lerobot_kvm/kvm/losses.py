"""KVM training objectives (paper §3.3, eqs. 5, 6, 13) and the BCE loss of the classifier ablation."""

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor

CONTRAST_MARGIN = 0.5  # m of eq. 5 (the features h lie on the unit sphere)
ENERGY_MARGIN = 10.0  # m_e of eq. 6 (App. E)
ENERGY_FLOOR = 10.0  # eq. 6's safe term stops at E = -ENERGY_FLOOR (see `energy_loss`)
ENERGY_WEIGHT = 1.0  # lambda of eq. 13
RECON_WEIGHT = 1.0  # E_c's reconstruction on routine safe contexts (§3.1: what makes sigma_c^2)
BCE_WEIGHT = 1.0  # Table 4's "w/o energy model" classifier, trained alongside on detached features


def contrastive_loss(anchor: Tensor, safe: Tensor, fail: Tensor, margin: float) -> Tensor:
    """Eq. 5: mean(max(0, D(anchor, safe) - D(anchor, fail) + m)) with Euclidean D; inputs [N, F]."""
    d_safe = (anchor - safe).norm(dim=-1)
    d_fail = (anchor - fail).norm(dim=-1)
    return F.relu(d_safe - d_fail + margin).mean()


def energy_loss(energy_safe: Tensor, energy_fail: Tensor, margin: float, floor: float | None = None) -> Tensor:
    """Eq. 6: E_safe[E(h_safe)] + E_fail[max(0, m_e - E(h_fail))]; an empty side contributes 0.

    `floor`: safe energies below -floor contribute the constant -floor (no gradient). Eq. 6's first term rewards
    ever lower safe energies; on a bounded energy that only pushes it into the flat part of the bound, where
    Adam's normalised steps turn vanishing gradients into a random walk. With the floor both terms are hinges
    that stop once satisfied (safe at or below -floor, hazardous at or above m_e)."""
    loss = energy_safe.new_zeros(())
    if energy_safe.numel():
        loss = loss + (energy_safe if floor is None else energy_safe.clamp_min(-floor)).mean()
    if energy_fail.numel():
        loss = loss + F.relu(margin - energy_fail).mean()
    return loss


def total_loss(contrast: Tensor, energy: Tensor, weight: float) -> Tensor:
    """Eq. 13: L_contrast + lambda * L_energy."""
    return contrast + weight * energy


def bce_loss(logit_safe: Tensor, logit_fail: Tensor) -> Tensor:
    """Binary cross-entropy of a failure logit: safe samples labelled 0, hazardous ones 1 (class-balanced)."""
    loss = logit_safe.new_zeros(())
    if logit_safe.numel():
        loss = loss + F.binary_cross_entropy_with_logits(logit_safe, torch.zeros_like(logit_safe))
    if logit_fail.numel():
        loss = loss + F.binary_cross_entropy_with_logits(logit_fail, torch.ones_like(logit_fail))
    return loss
