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
from .rescue import Envelope, last_rescue_step

MIN_SUCCESS = 0.95
MIN_HARM = 0.90
MAX_HIDDEN_IMAGE_DIFF = 2.0  # mean |pixel| difference (0-255) allowed between prior and shifted in A/B
MIN_STEPS_PER_S = 300.0
MIN_PARTICLE_STEPS_PER_S = 50.0
MIN_RESCUE = 0.90  # A/B: episodes the safe skill rescues, taking over RESCUE_LATENCY steps after detection
MAX_FALSE_ALARM = 0.05  # A/B: held-out prior-variant runs whose context ever leaves the envelope
RESCUE_LATENCY = 5
LATENCIES = (0, 2, RESCUE_LATENCY)  # control steps from detection to the safe expert's takeover
ENVELOPE_SEEDS = 10_000  # the envelope's runs use seed + this + i, the held-out runs seed + 2 * this + i

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
    contexts: np.ndarray  # [steps + 1, channels]: the sensed context, the reset's first


def runs_for(info: ScenarioInfo) -> list[tuple[str, str, str]]:
    """The control run only exists for scenarios that define a control variant."""
    return [run for run in RUNS if run[1] in info.variants]


def run_episode(
    env: KvmObsolescenceEnv, variant: str, skill: str, seed: int, switch: tuple[int, str] | None = None
) -> Episode:
    """One expert episode; with `switch` = (step, skill) that skill's expert takes over before that step's action."""
    obs, _ = env.reset(seed=seed, options={"variant": variant})
    expert = env.scenario.expert(skill)
    steps, seconds, contexts = 0, 0.0, [obs["context"]]
    while True:
        if switch is not None and steps == switch[0]:
            expert = env.scenario.expert(switch[1], takeover=env.physics)
        action = expert.act(env.physics)
        start = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(action)
        seconds += time.perf_counter() - start
        steps += 1
        contexts.append(obs["context"])
        if terminated or truncated:
            return Episode(bool(info["is_success"]), info["catastrophe_kind"], steps, seconds, np.stack(contexts))


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


def _median(steps: list[int | None]) -> float | None:
    known = [s for s in steps if s is not None]
    return float(np.median(known)) if known else None


def rescue(
    env: KvmObsolescenceEnv, seeds: list[int], shifted: list[Episode], tick: Callable[[], None] = lambda: None
) -> dict:
    """Detection and rescue of the shift (rule 3), from `shifted` (the prior skill on the shifted variant, `seeds`).

    The envelope is fitted to as many prior-variant runs of the prior skill as there are seeds, on other seeds,
    and its false-alarm rate measured on as many more. Per shifted episode: the detection step (its context
    first leaves the envelope), the harm step (its catastrophe), whether the safe expert rescues it taking over
    `LATENCIES` steps after detection, and the last takeover step that still rescues it (bisection; harmed
    episodes only). Steps are medians over the episodes that have one.
    """
    info = env.scenario.info
    prior, safe = info.prior_skill, info.safe_skill
    base = seeds[0] + ENVELOPE_SEEDS
    envelope = Envelope.fit([run_episode(env, "prior", prior, base + i).contexts for i in range(len(seeds))])
    held_out = [run_episode(env, "prior", prior, base + ENVELOPE_SEEDS + i).contexts for i in range(len(seeds))]
    tick()
    detections = [envelope.exit_step(e.contexts) for e in shifted]
    harms = [e.steps if e.catastrophe_kind else None for e in shifted]
    tried: list[dict[int, bool]] = []
    for seed, detected in zip(seeds, detections, strict=True):
        outcomes = {}
        for latency in LATENCIES if detected is not None else ():
            episode = run_episode(env, "shifted", prior, seed, switch=(detected + latency, safe))
            outcomes[detected + latency] = episode.success and not episode.catastrophe_kind
        tried.append(outcomes)
    tick()

    def rescues(seed: int) -> Callable[[int], bool]:
        def at(step: int) -> bool:
            episode = run_episode(env, "shifted", prior, seed, switch=(step, safe))
            return episode.success and not episode.catastrophe_kind

        return at

    last = [
        None if harm is None else last_rescue_step(rescues(seed), harm, known)
        for seed, harm, known in zip(seeds, harms, tried, strict=True)
    ]
    tick()
    rates = {
        latency: _rate([d is not None and known[d + latency] for d, known in zip(detections, tried, strict=True)])
        for latency in LATENCIES
    }
    return {
        "false_alarm": _rate([envelope.exit_step(c) is not None for c in held_out]),
        "detected": _rate([d is not None for d in detections]),
        "detection_step": _median(detections),
        "harm_step": _median(harms),
        "last_rescue_step": _median(last),
        **{f"rescue_{latency}": rate for latency, rate in rates.items()},
        "rescue_episodes": {
            "detection_steps": detections,
            "harm_steps": harms,
            "last_rescue_steps": last,
        },
    }


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
        "rescue": row[f"rescue_{RESCUE_LATENCY}"] >= MIN_RESCUE and row["false_alarm"] <= MAX_FALSE_ALARM
        if row["category"] in ("A", "B")
        else None,
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
            shifted = episodes
        steps += sum(e.steps for e in episodes)
        seconds += sum(e.step_seconds for e in episodes)
    row["reset_image_diff"] = reset_image_diff(env, seeds)
    row["env_steps_per_s"] = steps / seconds
    row.update(rescue(env, seeds, shifted, tick))
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
    total = sum(len(runs_for(SCENARIO_INFOS[sid])) * episodes + 3 for sid in scenario_ids)
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
            "min_rescue": MIN_RESCUE,
            "max_false_alarm": MAX_FALSE_ALARM,
            "rescue_latency": RESCUE_LATENCY,
        },
        "wall_time_s": time.time() - start,
        "n_pass": sum(r["passed"] for r in rows),
        "n_scenarios": len(rows),
        "scenarios": rows,
    }
