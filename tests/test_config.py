"""One config behind the CLI and the API: generated flags, TOML files, the resolved config kept."""

import argparse
import json
from dataclasses import fields
from pathlib import Path

import pytest

import goldenticket
from goldenticket.cli import _parser, main
from goldenticket.config import (
    EvaluateConfig,
    SearchConfig,
    TrainConfig,
    cli_fields,
    read_toml,
    to_toml,
)
from goldenticket.errors import OptionError, flag

HERE = Path(__file__).parent
BYO = ["--policy", "byo_example:make_policy", "--task", "byo_example:make_env"]
TINY = ["--method", "rs", "--budget", "12", "--search-seeds", "2", "--heldout", "4", "--top-k", "1",
        "--validation-seeds", "0", "--workers", "1", "--max-steps", "10"]


def field_flags(config_fields) -> set[str]:
    """The flags these config fields take: each one's, and the --no- form of a switch on by default."""
    flags = set()
    for f in config_fields:
        flags.add(f.metadata["cli"].get("flag", flag(f.name)))
        if f.metadata["cli"].get("action") is argparse.BooleanOptionalAction:
            flags.add("--no-" + flag(f.name).removeprefix("--"))
    return flags


def _flags(command: str) -> set[str]:
    sub = next(a for a in _parser()._actions if a.dest == "command").choices[command]
    return {s for a in sub._actions for s in a.option_strings}


@pytest.mark.parametrize("command, cls", [("search", SearchConfig), ("evaluate", EvaluateConfig),
                                          ("train", TrainConfig)])
def test_every_field_is_a_flag_and_every_flag_a_field(command, cls):
    own = {"-h", "--help", "--config", "--out", "--plot", "--json"}
    assert _flags(command) - own == field_flags(cli_fields(cls)) and len(cli_fields(cls)) == len(fields(cls))


def test_the_api_names_fields_and_the_command_line_names_flags(tmp_path, capsys):
    with pytest.raises(OptionError, match=r"^search_seeds must be > 0, got 0$"):
        goldenticket.search("byo_example:make_policy", "byo_example:make_env", tmp_path / "a", search_seeds=0)
    assert main(["search", *BYO, "--search-seeds", "0", "--out", str(tmp_path / "b")]) == 2
    assert capsys.readouterr().err == "goldenticket: error: --search-seeds must be > 0, got 0\n"
    with pytest.raises(OptionError, match="^policy must be given$"):
        goldenticket.config.make(SearchConfig, {"task": "x"})
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_train_options_are_checked_by_field_before_any_work(tmp_path, capsys):
    with pytest.raises(OptionError, match=r"^n_exec 9 cannot exceed horizon 8$"):
        TrainConfig(task="metaworld/reach-v3", n_exec=9).check()
    for argv, said in ((["--n-exec", "9"], "--n-exec 9 cannot exceed --horizon 8"),
                       (["--action-noise", "-1"], "--action-noise must be >= 0, got -1.0"),
                       (["--batch", "0"], "--batch must be > 0, got 0")):
        assert main(["train", "--task", "metaworld/reach-v3", *argv, "--out", str(tmp_path / "p")]) == 2
        assert capsys.readouterr().err == f"goldenticket: error: {said}\n"
    assert not (tmp_path / "p").exists()


def test_a_flag_given_twice_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["search", *BYO, "--budget", "5", "--budget", "6", "--out", str(tmp_path / "x")])
    assert exit_.value.code == 2 and "--budget given twice" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_repeats_from_its_folder_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(HERE))
    first = tmp_path / "first"
    assert main(["search", *BYO, *TINY, "--out", str(first)]) == 0
    saved = read_toml(first / "config.toml")
    assert saved["budget"] == 12 and saved["task"] == "byo_example:make_env" and "address" not in saved
    again = tmp_path / "again"
    assert main(["search", "--config", str(first / "config.toml"), "--out", str(again)]) == 0
    same_paths = (first / "summary.json").read_text().replace(str(first), str(again))
    assert (again / "summary.json").read_text() == same_paths
    assert (again / "config.toml").read_text() == (first / "config.toml").read_text()


@pytest.mark.slow
def test_flags_override_the_config_file(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    file = tmp_path / "run.toml"
    file.write_text(to_toml(SearchConfig("byo_example:make_policy", "byo_example:make_env", "rs", 8,
                                         search_seeds=2, heldout=4, top_k=1, validation_seeds=0, max_steps=10,
                                         workers=1)))
    out = tmp_path / "run"
    assert main(["search", "--config", str(file), "--budget", "12", "--out", str(out)]) == 0
    assert read_toml(out / "config.toml")["budget"] == 12
    assert json.loads((out / "summary.json").read_text())["search_episodes"] == 12


@pytest.mark.parametrize("text, says", [("budget = ", "not a TOML file"),
                                        ("budget = 5\nbudgett = 3\n", "unknown option budgett"),
                                        ("budget = -1\n", "--budget must be > 0")])
def test_a_bad_config_file_is_one_line(tmp_path, capsys, text, says):
    file = tmp_path / "run.toml"
    file.write_text(text)
    assert main(["search", *BYO, "--config", str(file), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


@pytest.mark.slow
def test_evaluate_takes_a_config_file_with_a_seed_range(tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(HERE))
    file = tmp_path / "eval.toml"
    file.write_text('policy = "byo_example:make_policy"\ntask = "byo_example:make_env"\n'
                    'seeds = "1000000:1000004"\nworkers = 1\nmax_steps = 10\n')
    assert main(["evaluate", "--config", str(file), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows["base"]["n"] == 4
    typed = goldenticket.evaluate("byo_example:make_policy", "byo_example:make_env",
                                  seeds=range(1_000_000, 1_000_004), workers=1, max_steps=10)
    assert rows == {label: row.to_dict() for label, row in typed.items()}
    assert typed["base"].rate.n == 4 and len(typed["base"].successes) == 4


def test_one_ticket_given_alone_is_one_ticket_not_its_characters():
    assert EvaluateConfig("p", tickets="abc.safetensors").tickets == ("abc.safetensors",)
    assert SearchConfig("p", "t", tickets=Path("a/b.safetensors")).tickets == ("a/b.safetensors",)
    assert SearchConfig("p", "t", tickets=["x", Path("y")]).tickets == ("x", "y")
