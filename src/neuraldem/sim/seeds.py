"""LIGGGHTS wants every random seed to be a distinct prime > 10000; derive them from a run index."""

from __future__ import annotations


def is_prime(n: int) -> bool:
    if n < 2:
        return False
    if n % 2 == 0:
        return n == 2
    f = 3
    while f * f <= n:
        if n % f == 0:
            return False
        f += 2
    return True


def next_prime(n: int) -> int:
    while not is_prime(n):
        n += 1
    return n


def prime_seeds(index: int, count: int, base: int = 10_007) -> list[int]:
    """`count` distinct primes, different for every `index` (spaced so runs never share a seed)."""
    seeds: list[int] = []
    n = base + 7919 * index * count
    for _ in range(count):
        p = next_prime(n)
        seeds.append(p)
        n = p + 1
    return seeds
