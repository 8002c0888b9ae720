"""A small, safe expression language that selects episodes by their provenance (``--where`` on the CLI).

Examples::

    skill == "expert" and success
    source in {"script", "haptic"} and not operator_simulated
    operator_id in {"surgeon1", "surgeon2"} or (skill == "novice" and path_length_cm < 30)
    episode_steps >= 20 and seed != 3

Names are columns of :attr:`DatasetReader.episodes` (``episode_index``, ``length`` and the provenance
columns). Allowed: literals (strings, numbers, True/False), set/list/tuple literals, ``== != < <= > >=``,
``in`` / ``not in``, ``and`` / ``or`` / ``not``, parentheses, and unary minus on numbers. Anything else
(calls, attributes, subscripts, arithmetic, lambdas ...) is rejected before evaluation: the string is parsed
with :mod:`ast` and walked node by node, never handed to ``eval``.
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable, Iterable

import numpy as np


class WhereError(ValueError):
    """A ``--where`` expression is malformed, uses something outside the language, or names no column."""


_COMPARE = {ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
            ast.Gt: operator.gt, ast.GtE: operator.ge}
_HELP = ("allowed: column names, string/number/True/False literals, {set} / [list] literals, == != < <= > >=, "
         "in / not in, and / or / not, parentheses")


def compile_where(expression: str, columns: Iterable[str]) -> Callable[[dict], bool]:
    """A predicate over one episodes row (a dict), or :class:`WhereError` naming the offending part."""
    if not isinstance(expression, str) or not expression.strip():
        raise WhereError(f"--where needs a non-empty expression, e.g. 'skill == \"expert\" and success'; got "
                         f"{expression!r}")
    columns = list(columns)
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError as e:
        raise WhereError(f"cannot parse --where {expression!r}: {e.msg} at column {e.offset}; {_HELP}") from None
    _check(tree.body, expression, set(columns))

    def predicate(row: dict) -> bool:
        value = _evaluate(tree.body, row)
        return bool(value.item() if isinstance(value, np.generic) else value)

    return predicate


def _literal(node: ast.AST, expression: str):
    """The python value of a literal node (constants, -number, and sets/lists/tuples of them)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (str, int, float, bool)):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant) \
            and isinstance(node.operand.value, (int, float)) and not isinstance(node.operand.value, bool):
        return -node.operand.value
    if isinstance(node, (ast.Set, ast.List, ast.Tuple)):
        return frozenset(_literal(e, expression) for e in node.elts)
    raise WhereError(f"--where {expression!r}: {ast.unparse(node)!r} is not a literal; {_HELP}")


def _check(node: ast.AST, expression: str, columns: set[str]) -> None:
    if isinstance(node, ast.BoolOp):
        for value in node.values:
            _check(value, expression, columns)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        _check(node.operand, expression, columns)
    elif isinstance(node, ast.Compare):
        for operand in (node.left, *node.comparators):
            if isinstance(operand, ast.Name):
                _check(operand, expression, columns)
            else:
                _literal(operand, expression)
        for op, right in zip(node.ops, node.comparators, strict=True):
            if isinstance(op, (ast.In, ast.NotIn)):
                if not isinstance(right, (ast.Set, ast.List, ast.Tuple)):
                    raise WhereError(f"--where {expression!r}: 'in' needs a literal set on its right, e.g. "
                                     f"source in {{\"script\", \"haptic\"}}; got {ast.unparse(right)!r}")
            elif type(op) not in _COMPARE:
                raise WhereError(f"--where {expression!r}: operator {type(op).__name__} is not allowed; {_HELP}")
    elif isinstance(node, ast.Name):
        if node.id not in columns:
            raise WhereError(f"--where {expression!r}: no column {node.id!r}; available: {sorted(columns)}")
    elif isinstance(node, ast.Constant) and isinstance(node.value, bool):
        pass
    else:
        raise WhereError(f"--where {expression!r}: {ast.unparse(node)!r} ({type(node).__name__}) is not allowed; "
                         f"{_HELP}")


def _operand(node: ast.AST, row: dict):
    if isinstance(node, ast.Name):
        value = row[node.id]
        return value.item() if isinstance(value, np.generic) else value
    return _literal(node, "")


def _evaluate(node: ast.AST, row: dict):
    if isinstance(node, ast.BoolOp):
        values = (_evaluate(v, row) for v in node.values)
        return all(values) if isinstance(node.op, ast.And) else any(values)
    if isinstance(node, ast.UnaryOp):
        return not _evaluate(node.operand, row)
    if isinstance(node, ast.Name):
        return bool(_operand(node, row))
    if isinstance(node, ast.Constant):
        return node.value
    left = _operand(node.left, row)
    for op, right_node in zip(node.ops, node.comparators, strict=True):
        right = _operand(right_node, row)
        if isinstance(op, ast.In):
            ok = left in right
        elif isinstance(op, ast.NotIn):
            ok = left not in right
        else:
            try:
                ok = _COMPARE[type(op)](left, right)
            except TypeError:
                raise WhereError(f"cannot compare {left!r} ({type(left).__name__}) with {right!r} "
                                 f"({type(right).__name__}) in --where; check the column's type") from None
        if not ok:
            return False
        left = right
    return True
