"""A stage's checkpoint chosen by what its skill does in closed loop.

A skill learned by imitation solves its task at some checkpoints of a run and not at others: the force-limited
pull of one stage run solved 2, 30, 30 and 14 of 30 stuck drawers at steps 200, 300, 400 and 500, and the training
loss does not show it (docs/measurements.md, "A stage's checkpoint chosen by its rollouts"). A stage therefore
saves checkpoints along its run, and the sequence goes on from the one whose skill, run alone on the stage's own
recorded task, solves most held-out episodes, as imitation-learning benchmarks select checkpoints by rollouts.
Only the recorded task's environment is used: no shifted variant the recording did not see.
"""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..envs.env import KvmObsolescenceEnv
from ..policy.feedback import skill_by_name
from .rollouts import load_checkpoint, run_attempt, skill_alone

# Selection episodes start here: apart from the recording (0..), the sequence's evaluation (100000..), the
# benchmark (200000..) and the forced-skill matrix (300000..).
SELECTION_SEED = 500_000


def saved_checkpoints(run_dir: Path) -> list[Path]:
    """The `pretrained_model` directories a `lerobot-train` run saved, in step order."""
    steps = [p for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit()]
    return [p / "pretrained_model" for p in sorted(steps, key=lambda p: int(p.name))]


def rollout_score(
    checkpoint: Path,
    scenario: str,
    variant: str,
    instruction: str,
    skill: str,
    episodes: int,
    device: str = "cpu",
) -> dict[str, int]:
    """{"success", "catastrophe", "episodes"} of a checkpoint on one task: a `coda_kvm` checkpoint with the KVM
    off and the fused prompt forced to `skill` alone (the skill must work alone), any other policy as it is."""
    policy, pre, post = load_checkpoint(checkpoint, kvm={"enabled": False}, device=device)
    weights = None
    if hasattr(policy, "skills"):
        index = skill_by_name(policy, skill)
        if index is None:
            raise ValueError(f"{checkpoint} has no skill {skill!r}")
        weights = skill_alone(policy, index)
    env = KvmObsolescenceEnv(scenario, variant=variant, instruction=instruction)
    try:
        outcomes = [
            run_attempt(policy, env, pre, post, seed=SELECTION_SEED + e, skill_weights=weights)["outcome"]
            for e in range(episodes)
        ]
    finally:
        env.close()
    return {"success": outcomes.count("success"), "catastrophe": outcomes.count("catastrophe"), "episodes": episodes}


def select_checkpoint(scores: Sequence[dict[str, int]]) -> int:
    """Index of the best of checkpoints in step order: most successes, then fewest catastrophes, then the later
    (the longer trained) checkpoint."""
    if not scores:
        raise ValueError("no checkpoint to select from")
    return max(range(len(scores)), key=lambda i: (scores[i]["success"], -scores[i]["catastrophe"], i))


def choose_stage_checkpoint(
    run_dir: Path, scenario: str, variant: str, instruction: str, skill: str, episodes: int, device: str = "cpu"
) -> dict[str, Any]:
    """Every saved checkpoint of a stage run scored on the stage's task, and the one selected:
    {"checkpoints": [{"step", "success", "catastrophe", "episodes"}], "selected": step directory name}."""
    checkpoints = saved_checkpoints(run_dir)
    scores = [rollout_score(c, scenario, variant, instruction, skill, episodes, device) for c in checkpoints]
    best = select_checkpoint(scores)
    return {
        "checkpoints": [{"step": c.parent.name, **s} for c, s in zip(checkpoints, scores, strict=True)],
        "selected": checkpoints[best].parent.name,
        "seed": SELECTION_SEED,
    }
