"""CODA-Prompt component pool with task-incremental growth, organised into skills.

Faithful to the official CODA-Prompt algorithm (Smith et al., CVPR 2023): per prompted layer, components
P [M, Lp, D], keys K [M, Dq] and attention vectors A [M, Dq]; alpha_m = cos(q * A_m, K_m) without softmax;
the layer prompt is sum_m alpha_m P_m over the components of the tasks begun so far; a new task's rows are
re-initialised by Gram-Schmidt against all earlier rows.

Differences that fix pitfalls of the official code:
* each task's slice is its own set of `nn.Parameter`s, so earlier tasks are frozen by `requires_grad=False`
  and never receive a gradient, weight decay or momentum: they stay bit-identical;
* the task counter and the skill table (names, descriptions) are persistent buffers in the state dict;
* optional query separation (not in CODA-Prompt): each skill keeps the mean of its training queries (one
  query_dim vector, no data), and a new skill's components can be trained to give those earlier queries
  zero relevance, so that learning a task does not change the prompt earlier tasks receive;
* new rows are made orthogonal to the span of all earlier rows (earlier rows are first orthonormalised,
  since trained rows are no longer mutually orthogonal).

The components owned by one task form a *skill*. Per-skill prompt contributions c_i and their sizes (the
skill's relevance) are exposed so the KVM can weight skills (eq. 3): with every weight 1 the fused prompt is
the CODA prompt.
"""

import json
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

SKILL_TABLE_BYTES_PER_TASK = 1024


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
        self.register_buffer("skill_queries", torch.zeros(n_tasks, query_dim))
        self.register_buffer("skill_query_counts", torch.zeros(n_tasks, dtype=torch.int64))
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

    @torch.no_grad()
    def copy_skill(self, source: int, target: int) -> None:
        """Start the skill being learned (`target`) as a copy of skill `source`'s components, keys and attention."""
        if target != self.n_skills - 1 or not 0 <= source < target:
            raise ValueError(f"can only copy an earlier skill into the one being learned, got {source} -> {target}")
        for attr in ("prompts", "keys", "attn"):
            getattr(self.tasks[target], attr).copy_(getattr(self.tasks[source], attr))

    # ----------------------------------------------------------------- CODA computation
    def _visible(self, attr: str, n_skills: int | None = None) -> Tensor:
        """[n_layers, n_skills * per_task, ...] rows of the tasks begun so far (or of the first `n_skills`)."""
        if self.n_skills == 0:
            raise RuntimeError("no skill has been begun in the prompt pool")
        n = self.n_skills if n_skills is None else n_skills
        return torch.cat([getattr(self.tasks[i], attr) for i in range(n)], dim=1)

    def component_alphas(self, query: Tensor) -> Tensor:
        """alpha [n_layers, B, M_visible] = cos(q * A_m, K_m) (no softmax, can be negative)."""
        keys = F.normalize(self._visible("keys"), dim=-1)  # [L, M, Dq]
        attended = F.normalize(torch.einsum("bd,lmd->lbmd", query, self._visible("attn")), dim=-1)
        return torch.einsum("lbmd,lmd->lbm", attended, keys)

    def skill_relevance(self, query: Tensor) -> Tensor:
        """alpha_i [B, n_skills] >= 0: how strongly skill i shapes the prompt, ||c_i|| over all prompted layers.

        The component alphas alone do not say this: they are cosines, and a skill learned later can act through
        small alphas on large prompts (a frozen query keeps its cosines with new keys small). The size of the
        skill's contribution is what the prompt actually receives from it."""
        return self.relevance_from_alphas(self.component_alphas(query))

    @torch.no_grad()
    def relevance_from_alphas(self, alphas: Tensor) -> Tensor:
        """`skill_relevance` from already computed component alphas [n_layers, B, M_visible]; a measurement, never
        differentiated (it may be computed lazily, after the step's inference mode has ended)."""
        return self.contributions_from_alphas(alphas).square().sum((0, 3, 4)).sqrt()

    def skill_prompts(self, query: Tensor) -> Tensor:
        """c_i [n_layers, B, n_skills, Lp, D] = sum_{m in skill i} alpha_m P_m; summed: the CODA prompt."""
        return self.contributions_from_alphas(self.component_alphas(query))

    def contributions_from_alphas(self, alphas: Tensor) -> Tensor:
        """`skill_prompts` from already computed component alphas [n_layers, B, M_visible]. The skills are those the
        alphas cover, so alphas kept from before a new skill began still give their own step's contributions."""
        n = alphas.shape[-1] // self.per_task
        prompts = self._visible("prompts", n).unflatten(1, (n, self.per_task))
        return torch.einsum("lbsm,lsmkd->lbskd", alphas.unflatten(-1, (n, self.per_task)), prompts)

    def forward(self, query: Tensor, skill_weights: Tensor | None = None) -> Tensor:
        """Fused prompt [n_layers, B, Lp, D] = sum_i v_i c_i; `skill_weights` v [B, n_skills], default ones.

        v scales each component's alpha, so v = 1 multiplies by exactly 1.0 and reproduces CODA bit for bit.
        """
        return self.prompt_from_alphas(self.component_alphas(query), skill_weights)

    def prompt_from_alphas(self, alphas: Tensor, skill_weights: Tensor | None = None) -> Tensor:
        """`forward` from already computed component alphas [n_layers, B, M_visible] (computed once per step
        and shared with the KVM's relevance scores)."""
        if skill_weights is not None:
            expected = (alphas.shape[1], self.n_skills)
            if tuple(skill_weights.shape) != expected:
                raise ValueError(f"skill_weights must have shape {expected}, got {tuple(skill_weights.shape)}")
            alphas = alphas * skill_weights.to(alphas).repeat_interleave(self.per_task, dim=-1)
        return torch.einsum("lbm,lmkd->lbkd", alphas, self._visible("prompts"))

    @torch.no_grad()
    def observe_queries(self, query: Tensor) -> None:
        """Fold training queries [B, Dq] into the current skill's running mean query."""
        t = self.n_skills - 1
        seen = self.skill_query_counts[t].to(query.dtype)
        self.skill_queries[t] = (self.skill_queries[t] * seen + query.sum(0)) / (seen + query.shape[0])
        self.skill_query_counts[t] += query.shape[0]

    def separation_penalty(self) -> Tensor:
        """Mean squared alpha of the current skill's components on the earlier skills' mean queries."""
        t = self.n_skills - 1
        earlier = self.skill_query_counts[:t] > 0
        if not bool(earlier.any()):
            return torch.zeros((), device=self.task_count.device)
        current = self.tasks[t]
        keys = F.normalize(current.keys, dim=-1)
        attended = F.normalize(torch.einsum("bd,lmd->lbmd", self.skill_queries[:t][earlier], current.attn), dim=-1)
        return torch.einsum("lbmd,lmd->lbm", attended, keys).pow(2).mean()

    def ortho_penalty(self) -> Tensor:
        """Official CODA orthogonality regulariser: mean ||R R^T - I||^2 over the visible rows of K, A, P."""
        total = torch.zeros((), device=self.task_count.device)
        for attr in ("keys", "attn", "prompts"):
            rows = self._visible(attr).flatten(2)  # [L, M, F]
            gram = rows @ rows.transpose(1, 2)
            eye = torch.eye(gram.shape[-1], device=gram.device, dtype=gram.dtype)
            total = total + ((gram - eye) ** 2).mean()
        return total
