"""Verification-based attribution and knowledge-gap confirmation (paper App. D).

A failure forms a low-confidence hypothesis "skill i is risky in context C". The culprit proposed is the skill the
CL core relied on most just before the failure, its largest share of the CODA prompt (`culprit_skill`). With a
corrective demonstration it is verified by counterfactuals (`counterfactual_culprit`): each skill the CL core
proposed is taken out of the prompt in turn, and another skill is blamed instead when its removal brings the
policy's actions on the demonstration clearly closer to it, and clearly closer than the proposed skill's removal
does. The largest share is often a skill learned later for the same scene, the very strategy the demonstration
shows. The skill whose removal takes the actions furthest from the demonstration is the one that shows the safe
strategy (`agreeing_skill`). The removals read the prompt before the KVM's re-weighting; the shares the culprit
rule reads are the executed prompt's, in which a skill suppressed during the attempt keeps its share, so a failure
while the culprit was already suppressed counts against its hypothesis instead of passing the blame to whichever
skills were left in force.

Later attempts verify the hypothesis: when the KVM suppresses skill i (v_i < tau_v) in a context similar to C and
the attempt succeeds, the hypothesis's intervention counter is incremented (persistence). An intervention confirms
the hypothesis when the counter exceeds N_p *and* the suppressed skill was a high-relevance option of the CL core
(normalised alpha_i > tau_high: necessity). A failure while skill i was suppressed in such a context breaks the
persistence (the counter restarts from 0).

Confirmed hypotheses make their failure contexts permanent h_fail negatives; if every alternative skill stayed
weak (normalised alpha < gap_alpha) a knowledge gap is diagnosed and a new skill is created.

The table is a set of fixed-capacity persistent buffers (one row per hypothesis).
"""

import torch
from torch import Tensor, nn

EMPTY, OPEN, CONFIRMED = 0, 1, 2
STATE_NAMES = {EMPTY: "empty", OPEN: "open", CONFIRMED: "confirmed"}
PERSISTENCE = 3  # App. D, App. E: N_p, a hypothesis is confirmed when its intervention counter exceeds it


class HypothesisTable(nn.Module):
    def __init__(self, capacity: int, raw_dim: int, persistence: int, tau_high: float) -> None:
        super().__init__()
        self.persistence = persistence
        self.tau_high = tau_high
        self.register_buffer("state", torch.zeros(capacity, dtype=torch.int64))
        self.register_buffer("skill", torch.full((capacity,), -1, dtype=torch.int64))
        self.register_buffer("counter", torch.zeros(capacity, dtype=torch.int64))  # persistent interventions
        self.register_buffer("necessary", torch.zeros(capacity, dtype=torch.int64))  # of which necessary
        self.register_buffer("failures", torch.zeros(capacity, dtype=torch.int64))
        self.register_buffer("gap", torch.zeros(capacity, dtype=torch.int64))  # knowledge gap confirmed
        self.register_buffer("new_skill", torch.full((capacity,), -1, dtype=torch.int64))
        self.register_buffer("hid", torch.full((capacity,), -1, dtype=torch.int64))  # stable id of the row
        self.register_buffer("prototype", torch.zeros(capacity, raw_dim))  # c_raw at the failure
        self.register_buffer("next_id", torch.zeros(1, dtype=torch.int64))

    @property
    def capacity(self) -> int:
        return self.state.shape[0]

    def row(self, hypothesis_id: int) -> int:
        rows = torch.nonzero((self.hid == hypothesis_id) & (self.state != EMPTY)).flatten()
        if not len(rows):
            raise KeyError(f"no hypothesis with id {hypothesis_id}")
        return int(rows[0])

    def ids(self, state: int | None = None, skill: int | None = None) -> list[int]:
        mask = self.state != EMPTY
        if state is not None:
            mask &= self.state == state
        if skill is not None:
            mask &= self.skill == skill
        return [int(self.hid[r]) for r in torch.nonzero(mask).flatten()]

    def info(self, hypothesis_id: int) -> dict:
        r = self.row(hypothesis_id)
        return {
            "id": hypothesis_id,
            "state": STATE_NAMES[int(self.state[r])],
            "skill": int(self.skill[r]),
            "counter": int(self.counter[r]),
            "necessary": int(self.necessary[r]),
            "failures": int(self.failures[r]),
            "gap": bool(self.gap[r]),
            "new_skill": int(self.new_skill[r]),
        }

    @torch.no_grad()
    def open(self, skill: int, prototype: Tensor) -> int:
        """A new low-confidence hypothesis; evicts the oldest open (else oldest) row when full."""
        free = torch.nonzero(self.state == EMPTY).flatten()
        if len(free):
            r = int(free[0])
        else:
            candidates = torch.nonzero(self.state == OPEN).flatten()
            if not len(candidates):
                candidates = torch.arange(self.capacity, device=self.state.device)
            r = int(candidates[torch.argmin(self.hid[candidates])])
        hypothesis_id = int(self.next_id.item())
        self.next_id += 1
        self.state[r] = OPEN
        self.skill[r] = skill
        self.counter[r] = 0
        self.necessary[r] = 0
        self.failures[r] = 1
        self.gap[r] = 0
        self.new_skill[r] = -1
        self.hid[r] = hypothesis_id
        self.prototype[r] = prototype.detach().to(self.prototype)
        return hypothesis_id

    @torch.no_grad()
    def record_intervention(self, hypothesis_id: int, necessary: bool) -> bool:
        """A successful intervention on the hypothesis's skill in a similar context. Returns True when this
        intervention confirms it (counter > N_p and necessary)."""
        r = self.row(hypothesis_id)
        self.counter[r] += 1
        self.necessary[r] += int(necessary)
        if int(self.state[r]) == OPEN and int(self.counter[r]) > self.persistence and necessary:
            self.state[r] = CONFIRMED
            return True
        return False

    @torch.no_grad()
    def record_failure(self, hypothesis_id: int, suppressed: bool) -> None:
        """Another failure in the hypothesis's context; if its skill was suppressed, persistence restarts."""
        r = self.row(hypothesis_id)
        self.failures[r] += 1
        if suppressed and int(self.state[r]) == OPEN:
            self.counter[r] = 0
            self.necessary[r] = 0

    @torch.no_grad()
    def mark_gap(self, hypothesis_id: int, new_skill: int) -> None:
        r = self.row(hypothesis_id)
        self.gap[r] = 1
        self.new_skill[r] = new_skill

    def is_confirmed(self, hypothesis_id: int) -> bool:
        return int(self.state[self.row(hypothesis_id)]) == CONFIRMED


def normalised_relevance(alphas: Tensor, active: Tensor) -> Tensor:
    """r_i = alpha_i / max_j alpha_j over every skill (the dominant skill has r = 1); 0 for pruned skills.

    alphas: per-skill relevance (the size of each skill's prompt contribution, non-negative). The scale is the
    pool's, pruned skills included: retiring the skill a task relied on must not promote the skills that
    barely touch that task's prompt to candidates, which would then be blamed for its failures in turn."""
    mass = alphas.abs()
    return mass * active.to(alphas) / mass.amax(-1, keepdim=True).clamp_min(1e-8)


def culprit_skill(alphas: Tensor, last_k: int) -> int:
    """Minimal counterfactual: the skill with the largest mean share of the CODA prompt over the last K steps.

    alphas: [T, S] per-skill weight in the prompt (zero for pruned skills); each row is normalised to shares.
    """
    contribution = alphas.abs()[-last_k:]
    share = contribution / contribution.sum(-1, keepdim=True).clamp_min(1e-8)
    return int(share.mean(0).argmax())


def counterfactual_culprit(error: float, without: Tensor, candidates: Tensor, proposed: int, margin: float) -> int:
    """The culprit verified by removals: the proposed skill (largest prompt share) stands unless taking another
    candidate out of the prompt cuts the action error on the correction by more than `margin` * error, and by
    that much more than taking the proposed skill out does.

    error: the policy's action error on the corrective demonstration with every skill in force; without: [S] the
    error with skill i taken out; candidates: [S] bool, the skills proposed (`proposed` among them)."""
    gain = (error - without).masked_fill(~candidates, float("-inf"))
    best = int(gain.argmax())
    helps = float(gain[best]) > margin * error
    return best if helps and float(gain[best] - gain[proposed]) > margin * error else proposed


def agreeing_skill(error: float, without: Tensor, candidates: Tensor, culprit: int) -> int | None:
    """The candidate other than the culprit whose removal takes the policy's actions furthest from the
    correction: the skill that demonstrates the safe strategy (None: removing any of them helps or changes
    nothing)."""
    others = candidates.clone()
    others[culprit] = False
    loss = (without - error).masked_fill(~others, float("-inf"))
    best = int(loss.argmax())
    return best if bool(others[best]) and float(loss[best]) > 0 else None


def knowledge_gap(relevance: Tensor, culprit: int, active: Tensor, gap_alpha: float) -> bool:
    """Gap when every active alternative to the culprit kept a normalised relevance below gap_alpha.

    relevance: [T, S] normalised relevance at the intervention steps."""
    alternatives = active.clone()
    alternatives[culprit] = False
    if not bool(alternatives.any()):
        return True
    return bool(relevance[:, alternatives].mean(0).max() < gap_alpha)


def demonstrated_skill(relevance: Tensor, culprit: int, active: Tensor) -> int | None:
    """The skill an unnamed corrective demonstration shows: the most relevant active alternative to the culprit.

    relevance: [T, S] normalised relevance over the demonstration's steps."""
    alternatives = active.clone()
    alternatives[culprit] = False
    if not bool(alternatives.any()):
        return None
    mean = relevance.mean(0).masked_fill(~alternatives, float("-inf"))
    return int(mean.argmax())
