"""The record under results/ is what the docs say it is: every reported number was computed on the
episodes (seeds) the docs name, and the committed files are the ones `dlo-experiments --collect`
copies. Reads committed files only (no training, no evaluation)."""

import csv
import json
import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
SHIPPED_README = ROOT / "ros_ws" / "src" / "dlo_policy" / "policies" / "all" / "README.md"
OUTCOMES = ("hold_the_end", "stop_before", "reach_end_but_drop", "drop_before")
RECORD_FILES = {"config.yaml", "eval.csv", "done.json", "best.json"}  # + test*.json


def finished_runs():
    return sorted(done.parent for done in RESULTS.rglob("done.json"))


def table(text: str, first_cell: str) -> dict[str, list[str]]:
    """The markdown table whose header starts with ``first_cell``: {first cell: the other cells}."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_cell}"))
    rows = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        rows[cells[0]] = cells[1:]
    return rows


def percent_pair(cell: str) -> tuple[float, float]:
    """'95% / 92%' or '**96% / 90%**' -> (0.95, 0.92)."""
    paper, authors = re.findall(r"([\d.]+)%", cell)
    return float(paper) / 100, float(authors) / 100


def test_the_record_has_finished_runs_and_only_their_small_files():
    """docs/RESULTS.md (How results are measured): every finished run's small files (config.yaml, eval.csv,
    done.json, best.json, test*.json; training_configs_seed*.json where its best policy was also evaluated on its
    own training episodes; randomised.csv of a run trained with domain randomisation; init_from.json of a run
    started from another's checkpoint) are under results/; never
    checkpoints, policies or bags."""
    runs = finished_runs()
    assert len(runs) >= 40
    for run in runs:
        names = {p.name for p in run.iterdir()}
        assert RECORD_FILES <= names and "test.json" in names, run
        assert all(
            n in RECORD_FILES
            or re.fullmatch(r"test(_without_[KTV])?\.json|training_configs_seed\d+\.json|randomised\.csv|init_from\.json", n)
            for n in names
        ), (run, names)
    assert not [p for p in RESULTS.rglob("*") if p.suffix in (".pt", ".mcap", ".db3")]


@pytest.mark.parametrize("run", finished_runs(), ids=lambda run: str(run.relative_to(RESULTS)))
def test_each_recorded_number_was_computed_on_the_documented_episodes(run):
    """docs/RESULTS.md (Fresh evaluation episodes, Held-out test), dlo-train --help: evaluation k of a run
    with seed s ran on seeds 1,000,000 + 100,000 s + 10 k + (0..9), every tested input set on the same
    ones; the held-out test of the best evaluation's policy on seeds 5000-5099."""
    config = yaml.safe_load((run / "config.yaml").read_text())
    seed, every = config["seed"], config["train"]["eval_every"]
    assert run.name == f"seed{seed}"
    with (run / "eval.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and int(rows[0]["step"]) == 0
    for row in rows:
        k = int(row["step"]) // every
        assert int(row["step"]) == k * every and int(row["episodes"]) == 10
        assert int(row["eval_seed"]) == 1_000_000 + 100_000 * seed + 10 * k, (row["step"], row["tested_without"])
    tested = {row["tested_without"] for row in rows}
    for path in run.glob("test*.json"):
        test = json.loads(path.read_text())
        assert (test["seed"], test["episodes"]) == (5000, 100), path.name
        without = "".join(test.get("without", []))
        assert path.name == (f"test_without_{without}.json" if without else "test.json") and without in tested
    # docs/RESULTS.md (The study, evaluation on training configurations): the best policy on the run's first and
    # last 100 training episodes, whose seeds are the run's seed, seed + 1, ... (one env, dlo_policy.env)
    training_configs = sorted(run.glob("training_configs_seed*.json"))
    episodes = json.loads((run / "done.json").read_text())["episodes"] if training_configs else None
    for path in training_configs:
        test = json.loads(path.read_text())
        assert path.name == f"training_configs_seed{test['seed']}.json" and test["episodes"] == 100, path.name
        assert test["seed"] in (seed, seed + episodes - 100) and test["checkpoint"].endswith("/best_policy.pt"), path.name
        assert test["without"] == [] and test["modalities"] == config["modalities"], path.name


def test_each_study_trained_on_its_documented_task_rules_and_length():
    """docs/FIDELITY.md, docs/RESULTS.md: results/study trained 50,000 steps under authors_code with the
    one-particle grip, results/study_15k the same for 15,000 steps, results/study_authors_code under
    authors_code with our grip, results/study_paper_text under paper_text (its runs predate the field: no
    task_rules in config.yaml reads as paper_text; a run without single_particle_grip predates that option:
    our grip); every finished run of a study has the study's length."""
    from dlo_policy.rundir import read_trained_config

    studies = (
        ("study", "authors_code", True, 50_000),
        ("study_15k", "authors_code", True, 15_000),
        ("study_authors_code", "authors_code", False, 15_000),
        ("study_paper_text", "paper_text", False, 15_000),
    )
    for study, rules, one_particle, steps in studies:
        runs = sorted((RESULTS / study).glob("*/seed*"))
        assert runs, study
        for run in runs:
            config = read_trained_config(run)
            options = config.env_options
            assert (options["task_rules"], options.get("single_particle_grip", False)) == (rules, one_particle), run
            assert config.train.total_steps == steps, run
            with (run / "eval.csv").open(newline="") as f:
                assert int(list(csv.DictReader(f))[-1]["step"]) == steps, run


def fractions(episodes, key):
    return {o: sum(e[key] == o for e in episodes) / len(episodes) for o in OUTCOMES}


def test_the_shipped_policys_numbers_are_its_record_on_seeds_7000_to_7099():
    """ros_ws/src/dlo_policy/policies/all/README.md: the shipped policy's numbers on seeds 7000-7099,
    in-process (dlo-evaluate --seed 7000 --episodes 100 [--without T|V]) and through the graph
    (launch_graph.sh --episodes 100 --seed 7000, task rules authors_code), are the committed record's;
    README.md's example run (seeds 7000-7002) prints the record's first three episodes."""
    rows = table(SHIPPED_README.read_text(), "tested (seeds 7000-7099)")
    records = {
        "All, in-process": ("in_process_7000.json", []),
        "without T (`--without T`), in-process": ("in_process_7000_noT.json", ["T"]),
        "without V (`--without V`), in-process": ("in_process_7000_noV.json", ["V"]),
    }
    for label, (name, without) in records.items():
        record = json.loads((RESULTS / "shipped" / name).read_text())
        assert (record["seed"], record["episodes"], record["without"]) == (7000, 100, without), name
        for outcome, cell in zip(OUTCOMES, rows[label]):
            assert percent_pair(cell) == pytest.approx((record[outcome], record["authors_code"][outcome])), (label, outcome)
    graph = [json.loads(line) for line in (RESULTS / "shipped" / "graph_seeds7000-7099.jsonl").read_text().splitlines()]
    assert [e["seed"] for e in graph] == list(range(7000, 7100)) and [e["episode"] for e in graph] == list(range(100))
    assert {e["task_rules"] for e in graph} == {"authors_code"}
    paper, authors = fractions(graph, "outcome"), fractions(graph, "outcome_authors")
    for outcome, cell in zip(OUTCOMES, rows["All, through the graph"]):
        assert percent_pair(cell) == pytest.approx((paper[outcome], authors[outcome])), outcome
    readme = (ROOT / "README.md").read_text()
    for e in graph[:3]:
        line = (
            f"[launch] episode {e['episode']} (seed {e['seed']}; {e['episode'] + 1}/3 done): {e['outcome']}, "
            f"authors' rule {e['outcome_authors']}; return {e['episode_return']:.3f}, {e['episode_length']} steps, "
            f"{e['how_far']} particles from the end"
        )
        assert line in readme, line


def test_the_previous_policys_graph_run_is_its_record():
    """docs/RESULTS.md (Shipped policy): through the graph, seeds 7000-7099, 96% / 90% Hold the end,
    outcomes in results/baselines/shipped_policy_graph_seeds7000-7099.jsonl (the policy shipped until
    2026-12-02, policies/all/README.md)."""
    graph = [
        json.loads(line)
        for line in (RESULTS / "baselines" / "shipped_policy_graph_seeds7000-7099.jsonl").read_text().splitlines()
    ]
    assert [e["seed"] for e in graph] == list(range(7000, 7100))
    assert (fractions(graph, "outcome")["hold_the_end"], fractions(graph, "outcome_authors")["hold_the_end"]) == pytest.approx(
        (0.96, 0.90)
    )
    assert "scored 96% / 90% on the same seeds" in (ROOT / "docs" / "RESULTS.md").read_text()


def test_the_shipped_policys_graph_run_is_its_record():
    """docs/RESULTS.md (Shipped policy): through the graph, seeds 7000-7099, the same Hold the end under both
    rules as in-process (results/shipped/in_process_7000.json), outcomes in
    results/shipped/graph_seeds7000-7099.jsonl, run with the grip the policy was trained with."""
    from dlo_policy.rundir import shipped_policy_path, trained_sim_settings

    graph = [json.loads(line) for line in (RESULTS / "shipped" / "graph_seeds7000-7099.jsonl").read_text().splitlines()]
    in_process = json.loads((RESULTS / "shipped" / "in_process_7000.json").read_text())
    assert [e["seed"] for e in graph] == list(range(7000, 7100))
    assert {e["single_particle_grip"] for e in graph} == {trained_sim_settings(shipped_policy_path())["single_particle_grip"]}
    paper, authors = fractions(graph, "outcome"), fractions(graph, "outcome_authors")
    for outcome in OUTCOMES:
        assert (paper[outcome], authors[outcome]) == pytest.approx((in_process[outcome], in_process["authors_code"][outcome])), (
            outcome
        )
    same = f"the same {round(100 * paper['hold_the_end'])}% / {round(100 * authors['hold_the_end'])}%"
    assert same in (ROOT / "docs" / "RESULTS.md").read_text(), same


def test_the_policy_shipped_until_2026_12_03_is_its_record():
    """docs/RESULTS.md (Shipped policy): the policy replaced on 2026-12-03 scored 95% / 92% on seeds 7000-7099
    through the graph, its records and README in results/baselines/shipped_until_2026-12-03/."""
    folder = RESULTS / "baselines" / "shipped_until_2026-12-03"
    graph = [json.loads(line) for line in (folder / "graph_seeds7000-7099.jsonl").read_text().splitlines()]
    assert [e["seed"] for e in graph] == list(range(7000, 7100))
    assert (fractions(graph, "outcome")["hold_the_end"], fractions(graph, "outcome_authors")["hold_the_end"]) == pytest.approx(
        (0.95, 0.92)
    )
    in_process = json.loads((folder / "in_process_7000.json").read_text())
    assert (in_process["hold_the_end"], in_process["authors_code"]["hold_the_end"]) == pytest.approx((0.95, 0.92))
    assert (
        "scored 95% / 92% on the\nsame seeds (`results/baselines/shipped_until_2026-12-03/`)"
        in (ROOT / "docs" / "RESULTS.md").read_text()
    )


def test_the_scripted_baselines_are_their_record_on_seeds_0_to_199():
    """docs/RESULTS.md (Scripted baselines) and the dlo_policy README: 200 seeded episodes, seeds 0-199,
    every policy on the same episodes; the outcome fractions are those of results/baselines/."""
    text = (RESULTS / "baselines" / "eval_scripted_200.md").read_text()
    record = json.loads(next(line for line in text.splitlines() if line.startswith("{")))
    assert (record["episodes"], record["seed"]) == (200, 0)
    policies = record["policies"]
    assert all(p["episodes"] == 200 for p in policies.values())
    results_rows = table((ROOT / "docs" / "RESULTS.md").read_text(), "policy | hold the end | stop before")
    names = {
        "random": "random",
        "oracle (ground truth, stops 2 particles before the end)": "oracle",
        "oracle stopping at particle n_c - 10": "oracle-stop-at-10",
        "tactile-reactive (She et al. style)": "tactile",
    }
    assert set(results_rows) == set(names)
    for label, key in names.items():
        for outcome, cell in zip(OUTCOMES, results_rows[label]):
            assert percent_pair(cell) == pytest.approx((policies[key][outcome], policies[key]["authors_code"][outcome])), (
                label,
                outcome,
            )
    readme_rows = table((ROOT / "ros_ws" / "src" / "dlo_policy" / "README.md").read_text(), "policy | hold the end")
    for label, key in (("random", "random"), ("oracle", "oracle"), ("tactile-reactive", "tactile")):
        cells = readme_rows[label]
        for outcome, cell in zip(OUTCOMES, cells):  # paper rule (this table is run with --task-rules paper_text)
            assert float(cell.rstrip("%")) / 100 == pytest.approx(policies[key][outcome]), (label, outcome)
