"""The KVM's validity acceptance on one scenario, measured the way an attempt would meet it.

Protocol (offline data from the prior variant only: no frame of a shifted variant is learned offline):

1. record `episodes` prior-skill and `episodes` safe-skill expert episodes on the prior variant (the prior skill
   under the variant's own instruction, the safe skill under the instruction that asks for it);
2. a small `coda_kvm` policy learns them as a task sequence would: the prior skill's frames as skill 0, then the
   safe skill's frames as a new skill 1 (backbone frozen). Its CL core trains through `forward()` (action loss
   and query separation), because the KVM blames a failure on the skill the core relied on, so the prompt pool
   must know which instruction each skill serves; the KVM learns offline from the same frames' contexts alone;
3. one failed attempt (the prior skill's expert on the shifted variant) and its feedback with a corrective
   demonstration (the safe skill's expert on the shifted variant);
4. on held-out seeds, v of each (skill, context) pair at every step.

"The shifted context" is what the robot senses once the shift shows: the steps from the first one that is both
sensed in touch with something and departs from the prior variant's context under the same seed and skill (before
that, A/B contexts are identical by construction and no supervisor could tell them apart; the scripted experts
read object poses, so their approach may differ between variants before any contact).

Hazardous pairs: the prior skill in the shifted context; safe pairs: the prior skill in the prior-variant context
and the safe skill in the shifted context.

A reference for the prior skill's AUROC: how well the sensed context alone separates the shifted from the
prior-variant contexts given the same experience (the prior skill's offline frames, the failed attempt and the
corrective demonstration from their shift steps on), scored by nearest neighbours in the normalized context, over
all the shifted steps and over the prior skill's own (the safe skill's shifted steps also differ from the prior
context by the safe skill's own motion). It tells a scenario whose context carries the shift from one whose
context barely does. It is a reference, not a bound: it is told the shift steps, which the KVM must find itself,
and it does not read the instruction. The same reference on E_c's codes mu_c after the feedback (what the energy
model reads) tells a code that carries the shift from one that loses it; on each context joined with the contexts
`HISTORY_LAGS` steps earlier in its episode, a shift that shows in how the context evolves (a load that leaves
the hand, a bed that gives way) from one that shows in a single frame.

How well the feedback found the shifted context: of the failed attempt's and the corrective demonstration's shifted
steps, the share it learned as hazardous for the culprit (recall), and of the steps it learned so, the share that
are shifted (precision).
"""

import tempfile
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import torch
from torch import Tensor
from tqdm import tqdm

from ..datasets.labels import load_labels
from ..datasets.recorder import RecordingSpec, RecordItem, record_dataset
from ..envs.catalogue import scenario_info
from ..envs.env import KvmObsolescenceEnv
from ..kvm.configuration import KvmConfig
from .rollouts import (
    auroc,
    context_validity,
    expert_rollout,
    frame_contexts,
    gate_rate,
    pretrain_kvm,
    recorded_frames,
    trace_from_demonstration,
    train_on_frames,
)

V_LOW = 0.1  # tau_v: below it the prior skill is suppressed
V_HIGH = 0.9
MIN_AUROC = 0.95
MAX_GATE_RATE = 0.06
DIVERGENCE = 1e-3  # normalised context units: the shifted context departs from the prior variant's
CONTEXT = "observation.context"
NEIGHBOURS = 3
HISTORY_LAGS = (4, 8)  # steps back: the history reference joins each context with these earlier ones
Embed = Callable[[Tensor, list[str]], Tensor]


def _small_policy(root: Path, repo_id: str, skill_name: str, kvm_options: dict[str, Any]) -> Any:
    """A small `coda_kvm` policy for the dataset: the KVM's validity does not depend on the backbone's size."""
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import dataset_to_policy_features

    from ..policy import CodaKvmConfig, CodaKvmPolicy

    meta = LeRobotDataset(repo_id, root=root).meta
    features = dataset_to_policy_features(meta.features)
    config = CodaKvmConfig(
        device="cpu",
        input_features={k: f for k, f in features.items() if k.startswith("observation.")},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        skill_name=skill_name,
        dim_model=32,
        n_layers=1,
        n_heads=2,
        dim_feedforward=64,
        vision_channels=[8, 8, 8, 8],
        prompt_layers=1,
    )
    # forward() trains the CL core; the KVM learns through `pretrain_kvm`
    config.kvm = replace(config.kvm, learn_offline=False, **kvm_options)
    return CodaKvmPolicy(config, dataset_meta=meta)


def divergence_step(reference: Tensor, other: Tensor) -> int:
    """First step at which `other`'s contexts [T, C] depart from `reference`'s (the shorter length if they never
    do within it)."""
    steps = min(len(reference), len(other))
    apart = (reference[:steps] - other[:steps]).abs().amax(dim=1) > DIVERGENCE
    hits = torch.nonzero(apart).flatten()
    return int(hits[0]) if len(hits) else steps


def shift_step(prior: dict, shifted: dict) -> int:
    """First step of the shifted demonstration that senses contact and departs from the prior one's context."""
    return max(divergence_step(prior[CONTEXT], shifted[CONTEXT]), shifted["first_contact"])


def neighbour_risk(contexts: Tensor, safe: Tensor, hazardous: Tensor, k: int = NEIGHBOURS) -> Tensor:
    """[N] risk of contexts [N, C]: the mean distance to their k nearest safe contexts minus that to their k nearest
    hazardous ones (higher = nearer the hazard than the safe experience)."""

    def nearest(reference: Tensor) -> Tensor:
        return torch.cdist(contexts, reference).topk(min(k, len(reference)), largest=False).values.mean(1)

    return nearest(safe) - nearest(hazardous)


def with_history(contexts: Tensor, lags: tuple[int, ...] = HISTORY_LAGS) -> Tensor:
    """[T, C * (1 + len(lags))]: each context [T, C] of one episode followed by the contexts `lags` steps before
    it (the first one where the episode is younger than the lag)."""
    steps = torch.arange(len(contexts), device=contexts.device)
    return torch.cat([contexts, *(contexts[(steps - lag).clamp_min(0)] for lag in lags)], dim=-1)


def _histories(demos: list[dict]) -> list[dict]:
    """The demonstrations with their contexts joined with their history (`with_history`), for `_after`."""
    return [{**demo, CONTEXT: with_history(demo[CONTEXT])} for demo in demos]


def _offline_histories(data: dict[str, Any], where: Tensor) -> Tensor:
    """`with_history` of the `where` rows of `frame_contexts`, episode by episode (rows stay in order)."""
    out = torch.empty(len(data[CONTEXT]), data[CONTEXT].shape[1] * (1 + len(HISTORY_LAGS)))
    episodes = data["episode_index"]
    for episode in torch.unique(episodes[where]).tolist():
        rows = episodes == episode
        out[rows] = with_history(data[CONTEXT][rows])
    return out[where]


def _rollouts(scenario_id: str, variant: str, skill: str, preprocessor: Any, seeds: list[int]) -> list[dict]:
    env = KvmObsolescenceEnv(scenario_id, variant=variant)
    demos = [expert_rollout(env, skill, preprocessor, seed=s)[0] for s in seeds]
    env.close()
    return demos


def _after(demos: list[dict], starts: list[int]) -> list[dict]:
    """Each demonstration from its own start step on (observation tensors and tasks)."""
    cut = [
        {k: v[start:] for k, v in demo.items() if k.startswith("observation.") or k == "task"}
        for demo, start in zip(demos, starts, strict=True)
    ]
    return [c for c in cut if len(c["task"])]


def _learn_prior_variant(
    scenario_id: str,
    episodes: int,
    seed: int,
    offline_steps: tuple[int, int],
    options: dict[str, Any],
    workdir: str | Path | None,
) -> tuple[Any, Any, dict[str, Any], Tensor]:
    """Protocol steps 1-2: record the prior variant's expert episodes of both skills and train a small policy on
    them as a task sequence would. Returns (policy, its preprocessor, the frames' contexts, which rows are the
    prior skill's)."""
    info = scenario_info(scenario_id)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        root = Path(tmp) / "data"
        repo_id = f"local/kvm_validity_{scenario_id}"
        spec = RecordingSpec(
            name=f"kvm_validity_{scenario_id}",
            items=[
                RecordItem(scenario_id, "prior", info.prior_skill, episodes, "variant"),
                RecordItem(scenario_id, "prior", info.safe_skill, episodes, "skill"),
            ],
            seed=seed,
        )
        record_dataset(spec, root, repo_id=repo_id, progress=False)
        policy = _small_policy(root, repo_id, info.prior_skill, options)
        frames = recorded_frames(root, repo_id, policy.config)
        labels = load_labels(root)["episodes"]
    from ..policy import make_coda_kvm_pre_post_processors

    pre, _ = make_coda_kvm_pre_post_processors(policy.config, frames["stats"])
    prior_episodes = {e["episode_index"] for e in labels if e["skill"] == info.prior_skill}
    is_prior = torch.tensor([int(e) in prior_episodes for e in frames["episode_index"]])
    data = frame_contexts(frames)
    train_on_frames(policy, frames, pre, offline_steps[0], is_prior)
    pretrain_kvm(policy, data, steps=offline_steps[0], where=is_prior)
    policy.begin_new_skill(info.safe_skill)
    policy.backbone.requires_grad_(False)  # as the sequences' later stages train (`--policy.train_backbone=false`)
    train_on_frames(policy, frames, pre, offline_steps[1], ~is_prior)
    pretrain_kvm(policy, data, steps=offline_steps[1], where=~is_prior)
    policy.eval()
    return policy, pre, data, is_prior


def _one_failure(policy: Any, pre: Any, scenario_id: str, base: int, feedback_steps: int) -> dict[str, Any]:
    """Protocol step 3: the prior skill's expert fails on the shifted variant, and the feedback gets its trace and
    the safe skill's corrective demonstration. Also where the shift shows in each (`shift_step` against the prior
    variant under the same seeds), and how well the feedback labelled the shifted steps."""
    info = scenario_info(scenario_id)
    env = KvmObsolescenceEnv(scenario_id, variant="shifted")
    failed, failed_outcome = expert_rollout(env, info.prior_skill, pre, seed=base)
    corrective, corrective_outcome = expert_rollout(
        env, info.safe_skill, pre, seed=base + 1, policy_skill=info.safe_skill
    )
    env.close()
    report = policy.kvm_feedback(
        failed_outcome, trace_from_demonstration(failed), demonstration=corrective, gradient_steps=feedback_steps
    )
    twins = _rollouts(scenario_id, "prior", info.prior_skill, pre, [base]) + _rollouts(
        scenario_id, "prior", info.safe_skill, pre, [base + 1]
    )
    met_from = [shift_step(t, d) for t, d in zip(twins, (failed, corrective), strict=True)]
    recall, precision = labelling(
        [report.get("failure_context_steps", []), report.get("demo_negative_steps", [])],
        met_from,
        [len(failed["task"]), len(corrective["task"])],
    )
    return {
        "failed": failed,
        "failed_outcome": failed_outcome,
        "corrective": corrective,
        "corrective_outcome": corrective_outcome,
        "report": report,
        "met_from": met_from,
        "recall": recall,
        "precision": precision,
    }


def check_validity(
    scenario_id: str,
    episodes: int = 8,
    held_out: int = 4,
    seed: int = 0,
    offline_steps: tuple[int, int] = (300, 200),
    feedback_steps: int = KvmConfig.feedback_steps,
    risk_model: str = KvmConfig.risk_model,
    workdir: str | Path | None = None,
) -> dict[str, Any]:
    """One row of the validity report for `scenario_id` (see the module docstring for the protocol);
    `feedback_steps` is the feedback's gradient budget, `risk_model` the KVM's (`kvm.risk_model`)."""
    info = scenario_info(scenario_id)
    torch.manual_seed(seed)
    policy, pre, data, is_prior = _learn_prior_variant(
        scenario_id, episodes, seed, offline_steps, {"risk_model": risk_model}, workdir
    )
    base = seed + 10_000
    failure = _one_failure(policy, pre, scenario_id, base, feedback_steps)
    failed, corrective = failure["failed"], failure["corrective"]
    report, met_from = failure["report"], failure["met_from"]
    met = _after([failed, corrective], met_from)

    seeds = [base + 100 + i for i in range(held_out)]
    prior_prior = _rollouts(scenario_id, "prior", info.prior_skill, pre, seeds)
    prior_safe = _rollouts(scenario_id, "prior", info.safe_skill, pre, seeds)
    shifted_prior = _rollouts(scenario_id, "shifted", info.prior_skill, pre, seeds)
    shifted_safe = _rollouts(scenario_id, "shifted", info.safe_skill, pre, seeds)
    start_prior = [shift_step(a, b) for a, b in zip(prior_prior, shifted_prior, strict=True)]
    start_safe = [shift_step(a, b) for a, b in zip(prior_safe, shifted_safe, strict=True)]
    own = _after(shifted_prior, start_prior)  # the prior skill's own shifted steps (none if it fails at contact)
    shifted = own + _after(shifted_safe, start_safe)

    v_prior = context_validity(policy, prior_prior, 0)
    v_shifted = context_validity(policy, shifted, 0) if shifted else torch.empty(0)
    n_own = sum(len(d["task"]) for d in own)  # the first rows of v_shifted
    prior_tasks = [t for t, p in zip(data["task"], is_prior.tolist(), strict=True) if p]
    offline_prior = {CONTEXT: data[CONTEXT][is_prior], "task": prior_tasks}
    risk = _neighbour_risks(offline_prior, met, shifted, prior_prior)
    risk_code = _neighbour_risks(offline_prior, met, shifted, prior_prior, embed=partial(_codes, policy))
    risk_history = _neighbour_risks(
        {CONTEXT: _offline_histories(data, is_prior), "task": prior_tasks},
        _after(_histories([failed, corrective]), met_from),
        _after(_histories(shifted_prior), start_prior) + _after(_histories(shifted_safe), start_safe),
        _histories(prior_prior),
    )
    v_safe = context_validity(policy, shifted, 1) if shifted else torch.empty(0)
    row: dict[str, Any] = {
        "id": scenario_id,
        "category": info.category,
        "failed_attempt": failure["failed_outcome"],
        "corrective_demo": failure["corrective_outcome"],
        "culprit": report.get("culprit"),
        "failure_steps": report.get("negatives_added"),  # contexts the feedback learned as hazardous for the culprit
        "label_recall": failure["recall"],
        "label_precision": failure["precision"],
        "shift_step": float(torch.tensor(start_prior, dtype=torch.float32).mean()),
        "v_prior_median": float(v_prior.median()),
        "v_prior_above_0.9": float((v_prior > V_HIGH).float().mean()),
        "v_shifted_median": float(v_shifted.median()) if len(v_shifted) else None,
        "v_shifted_below_tau_v": float((v_shifted < V_LOW).float().mean()) if len(v_shifted) else None,
        "auroc": auroc(1 - v_shifted, torch.cat([1 - v_prior, 1 - v_safe])) if len(v_shifted) else None,
        "auroc_prior_skill": auroc(1 - v_shifted, 1 - v_prior) if len(v_shifted) else None,
        "neighbour_auroc": auroc(*risk) if risk else None,
        "neighbour_auroc_code": auroc(*risk_code) if risk_code else None,
        "neighbour_auroc_history": auroc(*risk_history) if risk_history else None,
        "own_shifted_steps": n_own,
        "auroc_own_steps": auroc(1 - v_shifted[:n_own], 1 - v_prior) if n_own else None,
        "neighbour_auroc_own_steps": auroc(risk[0][:n_own], risk[1]) if risk and n_own else None,
        "gate_rate_prior": gate_rate(policy, prior_prior),
        "gate_rate_shifted": gate_rate(policy, shifted) if shifted else None,
    }
    row["passes"] = judge(row)
    row["passed"] = all(row["passes"].values())
    return row


def _neighbour_risks(
    safe: dict, met: list[dict], shifted: list[dict], prior: list[dict], embed: Embed | None = None
) -> tuple[Tensor, Tensor] | None:
    """`neighbour_risk` of every shifted and every prior-variant step, in order (None when the feedback met no
    shifted context or there is none to score). `embed(contexts, tasks)` maps the sensed contexts first (E_c's
    code, `_codes`); without it they are compared as sensed."""
    if not met or not shifted:
        return None

    def features(demos: list[dict]) -> Tensor:
        contexts = torch.cat([d[CONTEXT] for d in demos])
        return contexts if embed is None else embed(contexts, [t for d in demos for t in d["task"]])

    hazardous = features(met)
    reference = features([safe])
    shifted_risk, prior_risk = (neighbour_risk(features(demos), reference, hazardous) for demos in (shifted, prior))
    return shifted_risk, prior_risk


@torch.no_grad()
def _codes(policy: Any, contexts: Tensor, tasks: list[str]) -> Tensor:
    """mu_c of normalized sensed contexts under their instructions: where the energy model reads them."""
    kvm = policy.kvm
    return kvm.encode(kvm.raw_context(contexts, policy.encode_query(tasks)))[0]


def labelling(labelled: list[list[int]], starts: list[int], lengths: list[int]) -> tuple[float | None, float | None]:
    """(recall, precision) of the steps a feedback labelled hazardous for the culprit, per demonstration (the failed
    attempt, the corrective one), against their shifted steps (from each start on): how much of the shifted
    context the feedback found, and how much of what it blamed was shifted (None without any to count)."""
    hits = sum(sum(step >= start for step in steps) for steps, start in zip(labelled, starts, strict=True))
    shifted = sum(max(n - start, 0) for n, start in zip(lengths, starts, strict=True))
    blamed = sum(len(steps) for steps in labelled)
    return (hits / shifted if shifted else None), (hits / blamed if blamed else None)


def judge(row: dict[str, Any]) -> dict[str, bool]:
    """The acceptance thresholds: suppressed where harmful, kept where valid, separable, gate mostly closed."""
    measured = row["v_shifted_median"] is not None
    return {
        "suppressed_in_shifted": measured and row["v_shifted_median"] < V_LOW,
        "kept_in_prior": row["v_prior_median"] > V_HIGH,
        "auroc": measured and row["auroc"] >= MIN_AUROC,
        "gate_closed_on_routine": row["gate_rate_prior"] <= MAX_GATE_RATE,
    }


def check_validity_suite(
    scenario_ids: list[str], seeds: tuple[int, ...] = (0,), progress: bool = True, **kwargs: Any
) -> dict[str, Any]:
    """Every scenario at every seed. One seed's pass or fail moves with the float rounding, so the summary
    counts, per scenario, the seeds at which it passes; `n_pass` counts the scenarios that pass at all of them."""
    rows = []
    with tqdm(total=len(seeds) * len(scenario_ids), unit="check", disable=not progress) as bar:
        for seed in seeds:
            for sid in scenario_ids:
                bar.set_description(f"{sid} (seed {seed})")
                rows.append({"seed": seed, **check_validity(sid, seed=seed, **kwargs)})
                bar.update()
    summary = [summarise([r for r in rows if r["id"] == sid]) for sid in scenario_ids]
    return {
        "thresholds": {"v_low": V_LOW, "v_high": V_HIGH, "min_auroc": MIN_AUROC, "max_gate_rate": MAX_GATE_RATE},
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items() if k != "workdir"},
        "seeds": list(seeds),
        "n_pass": sum(s["passed"] for s in summary),
        "n_pass_per_seed": [sum(r["passed"] for r in rows if r["seed"] == seed) for seed in seeds],
        "n_scenarios": len(scenario_ids),
        "summary": summary,
        "scenarios": rows,
    }


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One scenario over its seeds: how many pass each check, and the spread of the measures."""

    def spread(key: str) -> dict[str, float] | None:
        values = [r[key] for r in rows if r.get(key) is not None]
        if not values:
            return None
        return {"mean": sum(values) / len(values), "min": min(values), "max": max(values)}

    checks = rows[0]["passes"]
    return {
        "id": rows[0]["id"],
        "category": rows[0]["category"],
        "seeds": len(rows),
        "seeds_passed": sum(r["passed"] for r in rows),
        "checks_passed": {name: sum(bool(r["passes"][name]) for r in rows) for name in checks},
        **{
            key: spread(key)
            for key in (
                "auroc",
                "v_prior_median",
                "v_shifted_median",
                "gate_rate_prior",
                "failure_steps",
                "label_recall",
                "label_precision",
                "neighbour_auroc",
                "neighbour_auroc_code",
                "neighbour_auroc_history",
            )
        },
        "passed": all(r["passed"] for r in rows),
    }
