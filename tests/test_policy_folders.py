"""Policy folders someone sends (`--policy DIR`): every field a folder's files set is checked, and a
bad one is one line naming the file and the field, before any network is built or any code runs."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from goldenticket.cli import main
from goldenticket.errors import UserError
from goldenticket.policies import BUNDLED_DIR, dppo, load_policy
from goldenticket.policies.lerobot import checkpoint

REACH = BUNDLED_DIR / "metaworld/reach-v3/flow"


def refusal(capsys, policy: Path | str) -> str:
    """The one line `goldenticket evaluate` prints for `policy`, once it exited with code 2."""
    assert main(["evaluate", "--policy", str(policy), "--task", "metaworld/reach-v3",
                 "--seeds", "1000000:1000002"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


# --- goldenticket's own format: config.json + model.safetensors ---------------------------------

def policy_folder(tmp_path: Path, drop: tuple[str, ...] = (), **changes) -> Path:
    """A copy of the bundled reach-v3 flow policy, its config.json changed."""
    folder = tmp_path / "policy"
    shutil.copytree(REACH, folder)
    config = json.loads((folder / "config.json").read_text()) | changes
    (folder / "config.json").write_text(json.dumps({k: v for k, v in config.items() if k not in drop}))
    return folder


BAD_FIELDS = {
    "n_exec 0": ({"n_exec": 0}, "n_exec must be an integer in 1..256, got 0"),
    "n_exec past horizon": ({"n_exec": 9}, "n_exec 9 cannot exceed horizon 8"),
    "steps text": ({"steps": "10"}, "steps must be an integer in 1..1000, got '10'"),
    "steps negative": ({"steps": -3}, "steps must be an integer in 1..1000, got -3"),
    "steps float": ({"steps": 1e9}, "steps must be an integer in 1..1000, got 1000000000.0"),
    "steps fraction": ({"steps": 2.5}, "steps must be an integer in 1..1000, got 2.5"),
    "steps 0": ({"steps": 0}, "steps must be an integer in 1..1000, got 0"),
    "steps bool": ({"steps": True}, "steps must be an integer in 1..1000, got True"),
    "steps huge": ({"steps": 10**12}, "steps must be an integer in 1..1000, got 1000000000000"),
    "hidden huge": ({"hidden": 10**9}, "hidden must be an integer in 1..8192, got 1000000000"),
    "horizon huge": ({"horizon": 10**9}, "horizon must be an integer in 1..256, got 1000000000"),
    "layers 0": ({"layers": 0}, "layers must be an integer in 1..64, got 0"),
    "obs_dim null": ({"obs_dim": None}, "obs_dim must be an integer in 1..4096, got None"),
    "train_timesteps 1": ({"train_timesteps": 1}, "train_timesteps must be an integer in 2..10000, got 1"),
    "ddim steps": ({"kind": "ddim", "steps": 200}, "steps 200 exceeds train_timesteps 100"),
    "kind": ({"kind": "ddpm"}, "kind must be one of flow, ddim, got 'ddpm'"),
    "name": ({"name": 7}, "name must be a non-empty string, got 7"),
    "tasks text": ({"tasks": "metaworld/reach-v3"}, "tasks must be null or a list of distinct task names"),
    "tasks empty": ({"tasks": []}, "tasks must be null or a list of distinct task names"),
    "tasks twice": ({"tasks": ["a", "a"]}, "tasks must be null or a list of distinct task names"),
    "image_size": ({"image_size": 0}, "image_size must be null or an integer in 8..512, got 0"),
    "image and tasks": ({"image_size": 64, "tasks": ["a"]}, "an image policy (image_size) cannot also be "
                        "multi-task (tasks)"),
    "unknown": ({"dropout": 0.1}, "unknown field dropout; a policy config.json has name, kind, obs_dim"),
    "missing": ({"drop": ("action_dim",)}, "no action_dim (a policy config.json needs name, kind, "
                "obs_dim, action_dim)"),
    "size": ({"hidden": 4096, "layers": 5}, "the network it describes holds 67,682,422 numbers, more "
             "than the 67,108,864 a policy folder may hold"),
}


@pytest.mark.parametrize("case", BAD_FIELDS)
def test_every_field_of_a_policy_config_is_checked_naming_file_and_field(tmp_path, case):
    changes, says = BAD_FIELDS[case]
    folder = policy_folder(tmp_path, **changes)
    with pytest.raises(UserError) as error:
        load_policy(str(folder))
    assert str(error.value).startswith(f"{folder / 'config.json'}: "), error.value
    assert says in str(error.value)


@pytest.mark.parametrize("text, says", [
    ("[1, 2]", "not a policy config (a JSON object of its fields)"),
    ("{not json", "not a JSON file"),
    ("[" * 100_000 + "]" * 100_000, "not a JSON file (nested too deeply)"),
], ids=["list", "text", "deep"])
def test_a_policy_config_that_is_no_json_object_is_one_line(tmp_path, capsys, text, says):
    folder = policy_folder(tmp_path)
    (folder / "config.json").write_text(text)
    line = refusal(capsys, folder)
    assert line.startswith(f"goldenticket: error: {folder / 'config.json'}: ") and says in line, line


@pytest.mark.parametrize("changes", [{"steps": "10"}, {"n_exec": 0}, {"steps": 2.5}], ids=str)
def test_a_bad_policy_config_is_one_line_with_exit_code_2(tmp_path, capsys, changes):
    folder = policy_folder(tmp_path, **changes)
    field = next(iter(changes))
    assert refusal(capsys, folder).startswith(f"goldenticket: error: {folder / 'config.json'}: {field} ")


def test_a_step_count_past_the_cap_is_refused():
    with pytest.raises(UserError, match=r"steps must be an integer in 1\.\.1000, got 5000"):
        load_policy("metaworld/reach-v3/flow@5000")


def _weights(folder: Path, edit) -> None:
    tensors = load_file(folder / "model.safetensors")
    edit(tensors)
    save_file(tensors, folder / "model.safetensors")


@pytest.mark.parametrize("edit, says", [
    (lambda t: t.update({"net.0.bias": torch.zeros(3)}),
     "tensor net.0.bias has shape [3]; the network its config.json describes needs [256]"),
    (lambda t: t.update({"net.99.weight": torch.zeros(2)}),
     "tensor net.99.weight [2] has no place in the network its config.json describes"),
    (lambda t: t.pop("obs_std"),
     "no tensor obs_std [39], which the network its config.json describes needs"),
], ids=["shape", "extra", "missing"])
def test_weights_that_do_not_fit_the_config_are_one_line(tmp_path, capsys, edit, says):
    folder = policy_folder(tmp_path)
    _weights(folder, edit)
    line = refusal(capsys, folder)
    assert line == f"goldenticket: error: {folder / 'model.safetensors'}: {says}", line


def test_a_config_that_does_not_fit_its_weights_is_one_line(tmp_path, capsys):
    folder = policy_folder(tmp_path, hidden=128)
    line = refusal(capsys, folder)
    assert line.startswith(f"goldenticket: error: {folder / 'model.safetensors'}: tensor net.0.bias has "
                           "shape [256]; the network its config.json describes needs [128]"), line


def test_a_sound_policy_folder_still_loads_and_acts(tmp_path):
    policy = load_policy(str(policy_folder(tmp_path)))
    actions = policy.act(np.zeros((2, 39), np.float32), np.zeros((2, 8, 4), np.float32))
    assert actions.shape == (2, 4, 4)
    assert policy.weights_hash() == load_policy("metaworld/reach-v3/flow").weights_hash()


# --- DPPO checkpoints: config.yaml with ${eval:...} -----------------------------------------------

OBS, ACT = 3, 2


def dppo_folder(tmp_path: Path, **config_edits: str) -> Path:
    """A small DPPO pre-training folder as DPPO writes it, its config.yaml's lines edited
    (`old=new` pairs given as {old: new})."""
    folder = tmp_path / "dppo"
    spec = dppo.NetworkSpec(action_dim=ACT, horizon_steps=4, cond_dim=OBS, mlp_dims=(16, 16))
    torch.manual_seed(0)
    normalization = {"obs_min": -np.ones(OBS, np.float32), "obs_max": np.ones(OBS, np.float32),
                     "action_min": -np.ones(ACT, np.float32), "action_max": np.ones(ACT, np.float32)}
    dppo.save_checkpoint(folder, dppo.DiffusionMLP(spec), normalization, denoising_steps=10)
    text = (folder / "config.yaml").read_text()
    for old, new in config_edits.items():
        assert old in text
        text = text.replace(old, new, 1)
    (folder / "config.yaml").write_text(text)
    return folder


COND = "cond_dim: ${eval:'${obs_dim} * ${cond_steps}'}"
FAN_OUT = "".join(f"k{i}: ${{eval:'" + " + ".join([f"${{k{i - 1}}}"] * 5) + " - " +  # k5 is 3,
                  " - ".join([f"${{k{i - 1}}}"] * 4) + "'}\n" for i in range(1, 6))  # from 9**5 references

BAD_DPPO = {
    "power": ({COND: "cond_dim: ${eval:'10**10**10'}"}, "only arithmetic"),
    "overflow": ({COND: "cond_dim: ${eval:'int(1e308 * 10)'}"}, "model.network.cond_dim: ${eval:'int(1e308 "
                 "* 10)'}: a number past 1e+18"),
    "infinite literal": ({COND: "cond_dim: ${eval:'round(1e999)'}"}, "a number past 1e+18"),
    "huge product": ({"obs_dim: 3\n": "obs_dim: 3\nbig: ${eval:'999999999 * 999999999 * 999999999'}\n",
                      COND: "cond_dim: ${eval:'${big} * 0 + 3'}"}, "big: ${eval:'999999999 * 999999999 * "
                     "999999999'}: a number past 1e+18"),
    "squares": ({"obs_dim: 3\n": "obs_dim: 3\n" + "s0: 10\n" + "".join(
        f"s{i}: ${{eval:'${{s{i - 1}}} * ${{s{i - 1}}}'}}\n" for i in range(1, 20)),
        COND: "cond_dim: ${eval:'${s19} * 0 + 3'}"}, "a number past 1e+18"),
    "nesting": ({COND: "cond_dim: ${eval:'" + "-" * 900 + "3'}"}, "nested more than 100 deep"),
    "parentheses": ({COND: "cond_dim: ${eval:'" + "(" * 300 + "3" + ")" * 300 + "'}"}, "only arithmetic"),
    "length": ({COND: "cond_dim: ${eval:'" + " + ".join(["0"] * 400) + " + 3'}"}, "longer than 1000 "
               "characters"),
    "fan-out": ({"obs_dim: 3\n": "obs_dim: 3\nk0: ${obs_dim}\n" + FAN_OUT,
                 COND: "cond_dim: ${eval:'${k5} * 0 + 3'}"}, "more than 10000 interpolations"),
    "width": ({"mlp_dims: [16, 16]": "mlp_dims: [1000000000]"},
              "model.network.mlp_dims must be a list of 1 to 64 layer widths in 1..10000, got [1000000000]"),
    "width text": ({"mlp_dims: [16, 16]": "mlp_dims: [1e9]"}, "model.network.mlp_dims must be a list of 1 "
                   "to 64 layer widths in 1..10000, got ['1e9']"),
    "size": ({"mlp_dims: [16, 16]": "mlp_dims: [9000, 9000]"}, "model.network: the network "
             "it describes holds 81,"),
    "time_dim": ({"time_dim: 16": "time_dim: 100000000"}, "model.network.time_dim must be an integer in "
                 "4..10000, got 100000000"),
    "denoising_steps": ({"denoising_steps: 10": "denoising_steps: 20000"}, "denoising_steps must be an "
                        "integer in 1..10000, got 20000"),
    "round digits": ({COND: "cond_dim: ${eval:'round(3, -100000000000000000)'}"}, "only arithmetic"),
    "clip nan": ({"denoised_clip_value: 1.0": "denoised_clip_value: .nan"},
                 "model.denoised_clip_value must be a finite number or null, got nan"),
    "clip digits": ({"denoised_clip_value: 1.0": "denoised_clip_value: " + "9" * 400},
                    "model.denoised_clip_value must be a finite number or null, got 99999"),
    "activation": ({"activation_type: Mish": "activation_type: [Mish]"},
                   "model.network.activation_type is ['Mish']; DPPO's DiffusionMLP takes"),
    "digits": ({"obs_dim: 3\n": "obs_dim: 3\nseed: " + "1" * 5000 + "\n"},
               "not a YAML file (Exceeds the limit"),
    "deep": ({"obs_dim: 3\n": "obs_dim: 3\ndeep: " + "[" * 5000 + "]" * 5000 + "\n"},
             "not a YAML file (nested too deeply)"),
}


@pytest.mark.parametrize("case", BAD_DPPO)
def test_a_dppo_config_is_bounded_and_one_line(tmp_path, capsys, case):
    edits, says = BAD_DPPO[case]
    folder = dppo_folder(tmp_path, **edits)
    line = refusal(capsys, folder)
    assert line.startswith(f"goldenticket: error: {folder / 'config.yaml'}: ") and says in line, line


def test_a_sound_dppo_folder_still_loads(tmp_path):
    folder = dppo_folder(tmp_path, **{COND: "cond_dim: ${eval:'max(1, round(${obs_dim} * 1.0)) * "
                                            "${cond_steps} % 1000'}"})
    assert load_policy(str(folder)).noise_shape == (4, ACT)


# --- LeRobot checkpoints: the processor steps their JSON names -----------------------------------

SHIPPED = Path(__file__).parents[1] / "examples" / "lerobot_reach_policy"
REGISTERED = {"rename_observations_processor", "to_batch_processor", "device_processor",
              "normalizer_processor", "unnormalizer_processor"}


def pipeline(*steps: dict) -> dict:
    return {"name": "policy_preprocessor", "steps": list(steps)}


def check(value, needed=()) -> None:
    files = {"policy_preprocessor_step_0_normalizer_processor.safetensors"}
    checkpoint.check_pipeline(value, "DIR/policy_preprocessor.json", REGISTERED, files, needed)


def test_the_shipped_lerobot_pipelines_pass():
    checkpoint.check_processors(SHIPPED, REGISTERED, needed=("device_processor",))


@pytest.mark.parametrize("value, says", [
    (pipeline({"class": "os.system", "config": {"command": "touch x"}}),
     "step 0 names the import path 'os.system'; goldenticket loads only the processor steps LeRobot "
     "registers, named by \"registry_name\""),
    (pipeline({"registry_name": "to_batch_processor"}, {"registry_name": "to_batch_processor",
                                                        "class": "evil.Step"}),
     "step 1 names the import path 'evil.Step'; goldenticket loads only the processor steps LeRobot "
     "registers, named by \"registry_name\""),
    (pipeline({"registry_name": "my_plugin_step"}),
     "step 0 'my_plugin_step' is no processor step LeRobot registers"),
    (pipeline({"registry_name": ["to_batch_processor"]}),
     "step 0 ['to_batch_processor'] is no processor step LeRobot registers"),
    (pipeline({"config": {}}), "step 0 names no \"registry_name\""),
    (pipeline("to_batch_processor"), "step 0 is not a JSON object"),
    (pipeline({"registry_name": "to_batch_processor", "config": []}), "step 0's config is not a JSON object"),
    (pipeline({"registry_name": "normalizer_processor", "state_file": "../../stats.safetensors"}),
     "step 0's state_file '../../stats.safetensors' is no file in the checkpoint"),
    (pipeline({"registry_name": "normalizer_processor", "state_file": "absent.safetensors"}),
     "step 0's state_file 'absent.safetensors' is no file in the checkpoint"),
    ({"name": "x"}, "not a LeRobot processor pipeline (a JSON object with a \"steps\" list)"),
    ([1], "not a LeRobot processor pipeline (a JSON object with a \"steps\" list)"),
    (pipeline({"registry_name": "to_batch_processor"}), "no 'device_processor' step, whose settings "
     "goldenticket sets (lerobot-train writes one)"),
], ids=["class", "class beside name", "unregistered", "name not text", "unnamed", "step text", "config",
        "state outside", "state absent", "no steps", "list", "no device step"])
def test_a_processor_step_lerobot_does_not_register_is_refused(value, says):
    with pytest.raises(UserError) as error:
        check(value, needed=("device_processor",))
    assert str(error.value) == f"DIR/policy_preprocessor.json: {says}"


def test_registered_steps_with_their_state_files_pass():
    check(pipeline({"registry_name": "to_batch_processor", "config": {}},
                   {"registry_name": "normalizer_processor", "config": {"eps": 1e-8},
                    "state_file": "policy_preprocessor_step_0_normalizer_processor.safetensors"},
                   {"registry_name": "device_processor"}), needed=("device_processor",))
