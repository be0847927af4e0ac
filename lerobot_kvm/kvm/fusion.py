"""Decision weights and the fused prompt (eqs. 3-4) on the CODA-Prompt core.

The paper fuses P_fused = sum_i w_i P_i / (sum_i w_i + eps) with w_i = v_i * alpha_i. The CODA prompt is the
*unnormalised* sum sum_i c_i of the skills' contributions c_i = sum_{m in i} alpha_m P_m (alpha_m signed cosines,
no softmax), so eq. 3 is applied as a re-weighting of those contributions that is the identity at v = 1 (a skill's
relevance alpha_i is the size ||c_i|| of its contribution, see `CodaPromptPool.skill_relevance`):

* default (`renormalize=False`): skill weights s_i = v_i, i.e. P_fused = sum_i v_i c_i and each component's
  alpha_m of skill i becomes v_i * alpha_m (w_i = v_i * alpha_i). A suppressed skill's contribution vanishes and
  the others keep exactly the magnitude they were trained with (CODA trains skill k under sum_{i<=k} c_i, so
  suppressing later skills restores an earlier skill's training prompt exactly).
* `renormalize=True`: eq. 3's normalisation carried over, s_i = v_i * S / max(sum_j v_j alpha_j, eps * S) with
  S = sum_j alpha_j: the suppressed relevance mass goes to the remaining skills (the factor is S / S = 1.0
  exactly at v = 1, and at most 1 / eps).

Either way, at v = 1 the prompt is the CODA prompt bit for bit.

A skill the KVM created for a knowledge gap *corrects* another skill: it is out of force where the gate is closed
(inside the safe experience the corrected skill still holds) and, where the gate is open, valid at least as much as
the skill it corrects is not (`correction_validity`): the correction takes over exactly where the obsolete
knowledge is suppressed, however narrow the few seed contexts it was learned from.
"""

import torch
from torch import Tensor


def fuse_weights(v: Tensor, alphas: Tensor, renormalize: bool = False, eps: float = 1e-3) -> Tensor:
    """Skill weights [B, S] for the CODA pool from validity v [B, S] and per-skill relevance alpha [B, S]."""
    if not renormalize:
        return v
    mass = alphas.abs()
    total = mass.sum(-1, keepdim=True)
    kept = (v * mass).sum(-1, keepdim=True)
    factor = torch.where(total > 0, total / torch.maximum(kept, eps * total), torch.ones_like(total))
    return v * factor


def plain_scale(alphas: Tensor, correcting: Tensor) -> Tensor:
    """[B] the largest relevance among the skills that correct nothing (`correcting` [S] bool): the scale on
    which a corrected skill counts as the knowledge a task relies on."""
    return alphas.abs().masked_fill(correcting.unsqueeze(0), 0.0).amax(-1).clamp_min(1e-8)


def correction_validity(
    v: Tensor,
    corrections: tuple[Tensor, Tensor] | None,
    alphas: Tensor,
    necessity: float = 0.8,
    active: Tensor | None = None,
) -> Tensor:
    """v [B, S] with each correcting skill i raised to max(v_i, 1 - v_target(i)) in the rows where its target is
    necessary: the target's relevance alpha [B, S] is at least `necessity` times the largest relevance of a skill
    that corrects nothing (the target is the knowledge the task relies on, not a bystander that every novel
    context makes invalid). `corrections` = (mask [S] bool, target [S] index) from
    `CodaPromptPool.corrections` (None: no correcting skill, v unchanged).

    Two refinements keep corrections where they were made for. When one skill has several corrections (each
    made in another context), only the one with the highest own validity in a row inherits there (ties go to
    the oldest): the others' strategies were learned elsewhere. A pruned target (`active` [S] bool false) passes
    nothing on: its v = 0 is no judgement of the context."""
    if corrections is None:
        return v
    mask, target = corrections
    mass = alphas.abs()
    necessary = mass[:, target] >= necessity * plain_scale(mass, mask).unsqueeze(-1)
    if active is not None:
        necessary &= active[target].unsqueeze(0)
    inherited = torch.where(necessary & _chosen_sibling(v, mask, target), 1 - v[:, target], torch.zeros_like(v))
    return torch.where(mask.unsqueeze(0), torch.maximum(v, inherited), v)


def _chosen_sibling(v: Tensor, mask: Tensor, target: Tensor) -> Tensor:
    """[B, S] bool: correction i has the highest own v among the corrections of its target (earlier index on a
    tie); True for every skill without a sibling."""
    n = mask.shape[0]
    index = torch.arange(n, device=mask.device)
    sibling = mask.unsqueeze(1) & mask.unsqueeze(0) & (target.unsqueeze(1) == target.unsqueeze(0))
    sibling &= index.unsqueeze(1) != index.unsqueeze(0)  # [i, j]: j is another correction of i's target
    own, other = v.unsqueeze(-1), v.unsqueeze(-2)  # [B, i, 1], [B, 1, j]
    earlier = (index.unsqueeze(0) < index.unsqueeze(1)).unsqueeze(0)  # [1, i, j]: j before i
    beats = torch.where(earlier, own > other, own >= other)
    return (beats | ~sibling.unsqueeze(0)).all(-1)
