from neuraldem.sim.seeds import is_prime, prime_seeds


def test_seeds_are_distinct_primes_per_run():
    all_seeds = [s for i in range(50) for s in prime_seeds(i, 3)]
    assert len(set(all_seeds)) == len(all_seeds)
    assert all(is_prime(s) and s > 10000 for s in all_seeds)
    assert prime_seeds(7, 3) == prime_seeds(7, 3)
    assert [n for n in range(20) if is_prime(n)] == [2, 3, 5, 7, 11, 13, 17, 19]
