"""Decision weights and the fused prompt's candidates (eq. 3), the suppression threshold, and corrections.

The paper fuses P_fused = sum_i w_i P_i / (sum_i w_i + eps) over the candidate skills P_cand, with w_i = v_i * alpha_i
(`decision_weights`; the pool applies the normalisation, `CodaPromptPool.prompt_from_alphas`): a suppressed skill's
share goes to the remaining valid candidates. The CL core proposes the candidates (`candidates`): the skills whose
relevance is at least `CANDIDATE_SHARE` of the best one's. A suppression (v_i < tau_v, App. A) removes the skill
from the fusion: with the pool's sharp relevance a suppressed prior skill would otherwise still outweigh the
alternative it must hand over to. With every v_i = 1 (the gate closed, or the KVM off) the weights are the
relevances alone. When every candidate is suppressed there is nothing valid to fuse and the policy abstains
(`abstains`).

A skill the KVM created for a knowledge gap *corrects* another skill: it is out of force where the gate is closed
(inside the safe experience the corrected skill still holds) and, where the gate is open and the task relies on the
skill it corrects, exactly as valid as that skill is not (`correction_validity`): the correction takes over where
the obsolete knowledge is suppressed, however narrow the few seed contexts it was learned from, and stays out of a
context where that knowledge still holds (a prompt mixed from the two is neither strategy).
"""

import torch
from torch import Tensor

TAU_V = 0.1  # App. E: v below tau_v is a suppression ("intervention"); also eq. 8's threshold
# Algorithm 1 line 5, P_cand: a skill is a candidate at relevance >= this share of the best skill's. With the pool's
# relevance temperature (0.01) that is a query cosine at most 0.23 below the best skill's: a scenario's safe skill
# (0.04-0.20 below its variant's instruction) is a candidate, other scenarios' skills (0.4 below or more) are not.
CANDIDATE_SHARE = 1e-10


def candidates(alphas: Tensor, active: Tensor) -> Tensor:
    """[B, S] bool: skills the CL core proposes for these rows (active, relevance alpha [B, S] at least
    `CANDIDATE_SHARE` of the row's best active skill)."""
    mass = alphas * active.to(alphas)
    return active.unsqueeze(0) & (mass >= CANDIDATE_SHARE * mass.amax(-1, keepdim=True)) & (mass > 0)


def decision_weights(v: Tensor, alphas: Tensor, candidate: Tensor) -> Tensor:
    """Eq. 3's w_i = v_i * alpha_i [B, S] over the candidates that are not suppressed (v_i >= tau_v; 0 elsewhere),
    the relevances taken relative to the best candidate's: a common factor, which eq. 3's normalisation removes,
    keeps the weights far above its eps however small the relevances."""
    scale = torch.where(candidate, alphas, torch.zeros_like(alphas)).amax(-1, keepdim=True).clamp_min(1e-30)
    return torch.where(candidate & (v >= TAU_V), v * alphas / scale, torch.zeros_like(alphas))


def abstains(v: Tensor, weights: Tensor, candidate: Tensor) -> Tensor:
    """[B] bool: no candidate in force is valid (every one suppressed, v_i < tau_v, or weighted 0): abstain."""
    return ~(candidate & (v >= TAU_V) & (weights > 0)).any(-1)


def plain_scale(alphas: Tensor, correcting: Tensor) -> Tensor:
    """[B] the largest relevance among the skills that correct nothing (`correcting` [S] bool): the scale on
    which a corrected skill counts as the knowledge a task relies on."""
    return alphas.abs().masked_fill(correcting.unsqueeze(0), 0.0).amax(-1).clamp_min(1e-8)


def correction_validity(v: Tensor, corrections: tuple[Tensor, Tensor] | None, mirror: Tensor | None) -> Tensor:
    """v [B, S] with each correcting skill i set to 1 - v_target(i) in the rows where it mirrors its target
    (`mirror` [B, S] from `mirrored`: the target is the knowledge the task relies on, not a bystander that every
    novel context makes invalid). Elsewhere a correction keeps its own v. `corrections` = (mask [S] bool, target
    [S] index) from `CodaPromptPool.corrections` (None: no correcting skill, v unchanged).

    The correction replaces its own v there rather than raising it: where the target still holds (v_target near 1)
    a correction with a high own v would otherwise share the fused prompt with it, and on the default pool the
    drawer's correction carried the prior variant's control steps without any suppression (docs/measurements.md,
    corrections in force only where the target is not). When one skill has several corrections (each made in
    another context), only the one with the highest own validity in a row takes over there (ties go to the
    oldest); the others weigh nothing there."""
    if corrections is None or mirror is None:
        return v
    mask, target = corrections
    inherited = torch.where(_chosen_sibling(v, mask, target), 1 - v[:, target], torch.zeros_like(v))
    return torch.where(mirror, inherited, v)


def mirrored(
    corrections: tuple[Tensor, Tensor], alphas: Tensor, necessity: float = 0.8, active: Tensor | None = None
) -> Tensor:
    """[B, S] bool: the correcting skills whose v mirrors the skill they correct in these rows (`correction_validity`):
    the target's relevance alpha [B, S] is at least `necessity` times the largest relevance of a skill that corrects
    nothing. Such a v is no judgement of the correction itself, so a correction held out where its target still
    holds is no suppression (`KvmStepTelemetry.intervention`). A pruned target (`active` [S] bool false) passes
    nothing on: its v = 0 is no judgement of the context."""
    mask, target = corrections
    mass = alphas.abs()
    necessary = mass[:, target] >= necessity * plain_scale(mass, mask).unsqueeze(-1)
    if active is not None:
        necessary &= active[target].unsqueeze(0)
    return mask.unsqueeze(0) & necessary


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
