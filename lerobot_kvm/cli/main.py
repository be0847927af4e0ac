"""`lerobot-kvm`: the project's own commands (LeRobot's CLIs do training and evaluation)."""

import argparse
import importlib
import signal
import sys

# command -> (its module in this package, one line of help). A command's module, and the libraries it needs, is
# imported only when that command runs or shows its own help: `lerobot-kvm --help` imports neither torch nor LeRobot.
COMMANDS = {
    "record": ("record", "record scripted-expert episodes into a LeRobotDataset"),
    "train-continual": ("train_continual", "train a task sequence with lerobot-train and report CL metrics"),
    "benchmark": ("benchmark", "the knowledge-obsolescence benchmark: challenge protocol, report, plots"),
    "walkthrough": ("walkthrough", "record, train and evaluate coda_kvm on egg_vs_stone"),
    "check-suite": ("check_suite", "run the scripted experts on every scenario and check the thresholds"),
    "contact-sheet": ("contact_sheet", "one PNG: each scenario at reset and after the prior skill, both variants"),
    "catalogue": ("catalogue", "write the Markdown scenario catalogue from the registry"),
    "overhead": ("overhead", "KVM latency overhead: off vs gate closed vs gate open (ratios)"),
    "kvm-check": ("kvm_check", "KVM validity per scenario after one failure and its feedback"),
    "skill-matrix": ("skill_matrix", "each skill of a checkpoint forced alone on each scenario variant"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI's parser; only `command`'s own arguments are loaded (every other command is listed by name)."""
    parser = argparse.ArgumentParser(prog="lerobot-kvm", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if name == command:
            importlib.import_module(f"{__package__}.{module}").add_arguments(p)
    return parser


def exit_on_sigterm() -> None:
    """A SIGTERM unwinds like Ctrl-C: the `lerobot-train` / `lerobot-eval` a pipeline started runs in its own
    session (see `run_logged`) and is stopped on the way out, and half-written outputs are cleaned up."""

    def _exit(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _exit)


def main(argv: list[str] | None = None) -> int:
    exit_on_sigterm()
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(command if command in COMMANDS else None).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"lerobot-kvm {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
