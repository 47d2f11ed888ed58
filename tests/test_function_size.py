"""No function of ``autograder/`` is longer than a TA reads at once, or takes more values
than a reader can hold (issue 51): at most 60 lines of body (its docstring aside) and at
most 8 parameters (``self`` and ``cls`` not counted; ``*args`` and ``**kwargs`` count one
each). Nested functions are measured on their own, and count in their enclosing one's
lines too, as a reader reads them there.

Every function is within them: the allow-list of the split's first round emptied when the
last ten were split (issue 51), and no exception is kept.
"""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "autograder"
MAX_LINES = 60
MAX_PARAMETERS = 8


def body_lines(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the last, inclusive."""
    body = fn.body
    if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)):
        body = body[1:]
    return 0 if not body else body[-1].end_lineno - body[0].lineno + 1


def parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef, in_class: bool) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    names += [p.arg for p in (a.vararg, a.kwarg) if p is not None]
    if in_class and names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names)


@lru_cache(maxsize=1)
def measured() -> dict[tuple[str, str], tuple[int, int]]:
    """{(file, qualified name): (body lines, parameters)} of every function of autograder/."""
    out = {}

    def visit(node, file: str, prefix: str, in_class: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                size = (body_lines(child), parameters(child, in_class))
                key = (file, name)
                # two functions of one name in a file (a property's setter): the larger
                out[key] = max(out.get(key, (0, 0)), size)
                visit(child, file, name + ".", False)
            elif isinstance(child, ast.ClassDef):
                visit(child, file, prefix + child.name + ".", True)
            else:
                visit(child, file, prefix, in_class)

    for path in sorted(ROOT.rglob("*.py")):
        visit(ast.parse(path.read_text(encoding="utf-8")), path.relative_to(ROOT).as_posix(),
              "", False)
    return out


def over(size: tuple[int, int]) -> bool:
    return size[0] > MAX_LINES or size[1] > MAX_PARAMETERS


def test_the_measure_sees_a_long_function_and_a_wide_one():
    long_one = "def f():\n    '''doc\n    doc'''\n" + "    x = 1\n" * 61
    wide = "class C:\n    def g(self, a, b, c, d, e, f, g, h, *rest):\n        pass\n"
    fn = ast.parse(long_one).body[0]
    method = ast.parse(wide).body[0].body[0]
    assert body_lines(fn) == 61 and over((body_lines(fn), 0))
    assert parameters(method, in_class=True) == 9 and over((1, 9))
    assert not over((60, 8))


def test_no_function_over_the_limits():
    over_limits = {k: v for k, v in measured().items() if over(v)}
    assert not over_limits, (f"functions over {MAX_LINES} lines or {MAX_PARAMETERS} parameters: "
                     + "; ".join(f"{f}:{n} {s}" for (f, n), s in sorted(over_limits.items()))
                     + ". Split them into smaller functions (or pass one typed value)")
