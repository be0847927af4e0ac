"""Helpers to exercise the KVM on the simulated suite: attempts, expert demonstrations, detection AUROC.

An attempt runs the policy in a `KvmObsolescenceEnv` the way `lerobot-eval` does (LeRobot's
`preprocess_observation`, the policy's pre/post-processors, `select_action`) and returns the outcome with the
policy's KVM trace; an expert rollout records a corrective demonstration in the policy's input format.
"""

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ..kvm.telemetry import KvmTrace
from ..policy.feedback import make_demonstration

Processor = Callable[[dict[str, Any]], Any]
# Per-step skill weights: (control step, the step's raw sensed context) -> [1, S] weights of the fused prompt.
WeightSchedule = Callable[[int, np.ndarray], Tensor]


def auroc(hazardous: Sequence[float] | Tensor, safe: Sequence[float] | Tensor) -> float:
    """Area under the ROC curve of a risk score (higher = more hazardous): P(risk_h > risk_s), ties count 1/2."""
    h = torch.as_tensor(hazardous, dtype=torch.float64).flatten()
    s = torch.as_tensor(safe, dtype=torch.float64).flatten()
    if not len(h) or not len(s):
        raise ValueError(f"AUROC needs both classes, got {len(h)} hazardous and {len(s)} safe scores")
    scores = torch.cat([h, s])
    order = torch.argsort(scores)
    ranks = torch.empty_like(scores)
    ranks[order] = torch.arange(1, len(scores) + 1, dtype=torch.float64)
    for value in torch.unique(scores):  # average ranks of ties
        tie = scores == value
        if int(tie.sum()) > 1:
            ranks[tie] = ranks[tie].mean()
    u = ranks[: len(h)].sum() - len(h) * (len(h) + 1) / 2
    return float(u / (len(h) * len(s)))


def policy_processors(policy: Any, checkpoint: Any) -> tuple[Processor, Processor]:
    """The checkpoint's pre/post-processors, with observations moved to the device the policy runs on now (a
    checkpoint records the device it was trained on), as `lerobot-eval` does."""
    from lerobot.policies.factory import make_pre_post_processors

    overrides = {"device_processor": {"device": str(policy.config.device)}}
    return make_pre_post_processors(policy.config, pretrained_path=str(checkpoint), preprocessor_overrides=overrides)


def load_checkpoint(
    checkpoint: Path,
    weights: Path | None = None,
    kvm: dict[str, Any] | None = None,
    device: str = "cpu",
) -> tuple[Any, Processor, Processor]:
    """(policy, preprocessor, postprocessor) of a checkpoint of any LeRobot policy type, in eval mode on `device`:
    the weights from `weights` when given (the state a resumed run had reached), the processors always from
    `checkpoint`. `kvm`: settings over a `coda_kvm` checkpoint's own KVM config."""
    from dataclasses import replace

    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class

    from ..policy import CodaKvmPolicy  # importing it registers the `coda_kvm` config type

    config = PreTrainedConfig.from_pretrained(weights or checkpoint)
    config.device = device
    if isinstance(config, CodaKvmPolicy.config_class):
        policy_class = CodaKvmPolicy
        config.kvm = replace(config.kvm, **(kvm or {}))
    else:  # a peer: the LeRobot policy class of the checkpoint's own type
        policy_class = get_policy_class(config.type)
    policy = policy_class.from_pretrained(weights or checkpoint, config=config)
    policy.eval()
    pre, post = policy_processors(policy, checkpoint)
    return policy, pre, post


def skill_alone(policy: Any, index: int) -> Tensor:
    """[1, S] skill weights of a `coda_kvm` policy with one skill at 1 and every other at 0 (the skill forced
    alone), on the policy's device."""
    return torch.nn.functional.one_hot(torch.tensor([index]), policy.n_skills).float().to(policy.config.device)


def observation_batch(observation: dict[str, Any], task: str) -> dict[str, Any]:
    """One environment observation in LeRobot's policy format (before the policy's preprocessor)."""
    from lerobot.envs.utils import preprocess_observation

    batch = preprocess_observation(observation)
    batch["task"] = [task]
    return batch


def outcome_of(info: dict[str, Any], trace: Any = None) -> str:
    """ "catastrophe", "success", "abstention" (neither, and the policy abstained safely at some step: every
    candidate skill was found invalid) or "failure"."""
    if info.get("catastrophe"):
        return "catastrophe"
    if info.get("is_success"):
        return "success"
    abstained = trace is not None and len(trace) and trace.summary()["abstention_steps"] > 0
    return "abstention" if abstained else "failure"


@torch.no_grad()
def run_attempt(
    policy: Any,
    env: Any,
    preprocessor: Processor,
    postprocessor: Processor,
    seed: int | None = None,
    max_steps: int | None = None,
    skill_weights: Tensor | WeightSchedule | None = None,
) -> dict[str, Any]:
    """One attempt of the policy: {"outcome", "steps", "catastrophe_kind", "trace", "contexts"} (trace: the KVM's
    record of the attempt, None for a policy without one; contexts [steps, C]: the raw sensed context of every
    observation the policy acted on). `skill_weights` forces the fused prompt's skill weights (a `coda_kvm` policy;
    the KVM is then not consulted): [1, S] for the whole attempt, or a schedule giving them per step (a change of
    weights drops the queued actions, so the new mix acts at once)."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    steps = 0
    limit = max_steps or env._max_episode_steps
    contexts = []
    in_force = None
    for steps in range(1, limit + 1):  # noqa: B007
        contexts.append(np.asarray(obs["context"], dtype=np.float64))
        weights = skill_weights(steps - 1, contexts[-1]) if callable(skill_weights) else skill_weights
        if in_force is not None and weights is not None and not torch.equal(weights, in_force):
            policy.reset()
        in_force = weights
        batch = preprocessor(observation_batch(obs, env.task_description))
        with torch.inference_mode():
            action = policy.select_action(batch, **({} if weights is None else {"skill_weights": weights}))
        action = postprocessor(action)
        obs, _, terminated, truncated, info = env.step(action[0].cpu().numpy())
        if terminated or truncated:
            break
    trace = policy.kvm_trace() if hasattr(policy, "kvm_trace") else None
    return {
        "outcome": outcome_of(info, trace),
        "steps": steps,
        "catastrophe_kind": info.get("catastrophe_kind", ""),
        "trace": trace,
        "contexts": np.stack(contexts),
    }


def expert_rollout(
    env: Any, skill: str, preprocessor: Processor, seed: int | None = None, policy_skill: str | None = None
) -> tuple[dict[str, Any], str]:
    """Run the scenario's scripted expert for `skill`; returns (demonstration in the policy's input format with
    normalized actions, outcome). `policy_skill` names the policy skill the demonstration shows, if known. The
    demonstration's "first_contact" is the index of its first step sensed while the robot touches something
    (0 when it holds a tool from the start; its length if it never touches anything)."""
    from ..envs.physics import holds_tool, robot_geom_mask, robot_in_contact

    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    robot = robot_geom_mask(env.model)
    first_contact = 0 if holds_tool(env.model) else None
    steps = []
    for _ in range(env._max_episode_steps):
        action = np.asarray(expert.act(env.physics), dtype=np.float32)
        batch = observation_batch(obs, env.task_description)
        batch["action"] = torch.from_numpy(action).unsqueeze(0)
        steps.append(preprocessor(batch))
        obs, _, terminated, truncated, info = env.step(action)
        if first_contact is None and robot_in_contact(env.data, robot):
            first_contact = len(steps)
        if terminated or truncated:
            break
    demo = make_demonstration(steps, skill=policy_skill)
    demo["first_contact"] = len(steps) if first_contact is None else first_contact
    return demo, outcome_of(info)


def trace_from_demonstration(demo: dict[str, Any], context_key: str = "observation.context") -> KvmTrace:
    """A one-environment trace of an externally driven attempt (e.g. the prior skill's expert on a shifted
    variant): contexts, tasks, actions and observations, without KVM assessments (as if the KVM was off)."""
    steps = demo["action"].shape[0]
    obs_keys = [k for k in demo if k.startswith("observation.") and isinstance(demo[k], Tensor)]
    return KvmTrace(
        tasks=[[t] for t in demo["task"]],
        contexts=[demo[context_key][t : t + 1] for t in range(steps)],
        actions=[demo["action"][t : t + 1] for t in range(steps)],
        telemetry=[None] * steps,
        observations=[{k: demo[k][t : t + 1] for k in obs_keys} for t in range(steps)],
    )


def context_validity(policy: Any, demos: Sequence[dict[str, Any]], skill: int) -> Tensor:
    """v of `skill` at every step of the given demonstrations/rollouts (gate bypassed), concatenated."""
    values = []
    for demo in demos:
        batch = {k: v for k, v in demo.items() if k.startswith("observation.")}
        batch["task"] = demo["task"]
        values.append(policy.kvm_validity(batch)[:, skill])
    return torch.cat(values)


@torch.no_grad()
def gate_rate(policy: Any, demos: Sequence[dict[str, Any]]) -> float:
    """Share of the steps of the given demonstrations/rollouts on which the smart gate would open."""
    opened = total = 0
    kvm = policy.kvm
    for demo in demos:
        c_raw = kvm.raw_context(demo[policy.config.context_key], policy.encode_query(demo["task"]))
        _, sigma2, _ = kvm.encode(c_raw)
        opened += int(kvm.gate_open(sigma2).sum())
        total += len(sigma2)
    return opened / max(total, 1)


def pretrain_kvm(
    policy: Any, data: dict[str, Any], steps: int, batch_size: int = 32, lr: float = 1e-3, where: Tensor | None = None
) -> dict[str, float]:
    """Offline KVM learning alone (the KVM term of `forward()`), on `frame_contexts` rows (optionally a subset)."""
    rows = torch.nonzero(where).flatten() if where is not None else torch.arange(len(data["task"]))
    optimizer = torch.optim.AdamW(policy.kvm.learnable_parameters(), lr=lr, weight_decay=0.0)
    info: dict[str, float] = {}
    with torch.enable_grad():
        for _ in range(steps):
            idx = rows[torch.randint(len(rows), (batch_size,))]
            batch = {
                "observation.context": data["observation.context"][idx],
                "episode_index": data["episode_index"][idx],
                "task": [data["task"][i] for i in idx.tolist()],
            }
            loss, info = policy.kvm_learn_offline(batch)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return info


def recorded_frames(root: Any, repo_id: str, policy_config: Any) -> dict[str, Any]:
    """Every frame of a small recorded dataset, with the action chunks `policy_config` trains on, decoded once
    (a few hundred frames) so that training can draw batches without decoding video again."""
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    meta = LeRobotDataset(repo_id, root=root).meta
    dataset = LeRobotDataset(repo_id, root=root, delta_timestamps=resolve_delta_timestamps(policy_config, meta))
    batches = list(torch.utils.data.DataLoader(dataset, batch_size=64, num_workers=0))
    keys = [k for k, v in batches[0].items() if isinstance(v, Tensor)]
    frames: dict[str, Any] = {k: torch.cat([b[k] for b in batches]) for k in keys}
    frames["task"] = [t for b in batches for t in b["task"]]
    frames["stats"] = meta.stats
    return frames


def frame_contexts(frames: dict[str, Any]) -> dict[str, Any]:
    """The sensed contexts of `recorded_frames`, normalized with the dataset's statistics (MEAN_STD, as the
    policy's preprocessor does), with their task strings and episode indices: what the KVM learns from offline."""
    stats = frames["stats"]["observation.context"]
    mean = torch.as_tensor(stats["mean"], dtype=torch.float32)
    std = torch.as_tensor(stats["std"], dtype=torch.float32)
    return {
        "observation.context": (frames["observation.context"].float() - mean) / (std + 1e-8),
        "episode_index": frames["episode_index"].reshape(-1).long(),
        "task": frames["task"],
    }


def train_on_frames(
    policy: Any, frames: dict[str, Any], preprocessor: Processor, steps: int, where: Tensor, batch_size: int = 32
) -> dict[str, float]:
    """`steps` optimizer steps of `forward()` on the `where` frames, with the policy's own optimizer preset and
    gradient clipping, as one `lerobot-train` stage runs them."""
    rows = torch.nonzero(where).flatten()
    groups = policy.get_optim_params()
    params = [p for group in groups for p in group["params"]]
    optimizer = policy.config.get_optimizer_preset().build(groups)
    info: dict[str, float] = {}
    policy.train()
    with torch.enable_grad():
        for _ in range(steps):
            idx = rows[torch.randint(len(rows), (batch_size,))]
            batch = {k: v[idx] for k, v in frames.items() if isinstance(v, Tensor)}
            batch["task"] = [frames["task"][i] for i in idx.tolist()]
            loss, info = policy.forward(preprocessor(batch))
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, policy.config.optimizer_grad_clip_norm)
            optimizer.step()
    policy.eval()
    return info
