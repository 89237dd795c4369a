"""Expanding a xacro file without letting it run code: a xacro is a program.

xacro evaluates ``$(eval …)`` with Python's real builtins, and ``${…}`` may read any file
(``xacro.load_yaml``) or environment variable into the model text, and from there into
``playback.html``. Unless the user trusts the file (``--trust-xacro``), :func:`sandboxed` expands
it with ``$(eval …)`` without builtins, ``${…}`` without ``load_yaml``, ``abs_filename``,
``type`` and ``vars``, no underscore, frame, code or ``str.format`` attribute (known ways out of
a builtin-free ``eval``), ``$(env)`` refused, and ``<xacro:include>`` only of files under the
xacro's folder, its package and the folders ``$(find …)`` returned.
"""

from __future__ import annotations

import ast
import builtins
import contextlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from pe_drake import limits
from pe_drake.exceptions import ConfigError
from pe_drake.limits import input_file_problem
from pe_drake.multibody.mesh_policy import is_under

#: What the refusals tell the user to do when they trust the file.
TRUST_HINT = ("a xacro file is a program that pe_drake runs to expand it; if you trust its author, pass "
              "--trust-xacro (or set robot.trust_xacro: true in your config)")

#: The builtins ``$(eval …)`` keeps: conversions and arithmetic, none that reaches a class or a file.
_PLAIN_BUILTINS = {name: getattr(builtins, name) for name in (
    "list", "dict", "map", "str", "float", "int", "bool", "len", "min", "max", "abs", "round", "sum", "range",
    "sorted", "zip", "any", "all", "True", "False", "None")}
_REMOVED_SYMBOLS = ("load_yaml", "abs_filename", "type", "vars")
_FORBIDDEN_ATTRIBUTES = ("format", "format_map", "mro")
_FORBIDDEN_PREFIXES = ("_", "gi_", "cr_", "ag_", "f_", "co_", "tb_", "func_")


class XacroRefused(ConfigError):
    """An untrusted xacro file uses a construct that could run code or read files."""


def check_expression(expression: str, where: str) -> None:
    """Refuses (:class:`XacroRefused`) an expression that reaches outside its symbols."""
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError:
        return  # xacro reports the syntax error itself
    for node in ast.walk(tree):
        name = node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else None
        if name is None:
            continue
        # A bare name is looked up in the sanitised symbols (a property called 'type' is fine);
        # an attribute can reach past them.
        bad = isinstance(node, ast.Attribute) and (
            name in _REMOVED_SYMBOLS or name in _FORBIDDEN_ATTRIBUTES or name.startswith(_FORBIDDEN_PREFIXES))
        if bad:
            raise XacroRefused(f"{where} '{expression.strip()[:200]}' uses '{name}', which an untrusted xacro may "
                               f"not use (it can run code or read files); {TRUST_HINT}")


def _sanitized_symbols(xacro) -> dict:
    """xacro's global symbols without the ones that read files or reach the interpreter."""
    out = {}
    for key, value in xacro._global_symbols.items():  # noqa: SLF001 (xacro keeps them in a module global)
        if key in _REMOVED_SYMBOLS:
            continue
        if isinstance(value, xacro.NameSpace):
            space = xacro.NameSpace()
            dict.update(space, {k: v for k, v in dict.items(value) if k not in _REMOVED_SYMBOLS})
            value = space
        out[key] = value
    return out


def _refuse_env(name: str, *_default, **_kwargs) -> str:
    from xacro.substitution_args import SubstitutionException  # lazy: only xacro models need it

    raise SubstitutionException(f"$(env {name}) / $(optenv {name}) reads an environment variable; {TRUST_HINT}")


def _safe_dollar_eval(substitution_args) -> Callable:
    """xacro's ``$(eval …)`` without builtins (it passes ``{}`` as globals: Python adds the real ones)."""

    def evaluate(text: str, context: dict) -> str:
        check_expression(text, "$(eval …)")
        if "__" in text:
            raise substitution_args.SubstitutionException("$(eval ...) may not contain double underscore expressions")
        context.setdefault("arg", {})
        functions = {
            "arg": lambda name: substitution_args.convert_value(
                substitution_args._eval_arg(name, args=context["arg"]), "auto"),  # noqa: SLF001
            "dirname": lambda: substitution_args._eval_dirname(context["filename"]),  # noqa: SLF001
        }
        functions.update({k: v for k, v in substitution_args._eval_dict.items()  # noqa: SLF001
                          if k not in ("__builtins__", "env", "optenv")})
        scope = substitution_args._DictWrapper(context["arg"], functions)  # noqa: SLF001
        return str(eval(text, {"__builtins__": dict(_PLAIN_BUILTINS)}, scope))  # noqa: S307 (checked above)

    return evaluate


def _confined_parse(original: Callable, allowed: list[str]) -> Callable:
    def parse(inp, filename=None):
        if inp is None and filename is not None:
            real = os.path.realpath(filename)
            if not is_under(real, allowed):
                raise XacroRefused(
                    f"xacro:include of '{filename}' ({real}) is outside the xacro's folder, its package and the "
                    f"packages it finds; {TRUST_HINT}")
            problem = input_file_problem(real)  # a named pipe would block the expansion
            if problem is None and os.path.getsize(real) > limits.in_bytes(limits.MESH):
                problem = f"is over {limits.describe(limits.MESH)}"
            if problem:
                raise XacroRefused(f"xacro:include of '{filename}': {real} {problem}")
        return original(inp, filename)

    return parse


@contextlib.contextmanager
def sandboxed(path: Path, package_root: Path | None, found: list[str]) -> Iterator[None]:
    """Within it, ``xacro.process_file`` expands ``path`` as described in the module docstring.

    Args:
        package_root: the folder of the package holding it, or None.
        found: the folders ``$(find …)`` returned; the caller's find appends to it.

    The caller holds the lock that serialises xacro (its state is module-global).
    """
    import xacro  # lazy: only xacro models need it
    from xacro import substitution_args

    allowed = found
    allowed += [os.path.realpath(path.parent)] + ([os.path.realpath(package_root)] if package_root else [])
    saved_symbols, saved_safe_eval, saved_parse = xacro._global_symbols, xacro.safe_eval, xacro.parse  # noqa: SLF001
    saved_subst = (substitution_args._eval, substitution_args._eval_env, substitution_args._eval_optenv,  # noqa: SLF001
                   substitution_args._eval_dict.get("env"), substitution_args._eval_dict.get("optenv"))  # noqa: SLF001

    def safe_eval(expression, symbols, local=None):
        check_expression(expression, "${…}")
        return saved_safe_eval(expression, symbols, local)

    xacro._global_symbols = _sanitized_symbols(xacro)  # noqa: SLF001
    xacro.safe_eval, xacro.parse = safe_eval, _confined_parse(saved_parse, allowed)
    substitution_args._eval = _safe_dollar_eval(substitution_args)  # noqa: SLF001
    substitution_args._eval_env = substitution_args._eval_optenv = _refuse_env  # noqa: SLF001
    substitution_args._eval_dict["env"] = substitution_args._eval_dict["optenv"] = _refuse_env  # noqa: SLF001
    try:
        yield
    finally:
        xacro._global_symbols, xacro.safe_eval, xacro.parse = saved_symbols, saved_safe_eval, saved_parse  # noqa: SLF001
        (substitution_args._eval, substitution_args._eval_env, substitution_args._eval_optenv,  # noqa: SLF001
         substitution_args._eval_dict["env"], substitution_args._eval_dict["optenv"]) = saved_subst  # noqa: SLF001
