"""CODA-Prompt component pool with task-incremental growth, organised into skills that each work alone.

Faithful to the official CODA-Prompt algorithm (Smith et al., CVPR 2023) inside a skill: per prompted layer,
components P [M, Lp, D], keys K [M, Dq] and attention vectors A [M, Dq]; alpha_m = cos(q * A_m, K_m) without
softmax; a new task's rows are re-initialised by Gram-Schmidt against all earlier rows.

Skills (the components one task owns) are the knowledge units the KVM weights, and each one works alone: skill i's
prompt is P_i = sum_{m in i} alpha_m P_m, and it is trained under that prompt only, not as a residual on the skills
before it. The pool fuses them as the paper's eq. 3 writes it, P = sum_i w_i P_i / (sum_i w_i + eps): a skill
whose weight falls hands its share to the others. The CL core's relevance alpha_i (the w of the KVM-off policy)
says how close the query is to the queries skill i was trained on (`skill_relevance`).

Differences that fix pitfalls of the official code:
* each task's slice is its own set of `nn.Parameter`s, so earlier tasks are frozen by `requires_grad=False`
  and never receive a gradient, weight decay or momentum: they stay bit-identical;
* the task counter, the skill table (names, descriptions) and each skill's query prototypes are persistent
  buffers in the state dict;
* new rows are made orthogonal to the span of all earlier rows (earlier rows are first orthonormalised,
  since trained rows are no longer mutually orthogonal).
"""

import json
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

SKILL_TABLE_BYTES_PER_TASK = 1024
# Distinct training queries (task strings) a skill keeps as prototypes of what it was trained on; more fold into
# the nearest. The full sequence's pretraining skill learns 10 instructions.
PROTOTYPES_PER_SKILL = 16
# Two queries closer than this (cosine) are one prototype: the same task string, up to float noise.
SAME_QUERY = 1.0 - 1e-4
# Relevance alpha_i = exp((s_i - s_max) / RELEVANCE_TEMPERATURE), s_i the query's best cosine with skill i's
# prototypes, s_max the closest skill's. Skills are trained alone, and a prompt mixed from two of them is no skill:
# on the default pool, drawer's prior skill forced alone solves 5 of 5 prior episodes, mixed 1 : 0.1 with the safe
# skill 0 of 5, 1 : 0.01 4 of 5, 1 : 0.001 5 of 5 (docs/measurements.md). Measured with all-MiniLM-L6-v2 on the
# catalogue's instructions: a scenario's safe-skill instruction has cosine 0.80-0.96 with its variant instruction,
# instructions of different scenarios at most 0.60. At 0.01 the skill trained on the very instruction has alpha 1,
# the same scenario's safe skill 2e-9-0.012 (a candidate that takes over when the prior skill is suppressed),
# other scenarios' skills < 1e-17 (tests/policy/test_catalogue_relevance.py).
RELEVANCE_TEMPERATURE = 0.01
# eq. 3's eps: negligible against the weights, which are scaled so that the best valid candidate's is v >= tau_v
# (`kvm.fusion.decision_weights`).
FUSION_EPS = 1e-12


@dataclass(frozen=True)
class Skill:
    """`corrects`: set on a skill the KVM created for a knowledge gap, the index of the skill it corrects. Such a
    skill is a correction for contexts outside the safe experience, not a replacement of what holds inside it:
    the KVM keeps it out of force where its gate is closed (see `kvm.fusion.correction_validity`)."""

    index: int
    name: str
    description: str
    corrects: int | None = None

    @property
    def gated(self) -> bool:
        return self.corrects is not None


class _TaskSlice(nn.Module):
    """The components one task owns, for every prompted layer at once."""

    def __init__(self, n_layers: int, n_components: int, prompt_length: int, dim_model: int, query_dim: int):
        super().__init__()
        self.prompts = nn.Parameter(torch.zeros(n_layers, n_components, prompt_length, dim_model))
        self.keys = nn.Parameter(torch.zeros(n_layers, n_components, query_dim))
        self.attn = nn.Parameter(torch.zeros(n_layers, n_components, query_dim))


def _project_out(v: Tensor, basis: list[Tensor]) -> Tensor:
    """Classical Gram-Schmidt step against orthonormal `basis`, done twice ("twice is enough")."""
    for _ in range(2):
        if basis:
            b = torch.stack(basis)
            v = v - (b @ v) @ b
    return v


def _orthonormal_extension(old: Tensor, n_new: int) -> Tensor:
    """`n_new` random unit rows orthogonal to span(old rows) and to each other.

    Trained old rows are no longer mutually orthogonal, so they are orthonormalised first; everything runs in
    float64 so that the float32 result is orthogonal to ~1e-7.
    """
    basis: list[Tensor] = []
    for row in old.detach().to("cpu", torch.float64):
        v = _project_out(row, basis)
        if v.norm() > 1e-10 * max(1.0, row.norm().item()):
            basis.append(v / v.norm())
    new_rows: list[Tensor] = []
    while len(new_rows) < n_new:
        v = _project_out(torch.randn(old.shape[-1], dtype=torch.float64), basis)
        if v.norm() < 1e-6:  # the random draw fell (almost) inside the span: draw again, as CODA does
            continue
        basis.append(v / v.norm())
        new_rows.append(basis[-1])
    return torch.stack(new_rows)


def _cos_alphas(query: Tensor, attn: Tensor, keys: Tensor) -> Tensor:
    """alpha [n_layers, B, M] = cos(q * A_m, K_m) for attention vectors and keys [n_layers, M, Dq]."""
    attended = F.normalize(torch.einsum("bd,lmd->lbmd", query, attn), dim=-1)
    return torch.einsum("lbmd,lmd->lbm", attended, F.normalize(keys, dim=-1))


class CodaPromptPool(nn.Module):
    """Task-incremental CODA-Prompt pool for the first `n_layers` transformer layers."""

    def __init__(
        self,
        n_layers: int,
        pool_size: int,
        n_tasks: int,
        prompt_length: int,
        dim_model: int,
        query_dim: int,
    ) -> None:
        super().__init__()
        if pool_size % n_tasks:
            raise ValueError(f"pool_size ({pool_size}) must be divisible by n_tasks ({n_tasks})")
        self.n_layers = n_layers
        self.n_tasks = n_tasks
        self.per_task = pool_size // n_tasks
        self.prompt_length = prompt_length
        self.dim_model = dim_model
        self.query_dim = query_dim
        self.tasks = nn.ModuleList(
            _TaskSlice(n_layers, self.per_task, prompt_length, dim_model, query_dim) for _ in range(n_tasks)
        )
        self.register_buffer("task_count", torch.zeros(1, dtype=torch.int64))
        self.register_buffer("skill_table", torch.zeros(SKILL_TABLE_BYTES_PER_TASK * n_tasks, dtype=torch.uint8))
        self.register_buffer("prototypes", torch.zeros(n_tasks, PROTOTYPES_PER_SKILL, query_dim))
        self.register_buffer("prototype_counts", torch.zeros(n_tasks, PROTOTYPES_PER_SKILL, dtype=torch.int64))
        self.register_load_state_dict_post_hook(CodaPromptPool._after_load)
        self._corrections: tuple[int, torch.device, tuple[Tensor, Tensor] | None] | None = None
        self.refresh_trainable()

    # ----------------------------------------------------------------- bookkeeping
    @property
    def n_skills(self) -> int:
        """Number of tasks begun so far (the last one is the one being learned)."""
        return int(self.task_count.item())

    @property
    def skills(self) -> list[Skill]:
        raw = bytes(self.skill_table.cpu().numpy()).rstrip(b"\x00")
        entries = json.loads(raw.decode("utf-8")) if raw else []
        return [Skill(int(e["index"]), str(e["name"]), str(e["description"]), e.get("corrects")) for e in entries]

    def corrections(self) -> tuple[Tensor, Tensor] | None:
        """([n_skills] bool: the skill corrects another, [n_skills] index of the skill it corrects (itself
        otherwise)), or None when no skill is a correction. Cached: it is read on every control step."""
        device = self.task_count.device
        if self._corrections is None or self._corrections[:2] != (self.n_skills, device):
            skills = self.skills
            value = None
            if any(s.gated for s in skills):
                mask = torch.tensor([s.gated for s in skills], dtype=torch.bool, device=device)
                target = torch.tensor([s.index if s.corrects is None else s.corrects for s in skills], device=device)
                value = (mask, target)
            self._corrections = (self.n_skills, device, value)
        return self._corrections[2]

    def _write_skill_table(self, skills: list[Skill]) -> None:
        raw = json.dumps([asdict(s) for s in skills], ensure_ascii=False).encode("utf-8")
        if len(raw) > self.skill_table.numel():
            raise ValueError(
                f"skill table needs {len(raw)} bytes but holds {self.skill_table.numel()}: "
                "shorten the skill names/descriptions"
            )
        table = torch.zeros_like(self.skill_table)
        table[: len(raw)] = torch.frombuffer(bytearray(raw), dtype=torch.uint8)
        self.skill_table.copy_(table)
        self._corrections = None

    @staticmethod
    def _after_load(module: "CodaPromptPool", _incompatible_keys: object) -> None:
        module.refresh_trainable()  # the loaded task counter decides which slice learns
        module._corrections = None

    def refresh_trainable(self) -> None:
        """Only the current task's slice learns; earlier slices are frozen, later ones are zero and frozen."""
        current = self.n_skills - 1
        for t, task in enumerate(self.tasks):
            trainable = t == current
            for p in task.parameters():
                p.requires_grad_(trainable)
                if not trainable:
                    p.grad = None

    @torch.no_grad()
    def begin_skill(self, name: str, description: str = "", corrects: int | None = None) -> int:
        """Start the next task: Gram-Schmidt init of its rows against all earlier rows; returns its index."""
        t = self.n_skills
        if t >= self.n_tasks:
            raise ValueError(f"the prompt pool is full: all n_tasks={self.n_tasks} skills are in use")
        if not name.strip():
            raise ValueError(f"skill name must be non-empty, got {name!r}")
        if any(s.name == name for s in self.skills):
            raise ValueError(f"a skill named {name!r} already exists")
        if corrects is not None and not 0 <= corrects < t:
            raise ValueError(f"corrects must name an earlier skill in [0, {t}), got {corrects}")
        new = self.tasks[t]
        for attr in ("prompts", "keys", "attn"):
            for layer in range(self.n_layers):
                target = getattr(new, attr)
                old_slices = [getattr(self.tasks[i], attr)[layer] for i in range(t)]
                old = torch.cat([target[layer][:0], *old_slices]).flatten(1)
                rows = _orthonormal_extension(old, self.per_task)
                target[layer].copy_(rows.reshape(target[layer].shape).to(target.dtype))
        self._write_skill_table([*self.skills, Skill(t, name, description, corrects)])
        self.task_count.fill_(t + 1)
        self.refresh_trainable()
        return t

    # ----------------------------------------------------------------- CODA computation
    def _visible(self, attr: str, n_skills: int | None = None) -> Tensor:
        """[n_layers, n_skills * per_task, ...] rows of the tasks begun so far (or of the first `n_skills`)."""
        if self.n_skills == 0:
            raise RuntimeError("no skill has been begun in the prompt pool")
        n = self.n_skills if n_skills is None else n_skills
        return torch.cat([getattr(self.tasks[i], attr) for i in range(n)], dim=1)

    def component_alphas(self, query: Tensor) -> Tensor:
        """alpha [n_layers, B, M_visible] = cos(q * A_m, K_m) (no softmax, can be negative)."""
        return _cos_alphas(query, self._visible("attn"), self._visible("keys"))

    def own_prompt(self, query: Tensor, skill: int) -> Tensor:
        """P_i [n_layers, B, Lp, D] of skill `skill` alone: eq. 3 with one-hot weights, computed from that skill's
        rows only. Every other row's weight is 0, and reading them anyway made a training step grow with the pool
        (docs/measurements.md, the training step's cost)."""
        task = self.tasks[skill]
        return torch.einsum("lbm,lmkd->lbkd", _cos_alphas(query, task.attn, task.keys), task.prompts)

    @torch.no_grad()
    def propose(self, query: Tensor) -> tuple[Tensor, Tensor]:
        """The CL core's proposal (Algorithm 1 line 5) for queries [B, Dq]: (relevance alpha [B, S], anchors [B, S,
        Dq]). Skill i's anchor is its prototype nearest to the query, the task it learned that this one is closest
        to: the skill runs as it was trained there (`anchored_alphas`). alpha_i = exp((s_i - s_max) / T), s_i that
        prototype's cosine with the query, s_max the closest skill's: relative to the closest skill, so that a query
        far from every skill still has one at alpha 1 (no underflow). A skill that has seen no query yet is anchored
        at the query itself with cosine 1: nothing says it does not apply."""
        n = self.n_skills
        counts = self.prototype_counts[:n]  # [S, K]
        protos = self.prototypes[:n].to(query)  # [S, K, Dq]
        cos = torch.einsum("bd,skd->bsk", F.normalize(query, dim=-1), F.normalize(protos, dim=-1))
        best, slot = cos.masked_fill(counts.unsqueeze(0) == 0, -2.0).max(-1)  # [B, S]
        seen = (counts > 0).any(-1).unsqueeze(0)
        best = torch.where(seen, best, torch.ones_like(best))
        anchors = protos[torch.arange(n, device=query.device).unsqueeze(0), slot]  # [B, S, Dq]
        anchors = torch.where(seen.unsqueeze(-1), anchors, query.unsqueeze(1).expand_as(anchors))
        return torch.exp((best - best.amax(-1, keepdim=True)) / RELEVANCE_TEMPERATURE), anchors

    def training_queries(self) -> tuple[Tensor, Tensor]:
        """(owner [Q], queries [Q, Dq]): every skill's query prototypes, the tasks it was trained on."""
        used = self.prototype_counts[: self.n_skills] > 0
        return torch.nonzero(used)[:, 0], self.prototypes[: self.n_skills][used]

    def skill_relevance(self, query: Tensor) -> Tensor:
        """alpha_i [B, n_skills] in (0, 1]: how close the query is to what skill i was trained on (see `propose`)."""
        return self.propose(query)[0]

    def anchored_alphas(self, anchors: Tensor) -> Tensor:
        """alpha [n_layers, B, M_visible]: each skill's components read with that skill's own query, anchors [B, S,
        Dq] (one query per row and skill); with every anchor the same query, `component_alphas` of it."""
        n = anchors.shape[1]
        keys = F.normalize(self._visible("keys", n), dim=-1).unflatten(1, (n, self.per_task))  # [L, S, m, Dq]
        attn = self._visible("attn", n).unflatten(1, (n, self.per_task))
        attended = F.normalize(torch.einsum("bsd,lsmd->lbsmd", anchors, attn), dim=-1)
        return torch.einsum("lbsmd,lsmd->lbsm", attended, keys).flatten(2)

    def skill_prompts(self, query: Tensor) -> Tensor:
        """P_i [n_layers, B, n_skills, Lp, D] = sum_{m in skill i} alpha_m P_m: each skill's own prompt."""
        return self.contributions_from_alphas(self.component_alphas(query))

    def contributions_from_alphas(self, alphas: Tensor) -> Tensor:
        """`skill_prompts` from already computed component alphas [n_layers, B, M_visible]. The skills are those the
        alphas cover, so alphas kept from before a new skill began still give their own step's prompts."""
        n = alphas.shape[-1] // self.per_task
        prompts = self._visible("prompts", n).unflatten(1, (n, self.per_task))
        return torch.einsum("lbsm,lsmkd->lbskd", alphas.unflatten(-1, (n, self.per_task)), prompts)

    def forward(self, query: Tensor, skill_weights: Tensor) -> Tensor:
        """Fused prompt [n_layers, B, Lp, D] (eq. 3) for decision weights w [B, n_skills]."""
        return self.prompt_from_alphas(self.component_alphas(query), skill_weights)

    def prompt_from_alphas(self, alphas: Tensor, skill_weights: Tensor) -> Tensor:
        """Eq. 3, P = sum_i w_i P_i / (sum_i w_i + eps), from already computed component alphas [n_layers, B,
        M_visible] and decision weights w [B, n_skills] >= 0. One-hot weights give that skill's own prompt: how
        each skill is trained (`own_weights`) and how it is forced."""
        expected = (alphas.shape[1], self.n_skills)
        if tuple(skill_weights.shape) != expected:
            raise ValueError(f"skill_weights must have shape {expected}, got {tuple(skill_weights.shape)}")
        w = skill_weights.to(alphas)
        w = w / (w.sum(-1, keepdim=True) + FUSION_EPS)
        return torch.einsum(
            "lbm,lmkd->lbkd", alphas * w.repeat_interleave(self.per_task, dim=-1), self._visible("prompts")
        )

    def own_weights(self, skill: int, batch_size: int, device: torch.device | None = None) -> Tensor:
        """[B, n_skills] one-hot weights of skill `skill`: its prompt alone."""
        weights = torch.zeros(batch_size, self.n_skills, device=device or self.task_count.device)
        weights[:, skill] = 1.0
        return weights

    @torch.no_grad()
    def observe_queries(self, query: Tensor, skill: int | None = None) -> None:
        """Keep the training queries [B, Dq] of `skill` (default: the one being learned) as its prototypes: each
        distinct query its own running mean; past `PROTOTYPES_PER_SKILL`, a new one folds into the nearest."""
        t = self.n_skills - 1 if skill is None else skill
        protos, counts = self.prototypes[t], self.prototype_counts[t]
        distinct, seen = torch.unique(query.detach().to(protos), dim=0, return_counts=True)
        for q, n in zip(distinct, seen.tolist(), strict=True):
            used = counts > 0
            cos = F.cosine_similarity(protos, q.unsqueeze(0), dim=-1).masked_fill(~used, -2.0)
            slot = int(cos.argmax())
            if not bool(used.any()) or float(cos[slot]) < SAME_QUERY:
                free = torch.nonzero(~used).flatten()
                if len(free):
                    slot = int(free[0])
            protos[slot] = (protos[slot] * counts[slot] + q * n) / (counts[slot] + n)
            counts[slot] += n

    def ortho_penalty(self) -> Tensor:
        """Official CODA orthogonality regulariser: mean ||R R^T - I||^2 over the visible rows of K, A, P."""
        total = torch.zeros((), device=self.task_count.device)
        for attr in ("keys", "attn", "prompts"):
            rows = self._visible(attr).flatten(2)  # [L, M, F]
            gram = rows @ rows.transpose(1, 2)
            eye = torch.eye(gram.shape[-1], device=gram.device, dtype=gram.dtype)
            total = total + ((gram - eye) ** 2).mean()
        return total
