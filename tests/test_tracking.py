"""A search logged to log.csv, TensorBoard and W&B (offline), each read back with its own reader and
compared with summary.json; search.png redrawn while the search runs; a missing package refused."""

import csv
import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest
import torch

from goldenticket import tracking
from goldenticket.cli import main
from goldenticket.policies import MLPPolicy, PolicyConfig

HERE = Path(__file__).parent
SEARCH = ["search", "--policy", "byo_example:make_policy", "--task", "byo_example:make_env",
          "--max-steps", "10", "--method", "cma-es", "--budget", "90", "--search-seeds", "3",
          "--validation-seeds", "3", "--heldout", "5", "--top-k", "2", "--workers", "1"]


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """A search (two CMA-ES generations) logged to TensorBoard, then run again logged to every sink
    (resuming from its store: logging is not part of the run), with search.png due after every
    generation; the drawings made during the second run."""
    pytest.importorskip("tensorboard")
    pytest.importorskip("wandb")
    out, drawn, search_png = tmp_path_factory.mktemp("run"), [], tracking.search_png

    def draw(scores, episodes, path, title):
        drawn.append((len(scores), search_png(scores, episodes, path, title).read_bytes()[:4]))

    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(HERE))
        patch.setenv("WANDB_MODE", "disabled")  # the sink's own offline mode must win over this
        patch.setenv("WANDB_SILENT", "true")
        patch.setattr(tracking, "REDRAW_SECONDS", 0.0)
        patch.setattr(tracking, "search_png", draw)
        for sinks in ("tensorboard", "tensorboard,wandb"):
            drawn.clear()
            assert main([*SEARCH, "--log", sinks, "--out", str(out)]) == 0
    with (out / "log.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    return out, json.loads((out / "summary.json").read_text()), rows, drawn


def _last(rows: list[dict], stage: str) -> dict[tuple[str, str], float]:
    """(arm, metric) -> the last value of `stage` in log.csv."""
    return {(r["arm"], r["metric"]): float(r["value"]) for r in rows if r["stage"] == stage}


def _scalars(rows: list[dict]) -> dict[tuple[str, int], float]:
    """What TensorBoard and W&B hold as scalars: (tag, search episodes) -> value; the per-ticket search
    rows go into a histogram instead."""
    return {("/".join(filter(None, (r["stage"], r["task"], r["arm"], r["metric"]))), int(r["episodes"])):
            float(r["value"]) for r in rows if r["stage"] != "search" or r["arm"] == "best"}


def _generation_scores(rows: list[dict]) -> dict[int, list[float]]:
    """Search episodes at the end of each generation -> the scores of that generation's tickets."""
    scores = defaultdict(list)
    for r in rows:
        if r["stage"] == "search" and r["arm"] != "best" and r["metric"] == "score":
            scores[int(r["episodes"])].append(float(r["value"]))
    return dict(scores)


@pytest.mark.slow
def test_the_csv_log_holds_the_numbers_of_summary_json(logged):
    out, summary, rows, _ = logged
    assert list(rows[0]) == ["stage", "step", "episodes", "task", "arm", "metric", "value"]
    assert [r["stage"] for r in rows] == sorted((r["stage"] for r in rows), key=["search", "validation",
                                                                                 "verdict"].index)
    search = [r for r in rows if r["stage"] == "search"]
    assert {r["step"] for r in search} == {"1", "2"}
    assert int(rows[-1]["episodes"]) == summary["search_episodes"]
    scored, validated = _last(rows, "search"), _last(rows, "validation")
    for ticket in summary["tickets"]:
        if ticket["search_score"] is not None:
            assert scored[ticket["ticket_id"], "score"] == ticket["search_score"]
        assert validated[ticket["ticket_id"], "score"] == ticket["validation_score"]
    full = max(v for (_, metric), v in scored.items() if metric == "episodes")
    assert scored["best", "score"] == max(scored[arm, "score"] for (arm, metric), v in scored.items()
                                          if metric == "episodes" and v == full)
    verdict = _last(rows, "verdict")
    arms = {"base": summary["base"], "zero": summary["zero"]}
    arms |= {t["ticket_id"]: t for t in summary["tickets"]}
    numbers = {(arm, k): float(v) for arm, row in arms.items() for k, v in row.items()
               if isinstance(v, int | float)}
    assert verdict == numbers and any(metric.startswith("p_") for _, metric in verdict)


@pytest.mark.slow
def test_search_png_is_redrawn_while_the_search_runs(logged):
    _, _, rows, drawn = logged
    tickets_by_generation = [len({r["arm"] for r in rows if r["stage"] == "search" and r["arm"] != "best"
                                  and int(r["step"]) <= step}) for step in (1, 2)]
    assert drawn == [(n, b"\x89PNG") for n in tickets_by_generation]


@pytest.mark.slow
def test_tensorboard_reads_back_the_logged_numbers(logged):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out, _, rows, _ = logged
    events = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0, "histograms": 0})
    events.Reload()
    read = {(tag, e.step): e.value for tag in events.Tags()["scalars"] for e in events.Scalars(tag)}
    expected = _scalars(rows)
    assert read.keys() == expected.keys()  # the rerun replaced the first run's points
    assert all(read[k] == pytest.approx(v, rel=1e-6) for k, v in expected.items())  # float32 there
    histograms = {e.step: e.histogram_value for e in events.Histograms("search/scores")}
    scores = _generation_scores(rows)
    assert {step: (h.num, h.sum) for step, h in histograms.items()} == {
        step: (len(s), pytest.approx(sum(s))) for step, s in scores.items()}


@pytest.mark.slow
def test_wandb_keeps_an_offline_run_that_reads_back_the_logged_numbers(logged):
    pytest.importorskip("wandb", minversion="0.31")  # its reader of offline runs, `wandb leet inspect`
    out, _, rows, _ = logged
    [run] = (out / "wandb").glob("offline-run-*")
    inspected = subprocess.run([sys.executable, "-m", "wandb", "leet", "inspect", "--json", str(run)],
                               capture_output=True, text=True, timeout=120, check=True).stdout
    records = [json.loads(line) for line in inspected.splitlines()]
    history = [r["history"]["item"] for r in records if r["type"] == "history"]
    read = {(key, item["_step"]): value for item in history for key, value in item.items()
            if not key.startswith("_") and not key.startswith("search/scores")}
    assert read == _scalars(rows)
    scores = _generation_scores(rows)
    assert {item["_step"]: sum(item["search/scores.values"]) for item in history} == {
        step: len(s) for step, s in scores.items()}
    config = next(r["run"]["config"]["update"] for r in records if r["type"] == "run")
    assert config["budget"] == 90 and config["log"] == ["tensorboard", "wandb"]
    assert [r["exit"]["exit_code"] for r in records if r["type"] == "exit"] == [0]


@pytest.mark.slow
def test_a_multitask_log_holds_the_task_average_and_each_tasks_verdict(tmp_path):
    tasks = ["metaworld/reach-v3", "metaworld/drawer-close-v3"]
    torch.manual_seed(0)
    MLPPolicy(PolicyConfig("test/mt2/flow", "flow", 39, 4, hidden=32, layers=2, steps=3, tasks=tasks)).save(
        tmp_path / "policy")
    out = tmp_path / "run"
    assert main(["search", "--policy", str(tmp_path / "policy"), "--task", tasks[0], "--task", tasks[1],
                 "--budget", "8", "--search-seeds", "2", "--heldout", "2", "--max-steps", "10",
                 "--method", "rs", "--workers", "1", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    with (out / "log.csv").open(newline="") as f:
        logged = {(r["task"], r["arm"], r["metric"]): float(r["value"]) for r in csv.DictReader(f)
                  if r["stage"] == "verdict"}
    verdicts = {"": summary["average"]} | summary["tasks"]
    assert logged == {(task, arm, metric): float(value) for task, arms in verdicts.items()
                      for arm, row in arms.items() for metric, value in row.items()
                      if isinstance(value, int | float)}
    assert {task for task, _, _ in logged} == {"", *tasks}


@pytest.mark.parametrize("sink", ["tensorboard", "wandb"])
def test_a_missing_package_is_one_line_before_any_work(sink, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, sink, None)  # its import now fails, as where it is not installed
    out = tmp_path / "run"
    assert main([*SEARCH, "--log", f"{sink}", "--out", str(out)]) == 2
    assert capsys.readouterr().err == (f"goldenticket: error: --log {sink} needs the {sink} package: "
                                       f"pip install {sink}\n")
    assert not out.exists()


def test_an_unknown_sink_is_refused(tmp_path, capsys):
    assert main([*SEARCH, "--log", "tensorboard", "--log", "mlflow", "--out", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == ("goldenticket: error: unknown --log 'mlflow'; choose from "
                                       "tensorboard, wandb\n")
    assert not (tmp_path / "run").exists()
