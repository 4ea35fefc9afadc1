"""`benchmarks.jobs.each_done`: the same results in this process and in worker processes."""

import operator

import pytest

from bodyscan.benchmarks.jobs import each_done


def test_each_item_once_with_its_result():
    serial = list(each_done(operator.mul, [1, 2, 3], 10))
    assert serial == [(1, 10), (2, 20), (3, 30)]          # in order, in this process
    assert sorted(each_done(operator.mul, [1, 2, 3], 10, jobs=2)) == serial


def test_an_error_in_a_worker_is_raised_here():
    with pytest.raises(ZeroDivisionError):
        list(each_done(operator.truediv, [1, 2], 0, jobs=2))
