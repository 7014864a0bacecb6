import ast
import builtins

import numpy as np
import pytest

from hyperoc.errors import InputError
from hyperoc.expr import Expression, expression_field, parse_expression

X = np.linspace(-1.0, 2.0, 7)
T = np.array([[0.0], [0.3], [1.0]])


@pytest.mark.parametrize(
    "source, reference",
    [
        ("0.1*sin(pi*t)*exp(-((x-0.9)/0.05)**2)",
         lambda x, t: 0.1 * np.sin(np.pi * t) * np.exp(-(((x - 0.9) / 0.05) ** 2))),
        ("where(r < 0.7, 1.0, 0.0)*t", lambda x, t: np.where(np.abs(x) < 0.7, 1.0, 0.0) * t),
        ("-x**2 + 3 % 2 - x/4 + +t", lambda x, t: -(x**2) + 1 - x / 4 + t),
        ("2**-1 * e", lambda x, t: 0.5 * np.e + 0 * x * t),
        ("x % 0.5", lambda x, t: np.mod(x, 0.5) + 0 * t),
        ("arctan2(x, 1 + t) + minimum(x, t) - maximum(x, t)",
         lambda x, t: np.arctan2(x, 1 + t) + np.minimum(x, t) - np.maximum(x, t)),
        ("clip(x, 0, 1) + heaviside(x, 0.5) + sign(x) + floor(x) + ceil(t)",
         lambda x, t: np.clip(x, 0, 1) + np.heaviside(x, 0.5) + np.sign(x) + np.floor(x) + np.ceil(t)),
        ("sqrt(abs(x)) + log(1 + t) + tanh(x) + cosh(t) - sinh(t)",
         lambda x, t: np.sqrt(np.abs(x)) + np.log(1 + t) + np.tanh(x) + np.cosh(t) - np.sinh(t)),
        ("(0 < x <= 1) + (x == 2) - (x != 2) * (t >= 0.3)",
         lambda x, t: 1.0 * ((0 < x) & (x <= 1)) + (x == 2) - 1.0 * (x != 2) * (t >= 0.3)),
        ("(x > 0 and t > 0) + 2*(x < 0 or t == 1) + 4*(not x)",
         lambda x, t: ((x > 0) & (t > 0)) + 2 * ((x < 0) | (t == 1)) + 4 * (x == 0)),
        ("-(x < 1) + tan(0.1*x) + arcsin(0.5*t) + arccos(0.5*t) + arctan(x) + cos(x)",
         lambda x, t: (-1.0 * (x < 1) + np.tan(0.1 * x) + np.arcsin(0.5 * t) + np.arccos(0.5 * t) + np.arctan(x)
                       + np.cos(x))),
    ],
)
def test_matches_numpy_with_broadcasting(source, reference):
    r = np.abs(X)
    value = parse_expression(source)(x=X, r=r, t=T)
    assert value.dtype == np.float64
    assert value.shape == (3, 7)
    np.testing.assert_allclose(value, np.broadcast_to(reference(X, T), (3, 7)), rtol=1e-14, atol=1e-14)


def test_constant_is_broadcast_to_input_shape():
    value = parse_expression("1.5")(x=np.zeros((4, 2)), t=0.0)
    assert value.shape == (4, 2) and value.dtype == np.float64
    assert np.all(value == 1.5)
    value[0, 0] = 0.0  # a real, writable array
    assert parse_expression("pi")().shape == ()


def test_expression_is_frozen_and_records_used_names():
    expr = parse_expression("t*x", variables={"x", "t"})
    assert isinstance(expr, Expression) and isinstance(expr.tree, ast.Expression)
    assert expr.names == {"x", "t"} and expr.variables == {"x", "t"}
    assert expr == Expression("t*x", frozenset({"x", "t"}))
    with pytest.raises(AttributeError):
        expr.source = "x"


def test_call_checks_variables():
    expr = parse_expression("t*x", variables={"x", "t"})
    with pytest.raises(TypeError, match="missing"):
        expr(t=1.0)
    with pytest.raises(TypeError, match="unknown"):
        expr(t=1.0, x=1.0, y=2.0)


@pytest.mark.parametrize(
    "source, construct",
    [
        ("__import__('os')", "dunder name '__import__'"),
        ("().__class__", "attribute access"),
        ("x.real", "attribute access"),
        ("[1][0]", "subscripts"),
        ("lambda: 1", "lambda"),
        ("open('f')", "unknown function 'open'"),
        ("q + 1", "unknown name 'q'"),
        ("foo(x)", "unknown function 'foo'"),
        ("np.sin(x)", "calling attribute access"),
        ("sin(x=1)", "keyword arguments"),
        ("sin(*x)", "starred"),
        ("[x for x in y]", "comprehensions"),
        ("'a' + x", "str literal"),
        ("True", "bool literal"),
        ("1j", "complex literal"),
        ("x if t else y", "conditional expressions"),
        ("x @ y", "operator 'MatMult'"),
        ("x is y", "comparison operator 'Is'"),
        ("x << 2", "operator 'LShift'"),
        ("(y := 2)", "assignment expressions"),
        ("sin", "must be called"),
        ("sin(x, y)", "takes 1 argument"),
        ("1e400", "out of float64 range"),
        ("x +", "invalid syntax"),
        ("x = 1", "invalid syntax"),
    ],
)
def test_forbidden_constructs_are_rejected(source, construct):
    with pytest.raises(InputError, match=construct.replace("(", r"\(").replace("*", r"\*")) as err:
        parse_expression(source)
    assert "\n" not in str(err.value)


def test_variables_restrict_names():
    with pytest.raises(InputError, match="unknown name 'x'"):
        parse_expression("x*t", variables={"t"})
    with pytest.raises(InputError, match="shadows"):
        parse_expression("1", variables={"sin"})
    with pytest.raises(InputError, match="must be a string"):
        parse_expression(1.0)


def test_evaluation_never_compiles_code(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("eval/exec called")

    real_compile = builtins.compile

    def ast_only_compile(source, filename, mode, flags=0, *args, **kwargs):
        assert flags & ast.PyCF_ONLY_AST, "user string compiled to a code object"
        return real_compile(source, filename, mode, flags, *args, **kwargs)

    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    monkeypatch.setattr(builtins, "compile", ast_only_compile)
    expr = parse_expression("0.1*sin(pi*t)*exp(-((x-0.9)/0.05)**2)")
    np.testing.assert_allclose(expr(x=0.9, t=0.5), 0.1)


def test_expression_field_pads_coordinates_and_computes_r():
    points = np.array([[3.0, 4.0], [1.0, 0.0]])
    np.testing.assert_allclose(expression_field("r + 10*x + 100*y + 1000*z + t", points, 2.0),
                               [5 + 30 + 400 + 2, 1 + 10 + 2])
    time_only = parse_expression("sin(pi*t)", variables={"t"})
    value = expression_field(time_only, points, 0.5)
    assert value.shape == (2,)
    np.testing.assert_allclose(value, 1.0)
    np.testing.assert_allclose(expression_field("x", np.array([0.25, 0.5]), 0.0), [0.25, 0.5])
