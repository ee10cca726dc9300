"""The worker pool an in-process build shares between its stages (:mod:`proctex.pools`)."""

import os

import pytest

from proctex.pools import process_pool, shared_pool


def _pid(_):
    import time

    time.sleep(0.05)  # long enough that both workers take a job
    return os.getpid()


def _threads(_):
    import torch

    return torch.get_num_threads()


def test_a_build_s_stages_share_one_pool_and_it_is_closed_after():
    with process_pool(2) as a:
        first = set(a.map(_pid, range(8)))
    with process_pool(2) as b:
        second = set(b.map(_pid, range(8)))
    assert a is not b and not first & second  # outside a build: a new pool each time
    with shared_pool():
        with process_pool(2) as a:
            first = set(a.map(_pid, range(8)))
            assert set(a.map(_threads, range(4))) == {1}
        with shared_pool():  # nested: the outer block owns the pool
            with process_pool(2) as b:
                second = set(b.map(_pid, range(8)))
        assert b is a and first == second and len(first) == 2  # the same worker processes
        with process_pool(1) as c:  # another size: another pool
            assert c is not a and not set(c.map(_pid, range(2))) & first
        with pytest.raises(RuntimeError):
            with process_pool(1) as d:
                raise RuntimeError("interrupted")
        with process_pool(1) as e:  # a pool whose block raised is not handed on
            assert e is not d
    with pytest.raises(RuntimeError):  # shut down on leaving the build
        e.submit(_pid, 0)


def test_a_plan_run_here_uses_its_torch_threads_and_gives_the_count_back():
    """A plan's batches run here (not in the pool) use its ``threads`` (the pairs: one, as a pool
    worker and a Ray task do, so a pair's figures are the same bits wherever it was solved); the
    count before is restored, also when a batch raises; None leaves it as it is."""
    import torch

    from proctex.build.plan import Plan, run_in_process

    before = torch.get_num_threads()
    seen = []
    run = lambda store, config, batch, context: [seen.append(torch.get_num_threads()) or b for b in batch]  # noqa: E731
    run_in_process(Plan("pairs", [[1], [2]], run, finish=lambda r: None, parallel=True, threads=1), None, None, log=lambda *_: None)
    run_in_process(Plan("other", [[1]], run, finish=lambda r: None), None, None, log=lambda *_: None)
    assert seen == [1, 1, before] and torch.get_num_threads() == before

    def boom(store, config, batch, context):
        raise RuntimeError("a batch failed")

    with pytest.raises(RuntimeError):
        run_in_process(Plan("pairs", [[1]], boom, finish=lambda r: None, threads=1), None, None, log=lambda *_: None)
    assert torch.get_num_threads() == before
