"""A Ctrl-C that lands inside a library surfaces as that library's error: still an interruption (nifo.interrupt)."""

from __future__ import annotations

import pytest

from nifo.interrupt import by_interrupt


def test_an_interrupt_inside_class_creation_counts_as_an_interrupt():
    # the shape measured in tests/test_kill.py: SIGINT while scipy.stats created a dataclass during an import;
    # Python 3.11 raises RuntimeError("Error calling __set_name__ ...") from the KeyboardInterrupt
    class Field:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt

    with pytest.raises(BaseException) as info:
        type("Method", (), {"rng": Field()})
    assert by_interrupt(info.value)


def test_an_error_raised_while_handling_an_interrupt_counts_and_others_do_not():
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise AttributeError("restore_bbox")   # matplotlib's savefig, interrupted
    except AttributeError as e:
        assert by_interrupt(e)
    assert not by_interrupt(ValueError("a bug"))
    assert not by_interrupt(None)
