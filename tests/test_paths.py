"""Path cost around the object's bounding sphere, and the shortest order to visit views: hand-computed
cases and brute force."""

import itertools
import math

import numpy as np
import pytest

from nbvdata.core.paths import EXACT_TOUR, distance_matrix, path_length, path_lengths, shortest_tour, tour_cost


def test_a_segment_that_clears_the_sphere_is_straight():
    a, b = np.array([1.0, 0.0, 0.0]), np.array([math.cos(0.3), math.sin(0.3), 0.0])
    assert path_length(a, b, 0.5) == pytest.approx(np.linalg.norm(b - a), abs=1e-15)
    assert path_length(a, b, 0.98) == pytest.approx(np.linalg.norm(b - a))  # cos(0.15) = 0.9888 > 0.98


def test_a_segment_through_the_sphere_wraps_around_it():
    """A quarter turn at radius 1 around a sphere of 0.9: the chord passes 0.707 from the centre,
    so tangent (sqrt(1 - 0.81)), arc of pi/2 - 2 acos(0.9) at radius 0.9, tangent."""
    a, b = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    expected = 2 * math.sqrt(1 - 0.81) + 0.9 * (math.pi / 2 - 2 * math.acos(0.9))
    assert path_length(a, b, 0.9) == pytest.approx(expected, rel=1e-12)
    assert path_length(a, b, 0.9) > np.linalg.norm(b - a)


def test_antipodal_views_go_half_way_round():
    a, b = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    assert path_length(a, b, 0.5) == pytest.approx(2 * math.sqrt(0.75) + 0.5 * (math.pi - 2 * math.acos(0.5)))


def test_objview_s_cameras_at_3_around_the_unit_sphere():
    theta = 2.5
    a, b = 3 * np.array([1.0, 0.0, 0.0]), 3 * np.array([math.cos(theta), math.sin(theta), 0.0])
    assert path_length(a, b, 1.0) == pytest.approx(2 * math.sqrt(8) + (theta - 2 * math.acos(1 / 3)))


def test_path_lengths_accumulate_and_the_first_view_costs_nothing(rng):
    positions = rng.normal(size=(6, 3))
    positions *= 0.4 / np.linalg.norm(positions, axis=1, keepdims=True)
    travelled = path_lengths(positions, 0.12)
    steps = [path_length(positions[i], positions[i + 1], 0.12) for i in range(5)]
    assert travelled[0] == 0 and np.allclose(np.diff(travelled), steps)
    assert all(path_length(positions[i], positions[j], 0.12) == pytest.approx(path_length(positions[j], positions[i], 0.12))
               for i in range(6) for j in range(6))


@pytest.mark.parametrize("count", [1, 2, 5, 8])
def test_the_tour_is_the_brute_force_optimum_on_small_instances(rng, count):
    for _ in range(2):
        points = rng.normal(size=(count + 1, 3))
        points *= 0.4 / np.linalg.norm(points, axis=1, keepdims=True)
        start, views = points[0], points[1:]
        order = shortest_tour(start, views, 0.12)
        matrix = distance_matrix(points, 0.12)
        best = min(tour_cost(matrix, [i + 1 for i in perm]) for perm in itertools.permutations(range(count)))
        assert sorted(order) == list(range(count))
        assert tour_cost(matrix, [i + 1 for i in order]) == pytest.approx(best, rel=1e-12)


def test_at_the_exact_size_the_tour_is_no_longer_than_the_heuristic_s(rng):
    from nbvdata.core.paths import _nearest_neighbour, _two_opt

    points = rng.normal(size=(EXACT_TOUR + 1, 3))
    points *= 0.4 / np.linalg.norm(points, axis=1, keepdims=True)
    matrix = distance_matrix(points, 0.12)
    exact = [i + 1 for i in shortest_tour(points[0], points[1:], 0.12)]
    assert tour_cost(matrix, exact) <= tour_cost(matrix, _two_opt(matrix, _nearest_neighbour(matrix))) + 1e-12


def test_above_the_exact_size_the_tour_is_a_2_opt_local_optimum_no_worse_than_nearest_neighbour(rng):
    points = rng.normal(size=(25, 3))
    points *= 0.4 / np.linalg.norm(points, axis=1, keepdims=True)
    order = shortest_tour(points[0], points[1:], 0.12)
    matrix = distance_matrix(points, 0.12)
    nearest, here, left = [], 0, set(range(1, 25))
    while left:
        here = min(left, key=lambda node: (matrix[here, node], node))
        nearest.append(here)
        left.remove(here)
    assert sorted(order) == list(range(24))
    assert tour_cost(matrix, [i + 1 for i in order]) <= tour_cost(matrix, nearest) + 1e-12
    assert shortest_tour(points[0], points[1:], 0.12) == order  # deterministic
