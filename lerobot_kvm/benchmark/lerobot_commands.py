"""Command lines of LeRobot's own CLIs (`lerobot-train`, `lerobot-eval`) as our pipelines run them.

Pipelines run the real tools as subprocesses and print each command, so that every stage can be copied and
varied by hand.
"""

import itertools
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

POLL_S = 5.0  # how often a running command is checked
# How long a command may outlive its completed work (`run_logged`): a `lerobot-train` stage exits 3-4 s after its
# final checkpoint, and a rank that hangs in the teardown instead held a tiny pool's build 120 s each time.
TEARDOWN_GRACE_S = 30.0
LOADER_WORKERS = 1  # DataLoader workers of a single-process `lerobot-train`
PR_SET_PDEATHSIG = 1  # prctl(2): the signal the calling process gets when its parent dies


def available_cores() -> int:
    """The cores this process may run on (the affinity mask where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def training_threads(workers: int) -> int:
    """Torch threads for a training process that shares the cores with `workers` batch-loading processes: a
    thread per remaining core. With torch's default (one per core) on two cores, its threads and the loader
    fight for the same core and a training step takes about 40 % longer."""
    return max(1, available_cores() - workers)


def lerobot_bin(name: str) -> str:
    """The console script next to this interpreter (the venv's), else from PATH."""
    local = Path(sys.executable).parent / name
    return str(local) if local.exists() else name


def program_name(cmd: Sequence[str]) -> str:
    """The program a command line runs (past an `env NAME=value ...` prefix)."""
    args = list(cmd)
    if args and Path(args[0]).name == "env":
        args = list(itertools.dropwhile(lambda a: re.match(r"[A-Za-z_]\w*=", a), args[1:]))
    return Path(args[0]).name


def run_logged(
    cmd: Sequence[str],
    log: Path | None = None,
    done: Callable[[], bool] | None = None,
    grace_s: float = TEARDOWN_GRACE_S,
) -> None:
    """Run `cmd`, printing it first; with `log`, its output goes to that file (quoted on failure).

    `done` tells when the command's work is complete (e.g. its final checkpoint is written). A command still
    running `grace_s` seconds after that is stopped with its whole process group and counts as finished: under a
    multi-process launcher a rank can hang in the process-group teardown after training has ended (gloo's
    `destroy_process_group`), which would otherwise block the pipeline forever."""
    print("\n$ " + shlex.join(cmd), flush=True)
    if log is None:
        subprocess.run(list(cmd), check=True)
        return
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as handle:
        proc = subprocess.Popen(list(cmd), stdout=handle, stderr=subprocess.STDOUT, preexec_fn=_child_of_pipeline)
        try:
            returncode = _wait(proc, done, grace_s)
        except BaseException:
            _stop_group(proc)
            raise
    if returncode is None:
        note = f"{program_name(cmd)} was still running {grace_s:.0f} s after its work was complete: stopped"
        print(f"warning: {note} (log: {log})", flush=True)
        with log.open("a") as handle:
            handle.write(f"\n{note}\n")
    elif returncode:
        tail = "".join(log.read_text().splitlines(keepends=True)[-40:])
        raise RuntimeError(f"{program_name(cmd)} failed with exit code {returncode} (log: {log}):\n{tail}")


def _child_of_pipeline() -> None:
    """In the child, before it runs the command: its own session (so it can be stopped with its whole group), and
    the parent-death signal (`die_with_parent`)."""
    os.setsid()
    die_with_parent()


def die_with_parent() -> None:
    """On Linux, a SIGTERM to the calling process when its parent dies, however it dies (SIGKILL included), so that
    no trainer or benchmark worker outlives its pipeline and races the next run into the same output directory."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _wait(proc: subprocess.Popen, done: Callable[[], bool] | None, grace_s: float) -> int | None:
    """The exit code, or None when the process outlived its completed work by `grace_s` and was stopped."""
    completed_at: float | None = None
    while True:
        try:
            return proc.wait(timeout=POLL_S)
        except subprocess.TimeoutExpired:
            pass
        if completed_at is None:
            completed_at = time.monotonic() if done is not None and done() else None
        elif time.monotonic() - completed_at > grace_s:
            _stop_group(proc)
            return None


def _stop_group(proc: subprocess.Popen) -> None:
    """Terminate the process and everything it started (its own session), killing what ignores SIGTERM."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=POLL_S)
            return
        except subprocess.TimeoutExpired:
            continue


def train_command(
    dataset_root: Path,
    repo_id: str,
    output_dir: Path,
    steps: int,
    batch_size: int,
    seed: int,
    policy: Sequence[str] = ("--policy.type=coda_kvm",),
    episodes: Sequence[int] | None = None,
    extra: Sequence[str] = (),
    launcher: Sequence[str] = (),
    device: str = "cpu",
    save_every: int | None = None,
) -> list[str]:
    """`lerobot-train` on a local dataset (optionally a subset of its episodes); `policy` names the policy
    (`--policy.type=...` or `--policy.path=...`), `launcher` prefixes a multi-process launcher, `device` is
    torch's (`cpu`, `cuda`, ...); a checkpoint is saved every `save_every` steps (default: at the end only).

    Under a launcher every rank loads its batches in its own process (no DataLoader worker): the ranks
    already fill the cores (torchrun gives each one thread), and a worker's shutdown at exit can leave a rank
    hanging after training. A single process loads in one worker and, unless OMP_NUM_THREADS is set, runs with
    `training_threads` (set through `env`, so that the printed command reproduces the run)."""
    workers = 0 if launcher else LOADER_WORKERS
    cmd = [*_train_prefix(launcher, workers), lerobot_bin("lerobot-train"), *policy]
    cmd += [
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={dataset_root}",
        "--policy.push_to_hub=false",
        f"--policy.device={device}",
        f"--output_dir={output_dir}",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        f"--save_freq={save_every or steps}",
        f"--log_freq={max(1, min(100, steps // 4))}",
        f"--num_workers={workers}",
        f"--seed={seed}",
        "--wandb.enable=false",
    ]
    if episodes is not None:
        cmd.append("--dataset.episodes=[" + ",".join(str(e) for e in episodes) + "]")
    return [*cmd, *extra]


def resume_command(run_dir: Path, steps: int, launcher: Sequence[str] = ()) -> list[str]:
    """`lerobot-train` resuming the run in `run_dir` from its last checkpoint (optimizer and data order included)
    until it has trained `steps` steps in all; every other setting is the run's own (its `train_config.json`) but
    the output directory, which stays `run_dir` wherever the run was first made."""
    config = run_dir / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    prefix = _train_prefix(launcher, 0 if launcher else LOADER_WORKERS)
    resume = [f"--config_path={config}", "--resume=true", f"--output_dir={run_dir}", f"--steps={steps}"]
    return [*prefix, lerobot_bin("lerobot-train"), *resume]


def _train_prefix(launcher: Sequence[str], workers: int) -> list[str]:
    """What runs `lerobot-train`: the multi-process launcher, or the thread count of a single process."""
    if launcher:
        return [lerobot_bin(launcher[0]), *launcher[1:]]
    if "OMP_NUM_THREADS" in os.environ:
        return []
    return ["env", f"OMP_NUM_THREADS={training_threads(workers)}"]


def eval_command(
    policy_path: Path,
    output_dir: Path,
    task: str,
    variant: str,
    episodes: int,
    seed: int,
    instruction: str = "variant",
    extra: Sequence[str] = (),
    device: str = "cpu",
) -> list[str]:
    """`lerobot-eval` of a checkpoint on scenario(s) `task` of the simulated suite, the policy on `device`."""
    return [
        lerobot_bin("lerobot-eval"),
        f"--policy.path={policy_path}",
        "--env.type=kvm_obsolescence",
        f"--env.task={task}",
        f"--env.variant={variant}",
        f"--env.instruction={instruction}",
        f"--eval.n_episodes={episodes}",
        f"--eval.batch_size={min(episodes, 10)}",
        "--eval.use_async_envs=false",
        f"--policy.device={device}",
        f"--output_dir={output_dir}",
        f"--seed={seed}",
        *extra,
    ]
