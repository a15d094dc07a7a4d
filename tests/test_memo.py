"""nifo_core.signal.memo.ArrayMemo: results looked up by the array's content, never by its identity."""

from __future__ import annotations

import numpy as np
import pytest

from nifo_core.signal.memo import ArrayMemo


def _counting():
    calls = []

    def fn(x, k):
        calls.append(k)
        return x * k
    return fn, calls


def test_memo_computes_once_per_content_and_arguments():
    fn, calls = _counting()
    memo = ArrayMemo(fn)
    x = np.arange(5.0)
    assert np.array_equal(memo(x, 2), x * 2)
    assert np.array_equal(memo(x.copy(), 2), x * 2)
    assert calls == [2]
    memo(x, 3)
    assert calls == [2, 3]


def test_memo_sees_an_array_changed_in_place():
    fn, calls = _counting()
    memo = ArrayMemo(fn)
    x = np.arange(5.0)
    memo(x, 2)
    x[0] = 10.0
    assert memo(x, 2)[0] == 20.0
    assert len(calls) == 2


def test_memo_results_are_read_only_and_inputs_untouched():
    memo = ArrayMemo(lambda x: x + 1)
    x = np.arange(3.0)
    out = memo(x)
    with pytest.raises(ValueError):
        out[0] = 5.0
    assert x.flags.writeable and np.array_equal(x, [0.0, 1.0, 2.0])


def test_memo_keeps_at_most_size_results_and_max_bytes():
    fn, calls = _counting()
    memo = ArrayMemo(fn, size=2)
    for k in (1, 2, 3, 1):
        memo(np.ones(4), k)
    assert calls == [1, 2, 3, 1]          # 1 was dropped (least recently used) when 3 came
    big = ArrayMemo(fn, max_bytes=16)
    big(np.ones(4), 1)
    big(np.ones(4), 1)
    assert calls[-2:] == [1, 1]           # 32 bytes: returned, never kept


def test_memo_refuses_a_size_below_one():
    with pytest.raises(ValueError, match="size=0"):
        ArrayMemo(lambda x: x, size=0)
