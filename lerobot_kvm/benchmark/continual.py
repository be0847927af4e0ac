"""A continual-learning sequence run through LeRobot's own CLIs.

One dataset is recorded for the whole sequence, so every stage is normalised with the same statistics; each
stage is a real `lerobot-train` run on that stage's episodes (`--dataset.episodes=[...]`), starting from the
previous stage's checkpoint (`--policy.path=...`). `coda_kvm` begins a new skill per stage (new CODA
components, earlier ones frozen); LeRobot's ACT and Diffusion Policy are fine-tuned the plain way. After every
stage each task learned so far is evaluated with the real `lerobot-eval`. A joint method trains once on every
task.

A sequence may begin with a pretraining stage on tasks outside the sequence (other scenarios), the counterpart
of the ImageNet-pretrained ViT that CODA-Prompt prompts: every method starts from its own pretraining on the
same episodes, and the pretraining tasks are never scored.

Finished stages and evaluations are kept on disk, so an interrupted run resumes where it stopped.
"""

import hashlib
import json
import platform
import shlex
import shutil
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from importlib import metadata
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from ..datasets.check import check_dataset
from ..datasets.json_config import build, build_list, check_counts, read_json
from ..datasets.labels import load_labels
from ..datasets.recorder import RecordingSpec, RecordItem, record_dataset
from ..envs.catalogue import scenario_info
from ..evaluation.checkpoint_selection import choose_stage_checkpoint, learned, saved_checkpoints, trained_steps
from .cl_metrics import cl_metrics, joint_metrics
from .lerobot_commands import eval_command, resume_command, run_logged, train_command
from .lock import hold
from .resume import check_settings

CHECKPOINT = Path("checkpoints") / "last" / "pretrained_model"
SELECTION = "selection.json"  # a stage's checkpoints scored by rollouts, and the one the sequence goes on from
TIMING = "timing.json"  # a stage's training wall time (every run of it), kept for runs that resume
POLICIES = ("coda_kvm", "act", "diffusion")  # LeRobot policy types a method may train
MODES = ("sequential", "joint")


@dataclass
class TaskSpec:
    """One task of the sequence: a scenario variant solved by its `prior` or `safe` expert skill, asked for by
    the variant's own instruction (`variant`) or by the instruction naming the skill (`skill`)."""

    scenario: str
    variant: str = "prior"
    skill: str = "prior"
    instruction: str = "variant"

    def __post_init__(self) -> None:
        if self.skill not in ("prior", "safe"):
            raise ValueError(f"task {self.scenario}: skill must be 'prior' or 'safe', got {self.skill!r}")
        self.record_item(1)  # unknown scenario, variant or instruction fail here, named in the message

    @property
    def expert_skill(self) -> str:
        info = scenario_info(self.scenario)
        return info.prior_skill if self.skill == "prior" else info.safe_skill

    @property
    def name(self) -> str:
        """The task's id, and the name of the CODA skill that learns it."""
        return f"{self.scenario}.{self.expert_skill}"

    @property
    def env_instruction(self) -> str:
        """`--env.instruction` that asks for this task the way it was recorded."""
        return "variant" if self.instruction == "variant" else self.skill

    def record_item(self, episodes: int) -> RecordItem:
        return RecordItem(self.scenario, self.variant, self.expert_skill, episodes, self.instruction)


@dataclass
class MethodSpec:
    """How one method learns the sequence: `policy` type, `sequential` stages or one `joint` run.

    `checkpoints_from` names an earlier sequential method whose stage checkpoints this one evaluates instead of
    training its own, with `eval_args` (e.g. `--policy.kvm.enabled=false`: the CODA-Prompt core of `coda_kvm`).
    """

    name: str
    policy: str = "coda_kvm"
    mode: str = "sequential"
    steps_per_stage: int = 500
    pretrain_steps: int = 0  # steps of the pretraining stage (when the sequence has pretraining tasks)
    batch_size: int = 32
    args: list[str] = field(default_factory=list)  # extra `lerobot-train` arguments for every stage
    later_stage_args: list[str] = field(default_factory=list)  # ... only for stages after the first
    eval_args: list[str] = field(default_factory=list)  # extra `lerobot-eval` arguments
    checkpoints_from: str | None = None
    # Steps between the checkpoints a stage saves; the sequence goes on from the one its skill solves most selection
    # episodes with (`evaluation.checkpoint_selection`). 0: from the stage's last checkpoint.
    select_every: int = 0
    # A stage whose selected checkpoint has not learned its skill (`evaluation.checkpoint_selection.learned`) trains
    # on from its last checkpoint, `steps_per_stage` more steps at a time, up to this many in all; the checkpoints
    # it adds are scored and compete with the earlier ones (docs/measurements.md, "A stage trained on until its
    # skill works alone"). 0: every stage trains `steps_per_stage` steps.
    max_steps_per_stage: int = 0

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"method {self.name}: policy must be one of {POLICIES}, got {self.policy!r}")
        if self.mode not in MODES:
            raise ValueError(f"method {self.name}: mode must be one of {MODES}, got {self.mode!r}")
        if self.checkpoints_from is not None and self.mode != "sequential":
            raise ValueError(f"method {self.name}: checkpoints_from needs mode 'sequential'")
        counts = {"steps_per_stage": 1, "batch_size": 1, "pretrain_steps": 0, "select_every": 0}
        check_counts(self, counts | {"max_steps_per_stage": 0})
        if self.select_every and (self.mode != "sequential" or self.checkpoints_from is not None):
            raise ValueError(f"method {self.name}: select_every needs a sequential method that trains its stages")
        if self.max_steps_per_stage and (not self.select_every or self.max_steps_per_stage < self.steps_per_stage):
            raise ValueError(
                f"method {self.name}: max_steps_per_stage ({self.max_steps_per_stage}) needs select_every and at "
                f"least steps_per_stage ({self.steps_per_stage}) steps"
            )
        for key in ("args", "later_stage_args", "eval_args"):  # a string would be passed on character by character
            value = getattr(self, key)
            if not isinstance(value, list) or not all(isinstance(a, str) for a in value):
                raise ValueError(f"{key} must be a list of command-line arguments (strings), got {value!r}")


@dataclass
class SequenceConfig:
    name: str
    tasks: list[TaskSpec]
    methods: list[MethodSpec]
    pretrain_tasks: list[TaskSpec] = field(default_factory=list)
    seed: int = 0
    episodes_per_task: int = 30
    pretrain_episodes_per_task: int = 20
    eval_episodes: int = 10
    eval_seed: int = 100_000  # far from the recording seeds: evaluation starts are held out
    select_episodes: int = 20  # episodes that score each saved checkpoint of a stage (methods with `select_every`)
    dataset_root: str | None = None
    action_noise: float = 0.0  # the recording's executed-action noise (`RecordingSpec.action_noise`)

    def __post_init__(self) -> None:
        # the recording's and evaluation's counts: refused here, not by the recorder after settings are written
        check_counts(
            self, {"episodes_per_task": 1, "pretrain_episodes_per_task": 1, "eval_episodes": 1, "select_episodes": 1}
        )
        if not self.tasks:
            raise ValueError("a sequence needs at least one task")
        names = [t.name for t in self.tasks]
        names += [t.name for t in self.pretrain_tasks]
        if len(set(names)) != len(names):
            raise ValueError(f"tasks and pretraining tasks must all be distinct, got {names}")
        for i, m in enumerate(self.methods):
            sources = {s.name: s for s in self.methods[:i] if s.mode == "sequential" and s.checkpoints_from is None}
            if m.checkpoints_from is not None and m.checkpoints_from not in sources:
                raise ValueError(
                    f"method {m.name}: checkpoints_from={m.checkpoints_from!r} must name an earlier sequential "
                    f"method that trains, one of {sorted(sources)}"
                )
        trained = [m for m in self.methods if m.checkpoints_from is None]
        if self.pretrain_tasks and not all(m.pretrain_steps for m in trained):
            raise ValueError("the sequence has pretraining tasks: every method needs pretrain_steps >= 1")
        if not self.methods or len({m.name for m in self.methods}) != len(self.methods):
            raise ValueError("a sequence needs at least one method, with distinct names")

    @classmethod
    def from_json(cls, path: str | Path) -> "SequenceConfig":
        raw = read_json(path)
        for key, spec in (("tasks", TaskSpec), ("pretrain_tasks", TaskSpec), ("methods", MethodSpec)):
            if key in raw:
                raw[key] = build_list(spec, raw, key, str(path))
        return build(cls, raw, str(path))

    @property
    def repo_id(self) -> str:
        return f"local/kvm_cl_{self.name}"

    def recording_spec(self) -> RecordingSpec:
        items = [t.record_item(self.pretrain_episodes_per_task) for t in self.pretrain_tasks]
        items += [t.record_item(self.episodes_per_task) for t in self.tasks]
        return RecordingSpec(name=f"kvm_cl_{self.name}", items=items, seed=self.seed, action_noise=self.action_noise)


def task_episodes(dataset_root: Path, tasks: Sequence[TaskSpec]) -> list[list[int]]:
    """The dataset's episode indices of each task, from the recorder's labels."""
    episodes = load_labels(dataset_root)["episodes"]
    out = []
    for task in tasks:
        text = task.record_item(1).task_string()
        mine = [
            e["episode_index"]
            for e in episodes
            if (e["scenario"], e["variant"], e["skill"], e["task"])
            == (task.scenario, task.variant, task.expert_skill, text)
        ]
        if not mine:
            raise ValueError(f"dataset {dataset_root} has no episode of task {task.name}")
        out.append(mine)
    return out


def finished(run_dir: Path, steps: int) -> bool:
    """A `lerobot-train` run saved its checkpoint at `steps` steps or a later one (a stage that trained on)."""
    return trained_steps(run_dir) >= steps


def stage_checkpoint(stage_dir: Path, selected: bool) -> Path:
    """The checkpoint a trained stage hands on: its selected one (`SELECTION`), or its last. A path that does not
    exist while the stage is not trained, or its checkpoint not selected, yet."""
    if not selected:
        return stage_dir / "train" / CHECKPOINT
    path = stage_dir / SELECTION
    if not path.exists():
        return path
    return stage_dir / "train" / "checkpoints" / json.loads(path.read_text())["selected"] / "pretrained_model"


def _all_episodes(per_task: list[list[int]]) -> list[int]:
    return sorted(e for episodes in per_task for e in episodes)


def _versions() -> dict[str, str]:
    names = ("lerobot", "torch", "mujoco", "lerobot_policy_coda_kvm")
    found = {}
    for name in names:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return {"python": platform.python_version(), **found}


class ContinualRun:
    """Runs (or resumes) every method of a `SequenceConfig` under `output_dir`."""

    def __init__(
        self,
        config: SequenceConfig,
        output_dir: Path,
        launcher: Sequence[str] = (),
        config_path: str = "",
        only: Sequence[str] | None = None,
        device: str = "cpu",
    ) -> None:
        """`only`: names of the methods to run now; the results of the others, if an earlier invocation finished
        them, are kept in `cl_results.json`. `device`: where every `lerobot-train` and `lerobot-eval` runs the
        policy."""
        if only is not None:
            unknown = sorted(set(only) - {m.name for m in config.methods})
            if unknown:
                raise ValueError(f"unknown methods {unknown}; the config has {[m.name for m in config.methods]}")
        try:  # a misspelt device would be kept in settings.json, and the rerun with the right one refused
            torch.device(device)
        except RuntimeError as err:
            raise ValueError(f"device {device!r} is not a torch device ({err})") from None
        self.config = config
        self.methods = [m for m in config.methods if only is None or m.name in only]
        self.out = Path(output_dir)
        self.launcher = list(launcher)
        self.device = device
        self.config_path = config_path
        self.dataset_root = Path(config.dataset_root or f"datasets/kvm_cl_{config.name}")
        self.results_path = self.out / "cl_results.json"

    def final_checkpoint(self, method_name: str) -> Path:
        """The checkpoint a method ends the sequence with (its last stage's, or its joint run's)."""
        method = next((m for m in self.config.methods if m.name == method_name), None)
        if method is None:
            raise ValueError(f"unknown method {method_name!r}; the config has {[m.name for m in self.config.methods]}")
        owner = self._owner(method)
        last = len(self.config.tasks) - 1
        stage = self.out / owner.name / "joint" if method.mode == "joint" else self._stage_dir(owner.name, last)
        checkpoint = stage_checkpoint(stage, bool(owner.select_every))
        if not checkpoint.exists():
            raise FileNotFoundError(f"{checkpoint} missing: run the sequence's method {owner.name!r} first")
        return checkpoint

    def _owner(self, method: MethodSpec) -> MethodSpec:
        """The method that trains `method`'s checkpoints (itself, or the one named by `checkpoints_from`)."""
        return next(m for m in self.config.methods if m.name == (method.checkpoints_from or method.name))

    def _check_settings(self) -> None:
        """Refuse to resume stages, evaluations or kept results made with other settings: the sequence's (every
        field but its methods, and the device) in the output directory, each method's in its own, for the methods
        run now and those whose earlier results are kept."""
        sequence = {k: v for k, v in asdict(self.config).items() if k != "methods"}
        sequence |= {"dataset_root": str(self.dataset_root), "device": self.device}  # results name one device
        check_settings(self.out, sequence, "a sequence's results")
        running = {m.name for m in self.methods}
        for method in self.config.methods:
            if method.name in running or (self.out / method.name).exists():
                check_settings(self.out / method.name, asdict(method), f"method {method.name}'s stages")

    # ------------------------------------------------------------------ stages
    def _stage_dir(self, method_name: str, k: int) -> Path:
        return self.out / method_name / f"stage_{k}_{self.config.tasks[k].name}"

    def _policy_args(self, method: MethodSpec, previous: Path | None, skill: str | None) -> list[str]:
        if previous is None:
            args = [f"--policy.type={method.policy}", *method.args]
        else:
            args = [f"--policy.path={previous}", *method.args, *method.later_stage_args]
        if method.policy == "coda_kvm" and skill is not None:
            args.append(f"--policy.skill_name={skill}")
        return args

    def _pretrain(self, method: MethodSpec, episodes: list[list[int]], bar: tqdm) -> Path | None:
        """The method's pretraining stage on the pretraining tasks (None when the sequence has none)."""
        if not self.config.pretrain_tasks or method.checkpoints_from is not None:
            return None
        bar.set_description(f"{method.name}: pretraining")
        stage = replace(method, steps_per_stage=method.pretrain_steps, max_steps_per_stage=0)
        # Methods with the same policy and training settings share one pretraining run (e.g. ACT's two modes).
        key = json.dumps([method.policy, method.args, method.pretrain_steps, method.batch_size, self.launcher])
        stage_dir = self.out / "pretrain" / f"{method.policy}-{hashlib.sha1(key.encode()).hexdigest()[:8]}"
        everything = _all_episodes(episodes)
        checkpoint = self._train(stage, stage_dir, self._policy_args(method, None, "pretrain"), everything)
        bar.update()
        return checkpoint

    def _train(self, method: MethodSpec, stage_dir: Path, policy: list[str], episodes: list[int]) -> Path:
        """One `lerobot-train` run; a finished stage is reused, an interrupted one starts again."""
        run_dir = stage_dir / "train"
        checkpoint = run_dir / CHECKPOINT
        if finished(run_dir, method.steps_per_stage):
            return checkpoint
        shutil.rmtree(run_dir, ignore_errors=True)  # lerobot-train refuses an existing output dir
        start = time.time()
        cmd = train_command(
            self.dataset_root,
            self.config.repo_id,
            run_dir,
            method.steps_per_stage,
            method.batch_size,
            self.config.seed,
            policy=policy,
            save_every=method.select_every or None,
            episodes=episodes,
            launcher=self.launcher,
            device=self.device,
        )
        (stage_dir / TIMING).unlink(missing_ok=True)
        run_logged(cmd, stage_dir / "train.log", done=lambda: finished(run_dir, method.steps_per_stage))
        self._add_train_time(stage_dir, time.time() - start)
        return checkpoint

    def _train_stage(
        self, method: MethodSpec, stage_dir: Path, policy: list[str], episodes: list[int], task: TaskSpec
    ) -> None:
        """Train a stage and, for a selecting method, choose its checkpoint; a stage whose skill is not learned
        trains on (`MethodSpec.max_steps_per_stage`). Every step is kept on disk, so a killed stage resumes."""
        run_dir = stage_dir / "train"
        self._train(method, stage_dir, policy, episodes)
        if not method.select_every:
            return
        while True:
            choice = self._select(stage_dir, task)
            trained = trained_steps(run_dir)
            if learned(choice) or trained >= method.max_steps_per_stage:
                return
            target = min((trained // method.steps_per_stage + 1) * method.steps_per_stage, method.max_steps_per_stage)
            start = time.time()
            cmd = resume_command(run_dir, target, self.launcher)
            run_logged(cmd, stage_dir / f"train_{target}.log", done=partial(finished, run_dir, target))
            self._add_train_time(stage_dir, time.time() - start)

    def _select(self, stage_dir: Path, task: TaskSpec) -> dict[str, Any]:
        """Score a trained stage's checkpoints on its task (each once) and keep the choice (`SELECTION`)."""
        path = stage_dir / SELECTION
        kept = json.loads(path.read_text()) if path.exists() else None
        steps = [c.parent.name for c in saved_checkpoints(stage_dir / "train")]
        if kept is not None and [c["step"] for c in kept["checkpoints"]] == steps:
            return kept
        start = time.time()
        choice = choose_stage_checkpoint(
            stage_dir / "train",
            task.scenario,
            task.variant,
            task.env_instruction,
            task.name,
            self.config.select_episodes,
            self.device,
            scored=kept["checkpoints"] if kept else (),
        )
        choice["wall_s"] = time.time() - start + (kept["wall_s"] if kept else 0.0)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(choice, indent=2))
        tmp.replace(path)  # a killed selection leaves no half-written choice
        return choice

    @staticmethod
    def _add_train_time(stage_dir: Path, seconds: float) -> None:
        path = stage_dir / TIMING
        kept = json.loads(path.read_text())["train_wall_s"] if path.exists() else 0.0
        path.write_text(json.dumps({"train_wall_s": kept + seconds}))

    @staticmethod
    def _train_time(stage_dir: Path) -> float | None:
        path = stage_dir / TIMING
        return json.loads(path.read_text())["train_wall_s"] if path.exists() else None

    def _evaluate(
        self, checkpoint: Path, eval_dir: Path, tasks: Sequence[TaskSpec], extra: Sequence[str] = ()
    ) -> dict[str, float]:
        """Success rate of each task: one `lerobot-eval` per (variant, instruction) group of tasks."""
        groups: dict[tuple[str, str], list[TaskSpec]] = {}
        for task in tasks:
            groups.setdefault((task.variant, task.env_instruction), []).append(task)
        success: dict[str, float] = {}
        for (variant, instruction), members in groups.items():
            out = eval_dir / f"{variant}_{instruction}"
            info_path = out / "eval_info.json"
            if not info_path.exists():
                shutil.rmtree(out, ignore_errors=True)
                scenarios = ",".join(t.scenario for t in members)
                cmd = eval_command(
                    checkpoint,
                    out,
                    scenarios,
                    variant,
                    self.config.eval_episodes,
                    self.config.eval_seed,
                    instruction,
                    list(extra),
                    self.device,
                )
                run_logged(cmd, eval_dir / f"{variant}_{instruction}.log")
            info = json.loads(info_path.read_text())
            per_task = {entry["task_group"]: entry["metrics"] for entry in info["per_task"]}
            for task in members:
                flags = per_task[task.scenario]["successes"]
                success[task.name] = sum(bool(f) for f in flags) / len(flags)
        return success

    # ------------------------------------------------------------------ methods
    def _run_sequential(
        self, method: MethodSpec, episodes: list[list[int]], previous: Path | None, bar: tqdm
    ) -> dict[str, Any]:
        tasks = self.config.tasks
        matrix: list[list[float | None]] = []
        stage_times = []
        for k, task in enumerate(tasks):
            stage_dir = self._stage_dir(method.name, k)
            bar.set_description(f"{method.name}: stage {k + 1}/{len(tasks)} {task.name}")
            if method.checkpoints_from is None:
                self._train_stage(method, stage_dir, self._policy_args(method, previous, task.name), episodes[k], task)
                stage_times.append(self._train_time(stage_dir))
                previous = stage_checkpoint(stage_dir, bool(method.select_every))
            else:
                owner = self.out / method.checkpoints_from / stage_dir.name
                previous = stage_checkpoint(owner, bool(self._owner(method).select_every))
                if not previous.exists():
                    raise FileNotFoundError(f"{method.name}: {previous} missing: run {method.checkpoints_from} first")
            bar.update()
            success = self._evaluate(previous, stage_dir / "eval", tasks[: k + 1], method.eval_args)
            matrix.append([success.get(t.name) for t in tasks])
            bar.update()
        return {
            "mode": "sequential",
            "success_matrix": matrix,
            "final": matrix[-1],
            "metrics": cl_metrics(matrix),
            "train_wall_s": stage_times,  # per stage (None: trained by an interrupted earlier invocation)
        }

    def _run_joint(
        self, method: MethodSpec, episodes: list[list[int]], previous: Path | None, bar: tqdm
    ) -> dict[str, Any]:
        stage_dir = self.out / method.name / "joint"
        bar.set_description(f"{method.name}: all {len(self.config.tasks)} tasks")
        everything = _all_episodes(episodes)
        checkpoint = self._train(method, stage_dir, self._policy_args(method, previous, "joint"), everything)
        bar.update()
        success = self._evaluate(checkpoint, stage_dir / "eval", self.config.tasks, method.eval_args)
        bar.update()
        final = [success[t.name] for t in self.config.tasks]
        train_s = [self._train_time(stage_dir)]
        return {"mode": "joint", "final": final, "metrics": joint_metrics(final), "train_wall_s": train_s}

    def _episodes(self) -> tuple[list[list[int]], list[list[int]]]:
        """The dataset's episodes of each task and of each pretraining task, once the dataset is checked: a damaged
        one is named here, not deep inside lerobot-train."""
        check_dataset(self.dataset_root)
        recorded = load_labels(self.dataset_root)["spec"].get("action_noise", 0.0)
        if recorded != self.config.action_noise:
            raise ValueError(
                f"dataset {self.dataset_root} was recorded with action_noise={recorded}, the sequence asks for "
                f"{self.config.action_noise}: record it again or pass another --dataset-root"
            )
        episodes = task_episodes(self.dataset_root, self.config.tasks)
        return episodes, task_episodes(self.dataset_root, self.config.pretrain_tasks)

    def check_dataset(self) -> None:
        """Refuse an existing dataset that is damaged or lacks a task of the sequence before anything is written:
        refused after the settings are recorded, the corrected rerun (another `--dataset-root`) would be refused
        as made with other settings. A dataset still to be recorded is checked once recorded."""
        if self.dataset_root.exists():
            self._episodes()

    def run(self) -> dict[str, Any]:
        """The whole run, holding the output directory (`lock.hold`) so that no second run works in it."""
        self.check_dataset()  # before the lock: a refused run leaves no output directory
        with hold(self.out):
            return self._run()

    def _run(self) -> dict[str, Any]:
        start = time.time()
        self._check_settings()  # before anything is recorded or trained for settings it would refuse
        if not self.dataset_root.exists():
            print(f"recording {self.dataset_root}")
            record_dataset(self.config.recording_spec(), self.dataset_root, repo_id=self.config.repo_id)
        episodes, pretrain_episodes = self._episodes()
        n_jobs = sum(
            2 * (len(self.config.tasks) if m.mode == "sequential" else 1)
            + bool(pretrain_episodes and m.checkpoints_from is None)
            for m in self.methods
        )
        results: dict[str, Any] = {}
        with tqdm(total=n_jobs, unit="job") as bar:
            for method in self.methods:
                runner = self._run_sequential if method.mode == "sequential" else self._run_joint
                began = time.time()
                pretrained = self._pretrain(method, pretrain_episodes, bar)
                result = runner(method, episodes, pretrained, bar)
                pretrain_s = self._train_time(pretrained.parents[3]) if pretrained is not None else None
                results[method.name] = {
                    "policy": method.policy,
                    **result,
                    "pretrain_train_wall_s": pretrain_s,
                    "wall_time_s": time.time() - began,
                }
        kept = {}  # methods of the config finished by an earlier invocation (e.g. `--methods` one at a time)
        if self.results_path.exists():
            earlier = json.loads(self.results_path.read_text()).get("methods", {})
            kept = {m.name: earlier[m.name] for m in self.config.methods if m.name in earlier and m.name not in results}
        merged = {**kept, **results}
        report = {
            "sequence": self.config.name,
            "config_path": self.config_path,
            "config": asdict(self.config),
            "tasks": [t.name for t in self.config.tasks],
            "episodes_per_task": [len(e) for e in episodes],
            "pretrain_tasks": [t.name for t in self.config.pretrain_tasks],
            "pretrain_episodes": sum(len(e) for e in pretrain_episodes),
            "dataset_root": str(self.dataset_root),
            "seeds": {"train": self.config.seed, "record": self.config.seed, "eval": self.config.eval_seed},
            "launcher": shlex.join(self.launcher),
            "device": self.device,
            "methods": {m.name: merged[m.name] for m in self.config.methods if m.name in merged},
            "versions": _versions(),
            "wall_time_s": time.time() - start,
        }
        self.results_path.write_text(json.dumps(report, indent=2))
        (self.out / "cl_report.md").write_text(markdown_report(report))
        return report


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f}"


def training_minutes(result: dict[str, Any]) -> float | None:
    """A method's recorded training wall time (its pretraining, if any, + stages) in minutes; None when it trained
    nothing itself (evaluation-only) or a stage's time is missing."""
    stages = result.get("train_wall_s") or []
    if not stages or any(t is None for t in stages):
        return None
    return (sum(stages) + (result.get("pretrain_train_wall_s") or 0.0)) / 60


def markdown_report(report: dict[str, Any]) -> str:
    """Metrics per method, then each method's success matrix (rows: after stage, columns: task)."""
    tasks = report["tasks"]
    lines = [
        f"# Continual learning: sequence `{report['sequence']}`",
        "",
        f"{len(tasks)} tasks, {report['config']['eval_episodes']} evaluation episodes per task and stage "
        f"(seed {report['seeds']['eval']}); this invocation's wall time {report['wall_time_s'] / 60:.1f} min.",
        "",
        "| method | policy | mode | A_N (%) | F_N (pp) | FWT (%) | NBT (pp) | AUC (%) | training (min) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, res in report["methods"].items():
        m = res["metrics"]
        cells = [_pct(m.get(key)) for key in ("A_N", "F_N", "FWT", "NBT", "AUC")]
        minutes = training_minutes(res)
        cells.append("-" if minutes is None else f"{minutes:.0f}")
        lines.append(f"| {name} | {res['policy']} | {res['mode']} | " + " | ".join(cells) + " |")
    lines += ["", "A_N / F_N: CODA-Prompt's final average success and forgetting; FWT / NBT / AUC: LIBERO's.", ""]
    header = "| after stage | " + " | ".join(f"{j}: {t}" for j, t in enumerate(tasks)) + " |"
    for name, res in report["methods"].items():
        lines += [f"## {name}: success (%)", "", header, "|---|" + "---|" * len(tasks)]
        rows = res.get("success_matrix") or [res["final"]]
        labels = [f"{i}: {tasks[i]}" for i in range(len(rows))] if res["mode"] == "sequential" else ["all (joint)"]
        for label, row in zip(labels, rows, strict=True):
            lines.append(f"| {label} | " + " | ".join(_pct(v) for v in row) + " |")
        lines.append("")
    return "\n".join(lines)
