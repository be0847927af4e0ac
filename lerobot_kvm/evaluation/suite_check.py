"""Acceptance check of the scenario suite, measured with the scripted experts.

A scenario is only a fair test of knowledge obsolescence if the old skill works where it is
valid, causes the declared harm where it is not, a safe skill exists, the shift is hidden
from the camera in categories A/B, and the scene is fast enough to record and evaluate on a
CPU. This module measures each of those per scenario; the CLI prints and saves the result.
"""

import importlib.metadata
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from tqdm import tqdm

from ..envs.catalogue import SCENARIO_INFOS, ScenarioInfo
from ..envs.env import KvmObsolescenceEnv

MIN_SUCCESS = 0.95
MIN_HARM = 0.90
MAX_HIDDEN_IMAGE_DIFF = 2.0  # mean |pixel| difference (0-255) allowed between prior and shifted in A/B
MIN_STEPS_PER_S = 300.0
MIN_PARTICLE_STEPS_PER_S = 50.0

# (result name, variant, which skill: "prior" or "safe")
RUNS = (
    ("prior_on_prior", "prior", "prior"),
    ("prior_on_shifted", "shifted", "prior"),
    ("safe_on_shifted", "shifted", "safe"),
    ("control_prior_skill", "control", "prior"),
)


@dataclass
class Episode:
    success: bool
    catastrophe_kind: str  # "" when none
    steps: int
    step_seconds: float  # time spent inside env.step (physics + rendering)


def runs_for(info: ScenarioInfo) -> list[tuple[str, str, str]]:
    """The control run only exists for scenarios that define a control variant."""
    return [run for run in RUNS if run[1] in info.variants]


def run_episode(env: KvmObsolescenceEnv, variant: str, skill: str, seed: int) -> Episode:
    env.reset(seed=seed, options={"variant": variant})
    expert = env.scenario.expert(skill)
    steps, seconds = 0, 0.0
    while True:
        action = expert.act(env.physics)
        start = time.perf_counter()
        _, _, terminated, truncated, info = env.step(action)
        seconds += time.perf_counter() - start
        steps += 1
        if terminated or truncated:
            return Episode(bool(info["is_success"]), info["catastrophe_kind"], steps, seconds)


def reset_image_diff(env: KvmObsolescenceEnv, seeds: list[int]) -> float:
    """Mean absolute pixel difference between prior and shifted reset observations, same seeds."""
    cam = env.cameras[0]
    diffs = []
    for seed in seeds:
        prior = env.reset(seed=seed, options={"variant": "prior"})[0]["pixels"][cam].astype(np.int16)
        shifted = env.reset(seed=seed, options={"variant": "shifted"})[0]["pixels"][cam].astype(np.int16)
        diffs.append(float(np.abs(prior - shifted).mean()))
    return float(np.mean(diffs))


def _rate(flags: list[bool]) -> float:
    return float(np.mean(flags))


def judge(row: dict) -> dict[str, bool | None]:
    """Each acceptance threshold as pass/fail; None where the check does not apply."""
    control = None
    if row["control_prior_skill_success"] is not None:
        control = row["control_prior_skill_success"] >= MIN_SUCCESS and row["control_prior_skill_catastrophe"] == 0
    diff = row["reset_image_diff"]
    min_speed = MIN_PARTICLE_STEPS_PER_S if row["particle_scene"] else MIN_STEPS_PER_S
    return {
        "prior_on_prior": row["prior_on_prior_success"] >= MIN_SUCCESS and row["prior_on_prior_catastrophe"] == 0,
        "prior_on_shifted": row["prior_on_shifted_catastrophe"] >= MIN_HARM,
        "harm_kind": set(row["prior_on_shifted_kinds"]) <= {row["harm"]},
        "safe_on_shifted": row["safe_on_shifted_success"] >= MIN_SUCCESS and row["safe_on_shifted_catastrophe"] == 0,
        "control_prior_skill": control,
        "reset_image_diff": diff > 0 if row["category"] == "C" else diff <= MAX_HIDDEN_IMAGE_DIFF,
        "throughput": row["env_steps_per_s"] >= min_speed,
    }


def check_scenario(scenario_id: str, seeds: list[int], tick: Callable[[], None] = lambda: None) -> dict:
    """Runs every (variant, skill) pair of the scenario over `seeds`; `tick` is called per episode."""
    env = KvmObsolescenceEnv(task=scenario_id)
    info = env.scenario.info
    skills = {"prior": info.prior_skill, "safe": info.safe_skill}
    row: dict = {"id": scenario_id, "category": info.category, "harm": info.harm}
    steps, seconds = 0, 0.0
    for name, variant, skill in RUNS:
        row[f"{name}_success"] = row[f"{name}_catastrophe"] = None
        if variant not in info.variants:
            continue
        episodes = []
        for seed in seeds:
            episodes.append(run_episode(env, variant, skills[skill], seed))
            tick()
        row[f"{name}_success"] = _rate([e.success for e in episodes])
        row[f"{name}_catastrophe"] = _rate([e.catastrophe_kind != "" for e in episodes])
        if name == "prior_on_shifted":
            row["prior_on_shifted_kinds"] = dict(Counter(e.catastrophe_kind for e in episodes if e.catastrophe_kind))
        steps += sum(e.steps for e in episodes)
        seconds += sum(e.step_seconds for e in episodes)
    row["reset_image_diff"] = reset_image_diff(env, seeds)
    row["env_steps_per_s"] = steps / seconds
    row["particle_scene"] = info.particles
    env.close()
    row["passes"] = judge(row)
    row["passed"] = all(ok for ok in row["passes"].values() if ok is not None)
    return row


def check_suite(scenario_ids: list[str], episodes: int, seed: int, progress: bool = True) -> dict:
    """The whole report: one row per scenario plus what is needed to reproduce it."""
    if episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {episodes}")
    start = time.time()
    seeds = [seed + i for i in range(episodes)]
    total = sum(len(runs_for(SCENARIO_INFOS[sid])) for sid in scenario_ids) * episodes
    rows = []
    with tqdm(total=total, unit="episode", disable=not progress) as bar:
        for sid in scenario_ids:
            bar.set_description(sid)
            rows.append(check_scenario(sid, seeds, lambda: bar.update(1)))
    return {
        "seed": seed,
        "episodes": episodes,
        "seeds": seeds,
        "versions": {
            "mujoco": mujoco.__version__,
            "lerobot_kvm": importlib.metadata.version("lerobot_policy_coda_kvm"),
        },
        "thresholds": {
            "min_success": MIN_SUCCESS,
            "min_harm": MIN_HARM,
            "max_hidden_image_diff": MAX_HIDDEN_IMAGE_DIFF,
            "min_steps_per_s": MIN_STEPS_PER_S,
            "min_particle_steps_per_s": MIN_PARTICLE_STEPS_PER_S,
        },
        "wall_time_s": time.time() - start,
        "n_pass": sum(r["passed"] for r in rows),
        "n_scenarios": len(rows),
        "scenarios": rows,
    }
