"""Task families: each registers itself with the task registry, get_task looks the name up, and the
unknown-task line is built from the families registered."""

import dataclasses
import pickle
from dataclasses import dataclass

import pytest

from goldenticket.errors import OptionError, UserError
from goldenticket.tasks import GymTask, MetaWorldTask, get_task, registry
from goldenticket.tasks.lerobot_envs import LeRobotEnvTask
from goldenticket.tasks.pixels import PixelsTask
from goldenticket.tasks.registry import task_family
from goldenticket.tasks.robomimic import RobomimicTask

UNKNOWN = ("unknown task 'metaworld/x'; tasks look like: metaworld/bin-picking-v3, "
           "metaworld/pick-out-of-hole-v3, metaworld/pick-place-v3, metaworld/pick-place-wall-v3, "
           "metaworld/reach-v3, metaworld/reach-wall-v3 "
           "(metaworld-pixels/<env-name> seen through a camera; LeRobot's envs libero/<suite>/<task id>, "
           "libero-listed/<suite>/<task id>, pusht, aloha/insertion, aloha/transfer-cube; "
           "robomimic/lift, can, square, transport; or package.module:factory for a Gymnasium env of yours)")


def make_env():
    """A factory given as a callable."""


@pytest.fixture
def families(monkeypatch) -> list:
    """The registry's families, restored after the test."""
    monkeypatch.setattr(registry, "FAMILIES", list(registry.FAMILIES))
    return registry.FAMILIES


@pytest.fixture
def built(families) -> list:
    """Every family's builder replaced by one that records (family, task, options) instead of building."""
    def recorder(name: str):
        return lambda task, **options: (name, task, options)

    for i, family in enumerate(families):
        families[i] = dataclasses.replace(family, build=recorder(family.name))
    return families


@dataclass(frozen=True)
class ToyTask:
    name: str
    max_steps: int = 10


def test_a_family_registered_from_outside_is_found_and_offered(families):
    task_family("toy", matches=lambda name: name.startswith("toy/"),
                examples=lambda: "toy/<n> for a toy")(ToyTask)
    assert get_task("toy/3", max_steps=4) == ToyTask("toy/3", 4)
    with pytest.raises(UserError) as unknown:
        get_task("metaworld/x")
    assert "; toy/<n> for a toy; or package.module:factory" in str(unknown.value)


def test_a_family_name_is_registered_once(families):
    with pytest.raises(ValueError, match="task family 'Meta-World' is already registered"):
        task_family("Meta-World", matches=bool, examples=str)(ToyTask)


def test_the_built_in_families_build_their_own_task_classes():
    assert {family.name: family.build for family in registry.FAMILIES} == {
        "Gymnasium": GymTask, "Meta-World": MetaWorldTask, "Meta-World through a camera": PixelsTask,
        "LeRobot": LeRobotEnvTask, "robomimic": RobomimicTask}


@pytest.mark.parametrize(("task", "family"), [
    ("byo_example:make_env", "Gymnasium"), (make_env, "Gymnasium"),
    ("robomimic/lift:x", "Gymnasium"), ("libero/x:y", "Gymnasium"),  # import strings before names
    ("metaworld/reach-v3", "Meta-World"), ("metaworld/pick-place-v3", "Meta-World"),
    ("metaworld-pixels/reach-v3", "Meta-World through a camera"),
    ("metaworld-pixels/pick-place-v3", "Meta-World through a camera"),
    ("pusht", "LeRobot"), ("aloha/insertion", "LeRobot"), ("aloha/transfer-cube", "LeRobot"),
    ("libero/object/0", "LeRobot"), ("libero-listed/kitchen/3", "LeRobot"),  # its own errors
    ("robomimic/lift", "robomimic"), ("robomimic/transport", "robomimic"), ("robomimic/nope", "robomimic"),
])
def test_built_in_names_resolve_to_their_family(built, task, family):
    assert get_task(task) == (family, task, {})
    assert get_task(task, max_steps=5) == (family, task, {"max_steps": 5})


def test_only_factories_take_a_success_predicate(built):
    assert get_task("x:y", 3, "a:b") == ("Gymnasium", "x:y", {"max_steps": 3, "success": "a:b"})
    for task in ("robomimic/can", "nope"):  # said before an unknown name is
        with pytest.raises(OptionError, match=f"success applies to Gymnasium tasks; '{task}' has its own"):
            get_task(task, success="a:b")


@pytest.mark.parametrize("task", ["metaworld/x", "metaworld-pixels/nope", "aloha", "metaworld", ""])
def test_unknown_names_list_every_family(built, task):
    with pytest.raises(UserError) as unknown:
        get_task(task)
    assert str(unknown.value) == UNKNOWN.replace("'metaworld/x'", repr(task))


def test_a_libero_task_is_built_with_the_env_options_it_takes(built):
    options = {"control_mode": "absolute", "observation_height": 128, "observation_width": 1024}
    assert get_task("libero/object/0", env_options=options) == ("LeRobot", "libero/object/0",
                                                                {"env_options": options})
    assert get_task("libero/object/0", env_options={}) == ("LeRobot", "libero/object/0", {})
    task = LeRobotEnvTask("libero/object/0", 6, options)  # as workers get it: pickled
    assert pickle.loads(pickle.dumps(task)).env_options == options


@pytest.mark.parametrize(("task", "options", "says"), [
    ("metaworld/reach-v3", {"control_mode": "absolute"}, "env_option applies to LeRobot tasks; "
                                                         "'metaworld/reach-v3' takes none"),
    ("x:y", {"observation_height": 96}, "env_option applies to LeRobot tasks; 'x:y' takes none"),
    ("pusht", {"observation_height": 96}, "env_option observation_height: pusht takes none (LeRobot's "
                                          "config for it hands its env no camera size"),
    ("libero/object/0", {"camera_name": "agentview_image"}, "unknown env_option 'camera_name'; LIBERO "
     "tasks take control_mode, observation_height, observation_width"),
    ("libero/object/0", {"control_mode": "abs"}, "env_option control_mode must be relative or absolute, "
                                                 "got 'abs'"),
    *[("libero-listed/goal/3", {"observation_width": size}, "env_option observation_width must be an integer "
       f"from 1 to 1024 (pixels), got {size!r}") for size in (0, 1025, 128.0, True, "128")],
])
def test_env_options_a_task_does_not_take_are_one_line_before_it_is_built(built, task, options, says):
    with pytest.raises(OptionError) as refused:
        get_task(task, env_options=options)
    assert str(refused.value).startswith(says) and refused.value.names == ("env_option",)
    if task.startswith("libero"):  # the task itself checks them too, before LeRobot is imported
        with pytest.raises(OptionError, match="env_option"):
            LeRobotEnvTask(task, env_options=options)


def test_a_bad_env_option_is_one_line_before_anything_loads(monkeypatch, tmp_path, capsys):
    from goldenticket import job
    from goldenticket.cli import main
    from goldenticket.job import evaluate

    for module in (job, evaluate):
        monkeypatch.setattr(module, "load_policy", lambda *_, **__: pytest.fail("the policy was loaded"))
    for command in (["evaluate", "--seeds", "1000000:1000002"], ["search", "--out", str(tmp_path / "run")]):
        assert main([*command, "--policy", "metaworld/reach-v3/flow", "--task", "libero/object/0",
                     "--env-option", "control_mode=absolute", "--env-option", "observation_height=4096"]) == 2
        errors = capsys.readouterr().err.strip().splitlines()
        assert errors == ["goldenticket: error: --env-option observation_height must be an integer from 1 to "
                          "1024 (pixels), got 4096"]
