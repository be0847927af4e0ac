"""Record scripted-expert episodes into a LeRobotDataset v3 (PNG frames in parquet).

Recording goes to a temporary sibling directory that is moved into place only after
`finalize()`, so an interrupted or failed run never leaves a half-written dataset at the
target root.
"""

import json
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tqdm import tqdm

import datasets as hf_datasets

from ..envs.catalogue import scenario_info
from ..envs.configuration_kvm_obsolescence import OBS_CONTEXT
from ..envs.env import KvmObsolescenceEnv
from ..envs.sensing import ACTION_NAMES, STATE_NAMES, context_names
from .json_config import build, build_list, check_counts, read_json
from .labels import LABELS_FILE
from .ownership import process_alive

OUTCOMES = ("success", "failure", "catastrophe")
# Per action channel (x, y, z in m, pitch in rad, grip command), the executed-action noise's standard deviation
# relative to `RecordingSpec.action_noise`: the angle and the grip span about ten times the metres of a position.
NOISE_SCALE = np.array([1.0, 1.0, 1.0, 10.0, 10.0], dtype=np.float32)
LABEL_KEYS = ("label.skill", "label.scenario", "label.variant", "label.outcome")


@dataclass
class RecordItem:
    """Episodes of one expert skill on one scenario variant.

    `instruction`: "variant" records the env's own instruction for the variant (what a
    benchmark attempt will say); "skill" records the instruction that asks for the skill
    explicitly (e.g. "gently pick up the stone").
    """

    scenario: str
    variant: str
    skill: str
    episodes: int
    instruction: str = "variant"

    def __post_init__(self) -> None:
        info = scenario_info(self.scenario)
        if self.variant not in info.variants:
            raise ValueError(f"{self.scenario}: unknown variant {self.variant!r} (have {list(info.variants)})")
        if self.skill not in (info.prior_skill, info.safe_skill):
            raise ValueError(
                f"{self.scenario}: unknown skill {self.skill!r} (have {info.prior_skill!r}, {info.safe_skill!r})"
            )
        if self.instruction not in ("variant", "skill"):
            raise ValueError(f"instruction must be 'variant' or 'skill', got {self.instruction!r}")
        check_counts(self, {"episodes": 1})

    def task_string(self) -> str:
        info = scenario_info(self.scenario)
        return info.instructions[self.variant] if self.instruction == "variant" else info.skill_instructions[self.skill]


@dataclass
class RecordingSpec:
    name: str
    items: list[RecordItem]
    seed: int = 0
    fps: int = 20
    image_size: int = 96
    keep_failures: bool = False  # expert episodes that fail are dropped unless kept as negatives
    # Standard deviation (m; see NOISE_SCALE) of Gaussian noise added to every action the expert sends to the
    # robot, while the frame keeps the expert's own action as the label: the data shows how the expert recovers
    # from the imprecision a learned policy has, and the KVM's safe experience covers the contexts it causes. A
    # seed whose noisy episode fails is recorded again without noise (a pinch or a drawn line tolerates none).
    action_noise: float = 0.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.items:
            raise ValueError("a recording spec needs at least one item")
        check_counts(self, {"fps": 1, "image_size": 1})  # before the temporary dataset is created
        if not 0.0 <= self.action_noise < 0.05:
            raise ValueError(f"action_noise must be in [0, 0.05) m, got {self.action_noise}")

    @classmethod
    def from_json(cls, path: str | Path) -> "RecordingSpec":
        raw = read_json(path)
        raw["items"] = build_list(RecordItem, raw, "items", str(path))
        return build(cls, raw, str(path))

    def vocab(self) -> dict[str, list[str]]:
        return {
            "skill": sorted({it.skill for it in self.items}),
            "scenario": sorted({it.scenario for it in self.items}),
            "variant": sorted({it.variant for it in self.items}),
            "outcome": list(OUTCOMES),
        }


def dataset_features(image_size: int) -> dict:
    scalar = {"dtype": "int64", "shape": (1,), "names": None}
    names = context_names()
    return {
        "observation.images.front": {
            "dtype": "image",
            "shape": (image_size, image_size, 3),
            "names": ["height", "width", "channels"],
        },
        "observation.state": {"dtype": "float32", "shape": (len(STATE_NAMES),), "names": list(STATE_NAMES)},
        OBS_CONTEXT: {"dtype": "float32", "shape": (len(names),), "names": list(names)},
        "action": {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": list(ACTION_NAMES)},
        **{key: dict(scalar) for key in LABEL_KEYS},
    }


def _run_episode(env: KvmObsolescenceEnv, skill: str, seed: int, noise: float = 0.0) -> tuple[list[dict], str]:
    """One expert episode; with `noise`, the robot executes the expert's action plus noise (its own stream, drawn
    from the episode seed) and the frame records the expert's action."""
    obs, _ = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    rng = np.random.default_rng([seed, 1])
    frames = []
    info: dict = {}
    for _ in range(env._max_episode_steps):
        action = expert.act(env.physics).astype(np.float32)
        frames.append(
            {
                "observation.images.front": obs["pixels"]["front"],
                "observation.state": obs["agent_pos"],
                OBS_CONTEXT: obs["context"],
                "action": action,
            }
        )
        if noise > 0:
            action = action + rng.normal(0.0, noise, action.shape).astype(np.float32) * NOISE_SCALE
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    outcome = "catastrophe" if info.get("catastrophe") else "success" if info.get("is_success") else "failure"
    return frames, outcome


def checked_root(root: str | Path, overwrite: bool) -> Path:
    """The absolute dataset root, refused before anything is written unless recording into it loses nothing.

    A new root is fine. An existing one is replaced only with `overwrite`, and only when this recorder made it
    (its labels file is the marker); never `/`, the home directory, the working directory or one of its parents.
    """
    path = Path(root).expanduser().resolve()
    cwd = Path.cwd().resolve()
    if path == Path(path.anchor) or path == Path.home().resolve() or cwd.is_relative_to(path):
        raise ValueError(f"dataset root {root!r} is {path}: refusing to record over a directory holding this one")
    if not path.exists():
        return path
    if not overwrite:
        raise FileExistsError(f"dataset root {path} already exists (pass --overwrite to replace a recorded dataset)")
    if not path.is_dir() or not (path / LABELS_FILE).is_file():
        raise FileExistsError(
            f"dataset root {path} exists and was not recorded by lerobot-kvm record (no {LABELS_FILE}): "
            "--overwrite replaces only a dataset this tool recorded"
        )
    return path


def _temporary(root: Path, pid: int) -> Path:
    """Where a recording into `root` is written before it moves into place: beside `root`, never inside it."""
    return root.parent / f".{root.name}.tmp-{pid}"


def remove_stale_temporaries(root: Path) -> list[Path]:
    """Remove the temporary roots that killed recordings into `root` left behind (their process is gone)."""
    removed = []
    for tmp in root.parent.glob(f".{root.name}.tmp-*"):
        pid = tmp.name.rpartition("-")[2]
        if tmp.is_dir() and pid.isdigit() and not process_alive(int(pid)):
            shutil.rmtree(tmp, ignore_errors=True)
            removed.append(tmp)
    return removed


def record_dataset(
    spec: RecordingSpec, root: str | Path, repo_id: str | None = None, overwrite: bool = False, progress: bool = True
) -> dict:
    """Record `spec` into `root`; returns a summary (episodes and outcomes per item)."""
    root = checked_root(root, overwrite)
    repo_id = repo_id or f"local/{spec.name}"
    vocab = spec.vocab()
    remove_stale_temporaries(root)
    tmp = _temporary(root, os.getpid())
    shutil.rmtree(tmp, ignore_errors=True)  # this process's own, from a recording it abandoned
    root.parent.mkdir(parents=True, exist_ok=True)
    summary: list[dict] = []
    episodes: list[dict] = []  # per kept episode: its labels, so trainers can map episode_index -> skill
    hf_datasets.disable_progress_bars()  # one bar per recording, not one per saved episode
    ds: LeRobotDataset | None = None
    try:
        ds = LeRobotDataset.create(
            repo_id=repo_id,
            fps=spec.fps,
            features=dataset_features(spec.image_size),
            root=tmp,
            use_videos=False,
        )
        episode_seed = spec.seed
        total = sum(it.episodes for it in spec.items)
        bar = tqdm(total=total, desc=f"recording {spec.name}", disable=not progress, unit="ep")
        for item in spec.items:
            env = KvmObsolescenceEnv(
                task=item.scenario,
                variant=item.variant,
                image_size=spec.image_size,
                fps=spec.fps,
            )
            counts = dict.fromkeys(OUTCOMES, 0)
            clean_reruns = 0
            task = item.task_string()
            labels = {
                "label.skill": vocab["skill"].index(item.skill),
                "label.scenario": vocab["scenario"].index(item.scenario),
                "label.variant": vocab["variant"].index(item.variant),
            }
            for _ in range(item.episodes):
                frames, outcome = _run_episode(env, item.skill, episode_seed, spec.action_noise)
                if outcome != "success" and spec.action_noise > 0:
                    frames, outcome = _run_episode(env, item.skill, episode_seed)
                    clean_reruns += 1
                episode_seed += 1
                counts[outcome] += 1
                bar.update()
                if outcome != "success" and not spec.keep_failures:
                    continue
                label_values = {**labels, "label.outcome": OUTCOMES.index(outcome)}
                episodes.append(
                    {
                        "episode_index": ds.num_episodes,
                        "scenario": item.scenario,
                        "variant": item.variant,
                        "skill": item.skill,
                        "outcome": outcome,
                        "task": task,
                        "seed": episode_seed - 1,
                    }
                )
                for frame in frames:
                    ds.add_frame(
                        {**frame, **{k: np.array([v], dtype=np.int64) for k, v in label_values.items()}, "task": task}
                    )
                ds.save_episode()
            env.close()
            summary.append({**asdict(item), "task": task, "outcomes": counts, "clean_reruns": clean_reruns})
        bar.close()
        if ds.num_episodes == 0:
            raise RuntimeError("no episode was kept: every expert episode failed")
        ds.finalize()
        (tmp / LABELS_FILE).write_text(
            json.dumps({"vocab": vocab, "spec": asdict(spec), "summary": summary, "episodes": episodes}, indent=2)
        )
        if root.exists():
            shutil.rmtree(root)
        os.replace(tmp, root)
    except BaseException:
        if ds is not None:  # close the writer first, or its finaliser re-creates files under tmp
            ds.finalize()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"root": str(root), "repo_id": repo_id, "episodes": ds.num_episodes, "items": summary}
