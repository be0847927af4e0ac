"""The KVM's memory as fixed-capacity persistent buffers (they live in `model.safetensors`).

* `SampleBuffer`: raw contexts c_raw with their skill, flags and a tag (hypothesis id). Three insertion
  policies: `ring` (FIFO: the gate's window of the last N successful interactions, online safe samples),
  `reservoir` (a uniform sample of everything offered: offline safe/fail frames), `protected` (FIFO that
  never evicts PERMANENT rows: confirmed h_fail negatives).
* `EpisodeLabels`: episode_index -> (dataset skill, outcome, usable) from the recorder's labels, so that
  `forward()` knows which skill produced a frame and how its episode ended.

Raw contexts, not features, are stored: features are recomputed with the current encoder, so they never go
stale while E_c learns.
"""

import json
from collections.abc import Sequence

import torch
from torch import Tensor, nn

# Flags of a stored sample.
ROUTINE = 1  # a safe sample from routine experience (no intervention): trains sigma_c^2, feeds the gate window
PERMANENT = 2  # a confirmed h_fail negative: never evicted
DEMO = 8  # from a corrective demonstration

MODES = ("ring", "reservoir", "protected")


class SampleBuffer(nn.Module):
    def __init__(self, capacity: int, dim: int, mode: str) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"buffer mode must be one of {MODES}, got {mode!r}")
        self.capacity = capacity
        self.dim = dim
        self.mode = mode
        self.register_buffer("data", torch.zeros(capacity, dim))
        self.register_buffer("skill", torch.full((capacity,), -1, dtype=torch.int64))
        self.register_buffer("flags", torch.zeros(capacity, dtype=torch.int64))
        self.register_buffer("tag", torch.full((capacity,), -1, dtype=torch.int64))
        self.register_buffer("stamp", torch.full((capacity,), -1, dtype=torch.int64))  # insertion order, -1 empty
        self.register_buffer("count", torch.zeros(1, dtype=torch.int64))  # rows ever offered

    def __len__(self) -> int:
        return int((self.stamp >= 0).sum())

    @property
    def n_offered(self) -> int:
        return int(self.count.item())

    def filled(self) -> Tensor:
        return torch.nonzero(self.stamp >= 0).flatten()

    def _slots(self, n_new: int, protected_mask: Tensor | None) -> list[int]:
        """Slot for each offered row (-1: dropped). Later rows win a slot chosen twice."""
        start = self.n_offered
        slots: list[int] = []
        if self.mode == "ring":
            return [(start + i) % self.capacity for i in range(n_new)]
        if self.mode == "reservoir":
            draws = torch.rand(n_new).tolist()
            for i in range(n_new):
                n = start + i
                if n < self.capacity:
                    slots.append(n)
                else:
                    j = int(draws[i] * (n + 1))
                    slots.append(j if j < self.capacity else -1)
            return slots
        # protected FIFO: empty slots first, then the oldest non-permanent row
        stamp = self.stamp.clone()
        permanent = (self.flags & PERMANENT) > 0
        for i in range(n_new):
            empty = torch.nonzero(stamp < 0).flatten()
            if len(empty):
                slot = int(empty[0])
            else:
                evictable = torch.nonzero(~permanent).flatten()
                if not len(evictable):
                    slots.append(-1)
                    continue
                slot = int(evictable[torch.argmin(stamp[evictable])])
            stamp[slot] = start + i
            permanent[slot] = bool(protected_mask[i]) if protected_mask is not None else False
            slots.append(slot)
        return slots

    @torch.no_grad()
    def add(self, rows: Tensor, skill: Tensor | int = -1, flags: Tensor | int = 0, tag: Tensor | int = -1) -> int:
        """Offer rows [n, dim]; returns how many were stored."""
        n = rows.shape[0]
        if n == 0:
            return 0
        if rows.ndim != 2 or rows.shape[1] != self.dim:
            raise ValueError(f"buffer rows must have shape [n, {self.dim}], got {list(rows.shape)}")
        dev = self.data.device

        def column(value: Tensor | int) -> Tensor:
            if isinstance(value, Tensor):
                return value.to(dev, torch.int64).reshape(n)
            return torch.full((n,), int(value), dtype=torch.int64, device=dev)

        skill_col, flags_col, tag_col = column(skill), column(flags), column(tag)
        slots = self._slots(n, (flags_col & PERMANENT) > 0)
        last: dict[int, int] = {}
        for i, slot in enumerate(slots):
            if slot >= 0:
                last[slot] = i
        if last:
            slot_idx = torch.tensor(list(last), dtype=torch.int64, device=dev)
            row_idx = torch.tensor(list(last.values()), dtype=torch.int64, device=dev)
            self.data[slot_idx] = rows.detach().to(self.data)[row_idx]
            self.skill[slot_idx] = skill_col[row_idx]
            self.flags[slot_idx] = flags_col[row_idx]
            self.tag[slot_idx] = tag_col[row_idx]
            self.stamp[slot_idx] = row_idx + self.n_offered
        self.count += n
        return len(last)

    @torch.no_grad()
    def set_flags(self, mask: Tensor, flags: int) -> None:
        self.flags[mask] |= flags

    @torch.no_grad()
    def clear_flags(self, mask: Tensor, flags: int) -> None:
        self.flags[mask] &= ~flags

    def sample(self, n: int, where: Tensor | None = None) -> Tensor:
        """Indices of up to `n` stored rows drawn uniformly with replacement (restricted to `where`)."""
        valid = self.stamp >= 0
        if where is not None:
            valid = valid & where
        idx = torch.nonzero(valid).flatten()
        if not len(idx) or n <= 0:
            return idx[:0]
        return idx[torch.randint(len(idx), (n,), device=idx.device)]

    def recent(self, n: int) -> Tensor:
        """Indices of the `n` most recently stored rows."""
        idx = self.filled()
        order = torch.argsort(self.stamp[idx], descending=True)
        return idx[order[:n]]


OUTCOME_IDS = {"success": 0, "failure": 1, "catastrophe": 2}
VOCAB_BYTES = 8192


class EpisodeLabels(nn.Module):
    """episode_index -> (dataset skill id, outcome id, usable) for offline learning inside `forward()`."""

    def __init__(self, capacity: int) -> None:
        super().__init__()
        self.register_buffer("table", torch.full((capacity, 3), -1, dtype=torch.int64))
        self.register_buffer("vocab_bytes", torch.zeros(VOCAB_BYTES, dtype=torch.uint8))
        self._mapping_key: tuple[str, ...] | None = None
        self._mapping: Tensor | None = None

    @property
    def skill_vocab(self) -> list[str]:
        raw = bytes(self.vocab_bytes.cpu().numpy()).rstrip(b"\x00")
        return json.loads(raw.decode("utf-8")) if raw else []

    @property
    def loaded(self) -> bool:
        return bool((self.table[:, 0] >= 0).any())

    @torch.no_grad()
    def load(self, episodes: Sequence[dict]) -> int:
        """Fill from `load_labels(root)["episodes"]`; returns the number of episodes stored. Frames of a
        benchmark-shifted variant are never learned offline (the leakage rule): they are stored as not usable."""
        vocab = sorted({str(e["skill"]) for e in episodes})
        raw = json.dumps(vocab).encode("utf-8")
        if len(raw) > VOCAB_BYTES:
            raise ValueError(f"dataset skill names need {len(raw)} bytes, the label table holds {VOCAB_BYTES}")
        table = torch.full_like(self.table, -1)
        stored = 0
        for e in episodes:
            index = int(e["episode_index"])
            if not 0 <= index < table.shape[0]:
                continue
            outcome = str(e.get("outcome", "success"))
            if outcome not in OUTCOME_IDS:
                raise ValueError(f"episode {index}: unknown outcome {outcome!r}; expected one of {list(OUTCOME_IDS)}")
            usable = str(e.get("variant", "prior")) != "shifted"
            table[index] = torch.tensor([vocab.index(str(e["skill"])), OUTCOME_IDS[outcome], int(usable)])
            stored += 1
        self.table.copy_(table)
        vocab_bytes = torch.zeros_like(self.vocab_bytes)
        vocab_bytes[: len(raw)] = torch.frombuffer(bytearray(raw), dtype=torch.uint8)
        self.vocab_bytes.copy_(vocab_bytes)
        self._mapping_key = None
        return stored

    def _skill_mapping(self, policy_skills: Sequence[str], current: int) -> Tensor:
        key = (*policy_skills, str(current))
        if self._mapping_key != key or self._mapping is None or self._mapping.device != self.table.device:
            names = list(policy_skills)
            vocab = self.skill_vocab
            mapping = [names.index(s) if s in names else current for s in vocab]
            self._mapping = torch.tensor(mapping or [current], dtype=torch.int64, device=self.table.device)
            self._mapping_key = key
        return self._mapping

    def lookup(
        self, episode_index: Tensor | None, batch_size: int, policy_skills: Sequence[str], current: int
    ) -> tuple[Tensor, Tensor, Tensor]:
        """(policy skill [B], outcome id [B], usable [B] bool). Frames without labels are safe demonstrations of
        the skill being trained; dataset skills the policy does not have also map to it."""
        dev = self.table.device
        skill = torch.full((batch_size,), current, dtype=torch.int64, device=dev)
        outcome = torch.zeros(batch_size, dtype=torch.int64, device=dev)
        usable = torch.ones(batch_size, dtype=torch.bool, device=dev)
        if episode_index is None:
            return skill, outcome, usable
        ep = torch.as_tensor(episode_index, device=dev).reshape(-1).to(torch.int64)
        if ep.shape[0] != batch_size:
            raise ValueError(f"'episode_index' has {ep.shape[0]} entries for a batch of {batch_size}")
        inside = (ep >= 0) & (ep < self.table.shape[0])
        rows = self.table[ep.clamp(0, self.table.shape[0] - 1)]
        known = inside & (rows[:, 0] >= 0)
        mapping = self._skill_mapping(policy_skills, current)
        skill = torch.where(known, mapping[rows[:, 0].clamp(0, len(mapping) - 1)], skill)
        outcome = torch.where(known, rows[:, 1], outcome)
        usable = torch.where(known, rows[:, 2] > 0, usable)
        return skill, outcome, usable
