"""Pure helpers of the Ray layer (no Ray started)."""

import pytest

from workers.train import teams


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
