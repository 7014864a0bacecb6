"""Quadrature rules on the reference simplex (`hyperoc.fem.quadrature.simplex_rule`): exact for every monomial
of the requested total degree, positive weights, points inside the simplex; the symmetric rules take fewer
points than the collapsed Gauss-Jacobi product of the same degree."""

import itertools
import math

import numpy as np
import pytest

from hyperoc.fem.quadrature import _collapsed_gauss_jacobi, simplex_rule


def exact_moment(exponents) -> float:
    """``int x^e dx`` over the reference simplex of dimension len(e): ``prod e_i! / (|e| + dim)!``."""
    return math.prod(math.factorial(k) for k in exponents) / math.factorial(sum(exponents) + len(exponents))


@pytest.mark.parametrize("dim, degree", [(d, k) for d in (1, 2, 3) for k in range(9)])
def test_rule_is_exact_to_its_degree_with_positive_weights_inside(dim, degree):
    """Every monomial of total degree <= degree integrates to its exact moment to round-off (1e-15: moments
    are at most 1/dim!, sums of at most 125 products of numbers in [0, 1])."""
    x, w = simplex_rule(dim, degree)
    for e in itertools.product(range(degree + 1), repeat=dim):
        if sum(e) <= degree:
            assert abs(np.sum(w * np.prod(x ** np.array(e), axis=1)) - exact_moment(e)) < 1e-15, e
    assert np.all(w > 0)
    assert np.all(x > 0) and np.all(x.sum(axis=1) < 1)


@pytest.mark.parametrize("dim, degree, points", [(2, 4, 6), (2, 5, 7), (3, 4, 14), (3, 5, 14)])
def test_symmetric_rules_take_fewer_points_than_the_collapsed_product(dim, degree, points):
    assert len(simplex_rule(dim, degree)[1]) == points < len(_collapsed_gauss_jacobi(dim, degree)[1])
