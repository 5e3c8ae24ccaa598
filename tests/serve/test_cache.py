"""The explorer's LRU cache: the least recently used entry goes first, a value is computed once."""

from __future__ import annotations

import pytest

from neuraldem.serve.cache import LruCache


def test_the_least_recently_used_entry_is_evicted():
    cache: LruCache[int] = LruCache(2)
    cache.put("a", 1)
    cache.put("b", 2)
    assert cache.get("a") == 1  # "b" is now the oldest
    cache.put("c", 3)
    assert "b" not in cache and cache.get("a") == 1 and cache.get("c") == 3 and len(cache) == 2


def test_a_value_is_computed_once():
    calls = []
    cache: LruCache[int] = LruCache(4)
    for _ in range(3):
        assert cache.get_or_compute("k", lambda: calls.append(1) or 7) == 7
    assert calls == [1] and cache.hits == 2


def test_a_cache_holds_at_least_one_entry():
    with pytest.raises(ValueError, match="capacity"):
        LruCache(0)
