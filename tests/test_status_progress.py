"""`blendgen status` while the in-process stages run (analysis, plan): no ledger exists yet."""

import argparse
import json

import pytest

from blendgen.pipeline.commands import cmd_status
from blendgen.pipeline.outputs import JobFolder, StageProgress


def test_progress_of_an_in_process_stage(tmp_path, capsys, monkeypatch):
    folder = JobFolder(tmp_path / "job")
    folder.root.mkdir()
    folder.resolved_job.write_text("name: x\n")
    cmd_status(argparse.Namespace(out=folder.root))
    assert "no frame has been rendered yet" in capsys.readouterr().out  # not an error
    with folder.lock():
        with folder.progress("analysis", 1000) as p:
            p(0, "road users")
            clock = [json.loads((folder.state / "progress.json").read_text())["started"]]
            monkeypatch.setattr("blendgen.pipeline.outputs.time.time", lambda: clock[0])
            clock[0] += 1.0
            p(3, "road users")  # within EVERY_S of the last write: not written
            assert json.loads((folder.state / "progress.json").read_text())["done"] == 0
            clock[0] += StageProgress.EVERY_S
            p(300, "road users")
            line = folder.progress_line()
            assert line.startswith("[analysis: road users] 300/1000 frames, running (pid")
            assert "100.00 frames/s" in line and "ETA 0m07s" in line, line
            p(0, "camera")  # a new phase is written at once, its rate from its own start
            assert folder.progress_line().startswith("[analysis: camera] 0/1000 frames, running")
            cmd_status(argparse.Namespace(out=folder.root))
            out = capsys.readouterr().out
            assert "[analysis: camera] 0/1000" in out and "no frame has been rendered" not in out
        assert folder.progress_line() is None  # the stage ended
        with pytest.raises(RuntimeError):
            with folder.progress("plan", 50) as p:
                clock[0] += StageProgress.EVERY_S
                p(20, "")
                raise RuntimeError("the process dies here")
    # cut short, and its process gone: run again
    assert folder.progress_line().startswith("[plan] 20/50 frames, stopped") and "run again" in folder.progress_line()
    with folder.lock():  # the next run starts afresh
        assert folder.progress_line() is None
    (folder.state / "progress.json").write_text('{"stage": "plan", "done": 3}')  # partial or foreign: ignored
    assert folder.progress_line() is None
