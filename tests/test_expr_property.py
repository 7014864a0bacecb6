"""Property tests of the expression parser: random valid expressions evaluate exactly as the same
numpy operations do; random text is either an expression or an `InputError`, never another exception."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hyperoc.errors import InputError
from hyperoc.expr import parse_expression

POINTS = {"x": np.linspace(-2.0, 2.0, 9), "y": np.linspace(0.0, 1.0, 9), "z": np.zeros(9),
          "r": np.linspace(0.0, 3.0, 9), "t": np.float64(0.7)}

# (source template, numpy function) of the operations drawn
UNARY = [("sin({})", np.sin), ("cos({})", np.cos), ("tanh({})", np.tanh), ("arctan({})", np.arctan),
         ("abs({})", np.abs), ("exp({})", np.exp), ("sqrt({})", np.sqrt), ("log({})", np.log), ("(-{})", np.negative),
         ("floor({})", np.floor), ("sign({})", np.sign)]
BINARY = [("({} + {})", np.add), ("({} - {})", np.subtract), ("({} * {})", np.multiply), ("({} / {})", np.true_divide),
          ("({} ** {})", np.power), ("({} % {})", np.mod), ("maximum({}, {})", np.maximum),
          ("minimum({}, {})", np.minimum), ("arctan2({}, {})", np.arctan2),
          ("({} < {})", lambda a, b: np.less(a, b).astype(float)),
          ("({} >= {})", lambda a, b: np.greater_equal(a, b).astype(float))]


def _leaf():
    names = st.sampled_from(sorted(POINTS)).map(lambda n: (n, lambda v, n=n: v[n]))
    numbers = st.floats(-10, 10, allow_nan=False).map(lambda c: (f"({c!r})", lambda v, c=c: np.float64(c)))
    return names | numbers | st.just(("pi", lambda v: np.float64(np.pi)))


def _extend(children):
    unary = st.tuples(st.sampled_from(UNARY), children).map(
        lambda p: (p[0][0].format(p[1][0]), lambda v, f=p[0][1], a=p[1][1]: f(a(v))))
    binary = st.tuples(st.sampled_from(BINARY), children, children).map(
        lambda p: (p[0][0].format(p[1][0], p[2][0]), lambda v, f=p[0][1], a=p[1][1], b=p[2][1]: f(a(v), b(v))))
    where = st.tuples(children, children, children).map(
        lambda p: (f"where({p[0][0]}, {p[1][0]}, {p[2][0]})",
                   lambda v, c=p[0][1], a=p[1][1], b=p[2][1]: np.where(c(v), a(v), b(v))))
    return unary | binary | where


EXPRESSIONS = st.recursive(_leaf(), _extend, max_leaves=25)


@settings(max_examples=300, deadline=None)
@given(EXPRESSIONS)
def test_valid_expressions_evaluate_as_numpy_does(pair):
    source, reference = pair
    with np.errstate(all="ignore"):
        expected = np.broadcast_to(np.asarray(reference(POINTS), dtype=np.float64), (9,))
        got = parse_expression(source)(**POINTS)
    np.testing.assert_array_equal(got, expected)


@settings(max_examples=500, deadline=None)
@given(st.text(alphabet=st.characters(codec="utf-8"), max_size=200)
       | st.text(alphabet="xyzrtpie0123456789.+-*/%()<>=! ,_sincoexplogwhrand", max_size=200))
def test_junk_is_an_expression_or_an_input_error(text):
    try:
        expr = parse_expression(text)
    except InputError as err:
        assert len(str(err)) < 400  # the source is quoted, cut to 80 characters
        return
    with np.errstate(all="ignore"):
        assert expr(**POINTS).shape == (9,)


@pytest.mark.parametrize("terms", [1000, 4999])
def test_flat_chains_up_to_the_documented_length(terms):
    """``x + x + ... + x``: a chain as long as the 10,000 characters allowed parses and evaluates."""
    source = " + ".join(["x"] * terms) if terms < 2000 else "+".join(["x"] * terms)
    assert len(source) <= 10_000
    np.testing.assert_array_equal(parse_expression(source)(x=POINTS["x"]), terms * POINTS["x"])
