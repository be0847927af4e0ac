"""`coda_kvm` policy: CODA-Prompt pool (queried by the frozen task-string embedding) prefix-tuning a small
VLA-style backbone that predicts action chunks (L1 on normalized actions, ACT-style).

The Knowledge Validity Module (`lerobot_kvm.kvm`, attribute `kvm`) supervises the skills at inference: every
model call of `select_action` / `predict_action_chunk` assesses the sensed context (E_c, smart gate, energy
model) and fuses the skill prompts with the resulting weights (eqs. 2-4); a suppression of the skill the task relies
on holds to the end of the attempt (`reset()`), and where every candidate skill is suppressed the policy abstains
safely (`policy.abstention`). It learns offline inside `forward()` during `lerobot-train` and
online through `kvm_feedback()`. With `config.kvm.enabled=False` the policy is the CODA-Prompt core: the same fusion
with every v = 1. Explicit skill weights [B, n_skills] passed to `forward`, `predict_action_chunk` or `select_action`
bypass the KVM (one-hot weights force that skill alone). `forward` trains the skill being learned under its own
prompt, so every skill works alone.
"""

from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE
from lerobot.utils.device_utils import resolve_safetensors_device
from safetensors.torch import load_file
from torch import Tensor

from ..datasets.labels import LABELS_FILE, load_labels
from ..kvm.fusion import candidates, decision_weights
from ..kvm.supervisor import KnowledgeValidityModule
from ..kvm.telemetry import KvmStepTelemetry, KvmTrace
from .abstention import hold_chunk, normalized_rest, release_mask
from .backbone import PromptedBackbone
from .coda_prompt import CodaPromptPool, Skill
from .configuration_coda_kvm import CodaKvmConfig, check_checkpoint_config
from .feedback import apply_feedback
from .input_range import check_input_values
from .text_encoder import FrozenTextEncoder

TASK_KEY = "task"
ACTION_PAD_KEY = "action_is_pad"
# State added after the checkpoint format was first released: a checkpoint without it loads with a fresh value.
LATER_STATE = ("kvm.metabolism.streak",)
# A fixed sentence whose embedding is stored with the weights: the query function must never change after
# skills are learned, so a checkpoint refuses to run with an encoder that embeds it differently.
_QUERY_PROBE = "pick up the object and place it on the target"
_QUERY_TOLERANCE = 1e-4
# The KVM's offline loss added to the action loss in `forward` (§3.3; the KVM's parameters are disjoint from the
# core's, so the weight only sets its share of the gradient clipping and the learning rate).
KVM_LOSS_WEIGHT = 0.1


class CodaKvmPolicy(PreTrainedPolicy):
    """CODA-Prompt continual-learning policy; the KVM (a later module) weights its skills."""

    config_class = CodaKvmConfig
    name = "coda_kvm"

    def __init__(self, config: CodaKvmConfig, **kwargs: Any) -> None:
        # kwargs: LeRobot passes dataset_stats= and dataset_meta=; normalization lives in the processors.
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.text_encoder = FrozenTextEncoder(config.text_encoder, config.query_dim)
        self.backbone = PromptedBackbone(
            image_shape=config.image_shape,
            n_cameras=len(config.image_features),
            state_dim=config.state_dim,
            context_dim=config.context_dim,
            action_dim=config.action_dim,
            chunk_size=config.chunk_size,
            vision_channels=list(config.vision_channels),
            dim_model=config.dim_model,
            n_layers=config.n_layers,
            n_heads=config.n_heads,
            dim_feedforward=config.dim_feedforward,
            dropout=config.dropout,
        )
        self.pool = CodaPromptPool(
            n_layers=config.prompt_layers,
            pool_size=config.pool_size,
            n_tasks=config.n_tasks,
            prompt_length=config.prompt_length,
            dim_model=config.dim_model,
            query_dim=config.query_dim,
        )
        self.kvm = KnowledgeValidityModule(config.kvm, config.context_dim, config.query_dim, config.n_tasks)
        self.register_buffer("query_fingerprint", torch.zeros(config.query_dim))
        self._init_abstention(kwargs.get("dataset_stats"), kwargs.get("dataset_meta"))
        self._query_checked = False
        self.register_load_state_dict_post_hook(CodaKvmPolicy._after_load)
        self.backbone.requires_grad_(config.train_backbone)
        self.pool.begin_skill(config.skill_name, config.skill_description)
        self._kvm_load_dataset_labels(kwargs.get("dataset_meta"))
        self._kvm_telemetry: KvmStepTelemetry | None = None
        self._kvm_trace = KvmTrace()
        self.reset()

    def _init_abstention(self, stats: dict | None, dataset_meta: Any) -> None:
        """The rest command and the grip-like dimensions of the safe abstention, from the training dataset (kept in
        the checkpoint; a policy built without a dataset rests at the normalized 0 and releases nothing)."""
        dim = self.config.action_dim
        mode = self.config.normalization_mapping.get("ACTION")
        action_stats = (stats or {}).get(ACTION)
        action_feature = (getattr(dataset_meta, "features", None) or {}).get(ACTION)
        names = action_feature.get("names") if isinstance(action_feature, dict) else None
        self.register_buffer("rest_action", normalized_rest(action_stats, mode, dim))
        self.register_buffer("release_mask", release_mask(names, dim))
        self._last_action: Tensor | None = None

    def _kvm_load_dataset_labels(self, dataset_meta: Any) -> None:
        """episode_index -> (skill, outcome, variant) from the recorder's labels, for offline KVM learning."""
        root = getattr(dataset_meta, "root", None)
        if root is None:
            return
        if (Path(root) / LABELS_FILE).exists():
            self.kvm_set_episode_labels(load_labels(root)["episodes"])

    @staticmethod
    def _after_load(module: "CodaKvmPolicy", _incompatible_keys: object) -> None:
        module._query_checked = False  # a loaded fingerprint must be checked against this process's encoder

    # ----------------------------------------------------------------- skills
    @property
    def skills(self) -> list[Skill]:
        return self.pool.skills

    @property
    def n_skills(self) -> int:
        return self.pool.n_skills

    def begin_new_skill(self, name: str, description: str = "", corrects: int | None = None) -> int:
        """Freeze the current skill and start learning a new one; rebuild the optimizer afterwards.
        `corrects`: the skill a knowledge-gap skill corrects (see `kvm.fusion.correction_validity`)."""
        index = self.pool.begin_skill(name, description, corrects)
        self.reset()
        return index

    # ----------------------------------------------------------------- KVM API
    def kvm_active_skills(self) -> Tensor:
        """[n_skills] bool: skills not pruned by the knowledge-base metabolism."""
        return self.kvm.metabolism.active(self.n_skills)

    @torch.no_grad()
    def kvm_negative_partners(self) -> Tensor:
        """[n_skills, n_skills] bool: skill j may stand as a cross-skill negative for skill i's recorded contexts
        (`KnowledgeValidityModule.negatives_for`): j is active, is not i, and the CL core, every skill in force,
        proposes it for none of the tasks i was trained on (pruning a skill makes no other one its task's)."""
        active = self.kvm_active_skills()
        n = self.n_skills
        owner, queries = self.pool.training_queries()
        proposed = torch.zeros(n, n, device=active.device)
        if len(owner):
            every = torch.ones_like(active)
            near = candidates(self.pool.skill_relevance(queries), every).to(proposed)
            proposed.index_add_(0, owner.to(active.device), near)
        eye = torch.eye(n, dtype=torch.bool, device=active.device)
        return active.unsqueeze(0) & (proposed == 0) & ~eye

    def kvm_prune_skill(self, index: int) -> None:
        """Deactivate a skill (weight 0 in the fused prompt while the KVM is enabled); recoverable."""
        self._check_skill_index(index)
        self.kvm.metabolism.prune(index)
        self.reset()

    def kvm_restore_skill(self, index: int) -> None:
        """Reactivate a pruned skill (its statistics start afresh)."""
        self._check_skill_index(index)
        self.kvm.metabolism.restore(index)
        self.reset()

    def _check_skill_index(self, index: int) -> None:
        if not 0 <= index < self.n_skills:
            raise ValueError(f"skill index must be in [0, {self.n_skills}), got {index}")

    def kvm_set_episode_labels(self, episodes: Sequence[dict]) -> int:
        """Labels of dataset episodes (`load_labels(root)["episodes"]`) for offline KVM learning."""
        return self.kvm.labels.load(episodes)

    @property
    def kvm_telemetry(self) -> KvmStepTelemetry | None:
        """The KVM assessment in force for the last action (None when the KVM is disabled)."""
        return self._kvm_telemetry

    def kvm_trace(self) -> KvmTrace:
        """What was recorded since the last `reset()` (one attempt): contexts, tasks, actions, telemetry."""
        return self._kvm_trace

    def kvm_feedback(
        self,
        outcome: str,
        trace: KvmTrace | None = None,
        demonstration: dict[str, Any] | None = None,
        gradient_steps: int | None = None,
        task: str | None = None,
    ) -> dict[str, Any]:
        """Learn from one finished attempt (Algorithm 1, lines 26-40); see `lerobot_kvm.policy.feedback`.

        outcome: "success", "failure", "abstention" or "catastrophe"; trace: the attempt (default: the current trace,
        which must hold one environment); demonstration: an optional corrective demonstration (policy inputs and
        normalized actions over T steps, see `policy.feedback.make_demonstration`; one that names a skill of the pool
        teaches that skill, so it is no knowledge gap); gradient_steps: the budget of
        KVM gradient steps (default `kvm.feedback_steps`). Returns a report of what was learned and decided.
        """
        trace = self._kvm_trace if trace is None else trace
        report = apply_feedback(self, outcome, trace, demonstration, gradient_steps, task)
        self.reset()
        return report

    @torch.no_grad()
    def kvm_validity(self, batch: dict[str, Any]) -> Tensor:
        """v [B, n_skills] of the batch's contexts with the gate bypassed (the risk model's judgement)."""
        batch_size = self._check_observation(batch)
        query = self.encode_query(self._tasks(batch, batch_size))
        c_raw = self.kvm.raw_context(batch[self.config.context_key], query)
        v = self.kvm.validity_of(c_raw, self.n_skills)
        return v * self.kvm_active_skills().to(v)

    def kvm_summary(self) -> dict[str, Any]:
        """The KVM's memory at a glance (JSON-friendly)."""
        kvm = self.kvm
        tau = kvm.threshold()
        hyps = [kvm.hypotheses.info(h) for h in kvm.hypotheses.ids()]
        n = self.n_skills
        return {
            "enabled": self.config.kvm.enabled,
            "gate": {
                "tau": float(tau),
                "mean": float(kvm.gate.stats[1]),
                "std": float(kvm.gate.stats[2]),
                "window": len(kvm.gate.window),
            },
            "buffers": {
                "safe_offline": len(kvm.safe_offline),
                "safe_online": len(kvm.safe_online),
                "fail_offline": len(kvm.fail_offline),
                "fail_online": len(kvm.fail_online),
                "fail_permanent": kvm.n_permanent(),
            },
            "hypotheses": hyps,
            "skills": [
                {
                    "index": s.index,
                    "name": s.name,
                    "pruned": bool(kvm.metabolism.pruned[s.index]),
                    "fcrnc": float(kvm.metabolism.fcrnc()[s.index]),
                    "srnc": float(kvm.metabolism.srnc()[s.index]),
                }
                for s in self.skills[:n]
            ],
        }

    # ----------------------------------------------------------------- LeRobot API
    def get_optim_params(self) -> list[dict[str, Any]]:
        """Trainable parameters only; prompt parameters get no weight decay (old skills must never drift).

        A third group holds the KVM's networks when it learns offline (their loss is added in `forward`)."""
        backbone = [p for p in self.backbone.parameters() if p.requires_grad]
        prompts = [p for p in self.pool.parameters() if p.requires_grad]
        groups: list[dict[str, Any]] = []
        if backbone:
            groups.append({"params": backbone})
        if prompts:
            groups.append({"params": prompts, "weight_decay": 0.0})
        if self.config.kvm.learn_offline:
            groups.append({"params": self.kvm.learnable_parameters(), "weight_decay": 0.0})
        return groups

    def reset(self) -> None:
        """Start a new attempt: empty action queue, new KVM trace."""
        self._action_queue: deque[Tensor] = deque([], maxlen=self.config.n_action_steps)
        self._kvm_trace = KvmTrace()
        self._kvm_telemetry = None
        self._queued_interventions: Tensor | None = None
        self._held: Tensor | None = None  # [B, S] suppressions held to the attempt's end (`KvmStepTelemetry.held`)
        self._last_action = None

    def forward(
        self, batch: dict[str, Any], reduction: str = "mean", skill_weights: Tensor | None = None
    ) -> tuple[Tensor, dict[str, float]]:
        """L1 between predicted and target normalized action chunks, ignoring padded steps. Without explicit
        weights the skill being learned acts under its own prompt alone: what it learns, it does alone."""
        if reduction not in ("mean", "none"):
            raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
        batch_size = self._check_observation(batch)
        query = self.encode_query(self._tasks(batch, batch_size))
        own = skill_weights is None
        if own:
            pred = self.decode_prompt(batch, self.pool.own_prompt(query, self.n_skills - 1))
        else:
            pred = self.decode(batch, self.pool.component_alphas(query), skill_weights)
        target, valid = self._check_action(batch, pred.shape[0])
        err = (pred - target).abs() * valid.unsqueeze(-1)
        per_sample = err.sum(dim=(1, 2)) / (valid.sum(dim=1) * pred.shape[-1]).clamp_min(1)
        l1 = err.sum() / (valid.sum() * pred.shape[-1]).clamp_min(1)
        info = {"l1_loss": l1.item()}
        loss = per_sample if reduction == "none" else l1
        if self.training and own:
            self.pool.observe_queries(query)
        if self.config.ortho_weight > 0:
            ortho = self.pool.ortho_penalty()
            loss = loss + self.config.ortho_weight * ortho
            info["ortho_loss"] = ortho.item()
        if self.training and self.config.kvm.learn_offline and torch.is_grad_enabled():
            kvm_loss, kvm_info = self._kvm_offline_loss(batch, query, batch_size)
            loss = loss + KVM_LOSS_WEIGHT * kvm_loss
            info.update(kvm_info)
        return loss, info

    def kvm_learn_offline(self, batch: dict[str, Any]) -> tuple[Tensor, dict[str, float]]:
        """The KVM's offline learning step alone (the term `forward()` adds to the action loss in training):
        needs only the sensed context, the task strings and, optionally, `episode_index`. Fills the memories."""
        context = batch.get(self.config.context_key)
        if not isinstance(context, Tensor) or context.ndim != 2 or context.shape[1] != self.config.context_dim:
            got = list(context.shape) if isinstance(context, Tensor) else type(context).__name__
            raise ValueError(f"'{self.config.context_key}' must have shape [B, {self.config.context_dim}], got {got}")
        if not torch.isfinite(context).all():
            raise ValueError(f"observation '{self.config.context_key}' contains NaN or inf values")
        batch_size = context.shape[0]
        return self._kvm_offline_loss(batch, self.encode_query(self._tasks(batch, batch_size)), batch_size)

    def _kvm_offline_loss(self, batch: dict[str, Any], query: Tensor, batch_size: int) -> tuple[Tensor, dict]:
        """The KVM's offline learning step on dataset frames: (context, skill that produced it, outcome)."""
        skills, outcome, usable = self.kvm.labels.lookup(
            batch.get("episode_index"), batch_size, [s.name for s in self.skills], self.n_skills - 1
        )
        c_raw = self.kvm.raw_context(batch[self.config.context_key], query)
        episodes = batch.get("episode_index")
        episodes = episodes.reshape(-1) if isinstance(episodes, Tensor) else None
        partners = self.kvm_negative_partners()
        return self.kvm.offline_step(c_raw, skills, outcome, usable, partners, episodes)

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Any], skill_weights: Tensor | None = None) -> Tensor:
        """Normalized action chunk [B, chunk_size, action_dim] (KVM-assessed unless skill weights are given)."""
        self._to_eval()
        chunk, telemetry = self._infer(batch, skill_weights)
        if telemetry is not None:
            self._kvm_telemetry = telemetry
        return chunk

    @torch.no_grad()
    def select_action(self, batch: dict[str, Any], skill_weights: Tensor | None = None) -> Tensor:
        """Next normalized action [B, action_dim]; a new chunk every `n_action_steps` calls, fused with the
        KVM's skill weights (or the given ones). While the gate is open the KVM assesses every call and replans at
        once when the set of suppressed skills changes (a suppression acts within one control step); while it is
        closed, the assessment of the chunk's first step holds (a closed gate costs E_c once per chunk)."""
        self._to_eval()
        pending = None
        gate_open = self._kvm_telemetry is not None and bool(self._kvm_telemetry.gate.any())
        if self._action_queue and gate_open and self._kvm_active(skill_weights):
            pending = self._plan(batch, skill_weights)
            self._kvm_telemetry = pending[2]
            changed = self._changed_rows(pending[2].intervention)
            if not bool(changed.any()):
                pending = None
            elif bool(changed.all()):
                self._action_queue.clear()
            else:
                self._replan_rows(changed, self._act(batch, *pending), pending[2].intervention)
                pending = None
        if not self._action_queue:
            if pending is not None:
                chunk, telemetry = self._act(batch, *pending), pending[2]
            else:
                chunk, telemetry = self._infer(batch, skill_weights)
            self._action_queue.extend(chunk[:, : self.config.n_action_steps].transpose(0, 1))
            self._kvm_telemetry = telemetry
            self._queued_interventions = None if telemetry is None else telemetry.intervention
        action = self._action_queue.popleft()
        self._last_action = action
        self._record_step(batch, action)
        return action

    def _changed_rows(self, intervention: Tensor) -> Tensor:
        """[B] bool: the rows whose suppressed skills differ from those their queued actions were planned under."""
        queued = self._queued_interventions
        if queued is None or queued.shape != intervention.shape:
            return torch.ones(intervention.shape[0], dtype=torch.bool, device=intervention.device)
        return (intervention != queued).any(-1)

    def _replan_rows(self, changed: Tensor, chunk: Tensor, intervention: Tensor) -> None:
        """Replace the queued actions of the `changed` rows [B] with the new chunk's first steps; every other row
        keeps executing its own chunk, as it would alone (`lerobot-eval` runs a batch of environments, and one
        environment's suppression must not replan the others: it cost a routine grasp half its successes)."""
        for step, queued in enumerate(self._action_queue):
            queued[changed] = chunk[changed, step]
        queued = self._queued_interventions.clone()
        queued[changed] = intervention[changed]
        self._queued_interventions = queued

    def _to_eval(self) -> None:
        """Inference runs in eval mode; `eval()` walks every submodule, which costs more than the KVM's gate-closed
        check, so it runs only when the policy is in training mode."""
        if self.training:
            self.eval()

    def _record_step(self, batch: dict[str, Any], action: Tensor) -> None:
        trace = self._kvm_trace
        if len(trace) >= self.config.kvm.trace_capacity:
            trace.truncated = True
            return
        context = batch.get(self.config.context_key)
        if not isinstance(context, Tensor) or context.ndim != 2 or context.shape[0] != action.shape[0]:
            return  # nothing to learn from (inputs are checked whenever a chunk is predicted)
        trace.contexts.append(context.detach())
        trace.tasks.append(self._tasks(batch, action.shape[0]))
        trace.actions.append(action.detach())
        trace.telemetry.append(self._kvm_telemetry)
        if action.shape[0] == 1:  # seed frames of a new skill; batched evaluation: contexts only
            keys = (*self.config.image_features, OBS_STATE, self.config.context_key)
            trace.observations.append({k: batch[k].detach() for k in keys if isinstance(batch.get(k), Tensor)})

    # ----------------------------------------------------------------- query and prompt
    def encode_query(self, tasks: Sequence[str]) -> Tensor:
        """Frozen CODA query q(x) [B, query_dim] of the task strings, on the policy's device."""
        device = self.query_fingerprint.device
        if not self._query_checked:
            self._check_query_function(device)
        return self.text_encoder.encode(tasks, device)

    def _check_query_function(self, device: torch.device) -> None:
        probe = self.text_encoder.encode([_QUERY_PROBE], device)[0]
        with torch.inference_mode(False), torch.no_grad():
            if not self.query_fingerprint.any():
                self.query_fingerprint.copy_(probe)
            elif (probe - self.query_fingerprint).abs().max() > _QUERY_TOLERANCE:
                raise ValueError(
                    f"text_encoder {self.config.text_encoder!r} embeds differently from the encoder these "
                    "skills were learned with; the CODA keys would silently change meaning"
                )
        self._query_checked = True

    def skill_relevance(self, tasks: Sequence[str]) -> Tensor:
        """Per-skill relevance alpha_i [B, n_skills] of the task strings."""
        return self.pool.skill_relevance(self.encode_query(tasks))

    def skill_prompts(self, tasks: Sequence[str]) -> Tensor:
        """Per-skill prompt contributions c_i [prompt_layers, B, n_skills, prompt_length, dim_model]."""
        return self.pool.skill_prompts(self.encode_query(tasks))

    def _kvm_active(self, skill_weights: Tensor | None) -> bool:
        return self.config.kvm.enabled and skill_weights is None

    def _plan(
        self, batch: dict[str, Any], skill_weights: Tensor | None
    ) -> tuple[Tensor, Tensor | None, KvmStepTelemetry | None]:
        """Algorithm 1, lines 4-20, each stage once: (component alphas, decision weights, the KVM's telemetry).

        The observation x_t and its sensed context (line 4) give the frozen query q(x); the CL core proposes the
        candidate skills and their relevance (line 5); the KVM assesses their validity (lines 7-17: E_c, the smart
        gate, energies, v) and turns it into eq. 3's decision weights (line 20). Explicit skill weights skip both;
        the KVM disabled keeps every v = 1 (telemetry None in both cases)."""
        batch_size = self._check_observation(batch)
        query = self.encode_query(self._tasks(batch, batch_size))
        relevance, anchors = self.pool.propose(query)
        alphas = self.pool.anchored_alphas(anchors)  # each skill as it was trained on its nearest task
        if skill_weights is not None:
            return alphas, skill_weights, None
        if not self.config.kvm.enabled:
            everyone = torch.ones(self.n_skills, dtype=torch.bool, device=relevance.device)
            return (
                alphas,
                decision_weights(torch.ones_like(relevance), relevance, candidates(relevance, everyone)),
                None,
            )
        n = self.n_skills
        held = self._held if self._held is not None and self._held.shape == relevance.shape else None
        weights, telemetry = self.kvm.assess(
            batch[self.config.context_key],
            query,
            relevance,
            self.kvm.metabolism.active(n),
            self.kvm.metabolism.all_active(n),
            self.pool.corrections(),
            held,
        )
        now = telemetry.held(self.config.kvm.tau_high) if telemetry.gate.any() else None
        if now is not None and bool(now.any()):
            self._held = now if held is None else held | now
        return alphas, weights, telemetry

    def _infer(self, batch: dict[str, Any], skill_weights: Tensor | None) -> tuple[Tensor, KvmStepTelemetry | None]:
        """One model call: `_plan`, then the fused prompt and the decoder (Algorithm 1, lines 21-22)."""
        alphas, weights, telemetry = self._plan(batch, skill_weights)
        return self._act(batch, alphas, weights, telemetry), telemetry

    def _act(
        self, batch: dict[str, Any], alphas: Tensor, weights: Tensor, telemetry: KvmStepTelemetry | None
    ) -> Tensor:
        """The action chunk: decoded from the fused prompt, or the safe abstention's hold in the rows where the KVM
        found every candidate invalid (no prompt is trusted there, so none reaches the decoder's output)."""
        chunk = self.decode(batch, alphas, weights)
        if telemetry is not None:
            abstained = telemetry.abstained
            if bool(abstained.any()):
                last = self._last_action
                if last is None or last.shape != chunk[:, 0].shape:
                    last = self.rest_action.to(chunk).expand_as(chunk[:, 0])
                held = hold_chunk(last.to(chunk), self.rest_action, self.release_mask, chunk.shape[1])
                chunk = torch.where(abstained.view(-1, 1, 1), held, chunk)
        return self._finite(chunk, batch)

    def _finite(self, chunk: Tensor, batch: dict[str, Any]) -> Tensor:
        """`chunk`, or an error naming the rows and inputs: never a NaN action (a finite but huge input can
        overflow the network)."""
        broken = ~torch.isfinite(chunk).flatten(1).all(-1)
        if bool(broken.any()):
            rows = torch.nonzero(broken).flatten().tolist()
            largest = {
                key: float(batch[key][rows].abs().max())
                for key in (*self.config.image_features, OBS_STATE, self.config.context_key)
            }
            raise ValueError(
                f"the policy's action is not finite for batch rows {rows}: an input is out of the range it can "
                f"compute with (largest |value| per input after normalisation: {largest})"
            )
        return chunk

    def decode(self, batch: dict[str, Any], alphas: Tensor, skill_weights: Tensor) -> Tensor:
        """Eq. 4: actions from the backbone prefixed by the fused prompt (component alphas [L, B, M], decision
        weights [B, S])."""
        return self.decode_prompt(batch, self.pool.prompt_from_alphas(alphas, skill_weights))

    def decode_prompt(self, batch: dict[str, Any], prompts: Tensor) -> Tensor:
        """Actions from the backbone prefixed by a given prompt [L, B, Lp, D]."""
        images = [batch[key] for key in self.config.image_features]
        return self.backbone(images, batch[OBS_STATE], batch[self.config.context_key], prompts)

    # ----------------------------------------------------------------- input checks
    def _check_observation(self, batch: dict[str, Any]) -> int:
        """Every observation key present, shaped [B, *feature_shape] with one B, finite; returns B."""
        batch_size: int | None = None
        for key in (*self.config.image_features, OBS_STATE, self.config.context_key):
            if key not in batch:
                raise ValueError(f"missing observation key '{key}'; batch has keys {sorted(batch)}")
            value = batch[key]
            if not isinstance(value, Tensor):
                raise ValueError(f"observation '{key}' must be a torch.Tensor, got {type(value).__name__}")
            feature_shape = tuple(self.config.input_features[key].shape)
            size = batch_size if batch_size is not None else "B"
            if (
                value.ndim != len(feature_shape) + 1
                or tuple(value.shape[1:]) != feature_shape
                or (batch_size is not None and value.shape[0] != batch_size)
            ):
                raise ValueError(
                    f"observation '{key}' must have shape [{size}, {', '.join(map(str, feature_shape))}], "
                    f"got {list(value.shape)}"
                )
            batch_size = value.shape[0]
            check_input_values(key, value)
        return batch_size

    def _tasks(self, batch: dict[str, Any], batch_size: int) -> list[str]:
        tasks = batch.get(TASK_KEY)
        if isinstance(tasks, str):
            return [tasks] * batch_size
        if not isinstance(tasks, list | tuple) or not all(isinstance(t, str) for t in tasks):
            raise ValueError(f"'{TASK_KEY}' must be a string or a list of {batch_size} strings, got {tasks!r}")
        if len(tasks) != batch_size:
            raise ValueError(f"'{TASK_KEY}' has {len(tasks)} strings for a batch of {batch_size}")
        return list(tasks)

    def _check_action(self, batch: dict[str, Any], batch_size: int) -> tuple[Tensor, Tensor]:
        """Target chunk [B, chunk, A] and validity mask [B, chunk] (from `action_is_pad`, if present)."""
        expected = [batch_size, self.config.chunk_size, self.config.action_dim]
        target = batch.get(ACTION)
        if not isinstance(target, Tensor) or list(target.shape) != expected:
            got = list(target.shape) if isinstance(target, Tensor) else type(target).__name__
            raise ValueError(f"'{ACTION}' must have shape {expected}, got {got}")
        if not torch.isfinite(target).all():
            raise ValueError(f"'{ACTION}' contains NaN or inf values")
        pad = batch.get(ACTION_PAD_KEY)
        if pad is None:
            return target, torch.ones(expected[:2], dtype=target.dtype, device=target.device)
        if not isinstance(pad, Tensor) or list(pad.shape) != expected[:2]:
            got = list(pad.shape) if isinstance(pad, Tensor) else type(pad).__name__
            raise ValueError(f"'{ACTION_PAD_KEY}' must have shape {expected[:2]}, got {got}")
        return target, (~pad.bool()).to(target.dtype)

    # ----------------------------------------------------------------- loading
    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, **kwargs: Any) -> "CodaKvmPolicy":
        """LeRobot's loader, once the checkpoint's config.json is checked as a whole: LeRobot would fill a missing
        field with its default and build this class from another policy's config."""
        if Path(pretrained_name_or_path).is_dir():
            check_checkpoint_config(pretrained_name_or_path)
        return super().from_pretrained(pretrained_name_or_path, **kwargs)

    @classmethod
    def _load_as_safetensor(
        cls, model: "CodaKvmPolicy", model_file: str, map_location: str, strict: bool
    ) -> "CodaKvmPolicy":
        """Always strict: a checkpoint with missing, unexpected or mis-shaped tensors is an error, not a
        silently half-initialised policy (except the `LATER_STATE` counters, absent from older checkpoints).

        Task-incremental learning: when the config names a skill the checkpoint does not have yet
        (`lerobot-train --policy.path=<previous> --policy.skill_name=<next task>`), that skill is begun after
        loading, in new CODA components; every earlier skill's rows stay frozen and bit-identical."""
        state = load_file(model_file, device=resolve_safetensors_device(map_location))
        expected = model.state_dict()
        for key in LATER_STATE:  # older checkpoints: these start as in a fresh policy
            if key in expected and key not in state:
                state[key] = expected[key].clone()
        missing = sorted(set(expected) - set(state))
        unexpected = sorted(set(state) - set(expected))
        mismatched = [
            f"{k}: checkpoint {list(state[k].shape)} vs policy {list(v.shape)}"
            for k, v in expected.items()
            if k in state and state[k].shape != v.shape
        ]
        if missing or unexpected or mismatched:
            raise ValueError(
                f"incompatible coda_kvm checkpoint {model_file}: missing keys {missing}, "
                f"unexpected keys {unexpected}, shape mismatches {mismatched}"
            )
        # a NaN or inf weight would only show as NaN actions: refused here, by name
        broken = [k for k, _ in model.named_parameters() if not torch.isfinite(state[k]).all()]
        if broken:
            raise ValueError(f"coda_kvm checkpoint {model_file} has non-finite weights in {broken[:5]}")
        model.load_state_dict(state, strict=True)
        if model.config.skill_name not in {skill.name for skill in model.skills}:
            model.begin_new_skill(model.config.skill_name, model.config.skill_description)
        return model
