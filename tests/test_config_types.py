"""Every option is checked against its field's type, from a TOML file and from the Python API alike."""

import re
from pathlib import Path

import pytest

import goldenticket
from goldenticket.cli import main
from goldenticket.config import EvaluateConfig, SearchConfig, TrainConfig, make
from goldenticket.errors import OptionError

RUN = 'policy = "byo_example:make_policy"\ntask = "byo_example:make_env"\n'


@pytest.mark.parametrize("line, said", [
    ('budget = "32"', "--budget must be of type int, got '32' (str)"),
    ("budget = 32.5", "--budget must be of type int, got 32.5 (float)"),
    ("budget = true", "--budget must be of type int, got True (bool)"),
    ("workers = [1, 2]", "--workers must be of type int, got [1, 2] (list)"),
    ("search_seeds = 4.7", "--search-seeds must be of type int, got 4.7 (float)"),
    ('max_nonfinite = "x"', "--max-nonfinite must be of type float, got 'x' (str)"),
    ("no_regression = 1", "--no-regression must be of type bool, got 1 (int)"),
    ('log = [1]', "--log must be of type tuple[str, ...] | str, got [1] (list)"),
])
def test_a_config_value_of_the_wrong_type_is_one_line(tmp_path, capsys, line, said):
    file = tmp_path / "run.toml"
    file.write_text(RUN + line + "\n")
    assert main(["search", "--config", str(file), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == f"goldenticket: error: {said}\n"
    assert not (tmp_path / "o").exists()


def test_a_task_of_the_wrong_type_is_one_line(tmp_path, capsys):
    file = tmp_path / "run.toml"
    file.write_text('policy = "p"\ntask = 7\n')
    assert main(["search", "--config", str(file), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == ("goldenticket: error: --task must be of type str | Callable | "
                                       "tuple[str, ...], got 7 (int)\n")


def test_train_and_evaluate_files_are_checked_too(tmp_path, capsys):
    file = tmp_path / "train.toml"
    file.write_text('task = "metaworld/reach-v3"\ndemos = 2.0\n')
    assert main(["train", "--config", str(file), "--out", str(tmp_path / "p")]) == 2
    assert capsys.readouterr().err == "goldenticket: error: --demos must be of type int, got 2.0 (float)\n"
    file.write_text('policy = "p"\nseeds = 5\n')
    assert main(["evaluate", "--config", str(file)]) == 2
    assert "--seeds must be of type Sequence[int], got 5 (int)" in capsys.readouterr().err


@pytest.mark.parametrize("options, said", [
    ({"budget": True}, "budget must be of type int, got True (bool)"),
    ({"budget": 32.5}, "budget must be of type int, got 32.5 (float)"),
    ({"top_k": "3"}, "top_k must be of type int, got '3' (str)"),
    ({"tickets": 5}, "tickets must be of type tuple[str | Path, ...] | str | Path, got 5 (int)"),
    ({"task": ("a", 7)}, "task must be of type str | Callable | tuple[str, ...], got ('a', 7) (tuple)"),
])
def test_the_api_checks_types_naming_fields(tmp_path, options, said):
    with pytest.raises(OptionError, match=f"^{re.escape(said)}$") as caught:
        goldenticket.search("p", options.pop("task", "t"), tmp_path / "o", **options)
    assert caught.value.names == (next(iter(options), "task"),)
    assert not (tmp_path / "o").exists()


def test_what_each_type_allows():
    cfg = make(SearchConfig, {"policy": object(), "task": ["a", "b"], "max_nonfinite": 1, "tickets": "x",
                              "log": "tensorboard", "success": len, "max_steps": None})
    assert cfg.task == ("a", "b") and cfg.max_nonfinite == 1 and cfg.tickets == ("x",)
    assert make(SearchConfig, {"policy": "p", "task": len, "tickets": [Path("a"), "b"]}).tickets == ("a", "b")
    assert make(EvaluateConfig, {"policy": "p", "seeds": [1_000_000, 1_000_001]}).seeds[1] == 1_000_001
    assert make(TrainConfig, {"task": "t", "grasp_offset": 0}).grasp_offset == 0
    with pytest.raises(OptionError, match=r"^seeds must be of type Sequence\[int\], got '1000000:1000002'"):
        make(EvaluateConfig, {"policy": "p", "seeds": "1000000:1000002"})
