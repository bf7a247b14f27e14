"""dlo-experiments --out RUNS --collect RESULTS (was scripts/collect_results.sh): the small
files of every finished run, the same layout, copied only when they differ, the run directories
added or updated printed; unfinished runs and big files never; a missing RUNS is one line, exit 2."""

import os
from pathlib import Path

from dlo_policy import experiments

SMALL = ("config.yaml", "eval.csv", "done.json", "best.json", "test.json", "test_without_T.json")
BIG = ("checkpoint.pt", "policy.pt", "best_policy.pt", "train.log")


def make_runs(root: Path) -> Path:
    for run in ("All/seed1", "All/seed2", "group/V+K/seed1"):
        for name in SMALL + BIG:
            (root / run).mkdir(parents=True, exist_ok=True)
            (root / run / name).write_text(f"{run} {name}\n")
    (root / "All/seed3").mkdir(parents=True)  # not finished: no done.json
    for name in ("config.yaml", "eval.csv", "checkpoint.pt"):
        (root / "All/seed3" / name).write_text("partial\n")
    return root


def test_collect_copies_the_record_of_finished_runs_only(tmp_path, capsys):
    runs, results = make_runs(tmp_path / "runs"), tmp_path / "results"
    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(results / r) for r in ("All/seed1", "All/seed2", "group/V+K/seed1")]
    for run in ("All/seed1", "All/seed2", "group/V+K/seed1"):
        assert sorted(p.name for p in (results / run).iterdir()) == sorted(SMALL)
        assert (results / run / "eval.csv").read_text() == f"{run} eval.csv\n"
    assert not (results / "All/seed3").exists()

    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out == ""  # nothing changed: nothing copied, nothing printed
    (runs / "All/seed2/eval.csv").write_text("more rows\n")
    (runs / "All/seed3/done.json").write_text("{}\n")
    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out.split() == [str(results / "All/seed2"), str(results / "All/seed3")]
    assert (results / "All/seed2/eval.csv").read_text() == "more rows\n"
    assert sorted(p.name for p in (results / "All/seed3").iterdir()) == ["config.yaml", "done.json", "eval.csv"]


def test_collect_from_a_missing_directory_is_one_line(tmp_path, capsys):
    assert experiments.main(["--out", str(tmp_path / "nothing"), "--collect", str(tmp_path / "results")]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.strip() == f"dlo-experiments: error: --collect: no directory {tmp_path / 'nothing'}"
    assert not (tmp_path / "results").exists()


def test_collect_copies_a_changed_file_of_the_same_size_and_time(tmp_path, capsys):
    """--collect copies a file 'only when it differs': by content, so an edit that keeps the size and
    the modification time is still copied."""
    runs, results = tmp_path / "runs", tmp_path / "results"
    run = runs / "V" / "seed0"
    run.mkdir(parents=True)
    for name in ("config.yaml", "eval.csv", "done.json"):
        (run / name).write_text(f"{name} first\n")
    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out.split() == [str(results / "V" / "seed0")]
    copied = results / "V" / "seed0" / "eval.csv"
    stat = copied.stat()
    (run / "eval.csv").write_text("eval.csv fixed\n")  # same length
    os.utime(run / "eval.csv", ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert (run / "eval.csv").stat().st_size == stat.st_size
    assert experiments.main(["--out", str(runs), "--collect", str(results)]) == 0
    assert capsys.readouterr().out.split() == [str(results / "V" / "seed0")]
    assert copied.read_text() == "eval.csv fixed\n"
