"""Safe evaluation of user expression strings from configuration files.

An expression such as ``"0.1*sin(pi*t)*exp(-((x-0.9)/0.05)**2)"`` or
``"where(r < 0.7, 1.0, 0.0)*t"`` is parsed with ``ast.parse(source, mode="eval")`` and
checked against a whitelist; it is then evaluated by walking the syntax tree with numpy
ufuncs. The string is never compiled to a code object nor passed to ``eval``/``exec``.

Allowed syntax
--------------
- numbers (int or float literals, all evaluated as float64);
- names: the allowed variables (default ``x, y, z, r, t``) and the constants ``pi``, ``e``;
- ``+ - * / ** %`` (binary), ``+ -`` (unary);
- comparisons ``< <= > >= == !=`` (chains allowed), giving 1.0 / 0.0;
- ``and``, ``or``, ``not``, mapped to numpy's element-wise logical operations;
- calls, with positional arguments only, of: ``sin cos tan exp log sqrt abs tanh sinh cosh
  arctan arctan2 arcsin arccos minimum maximum where heaviside clip floor ceil sign``.

Anything else (attributes, subscripts, lambdas, comprehensions, strings, keyword arguments,
dunder names, unknown names or functions) raises `InputError` naming the construct and quoting at
most 80 characters of the expression.

Length: up to 10,000 characters. The tree is checked and evaluated with an explicit stack, so a
flat chain such as ``x + x + ... + x`` of that length works (Python's own parser, which builds the
tree, nests up to 200 parentheses).
"""

from __future__ import annotations

import ast
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, quote

__all__ = ["Expression", "parse_expression", "expression_field", "DEFAULT_VARIABLES", "FUNCTIONS", "CONSTANTS"]

DEFAULT_VARIABLES = frozenset({"x", "y", "z", "r", "t"})

CONSTANTS = {"pi": np.pi, "e": np.e}

# name -> (numpy function, number of positional arguments)
FUNCTIONS = {
    **{name: (getattr(np, name), 1) for name in (
        "sin", "cos", "tan", "exp", "log", "sqrt", "abs", "tanh", "sinh", "cosh",
        "arctan", "arcsin", "arccos", "floor", "ceil", "sign",
    )},
    **{name: (getattr(np, name), 2) for name in ("arctan2", "minimum", "maximum", "heaviside")},
    **{name: (getattr(np, name), 3) for name in ("where", "clip")},
}

_BINARY = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.true_divide,
    ast.Pow: np.power,
    ast.Mod: np.mod,
}
_UNARY = {ast.UAdd: np.positive, ast.USub: np.negative, ast.Not: np.logical_not}
_COMPARE = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}
_BOOLEAN = {ast.And: np.logical_and, ast.Or: np.logical_or}

_CONSTRUCT_NAMES = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscripts",
    ast.Lambda: "lambda",
    ast.ListComp: "comprehensions",
    ast.SetComp: "comprehensions",
    ast.DictComp: "comprehensions",
    ast.GeneratorExp: "comprehensions",
    ast.List: "lists",
    ast.Tuple: "tuples",
    ast.Set: "sets",
    ast.Dict: "dicts",
    ast.IfExp: "conditional expressions (use where(cond, a, b))",
    ast.NamedExpr: "assignment expressions",
    ast.Starred: "starred arguments",
    ast.JoinedStr: "f-strings",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield",
    ast.Slice: "slices",
}

_MAX_SOURCE_LENGTH = 10_000


@dataclass(frozen=True)
class Expression:
    """A validated expression of some named variables.

    Parameters
    ----------
    source : str
        The expression text, e.g. ``"0.1*sin(pi*t)"``.
    variables : frozenset of str
        Names the expression may use (besides ``pi`` and ``e``).

    Attributes
    ----------
    tree : ast.Expression
        The parsed, validated syntax tree.
    names : frozenset of str
        The variables the expression actually uses (a subset of ``variables``).

    Raises
    ------
    InputError
        On a syntax error or any construct outside the whitelist (see the module docstring).
    """

    source: str
    variables: frozenset = DEFAULT_VARIABLES
    tree: ast.Expression = field(init=False, repr=False, compare=False)
    names: frozenset = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        variables = frozenset(self.variables)
        _check_variable_names(variables)
        tree = _parse(self.source)
        names = frozenset(_check(tree.body, variables, self.source))
        object.__setattr__(self, "variables", variables)
        object.__setattr__(self, "tree", tree)
        object.__setattr__(self, "names", names)

    def __call__(self, **values) -> np.ndarray:
        """Evaluate element-wise on broadcast inputs.

        Parameters
        ----------
        **values : array_like
            One value per used variable (scalars or arrays, mutually broadcastable); unused
            allowed variables may be given too and take part in the broadcast.

        Returns
        -------
        numpy.ndarray of float64
            Shape ``np.broadcast_shapes(*(shape of each input))``, also for a constant expression.

        Raises
        ------
        TypeError
            If a used variable is missing or an unknown variable is given.
        """
        unknown = sorted(set(values) - self.variables)
        if unknown:
            raise TypeError(f"expression {quote(self.source)}: unknown variable(s) {unknown}")
        missing = sorted(self.names - set(values))
        if missing:
            raise TypeError(f"expression {quote(self.source)}: missing value(s) for {missing}")
        arrays = {name: np.asarray(v, dtype=np.float64) for name, v in values.items()}
        result = _evaluate(self.tree.body, arrays)
        shape = np.broadcast_shapes(result.shape, *(a.shape for a in arrays.values()))
        return np.array(np.broadcast_to(result, shape), dtype=np.float64)

    def traced(self, **values):
        """Evaluate with ``jax.numpy`` (the same functions by name), so that the expression is a JAX function
        of its variables (traceable, differentiable), e.g. a time law ``g(t)``. Used variables must be given."""
        import jax.numpy as jnp

        missing = sorted(self.names - set(values))
        if missing:
            raise TypeError(f"expression {quote(self.source)}: missing value(s) for {missing}")
        return _evaluate(self.tree.body, {k: jnp.asarray(v, dtype=jnp.float64) for k, v in values.items()}, jnp)


def parse_expression(source: str, variables=DEFAULT_VARIABLES) -> Expression:
    """Parse and validate ``source`` as an expression of ``variables``; see `Expression`."""
    return Expression(source, frozenset(variables))


def expression_field(expr, points, t: float = 0.0) -> np.ndarray:
    """Evaluate an expression of ``x, y, z, r, t`` at points.

    Parameters
    ----------
    expr : Expression or str
        A string is parsed with the default variables.
    points : (n, dim) array_like, dim <= 3
        Coordinates; missing coordinates are zero, ``r`` is the distance to the origin.
    t : float
        Time.

    Returns
    -------
    (n,) float64
    """
    expr = parse_expression(expr) if isinstance(expr, str) else expr
    pts = np.asarray(points, dtype=np.float64)
    pts = pts[:, None] if pts.ndim == 1 else pts
    if pts.ndim != 2 or pts.shape[1] > 3:
        raise ValueError(f"expression_field: points must have shape (n, dim <= 3), got {pts.shape}")
    padded = np.zeros((pts.shape[0], 3))
    padded[:, : pts.shape[1]] = pts
    available = {
        "x": padded[:, 0],
        "y": padded[:, 1],
        "z": padded[:, 2],
        "r": np.linalg.norm(padded, axis=1),
        "t": np.float64(t),
    }
    values = {name: v for name, v in available.items() if name in expr.variables}
    return np.array(np.broadcast_to(expr(**values), (pts.shape[0],)))


def _check_variable_names(variables: frozenset) -> None:
    for name in variables:
        if not isinstance(name, str) or not name.isidentifier() or name.startswith("__"):
            raise InputError(f"invalid expression variable name {name!r}")
        if name in FUNCTIONS or name in CONSTANTS:
            raise InputError(f"expression variable {name!r} shadows a function or constant")


def _parse(source) -> ast.Expression:
    if not isinstance(source, str):
        raise InputError(f"expression must be a string, got {type(source).__name__}")
    if len(source) > _MAX_SOURCE_LENGTH:
        raise InputError(f"expression {quote(source)} is longer than {_MAX_SOURCE_LENGTH} characters")
    try:
        with _recursion_limit(sys.getrecursionlimit() + len(source)):
            return ast.parse(source.strip(), mode="eval")
    except SyntaxError as err:
        raise InputError(f"expression {quote(source)}: invalid syntax ({err.msg}, column {err.offset})") from None
    except (ValueError, RecursionError, MemoryError) as err:
        raise InputError(f"expression {quote(source)}: cannot be parsed "
                         f"({type(err).__name__}: nested too deeply)") from None


@contextmanager
def _recursion_limit(limit: int):
    """Python's recursion limit raised to ``limit`` inside the block: the C code that turns the
    parser's tree into `ast` nodes counts one level per operator of a chain like ``x + x + ...``."""
    previous = sys.getrecursionlimit()
    sys.setrecursionlimit(max(previous, limit))
    try:
        yield
    finally:
        sys.setrecursionlimit(previous)


def _reject(source: str, what: str) -> InputError:
    return InputError(f"expression {quote(source)}: {what} not allowed")


def _children(node: ast.AST) -> list:
    """The operands of an allowed node (a call's arguments, not its name)."""
    if isinstance(node, ast.BinOp):
        return [node.left, node.right]
    if isinstance(node, ast.UnaryOp):
        return [node.operand]
    if isinstance(node, ast.BoolOp):
        return list(node.values)
    if isinstance(node, ast.Compare):
        return [node.left, *node.comparators]
    if isinstance(node, ast.Call):
        return list(node.args)
    return []


def _preorder(root: ast.AST):
    """The nodes under ``root``, every node before its operands, left to right (an explicit stack:
    no recursion)."""
    stack = [root]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(_children(node)))


def _postorder(root: ast.AST) -> list:
    """The nodes under ``root``, every node after its operands."""
    order, stack = [], [root]
    while stack:
        node = stack.pop()
        order.append(node)
        stack.extend(_children(node))
    return order[::-1]


def _check(root: ast.AST, variables: frozenset, source: str) -> set:
    """Validate every node under ``root``, outermost first (a call's name before its arguments);
    return the variable names it uses."""
    names = set()
    for node in _preorder(root):
        names |= _check_node(node, variables, source)
    return names


def _check_node(node: ast.AST, variables: frozenset, source: str) -> set:
    """Validate one node (its operands are checked separately); the variable it names, if any."""
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise _reject(source, f"{type(node.value).__name__} literal {quote(node.value, 40)}")
        if not _fits_float64(node.value):
            raise InputError(f"expression {quote(source)}: number {quote(node.value, 40)} is out of float64 range")
        return set()
    if isinstance(node, ast.Name):
        return _check_name(node.id, variables, source)
    if isinstance(node, (ast.BinOp, ast.UnaryOp)):
        if type(node.op) not in (_BINARY if isinstance(node, ast.BinOp) else _UNARY):
            raise _reject(source, f"operator {type(node.op).__name__!r}")
        return set()
    if isinstance(node, ast.BoolOp):
        return set()
    if isinstance(node, ast.Compare):
        for op in node.ops:
            if type(op) not in _COMPARE:
                raise _reject(source, f"comparison operator {type(op).__name__!r}")
        return set()
    if isinstance(node, ast.Call):
        return _check_call(node, variables, source)
    raise _reject(source, _CONSTRUCT_NAMES.get(type(node), f"{type(node).__name__} syntax"))


def _fits_float64(value) -> bool:
    try:
        return bool(np.isfinite(float(value)))
    except OverflowError:
        return False


def _check_name(name: str, variables: frozenset, source: str) -> set:
    if name.startswith("__"):
        raise _reject(source, f"dunder name {quote(name, 40)}")
    if name in variables:
        return {name}
    if name in CONSTANTS:
        return set()
    if name in FUNCTIONS:
        raise InputError(f"expression {quote(source)}: function {name!r} must be called, e.g. {name}(x)")
    raise InputError(f"expression {quote(source)}: unknown name {quote(name, 40)} (variables: {sorted(variables)}, "
                     "constants: pi, e)")


def _check_call(node: ast.Call, variables: frozenset, source: str) -> set:
    if not isinstance(node.func, ast.Name):
        raise _reject(source, f"calling {_CONSTRUCT_NAMES.get(type(node.func), type(node.func).__name__)}")
    name = node.func.id
    if name.startswith("__"):
        raise _reject(source, f"dunder name {quote(name, 40)}")
    if name not in FUNCTIONS:
        raise InputError(f"expression {quote(source)}: unknown function {quote(name, 40)} "
                         f"(allowed: {', '.join(sorted(FUNCTIONS))})")
    if node.keywords:
        raise _reject(source, f"keyword arguments in call to {name!r}")
    arity = FUNCTIONS[name][1]
    if len(node.args) != arity:
        raise InputError(f"expression {quote(source)}: {name}() takes {arity} argument(s), got {len(node.args)}")
    return set()


def _evaluate(root: ast.AST, values: dict, xp=np) -> np.ndarray:
    """Evaluate a validated tree, operands before operators; every result is a float64 array of the array
    namespace ``xp`` (numpy, or jax.numpy for a traced evaluation: the functions of the same names)."""
    results = {}
    for node in _postorder(root):
        operands = [results.pop(id(child)) for child in _children(node)]
        results[id(node)] = _evaluate_node(node, operands, values, xp)
    return results[id(root)]


def _in(xp, fn):
    """The function of ``xp`` named as the numpy function ``fn``."""
    return fn if xp is np else getattr(xp, fn.__name__)


def _evaluate_node(node: ast.AST, operands: list, values: dict, xp=np) -> np.ndarray:
    """One node's value from its operands' values."""
    if isinstance(node, ast.Constant):
        return xp.asarray(node.value, dtype=np.float64)
    if isinstance(node, ast.Name):
        return values[node.id] if node.id in values else xp.asarray(CONSTANTS[node.id])
    if isinstance(node, ast.BinOp):
        return _in(xp, _BINARY[type(node.op)])(*operands)
    if isinstance(node, ast.UnaryOp):
        return xp.asarray(_in(xp, _UNARY[type(node.op)])(operands[0]), dtype=np.float64)
    if isinstance(node, ast.BoolOp):
        combined = operands[0]
        for operand in operands[1:]:
            combined = _in(xp, _BOOLEAN[type(node.op)])(combined, operand)
        return xp.asarray(combined, dtype=np.float64)
    if isinstance(node, ast.Compare):
        return _evaluate_comparison(node, operands, xp)
    return xp.asarray(_in(xp, FUNCTIONS[node.func.id][0])(*operands), dtype=np.float64)


def _evaluate_comparison(node: ast.Compare, operands: list, xp=np) -> np.ndarray:
    """``a < b <= c`` as ``(a < b) and (b <= c)``, as 1.0 / 0.0."""
    result = xp.asarray(True)
    for op, left, right in zip(node.ops, operands[:-1], operands[1:]):
        result = xp.logical_and(result, _in(xp, _COMPARE[type(op)])(left, right))
    return xp.asarray(result, dtype=np.float64)
