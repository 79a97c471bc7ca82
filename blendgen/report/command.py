"""`blendgen report OUT`."""

from __future__ import annotations

from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("report", help="(re)build OUT/report/: contact sheet, label plots, realism, timings",
                              description="Rebuild OUT/report/ from a job folder's frames, labels and run "
                                          "summary: clean and annotated composites, label statistics, realism "
                                          "and timings (index.md). Renders nothing.")
    p.add_argument("out", type=Path, help="a job's output folder")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from blendgen.report import build_report

    print(f"report: {build_report(args.out)}")
    return 0
