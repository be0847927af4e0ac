"""A stage's checkpoint chosen by what its skill does in closed loop.

A skill learned by imitation solves its task at some checkpoints of a run and not at others: the force-limited
pull of one stage run solved 2, 30, 30 and 14 of 30 stuck drawers at steps 200, 300, 400 and 500, and the training
loss does not show it (docs/measurements.md, "A stage's checkpoint chosen by its rollouts"). A stage therefore
saves checkpoints along its run, and the sequence goes on from the one whose skill, run alone on the stage's own
recorded task, solves most held-out episodes, as imitation-learning benchmarks select checkpoints by rollouts.
Only the recorded task's environment is used: no shifted variant the recording did not see.

A stage whose best checkpoint solves fewer than `LEARNED_SHARE` of those episodes has not learned its skill yet
(`learned`); the sequence may train it on (`MethodSpec.max_steps_per_stage`), and the checkpoints the longer run
adds are scored the same way and compete with the earlier ones.
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
# A skill counts as learned when it solves this share of its selection episodes alone: the per-skill target of the
# forced-skill matrix (DESIGN §3, every skill forced alone solves at least 90 % of its own variant's episodes).
LEARNED_SHARE = 0.9


def trained_steps(run_dir: Path) -> int:
    """Steps of the newest checkpoint a `lerobot-train` run has finished writing (0 before its first): LeRobot points
    `checkpoints/last` at a checkpoint once it is written."""
    last = run_dir / "checkpoints" / "last"
    return int(last.resolve().name) if last.exists() else 0


def saved_checkpoints(run_dir: Path) -> list[Path]:
    """The `pretrained_model` directories a `lerobot-train` run saved, in step order, up to its newest finished
    one (a later one may be half-written by a killed run)."""
    newest = trained_steps(run_dir)
    steps = [p for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit() and int(p.name) <= newest]
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
    run_dir: Path,
    scenario: str,
    variant: str,
    instruction: str,
    skill: str,
    episodes: int,
    device: str = "cpu",
    scored: Sequence[dict[str, Any]] = (),
) -> dict[str, Any]:
    """Every saved checkpoint of a stage run scored on the stage's task, and the one selected:
    {"checkpoints": [{"step", "success", "catastrophe", "episodes"}], "selected": step directory name}.
    `scored`: entries of an earlier choice on this run (its "checkpoints"), reused for the steps they name."""
    known = {entry["step"]: entry for entry in scored}
    checkpoints = saved_checkpoints(run_dir)
    entries = [
        known.get(c.parent.name)
        or {"step": c.parent.name, **rollout_score(c, scenario, variant, instruction, skill, episodes, device)}
        for c in checkpoints
    ]
    best = select_checkpoint(entries)
    return {"checkpoints": entries, "selected": checkpoints[best].parent.name, "seed": SELECTION_SEED}


def learned(choice: dict[str, Any]) -> bool:
    """The selected checkpoint of a choice (`choose_stage_checkpoint`) solves at least `LEARNED_SHARE` of its
    selection episodes."""
    entry = next(e for e in choice["checkpoints"] if e["step"] == choice["selected"])
    return entry["success"] >= LEARNED_SHARE * entry["episodes"]
