"""The one fitting loop (bench.core.search.evolve): independent problems searched side by side, every
population costed in one call, the start kept unless a candidate beats it, the best's details kept."""

from __future__ import annotations

import numpy as np

from bench.core.search import evolve

TARGETS = np.array([[0.3, 2.0], [0.7, 4.0]])  # problem 0's and problem 1's minimum


def _staircase(values: np.ndarray, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A quadratic bowl per problem, read through a 0.001 staircase (as an encoder's ticks make a
    simulation's error); the details: each candidate's distance to its minimum."""
    gap = values - TARGETS[which]
    return np.floor(np.sum(gap ** 2, axis=1) * 1000) / 1000, np.abs(gap)


def test_each_problem_finds_its_own_minimum_from_one_batched_cost():
    calls = []

    def cost(values, which):
        calls.append(np.asarray(which).copy())
        return _staircase(values, np.asarray(which))

    start = np.array([[0.5, 3.0], [0.5, 3.0]])
    found = evolve(cost, start, start.copy(), np.array([0.0, 0.0]), np.array([1.0, 5.0]), lambda x: x,
                   generations=60, population=8, sigma=0.3, seed=0)
    assert np.allclose(found.values, TARGETS, atol=0.05)
    assert np.all(found.cost <= 0.002)
    assert np.all(found.cost < _staircase(start, np.array([0, 1]))[0])
    # the start costed first, then both populations in each call
    assert calls[0].tolist() == [0, 1] and sorted(set(calls[1].tolist())) == [0, 1] and len(calls[1]) == 16
    assert np.allclose(found.start_details[1], [0.2, 1.0])  # the start's details, kept apart
    assert np.allclose(found.details[0], np.abs(found.values[0] - TARGETS[0]))
    assert 0 < found.generations <= 60


def test_a_start_no_candidate_beats_is_kept_and_decode_maps_the_coordinates():
    """Coordinates 0..1 across a range (as the stand searches): the best comes back in values."""
    lower, upper = np.array([0.0, 1.0]), np.array([1.0, 5.0])
    target = TARGETS[:1]
    found = evolve(lambda v, w: _staircase(v, np.zeros(len(v), int)), target.copy(),
                   (target - lower) / (upper - lower), 0.0, 1.0,
                   lambda x: lower + np.clip(x, 0.0, 1.0) * (upper - lower),
                   generations=5, population=6, sigma=0.2, seed=1)
    assert np.array_equal(found.values, target)  # already at the minimum: nothing beats cost 0
    assert found.cost.tolist() == [0.0]
