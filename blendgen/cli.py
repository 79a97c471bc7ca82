"""`blendgen` command line. User mistakes print one clear message and exit 2, no traceback."""

from __future__ import annotations

import argparse
import importlib
import sys

from blendgen import __version__
from blendgen.errors import StageError, UserError

# Stage modules that add their own subcommands through `register(subparsers)`.
COMMAND_MODULES = [
    "blendgen.pipeline.commands",       # run, validate, status
    "blendgen.sync.command",            # sync
    "blendgen.pipeline.import_command", # import
    "blendgen.eval.command",            # realism
    "blendgen.train.command",           # train-check (torch, an optional extra, imported when it runs)
    "blendgen.report.command",          # report
    "blendgen.twin.command",            # twin import / show
    "blendgen.analysis.calibrate",      # calibrate
    "blendgen.render.gpu_kernels",      # gpu-kernels
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="blendgen",
        description="Turn real driving recordings into larger, rarer, perfectly labelled training sets.")
    parser.add_argument("--version", action="version", version=f"blendgen {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name and name.startswith(e.name):  # that stage is not built yet
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as e:
        print(f"blendgen: error: {e}", file=sys.stderr)
        return e.exit_code
    except StageError as e:
        print(f"blendgen: failed: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("blendgen: interrupted; finished work is kept, run the same command to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
