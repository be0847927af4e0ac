"""The benchmark: config validation (fast) and a tiny real run of every method from the tiny pool (slow)."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from lerobot_kvm.benchmark import protocol
from lerobot_kvm.benchmark.continual import ContinualRun, SequenceConfig, TaskSpec
from lerobot_kvm.benchmark.protocol import (
    KVM_METHODS,
    ORACLE_METHODS,
    PEER_METHODS,
    SEED_OFFSETS,
    Benchmark,
    BenchmarkConfig,
    SwitchOnExit,
    delta_windows,
    episode_fields,
    episode_seed,
    finetune,
    learned_skill,
    load_policy,
    uncovered_scenarios,
)
from lerobot_kvm.benchmark.report import coverage_lines
from lerobot_kvm.envs.scenario import SCENARIOS
from lerobot_kvm.evaluation.rescue import Envelope
from lerobot_kvm.policy.feedback import chunk_targets

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_every_shipped_benchmark_config_loads_and_names_a_shipped_sequence():
    paths = sorted(CONFIGS.glob("benchmark_*.json"))
    assert paths
    for path in paths:
        config = BenchmarkConfig.from_json(path)
        assert (CONFIGS.parent / config.sequence).exists(), config.sequence


@pytest.mark.parametrize(
    "change, message",
    [
        ({"methods": ["coda_kvm", "pi0"]}, "pi0"),
        ({"scenarios": ["egg_vs_stone", "teapot"]}, "teapot"),
        ({"controls": ["prior", "sideways"]}, "sideways"),
        ({"passes": 0}, "passes"),
        ({"kvm": {"tau_high": 0.8, "gate_k": 3.0, "warp": 1}}, "warp"),
        ({"kvm": {"risk_model": "svm"}}, "risk_model"),
    ],
)
def test_bad_benchmark_configs_are_rejected_with_the_offending_value(change, message):
    raw = {"name": "x", "sequence": "configs/cl_tiny.json", "scenarios": ["egg_vs_stone"], **change}
    with pytest.raises(ValueError, match=message):
        BenchmarkConfig(**raw)


def test_episode_seeds_are_distinct_per_role_and_far_from_recording_and_cl_seeds():
    offsets = SEED_OFFSETS.values()
    seeds = {episode_seed(0, r, p, i, o) for r in range(5) for p in (1, 2, 3) for i in range(18) for o in offsets}
    assert len(seeds) == 5 * 3 * 18 * len(SEED_OFFSETS)
    assert SEED_OFFSETS["attempt_2"] not in (SEED_OFFSETS["attempt_1"], SEED_OFFSETS["prior"], SEED_OFFSETS["control"])
    assert min(seeds) > 100_000 + 10_000


def test_scenarios_without_their_prior_skill_or_a_safe_alternative_in_the_pool_are_flagged():
    sequence = SequenceConfig.from_json(CONFIGS / "cl_tiny.json")
    tasks = [
        {"scenario": "egg_vs_stone"},  # prior skill only
        {"scenario": "chip_bag", "skill": "safe", "instruction": "skill"},  # alternative only
        {"scenario": "potato"},
        {"scenario": "potato", "skill": "safe", "instruction": "skill"},
    ]
    sequence = replace(sequence, tasks=[TaskSpec(**t) for t in tasks], pretrain_tasks=[])
    scenarios = ["egg_vs_stone", "chip_bag", "potato", "ice_cream"]
    assert uncovered_scenarios(sequence, scenarios) == ["egg_vs_stone", "chip_bag", "ice_cream"]
    assert coverage_lines([]) == [] and "chip_bag" in coverage_lines(["chip_bag"])[0]


@pytest.mark.parametrize("name", ["quick", "default", "full"])
def test_every_shipped_benchmark_scenario_has_its_prior_skill_and_a_separate_safe_alternative(name):
    """Suppressing a scenario's prior skill must leave an alternative the pool learned for it, in another skill
    (DESIGN §6), learned from the prior variant or a visibly different control, never from a shifted frame."""
    config = BenchmarkConfig.from_json(CONFIGS / f"benchmark_{name}.json")
    sequence = SequenceConfig.from_json(CONFIGS.parent / config.sequence)
    assert uncovered_scenarios(sequence, config.scenarios) == []
    assert {t.variant for t in [*sequence.tasks, *sequence.pretrain_tasks]} <= {"prior", "control"}
    skills = [sequence.pretrain_tasks, *([t] for t in sequence.tasks)]  # what each CODA skill learns

    def learning(scenario: str, expert_skill: str) -> set[int]:
        return {
            i
            for i, tasks in enumerate(skills)
            if any((t.scenario, t.expert_skill) == (scenario, expert_skill) for t in tasks)
        }

    for scenario_id in config.scenarios:
        info = SCENARIOS[scenario_id].info
        assert not learning(scenario_id, info.safe_skill) & learning(scenario_id, info.prior_skill), scenario_id


def test_quick_and_default_configurations_cover_every_category():
    for name, per_category in (("quick", 1), ("default", 2)):
        config = BenchmarkConfig.from_json(CONFIGS / f"benchmark_{name}.json")
        categories = [SCENARIOS[s].info.category for s in config.scenarios]
        assert {c: categories.count(c) for c in "ABC"} == dict.fromkeys("ABC", per_category), name


def test_full_benchmark_covers_the_whole_suite_with_every_method():
    full = BenchmarkConfig.from_json(CONFIGS / "benchmark_full.json")
    assert sorted(full.scenarios) == sorted(SCENARIOS) and full.runs >= 5 and full.passes == 3
    assert set(full.methods) == {*KVM_METHODS, *PEER_METHODS, *ORACLE_METHODS}


def test_every_row_starts_from_the_final_checkpoint_of_its_own_sequence_method(tmp_path):
    full = BenchmarkConfig.from_json(CONFIGS / "benchmark_full.json")
    bench = Benchmark(replace(full, sequence=str(CONFIGS / "cl_full.json")), tmp_path)
    assert bench.families == {"kvm": "coda_kvm", "act": "act_joint", "diffusion": "diffusion_joint"}
    assert [full.pool_method(m) for m in ("coda_prompt", "oracle_skill", "act", "diffusion")] == [
        "coda_kvm",
        "coda_kvm",
        "act_joint",
        "diffusion_joint",
    ]
    only_peers = Benchmark(replace(full, sequence=str(CONFIGS / "cl_full.json"), methods=["diffusion"]), tmp_path)
    assert only_peers.pool_methods == ["diffusion_joint"]  # no coda_kvm pool grown for a peer alone


@pytest.mark.parametrize(
    "change, message",
    [
        ({}, r"has no methods \['diffusion_joint'\]"),  # the tiny pool trains no Diffusion Policy
        ({"diffusion_method": "act_joint"}, r"diffusion_method='act_joint' trains a 'act' policy, not 'diffusion'"),
        ({"methods": ["act"], "act_method": "coda_kvm"}, r"act_method='coda_kvm' trains a 'coda_kvm' policy"),
    ],
)
def test_a_peer_row_needs_a_sequence_method_that_trains_its_own_policy_type(change, message, tmp_path):
    config = BenchmarkConfig("b", str(CONFIGS / "cl_tiny.json"), ["book"], methods=["coda_kvm", "diffusion"])
    with pytest.raises(ValueError, match=message):
        Benchmark(replace(config, **change), tmp_path)


def test_delta_windows_draw_history_and_targets_as_the_dataset_does_and_match_act_s_chunks():
    values = torch.arange(4.0).unsqueeze(1)  # [T=4, 1]
    windows, pad = delta_windows(values, [-1, 0, 1])
    assert windows.squeeze(-1).tolist() == [[0, 0, 1], [0, 1, 2], [1, 2, 3], [2, 3, 3]]  # edges copy the frame
    assert pad.tolist() == [[True, False, False], [False, False, False], [False, False, False], [False, False, True]]
    actions = torch.randn(7, 5)
    chunks, chunk_pad = chunk_targets(actions, 3)  # what the ACT and coda_kvm baselines fine-tuned on before
    windows, pad = delta_windows(actions, range(3))
    assert torch.equal(windows, chunks) and torch.equal(pad, chunk_pad)


def test_oracle_switch_forces_the_prior_skill_until_the_context_leaves_the_envelope_then_the_safe_one():
    runs = [np.zeros((5, 2)), np.ones((5, 2)) * 0.1]
    envelope = Envelope.fit(runs, window=0, stretch=0.0, margin=0.0, floor=0.01)
    prior, safe = torch.tensor([[1.0, 0.0]]), torch.tensor([[0.0, 1.0]])
    switch = SwitchOnExit(envelope, prior, safe)
    contexts = [[0.05, 0.05], [0.1, 0.0], [0.5, 0.0], [0.05, 0.05], [0.05, 0.05]]
    weights = [switch(step, np.array(c)) for step, c in enumerate(contexts)]
    assert [w.argmax().item() for w in weights] == [0, 0, 1, 1, 1] and switch.switch_step == 2  # and stays


def test_learned_skill_finds_a_stage_skill_by_name_and_pretraining_as_skill_0(monkeypatch):
    sequence = SequenceConfig.from_json(CONFIGS / "cl_tiny.json")  # pretraining: potato's prior skill
    names = {"egg_vs_stone.firm_grasp": 1, "egg_vs_stone.gentle_grasp": 2}
    monkeypatch.setattr(protocol, "skill_index", lambda policy, scenario, expert: names.get(f"{scenario}.{expert}"))
    assert learned_skill(None, sequence, "egg_vs_stone", "prior") == 1
    assert learned_skill(None, sequence, "egg_vs_stone", "safe") == 2
    assert learned_skill(None, sequence, "potato", "prior") == 0
    assert learned_skill(None, sequence, "potato", "safe") is None


def test_episode_fields_without_a_validity_trace():
    fields = episode_fields({"outcome": "failure", "steps": 7, "catastrophe_kind": "", "trace": None})
    assert fields["series"] is None and fields["gate_steps"] == 0 and fields["first_intervention"] is None


def _tiny_benchmark(tiny_pool: dict, methods: list[str], passes: int = 1) -> BenchmarkConfig:
    """A benchmark of egg_vs_stone on the tiny pool with a 2-step feedback budget."""
    return BenchmarkConfig(
        name="tiny",
        sequence=str(CONFIGS / "cl_tiny.json"),
        scenarios=["egg_vs_stone"],
        methods=methods,
        passes=passes,
        feedback_steps=2,
        finetune_batch=4,
        dataset_root=str(tiny_pool["data"]),
    )


@pytest.mark.slow
def test_tiny_benchmark_runs_every_method_from_the_pool_and_resumes(tiny_pool):
    base: Path = tiny_pool["base"]
    config = {
        "name": "tiny",
        "sequence": str(CONFIGS / "cl_tiny.json"),
        "scenarios": ["egg_vs_stone", "chip_bag"],
        "methods": ["coda_kvm", "coda_prompt", "no_smart_gate", "no_energy_model", "act", *ORACLE_METHODS],
        "passes": 2,
        "feedback_steps": 2,
        "finetune_batch": 4,
        "overhead_steps": 10,
        "dataset_root": str(tiny_pool["data"]),
    }
    config_path = base / "benchmark_tiny.json"
    config_path.write_text(json.dumps(config))
    out = base / "bench"
    cmd = [tiny_pool["cli"], "benchmark", f"--config={config_path}", f"--output-dir={out}", tiny_pool["launcher"]]
    proc = tiny_pool["run"](cmd, 1200)
    assert "lerobot-train" not in proc.stdout  # the pool grown by train-continual is reused as it is

    results = json.loads((out / "results.json").read_text())
    assert list(results["methods"]) == config["methods"]
    for name, res in results["methods"].items():
        overall = res["overall"]
        assert overall["challenges"] == 4, name  # 2 scenarios x 2 passes
        assert set(overall["per_category"]) == {"B", "C"}
        assert 0.0 <= overall["catastrophic_failure_rate"] <= 1.0
        assert set(res["per_pass"]) == {"1", "2"}
    assert results["methods"]["coda_prompt"]["overall"]["gate_activation_rate"] is None
    assert results["methods"]["act"]["overall"]["validity_auroc"] is None
    kvm = results["methods"]["coda_kvm"]["overall"]
    assert 0.0 <= kvm["gate_activation_rate"] <= 1.0 and 0.0 <= kvm["false_intervention_rate"] <= 1.0
    assert kvm["validity_auroc"] is not None  # egg_vs_stone's prior skill is in the pool: it is probed
    assert results["overhead"]["ratio_gate_closed"] > 0 and results["overhead"]["kvm_state_mb"] > 0
    assert {"coda_kvm", "act_joint"} <= set(results["pool"]["continual_metrics"])
    assert {"lerobot", "torch", "mujoco"} <= set(results["versions"])

    run = json.loads((out / "episodes" / "coda_kvm" / "run_0.json").read_text())
    kinds = {(r["scenario"], r["kind"]) for r in run["records"]}
    assert ("chip_bag", "control") in kinds and ("egg_vs_stone", "prior") in kinds
    assert ("egg_vs_stone", "control") not in kinds  # a scenario without a benign variant has no such control
    assert all(r["series"] is not None for r in run["records"])
    challenge = [r for r in run["records"] if r["kind"] == "challenge"]
    reported = [r for r in challenge if r["attempt"] == 2 or r["outcome"] == "success"]
    assert all(isinstance(r["pruned"], list) for r in reported)  # the metabolism's pruning is kept
    assert all(r["pruned"] == [] for r in run["records"] if r["kind"] != "challenge")  # controls teach nothing
    seeds = {(r["pass"], r["scenario"], r["kind"], r["attempt"]): r["seed"] for r in run["records"]}
    for (pass_, scenario, kind, attempt), seed in seeds.items():
        if kind == "challenge" and attempt == 2:  # a new episode of the shifted variant, not a replay
            assert seed != seeds[pass_, scenario, "challenge", 1]
    assert len(set(seeds.values())) == len(seeds)
    assert "Differences from `coda_kvm`" in (out / "report.md").read_text()
    act_run = json.loads((out / "episodes" / "act" / "run_0.json").read_text())
    assert all(r["series"] is None for r in act_run["records"])
    failed_first = [r for r in act_run["records"] if r["kind"] == "challenge" and r["attempt"] == 1]
    failed_first = [r for r in failed_first if r["outcome"] != "success"]
    assert len(act_run["feedback"]) == len(failed_first)  # one fine-tuning per failed first attempt
    core = json.loads((out / "episodes" / "coda_prompt" / "run_0.json").read_text())["feedback"]
    assert all(f["new_skill"]["created"] for f in core)  # the KVM-off core learns each demonstration as a new skill
    for method in config["methods"]:  # every method's counted steps are the budget, whatever it trains
        feedback = json.loads((out / "episodes" / method / "run_0.json").read_text())["feedback"]
        budget = 0 if method in ORACLE_METHODS else config["feedback_steps"]  # a diagnostic learns nothing
        assert all(f["gradient_steps"] == budget for f in feedback), method
        if method not in ORACLE_METHODS:
            assert results["methods"][method]["feedback"]["steps_each"] in ([], [budget]), method
    switch = json.loads((out / "episodes" / "oracle_switch" / "run_0.json").read_text())["records"]
    eggs = [r for r in switch if (r["scenario"], r["kind"]) == ("egg_vs_stone", "challenge")]
    assert eggs and all("switch_step" in r for r in eggs)  # egg_vs_stone has both skills in the tiny pool

    report = (out / "report.md").read_text()
    for heading in ("What `coda_kvm` did in each challenge", "Table 1/9", "Table 4", "Table 10", "Table 11"):
        assert heading in report
    assert "| coda_kvm |" in report and "| act |" in report and "| oracle_switch (privileged) |" in report
    assert (out / "plots" / "success_by_pass.png").stat().st_size > 0
    assert (out / "plots" / "energy_histograms.png").stat().st_size > 0

    # A second invocation finds every (method, run) on disk and runs no episode again.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "episodes").rglob("run_*.json")}
    tiny_pool["run"](cmd, 600)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert json.loads((out / "results.json").read_text())["overhead"] == results["overhead"]  # measured once
    assert not list((out / "episodes").rglob("*.partial"))  # finished runs keep no per-pass state


@pytest.mark.slow
def test_an_interrupted_run_resumes_at_its_next_pass_with_the_result_of_an_uninterrupted_one(
    tiny_pool, tmp_path, monkeypatch
) -> None:
    config = _tiny_benchmark(tiny_pool, ["coda_kvm", "act"], passes=2)

    whole = Benchmark(config, tmp_path / "whole", progress=False)
    resumed = Benchmark(config, tmp_path / "resumed", progress=False)
    pool = ContinualRun(whole.sequence, tiny_pool["out"])  # the tiny pool's checkpoints, read only
    checkpoints = {"kvm": pool.final_checkpoint("coda_kvm"), "act": pool.final_checkpoint("act_joint")}
    controls = Benchmark._controls

    def interrupted_in_pass_2(self, policy, pre, post, base, seed, out) -> None:
        if base["pass"] == 2:
            raise KeyboardInterrupt
        controls(self, policy, pre, post, base, seed, out)

    def summary(run: dict) -> list[tuple]:
        return [(r["pass"], r["kind"], r["attempt"], r["outcome"], r["steps"]) for r in run["records"]]

    for method, family in (("coda_kvm", "kvm"), ("act", "act")):
        reference = whole.run_method(method, 0, checkpoints[family])
        with monkeypatch.context() as patch:
            patch.setattr(Benchmark, "_controls", interrupted_in_pass_2)
            with pytest.raises(KeyboardInterrupt):
                resumed.run_method(method, 0, checkpoints[family])
        partial = resumed._partial_dir(method, 0)
        assert (partial / "pass_1.json").exists() and (partial / "pass_1" / "config.json").exists()
        again = resumed.run_method(method, 0, checkpoints[family])
        assert {r["pass"] for r in again["records"]} == {1, 2}
        assert summary(again) == summary(reference), method
        assert len(again["feedback"]) == len(reference["feedback"])


@pytest.mark.slow
def test_controls_change_no_weight_or_memory_of_any_method(tiny_pool, tmp_path) -> None:
    config = BenchmarkConfig(
        name="tiny",
        sequence=str(CONFIGS / "cl_tiny.json"),
        scenarios=["chip_bag"],  # it has both a prior and a benign control variant
        dataset_root=str(tiny_pool["data"]),
    )
    bench = Benchmark(config, tmp_path, progress=False)
    pool = ContinualRun(bench.sequence, tiny_pool["out"])
    checkpoints = {"kvm": pool.final_checkpoint("coda_kvm"), "act": pool.final_checkpoint("act_joint")}
    base = {"method": "", "run": 0, "pass": 1, "scenario": "chip_bag", "category": "B"}
    for method in (*KVM_METHODS, "act"):
        policy, pre, post = load_policy(method, checkpoints["kvm" if method in KVM_METHODS else "act"])
        if method in KVM_METHODS:
            policy.kvm.threshold()  # eq. 1's statistics, a cache of the safe memory, computed before acting
        before = {k: v.clone() for k, v in policy.state_dict().items()}
        out = {"records": []}
        bench._controls(policy, pre, post, base | {"method": method}, episode_seed(0, 0, 1, 0), out)
        assert [r["kind"] for r in out["records"]] == ["prior", "control"], method
        after = policy.state_dict()
        assert after.keys() == before.keys(), method
        changed = [k for k in before if not before[k].equal(after[k])]
        assert not changed, (method, changed[:5])


@pytest.mark.slow
def test_worker_processes_give_the_results_of_one_process(tiny_pool, tmp_path) -> None:
    import torch
    from tqdm import tqdm

    config = _tiny_benchmark(tiny_pool, ["coda_kvm", "coda_prompt"])
    sequence = SequenceConfig.from_json(CONFIGS / "cl_tiny.json")
    checkpoints = {"kvm": ContinualRun(sequence, tiny_pool["out"]).final_checkpoint("coda_kvm")}

    def summary(per_method: dict) -> dict:
        return {
            m: [(r["kind"], r["attempt"], r["outcome"], r["steps"]) for run in runs for r in run["records"]]
            for m, runs in per_method.items()
        }

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as each of two workers on two cores
    try:
        serial = Benchmark(config, tmp_path / "serial", progress=False)._all_runs(checkpoints, tqdm(disable=True))
    finally:
        torch.set_num_threads(threads)
    parallel_bench = Benchmark(config, tmp_path / "parallel", progress=False, workers=2)
    parallel = parallel_bench._all_runs(checkpoints, tqdm(disable=True))
    assert summary(parallel) == summary(serial)
    assert all((tmp_path / "parallel" / "episodes" / m / "run_0.json").exists() for m in config.methods)


@pytest.mark.slow
def test_the_skill_matrix_forces_each_skill_of_the_pool_alone(tiny_pool) -> None:
    from lerobot_kvm.evaluation.skill_matrix import CORE, skill_matrix

    sequence = SequenceConfig.from_json(CONFIGS / "cl_tiny.json")
    checkpoint = ContinualRun(sequence, tiny_pool["out"]).final_checkpoint("coda_kvm")
    policy, pre, post = load_policy("coda_prompt", checkpoint)
    matrix = skill_matrix(policy, pre, post, ["egg_vs_stone"], episodes=1)
    assert matrix["columns"] == ["egg_vs_stone/prior", "egg_vs_stone/shifted"]
    assert [r["skill"] for r in matrix["rows"]] == [*(s.name for s in policy.skills), CORE]
    for row in matrix["rows"]:
        for cell in row["cells"].values():
            assert cell["episodes"] == 1 and cell["success"] + cell["catastrophe"] <= 1.0


@pytest.mark.slow
def test_kvm_settings_reach_every_validity_method_under_its_own_switches(tiny_pool):
    checkpoint = ContinualRun(SequenceConfig.from_json(CONFIGS / "cl_tiny.json"), tiny_pool["out"]).final_checkpoint(
        "coda_kvm"
    )
    settings = {"gap_on_failure": False, "smart_gate": True}
    kvm_on, _, _ = load_policy("coda_kvm", checkpoint)
    assert kvm_on.config.kvm.gap_on_failure is True  # the pool's own setting
    for method, switches in KVM_METHODS.items():
        policy, _, _ = load_policy(method, checkpoint, kvm=settings)
        assert policy.config.kvm.gap_on_failure is False, method
        assert policy.config.kvm.smart_gate == switches.get("smart_gate", True), method
        for key, value in switches.items():
            assert getattr(policy.config.kvm, key) == value, (method, key)


def test_a_resumed_benchmark_refuses_settings_that_change_its_episodes(tmp_path, monkeypatch):
    class PoolReached(Exception):
        pass

    def grow_pool(self):
        raise PoolReached

    monkeypatch.setattr(Benchmark, "grow_pool", grow_pool)
    config = BenchmarkConfig("b", str(CONFIGS / "cl_tiny.json"), ["book"], methods=["coda_kvm"], passes=2)
    for same in (config, replace(config, methods=["coda_kvm", "act"], runs=3, trace_plots=0)):
        with pytest.raises(PoolReached):  # more methods or runs extend the directory
            Benchmark(same, tmp_path, progress=False).run()
    with pytest.raises(ValueError, match=r"a benchmark's episodes and overhead made with other settings \(passes"):
        Benchmark(replace(config, passes=3), tmp_path, progress=False).run()
    with pytest.raises(ValueError, match=r"\(device: \"cpu\" -> \"cuda\"\)"):  # its timings name one device
        Benchmark(config, tmp_path, progress=False, device="cuda").run()


# The full configuration's Diffusion Policy shrunk for a test: two denoising steps, a small U-Net, a short horizon.
TINY_DIFFUSION = [
    "--policy.type=diffusion",
    "--policy.pretrained_backbone_weights=null",
    "--policy.use_group_norm=true",
    "--policy.n_obs_steps=2",
    "--policy.horizon=8",
    "--policy.n_action_steps=4",
    "--policy.drop_n_last_frames=3",
    "--policy.down_dims=[16,32]",
    "--policy.crop_shape=[84,84]",
    "--policy.noise_scheduler_type=DDIM",
    "--policy.num_inference_steps=2",
]


@pytest.mark.slow
def test_a_diffusion_policy_trained_by_lerobot_train_acts_and_fine_tunes_as_a_peer_row(tmp_path) -> None:
    """The `diffusion` row's path, on a policy `lerobot-train` trained for 2 steps on one recorded episode: loaded
    by `load_policy`, one attempt through `run_attempt` (LeRobot's processors and `select_action` with its
    observation history), and one feedback step of `finetune` on a corrective demonstration."""
    pytest.importorskip("diffusers", reason="LeRobot's Diffusion Policy needs lerobot[diffusion]")
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    from lerobot_kvm.benchmark.lerobot_commands import run_logged, train_command
    from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset
    from lerobot_kvm.envs.env import KvmObsolescenceEnv
    from lerobot_kvm.evaluation.rollouts import expert_rollout, run_attempt

    spec = RecordingSpec(name="tiny_diffusion", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 1)])
    record_dataset(spec, tmp_path / "data", repo_id="local/tiny_diffusion", progress=False)
    cmd = train_command(tmp_path / "data", "local/tiny_diffusion", tmp_path / "train", 2, 4, 0, policy=TINY_DIFFUSION)
    run_logged(cmd, tmp_path / "train.log")
    policy, pre, post = load_policy("diffusion", tmp_path / "train" / "checkpoints" / "last" / "pretrained_model")
    assert isinstance(policy, DiffusionPolicy) and not policy.training

    env = KvmObsolescenceEnv("egg_vs_stone", variant="shifted")
    try:
        attempt = run_attempt(policy, env, pre, post, seed=1)
        demo, _ = expert_rollout(env, "gentle_grasp", pre, seed=2)
    finally:
        env.close()
    assert attempt["outcome"] in ("success", "failure", "catastrophe") and attempt["trace"] is None
    assert episode_fields(attempt)["series"] is None
    before = {k: v.clone() for k, v in policy.state_dict().items()}
    info = finetune(policy, demo, steps=1, lr=1e-3, batch_size=4)
    assert set(info) == {"loss"} and np.isfinite(info["loss"])
    assert any(not torch.equal(v, before[k]) for k, v in policy.state_dict().items())
    assert not policy.training and all(len(q) == 0 for q in policy._queues.values())  # reset for the next attempt
