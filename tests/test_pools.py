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
