"""Command-line input at its edges: seed ranges, policies' noise shapes, help, the task a bundled
policy implies, and the session and transfer flags made from their config fields."""

import argparse
import subprocess
import sys
from dataclasses import MISSING, fields

import pytest
from test_config import field_flags

import goldenticket
from goldenticket import cli, config
from goldenticket.cli import _parser, main
from goldenticket.config import SearchConfig, cli_fields
from goldenticket.errors import OptionError, UserError, flag
from goldenticket.policies import load_policy

POLICY = "metaworld/pick-place-v3/flow"


def _sub(*words: str) -> argparse.ArgumentParser:
    parser = _parser()
    for word in words:
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
    return parser


def _helps(*words: str) -> dict[str, str]:
    """Each option's help as --help prints it."""
    parser = _sub(*words)
    formatter = parser._get_formatter()
    return {a.option_strings[0]: formatter._expand_help(a) for a in parser._actions
            if a.option_strings and a.help}


def test_a_seed_range_beyond_the_seed_sets_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["evaluate", "--policy", "p", "--task", "t", "--seeds", "1000000:99999999999999999999"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and "beyond the seed sets (0:4000000)" in err
    beyond = rf"^seeds 1000000:{10**20} lie beyond the seed sets \(0:4000000\)$"
    with pytest.raises(OptionError, match=beyond):
        goldenticket.evaluate("p", "t", seeds=range(1_000_000, 10**20))
    with pytest.raises(OptionError, match="^seeds: none given$"):
        goldenticket.evaluate("p", "t", seeds=[])


class _Huge:
    noise_shape, n_exec, name = (10**6, 10**6), 1, "huge"

    def act(self, obs, noise):
        raise AssertionError("never called")


def test_a_policy_whose_noise_shape_cannot_be_held_is_one_line():
    with pytest.raises(UserError, match=r"^policy 'huge': noise_shape \(1000000, 1000000\) holds more than "
                                        r"the 16777216 values a ticket may have$"):
        load_policy(_Huge())
    boolean = _Huge()
    boolean.noise_shape = (True, 4)
    with pytest.raises(UserError, match=r"^policy 'huge': noise_shape must be \(H, A\) with H, A >= 1"):
        load_policy(boolean)


def test_help_says_which_options_are_required_and_every_default():
    search = _helps("search")
    assert search["--policy"].endswith("(required)") and _helps("train")["--task"].endswith("(required)")
    assert search["--task"].endswith("(default in search: the task a bundled single-task policy was trained "
                                     "on)")
    assert search["--budget"].endswith("(default: 1100)") and search["--out"].endswith("(required)")
    assert _helps("evaluate")["--seeds"].endswith("(default: 1000000:1000200)")
    assert _helps("demo")["--seed"].endswith("(default: 0)")
    for cls, words in ((SearchConfig, ("search",)), (config.SessionConfig, ("session", "new")),
                       (config.ServeConfig, ("session", "serve"))):
        helps = _helps(*words)
        for f in fields(cls):
            said = any(f.default is v for v in (MISSING, None, False)) or f.default == () \
                or "(default" in f.metadata["help"]
            assert said or f"(default: {f.default})" in helps[f.metadata["cli"].get("flag", flag(f.name))]


def test_search_takes_the_task_a_bundled_policy_was_trained_on(monkeypatch, tmp_path, capsys):
    ran = []
    monkeypatch.setattr(cli, "_run_search", lambda cfg, out: ran.append(cfg) or 0)
    for policy in (POLICY, "metaworld/pick-place-v3/ddim@2", "metaworld-pixels/drawer-open-v3/flow"):
        assert main(["search", "--policy", policy, "--out", str(tmp_path)]) == 0
    assert [cfg.task for cfg in ran] == ["metaworld/pick-place-v3"] * 2 + ["metaworld-pixels/drawer-open-v3"]
    assert main(["search", "--policy", POLICY, "--task", "metaworld/reach-v3", "--out", str(tmp_path)]) == 0
    assert ran[-1].task == "metaworld/reach-v3"
    for policy, said in (("metaworld/nope/flow", "unknown policy 'metaworld/nope/flow'"),
                         ("metaworld/mt10/flow", "--task must be given"),
                         ("byo_example:make_policy", "--task must be given")):
        assert main(["search", "--policy", policy, "--out", str(tmp_path)]) == 2
        assert said in capsys.readouterr().err
    assert len(ran) == 4


def test_session_new_names_its_own_flags_in_errors(tmp_path, capsys):
    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "s"), "--tickets", "1"]) == 2
    assert capsys.readouterr().err == ("goldenticket: error: --tickets must be at least 2 (the confirm phase "
                                       "takes the top 2), got 1\n")
    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "s"), "--seed", "-1"]) == 2
    assert capsys.readouterr().err == "goldenticket: error: --seed must be >= 0, got -1\n"


@pytest.mark.parametrize("words, classes", [(("session", "new"), ("SessionConfig",)),
                                            (("session", "serve"), ("ServeConfig",)),
                                            (("transfer",), ("TransferOptions", "SearchConfig"))])
def test_session_and_transfer_flags_are_their_config_fields(words, classes):
    own = {"-h", "--help", "--config", "--out"}
    flags = {s for a in _sub(*words)._actions for s in a.option_strings} - own
    skips = {"SearchConfig": cli.TRANSFER_SKIPS}
    assert flags == field_flags(f for name in classes
                                for f in cli_fields(getattr(config, name), skips.get(name, ())))


def test_session_new_plans_with_the_config_defaults(tmp_path, capsys):
    from goldenticket.session import Session

    assert main(["session", "new", "--policy", POLICY, "--out", str(tmp_path / "s")]) == 0
    plan, cfg = Session(tmp_path / "s").plan, config.SessionConfig(policy=POLICY)
    assert (plan.tickets, plan.episodes_per_ticket, plan.stopping, plan.alpha, plan.seed, plan.confirm) == (
        cfg.tickets, cfg.episodes_per_ticket, cfg.stopping, cfg.alpha, cfg.seed, cfg.confirm_episodes())


@pytest.mark.parametrize("command", [["search", "--policy", "metaworld/pick-place-v3/flow"],
                                     ["transfer", "--policy", "metaworld/mt10/flow"],
                                     ["train", "--task", "metaworld/reach-v3"],
                                     ["session", "new", "--policy", "metaworld/reach-v3/flow"]])
def test_an_empty_out_is_refused_not_the_current_folder(command, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main([*command, "--out", ""])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "argument --out: empty; name a folder" in err
    assert len(err.strip().splitlines()) == 1 and not any(tmp_path.iterdir())


@pytest.mark.parametrize(("device", "says"), [
    ("gpu", "--device must be cpu, cuda or cuda:N, got 'gpu'"),
    ("cuda:x", "--device must be cpu, cuda or cuda:N, got 'cuda:x'"),
])
def test_a_device_that_is_no_device_is_one_line(capsys, device, says):
    assert main(["evaluate", "--policy", POLICY, "--seeds", "1000000:1000002", "--device", device]) == 2
    assert capsys.readouterr().err.strip() == f"goldenticket: error: {says}"


def test_a_gpu_device_without_a_gpu_is_one_line(capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    assert main(["search", "--policy", POLICY, "--device", "cuda", "--out", "never-made"]) == 2
    assert "torch sees no CUDA GPU here" in capsys.readouterr().err


def test_only_lerobot_checkpoints_take_a_device(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    with pytest.raises(UserError, match="only LeRobot checkpoints run on a chosen device"):
        load_policy(POLICY, "cuda")


def test_a_seed_range_given_to_seed_points_at_seeds(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["evaluate", "--policy", POLICY, "--seed", "1005000:1005300"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1 and "a range of seeds A:B is --seeds" in err


@pytest.mark.parametrize("argv", [
    ["search", "--policy", POLICY, "--out", "{tmp}/run", "--budget", "-3"],
    ["search", "--policy", "nope/flow", "--out", "{tmp}/run"],
    ["search", "--policy", "nope/flow", "--task", "metaworld/reach-v3", "--out", "{tmp}/run"],
    ["evaluate", "--policy", POLICY, "--seeds", "1:5"],
    ["evaluate", "--policy", "nope/flow", "--seeds", "1000000:1000005"],
    ["evaluate", "--policy", POLICY, "--ticket", "{tmp}/none.safetensors"],
    ["evaluate", "--policy", POLICY, "--plot", "{tmp}/no/folder.png"],
    ["train", "--task", "metaworld/reach-v3", "--out", "{tmp}/policy", "--steps", "0"],
    ["search", "--policy", POLICY, "--task", "metaworld/nope-v3", "--out", "{tmp}/run"],
    ["evaluate", "--policy", POLICY, "--task", "nope", "--seeds", "1000000:1000005"],
])
def test_a_bad_option_policy_task_or_ticket_answers_before_anything_heavy_loads(tmp_path, argv):
    """One line, exit 2, and no model library imported (a task's name may ask Meta-World for its
    names): the answer comes in a fraction of a second."""
    named_task = "--task" in argv and argv[0] != "train"
    heavy = " ".join(("torch",) if named_task else ("torch", "numpy", "metaworld"))
    code = ("import sys\nfrom goldenticket.cli import main\nrc = main(sys.argv[2:])\n"
            "print(rc, sorted(set(sys.argv[1].split()) & set(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", code, heavy, *(a.format(tmp=tmp_path) for a in argv)],
                          capture_output=True, text=True, timeout=60)
    assert done.stdout == "2 []\n" and done.stderr.count("\n") == 1, (done.stdout, done.stderr)
    assert not any(tmp_path.iterdir())
