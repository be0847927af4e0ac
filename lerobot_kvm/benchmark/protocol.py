"""`lerobot-kvm benchmark`: the knowledge-obsolescence challenge protocol (docs/benchmark.md).

1. **Pool.** A continual-learning sequence (`train-continual` config) grows the skill pool with the real
   `lerobot-train`: `coda_kvm` stage by stage, each LeRobot peer (ACT, Diffusion Policy) as its own method. Its
   metrics are part of the results.
2. **Challenge.** For each method, run r = 1..R (the pretrained checkpoint loaded afresh, its own seeds) and pass
   p = 1..P (what a method learns is kept across passes), each scenario in turn: attempt 1 on the shifted variant;
   after a failure the feedback, then attempt 2 on a new episode of the same variant (its own seed, so that
   remembering attempt 1's initial state does not help). The feedback is the same information for every method:
   the failed attempt's trace, one corrective demonstration (the safe skill's scripted expert on the shifted
   variant, another seed) and `feedback_steps` gradient steps. `coda_kvm` and its ablations spend it in the KVM's
   feedback API; the baselines (the CODA core with the KVM off, the LeRobot peers) fine-tune their trainable
   parameters on the demonstration. A validity method's successful attempts report their outcome to the feedback
   API without gradient steps (the metabolism and the hypotheses count the challenge's interactions).
3. **Controls**, interleaved after every challenge: the scenario's prior variant (the old skill is still right)
   and, where the scenario has one, its benign-novelty `control` variant. Controls are measurements: no method
   learns from them (nothing is reported to the feedback API; no weight or memory changes).
4. **Validity probes** before each first attempt (validity methods): v and E of the scenario's prior skill along
   the scripted experts' shifted-variant contexts (from the step the shift shows: hazardous) and along the prior
   skill's expert on the prior variant (safe), same seed. The prior skill's shifted expert's catastrophe step is
   the reference for the detection lead.

The unit of resumption is one pass of one (method, run): a finished run's episode records are reused by a later
invocation, and an interrupted run resumes at the pass after its last finished one, from the policy that pass
left behind. Nothing the policy sees carries the variant, object parameters or hazard labels.
"""

import json
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from ..datasets.json_config import build, check_counts, read_json
from ..envs.catalogue import SCENARIO_INFOS, scenario_info
from ..envs.env import KvmObsolescenceEnv
from ..evaluation.rescue import Envelope
from ..evaluation.rollouts import expert_rollout, load_checkpoint, run_attempt
from ..evaluation.validity_check import CONTEXT, shift_step
from ..kvm.configuration import KvmConfig
from ..kvm.supervisor import FEEDBACK_LR
from ..policy.feedback import FOCUSED_LR, skill_by_name
from .continual import ContinualRun, SequenceConfig, training_minutes
from .estimate import Estimate, estimate
from .lerobot_commands import die_with_parent
from .lock import hold
from .resume import check_settings

# Methods evaluated on the `coda_kvm` pool checkpoint, with the KVM settings that make them.
KVM_METHODS: dict[str, dict[str, Any]] = {
    "coda_kvm": {},
    "coda_prompt": {"enabled": False},
    "no_smart_gate": {"smart_gate": False},
    "no_energy_model": {"risk_model": "bce"},
    "novelty_detector": {"risk_model": "novelty"},  # §4.3's generic OOD monitor: suppress everything where novel
}
# LeRobot's own policies, compared as they come: each row starts from the final checkpoint of the sequence method
# that a `BenchmarkConfig` field names (a method of the sequence training the LeRobot policy type of the same name).
PEER_METHODS: dict[str, str] = {"act": "act_method", "diffusion": "diffusion_method"}
# Diagnostic rows on the `coda_kvm` pool checkpoint, KVM off, told what no method may know (the variant, where the
# shift shows): privileged, reported apart and never counted as methods. `oracle_skill` forces the scenario's safe
# skill from the first step of a shifted episode (its prior skill elsewhere); `oracle_switch` forces the prior skill
# until the sensed context first leaves the prior variant's envelope, then the safe skill. They bound what any
# supervisor could reach with this pool and separate detection losses from switching losses.
ORACLE_METHODS = ("oracle_skill", "oracle_switch")
ENVELOPE_RUNS = 10  # prior-variant episodes of the prior skill that make `oracle_switch`'s envelope (per scenario)
CONTROL_KINDS = ("prior", "control")
# Settings an output directory may change between invocations: which methods and runs (each method's runs are
# kept apart), the plots drawn, and the name; the pool's own settings are checked by its sequence run.
FREE_SETTINGS = ("name", "methods", "runs", "trace_plots", "sequence", "dataset_root")


@dataclass
class BenchmarkConfig:
    name: str
    sequence: str  # the `train-continual` config that grows the pool
    scenarios: list[str]
    methods: list[str] = field(default_factory=lambda: list(KVM_METHODS))
    kvm_method: str = "coda_kvm"  # the sequence's method whose final checkpoint the validity methods start from
    act_method: str = "act_joint"  # the sequence's method whose final checkpoint the `act` row starts from
    diffusion_method: str = "diffusion_joint"  # ... and the `diffusion` row
    runs: int = 1
    passes: int = 3
    seed: int = 0
    feedback_steps: int = 100
    finetune_lr: float = 1e-4
    finetune_batch: int = 16
    controls: list[str] = field(default_factory=lambda: list(CONTROL_KINDS))
    overhead_steps: int = 100
    trace_plots: int = 6
    dataset_root: str | None = None  # overrides the sequence's dataset location
    # KVM settings every validity method loads with, over the pool checkpoint's (a method's own switches win);
    # shapes cannot change: a setting that resizes a network fails at loading
    kvm: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.methods or not self.scenarios:
            raise ValueError(f"a benchmark needs methods and scenarios, got {self.methods} and {self.scenarios}")
        known = [*KVM_METHODS, *PEER_METHODS, *ORACLE_METHODS]
        unknown = [m for m in self.methods if m not in known]
        if unknown:
            raise ValueError(f"unknown methods {unknown}; known: {known}")
        missing = [s for s in self.scenarios if s not in SCENARIO_INFOS]
        if missing:
            raise ValueError(f"unknown scenarios {missing}; known: {sorted(SCENARIO_INFOS)}")
        bad = [c for c in self.controls if c not in CONTROL_KINDS]
        if bad:
            raise ValueError(f"controls must be among {CONTROL_KINDS}, got {bad}")
        check_counts(
            self,
            {"runs": 1, "passes": 1, "feedback_steps": 0, "finetune_batch": 1, "overhead_steps": 1, "trace_plots": 0},
        )
        unknown_kvm = sorted(set(self.kvm) - {f.name for f in fields(KvmConfig)})
        if unknown_kvm:
            raise ValueError(f"`kvm` has unknown settings {unknown_kvm}")
        replace(KvmConfig(), **self.kvm)  # the KVM's own checks of the values

    @classmethod
    def from_json(cls, path: str | Path) -> "BenchmarkConfig":
        return build(cls, read_json(path), str(path))

    def pool_method(self, method: str) -> str:
        """The sequence method whose final checkpoint a row starts from: a peer's own, else `kvm_method`."""
        return getattr(self, PEER_METHODS[method]) if method in PEER_METHODS else self.kvm_method


# An episode's role within one scenario of one pass: its seed is `episode_seed(...) + offset`.
SEED_OFFSETS = {"attempt_1": 0, "demonstration": 1, "prior": 2, "control": 3, "attempt_2": 4}


def episode_seed(base: int, run: int, pass_: int, index: int, offset: int = 0) -> int:
    """Seeds far from the recording (0..) and CL evaluation (100000..) seeds, distinct per episode role."""
    return 200_000 + base + 10_000 * run + 1_000 * pass_ + 10 * index + offset


# ---------------------------------------------------------------------------- policies
def load_policy(
    method: str,
    checkpoint: Path,
    weights: Path | None = None,
    kvm: dict[str, Any] | None = None,
    device: str = "cpu",
) -> tuple[Any, Any, Any]:
    """(policy, preprocessor, postprocessor) of a method on `device`: the policy from its pool checkpoint (or from
    `weights`, the state a resumed run had reached), the processors always from the pool checkpoint. `kvm`:
    settings over the checkpoint's KVM config, under the method's own switches."""
    if method in KVM_METHODS:
        kvm = {**(kvm or {}), **KVM_METHODS[method]}
    elif method in ORACLE_METHODS:
        kvm = {"enabled": False}
    else:  # a peer: its checkpoint has no KVM
        kvm = None
    return load_checkpoint(checkpoint, weights, kvm, device)


# Every other method is compared with this one by a paired interval on each rate's difference (docs/benchmark.md).
REFERENCE_METHOD = "coda_kvm"


def feedback_budget(method: str, runs: list[dict[str, Any]], cfg: "BenchmarkConfig") -> dict[str, Any] | None:
    """What one method spent on its feedbacks: how many, the gradient steps each counted, and the step sizes (None
    for a diagnostic row, which learns nothing)."""
    if method in ORACLE_METHODS:
        return None
    steps = sorted({f["gradient_steps"] for run in runs for f in run["feedback"]})
    if uses_validity(method):
        rates = {"kvm_lr": FEEDBACK_LR, "new_skill_lr": FOCUSED_LR}
    else:
        rates = {"lr": cfg.finetune_lr, "batch": cfg.finetune_batch}
    return {
        "feedbacks": sum(len(run["feedback"]) for run in runs),
        "steps_each": steps,
        "budget": cfg.feedback_steps,
    } | rates


def uses_validity(method: str) -> bool:
    return method in KVM_METHODS and KVM_METHODS[method].get("enabled", True)


def on_kvm_pool(method: str) -> bool:
    """Whether the method runs from the `coda_kvm` pool checkpoint (every row but the peers')."""
    return method in KVM_METHODS or method in ORACLE_METHODS


def pool_family(method: str) -> str:
    """The key of the pool checkpoint a row starts from: "kvm" for the rows on the `coda_kvm` pool, else the peer's
    own name (each peer trains its own sequence method)."""
    return "kvm" if on_kvm_pool(method) else method


def delta_windows(values: Tensor, deltas: Sequence[int]) -> tuple[Tensor, Tensor]:
    """Windows [T, D, ...] of a trajectory [T, ...] at offsets `deltas` from each step, as LeRobot's dataset draws
    them for a policy's `*_delta_indices` (out-of-episode offsets copy the nearest frame), and their padding mask
    [T, D] (True where the offset leaves the episode)."""
    t_len, device = values.shape[0], values.device
    idx = torch.arange(t_len, device=device).unsqueeze(1) + torch.as_tensor(list(deltas), device=device)
    return values[idx.clamp(0, t_len - 1)], (idx < 0) | (idx >= t_len)


class SwitchOnExit:
    """`oracle_switch`'s skill weights: the prior skill's until the step whose raw sensed context first leaves the
    envelope, the safe skill's from that step on (`switch_step`)."""

    def __init__(self, envelope: Envelope, prior: Tensor, safe: Tensor) -> None:
        self.envelope, self.prior, self.safe = envelope, prior, safe
        self.switch_step: int | None = None

    def __call__(self, step: int, context: np.ndarray) -> Tensor:
        if self.switch_step is None and self.envelope.outside(step, context):
            self.switch_step = step
        return self.prior if self.switch_step is None else self.safe


def finetune(policy: Any, demo: dict[str, Any], steps: int, lr: float, batch_size: int) -> dict[str, float]:
    """A baseline's use of the feedback budget: `steps` Adam steps of its own training loss on the corrective
    demonstration, on the parameters its checkpoint trains (a `coda_kvm` pool trains its latest skill only). Each
    demonstration step becomes a training frame with the observation history and action targets the policy's
    config asks for (`observation_delta_indices`, `action_delta_indices`), as `lerobot-train` would draw it."""
    if steps <= 0:
        return {}
    config = policy.config
    keys = [k for k in config.input_features if isinstance(demo.get(k), torch.Tensor)]
    history = config.observation_delta_indices
    frames: dict[str, Any] = {k: demo[k] if history is None else delta_windows(demo[k], history)[0] for k in keys}
    frames["action"], frames["action_is_pad"] = delta_windows(demo["action"], config.action_delta_indices)
    tasks = list(demo["task"])
    params = [p for p in policy.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(params, lr=lr)
    kvm_config = getattr(policy.config, "kvm", None)
    learn_offline = kvm_config.learn_offline if kvm_config is not None else None
    if kvm_config is not None:
        kvm_config.learn_offline = False  # the KVM is off in a baseline: only the action loss is fine-tuned
    n = len(tasks)
    info: dict[str, float] = {}
    policy.train()
    try:
        with torch.enable_grad():
            for _ in range(steps):
                idx = torch.randperm(n)[:batch_size]
                batch = {k: v[idx] for k, v in frames.items()}
                batch["task"] = [tasks[i] for i in idx.tolist()]
                loss, info = policy.forward(batch)
                info = info or {"loss": loss.item()}  # Diffusion Policy reports no loss terms of its own
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
    finally:
        if kvm_config is not None:
            kvm_config.learn_offline = learn_offline
        optimizer.zero_grad(set_to_none=True)
        policy.eval()
        policy.reset()
    return {k: float(v) for k, v in info.items() if isinstance(v, int | float)}


def _run_unit(
    config: BenchmarkConfig, out: Path, device: str, threads: int, method: str, run: int, checkpoint: Path
) -> tuple[tuple[str, int], dict[str, Any]]:
    """A worker process's (method, run) unit: the same as `Benchmark.finish_run` in the parent, on `threads`."""
    torch.set_num_threads(threads)
    return (method, run), Benchmark(config, out, progress=False, device=device).finish_run(method, run, checkpoint)


def in_workers(fn: Callable[..., Any], jobs: Sequence[tuple], workers: int) -> Iterator[Any]:
    """fn(*job) for every job in `workers` spawned processes (no torch or simulator state inherited), each result as
    it completes. The workers end with this process however it ends: leaving the iteration (an error, a SIGTERM's
    exit) terminates them, and each has the parent-death signal for a SIGKILL. A worker left running would go on
    writing into the output directory that the next run, its lock released, works in."""
    with multiprocessing.get_context("spawn").Pool(workers, initializer=die_with_parent) as pool:
        yield from pool.imap_unordered(_call, [(fn, *job) for job in jobs])


def _call(job: tuple) -> Any:
    return job[0](*job[1:])


def begin_feedback_skill(policy: Any, name: str) -> dict[str, Any]:
    """A new CODA skill for a corrective demonstration: fresh components (Gram-Schmidt against every earlier row),
    the only prompt rows the fine-tuning then trains. With the pool full, the latest skill is fine-tuned instead."""
    if policy.n_skills >= policy.config.n_tasks:
        return {"created": False, "reason": f"the prompt pool is full ({policy.config.n_tasks} skills)"}
    index = policy.begin_new_skill(name, "learned from a corrective demonstration")
    return {"created": True, "index": index, "name": name}


# ---------------------------------------------------------------------------- episodes
def episode_fields(result: dict[str, Any], skills: Sequence[str] = ()) -> dict[str, Any]:
    """Outcome, length and the KVM's per-step series (None without a validity module) of one attempt; with the
    pool's skill names, also which skill carried the first step (`proposed`), which one carried the first step of
    the first intervention (`took_over`, None if the policy abstained there) and the first abstention step."""
    trace = result.get("trace")
    telemetry = [] if trace is None else [t for t in trace.telemetry if t is not None]
    fields: dict[str, Any] = {
        "outcome": result["outcome"],
        "steps": result["steps"],
        "catastrophe_kind": result["catastrophe_kind"],
        "series": None,
        "gate_steps": 0,
        "intervention_steps": 0,
        "first_intervention": None,
    }
    if not telemetry or len(telemetry) != len(trace.telemetry):
        return fields
    series = {
        "sigma2": [float(t.sigma2[0]) for t in telemetry],
        "tau": [float(t.tau) for t in telemetry],
        "gate": [int(t.gate[0]) for t in telemetry],
        "intervention": [int(t.intervention[0].any()) for t in telemetry],
    }
    hits = [i for i, x in enumerate(series["intervention"]) if x]
    fields.update(
        series=series,
        gate_steps=sum(series["gate"]),
        intervention_steps=len(hits),
        first_intervention=hits[0] if hits else None,
    )
    if skills:
        abstained = [i for i, t in enumerate(telemetry) if bool(t.abstained[0])]

        def carrier(step: int) -> str | None:
            """The skill with the largest decision weight at `step` (None where the policy abstained)."""
            weights = telemetry[step].skill_weight[0]
            held = bool(telemetry[step].abstained[0]) or not bool(weights.any())
            return None if held else skills[int(weights.argmax())]

        fields.update(
            proposed=carrier(0),
            took_over=carrier(hits[0]) if hits else None,
            first_abstention=abstained[0] if abstained else None,
        )
    return fields


@torch.no_grad()
def prior_skill_scores(policy: Any, demos: list[dict[str, Any]], skill: int) -> tuple[list[float], list[float]]:
    """(v, E) of one skill along demonstrations' contexts, the gate bypassed (the risk model's judgement)."""
    from ..kvm.energy import GAMMA, L0, validity

    kvm = policy.kvm
    v_all, e_all = [], []
    for demo in demos:
        if not len(demo["task"]):
            continue
        c_raw = kvm.raw_context(demo[CONTEXT], policy.encode_query(demo["task"]))
        mu, _, _ = kvm.encode(c_raw)
        energy = kvm.skill_energies(mu, policy.n_skills)[:, skill]
        v_all += validity(energy, GAMMA, L0).tolist()
        e_all += energy.tolist()
    return v_all, e_all


def skill_index(policy: Any, scenario: str, skill: str) -> int | None:
    """The pool's skill learned from `scenario`'s `skill` expert (named "<scenario>.<skill>" by the sequence)."""
    return skill_by_name(policy, f"{scenario}.{skill}")


def learned_skill(policy: Any, sequence: SequenceConfig, scenario: str, skill: str) -> int | None:
    """The pool's skill that learned `scenario`'s `skill` ("prior" or "safe") on its prior variant: a stage's own
    skill, or the pretraining skill (0); None when the pool never learned it."""
    expert = getattr(scenario_info(scenario), f"{skill}_skill")
    index = skill_index(policy, scenario, expert)
    if index is None and any((t.scenario, t.skill) == (scenario, skill) for t in sequence.pretrain_tasks):
        index = 0
    return index


def uncovered_scenarios(sequence: SequenceConfig, scenarios: Sequence[str]) -> list[str]:
    """Benchmark scenarios the pool does not cover: it never learned the prior skill as the challenge asks for it
    (the prior expert on the prior variant under the variant's own instruction), so the challenge tests no obsolete
    knowledge, or it holds no safe alternative to hand control to (the safe expert on the prior variant asked for by
    the instruction naming the strategy, or on the visibly different control: learned before any shifted frame)."""
    tasks = [*sequence.tasks, *sequence.pretrain_tasks]
    prior = {t.scenario for t in tasks if (t.variant, t.skill, t.instruction) == ("prior", "prior", "variant")}
    safe = {t.scenario for t in tasks if t.skill == "safe" and t.variant in ("prior", "control")}
    return [s for s in scenarios if s not in prior or s not in safe]


def _skill_names(policy: Any) -> list[str]:
    """The pool's skill names now (a `coda_kvm` policy; none for a peer)."""
    return [s.name for s in getattr(policy, "skills", [])]


def _switch_field(oracle: Any) -> dict[str, Any]:
    """`oracle_switch`'s switch step in its episode record (None: the context never left the envelope)."""
    return {"switch_step": oracle.switch_step} if isinstance(oracle, SwitchOnExit) else {}


def _from_step(demo: dict[str, Any], start: int) -> dict[str, Any]:
    return {k: (v[start:] if isinstance(v, torch.Tensor | list) else v) for k, v in demo.items()}


class Benchmark:
    def __init__(
        self,
        config: BenchmarkConfig,
        output_dir: str | Path,
        config_path: str = "",
        launcher: Sequence[str] = (),
        progress: bool = True,
        device: str = "cpu",
        workers: int = 1,
    ) -> None:
        """`launcher`: the multi-process launcher of the pool's `lerobot-train` stages (see `train-continual`);
        `device`: where the pool trains and every method runs (its timings are that device's); `workers`: worker
        processes that run the independent (method, run) units side by side (1: in this process)."""
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers
        self.config = config
        self.out = Path(output_dir)
        self.config_path = config_path
        self.launcher = list(launcher)
        self.device = device
        self.progress = progress
        self.sequence_path = Path(config.sequence)
        self.sequence = SequenceConfig.from_json(self.sequence_path)
        if config.dataset_root:
            self.sequence.dataset_root = config.dataset_root
        # pool checkpoint key ("kvm" or a peer's name) -> the sequence method that trains it
        self.families = {pool_family(m): config.pool_method(m) for m in config.methods}
        known = {m.name: m for m in self.sequence.methods}
        missing = [m for m in self.families.values() if m not in known]
        if missing:
            raise ValueError(f"{config.sequence} has no methods {missing} (it has {sorted(known)})")
        for peer in set(self.families) & set(PEER_METHODS):
            source = known[self.families[peer]]
            if source.policy != peer:
                raise ValueError(
                    f"{PEER_METHODS[peer]}={source.name!r} trains a {source.policy!r} policy, not {peer!r}"
                )
        self.pool_methods = list(dict.fromkeys(self.families.values()))
        self._envelopes: dict[tuple[int, str], Envelope] = {}
        self.pool = ContinualRun(
            self.sequence, self.out / "pool", self.launcher, str(self.sequence_path), self.pool_methods, device
        )

    def estimate(self) -> Estimate:
        """What this invocation costs from scratch on 2 CPU cores (`estimate`), printed before it starts."""
        cfg = self.config
        return estimate(
            self.sequence, self.pool_methods, cfg.methods, cfg.runs, cfg.passes, len(cfg.scenarios), self.workers
        )

    # ------------------------------------------------------------------ pool
    def grow_pool(self) -> tuple[dict[str, Any], dict[str, Path]]:
        """The continual-learning sequence (resumable), and the pool checkpoint of each method family."""
        results = self.pool.run()
        return results, {family: self.pool.final_checkpoint(m) for family, m in self.families.items()}

    # ------------------------------------------------------------------ one (method, run)
    def run_method(self, method: str, run: int, checkpoint: Path, bar: tqdm | None = None) -> dict[str, Any]:
        """Every pass of one run of one method, from the pool checkpoint loaded afresh. After each pass but the
        last, the policy (all it learned) and the records so far are kept under `run_<r>.partial/`, so that an
        interrupted run resumes at its next pass with the same result as an uninterrupted one."""
        cfg = self.config
        partial = self._partial_dir(method, run)
        done, out, weights = self._resume(partial)
        if out is None:
            out = {"method": method, "run": run, "records": [], "probes": [], "feedback": [], "wall_time_s": 0.0}
            out["feedback_time_s"] = 0.0
        policy, pre, post = load_policy(method, checkpoint, weights, cfg.kvm, self.device)
        if bar is not None:
            bar.update(done * len(cfg.scenarios))
        for pass_ in range(done + 1, cfg.passes + 1):
            started = time.time()
            torch.manual_seed(episode_seed(cfg.seed, run, pass_, 0))  # per pass: a resumed pass draws the same
            for i, scenario in enumerate(cfg.scenarios):
                if bar is not None:
                    bar.set_description(f"{method} run {run + 1} pass {pass_} {scenario}")
                base = {
                    "method": method,
                    "run": run,
                    "pass": pass_,
                    "scenario": scenario,
                    "category": scenario_info(scenario).category,
                }
                seed = episode_seed(cfg.seed, run, pass_, i)
                self._challenge(method, policy, pre, post, base, seed, out)
                self._controls(policy, pre, post, base, seed, out)
                if bar is not None:
                    bar.update()
            out["wall_time_s"] += time.time() - started
            if pass_ < cfg.passes:
                self._keep_pass(partial, pass_, policy, out)
        return out

    def _partial_dir(self, method: str, run: int) -> Path:
        return self.out / "episodes" / method / f"run_{run}.partial"

    @staticmethod
    def _resume(partial: Path) -> tuple[int, dict[str, Any] | None, Path | None]:
        """(passes done, their records, the policy they left) of an interrupted run; (0, None, None) if none."""
        states = sorted(partial.glob("pass_*.json"), key=lambda p: int(p.stem.split("_")[1]))
        if not states:
            return 0, None, None
        done = int(states[-1].stem.split("_")[1])
        return done, json.loads(states[-1].read_text()), partial / f"pass_{done}"

    @staticmethod
    def _keep_pass(partial: Path, pass_: int, policy: Any, out: dict[str, Any]) -> None:
        """The policy first, then the records that point to it: a state file only ever names a whole policy."""
        policy_dir = partial / f"pass_{pass_}"
        shutil.rmtree(policy_dir, ignore_errors=True)
        partial.mkdir(parents=True, exist_ok=True)
        policy.save_pretrained(policy_dir)
        tmp = partial / f"pass_{pass_}.tmp"
        tmp.write_text(json.dumps(out))
        tmp.replace(partial / f"pass_{pass_}.json")
        for older in range(1, pass_):
            (partial / f"pass_{older}.json").unlink(missing_ok=True)
            shutil.rmtree(partial / f"pass_{older}", ignore_errors=True)

    def _env(self, scenario: str, variant: str) -> KvmObsolescenceEnv:
        """The scenario's environment, sensing as the pool's datasets were recorded."""
        return KvmObsolescenceEnv(scenario, variant=variant)

    def _challenge(
        self, method: str, policy: Any, pre: Any, post: Any, base: dict[str, Any], seed: int, out: dict[str, Any]
    ) -> None:
        """Probe, attempt 1, and after a failure the feedback and attempt 2, on the shifted variant."""
        info = scenario_info(base["scenario"])
        env = self._env(base["scenario"], "shifted")
        try:
            reference, ref_outcome = expert_rollout(env, info.prior_skill, pre, seed=seed)
            if uses_validity(method):
                probe = self._probe(policy, pre, base, seed, reference)
                if probe is not None:
                    out["probes"].append(probe)
            challenge = {**base, "kind": "challenge", "seed": seed}
            oracle = self._oracle(method, policy, pre, post, base, "shifted")
            first = run_attempt(policy, env, pre, post, seed=seed, skill_weights=oracle)
            ref_step = len(reference["task"]) if ref_outcome == "catastrophe" else None
            out["records"].append(
                {**challenge, "attempt": 1, "reference_catastrophe_step": ref_step}
                | episode_fields(first, _skill_names(policy))
                | _switch_field(oracle)
            )
            if first["outcome"] == "success":
                out["records"][-1]["pruned"] = self._report(method, policy, first)
                return
            demo, demo_outcome = expert_rollout(env, info.safe_skill, pre, seed=seed + SEED_OFFSETS["demonstration"])
            started = time.time()
            feedback = self._feedback(method, policy, first, demo, base)
            out["feedback_time_s"] = out.get("feedback_time_s", 0.0) + time.time() - started
            out["feedback"].append({**base, "demonstration": demo_outcome, **feedback})
            second_seed = seed + SEED_OFFSETS["attempt_2"]
            oracle = self._oracle(method, policy, pre, post, base, "shifted")
            second = run_attempt(policy, env, pre, post, seed=second_seed, skill_weights=oracle)
            out["records"].append(
                {**challenge, "attempt": 2, "seed": second_seed, "reference_catastrophe_step": None}
                | episode_fields(second, _skill_names(policy))
                | _switch_field(oracle)
            )
            out["records"][-1]["pruned"] = self._report(method, policy, second)
        finally:
            env.close()

    def _probe(
        self, policy: Any, pre: Any, base: dict[str, Any], seed: int, reference: dict[str, Any]
    ) -> dict[str, Any] | None:
        """v and E of the scenario's prior skill. Hazardous: the shifted contexts both scripted experts sense once
        the shift shows (the prior skill's own attempt often ends at the harm, the safe skill's goes on); safe:
        the prior skill's expert on the prior variant. Same seed throughout."""
        scenario = base["scenario"]
        info = scenario_info(scenario)
        skill = skill_index(policy, scenario, info.prior_skill)
        if skill is None:
            return None
        rollouts = {}
        for variant in ("prior", "shifted"):
            env = self._env(scenario, variant)
            try:
                for expert in (info.prior_skill, info.safe_skill):
                    if (variant, expert) != ("shifted", info.prior_skill):
                        rollouts[variant, expert] = expert_rollout(env, expert, pre, seed=seed)[0]
            finally:
                env.close()
        rollouts["shifted", info.prior_skill] = reference
        hazardous = [
            _from_step(rollouts["shifted", e], shift_step(rollouts["prior", e], rollouts["shifted", e]))
            for e in (info.prior_skill, info.safe_skill)
        ]
        v_h, e_h = prior_skill_scores(policy, hazardous, skill)
        v_s, e_s = prior_skill_scores(policy, [rollouts["prior", info.prior_skill]], skill)
        return {**base, "v_hazard": v_h, "e_hazard": e_h, "v_safe": v_s, "e_safe": e_s}

    def _controls(self, policy: Any, pre: Any, post: Any, base: dict[str, Any], seed: int, out: dict[str, Any]) -> None:
        """The interleaved prior-variant and benign-novelty episodes of the scenario (where it has the variant).

        Measurements only: nothing is reported to the feedback API, so no method learns from a control."""
        variants = scenario_info(base["scenario"]).variants
        for kind in self.config.controls:
            if kind not in variants:
                continue
            env = self._env(base["scenario"], kind)
            try:
                oracle = self._oracle(base["method"], policy, pre, post, base, kind)
                result = run_attempt(policy, env, pre, post, seed=seed + SEED_OFFSETS[kind], skill_weights=oracle)
            finally:
                env.close()
            policy.reset()  # the control's trace is not kept for any later feedback
            record = {**base, "kind": kind, "attempt": 1, "seed": seed + SEED_OFFSETS[kind]}
            out["records"].append(record | episode_fields(result) | {"pruned": []})

    def _oracle(
        self, method: str, policy: Any, pre: Any, post: Any, base: dict[str, Any], variant: str
    ) -> Tensor | SwitchOnExit | None:
        """The skill weights a diagnostic row forces on one episode (None for a method, or where the pool lacks the
        scenario's prior or safe skill: the core then routes)."""
        if method not in ORACLE_METHODS:
            return None
        prior = learned_skill(policy, self.sequence, base["scenario"], "prior")
        safe = learned_skill(policy, self.sequence, base["scenario"], "safe")
        if prior is None or safe is None:
            return None
        prior_w, safe_w = policy.pool.own_weights(prior, 1), policy.pool.own_weights(safe, 1)
        if variant != "shifted":
            return prior_w
        if method == "oracle_skill":
            return safe_w
        return SwitchOnExit(self._envelope(policy, pre, post, base, prior_w), prior_w, safe_w)

    def _envelope(self, policy: Any, pre: Any, post: Any, base: dict[str, Any], prior: Tensor) -> Envelope:
        """The prior variant's sensed-context envelope under the pool's prior skill, from `ENVELOPE_RUNS` episodes
        on seeds of their own (pass 0's, which no challenge or control uses); built once per run and scenario."""
        key = (base["run"], base["scenario"])
        if key not in self._envelopes:
            index = self.config.scenarios.index(base["scenario"])
            env = self._env(base["scenario"], "prior")
            try:
                runs = [
                    run_attempt(
                        policy,
                        env,
                        pre,
                        post,
                        seed=episode_seed(self.config.seed, base["run"], 0, index, k),
                        skill_weights=prior,
                    )["contexts"]
                    for k in range(ENVELOPE_RUNS)
                ]
            finally:
                env.close()
            self._envelopes[key] = Envelope.fit(runs)
        return self._envelopes[key]

    def _feedback(
        self, method: str, policy: Any, attempt: dict[str, Any], demo: dict[str, Any], base: dict[str, Any]
    ) -> dict[str, Any]:
        """Spend the feedback budget after a failed first attempt; a short JSON-friendly report."""
        steps = self.config.feedback_steps
        if uses_validity(method):
            report = policy.kvm_feedback(attempt["outcome"], attempt["trace"], demonstration=demo, gradient_steps=steps)
            return {
                "gradient_steps": report["kvm_steps"] + report["skill_steps"],  # everything the mechanism trained
                "kvm_steps": report["kvm_steps"],
                "skill_steps": report["skill_steps"],
                "culprit": report.get("culprit"),
                "attribution": report.get("attribution"),
                "hypothesis": report.get("hypothesis"),
                "new_skill": report.get("new_skill"),
                "confirmed": report.get("confirmed"),
                "pruned": report.get("pruned"),
            }
        if method in ORACLE_METHODS:  # a diagnostic: it learns nothing
            return {"gradient_steps": 0}
        new_skill = None
        if method in KVM_METHODS:  # the KVM-off core learns the demonstration as CODA-Prompt learns anything new
            new_skill = begin_feedback_skill(policy, f"{base['scenario']}.feedback_p{base['pass']}")
        info = finetune(policy, demo, steps, self.config.finetune_lr, self.config.finetune_batch)
        return {"gradient_steps": steps, "finetune": info, "new_skill": new_skill}

    @staticmethod
    def _report(method: str, policy: Any, attempt: dict[str, Any]) -> list[int]:
        """Report an attempt's outcome without gradient steps (validity methods: metabolism and hypotheses).
        Returns the skills the metabolism pruned on this report."""
        if uses_validity(method):
            return list(policy.kvm_feedback(attempt["outcome"], attempt["trace"], gradient_steps=0)["pruned"])
        policy.reset()
        return []

    def _run_path(self, method: str, run: int) -> Path:
        return self.out / "episodes" / method / f"run_{run}.json"

    def finish_run(self, method: str, run: int, checkpoint: Path, bar: tqdm | None = None) -> dict[str, Any]:
        """One (method, run) unit, written whole to `episodes/<method>/run_<r>.json` once it is finished."""
        result = self.run_method(method, run, checkpoint, bar)
        path = self._run_path(method, run)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(result))
        tmp.replace(path)  # a finished run is never half-written
        shutil.rmtree(self._partial_dir(method, run), ignore_errors=True)
        return result

    def _all_runs(self, checkpoints: dict[str, Path], bar: tqdm) -> dict[str, list[dict[str, Any]]]:
        """Every (method, run) unit: finished ones read back, the others run here or in `workers` processes (the
        units are independent: each starts from the pool checkpoint with its own seeds)."""
        cfg = self.config
        per_unit = cfg.passes * len(cfg.scenarios)
        done: dict[tuple[str, int], dict[str, Any]] = {}
        pending = []
        for method in cfg.methods:
            for run in range(cfg.runs):
                path = self._run_path(method, run)
                if path.exists():
                    done[method, run] = json.loads(path.read_text())
                    bar.update(per_unit)
                else:
                    pending.append((method, run, checkpoints[pool_family(method)]))
        if self.workers == 1 or len(pending) < 2:
            for method, run, checkpoint in pending:
                done[method, run] = self.finish_run(method, run, checkpoint, bar)
        else:
            threads = max(1, (os.cpu_count() or 1) // self.workers)
            jobs = [(self.config, self.out, self.device, threads, *unit) for unit in pending]
            for (method, run), result in in_workers(_run_unit, jobs, min(self.workers, len(pending))):
                done[method, run] = result
                bar.set_description(f"{method} run {run + 1} done")
                bar.update(per_unit)
        return {method: [done[method, run] for run in range(cfg.runs)] for method in cfg.methods}

    # ------------------------------------------------------------------ everything
    def run(self) -> dict[str, Any]:
        """The whole run, holding the output directory (`lock.hold`) so that no second run works in it."""
        self.pool.check_dataset()  # before the lock and the settings: a refused run leaves nothing behind
        with hold(self.out):
            return self._run()

    def _run(self) -> dict[str, Any]:
        from . import metrics
        from .report import write_report

        start = time.time()
        kept = {k: v for k, v in asdict(self.config).items() if k not in FREE_SETTINGS} | {"device": self.device}
        check_settings(self.out, kept, "a benchmark's episodes and overhead")  # its timings name one device
        pool_results, checkpoints = self.grow_pool()
        pool_done = time.time()
        cfg = self.config
        total = len(cfg.methods) * cfg.runs * cfg.passes * len(cfg.scenarios)
        with tqdm(total=total, unit="challenge", disable=not self.progress) as bar:
            per_method = self._all_runs(checkpoints, bar)
        units_done = time.time()
        records = [r for runs in per_method.values() for run in runs for r in run["records"]]
        probes = [p for runs in per_method.values() for run in runs for p in run["probes"]]
        methods = {
            method: metrics.method_summary(
                [r for r in records if r["method"] == method],
                [p for p in probes if p["method"] == method],
                cfg.passes,
                uses_validity(method),
            )
            | {"wall_time_s": sum(run["wall_time_s"] for run in runs), "feedback": feedback_budget(method, runs, cfg)}
            for method, runs in per_method.items()
        }
        by_method = {method: [r for r in records if r["method"] == method] for method in per_method}
        reference = REFERENCE_METHOD if REFERENCE_METHOD in per_method else None
        differences = {
            method: metrics.paired_differences(by_method[method], by_method[reference], uses_validity(method))
            for method in per_method
            if reference is not None and method != reference
        }
        overhead = self.overhead(checkpoints["kvm"]) if "kvm" in checkpoints else None
        all_runs = [run for runs in per_method.values() for run in runs]
        time_breakdown = {  # this invocation's wall time by phase; the units' own seconds (over workers) beside it
            "pool_s": pool_done - start,
            "units_s": units_done - pool_done,
            "overhead_s": time.time() - units_done,
            "workers": self.workers,
            "unit_episodes_and_feedback_s": sum(run["wall_time_s"] for run in all_runs),
            "unit_feedback_s": sum(run.get("feedback_time_s", 0.0) for run in all_runs),
            # the pool's training as its stages recorded it: also when this invocation reused a built pool
            "pool_training_min": {m: training_minutes(r) for m, r in pool_results["methods"].items()},
        }
        results = {
            "benchmark": cfg.name,
            "config_path": self.config_path,
            "config": asdict(cfg),
            "pool": {
                "sequence": self.sequence.name,
                "checkpoints": {k: str(v) for k, v in checkpoints.items()},
                "continual_metrics": {m: r["metrics"] for m, r in pool_results["methods"].items()},
                "uncovered_scenarios": uncovered_scenarios(self.sequence, cfg.scenarios),
            },
            "methods": methods,
            "differences": {"reference": reference, "methods": differences},
            "overhead": overhead,
            "seeds": {"benchmark": cfg.seed, "pool": self.sequence.seed},
            "device": self.device,
            "versions": pool_results["versions"],
            "wall_time_s": time.time() - start,
            "time_breakdown": time_breakdown,
        }
        (self.out / "results.json").write_text(json.dumps(results, indent=2))
        write_report(results, records, probes, self.out)
        return results

    def overhead(self, checkpoint: Path) -> dict[str, Any]:
        """Per-step latency of the pool policy: KVM off (the backbone's step), gate closed, gate open; memory.

        Measured once per output directory and kept in `overhead.json` (timings need a quiet machine; a resumed
        run must not replace them with ones taken beside other work). Delete the file to measure again."""
        path = self.out / "overhead.json"
        if path.exists():
            return json.loads(path.read_text())
        from ..evaluation.overhead import measure_overhead, observation_inputs

        policy, _, _ = load_policy("coda_kvm", checkpoint, device=self.device)  # the checkpoint's own KVM settings
        batch, source = observation_inputs(policy, checkpoint, self.config.scenarios[0], "prior", self.config.seed)
        result = measure_overhead(policy, batch, steps=self.config.overhead_steps)
        kvm_bytes = sum(t.numel() * t.element_size() for t in policy.kvm.state_dict().values())
        total_bytes = sum(t.numel() * t.element_size() for t in policy.state_dict().values())
        result.update(inputs=source, kvm_state_mb=kvm_bytes / 2**20, policy_state_mb=total_bytes / 2**20)
        path.write_text(json.dumps(result, indent=2))
        return result
