"""Knowledge-base metabolism (paper §3.2, App. A.1, eqs. 7-8): FCRNC and SRNC per skill, pruning.

An interaction is one attempt. For the skill the CL core proposed in that attempt (the one it relied on: the
largest share of the CODA prompt before any KVM re-weighting, see `policy.feedback.apply_feedback`), the attempt's
outcome and whether the KVM suppressed the skill (min_t v_t < tau_v) are counted in the slot of the attempt's
task; a failure counts as the skill's contribution only where the KVM had not suppressed it (a suppressed
skill's interaction is SRNC's to count). Skills that merely touched the prompt are not charged: a suite whose
challenges fail by design would otherwise retire every broadly relevant skill within one window. Only the N most
recent new tasks have slots (a sliding window; a new task evicts the oldest slot). FCRNC_i = failures /
proposals and SRNC_i = suppressions / proposals over the window.

A skill is pruned when its FCRNC or SRNC *remains* above the threshold over a sliding window: above it (with
the window full and at least `min_interactions` proposals in it) at each of the last N arrivals of a new task,
and still now. One window above the threshold is not enough: a skill shared by many tasks (a pretraining skill)
meets a run of new contexts that its knowledge does not fit, and suppression, not retirement, is the answer
while the skill still serves its routine contexts. Pruning deactivates the skill (weight 0 in the fused
prompt, no longer a candidate); it is never deleted from the checkpoint, and restorable.
"""

import hashlib

import torch
from torch import Tensor, nn

METABOLISM_WINDOW = 5  # App. E: FCRNC and SRNC over the 5 most recent new tasks
PRUNE_THRESHOLD = 0.8  # App. E: pruned when FCRNC or SRNC remains above 0.8
PRUNE_MIN_INTERACTIONS = 5  # eqs. 7-8 need proposals: fewer in the window judge nothing


def task_key(task: str) -> int:
    """A stable non-negative 63-bit id of a task string."""
    return int.from_bytes(hashlib.sha1(task.encode("utf-8")).digest()[:8], "big") >> 1


def fcrnc(failed: Tensor, proposed: Tensor) -> Tensor:
    """Eq. 7 from counts [S, N] (or [S]); 0 for skills never proposed."""
    p = proposed.sum(-1) if proposed.ndim > 1 else proposed
    f = failed.sum(-1) if failed.ndim > 1 else failed
    return torch.where(
        p > 0, f.to(torch.float32) / p.clamp_min(1).to(torch.float32), torch.zeros_like(p, dtype=torch.float32)
    )


def srnc(suppressed: Tensor, proposed: Tensor) -> Tensor:
    """Eq. 8 from counts [S, N] (or [S]); 0 for skills never proposed."""
    return fcrnc(suppressed, proposed)


class SkillMetabolism(nn.Module):
    def __init__(self, max_skills: int, window: int, threshold: float, min_interactions: int) -> None:
        super().__init__()
        self.window = window
        self.threshold = threshold
        self.min_interactions = min_interactions
        self.register_buffer("task_keys", torch.full((window,), -1, dtype=torch.int64))
        self.register_buffer("tasks_seen", torch.zeros(1, dtype=torch.int64))
        self.register_buffer("proposed", torch.zeros(max_skills, window, dtype=torch.int64))
        self.register_buffer("failed", torch.zeros(max_skills, window, dtype=torch.int64))
        self.register_buffer("suppressed", torch.zeros(max_skills, window, dtype=torch.int64))
        self.register_buffer("pruned", torch.zeros(max_skills, dtype=torch.int64))
        # consecutive new-task arrivals at which the skill was above the threshold
        self.register_buffer("streak", torch.zeros(max_skills, dtype=torch.int64))
        self._active: dict[int, tuple[Tensor, bool]] = {}  # runtime cache, cleared whenever `pruned` changes
        self.register_load_state_dict_post_hook(lambda module, _keys: module._active.clear())

    @torch.no_grad()
    def _slot(self, task: str) -> int:
        key = task_key(task)
        hit = torch.nonzero(self.task_keys == key).flatten()
        if len(hit):
            return int(hit[0])
        above = self._above()
        self.streak.copy_(torch.where(above, self.streak + 1, torch.zeros_like(self.streak)))
        slot = int(self.tasks_seen.item()) % self.window
        self.task_keys[slot] = key
        self.proposed[:, slot] = 0
        self.failed[:, slot] = 0
        self.suppressed[:, slot] = 0
        self.tasks_seen += 1
        return slot

    @torch.no_grad()
    def record(self, task: str, proposed: Tensor, failed: bool, suppressed: Tensor) -> None:
        """One interaction: proposed [S] bool, suppressed [S] bool (S <= max_skills)."""
        slot = self._slot(task)
        s = proposed.shape[0]
        p = proposed.to(self.proposed.device, torch.int64)
        q = suppressed.to(self.proposed.device, torch.int64)
        self.proposed[:s, slot] += p
        self.failed[:s, slot] += p * (1 - q) * int(failed)
        self.suppressed[:s, slot] += p * q

    def fcrnc(self) -> Tensor:
        return fcrnc(self.failed, self.proposed)

    def srnc(self) -> Tensor:
        return srnc(self.suppressed, self.proposed)

    @property
    def window_full(self) -> bool:
        return int(self.tasks_seen.item()) >= self.window

    def _above(self) -> Tensor:
        """[max_skills] bool: FCRNC or SRNC above the threshold over a full window with enough proposals."""
        if not self.window_full:
            return torch.zeros_like(self.pruned, dtype=torch.bool)
        enough = self.proposed.sum(-1) >= self.min_interactions
        return enough & ((self.fcrnc() > self.threshold) | (self.srnc() > self.threshold))

    @torch.no_grad()
    def check_prune(self, n_skills: int) -> list[int]:
        """Prune (and return) skills whose FCRNC or SRNC remains above the threshold over the sliding window."""
        remains = self._above() & (self.streak >= self.window) & (self.pruned == 0)
        newly = torch.nonzero(remains[:n_skills]).flatten().tolist()
        for i in newly:
            self.prune(i)
        return newly

    @torch.no_grad()
    def prune(self, skill: int) -> None:
        self.pruned[skill] = 1
        self._active.clear()

    @torch.no_grad()
    def restore(self, skill: int) -> None:
        self.pruned[skill] = 0
        self.streak[skill] = 0
        self.proposed[skill] = 0
        self.failed[skill] = 0
        self.suppressed[skill] = 0
        self._active.clear()

    def active(self, n_skills: int) -> Tensor:
        """[n_skills] bool: not pruned (cached: read at every control step)."""
        return self._active_entry(n_skills)[0]

    def all_active(self, n_skills: int) -> bool:
        return self._active_entry(n_skills)[1]

    def _active_entry(self, n_skills: int) -> tuple[Tensor, bool]:
        entry = self._active.get(n_skills)
        if entry is None or entry[0].device != self.pruned.device:
            with torch.inference_mode(False):
                active = self.pruned[:n_skills] == 0
            entry = (active, bool(active.all()))
            self._active[n_skills] = entry
        return entry
