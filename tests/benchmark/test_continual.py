"""The continual-learning sequence: config validation (fast) and a tiny real run of every method (slow)."""

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from lerobot_kvm.benchmark.continual import MethodSpec, SequenceConfig, TaskSpec

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_every_shipped_sequence_config_loads():
    for path in sorted(CONFIGS.glob("cl_*.json")):
        config = SequenceConfig.from_json(path)
        assert config.tasks and config.methods, path


def test_default_sequence_has_distinct_tasks_from_prior_variants_and_safe_skills():
    config = SequenceConfig.from_json(CONFIGS / "cl_default.json")
    assert len({t.name for t in config.tasks}) >= 6
    assert {t.variant for t in config.tasks} == {"prior"}  # leakage rule: no shifted variant before the benchmark
    assert {m.policy for m in config.methods} == {"coda_kvm", "act"}
    assert {m.mode for m in config.methods if m.policy == "act"} == {"sequential", "joint"}


def test_shipped_diffusion_policies_are_cpu_sized_and_valid_for_lerobot():
    """Every Diffusion Policy a shipped sequence trains: LeRobot's own checks of its settings, no download (no
    pretrained backbone), a crop inside the 96x96 camera, few denoising steps, and the action queue LeRobot's
    `select_action` needs (n_action_steps <= horizon - n_obs_steps + 1, the last frames dropped to match)."""
    import draccus
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    found = 0
    for path in sorted(CONFIGS.glob("cl_*.json")):
        for method in SequenceConfig.from_json(path).methods:
            if method.policy != "diffusion":
                continue
            found += 1
            args = [a.replace("--policy.", "--", 1) for a in method.args]
            config = draccus.parse(DiffusionConfig, args=args)
            assert config.pretrained_backbone_weights is None, method.name
            assert config.crop_shape is not None and max(config.crop_shape) <= 96, method.name
            assert config.num_inference_steps is not None and config.num_inference_steps <= 10, method.name
            assert config.n_action_steps <= config.horizon - config.n_obs_steps + 1, method.name
            assert config.drop_n_last_frames == config.horizon - config.n_action_steps - config.n_obs_steps + 1
    assert found >= 1  # the full configuration's `diffusion_joint`


def test_task_names_and_instructions():
    task = TaskSpec("chip_bag", skill="safe", instruction="skill")
    assert task.name == "chip_bag.gentle_grasp"
    assert task.env_instruction == "safe"
    assert task.record_item(3).task_string() == "gently pick up the bag of chips"
    assert TaskSpec("egg_vs_stone").env_instruction == "variant"


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: TaskSpec("no_such_scenario"), "no_such_scenario"),
        (lambda: TaskSpec("egg_vs_stone", variant="sideways"), "sideways"),
        (lambda: TaskSpec("egg_vs_stone", skill="clumsy"), "clumsy"),
        (lambda: TaskSpec("egg_vs_stone", instruction="loud"), "loud"),
        (lambda: MethodSpec("m", policy="pi0"), "pi0"),
        (lambda: MethodSpec("m", mode="shuffled"), "shuffled"),
        (lambda: SequenceConfig("s", [TaskSpec("book"), TaskSpec("book")], [MethodSpec("m")]), "distinct"),
        (lambda: SequenceConfig("s", [TaskSpec("book")], [MethodSpec("m", checkpoints_from="later")]), "later"),
        (lambda: MethodSpec("m", mode="joint", checkpoints_from="x"), "sequential"),
        (lambda: MethodSpec("m", mode="joint", select_every=100), "select_every"),
        (lambda: MethodSpec("m", checkpoints_from="x", select_every=100), "select_every"),
        (lambda: MethodSpec("m", select_every=-1), "select_every"),
        (lambda: MethodSpec("m", max_steps_per_stage=1000), "max_steps_per_stage"),
        (lambda: MethodSpec("m", steps_per_stage=500, select_every=100, max_steps_per_stage=300), "max_steps"),
        (lambda: SequenceConfig("s", [TaskSpec("book")], [MethodSpec("m")], select_episodes=0), "select_episodes"),
    ],
)
def test_bad_configs_are_rejected_with_the_offending_value(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_sequence_trains_every_stage_on_its_device(tmp_path, monkeypatch):
    from lerobot_kvm.benchmark import continual

    commands = []
    monkeypatch.setattr(continual, "run_logged", lambda cmd, *args, **kwargs: commands.append(cmd))
    method = MethodSpec("coda_kvm")
    run = continual.ContinualRun(SequenceConfig("d", [TaskSpec("book")], [method]), tmp_path, device="cuda")
    (tmp_path / "stage").mkdir()
    run._train(method, tmp_path / "stage", run._policy_args(method, None, "book"), [0, 1])
    (cmd,) = commands
    assert "--policy.device=cuda" in cmd and "--policy.device=cpu" not in cmd


def test_a_stage_hands_on_its_selected_checkpoint_once_selected(tmp_path):
    from lerobot_kvm.benchmark.continual import SELECTION, stage_checkpoint

    assert stage_checkpoint(tmp_path, False) == tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    assert not stage_checkpoint(tmp_path, True).exists()  # not selected yet: reads as missing
    (tmp_path / SELECTION).write_text(json.dumps({"selected": "000300"}))
    assert stage_checkpoint(tmp_path, True) == tmp_path / "train" / "checkpoints" / "000300" / "pretrained_model"


def test_a_run_is_finished_only_once_its_final_checkpoint_is_written(tmp_path):
    from lerobot_kvm.benchmark.continual import finished

    checkpoints = tmp_path / "checkpoints"
    assert not finished(tmp_path, 500)
    for step in ("000100", "000500"):
        (checkpoints / step / "pretrained_model").mkdir(parents=True)
    (checkpoints / "last").symlink_to("000100")  # an intermediate checkpoint: the run is still training
    assert not finished(tmp_path, 500)
    (checkpoints / "last").unlink()
    (checkpoints / "last").symlink_to("000500")
    assert finished(tmp_path, 500) and not finished(tmp_path, 1000)
    (checkpoints / "001000" / "pretrained_model").mkdir(parents=True)
    (checkpoints / "last").unlink()
    (checkpoints / "last").symlink_to("001000")  # the stage trained on: its first part stays finished
    assert finished(tmp_path, 500) and finished(tmp_path, 1000)


def _fake_lerobot_train(commands: list) -> object:
    """Stands in for `lerobot-train` (new or resumed): saves a checkpoint every 100 steps up to `--steps`."""

    def run(cmd, *args, **kwargs):
        from lerobot_kvm.evaluation.checkpoint_selection import trained_steps

        commands.append(cmd)
        option = {a.split("=", 1)[0]: a.split("=", 1)[1] for a in cmd if a.startswith("--")}
        run_dir = Path(option.get("--output_dir") or Path(option["--config_path"]).parents[3])
        steps = int(option["--steps"])
        for step in range(trained_steps(run_dir) + 100, steps + 1, 100):
            (run_dir / "checkpoints" / f"{step:06d}" / "pretrained_model").mkdir(parents=True)
        last = run_dir / "checkpoints" / "last"
        last.unlink(missing_ok=True)
        last.symlink_to(f"{steps:06d}")

    return run


@pytest.mark.parametrize(
    "max_steps, successes, resumed_to, selected",
    [
        (1500, {500: 11, 700: 19, 900: 20}, [1000], "000900"),  # learned within the first extension
        (1500, {500: 11, 700: 12}, [1000, 1500], "000700"),  # never learned: trains up to the cap
        (0, {500: 11, 700: 19}, [], "000500"),  # no extension configured
        (1500, {300: 18}, [], "000300"),  # learned in the stage's own steps
    ],
)
def test_a_stage_trains_on_until_its_skill_is_learned(
    tmp_path, monkeypatch, max_steps, successes, resumed_to, selected
):
    from lerobot_kvm.benchmark import continual
    from lerobot_kvm.evaluation import checkpoint_selection

    commands: list = []
    monkeypatch.setattr(continual, "run_logged", _fake_lerobot_train(commands))
    monkeypatch.setattr(
        checkpoint_selection,
        "rollout_score",
        lambda ck, *a, **k: {"success": successes.get(int(ck.parent.name), 0), "catastrophe": 0, "episodes": 20},
    )
    method = MethodSpec("coda_kvm", steps_per_stage=500, select_every=100, max_steps_per_stage=max_steps)
    task = TaskSpec("drawer")
    run = continual.ContinualRun(SequenceConfig("d", [task], [method]), tmp_path)
    stage = tmp_path / "stage"
    run._train_stage(method, stage, run._policy_args(method, None, task.name), [0, 1], task)
    assert [c for c in commands[1:] if "--resume=true" in c] == commands[1:]
    assert [int(c[-1].removeprefix("--steps=")) for c in commands[1:]] == resumed_to
    choice = json.loads((stage / continual.SELECTION).read_text())
    assert choice["selected"] == selected and len(choice["checkpoints"]) == max([500, *resumed_to]) // 100
    assert continual.stage_checkpoint(stage, True).parent.name == selected

    # Run again (a resumed sequence): nothing is trained or scored twice.
    monkeypatch.setattr(checkpoint_selection, "rollout_score", None)
    run._train_stage(method, stage, run._policy_args(method, None, task.name), [0, 1], task)
    assert len(commands) == 1 + len(resumed_to)


def _identical(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(v, sb[k]) for k, v in sa.items())


@pytest.mark.slow
def test_tiny_sequence_runs_every_method_through_the_real_clis(tiny_pool):
    from lerobot_kvm.benchmark.continual import CHECKPOINT, SELECTION, stage_checkpoint
    from lerobot_kvm.policy import CodaKvmPolicy

    out = tiny_pool["out"]
    results = json.loads((out / "cl_results.json").read_text())
    assert results["tasks"] == ["egg_vs_stone.firm_grasp", "egg_vs_stone.gentle_grasp", "chip_bag.gentle_grasp"]
    coda = results["methods"]["coda_kvm"]
    assert len(coda["success_matrix"]) == 3 and coda["success_matrix"][0][1] is None
    assert set(coda["metrics"]) == {"A_N", "F_N", "FWT", "NBT", "AUC"}
    assert len(results["methods"]["coda_prompt"]["success_matrix"]) == 3  # coda_kvm's checkpoints, KVM off
    assert not (out / "coda_prompt" / "stage_0_egg_vs_stone.firm_grasp" / "train").exists()
    assert len(results["methods"]["act_joint"]["final"]) == 3
    assert {"lerobot", "torch", "mujoco"} <= set(results["versions"])
    assert "| coda_kvm | coda_kvm | sequential |" in (out / "cl_report.md").read_text()

    # Each stage learned in new components: earlier components and the frozen backbone stay bit-identical.
    stages = sorted((out / "coda_kvm").glob("stage_*"), key=lambda p: int(p.name.split("_")[1]))
    pretrained = CodaKvmPolicy.from_pretrained(next(out.glob(f"pretrain/coda_kvm-*/train/{CHECKPOINT}")))
    first, second = (CodaKvmPolicy.from_pretrained(stage_checkpoint(stages[k], True)) for k in (0, 2))
    assert [s.name for s in second.skills] == ["pretrain", *results["tasks"]]
    assert _identical(pretrained.pool.tasks[0], second.pool.tasks[0])
    assert _identical(first.pool.tasks[1], second.pool.tasks[1])
    assert _identical(pretrained.backbone, second.backbone)

    # Every trained stage scored each saved checkpoint by rollouts, and the next stage began from the one selected;
    # a stage whose skill was not learned in its 2 steps trained on to 3 (`max_steps_per_stage`), resumed by
    # `lerobot-train` itself.
    for k, stage in enumerate(stages):
        choice = json.loads((stage / SELECTION).read_text())
        first = [c for c in choice["checkpoints"] if c["step"] in ("000001", "000002")]
        steps = ["000001", "000002"] if any(c["success"] for c in first) else ["000001", "000002", "000003"]
        assert [c["step"] for c in choice["checkpoints"]] == steps
        assert (stage / "train_3.log").exists() == (len(steps) == 3)
        assert choice["selected"] in steps
        assert all(c["episodes"] == 1 and c["success"] + c["catastrophe"] <= 1 for c in choice["checkpoints"])
        if k:
            config = json.loads(
                (stage / "train" / "checkpoints" / "000001" / "pretrained_model" / "config.json").read_text()
            )
            assert Path(config["pretrained_path"]) == stage_checkpoint(stages[k - 1], True)

    # A second invocation resumes: every stage and evaluation is found on disk and nothing is retrained.
    assert "lerobot-train" not in tiny_pool["run"](tiny_pool["cmd"], 600).stdout


def test_methods_with_one_policy_and_training_settings_share_one_pretraining_run(tmp_path, monkeypatch):
    """ACT's sequential and joint methods differ in mode and stages only: one pretraining serves both."""
    from tqdm import tqdm

    from lerobot_kvm.benchmark.continual import ContinualRun

    act = MethodSpec("act_sequential", policy="act", pretrain_steps=2)
    methods = [act, replace(act, name="act_joint", mode="joint"), replace(act, name="act_other", args=["--seed=1"])]
    sequence = SequenceConfig("s", [TaskSpec("book")], methods, pretrain_tasks=[TaskSpec("potato")])
    run = ContinualRun(sequence, tmp_path)
    monkeypatch.setattr(ContinualRun, "_train", lambda self, method, stage_dir, policy, episodes: stage_dir)
    dirs = [run._pretrain(m, [[0]], tqdm(disable=True)) for m in methods]
    assert dirs[0] == dirs[1] != dirs[2]


def test_a_pretraining_longer_than_a_stage_may_train_runs_its_own_steps(tmp_path, monkeypatch):
    from tqdm import tqdm

    from lerobot_kvm.benchmark.continual import ContinualRun

    coda = MethodSpec("coda_kvm", steps_per_stage=500, select_every=100, max_steps_per_stage=1000, pretrain_steps=1500)
    run = ContinualRun(SequenceConfig("s", [TaskSpec("book")], [coda], pretrain_tasks=[TaskSpec("potato")]), tmp_path)
    trained = []
    monkeypatch.setattr(ContinualRun, "_train", lambda self, method, *args: trained.append(method.steps_per_stage))
    run._pretrain(coda, [[0]], tqdm(disable=True))
    assert trained == [1500]


def test_training_minutes_add_pretraining_and_stages_and_skip_evaluation_only_methods():
    from lerobot_kvm.benchmark.continual import training_minutes

    assert training_minutes({"pretrain_train_wall_s": 60.0, "train_wall_s": [30.0, 30.0]}) == 2.0
    assert training_minutes({"pretrain_train_wall_s": None, "train_wall_s": [120.0]}) == 2.0
    assert training_minutes({"pretrain_train_wall_s": None, "train_wall_s": []}) is None  # evaluated only
    assert training_minutes({"pretrain_train_wall_s": 5.0, "train_wall_s": [None, 3.0]}) is None


def test_a_resumed_sequence_refuses_other_settings_of_the_sequence_or_of_a_method(tmp_path):
    from lerobot_kvm.benchmark.continual import ContinualRun

    methods = [MethodSpec("coda_kvm"), MethodSpec("act", policy="act")]
    ContinualRun(SequenceConfig("s", [TaskSpec("book")], methods), tmp_path, only=["coda_kvm"])._check_settings()
    # another method joins later; the first one's settings are unchanged
    ContinualRun(SequenceConfig("s", [TaskSpec("book")], methods), tmp_path)._check_settings()
    with pytest.raises(ValueError, match=r"a sequence's results made with other settings \(eval_episodes: 10 -> 5\)"):
        ContinualRun(SequenceConfig("s", [TaskSpec("book")], methods, eval_episodes=5), tmp_path)._check_settings()
    with pytest.raises(ValueError, match=r"\(device: \"cpu\" -> \"cuda\"\)"):
        ContinualRun(SequenceConfig("s", [TaskSpec("book")], methods), tmp_path, device="cuda")._check_settings()
    # a method whose stages exist is checked even when it is not run now: its kept results are reported
    changed = [MethodSpec("coda_kvm", steps_per_stage=100), methods[1]]
    with pytest.raises(ValueError, match=r"method coda_kvm's stages made with other settings \(steps_per_stage"):
        ContinualRun(SequenceConfig("s", [TaskSpec("book")], changed), tmp_path, only=["act"])._check_settings()


def test_a_dataset_recorded_with_other_action_noise_is_refused(tmp_path):
    from lerobot_kvm.benchmark.continual import ContinualRun
    from lerobot_kvm.datasets.recorder import record_dataset

    root = tmp_path / "data"
    sequence = SequenceConfig("s", [TaskSpec("book")], [MethodSpec("coda_kvm")], dataset_root=str(root))
    spec = sequence.recording_spec()
    spec.items[0].episodes = 1  # a fast recording
    record_dataset(spec, root, progress=False)
    ContinualRun(sequence, tmp_path / "out").check_dataset()
    noisy = SequenceConfig("s", [TaskSpec("book")], [MethodSpec("coda_kvm")], dataset_root=str(root), action_noise=2e-3)
    with pytest.raises(ValueError, match=r"recorded with action_noise=0.0, the sequence asks for 0.002"):
        ContinualRun(noisy, tmp_path / "out").check_dataset()
