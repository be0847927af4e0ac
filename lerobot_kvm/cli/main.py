"""`lerobot-kvm`: the project's own commands (LeRobot's CLIs do training and evaluation)."""

import argparse
import signal
import sys

from . import (
    benchmark,
    catalogue,
    check_suite,
    contact_sheet,
    kvm_check,
    overhead,
    record,
    train_continual,
    walkthrough,
)

COMMANDS = {
    "record": record,
    "train-continual": train_continual,
    "benchmark": benchmark,
    "walkthrough": walkthrough,
    "check-suite": check_suite,
    "contact-sheet": contact_sheet,
    "catalogue": catalogue,
    "overhead": overhead,
    "kvm-check": kvm_check,
}


def exit_on_sigterm() -> None:
    """A SIGTERM unwinds like Ctrl-C: the `lerobot-train` / `lerobot-eval` a pipeline started runs in its own
    session (see `run_logged`) and is stopped on the way out, and half-written outputs are cleaned up."""

    def _exit(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _exit)


def main(argv: list[str] | None = None) -> int:
    exit_on_sigterm()
    parser = argparse.ArgumentParser(prog="lerobot-kvm", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS.values():
        module.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileExistsError, FileNotFoundError) as err:
        print(f"lerobot-kvm {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
