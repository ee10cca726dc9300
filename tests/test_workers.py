"""Pure helpers of the Ray layer (no Ray started)."""

import pytest

from workers.train import checkpoint_records, shared_teams, teams


def test_teams_use_every_worker_and_every_group_once():
    assert teams(1, [0, 1, 4, 5]) == [([0], [0, 1, 4, 5])]
    assert teams(2, [0, 1, 4, 5]) == [([0], [0, 4]), ([1], [1, 5])]  # groups in parallel
    assert teams(6, [0, 1, 4, 5]) == [([0, 4], [0]), ([1, 5], [1]), ([2], [4]), ([3], [5])]  # extra workers join teams
    assert teams(3, [7]) == [([0, 1, 2], [7])]  # one group: all workers data-parallel on it
    for world in range(1, 9):
        for n in range(1, 7):
            plan = teams(world, list(range(n)))
            assert sorted(r for ranks, _ in plan for r in ranks) == list(range(world))
            assert sorted(g for _, gs in plan for g in gs) == list(range(n))
            assert all(ranks and gs for ranks, gs in plan)
    with pytest.raises(ValueError):
        teams(0, [1])
    # only a team of several ranks needs a torch process group (a TorchTrainer)
    assert not shared_teams(teams(2, [0, 1, 4, 5])) and not shared_teams(teams(1, [3]))
    assert shared_teams(teams(3, [7])) and shared_teams(teams(6, [0, 1, 4, 5]))


def test_the_records_of_a_fit_are_read_from_its_checkpoint(tmp_path):
    """Team leaders put their groups' records in the fit's checkpoint (``records_rank<r>.json``, next
    to the networks): the driver merges them; a fit without a checkpoint has none."""
    import json

    from ray.train import Checkpoint

    (tmp_path / "records_rank0.json").write_text(json.dumps({"0": {"iterations": 20}, "4": {"iterations": 0}}))
    (tmp_path / "records_rank1.json").write_text(json.dumps({"1": {"iterations": 30}}))
    (tmp_path / "group_0.pt").write_bytes(b"not read")
    assert checkpoint_records(Checkpoint.from_directory(str(tmp_path))) == {"0": {"iterations": 20}, "4": {"iterations": 0}, "1": {"iterations": 30}}
    assert checkpoint_records(None) == {}


def test_a_family_serve_unloads_leaves_the_catalog_once_and_only_once(painted_mug_root):
    """Serve's multiplexing LRU unloads a family by calling ``__del__`` on what it held; the catalog
    drops the family then, and the garbage collector's later call (after a reload) changes nothing."""
    from proctex.serve.catalog import Catalog
    from workers.serve import _Held, deployment

    cat = Catalog(str(painted_mug_root), check_every=0, lazy=True)
    cat.get("mug")
    held = _Held(cat, "mug")
    held.__del__()  # Serve unloads it
    assert cat.loaded() == []
    cat.get("mug")  # asked for again: loaded anew
    held.__del__()  # the garbage collector, later
    assert cat.loaded() == ["mug"]
    assert cat.health() == {"mug": "ok"}
    with pytest.raises(ValueError, match="max_families"):
        deployment(-1)
