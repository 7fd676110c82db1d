import dataclasses

import pytest

from taskrl.tasks import TaskSet, TaskSpec


def _set() -> TaskSet:
    return TaskSet.from_pairs([("reach", "Reach a goal."), ("pick-place", "Pick and place a puck."), ("push", "Push a puck.")])


def test_task_spec_is_frozen_and_validated():
    spec = TaskSpec("reach", "Reach a goal.", 0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.name = "push"  # type: ignore[misc]
    with pytest.raises(ValueError, match="name"):
        TaskSpec("", "Reach a goal.", 0)
    with pytest.raises(ValueError, match="description"):
        TaskSpec("reach", " ", 0)
    with pytest.raises(ValueError, match="index"):
        TaskSpec("reach", "Reach a goal.", -1)
    with pytest.raises(ValueError, match="index"):
        TaskSpec("reach", "Reach a goal.", True)


def test_task_set_order_names_descriptions_and_lookup():
    tasks = _set()
    assert len(tasks) == 3
    assert tasks.names == ["reach", "pick-place", "push"]
    assert tasks.descriptions == ["Reach a goal.", "Pick and place a puck.", "Push a puck."]
    assert [t.index for t in tasks] == [0, 1, 2]
    assert tasks[1] == TaskSpec("pick-place", "Pick and place a puck.", 1)
    assert tasks["push"].index == 2 and tasks.get("reach").index == 0 and tasks.index("pick-place") == 1
    assert "push" in tasks and "door-open" not in tasks and tasks[0] in tasks
    assert tasks == _set() and hash(tasks) == hash(_set())
    assert "pick-place" in repr(tasks)


def test_unknown_name_error_lists_the_allowed_names():
    with pytest.raises(KeyError, match="unknown task 'door-open'; allowed names: reach, pick-place, push"):
        _set()["door-open"]
    with pytest.raises(KeyError, match="allowed names"):
        _set().index("door")


def test_task_set_rejects_bad_collections():
    with pytest.raises(ValueError, match="at least one"):
        TaskSet([])
    with pytest.raises(ValueError, match="repeated: reach"):
        TaskSet.from_pairs([("reach", "a."), ("reach", "b.")])
    with pytest.raises(ValueError, match="position 0 but has index 1"):
        TaskSet([TaskSpec("reach", "a.", 1)])
    with pytest.raises(TypeError, match="TaskSpec"):
        TaskSet([("reach", "a.", 0)])  # type: ignore[list-item]
    with pytest.raises(TypeError, match="slicing"):
        _set()[0:2]
