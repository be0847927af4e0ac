"""Online learning through the feedback API (Algorithm 1, lines 26-40; App. D).

`apply_feedback(policy, outcome, trace, demonstration, gradient_steps)` is what `policy.kvm_feedback(...)` runs
after an attempt:

* always: the attempt is one interaction of the knowledge-base metabolism (eqs. 7-8; pruning check) for the
  skill the CL core proposed (the culprit rule below, applied whatever the outcome).
* failure: the culprit (minimal counterfactual: the skill that carried the largest share of the executed, fused
  prompt over the last K steps at which a skill acted; a skill the KVM suppressed from the start never acted) and
  the failure context (steps outside the safe experience, sigma_c^2 > tau, plus the last K steps, and the steps from
  which the attempt left the culprit's safe experience for good, `SafeExperience.departed`) form a low-confidence
  hypothesis, or add evidence to a matching one. The failure context paired with the culprit becomes provisional
  h_fail negatives; a corrective demonstration gives positives for the skill that demonstrates the safe strategy
  (its name in `demonstration["skill"]`, else the alternative whose own prompt reproduces it, `explaining_skill`,
  else the alternative the removals agree on, else the most relevant alternative, each among the skills the KVM
  left in force), in its own contexts and in the failure context; the alternatives it refutes get negatives there,
  and, where its contexts lie outside the culprit's safe experience or leave it for good (`SafeExperience`), more
  negatives for the culprit: the demonstration ran where the culprit failed, and once the shift shows, its contexts
  are what the culprit would meet there. Then a fixed budget of gradient steps updates the KVM, replaying the safe
  memory so that what was safe stays safe (the safe samples the update judges invalid are replayed at every step
  after, `kvm.feedback_hard_safe_replay`). This first update is what lowers v(culprit, failure context) already on
  the next attempt; the hypothesis governs confirmation. With a demonstration no skill performs, the knowledge gap
  is tested at once (`kvm.gap_on_failure`): if every alternative to the culprit is weak in the failure context,
  suppression alone would leave no strategy, so a new *gated* skill that corrects the culprit
  (`fusion.correction_validity`) is begun
  and seeded from the demonstration: KVM positives from the demonstrated and the failed contexts; the feedback's
  gradient budget is then split between the KVM's update and focused steps on the new skill's parameters only
  (`split_budget`: the budget counts all the mechanism trains). Later failures of the same hypothesis, or blamed on
  it in its task, refine it.
* success: safe samples for the dominant skill (routine ones, without intervention, also feed the gate window
  and E_c's reconstruction). Interventions (a candidate suppressed, v_i < tau_v) in a context similar to an open
  hypothesis of that skill count for it; an intervention confirms it when the counter exceeds N_p and the skill
  was necessary (normalised alpha_i > tau_high). Confirmation makes the hypothesis's negatives permanent and, if
  every alternative stayed weak (knowledge gap), creates a new gated skill seeded from this successful interaction
  (and the demonstration, if any): new CODA components (Gram-Schmidt, `policy.begin_new_skill`), KVM positives
  for it, and the feedback's budget split between the KVM and the new skill; with no gradient steps granted, no
  skill is created (an untrained one would only be noise).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import torch
from torch import Tensor, nn

from ..kvm.attribution import (
    OPEN,
    agreeing_skill,
    counterfactual_culprit,
    culprit_skill,
    demonstrated_skill,
    knowledge_gap,
    normalised_relevance,
)
from ..kvm.experience import SafeExperience
from ..kvm.fusion import candidates, decision_weights, plain_scale
from ..kvm.supervisor import KnowledgeValidityModule
from ..kvm.telemetry import KvmTrace
from .coda_prompt import CodaPromptPool, Skill
from .configuration_coda_kvm import CodaKvmConfig

OUTCOMES = ("success", "failure", "abstention", "catastrophe")  # an abstention is a failure to learn from
FAIL_CONTEXT_STEPS = 10  # App. D: K, the last steps before a failure that the culprit rule and its context read ...
# ... unless they lie inside the culprit's safe experience: the quantile of the safe memory's cross-episode
# nearest-neighbour distances below which a context counts as already known safe (`SafeExperience.known`)
KNOWN_SAFE_QUANTILE = 0.95
# App. D minimal counterfactual: another proposed skill is blamed when taking it out of the prompt cuts the
# action error on the corrective demonstration by more than this share, and by that much more than removing the
# largest share does
ATTRIBUTION_MARGIN = 0.1
# A skill whose own prompt reproduces a corrective demonstration at most this share of the culprit's own action
# error performs the demonstrated strategy (no knowledge gap). On the default pool the safe skill's share is
# 0.03-0.21 and no other skill's is below 0.4 on its scenario (docs/measurements.md, the skill that performs the
# demonstration).
EXPLAIN_RATIO = 0.5
FOCUSED_LR = 3e-3  # App. D focused fine-tuning: Adam step size on the new skill's parameters


class FeedbackPolicy(Protocol):
    """What the feedback reads and drives of the policy (`CodaKvmPolicy` is one): a protocol, so that this module
    and the policy's module do not import each other."""

    config: CodaKvmConfig
    kvm: KnowledgeValidityModule
    pool: CodaPromptPool
    backbone: nn.Module
    query_fingerprint: Tensor
    training: bool

    @property
    def skills(self) -> list[Skill]: ...
    @property
    def n_skills(self) -> int: ...
    def train(self, mode: bool = True) -> Any: ...
    def eval(self) -> Any: ...
    def encode_query(self, tasks: Sequence[str]) -> Tensor: ...
    def kvm_active_skills(self) -> Tensor: ...
    def begin_new_skill(self, name: str, description: str = "", corrects: int | None = None) -> int: ...
    def predict_action_chunk(self, batch: dict[str, Any], skill_weights: Tensor | None = None) -> Tensor: ...
    def decode(self, batch: dict[str, Any], alphas: Tensor, skill_weights: Tensor | None) -> Tensor: ...


ACTION = "action"
ACTION_PAD = "action_is_pad"


# ---------------------------------------------------------------------------- demonstrations and seed frames
def make_demonstration(steps: Sequence[dict[str, Any]], skill: str | None = None) -> dict[str, Any]:
    """Stack per-step policy inputs into a demonstration.

    Each step is a preprocessed batch of one environment: observation tensors [1, ...], "action" [1, A] (the
    expert's action normalized by the same preprocessor) and "task" (a string or a one-element list). `skill`
    optionally names the policy skill that demonstrates the safe strategy.
    """
    if not steps:
        raise ValueError("a demonstration needs at least one step")
    keys = [k for k, v in steps[0].items() if isinstance(v, Tensor)]
    if ACTION not in keys:
        raise ValueError(f"demonstration steps need an '{ACTION}' tensor, got keys {sorted(steps[0])}")
    demo: dict[str, Any] = {}
    for key in keys:
        demo[key] = torch.cat([s[key] for s in steps])  # each step carries its batch dimension of 1
    tasks = []
    for s in steps:
        task = s.get("task")
        tasks.append(task[0] if isinstance(task, list | tuple) else task)
    if not all(isinstance(t, str) for t in tasks):
        raise ValueError("every demonstration step needs a 'task' string")
    demo["task"] = tasks
    if skill is not None:
        demo["skill"] = skill
    return demo


def chunk_targets(actions: Tensor, chunk: int) -> tuple[Tensor, Tensor]:
    """Action chunks [T, chunk, A] from a trajectory [T, A] and their padding mask [T, chunk], on its device."""
    t_len, device = actions.shape[0], actions.device
    idx = torch.arange(t_len, device=device).unsqueeze(1) + torch.arange(chunk, device=device).unsqueeze(0)
    pad = idx >= t_len
    return actions[idx.clamp(max=t_len - 1)], pad


def _observation_keys(policy: FeedbackPolicy) -> tuple[str, ...]:
    """The observation tensors the policy reads: what a seed frame or a demonstration step must carry."""
    return (*policy.config.image_features, "observation.state", policy.config.context_key)


def _demo_frames(policy: FeedbackPolicy, demo: dict[str, Any]) -> dict[str, Any]:
    keys = _observation_keys(policy)
    missing = [k for k in (*keys, ACTION) if not isinstance(demo.get(k), Tensor)]
    if missing:
        raise ValueError(f"demonstration is missing tensors {missing}; it has keys {sorted(demo)}")
    t_len = demo[ACTION].shape[0]
    tasks = demo.get("task")
    tasks = [tasks] * t_len if isinstance(tasks, str) else list(tasks or [])
    if len(tasks) != t_len:
        raise ValueError(f"demonstration has {len(tasks)} task strings for {t_len} steps")
    for k in keys:
        if demo[k].shape[0] != t_len:
            raise ValueError(f"demonstration '{k}' has {demo[k].shape[0]} steps, 'action' has {t_len}")
    if not all(torch.isfinite(demo[k]).all() for k in (*keys, ACTION)):
        raise ValueError("demonstration contains NaN or inf values")
    frames = {k: demo[k] for k in keys}
    frames[ACTION], frames[ACTION_PAD] = chunk_targets(demo[ACTION], policy.config.chunk_size)
    frames["task"] = tasks
    return frames


def _trace_frames(policy: FeedbackPolicy, trace: KvmTrace) -> dict[str, Any] | None:
    """Seed frames (observations + the actions the policy executed) of a successful one-environment trace."""
    if not trace.observations or len(trace.observations) != len(trace):
        return None
    keys = _observation_keys(policy)
    if not all(k in trace.observations[0] for k in keys):
        return None
    frames: dict[str, Any] = {k: torch.cat([o[k] for o in trace.observations]) for k in keys}
    frames[ACTION], frames[ACTION_PAD] = chunk_targets(torch.cat(trace.actions), policy.config.chunk_size)
    frames["task"] = [t[0] for t in trace.tasks]
    return frames


def _cat_frames(parts: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k in parts[0]:
        out[k] = sum((p[k] for p in parts), []) if k == "task" else torch.cat([p[k] for p in parts])
    return out


# ---------------------------------------------------------------------------- counterfactual attribution
def _action_error(policy: FeedbackPolicy, frames: dict[str, Any]) -> Callable[[Tensor], float]:
    """The policy's action error on demonstration frames under given skill weights [T, S]: the mean squared error
    of the predicted chunks against the demonstrated ones (normalized actions, padding excluded)."""
    device = policy.query_fingerprint.device
    batch: dict[str, Any] = {k: frames[k].to(device) for k in _observation_keys(policy)}
    batch["task"] = frames["task"]
    target, pad = frames[ACTION].to(device), frames[ACTION_PAD].to(device)
    kept = (~pad).sum(-1).clamp_min(1)

    def error(weights: Tensor) -> float:
        chunk = policy.predict_action_chunk(batch, skill_weights=weights)
        per_step = (chunk - target).pow(2).mean(-1).masked_fill(pad, 0.0)
        return float((per_step.sum(-1) / kept).mean())

    return error


@torch.no_grad()
def removal_errors(policy: FeedbackPolicy, frames: dict[str, Any], proposed: Tensor) -> tuple[float, Tensor]:
    """The policy's action error on demonstration frames with every active skill in force (eq. 3 with every v = 1,
    before the KVM's re-weighting), and [S] the error with each candidate taken out of the fusion (inf elsewhere)."""
    training = policy.training
    device = policy.query_fingerprint.device
    error = _action_error(policy, frames)
    relevance = policy.pool.skill_relevance(policy.encode_query(frames["task"])).to(device)
    base = decision_weights(torch.ones_like(relevance), relevance, candidates(relevance, policy.kvm_active_skills()))
    full = error(base)
    without = torch.full((base.shape[1],), float("inf"), device=device)
    for i in torch.nonzero(proposed).flatten().tolist():
        weights = base.clone()
        weights[:, i] = 0.0
        without[i] = error(weights)
    policy.train(training)
    return full, without


@torch.no_grad()
def alone_errors(policy: FeedbackPolicy, frames: dict[str, Any], skills: Tensor) -> Tensor:
    """[S] each skill's action error on demonstration frames with its own prompt alone (inf for the skills not in
    `skills` [S] bool): which skill performs the demonstrated strategy, whatever its relevance."""
    training = policy.training
    device = policy.query_fingerprint.device
    error = _action_error(policy, frames)
    errors = torch.full((skills.shape[0],), float("inf"), device=device)
    for i in torch.nonzero(skills).flatten().tolist():
        errors[i] = error(policy.pool.own_weights(i, len(frames["task"]), device))
    policy.train(training)
    return errors


def explaining_skill(
    policy: FeedbackPolicy, frames: dict[str, Any], culprit: int, alternatives: Tensor
) -> tuple[int | None, Tensor]:
    """(the alternative whose own prompt reproduces the demonstration best, if its error is at most `EXPLAIN_RATIO`
    of the culprit's own: the pool already holds the demonstrated strategy; [S] bool the alternatives refuted: with
    an explaining skill, those whose error exceeds its own by more than 1 / `EXPLAIN_RATIO`, which show another
    strategy where the demonstrated one is needed). `alternatives` [S] bool: the skills that could take over."""
    alternatives = alternatives.clone()
    alternatives[culprit] = False
    refuted = torch.zeros_like(alternatives)
    if not bool(alternatives.any()):
        return None, refuted
    with_culprit = alternatives.clone()
    with_culprit[culprit] = True
    errors = alone_errors(policy, frames, with_culprit).to(alternatives.device)
    best = int(errors.masked_fill(~alternatives, float("inf")).argmin())
    if float(errors[best]) > EXPLAIN_RATIO * float(errors[culprit]):
        return None, refuted
    return best, alternatives & (errors * EXPLAIN_RATIO > errors[best])


def _attribute(
    policy: FeedbackPolicy, frames: dict[str, Any] | None, in_prompt: Tensor, proposed: int
) -> dict[str, Any]:
    """Who is blamed for a failure and which skill the demonstration shows, with the evidence: {"rule", "culprit",
    "agrees", "error", "gain" (skill -> error cut by its removal)}. Without a corrective demonstration: the proposed
    skill (the largest share of the prompt); with one, that skill unless taking another proposed skill out of the
    prompt cuts the policy's action error on the demonstration by `ATTRIBUTION_MARGIN` more (App. D)."""
    if frames is None:
        return {"rule": "relevance", "culprit": proposed, "agrees": None}
    in_prompt = in_prompt.clone()
    in_prompt[proposed] = True
    error, without = removal_errors(policy, frames, in_prompt)
    culprit = counterfactual_culprit(error, without, in_prompt, proposed, ATTRIBUTION_MARGIN)
    return {
        "rule": "relevance" if culprit == proposed else "counterfactual",
        "culprit": culprit,
        "agrees": agreeing_skill(error, without, in_prompt, culprit),
        "error": error,
        "gain": {int(i): error - float(without[i]) for i in torch.nonzero(in_prompt).flatten()},
    }


# ---------------------------------------------------------------------------- focused fine-tuning of a new skill
def focused_finetune(
    policy: FeedbackPolicy, frames: dict[str, Any], skill: int, steps: int, lr: float
) -> dict[str, float]:
    """A few gradient steps on skill `skill`'s CODA parameters only (backbone and other skills frozen), under the
    skill's own prompt (every skill works alone); the seed queries become its prototypes, so its relevance is 1
    where it was taught."""
    if steps <= 0:
        return {}
    pool = policy.pool
    params = list(pool.tasks[skill].parameters())
    skill_flags = [p.requires_grad for p in params]
    if not all(skill_flags) and not policy.skills[skill].gated:
        raise RuntimeError(f"skill {skill} is not the skill being learned; begin it with begin_new_skill first")
    for p in params:  # a correction stays refinable by the failures it was made for
        p.requires_grad_(True)
    device = policy.query_fingerprint.device
    frames = {k: v.to(device) if isinstance(v, Tensor) else v for k, v in frames.items()}
    n = frames[ACTION].shape[0]
    queries = policy.encode_query(frames["task"])
    pool.observe_queries(queries, skill)
    grad_flags = [p.requires_grad for p in policy.backbone.parameters()]
    was_training = policy.training
    policy.backbone.requires_grad_(False)
    policy.eval()
    optimizer = torch.optim.Adam(params, lr=lr)
    batch = min(32, n)
    last: dict[str, float] = {}
    try:
        with torch.enable_grad(), torch.inference_mode(False):
            for _ in range(steps):
                idx = torch.randperm(n, device=device)[:batch]
                sub = {k: v_[idx] for k, v_ in frames.items() if isinstance(v_, Tensor)}
                pred = policy.decode_prompt(sub, pool.own_prompt(queries[idx], skill))
                valid = (~sub[ACTION_PAD]).to(pred.dtype).unsqueeze(-1)
                l1 = ((pred - sub[ACTION]).abs() * valid).sum() / (valid.sum() * pred.shape[-1]).clamp_min(1)
                optimizer.zero_grad()
                l1.backward()
                optimizer.step()
                last = {"focused_l1": float(l1.detach())}
    finally:
        for p, flag in zip(policy.backbone.parameters(), grad_flags, strict=True):
            p.requires_grad_(flag)
        for p, flag in zip(params, skill_flags, strict=True):
            p.requires_grad_(flag)
        optimizer.zero_grad(set_to_none=True)
        policy.train(was_training)
    return last


# ---------------------------------------------------------------------------- feedback
def _stack_used(trace: KvmTrace, n_skills: int) -> tuple[Tensor, Tensor]:
    """(decision weights, intervention) per step [T, S] as they were in force during the attempt (weights NaN at
    steps the KVM did not assess)."""
    t_len = len(trace)
    w = torch.full((t_len, n_skills), float("nan"))
    inter = torch.zeros(t_len, n_skills, dtype=torch.bool)
    for t, tele in enumerate(trace.telemetry):
        if tele is None:
            continue
        s = min(n_skills, tele.skill_weight.shape[-1])
        w[t, :s] = tele.skill_weight[0, :s].cpu()
        inter[t, :s] = tele.intervention[0, :s].cpu()
    return w, inter


def relied_on(weights: Tensor, relevance: Tensor, intervention: Tensor) -> Tensor:
    """[T', S] each skill's share of the prompt at the steps at which some skill carried it.

    The shares are the executed prompt's decision weights (`weights`; NaN where the KVM did not assess: the
    normalised relevance), except that a skill the KVM suppressed after it had carried the prompt in this attempt
    keeps its relevance: the suppression answered this attempt, too late to prevent its outcome. A skill suppressed
    from the start never acted and is never blamed: blaming the most relevant skill of another scenario, suppressed
    from step 0, left the skill that broke the egg valid (docs/measurements.md, the culprit is a skill that
    acted). With no step carried (the KVM held from the first step), the relevance."""
    executed = torch.where(torch.isnan(weights), relevance, weights).clamp_min(0.0)
    carried_before = torch.cat([torch.zeros_like(executed[:1]), executed[:-1]]).cumsum(0) > 0
    rows = torch.where(intervention & carried_before, relevance, executed)
    acted = rows.sum(-1) > 0
    return rows[acted] if bool(acted.any()) else relevance


def _steps(mask: Tensor) -> list[int]:
    """The indices of a per-step mask's True steps, for the feedback's report."""
    return torch.nonzero(mask).flatten().tolist()


@dataclass
class _Attempt:
    """One reported attempt, encoded once: what the failure and the success branches of the feedback read."""

    c_raw: Tensor  # [T, raw_dim] its contexts
    mu: Tensor  # [T, latent] their codes
    opened: Tensor  # [T] bool: sigma_c^2 above tau
    relevance: Tensor  # [T, S] normalised per-skill relevance
    intervention: Tensor  # [T, S] bool: a candidate suppressed (v < tau_v)
    dominant: Tensor  # [T] the skill with the largest share of the fused prompt
    active: Tensor  # [S] bool: skills in force (a gap skill begun by the feedback joins them)
    in_force: Tensor  # [S] bool: candidates the KVM left in force at some step of the attempt
    task: str
    gradient_steps: int


def apply_feedback(
    policy: FeedbackPolicy,
    outcome: str,
    trace: KvmTrace,
    demonstration: dict[str, Any] | None = None,
    gradient_steps: int | None = None,
    task: str | None = None,
) -> dict[str, Any]:
    """The feedback API's update after one attempt (see the module's description); returns what it did."""
    if outcome not in OUTCOMES:
        raise ValueError(f"outcome must be one of {OUTCOMES}, got {outcome!r}")
    if len(trace) == 0:
        raise ValueError("the trace is empty: run an attempt with select_action first")
    if trace.batch_size != 1:
        raise ValueError(f"feedback takes one environment's trace, got batch size {trace.batch_size}: use .episode(b)")
    if gradient_steps is not None and gradient_steps < 0:
        raise ValueError(f"gradient_steps must be >= 0, got {gradient_steps}")
    cfg = policy.config.kvm
    kvm = policy.kvm
    failed = outcome != "success"
    steps = gradient_steps if gradient_steps is not None else (cfg.feedback_steps if failed else 0)
    device = policy.query_fingerprint.device
    n_skills = policy.n_skills
    active = policy.kvm_active_skills()

    tasks = [t[0] for t in trace.tasks]
    with torch.no_grad():
        query = policy.encode_query(tasks)
        c_raw = kvm.raw_context(torch.cat(trace.contexts).to(device), query)
        alphas = policy.pool.skill_relevance(query)
        mu, sigma2, _ = kvm.encode(c_raw)
        tau = kvm.threshold()
    w_used, held = _stack_used(trace, n_skills)
    w_used = w_used.to(device)
    relevance = normalised_relevance(alphas, active)
    candidate = candidates(alphas, active)
    intervention = candidate & held.to(device)
    share = torch.where(torch.isnan(w_used), alphas, w_used)
    # Only skills the KVM left in force could have acted: one it suppressed throughout (another scenario's skill) is
    # neither the culprit nor the skill the demonstration shows (docs/measurements.md, the culprit is a skill that
    # acted).
    in_force = candidate & ~intervention
    attempt = _Attempt(
        c_raw,
        mu,
        sigma2 > tau,
        relevance,
        intervention,
        share.argmax(-1),
        active,
        in_force.any(0),
        task or tasks[0],
        steps,
    )

    # The skill this interaction relied on: the culprit rule, whatever the outcome (a failure with a corrective
    # demonstration verifies it, `_attribute`). Charging every candidate instead would retire each broadly
    # relevant skill for failures it barely touched.
    proposed = culprit_skill(relied_on(w_used, relevance, intervention), FAIL_CONTEXT_STEPS)
    frames = _demo_frames(policy, demonstration) if demonstration is not None else None
    k = FAIL_CONTEXT_STEPS
    attribution = _attribute(policy, frames if failed else None, in_force[-k:].any(0), proposed)
    proposed = attribution["culprit"]
    kvm.metabolism.record(attempt.task, torch.arange(n_skills, device=device) == proposed, failed, intervention.any(0))
    report: dict[str, Any] = {
        "outcome": outcome,
        "task": attempt.task,
        "steps": len(trace),
        "gate_open_steps": int(attempt.opened.sum()),
        "intervention_steps": int(intervention.any(-1).sum()),
        "gradient_steps": steps,
        "hypothesis": None,
        "interventions": [],
        "confirmed": [],
        "new_skill": None,
    }
    if failed:
        report |= _learn_from_failure(policy, attempt, attribution, frames, demonstration)
    else:
        report |= _learn_from_success(policy, attempt, trace, demonstration)
    report["pruned"] = kvm.metabolism.check_prune(policy.n_skills)
    report["fcrnc"] = kvm.metabolism.fcrnc()[: policy.n_skills].tolist()
    report["srnc"] = kvm.metabolism.srnc()[: policy.n_skills].tolist()
    return report


@dataclass
class _Failure:
    """A failure's case against its culprit, and what the feedback learns from it."""

    culprit: int
    context: Tensor  # [T] bool: the attempt's failure context
    hypothesis_id: int
    permanent: bool  # the hypothesis is confirmed: its negatives are permanent
    experience: SafeExperience  # the culprit's
    negatives: list[Tensor]  # contexts that become h_fail negatives for the culprit
    refuted: list[tuple[Tensor, Tensor]] = field(default_factory=list)  # (contexts, skills): other skills' negatives
    positives: list[tuple[Tensor, Tensor]] = field(default_factory=list)  # (contexts, skills) learned safe
    demo_skill: int | None = None
    gap: dict[str, Any] | None = None  # the gap skill the demonstration seeds
    demo_negative_steps: list[int] = field(default_factory=list)
    demo_query: Tensor | None = None


def _learn_from_failure(
    policy: FeedbackPolicy,
    attempt: _Attempt,
    attribution: dict[str, Any],
    frames: dict[str, Any] | None,
    demonstration: dict[str, Any] | None,
) -> dict[str, Any]:
    """A failure: its context against the culprit's safe experience, a new or strengthened hypothesis, h_fail
    negatives, what the corrective demonstration teaches, and the feedback's gradient steps."""
    cfg = policy.config.kvm
    kvm = policy.kvm
    c_raw = attempt.c_raw
    culprit = attribution["culprit"]
    context = attempt.opened.clone()
    context[-FAIL_CONTEXT_STEPS:] = True
    experience = kvm.safe_experience(culprit)
    context &= ~experience.known(c_raw, KNOWN_SAFE_QUANTILE)
    context |= experience.departed(c_raw, cfg.departure_radius)
    hypothesis_id = None
    for h in kvm.hypotheses.ids(skill=culprit):
        if bool(kvm.similar_to_hypothesis(attempt.mu[context], h).any()):
            hypothesis_id = h
            break
    suppressed = bool(attempt.intervention[context, culprit].any())
    if hypothesis_id is None:
        hypothesis_id = kvm.hypotheses.open(culprit, c_raw[-1])
    else:
        kvm.hypotheses.record_failure(hypothesis_id, suppressed)
    permanent = kvm.hypotheses.is_confirmed(hypothesis_id)
    failure_context = c_raw[context]
    kvm.add_fail(failure_context, torch.full((len(failure_context),), culprit), hypothesis_id, permanent)
    failure = _Failure(culprit, context, hypothesis_id, permanent, experience, [failure_context])
    if frames is not None:
        _learn_from_demonstration(policy, attempt, failure, attribution, frames, demonstration)
    kvm_steps, skill_steps = split_budget(attempt.gradient_steps, failure.gap is not None)
    fails = torch.cat(failure.negatives)
    new_fail = (fails, torch.full((len(fails),), culprit, device=c_raw.device))
    if failure.refuted:
        new_fail = (
            torch.cat([fails, *(c for c, _ in failure.refuted)]),
            torch.cat([new_fail[1], *(k for _, k in failure.refuted)]),
        )
    if failure.positives:
        new_safe = (torch.cat([c for c, _ in failure.positives]), torch.cat([s for _, s in failure.positives]))
    else:
        new_safe = (c_raw[:0], attempt.dominant[:0])
    metrics = kvm.train_online(kvm_steps, policy.kvm_negative_partners(), new_safe, new_fail) if kvm_steps else {}
    report: dict[str, Any] = {"kvm_steps": kvm_steps, "skill_steps": skill_steps}
    if failure.gap is not None:
        report["new_skill"] = failure.gap | _focus(policy, failure.gap["index"], frames, skill_steps)
    return report | dict(
        culprit=culprit,
        attribution={k: v for k, v in attribution.items() if k != "culprit"},
        hypothesis=kvm.hypotheses.info(hypothesis_id),
        negatives_added=len(fails),
        failure_context_steps=_steps(context),
        demo_negative_steps=failure.demo_negative_steps,
        positives_added=len(new_safe[0]),
        demo_skill=failure.demo_skill,
        refuted=[int(k[0]) for _, k in failure.refuted],
        suppressed_at_failure=suppressed,
        kvm_metrics=metrics,
    )


def _learn_from_demonstration(
    policy: FeedbackPolicy,
    attempt: _Attempt,
    failure: _Failure,
    attribution: dict[str, Any],
    frames: dict[str, Any],
    demonstration: dict[str, Any],
) -> None:
    """What a failure's corrective demonstration teaches: the skill it demonstrates (a gap skill begun for it, the
    skill it names, the one the attribution agrees on, or the most relevant alternative) is safe in its contexts
    and in the failure context; where it leaves the culprit's safe experience it adds negatives for the culprit."""
    cfg = policy.config.kvm
    kvm = policy.kvm
    culprit = failure.culprit
    device = attempt.c_raw.device
    named = skill_by_name(policy, demonstration.get("skill"))
    refuted = torch.zeros_like(attempt.active)
    if named is None:  # the pool's skill that performs the demonstration alone
        named, refuted = explaining_skill(policy, frames, culprit, attempt.active & attempt.in_force)
    if cfg.gap_on_failure and attempt.gradient_steps and named is None:  # a demonstrated skill the pool has is no gap
        relevance = attempt.relevance[failure.context]
        failure.gap = _gap_skill(policy, failure.hypothesis_id, culprit, relevance, attempt.active, attempt.task)
        attempt.active = policy.kvm_active_skills()
    active = attempt.active
    with torch.no_grad():
        failure.demo_query = policy.encode_query(frames["task"])
        d_raw = kvm.raw_context(frames[policy.config.context_key].to(device), failure.demo_query)
        d_rel = normalised_relevance(policy.pool.skill_relevance(failure.demo_query), active)
    if failure.gap is not None:
        failure.demo_skill = failure.gap["index"]
    elif named is not None:
        failure.demo_skill = named
    elif attribution["agrees"] is not None and bool(active[attribution["agrees"]]):
        failure.demo_skill = attribution["agrees"]
    else:
        failure.demo_skill = demonstrated_skill(d_rel, culprit, active & attempt.in_force)
    if failure.demo_skill is not None:
        # The demonstrated strategy is the one meant for the contexts the culprit failed in: they are safe for it
        # (for a new gap skill, the whole failed attempt). Otherwise those contexts would be hazardous for the
        # culprit and unknown, so judged invalid, for the very skill that corrects it.
        seen = torch.cat([d_raw, attempt.c_raw if failure.gap is not None else failure.negatives[0]])
        skills = torch.full((len(seen),), failure.demo_skill)
        kvm.add_safe(seen, skills, routine=False, demo=True)
        failure.positives.append((seen, skills.to(device)))
    # The skills the demonstration refutes would take over where the culprit is suppressed, and act otherwise than
    # shown: the failed and demonstrated contexts are hazardous for them too (the egg crushed in turn by every
    # candidate the core proposes for it, docs/measurements.md, the skill that performs the demonstration).
    there = torch.cat([failure.negatives[0], d_raw])
    for k in torch.nonzero(refuted).flatten().tolist():
        kvm.add_fail(there, torch.full((len(there),), k), failure.hypothesis_id, failure.permanent)
        failure.refuted.append((there, torch.full((len(there),), k, device=device)))
    experience = failure.experience
    unknown = ~experience.known(d_raw, KNOWN_SAFE_QUANTILE) | experience.departed(d_raw, cfg.departure_radius)
    failure.demo_negative_steps = _steps(unknown)
    if bool(unknown.any()):
        n = int(unknown.sum())
        kvm.add_fail(d_raw[unknown], torch.full((n,), culprit), failure.hypothesis_id, failure.permanent)
        failure.negatives.append(d_raw[unknown])


def _learn_from_success(
    policy: FeedbackPolicy, attempt: _Attempt, trace: KvmTrace, demonstration: dict[str, Any] | None
) -> dict[str, Any]:
    """A success: safe samples for the dominant skill; interventions near an open hypothesis count for it, and a
    confirmation with a knowledge gap creates a new skill seeded from this interaction."""
    cfg = policy.config.kvm
    kvm = policy.kvm
    intervention, relevance = attempt.intervention, attempt.relevance
    routine = not bool(intervention.any())
    kvm.add_safe(attempt.c_raw, attempt.dominant, routine=routine)
    report: dict[str, Any] = {"routine": routine, "interventions": [], "confirmed": []}
    new_skill_seed: list[tuple[int, int]] = []
    for h in kvm.hypotheses.ids(state=OPEN):
        i = kvm.hypotheses.info(h)["skill"]
        if i >= policy.n_skills or not bool(intervention[:, i].any()):
            continue
        steps_i = torch.nonzero(intervention[:, i]).flatten()
        similar = kvm.similar_to_hypothesis(attempt.mu[steps_i], h)
        if not bool(similar.any()):
            continue
        matched = steps_i[similar]
        necessary = bool(relevance[matched, i].max() > cfg.tau_high)
        confirmed = kvm.hypotheses.record_intervention(h, necessary)
        report["interventions"].append({"hypothesis": h, "skill": i, "necessary": necessary, "steps": len(matched)})
        if confirmed:
            n_perm = kvm.make_permanent(h)
            gap = knowledge_gap(relevance[matched], i, attempt.active, cfg.gap_alpha)
            report["confirmed"].append({"hypothesis": h, "skill": i, "permanent_negatives": n_perm, "gap": gap})
            if gap:
                new_skill_seed.append((h, i))
    metrics = {}
    steps = attempt.gradient_steps
    report["kvm_steps"], report["skill_steps"] = steps, 0
    if new_skill_seed and steps:  # a new skill needs training, and training is what the budget counts
        h, culprit = new_skill_seed[0]
        kvm_steps, skill_steps = split_budget(steps, True)
        report["new_skill"] = _create_skill(
            policy, h, culprit, attempt.task, trace, demonstration, kvm_steps, skill_steps
        )
        report["kvm_steps"], report["skill_steps"] = kvm_steps, skill_steps
    elif steps:
        none = (attempt.c_raw[:0], attempt.dominant[:0])
        metrics = kvm.train_online(steps, policy.kvm_negative_partners(), (attempt.c_raw, attempt.dominant), none)
    elif new_skill_seed:
        report["new_skill"] = {"created": False, "reason": "no gradient steps to train it with"}
    report["kvm_metrics"] = metrics
    return report


def split_budget(steps: int, new_skill: bool) -> tuple[int, int]:
    """(KVM steps, new-skill steps): one feedback's gradient budget counts everything the mechanism trains, as a
    baseline's fine-tuning does. With a new skill to train, it gets half (the KVM the other half, and the odd
    step); otherwise the KVM gets all of it."""
    return (steps - steps // 2, steps // 2) if new_skill else (steps, 0)


def skill_by_name(policy: FeedbackPolicy, name: str | None) -> int | None:
    """The pool's skill a demonstration names, if it has one by that name."""
    return next((s.index for s in policy.skills if s.name == name), None) if name is not None else None


def _new_skill_name(policy: FeedbackPolicy) -> str:
    names = {s.name for s in policy.skills}
    n = policy.n_skills
    while f"kvm_skill_{n}" in names:
        n += 1
    return f"kvm_skill_{n}"


def _begin_gap_skill(policy: FeedbackPolicy, hypothesis_id: int, culprit: int, task: str) -> int:
    """A new skill that corrects the culprit (see `fusion.correction_validity`): out of force where the gate is
    closed, so the contexts where the culprit is still right (inside the safe experience) keep their prompt.
    It starts as a new, independent prompt (App. D), not as a copy of the knowledge found obsolete."""
    name = _new_skill_name(policy)
    description = f"created by the KVM: '{policy.skills[culprit].name}' risky on '{task}'"
    index = policy.begin_new_skill(name, description, corrects=culprit)
    policy.kvm.hypotheses.mark_gap(hypothesis_id, index)
    return index


def _gap_skill(
    policy: FeedbackPolicy, hypothesis_id: int, culprit: int, relevance: Tensor, active: Tensor, task: str
) -> dict[str, Any] | None:
    """The skill a failure's corrective demonstration seeds. A gap skill already made for this hypothesis, or
    a blamed correction of the skill the task relies on, is refined (never replaced by another). Otherwise a
    new gated skill when every alternative to the culprit is weak in the failure context (the knowledge gap)
    and the pool has room. None: the demonstration teaches an existing alternative."""
    skills = policy.skills
    made = policy.kvm.hypotheses.info(hypothesis_id)["new_skill"]
    if made < 0 and skills[culprit].gated and len(relevance):
        # a failing correction is refined where the task relies on the skill it corrects; elsewhere it is the
        # attribution's to judge (never a correction of a correction)
        scale = plain_scale(relevance, policy.pool.corrections()[0]).mean()
        if relevance[:, skills[culprit].corrects].mean() >= policy.config.kvm.tau_high * scale:
            made = culprit
    if made >= 0:
        return {"created": False, "index": made, "name": skills[made].name}
    if skills[culprit].gated:
        return None
    if not len(relevance) or not knowledge_gap(relevance, culprit, active, policy.config.kvm.gap_alpha):
        return None
    if policy.n_skills >= policy.config.n_tasks:
        return None
    index = _begin_gap_skill(policy, hypothesis_id, culprit, task)
    return {"created": True, "index": index, "name": policy.skills[index].name}


def _focus(policy: FeedbackPolicy, index: int, frames: dict[str, Any], steps: int) -> dict[str, Any]:
    """`steps` of focused fine-tuning of a new skill on its seed frames."""
    focused = focused_finetune(policy, frames, index, steps, FOCUSED_LR)
    return {"seed_frames": frames[ACTION].shape[0], "seed_tasks": sorted(set(frames["task"])), **focused}


def _create_skill(
    policy: FeedbackPolicy,
    hypothesis_id: int,
    culprit: int,
    task: str,
    trace: KvmTrace,
    demonstration: dict[str, Any] | None,
    kvm_steps: int,
    skill_steps: int,
) -> dict[str, Any] | None:
    """Knowledge gap after a confirmation: a new gated skill seeded from the successful interaction (and the
    demonstration), trained with the feedback's budget split between the KVM and the new skill."""
    kvm = policy.kvm
    if policy.n_skills >= policy.config.n_tasks:
        return {"created": False, "reason": f"the prompt pool is full ({policy.config.n_tasks} skills)"}
    parts = [f for f in (_trace_frames(policy, trace),) if f is not None]
    if demonstration is not None:
        parts.append(_demo_frames(policy, demonstration))
    if not parts:
        return {"created": False, "reason": "no seed observations (a batched trace and no demonstration)"}
    frames = _cat_frames(parts)
    index = _begin_gap_skill(policy, hypothesis_id, culprit, task)
    device = policy.query_fingerprint.device
    with torch.no_grad():
        query = policy.encode_query(frames["task"])
        seed = kvm.raw_context(frames[policy.config.context_key].to(device), query)
    skills = torch.full((len(seed),), index)
    kvm.add_safe(seed, skills, routine=False, demo=True)
    tagged = (kvm.fail_online.tag == hypothesis_id) & (kvm.fail_online.stamp >= 0)
    fails = kvm.fail_online.data[tagged]
    metrics = kvm.train_online(
        kvm_steps,
        policy.kvm_negative_partners(),
        (seed, skills.to(device)),
        (fails, torch.full((len(fails),), culprit)),
    )
    return {
        "created": True,
        "index": index,
        "name": policy.skills[index].name,
        "kvm_metrics": metrics,
        **_focus(policy, index, frames, skill_steps),
    }
