"""A benchmark killed mid-run leaves no process behind and a journal that --resume finishes, with the results of
an uninterrupted run."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from superex_deploy.cli import main
from superex_deploy.parallel import read_journal

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["benchmark", "--maps", "50052750", "--planners", "nearest,mapex", "--steps", "250", "--jobs", "2"]


def _descendants(pid: int) -> set[int]:
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            parents.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigterm_stops_every_worker_and_resume_finishes_with_identical_results(deterministic_episodes, tmp_path,
                                                                              capsys):
    reference = tmp_path / "reference"
    assert main(ARGS + ["--out", str(reference)]) == 0
    out = tmp_path / "killed"
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "superex_deploy.cli", *ARGS, "--out", str(out)], cwd=ROOT,
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    journal = out / "episodes.jsonl"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and len(read_journal(journal)) < 1:
        time.sleep(0.2)
    workers = _descendants(process.pid)
    assert len(workers) >= 2  # the fork server and the pool's workers
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143 and "rerun with --resume" in stderr  # 128 + SIGTERM, as a shell reports
    time.sleep(1.0)
    assert not [pid for pid in workers if _alive(pid)], "a worker outlived the benchmark"
    held = len(read_journal(journal))
    assert 1 <= held < 8 and not (out / "results.json").exists()

    assert main(ARGS + ["--out", str(out)]) == 2  # a folder holding a run needs --resume
    assert "pass --resume" in capsys.readouterr().err
    assert main(ARGS + ["--out", str(out), "--resume"]) == 0
    assert len(read_journal(journal)) == 8
    assert deterministic_episodes(out) == deterministic_episodes(reference)
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest", "--steps", "100", "--out", str(out),
                 "--resume"]) == 2
    assert "other settings" in capsys.readouterr().err


def test_bad_output_folders_are_refused_before_anything_is_written(tmp_path, capsys):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest", "--out", str(a_file)]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest", "--steps", "0",
                 "--out", str(tmp_path / "new")]) == 2
    assert "--steps must be >= 1" in capsys.readouterr().err and not (tmp_path / "new").exists()
    assert main(["explore", "--map", "50052750", "--steps", "0", "--out", str(tmp_path / "e")]) == 2
    assert not (tmp_path / "e").exists()
    assert main(["explore", "--map", "50052750", "--pose", "0", "0", "--out", str(tmp_path / "p")]) == 2
    assert "outside the valid" in capsys.readouterr().err and not (tmp_path / "p").exists()


def test_a_journal_cut_mid_line_keeps_its_complete_records(tmp_path):
    journal = tmp_path / "episodes.jsonl"
    journal.write_text('{"key": "a", "result": 1}\n{"key": "b", "result": 2}\n{"key": "c", "res')
    assert read_journal(journal) == {"a": 1, "b": 2}
    journal.write_text('{"key": "a", "result": 1}\nnot json\n{"key": "c", "result": 3}\n')
    with pytest.raises(ValueError, match="line 2 is not a journal record"):
        read_journal(journal)


def _double(x):
    return 2 * x


def test_a_journal_cut_mid_line_resumes_without_losing_a_record(tmp_path):
    from superex_deploy.parallel import LocalBackend, run_tasks

    journal = tmp_path / "episodes.jsonl"
    journal.write_text('{"key": "a", "result": 2}\n{"key": "b", "res')  # killed while writing b
    assert run_tasks(_double, [1, 2, 3], ["a", "b", "c"], LocalBackend(1), journal) == [2, 4, 6]
    assert read_journal(journal) == {"a": 2, "b": 4, "c": 6}
    assert journal.read_text().count("\n") == 3  # every record on a line of its own
